"""vcirun: event-driven variational collision integrators (Pekarek & Murphey) as an experiment runner.

Python API: `simulate`, `ensemble`, `reference`, `l2_error`, `open_results`; command line: `vcirun --help`.

The API names are loaded on first use (PEP 562), so `import vcirun` costs next to nothing and a warm
`vcirun.simulate` imports neither sympy nor scipy.integrate. `vcirun.reference` is the function that
computes the exact nonsmooth solution; the package that implements it is `vcirun.reference_solution`.
"""
__version__ = "0.1.0"

__all__ = ["simulate", "ensemble", "reference", "l2_error", "Trajectory", "open_results", "periodic_orbit", "__version__"]

_LAZY = {"simulate": ("run.api", "simulate"), "ensemble": ("run.ensemble", "ensemble"),
         "reference": ("reference_solution", "reference"), "l2_error": ("reference_solution", "l2_error"),
         "Trajectory": ("run.trajectory", "Trajectory"), "open_results": ("io.results", "open_results"),
         "verify": ("verification", "verify"), "periodic_orbit": ("experiments.periodic", "periodic_orbit")}


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
