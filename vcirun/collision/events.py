# numba source unit: CollisionTime[Phi^partial, q, p] (Algorithm 1, line 8).
# Requires: NDOF, partial, sys_phi.
import math

import numpy as np
from numba import njit

N_SCAN = 4  # interior samples of the initial bracket (first-root search)


@njit(cache=True, nogil=True, error_model="numpy")
def collision_time(qh, ph, tau_max, h, t, prm, ntol, maxit, event_tol, qt, pt, vt):
    """First root tau in (0, tau_max] of g(tau) = phi(q(tau)), q(tau) from Phi^partial_tau(qh, ph).

    Returns (code, tau, E_pre, newton_iters): code 1 = collision at tau, 0 = no collision in
    (0, tau_max] (tau = tau_max), -1 = a partial step failed, -2 = the root search failed. On return
    (qt, pt, vt) hold the partial-step state at tau and E_pre its discrete energy (for R^VCI).
    The root is located to |Delta tau| <= event_tol * h (interior samples pick the first sign
    change, then a bracketing Illinois iteration, which cannot leave the bracket); a start on the
    surface (g(0) <= 0, e.g. right after an impact) is not a root: the search first steps forward
    to a point with g > 0.
    """
    iters = 0
    it, E = partial(qh, ph, tau_max, h, t, prm, ntol, maxit, qt, pt, vt)
    if it < 0:
        return -1, tau_max, E, -it
    iters += it
    gb = sys_phi(qt, prm)
    if not math.isfinite(gb):
        return -1, tau_max, E, iters
    if gb >= 0.0:
        return 0, tau_max, E, iters
    b = tau_max
    a = 0.0
    ga = sys_phi(qh, prm)
    tol = event_tol * h
    if ga <= 0.0:
        # On (or numerically just past) the surface: the trivial root at 0 is not a collision.
        # Halve towards 0 until g > 0; the first collision lies before any point with g < 0.
        s = tau_max
        found = False
        while s > 1e-3 * tol:
            s *= 0.5
            it, E = partial(qh, ph, s, h, t, prm, ntol, maxit, qt, pt, vt)
            if it < 0:
                return -1, s, E, iters - it
            iters += it
            gs = sys_phi(qt, prm)
            if gs > 0.0:
                a = s
                ga = gs
                found = True
                break
            b = s
            gb = gs
        if not found:
            # moving into the constraint from the surface: the impact is at tau = 0
            it, E = partial(qh, ph, 0.0, h, t, prm, ntol, maxit, qt, pt, vt)
            return 1, 0.0, E, iters + abs(it)
    # CollisionTime is a set: look for the FIRST sign change. A few interior samples catch an
    # earlier root that a plain [a, b] bracket would skip (phi < 0 inside, > 0 again at b's left).
    a0 = a
    span = b - a
    for j in range(1, N_SCAN):
        c = a0 + span * j / N_SCAN
        it, E = partial(qh, ph, c, h, t, prm, ntol, maxit, qt, pt, vt)
        if it < 0:
            return -1, c, E, iters - it
        iters += it
        gc = sys_phi(qt, prm)
        if gc < 0.0:
            b = c
            gb = gc
            break
        if gc > 0.0:
            a = c
            ga = gc
        else:
            return 1, c, E, iters
    side = 0
    converged = False
    for _ in range(200):
        c = (a * gb - b * ga) / (gb - ga)
        if not (c > a and c < b):
            c = 0.5 * (a + b)
        it, E = partial(qh, ph, c, h, t, prm, ntol, maxit, qt, pt, vt)
        if it < 0:
            return -1, c, E, iters - it
        iters += it
        gc = sys_phi(qt, prm)
        if gc > 0.0:
            a = c
            ga = gc
            if side == 1:
                gb *= 0.5  # Illinois: halve the stale end's value to keep superlinear convergence
            side = 1
        elif gc < 0.0:
            b = c
            gb = gc
            if side == -1:
                ga *= 0.5
            side = -1
        else:
            a = c
            b = c
        if b - a <= tol:
            converged = True
            break
    if not converged:
        return -2, b, E, iters
    # report the bracket end closer to the surface; the state must be that end's
    tau = a if abs(ga) < abs(gb) else b
    if tau != c:
        it, E = partial(qh, ph, tau, h, t, prm, ntol, maxit, qt, pt, vt)
        iters += abs(it)
    return 1, tau, E, iters
