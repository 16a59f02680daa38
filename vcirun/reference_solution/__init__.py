"""The exact nonsmooth solution a run is measured against: `reference(system, T=..., ...)` (the public
`vcirun.reference`) and `l2_error(trajectory, reference)`. `exact` is the entry point and the accuracy check; `loop` resolves
the events (impact law, holds, accumulation, releases) between the segments of an integration path:
`taylor` (heyoka, every root of every phi_i isolated in each step) or `dop853` (for systems the Taylor
path cannot express); `held` is the geometry of held contacts, `flight` what a segment returns.
"""
from .exact import Reference, l2_error, reference

__all__ = ["reference", "l2_error", "Reference"]
