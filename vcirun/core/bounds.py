"""Argument checks of `vcirun.simulate` and `vcirun.reference`: they run before any work starts and
turn bad input into a one-line `ValueError` that names the field and says what to write instead,
with the bounds and messages of a sweep config.

No sympy and no numba here.
"""
from __future__ import annotations

import math

import numpy as np

from .grid import grid_steps
from .limits import check_count, sized_family
from .names import ascii_name_problem, check_distinct_names, reserved_name_problem
from .tolerances import check_tolerances
from .values import check_bool, check_number, check_state_vector, describe

__all__ = ["check_params", "check_system_names", "check_scene_size", "check_one_start", "check_simulate_args",
           "check_reference_args", "nonfinite_start"]


def check_params(params, field: str = "params") -> dict | None:
    if params is None:
        return None
    if not isinstance(params, dict):
        raise ValueError(f"{field}: must be a mapping of parameter names to numbers (got {describe(params)})")
    out = {}
    for k, v in params.items():
        if not isinstance(k, str):
            raise ValueError(f"{field}: names must be strings (got {describe(k)})")
        problem = ascii_name_problem(k)
        if problem:
            raise ValueError(f"{field}.{describe(k)}: {problem}")
        out[k] = check_number(f"{field}.{k}", v)
    return out


def check_system_names(system) -> None:
    """A MechanicalSystem built in Python: its coordinate and parameter names obey the loader's rules."""
    q = getattr(system, "q", None)
    params = getattr(system, "params", None)
    if not isinstance(q, (list, tuple)) or not isinstance(params, dict):
        return
    names = {f"coordinates[{i}]": getattr(s, "name", str(s)) for i, s in enumerate(q)}
    names.update({f"parameters.{k}": k for k in params})
    check_distinct_names(names, "system")
    for fld, name in names.items():
        problem = reserved_name_problem(name)
        if problem:
            raise ValueError(f"system.{fld}: {problem}")


def check_scene_size(system, field: str = "system") -> None:
    """A sized built-in scene (`n_pendulum_K`, `link_chain_K`, `cradle_K`, `newton_cradle_K`) within
    its range (vcirun.core.limits.FAMILY_SIZES): K = 100000 would build its symbolic model and kernels
    until memory runs out. A MechanicalSystem within the caps on coordinates, contacts and parameters."""
    if isinstance(system, str):
        try:
            sized_family(system)
        except ValueError as e:
            raise ValueError(f"{field}{str(e)[len('system'):]}") from None
        return
    q, params = getattr(system, "q", None), getattr(system, "params", None)
    constraints = getattr(system, "constraints", None)
    if isinstance(q, (list, tuple)):
        check_count("coordinates", f"{field}.q", len(q))
    if isinstance(constraints, (list, tuple)):
        check_count("contacts", f"{field}.constraints", len(constraints))
    if isinstance(params, dict):
        check_count("parameters", f"{field}.params", len(params))


def check_one_start(beta, q0, p0) -> None:
    """Either beta or q0/p0: given both, one of them would be silently ignored (q0/p0 won)."""
    if beta is not None and (q0 is not None or p0 is not None):
        raise ValueError("beta: give either beta or q0 and p0, not both (the initial state would ignore one)")


def check_simulate_args(*, h, T, t0=0.0, beta=None, q0=None, p0=None, params=None, constrained=None,
                        energies=True, tolerances: dict | None = None, system=None,
                        resting_contact=True) -> tuple[float, float, int]:
    """Validate `vcirun.simulate`'s arguments (same bounds and messages as a sweep config); returns the
    grid (h, T, N) of `vcirun.core.grid.grid_steps`."""
    h, T, N = grid_steps(h, T)
    t0 = check_number("t0", t0)
    if not math.isfinite(t0 + float(T)) or t0 + h == t0:
        raise ValueError(f"t0: h = {h:g} is below the resolution of times near t0 = {t0:g}; use a smaller |t0|")
    check_bool("resting_contact", resting_contact)
    check_start_args(beta, q0, p0, params)
    check_bool("constrained", constrained, allow_none=True)
    check_bool("energies", energies)
    check_tolerances(tolerances)
    if system is not None:
        check_scene_size(system)
        check_system_names(system)
    return h, T, N


def check_reference_args(*, T, rtol=1e-13, method="exact", h=None, beta=None, q0=None, p0=None,
                         params=None, system=None, resting_contact=True, check_accuracy=True) -> None:
    """Validate `vcirun.reference`'s arguments (the config layer's bounds on reference.rtol, T, h)."""
    check_number("T", T, gt=0)
    check_start_args(beta, q0, p0, params)
    check_bool("resting_contact", resting_contact)
    check_bool("check_accuracy", check_accuracy)
    check_scene_size(system)
    if not isinstance(method, str):
        raise ValueError(f"method: must be 'exact' or a method name (got {describe(method)})")
    if method == "exact":
        check_number("rtol", rtol, ge=2.3e-14, lt=1e-3)
    elif h is not None:
        grid_steps(h, T)


def nonfinite_start(H0, Ed0=0.0, Hmod0=0.0, q0=None, p0=None) -> str:
    """Why a run cannot be trusted from its first grid point ('' if it can): a non-finite initial energy
    (an initial state so large that H overflows) makes every energy error NaN."""
    if ((H0 is None or math.isfinite(H0)) and (Ed0 is None or math.isfinite(Ed0))
            and (Hmod0 is None or math.isfinite(Hmod0))):   # (every run asks: the common case first)
        return ""
    bad = [(name, v) for name, v in (("H", H0), ("Ed", Ed0), ("Hmod", Hmod0)) if v is not None and not np.isfinite(v)]
    if not bad:
        return ""
    scale = ""
    if q0 is not None and p0 is not None:
        scale = f" (max |q0| = {float(np.max(np.abs(q0))):.3g}, max |p0| = {float(np.max(np.abs(p0))):.3g})"
    what = ", ".join(f"{k}(0) = {v}" for k, v in bad)
    return (f"non-finite initial energy: {what}; the initial state{scale} overflows the energy in floating "
            "point, so no energy or trajectory error can be measured")


def check_start_args(beta=None, q0=None, p0=None, params=None) -> None:
    """The per-run arguments: one start (beta, or q0 and p0), each finite, and the parameters."""
    check_one_start(beta, q0, p0)
    if beta is not None:
        check_number("beta", beta)
    if q0 is not None:
        check_state_vector("q0", q0)
    if p0 is not None:
        check_state_vector("p0", p0)
    check_params(params)
