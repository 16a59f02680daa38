"""The Python API: `simulate`, `reference`, `l2_error`. The CLI and the sweep runner go through these."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from . import trajectory as tr
from .codegen.build import load_module
from .mechanics.system import MechanicalSystem
from .methods import resolve_method

DEFAULT_TOLERANCES = {"newton_tol": 1e-12, "event_tol": 1e-13, "max_iter": 50, "max_impacts_step": 64}
_METHOD_OPTIONS = {"ld", "mh_order", "flow_order"}


def resolve_system(system, params: dict | None = None) -> MechanicalSystem:
    """A MechanicalSystem from a built-in name, a YAML file path, or an instance."""
    if isinstance(system, MechanicalSystem):
        if params:
            system.param_values(params)  # validates the names
        return system
    if isinstance(system, (str, Path)):
        s = str(system)
        if s.endswith((".yaml", ".yml")) or Path(s).is_file():
            from .mechanics.loader import load_system_yaml

            return load_system_yaml(s)
        from .mechanics.scenes import get_scene

        return get_scene(s)
    raise ValueError(f"system: expected a built-in name, a YAML path or a MechanicalSystem, got {type(system).__name__}")


def simulate(system, method, *, h, T, beta=None, q0=None, p0=None, params=None, constrained=None,
             t0=0.0, **options) -> tr.Trajectory:
    """Simulate `system` with `method` on the grid t_k = t0 + k h, k = 0..N, N = round(T / h).

    system : built-in name ('cart_pendulum', 'double_pendulum', 'oscillator_wall', ...), YAML path,
             or MechanicalSystem.
    method : 'CVA', 'VCI', 'MCVAA', 'MCVAC', 'MCVA' (options ld=, mh_order=, flow_order=), or a
             discrete Lagrangian ('SE1', 'SE2', 'SVA', 'SVB', 'SVC', 'midpoint') for smooth
             integration with the constraint ignored.
    beta   : the scene's initial-condition map (Xi(beta) for the cart-pendulum); or give q0 and p0.
    params : parameter overrides; constrained: False ignores the constraint (default: per method).
    options: newton_tol, event_tol, max_iter, max_impacts_step.
    Numerical failure is returned as the trajectory's status (never raised); bad input raises
    ValueError naming the field.
    """
    mopts = {k: options.pop(k) for k in list(options) if k in _METHOD_OPTIONS}
    unknown = set(options) - set(DEFAULT_TOLERANCES)
    if unknown:
        raise ValueError(f"options: unknown option {sorted(unknown)[0]!r} (known: "
                         f"{', '.join(sorted(set(DEFAULT_TOLERANCES) | _METHOD_OPTIONS | {'params', 'constrained'}))})")
    tol = DEFAULT_TOLERANCES | options
    h = float(h)
    T = float(T)
    if not (h > 0 and np.isfinite(h)):
        raise ValueError(f"h: must be a positive finite step (got {h})")
    if not (T > 0 and np.isfinite(T)):
        raise ValueError(f"T: must be a positive finite time (got {T})")
    N = int(round(T / h))
    if N < 1:
        raise ValueError(f"T: must be at least one step h (got T={T}, h={h})")
    sysm = resolve_system(system)
    meth = resolve_method(method, **mopts)
    prm = sysm.param_values(params)
    q0, p0 = sysm.initial_state(beta=beta, q0=q0, p0=p0, params=prm)
    if constrained is None:
        constrained = meth.constrained
    mod = load_module(sysm, meth.kernel_set())
    n = sysm.n
    cap_imp = max(64, N // 4 + 16)
    out = dict(
        Q=np.zeros((N + 1, n)), P=np.zeros((N + 1, n)), Hs=np.full(N + 1, np.nan), Eds=np.full(N + 1, np.nan),
        Hm=np.full(N + 1, np.nan), imp_t=np.zeros(cap_imp), imp_q=np.zeros((cap_imp, n)),
        imp_pm=np.zeros((cap_imp, n)), imp_pp=np.zeros((cap_imp, n)), imp_step=np.zeros(N, dtype=np.bool_),
        partial_log=np.zeros(2 * cap_imp + 16), iters_log=np.zeros(N, dtype=np.int64),
        info=np.zeros(5, dtype=np.int64))
    t_start = time.perf_counter()
    with np.errstate(all="ignore"):
        mod.integrate(q0, p0, float(t0), h, N, prm, bool(constrained), float(tol["newton_tol"]), int(tol["max_iter"]),
                      float(tol["event_tol"]), int(tol["max_impacts_step"]), *out.values())
    wall = time.perf_counter() - t_start
    info = out["info"]
    status_code, fail, n_imp, n_par, steps = (int(x) for x in info)
    status = tr.STATUS_CODES[status_code]
    K = steps + 1  # grid points actually reached
    t = t0 + h * np.arange(N + 1)
    message = ""
    if status != tr.OK:
        message = (f"{status} in step {fail} (t = {t0 + fail * h:.6g}) from q = {out['Q'][fail].tolist()}, "
                   f"p = {out['P'][fail].tolist()}")
    return tr.Trajectory(
        method=meth.name, system=sysm.name, h=h, T=N * h, t=t[:K], q=out["Q"][:K], p=out["P"][:K], H=out["Hs"][:K],
        Ed=out["Eds"][:K], Hmod=out["Hm"][:K] if meth.reset == "mcva" else None,
        impacts=out["imp_t"][:n_imp].copy(), impact_q=out["imp_q"][:n_imp].copy(),
        impact_p_minus=out["imp_pm"][:n_imp].copy(), impact_p_plus=out["imp_pp"][:n_imp].copy(),
        impact_step=out["imp_step"][:steps].copy(), partial_steps=out["partial_log"][:n_par].copy(),
        newton_iters=out["iters_log"][:steps].copy(), status=status, message=message,
        fail_step=fail, fail_time=(t0 + fail * h) if fail >= 0 else float("nan"), beta=beta, wall_time=wall,
        tolerances={k: tol[k] for k in ("newton_tol", "event_tol", "max_iter", "max_impacts_step")},
        options={"params": dict(zip(sysm.params, prm.tolist())), "constrained": bool(constrained), **mopts})
