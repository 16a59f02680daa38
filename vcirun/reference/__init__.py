"""The exact nonsmooth solution a run is measured against: `reference(system, T=..., ...)` and
`l2_error(trajectory, reference)`. `exact` integrates the flights and applies the impact law at each
event; `held` integrates the phases in which contacts rest (index-reduced dynamics) and their releases.
"""
from .exact import Reference, l2_error, reference

__all__ = ["reference", "l2_error", "Reference"]
