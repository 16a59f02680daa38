"""Python drivers of a compiled module's maps, and the smooth exact solution (shared with the tests).

exact_smooth : DOP853 (rtol 1e-13) on Hamilton's equations from the compiled hamilton_rhs (constraint
               ignored), plus a generalized force f(q, qdot, t) when one is given
step         : one application of the module's one-step map Phi_h (mod.ld_step)
run_map      : N steps of Phi_h from Python
"""
from __future__ import annotations

import numpy as np

from ..core.tolerances import DEFAULT_TOLERANCES


def exact_smooth(mod, prm, q0, p0, t_eval, rtol=1e-13, force=None):
    """The smooth (constraint ignored) solution of Hamilton's equations at times t_eval:
    DOP853 at rtol (atol = rtol * max(1, |y0|)) on mod.hamilton_rhs; `force(q, qdot, t)` (length n),
    if given, is added to pdot (qdot = M^-1 p). Returns (q, p), each (len(t), n)."""
    from scipy.integrate import solve_ivp  # here: importing the package stays light

    n = len(q0)
    buf = np.empty(2 * n)

    def rhs(t, y):
        mod.hamilton_rhs(y, prm, buf)
        out = buf.copy()
        if force is not None:
            out[n:] += force(y[:n], out[:n], t)
        return out

    y0 = np.concatenate([q0, p0]).astype(float)
    atol = rtol * max(1.0, float(np.max(np.abs(y0))))
    sol = solve_ivp(rhs, (float(t_eval[0]), float(t_eval[-1])), y0, method="DOP853", rtol=rtol, atol=atol,
                    t_eval=t_eval)
    if sol.status != 0:
        raise RuntimeError(f"smooth reference: DOP853 failed at t = {sol.t[-1]:.6g}: {sol.message}")
    return sol.y[:n].T, sol.y[n:].T


class StepFailed(AssertionError):
    """ld_step's Newton solve did not converge (an AssertionError: the tests assert with it)."""


def step(mod, q, p, h, t=0.0, prm=None, newton_tol=DEFAULT_TOLERANCES["newton_tol"],
         max_iter=DEFAULT_TOLERANCES["max_iter"]):
    """One application of the module's one-step map Phi_h: (q, p) -> (q1, p1). Raises StepFailed if
    Newton does not converge."""
    n = len(q)
    q1, p1, vl = np.empty(n), np.empty(n), np.empty(n)
    it, _ = mod.ld_step(np.asarray(q, float), np.asarray(p, float), float(h), float(t), prm, newton_tol,
                        max_iter, q1, p1, vl)
    if it < 0:
        raise StepFailed(f"Newton failed in ld_step (h={h}, q={q}, p={p})")
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


def smooth_until_failure(mod, prm, q0, p0, T, rtol=1e-13, force=None):
    """The smooth solution as far as DOP853 gets on [0, T] (every internal step): (t, q, message), with
    message '' if it reached T. Where `exact_smooth` fails, this shows where and in what state."""
    from scipy.integrate import solve_ivp

    n = len(q0)
    buf = np.empty(2 * n)

    def rhs(t, y):
        mod.hamilton_rhs(y, prm, buf)
        out = buf.copy()
        if force is not None:
            out[n:] += force(y[:n], out[:n], t)
        return out

    y0 = np.concatenate([q0, p0]).astype(float)
    atol = rtol * max(1.0, float(np.max(np.abs(y0))))
    sol = solve_ivp(rhs, (0.0, float(T)), y0, method="DOP853", rtol=rtol, atol=atol)
    return sol.t, sol.y[:n].T, ("" if sol.status == 0 else sol.message)
