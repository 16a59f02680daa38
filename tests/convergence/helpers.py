"""Numerical helpers for the convergence and structure tests (issue 3 acceptance).

fit_order     : the ONE observed-order estimator used by every order test
exact_smooth  : DOP853 (rtol 1e-13) on Hamilton's equations from the compiled hamilton_rhs
run_map       : N steps of a compiled one-step map Phi_h (mod.ld_step) from Python
map_jacobian  : d Phi_h / d(q, p) by a 4th-order central difference stencil
drift_slope   : least-squares slope (with 95% CI) of windowed max |H - H0| against time
"""
from __future__ import annotations

import numpy as np
from scipy import stats
from scipy.integrate import solve_ivp

EPS = np.finfo(float).eps


def fit_order(hs, errs, scale=1.0, plateau=1e3, min_local_slope=0.5):
    """Observed order: least-squares slope of log(err) against log(h), round-off plateau masked.

    Going from coarse to fine h, the plateau starts at the first point whose error is below
    `plateau` * eps * `scale` (round-off level relative to the solution's magnitude `scale`), or
    where the error stops decreasing (local slope against the previous point below
    `min_local_slope`); that point and every finer one are dropped. Returns (slope, mask), mask
    marking the points used (in the order given). Raises AssertionError if fewer than 3 remain.
    """
    hs = np.asarray(hs, float)
    errs = np.asarray(errs, float)
    order = np.argsort(hs)[::-1]  # coarse to fine
    keep = np.zeros(hs.size, bool)
    prev = None
    for i in order:
        e = errs[i]
        if not np.isfinite(e) or e <= plateau * EPS * scale:
            break
        if prev is not None and np.log(errs[prev] / e) < min_local_slope * np.log(hs[prev] / hs[i]):
            break  # stalled: round-off (or Newton tolerance) dominated from here on
        keep[i] = True
        prev = i
    if keep.sum() < 3:
        raise AssertionError(f"fit_order: fewer than 3 usable points (h={hs.tolist()}, err={errs.tolist()})")
    slope = np.polyfit(np.log(hs[keep]), np.log(errs[keep]), 1)[0]
    return float(slope), keep


def exact_smooth(mod, prm, q0, p0, t_eval, rtol=1e-13):
    """The smooth (constraint ignored) solution of Hamilton's equations at times t_eval:
    DOP853 at rtol (atol = rtol * max(1, |y0|)) on mod.hamilton_rhs. Returns (q, p), each (len(t), n)."""
    n = len(q0)
    buf = np.empty(2 * n)

    def rhs(t, y):
        mod.hamilton_rhs(y, prm, buf)
        return buf.copy()

    y0 = np.concatenate([q0, p0]).astype(float)
    atol = rtol * max(1.0, float(np.max(np.abs(y0))))
    sol = solve_ivp(rhs, (float(t_eval[0]), float(t_eval[-1])), y0, method="DOP853", rtol=rtol, atol=atol,
                    t_eval=t_eval)
    assert sol.status == 0, sol.message
    return sol.y[:n].T, sol.y[n:].T


def step(mod, q, p, h, t=0.0, prm=None, newton_tol=1e-12, max_iter=50):
    """One application of the module's one-step map Phi_h: (q, p) -> (q1, p1). Asserts convergence."""
    n = len(q)
    q1, p1, vl = np.empty(n), np.empty(n), np.empty(n)
    it, _ = mod.ld_step(np.asarray(q, float), np.asarray(p, float), float(h), float(t), prm, newton_tol,
                        max_iter, q1, p1, vl)
    assert it >= 0, f"Newton failed in ld_step (h={h}, q={q}, p={p})"
    return q1, p1


def run_map(mod, prm, q0, p0, h, N, t0=0.0):
    """N steps of Phi_h from (q0, p0): returns Q (N+1, n), P (N+1, n)."""
    n = len(q0)
    Q = np.empty((N + 1, n))
    P = np.empty((N + 1, n))
    Q[0], P[0] = q0, p0
    q, p = np.array(q0, float), np.array(p0, float)
    for k in range(N):
        q, p = step(mod, q, p, h, t0 + k * h, prm)
        Q[k + 1], P[k + 1] = q, p
    return Q, P


def map_jacobian(f, y, d=1e-3):
    """Jacobian of f: R^m -> R^m at y by the 4th-order central stencil (error O(d^4) + O(eps/d))."""
    y = np.asarray(y, float)
    m = y.size
    J = np.empty((m, m))
    for j in range(m):
        e = np.zeros(m)
        e[j] = d * max(1.0, abs(y[j]))
        J[:, j] = (-f(y + 2 * e) + 8 * f(y + e) - 8 * f(y - e) + f(y - 2 * e)) / (12 * e[j])
    return J


def omega(n):
    """The canonical symplectic matrix on (q, p) in R^2n."""
    return np.block([[np.zeros((n, n)), np.eye(n)], [-np.eye(n), np.zeros((n, n))]])


def symplecticity_defect(J):
    """max |J^T Omega J - Omega| (entrywise)."""
    n = J.shape[0] // 2
    W = omega(n)
    return float(np.max(np.abs(J.T @ W @ J - W)))


def drift_slope(t, dH, n_windows=100):
    """Split the run into n_windows equal windows, take max |H - H0| in each, and fit a line against
    the window centre time. Returns (slope, (ci_lo, ci_hi) 95%, window maxima)."""
    t = np.asarray(t, float)
    dH = np.abs(np.asarray(dH, float))
    idx = np.array_split(np.arange(t.size), n_windows)
    tc = np.array([t[i].mean() for i in idx])
    wmax = np.array([dH[i].max() for i in idx])
    res = stats.linregress(tc, wmax)
    tq = stats.t.ppf(0.975, n_windows - 2)
    return float(res.slope), (res.slope - tq * res.stderr, res.slope + tq * res.stderr), wmax
