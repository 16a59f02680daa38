"""What a user would otherwise pick: scipy's `solve_ivp` with event location and the exact elastic reset.

`solve_ivp_run(system, "DOP853" | "Radau", h=, T=, rtol=, beta=...)` integrates Hamilton's
equations qdot = M^-1 p, pdot = -dH/dq with a terminal event on phi(q) = 0 (direction: entering the
constraint), applies the exact elastic reset p+ = p- + lam grad phi, lam = -2 g^T M^-1 p- / g^T M^-1 g
(H conserved; the same formula as `vcirun.reference`), restarts, and reports the solution on the
run's grid t_k = t0 + k h, k = 0..N, N = floor(T / h) (vcirun.core.grid) through `t_eval` (as a vcirun method would
report it). The result is a `vcirun.run.trajectory.Trajectory`, so `vcirun.l2_error(traj, ref)` and the
energy metrics apply unchanged; `wall_time` is the time of the solve loop (right-hand side calls,
event location, resets, dense output on the grid), the analogue of a vcirun run's compiled-loop time.
H on the grid is computed after the timed loop (a vcirun run computes it inside its loop).

Right-hand sides (`kernels=`):
- "compiled" (default): the scene's numba kernels (`hamilton_rhs`, `sys_phi`, `cva_lambda`), the
  fastest a solve_ivp user can make the model, so the comparison is as kind to scipy as it can be;
- "numpy": `sympy.lambdify` of M(q), dH/dq and phi with numpy solves, what a plain numpy/scipy
  implementation looks like.

Radau uses scipy's finite-difference Jacobian (what `solve_ivp(method="Radau")` does by default).
Failure never raises: the trajectory's status is "solver_failed" (scipy's message in `message`),
"reset_failed" (grazing contact: zero normal velocity), "accumulation" (more than `max_impacts`),
"nonfinite" (overflow) or "time_limit" (the run took longer than `time_limit` seconds).
"""
from __future__ import annotations

import time

import numpy as np

from ..run import trajectory as tr
from ..reference_solution.dop853 import step_off_surface

__all__ = ["BASELINES", "solve_ivp_run", "is_baseline", "hamiltonian_on_grid"]

BASELINES = ("DOP853", "Radau")
SOLVER_FAILED = "solver_failed"
TIME_LIMIT = "time_limit"


class _TimeLimit(Exception):
    pass


def is_baseline(method) -> bool:
    return isinstance(method, str) and method in BASELINES


class _CompiledModel:
    """Hamilton's equations, phi and the elastic reset from the scene's compiled kernels."""

    def __init__(self, sysm, prm):
        from ..codegen.build import load_module
        from ..codegen.kernel_set import SYSTEM_KERNELS

        self.mod = load_module(sysm, SYSTEM_KERNELS)
        self.n = sysm.n
        self.prm = prm
        self._buf = np.empty(2 * sysm.n)
        self._g = np.empty(sysm.n)
        mod, buf, n = self.mod, self._buf, self.n

        def rhs(t, y):
            mod.dynamics_rhs(t, y, prm, buf)  # forced Hamilton's equations (= hamilton_rhs unforced)
            return buf.copy()

        def phi(t, y):
            return mod.sys_phi(y[:n], prm)

        self.rhs, self.phi = rhs, phi

    def reset_lambda(self, q, pm):
        lam = self.mod.cva_lambda(q, pm, self.prm, self._g)
        return lam, self._g.copy()

    def hamiltonian(self, q, p) -> float:
        return float(self.mod.hamiltonian(q, p, self.prm))


class _NumpyModel:
    """The same model as a plain numpy/scipy user writes it: lambdified M(q), dH/dq at x = M^-1 p, V,
    phi and grad phi, numpy solves."""

    def __init__(self, sysm, prm):
        n = sysm.n
        self.n = n
        prm = [float(v) for v in prm]
        # lambdified in the mechanics layer: the runner never touches sympy itself
        Mf, dHf, Vf, phif, gf, ff = (sysm.numpy_functions()[k] for k in ("M", "dHq", "V", "phi", "grad_phi", "f"))
        self.M = lambda qq: np.asarray(Mf(qq, prm), float)
        self.V = lambda qq: float(Vf(qq, prm))
        self.grad = lambda qq: np.asarray(gf(qq, prm), float).ravel()

        def rhs(t, y):
            qq, pp = y[:n], y[n:]
            xx = np.linalg.solve(np.asarray(Mf(qq, prm), float), pp)
            pdot = -np.asarray(dHf(qq, xx, prm), float).ravel()
            if ff is not None:
                pdot = pdot + np.asarray(ff(qq, xx, t, prm), float).ravel()
            return np.concatenate([xx, pdot])

        def phi(t, y):
            return float(phif(y[:n], prm))

        self.rhs, self.phi = rhs, phi

    def reset_lambda(self, q, pm):
        g = self.grad(q)
        x = np.linalg.solve(self.M(q), g)
        gWg = float(g @ x)
        if not gWg > 0:
            return 0.0, g
        return -2.0 * float(x @ pm) / gWg, g

    def hamiltonian(self, q, p) -> float:
        return 0.5 * float(p @ np.linalg.solve(self.M(q), p)) + self.V(q)


_MODELS: dict = {}


def _model(sysm, prm, kernels):
    key = (id(sysm), sysm.fingerprint(), tuple(np.asarray(prm, float).tolist()), kernels)
    if key not in _MODELS:
        if kernels == "compiled":
            _MODELS[key] = _CompiledModel(sysm, np.asarray(prm, float))
        elif kernels == "numpy":
            _MODELS[key] = _NumpyModel(sysm, prm)
        else:
            raise ValueError(f"kernels: expected 'compiled' or 'numpy' (got {kernels!r})")
    return _MODELS[key]


def refusal(sysm) -> str | None:
    """Why the solve_ivp baselines cannot run symbolic system `sysm`, or None. Their event loop and reset
    are the paper's: one elastic constraint (the general impact law lives in the compiled loop and the
    exact reference)."""
    if sysm.m != 1 or any(c.restitution != 1 for c in sysm.constraints):
        return (f"the solve_ivp baselines take one elastic constraint; {sysm.name} declares {sysm.m} "
                f"(restitutions {[str(c.restitution) for c in sysm.constraints]})")
    return None


def solve_ivp_run(system, method: str = "DOP853", *, h, T, rtol, atol=None, beta=None, q0=None, p0=None,
                  params=None, t0: float = 0.0, kernels: str = "compiled", max_impacts: int = 100_000,
                  first_step=None, time_limit: float | None = None, energies: bool = True, escape: bool = True,
                  escape_step: float = 1e-7) -> tr.Trajectory:
    """solve_ivp (`method` = DOP853 or Radau) with a terminal event on phi, the exact elastic reset and
    output on the grid t0 + k h, k = 0..floor(T / h). atol defaults to rtol * max(1, max|y0|) (as the
    exact reference). Returns a Trajectory (`method` = "DOP853@rtol=1e-08" etc.; `options` records
    rtol, atol and the number of right-hand-side evaluations). escape: after each reset, one RK4 micro
    step (<= escape_step, and before the next grid point) to a state with phi > 0 before restarting
    with the event (escape=False reproduces the naive restart, which misses short hops at loose
    tolerances). time_limit (seconds): stop a run that
    takes longer (status "time_limit"). energies=False leaves H as NaN (saves a Python loop over the
    grid after the timed part)."""
    from scipy.integrate import solve_ivp

    from ..core.grid import grid_steps
    from ..run.resolve import resolve_system

    if method not in BASELINES:
        raise ValueError(f"method: expected one of {', '.join(BASELINES)} (got {method!r})")
    h, T, N = grid_steps(h, T)
    rtol = float(rtol)
    if not (rtol > 0 and np.isfinite(rtol)):
        raise ValueError(f"rtol: must be positive (got {rtol})")
    sysm = resolve_system(system)
    refused = refusal(sysm)
    if refused:
        raise ValueError(f"system: {refused}; use vcirun.simulate or vcirun.reference")
    prm = sysm.param_values(params)
    q0, p0 = sysm.initial_state(beta=beta, q0=q0, p0=p0, params=prm)
    model = _model(sysm, prm, kernels)
    n = sysm.n
    tgrid = t0 + h * np.arange(N + 1)
    y = np.concatenate([np.asarray(q0, float), np.asarray(p0, float)])
    if atol is None:
        atol = rtol * max(1.0, float(np.max(np.abs(y))))
    event = model.phi
    event.terminal = True
    event.direction = -1.0
    rhs = model.rhs
    if time_limit is not None:
        deadline = time.perf_counter() + float(time_limit)
        inner = rhs

        def rhs(t, y):
            if time.perf_counter() > deadline:
                raise _TimeLimit
            return inner(t, y)
    Y = np.full((N + 1, 2 * n), np.nan)
    imp_t, imp_q, imp_pm, imp_pp = [], [], [], []
    status, message = tr.OK, ""
    nfev = 0
    k = 0                      # next grid index to fill
    t = float(t0)
    T_end = float(tgrid[-1])
    extra = {} if first_step is None else {"first_step": first_step}
    t_start = time.perf_counter()
    while True:
        # grid points of this segment: t_k >= t (the first segment) or t_k > t (after an impact at t)
        teval = tgrid[k:]
        try:
            with np.errstate(all="ignore"):
                sol = solve_ivp(rhs, (t, T_end), y, method=method, rtol=rtol, atol=atol, events=event,
                                t_eval=teval, **extra)
        except _TimeLimit:
            status, message = TIME_LIMIT, f"stopped at the time limit of {time_limit:g} s (t = {t:.9g})"
            break
        nfev += int(sol.nfev)
        # scipy leaves sol.t / sol.y as (empty) lists when the solver fails before its first output
        m = int(np.size(sol.t))
        if m:
            Y[k:k + m] = np.asarray(sol.y).T
            k += m
        if sol.status < 0:
            status, message = SOLVER_FAILED, f"{method} failed at t = {t:.9g}: {sol.message}"
            break
        if m and not np.all(np.isfinite(np.asarray(sol.y)[:, -1])):
            status, message = tr.NONFINITE, f"{method}: the state overflowed by t = {sol.t[-1]:.9g}"
            break
        if sol.status == 1 and sol.t_events[0].size:
            te = float(sol.t_events[0][0])
            ye = sol.y_events[0][0].copy()
            lam, g = model.reset_lambda(ye[:n], ye[n:])
            if lam == 0.0 or not np.isfinite(lam):
                status, message = tr.RESET_FAILED, f"grazing contact at t = {te:.9g} (zero normal velocity)"
                break
            imp_t.append(te)
            imp_q.append(ye[:n].copy())
            imp_pm.append(ye[n:].copy())
            ye[n:] = ye[n:] + lam * g
            imp_pp.append(ye[n:].copy())
            if len(imp_t) > max_impacts:
                status, message = tr.ACCUMULATION, f"more than {max_impacts} impacts by t = {te:.9g}"
                break
            t, y = te, ye
            # grid points at or before the impact are done; the next segment fills t_k > te
            while k <= N and tgrid[k] <= te:
                k += 1
            if k > N or te >= T_end:
                break
            # step off the surface before restarting with the event (reference.step_off_surface)
            if escape:
                nxt = float(tgrid[k]) if k <= N else T_end
                off = step_off_surface(rhs, lambda yy: model.phi(t, yy), t, y, min(escape_step, 0.5 * (nxt - t)))
                if off is not None:
                    t, y = off
        else:
            break
    wall = time.perf_counter() - t_start
    K = k if status == tr.OK else max(k, 1)
    if status == tr.OK and k != N + 1:
        status, message = SOLVER_FAILED, f"{method} filled {k} of {N + 1} grid points"
        K = max(k, 1)
    Q, P = Y[:K, :n], Y[:K, n:]
    if energies:
        with np.errstate(all="ignore"):
            H = np.array([model.hamiltonian(Q[i], P[i]) for i in range(K)])
    else:
        H = np.full(K, np.nan)
    imps = np.asarray(imp_t, float)
    imp_step = np.zeros(max(K - 1, 0), dtype=bool)
    if imps.size and K > 1:
        idx = np.clip(np.floor((imps - t0) / h).astype(int), 0, K - 2)
        imp_step[idx] = True
    fail = -1 if status == tr.OK else max(K - 1, 0)
    return tr.Trajectory(
        method=f"{method}@rtol={rtol:g}", system=sysm.name, h=h, T=N * h, t=tgrid[:K], q=Q, p=P, H=H,
        Ed=np.full(K, np.nan), Hmod=None, impacts=imps,
        impact_q=np.asarray(imp_q, float).reshape(-1, n), impact_p_minus=np.asarray(imp_pm, float).reshape(-1, n),
        impact_p_plus=np.asarray(imp_pp, float).reshape(-1, n), impact_step=imp_step,
        partial_steps=np.zeros(0), newton_iters=np.zeros(max(K - 1, 0), dtype=np.int64), status=status,
        message=message, fail_step=fail, fail_time=(t0 + fail * h) if fail >= 0 else float("nan"), beta=beta,
        wall_time=wall, tolerances={"rtol": rtol, "atol": float(atol)},
        options={"params": dict(zip(sysm.params, np.asarray(prm).tolist())), "solver": method, "kernels": kernels,
                 "nfev": nfev, "impacts": int(imps.size)})


def hamiltonian_on_grid(system, q, p, params=None, kernels: str = "compiled") -> np.ndarray:
    """H(q_k, p_k) for the rows of q, p (what `energies=True` computes, callable outside a timed run)."""
    from ..run.resolve import resolve_system

    sysm = resolve_system(system)
    prm = sysm.param_values(params)
    model = _model(sysm, prm, kernels)
    q, p = np.ascontiguousarray(q, float), np.ascontiguousarray(p, float)
    with np.errstate(all="ignore"):
        return np.array([model.hamiltonian(q[i], p[i]) for i in range(q.shape[0])])
