"""vcirun: event-driven variational collision integrators (Pekarek & Murphey) as an experiment runner.

Python API: `simulate`, `ensemble`, `reference`, `l2_error`, `open_results`; command line: `vcirun --help`.

The API names are loaded on first use (PEP 562), so `import vcirun` costs next to nothing and a warm
`vcirun.simulate` imports neither sympy nor scipy.integrate.
"""
import sys as _sys
import types as _types

__version__ = "0.1.0"

__all__ = ["simulate", "ensemble", "reference", "l2_error", "Trajectory", "open_results", "periodic_orbit", "__version__"]

_LAZY = {"simulate": ("run.api", "simulate"), "ensemble": ("run.ensemble", "ensemble"), "reference": ("reference", "reference"),
         "l2_error": ("reference", "l2_error"), "Trajectory": ("run.trajectory", "Trajectory"),
         "open_results": ("io.results", "open_results"), "verify": ("verification", "verify"),
         "periodic_orbit": ("experiments.periodic", "periodic_orbit")}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        value = getattr(importlib.import_module(f".{module}", __name__), attr)
        globals()[name] = value  # later look-ups skip this function
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


class _Package(_types.ModuleType):
    """`vcirun.reference` is the function: importing the subpackage vcirun.reference (e.g.
    `from vcirun.reference.exact import l2_error`) makes the import system bind the package attribute
    of the same name to the subpackage; keep the function."""

    def __setattr__(self, name, value):
        if name == "reference" and isinstance(value, _types.ModuleType) and hasattr(value, "reference"):
            value = value.reference
        super().__setattr__(name, value)


_sys.modules[__name__].__class__ = _Package
