"""The continuous nonsmooth solution to high accuracy, for error measurement.

Exact reference: Hamilton's equations integrated by DOP853 (scipy) with event location on
phi(q) = 0 (direction: entering the constraint) and the exact elastic reset p+ = p- + lam grad phi,
lam = -2 g^T M^-1 p- / g^T M^-1 g (H conserved), restarted after each impact; dense output on any
grid. Its accuracy is self-reported as the largest difference (trajectory and impact times) from
a second solve at a 10x tighter tolerance (at least scipy's floor of ~2.2e-14).

Also: a fine-step method reference (the paper's choice: CVA at a small h) and the closed-form
oscillator against a wall.
"""
from __future__ import annotations

import numpy as np

from .codegen.build import load_module
from .methods import METHODS


class Reference:
    """Callable reference solution: ref(t) -> q (len(t), n); ref.p(t); ref.impacts; ref.accuracy."""

    def __init__(self, segments, n, impacts, H0, T, accuracy=np.nan, kind="exact"):
        self.segments = segments  # list of (t_start, t_end, dense OdeSolution)
        self.n = n
        self.impacts = np.asarray(impacts, float)
        self.H0 = H0
        self.T = T
        self.accuracy = accuracy
        self.kind = kind

    def state(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, float))
        out = np.empty((t.size, 2 * self.n))
        starts = np.array([s[0] for s in self.segments])
        idx = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(self.segments) - 1)
        for j in np.unique(idx):
            m = idx == j
            out[m] = self.segments[j][2](t[m]).T
        return out

    def __call__(self, t) -> np.ndarray:
        return self.state(t)[:, : self.n]

    def p(self, t) -> np.ndarray:
        return self.state(t)[:, self.n:]


def _first_root(g, a, b, samples=64):
    """First sign change of g on [a, b] (g(a) >= 0 > g(b)): dense samples bracket it, brentq refines."""
    from scipy.optimize import brentq

    ts = np.linspace(a, b, samples + 1)
    prev = ts[0]
    for s in ts[1:]:
        if g(s) < 0.0:
            return float(brentq(g, prev, s, xtol=1e-15, rtol=4 * np.finfo(float).eps))
        prev = s
    return float(b)


def rk4_step(f, t, y, dt):
    """One classical RK4 step (the escape micro step off the surface after a reset; also used by the
    solve_ivp baseline)."""
    k1 = f(t, y)
    k2 = f(t + dt / 2, y + dt / 2 * k1)
    k3 = f(t + dt / 2, y + dt / 2 * k2)
    k4 = f(t + dt, y + dt * k3)
    return y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


class _HermiteSegment:
    """Dense output of the escape micro step: cubic Hermite on [t0, t1], called like an OdeSolution."""

    def __init__(self, t0, y0, f0, t1, y1, f1):
        self.t0, self.d = t0, t1 - t0
        self.c = (np.array(y0, float), np.array(f0, float) * self.d, np.array(y1, float),
                  np.array(f1, float) * self.d)

    def __call__(self, t):
        s = (np.atleast_1d(np.asarray(t, float)) - self.t0) / self.d
        y0, m0, y1, m1 = self.c
        h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
        h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
        return np.outer(y0, h00) + np.outer(m0, h10) + np.outer(y1, h01) + np.outer(m1, h11)


def _exact(system, q0, p0, prm, T, rtol, max_impacts=10_000):
    from scipy.integrate import solve_ivp  # here, not at module level: `import vcirun` stays light

    mod = load_module(system, METHODS["CVA"].kernel_set())  # system kernels + Hamilton's equations
    n = system.n
    buf = np.empty(2 * n)

    def rhs(t, y):
        mod.hamilton_rhs(y, prm, buf)
        return buf.copy()

    def event(t, y):
        return mod.sys_phi(y[:n], prm)

    event.terminal = True
    event.direction = -1.0

    def dip(t, y):  # d phi / dt: crosses 0 upwards at every local minimum of phi along the flow
        return mod.gdot(y[:n], y[n:], prm)

    dip.terminal = False  # recorded, checked after the solve (a terminal event at a minimum would
    dip.direction = 1.0   # restart where d phi/dt = 0 and fire again at once)
    y = np.concatenate([q0, p0])
    t = 0.0
    segments, impacts = [], []
    atol = rtol * max(1.0, float(np.max(np.abs(y))))
    while t < T:
        sol = solve_ivp(rhs, (t, T), y, method="DOP853", rtol=rtol, atol=atol, events=(event, dip),
                        dense_output=True)
        if sol.status < 0:
            raise RuntimeError(f"reference: DOP853 failed at t={sol.t[-1]:.6g}: {sol.message}")
        te = None
        if sol.status == 1 and sol.t_events[0].size:
            te = float(sol.t_events[0][0])
            ye = sol.y_events[0][0].copy()
        # Minima of phi: solve_ivp sees a crossing only where phi changes sign between two of its
        # steps, so a dip below the surface shorter than one step (a near-grazing impact) goes
        # unnoticed; its minimum is then negative. The first such minimum before the detected
        # impact means an earlier, missed impact: its first root on the dense output replaces it.
        for tm, ym in zip(sol.t_events[1], sol.y_events[1]):
            if te is not None and tm >= te:
                break
            if mod.sys_phi(ym[:n], prm) < 0.0:
                te = _first_root(lambda s: mod.sys_phi(sol.sol(s)[:n], prm), t, float(tm))
                ye = sol.sol(te).copy()
                break
        segments.append((t, sol.t[-1] if te is None else te, sol.sol))
        if te is not None:
            g = np.empty(n)
            lam = mod.cva_lambda(ye[:n], ye[n:], prm, g)
            if lam == 0.0:
                raise RuntimeError(f"reference: grazing contact at t={te:.6g} (zero normal velocity)")
            ye[n:] = ye[n:] + lam * g
            impacts.append(te)
            if len(impacts) > max_impacts:
                raise RuntimeError(f"reference: more than {max_impacts} impacts (accumulation?) by t={te:.6g}")
            t, y = te, ye
            # Step off the surface before restarting: right after the reset phi is ~0 (often -1e-17)
            # and solve_ivp only sees a crossing from a start value >= 0, so a hop shorter than its
            # first step would go unnoticed. One RK4 micro step (<= 1e-9, local error ~1e-45) to
            # phi > 0, covered by a cubic Hermite segment (error ~delta^4 times the 4th derivative).
            delta = min(1e-9, 0.5 * (T - t))
            for _ in range(40):
                if delta <= 0.0:
                    break
                y1 = rk4_step(rhs, t, y, delta)
                if mod.sys_phi(y1[:n], prm) > 0.0:
                    segments.append((t, t + delta, _HermiteSegment(t, y, rhs(t, y), t + delta, y1,
                                                                   rhs(t + delta, y1))))
                    t, y = t + delta, y1
                    break
                delta *= 0.5
        else:
            t = T
    return segments, impacts, float(mod.hamiltonian(q0, p0, prm))


def reference(system, *, T, beta=None, q0=None, p0=None, params=None, rtol=1e-13, method="exact", h=None,
              check_accuracy=True) -> Reference:
    """The nonsmooth solution on [0, T] from (q0, p0) or the scene's initial-condition map at beta.

    method='exact' (default): DOP853 + event location + exact elastic reset, at rtol; accuracy is
    estimated against a second solve at rtol / 10 (check_accuracy=False skips it).
    method='CVA' (or any method name) with h: a fine-step simulation, interpolated by cubic Hermite
    on (q, qdot = M^-1 p) between its grid points (exact at the grid points)."""
    from .api import resolve_system, simulate
    from .validation import check_reference_args

    check_reference_args(T=T, rtol=rtol, method=method, h=h, beta=beta, q0=q0, p0=p0, params=params)  # (issue 22)
    sysm = resolve_system(system)
    prm = sysm.param_values(params)
    q0, p0 = sysm.initial_state(beta=beta, q0=q0, p0=p0, params=prm)
    T = float(T)
    if method != "exact":
        if h is None:
            raise ValueError("reference.h: a fine step is required for a method reference")
        tr = simulate(sysm, method, h=h, T=T, q0=q0, p0=p0, params=params)
        if tr.status != "ok":
            raise RuntimeError(f"reference: {method} at h={h} failed: {tr.message}")
        return _grid_reference(sysm, tr, prm)
    segs, imps, H0 = _exact(sysm, q0, p0, prm, T, rtol)
    acc = np.nan
    if check_accuracy:
        # estimate the returned solve's error against a tighter one (scipy's floor is ~2.2e-14)
        segs2, imps2, _ = _exact(sysm, q0, p0, prm, T, max(rtol / 10, 2.3e-14))
        tt = np.linspace(0.0, T, 2001)
        a, b = Reference(segs, sysm.n, imps, H0, T), Reference(segs2, sysm.n, imps2, H0, T)
        acc = float(np.max(np.abs(a(tt) - b(tt))))
        if len(imps) == len(imps2) and imps:
            acc = max(acc, float(np.max(np.abs(np.subtract(imps, imps2)))))
    return Reference(segs, sysm.n, imps, H0, T, accuracy=acc, kind="exact")


class _Hermite:
    def __init__(self, t, y, dy):
        from scipy.interpolate import CubicHermiteSpline

        self.f = CubicHermiteSpline(t, y, dy, axis=0)

    def __call__(self, t):
        return self.f(t).T


def _grid_reference(system, tr, prm):
    mod = load_module(system, METHODS["CVA"].kernel_set())
    n = system.n
    buf = np.empty(2 * n)
    dq = np.empty_like(tr.q)
    dp = np.empty_like(tr.p)
    for k in range(len(tr.t)):
        mod.hamilton_rhs(np.concatenate([tr.q[k], tr.p[k]]), prm, buf)
        dq[k], dp[k] = buf[:n], buf[n:]
    # split at impact steps so that interpolation never straddles a velocity jump
    y = np.hstack([tr.q, tr.p])
    dy = np.hstack([dq, dp])
    cuts = [0] + [k + 1 for k in np.flatnonzero(tr.impact_step)] + [len(tr.t) - 1]
    cuts = sorted(set(cuts))
    segs = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        if b - a >= 1:
            segs.append((tr.t[a], tr.t[b], _Hermite(tr.t[a:b + 1], y[a:b + 1], dy[a:b + 1])))
    return Reference(segs, n, tr.impacts, float(tr.H[0]), tr.T, accuracy=np.nan, kind=f"{tr.method}@h={tr.h:g}")


def l2_error(traj, ref) -> float:
    """The L2 trajectory error used everywhere: sqrt(h * sum_k |q_k - q_ref(t_k)|^2) over the grid
    points k = 0..N of the run (a Riemann sum of the continuous L2 norm of q - q_ref on [0, T])."""
    d = traj.q - ref(traj.t)
    return float(np.sqrt(traj.h * np.sum(d * d)))


def oscillator_wall_exact(t, x0, v0, m=1.0, k=1.0, d=0.5):
    """Closed form of m x'' = -k x with an elastic wall at x = -d (phi = x + d >= 0).

    Phase form x = A cos(th), v = -A w sin(th), th' = w; at an impact (x = -d, v < 0, th = th_i with
    cos th_i = -d/A) the reflection v -> -v maps th_i to 2 pi - th_i. Returns (x, v, impact_times)."""
    t = np.asarray(t, float)
    w = np.sqrt(k / m)
    A = np.hypot(x0, v0 / w)
    if A <= d:
        th0 = np.arctan2(-v0 / w, x0)
        th = th0 + w * t
        return A * np.cos(th), -A * w * np.sin(th), np.array([])
    thi = np.arccos(-d / A)                        # impact phase in (pi/2, pi)
    th0 = np.mod(np.arctan2(-v0 / w, x0), 2 * np.pi)  # x0 = A cos th0, v0 = -A w sin th0
    # admissible phases: [2pi - thi, 2pi + thi) (mod 2pi); unfold into a phase that advances by 2 thi
    # per period and wraps back
    th0 = th0 if th0 < thi else th0 - 2 * np.pi   # now in [-(2pi - ... ), thi)
    if th0 < -thi:
        th0 = -thi
    period = 2 * thi / w
    s = (th0 + thi) / w + t                       # time since the last reflection point
    frac = np.mod(s, period)
    th = -thi + w * frac
    n_imp = int(np.floor(((th0 + thi) / w + float(np.max(t, initial=0.0))) / period))
    t_imp = np.array([(j + 1) * period - (th0 + thi) / w for j in range(n_imp)])
    t_imp = t_imp[t_imp > 0]
    return A * np.cos(th), -A * w * np.sin(th), t_imp
