# numba source unit: CollisionTime[Phi^partial, q, p] (Algorithm 1, line 8), over every constraint
# at once: the first root of the gap g = min_i phi_i (its slope: that of the smallest phi_i).
# Contract: vcirun.codegen.units.
#
# Several constraints: a contact that is touching at the start of a search (phi_i within
# round-off or the event tolerance of 0) and not approaching (normal velocity >= 0, or approaching by
# less than the round-off of phi_i within a step) is left out of the gap for that search -- it would
# pin g at 0 (two balls at rest against each other, or moving together) -- unless the trial end
# point shows the motion driving it into its constraint (unmask_penetrating). The impact law (collision/impact.py) still takes every
# contact at phi = 0 into the impact. One constraint: no mask, the paper's search bit for bit.
import math
from collections import namedtuple

import numpy as np
from numba import njit

from vcirun.codegen.frame import scratch, scratch_i
from vcirun.codegen.roles import NCON, sys_phi, sys_phis, partial
from vcirun.collision.impact import gap, gap_slope, touching_mask, unmask_penetrating
from vcirun.maps.held import held_step

N_SCAN = 4  # interior samples of the initial bracket (first-root search), when the cubic model is unsure
N_MODEL = 32  # samples of the cubic Hermite model of g on the bracket (no partial steps: free)

# One search's record, which every stage of it takes (a numba namedtuple, like the loop's LoopState):
# the state (qh, ph) at the search's start time t, the partial steps' output (qt, pt, vt: each stage
# leaves the state at its last evaluated tau there), the held contacts (held, nheld) and the friction
# work fw[0] of the last held partial step, the contacts left out of the gap (mask), the parameters
# and the settings: the grid step h, Newton's tolerance and cap, the event tolerance (the root's
# tolerance is event_tol h).
Search = namedtuple("Search", ("qh", "ph", "qt", "pt", "vt", "held", "fw", "mask", "prm",
                               "h", "t", "ntol", "maxit", "event_tol", "nheld"))


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _hermite(s, ga, da, gb, db, H):
    s2 = s * s
    s3 = s2 * s
    return ((2.0 * s3 - 3.0 * s2 + 1.0) * ga + (s3 - 2.0 * s2 + s) * H * da
            + (3.0 * s2 - 2.0 * s3) * gb + (s3 - s2) * H * db)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _model_first_root(a, ga, da, b, gb, db):
    """First root in (a, b) of the cubic Hermite model of g (values and slopes at both ends), or -1
    if the model shows more than one sign change (an earlier root may hide: scan instead) or is not
    finite. With ga > 0 > gb the model has at least one root."""
    H = b - a
    if not (math.isfinite(da) and math.isfinite(db) and H > 0.0):
        return -1.0
    changes = 0
    lo = 0.0
    hi = 1.0
    prev = ga
    for j in range(1, N_MODEL + 1):
        sj = j / N_MODEL
        v = _hermite(sj, ga, da, gb, db, H) if j < N_MODEL else gb
        if (prev > 0.0) != (v > 0.0):
            changes += 1
            if changes == 1:
                lo = (j - 1) / N_MODEL
                hi = sj
        prev = v
    if changes != 1:
        return -1.0
    # bisection on the model (no partial steps), to far below the tolerance of the real search
    glo = _hermite(lo, ga, da, gb, db, H)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        gm = _hermite(mid, ga, da, gb, db, H)
        if (gm > 0.0) == (glo > 0.0):
            lo = mid
            glo = gm
        else:
            hi = mid
        if hi - lo < 1e-15:
            break
    return a + 0.5 * (lo + hi) * H


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def step_admissible(q, p, qt, h, event_tol, prm, held, nheld, phis):
    """Algorithm 1's precondition (31) for the full step q -> qt: phi(qt) > 0 (one constraint, none
    held), or every contact neither held nor touching at q positive at qt and the touching ones not
    penetrating. phis: scratch of length NCON."""
    if NCON == 1 and nheld == 0:
        return sys_phi(qt, prm) > 0.0
    # every phi_i(qt) > 0: admissible whatever is touching or held (the gap over any mask is > 0 and
    # nothing penetrates): the common smooth step pays one evaluation of the constraints, not the
    # touching test's mass-matrix solve (what an inactive constraint costs)
    sys_phis(qt, prm, phis)
    ok = True
    for i in range(NCON):
        if not phis[i] > 0.0:
            ok = False
            break
    if ok:
        return True
    mask = np.empty(NCON, dtype=np.int64)
    touching_mask(q, p, h, event_tol, prm, mask, held)
    return gap(qt, prm, mask) > 0.0 and unmask_penetrating(q, qt, prm, mask, held) == 0


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def partial_map(q0, p0, tau, h, t, prm, ntol, maxit, q1, p1, v1, held, nheld, fw):
    """Phi^partial_tau, or with contacts held the constrained map of the full step's discrete
    Lagrangian (maps/held.py held_step: every method, with friction the contacts' slip and stick
    modes; fw[0] receives its friction work, the caller's to count when it takes the step)."""
    if nheld > 0:
        imp = scratch(NCON)
        impt = scratch(NCON)
        return held_step(q0, p0, tau, t, prm, ntol, maxit, held, q1, p1, v1, imp, impt, fw)
    return partial(q0, p0, tau, h, t, prm, ntol, maxit, q1, p1, v1)


@njit(cache=True, nogil=True, error_model="numpy")
def collision_time(qh, ph, tau_max, h, t, prm, ntol, maxit, event_tol, qt, pt, vt, held):
    """First root tau in (0, tau_max] of the gap g(tau) = min_i phi_i(q(tau)), q(tau) from
    Phi^partial_tau(qh, ph).

    Returns (code, tau, E_pre, newton_iters): code 1 = collision at tau, 0 = no collision in
    (0, tau_max] (tau = tau_max), -1 = a partial step failed, -2 = the root search failed. On return
    (qt, pt, vt) hold the partial-step state at tau and E_pre its discrete energy (for R^VCI).
    The root is located to |Delta tau| <= event_tol * h; a start on the surface (g(0) <= 0, e.g.
    right after an impact) is not a root: the search first steps forward to a point with g > 0.
    See _search for the method."""
    nheld = 0
    for i in range(NCON):
        nheld += 1 if held[i] != 0 else 0
    fw = scratch(1)
    mask = scratch_i(NCON)
    s = Search(qh, ph, qt, pt, vt, held, fw, mask, prm, h, t, ntol, maxit, event_tol, nheld)
    return _search(s, tau_max, np.bool_(False))


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def search_collision(st, tau_max, t, have_end, nheld):
    """collision_time from the event loop's state st (collision/state.py LoopState: the search starts
    at (st.qh, st.ph) at time t, with st.held's nheld contacts held); have_end: (st.qt, st.pt) already
    hold Phi^partial_{tau_max}(qh, ph) (Algorithm 1's full step, when the partial map is the full
    one), so it is not recomputed."""
    mask = scratch_i(NCON)
    s = Search(st.qh, st.ph, st.qt, st.pt, st.vt, st.held, st.fw, mask, st.prm, st.h, t, st.ntol, st.maxit,
               st.event_tol, nheld)
    return _search(s, tau_max, have_end)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _partial(s, tau):
    """The search's partial step to tau: (qt, pt, vt) = Phi^partial_tau(qh, ph); (iterations, E)."""
    return partial_map(s.qh, s.ph, tau, s.h, s.t, s.prm, s.ntol, s.maxit, s.qt, s.pt, s.vt, s.held, s.nheld, s.fw)


# _search and its stages inline: search_collision is a frame for the mask around them, and a call
# would have numba optimize and emit the partial steps below it once more in each caller
@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _search(s, tau_max, have_end):
    """The search of collision_time over the record s. The held contacts stay out of the gap, and
    partial steps are then the constrained map.

    Method. g(0) > 0 > g(tau_max) brackets a root; CollisionTime is a set and the FIRST root is
    wanted. The cubic Hermite model of g from the values and the flow's slopes at both ends
    locates it when the model has a single sign change (a resolved motion); otherwise interior
    samples of the partial map pick the first sign change (`_scan_bracket`). From the model's root
    the iteration is secant on the partial map's own g (`_refine_root`). Typically 2-3 partial steps
    per impact, against 10-12 for bracketing alone.
    """
    masked = touching_mask(s.qh, s.ph, s.h, s.event_tol, s.prm, s.mask, s.held)
    iters = 0
    E = np.nan
    if not have_end:
        it, E = _partial(s, tau_max)
        if it < 0:
            return -1, tau_max, E, -it
        iters += it
    if NCON > 1:
        unmask_penetrating(s.qh, s.qt, s.prm, s.mask, s.held)
    gb = gap(s.qt, s.prm, s.mask)
    if not math.isfinite(gb) and not (gb > 0.0 and masked > 0):  # (+inf: every contact masked or held)
        return -1, tau_max, E, iters
    if gb >= 0.0:
        if have_end:  # the caller's full step knows E; recompute only when asked for the state's energy
            it, E = _partial(s, tau_max)
            iters += abs(it)
        return 0, tau_max, E, iters
    db = gap_slope(s.qt, s.pt, s.prm, s.mask)
    b = tau_max
    a = 0.0
    ga = gap(s.qh, s.prm, s.mask)
    da = gap_slope(s.qh, s.ph, s.prm, s.mask)
    if ga <= 0.0:
        code, a, ga, da, b, gb, db, E, itc = _leave_surface(s, tau_max, b, gb, db)
        iters += itc
        if code != 0:
            return code, (a if code == 1 else b), E, iters
    c = _model_first_root(a, ga, da, b, gb, db)
    if c < 0.0:
        code, c, a, ga, b, gb, E, itc = _scan_bracket(s, a, ga, b, gb)
        iters += itc
        if code != 0:
            return code, c, E, iters
    code, tau, E, itc = _refine_root(s, c, a, ga, b, gb)
    return code, tau, E, iters + itc


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _leave_surface(s, tau_max, b, gb, db):
    """On (or numerically just past) the surface at tau = 0: the trivial root at 0 is not a
    collision. Halve towards 0 until g > 0; the first collision lies before any point with g < 0.
    Returns (code, a, ga, da, b, gb, db, E, iters): code 0 with the bracket [a, b]; 1 = moving into the
    constraint from the surface, the impact at tau = 0 (returned as a, with its state); -1 = a partial
    step failed (at b)."""
    x = tau_max
    iters = 0
    E = np.nan
    while x > 1e-3 * (s.event_tol * s.h):
        x *= 0.5
        it, E = _partial(s, x)
        if it < 0:
            return -1, 0.0, 0.0, 0.0, x, gb, db, E, iters - it
        iters += it
        gs = gap(s.qt, s.prm, s.mask)
        if gs > 0.0:
            return 0, x, gs, gap_slope(s.qt, s.pt, s.prm, s.mask), b, gb, db, E, iters
        b = x
        gb = gs
        db = gap_slope(s.qt, s.pt, s.prm, s.mask)
    it, E = _partial(s, 0.0)
    return 1, 0.0, 0.0, 0.0, b, gb, db, E, iters + abs(it)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _scan_bracket(s, a, ga, b, gb):
    """The cubic model is unsure (several sign changes, or no slopes): sample the bracket for the first
    sign change, as a plain bracket would skip an earlier root. Returns (code, c, a, ga, b, gb, E,
    iters): code 0 with the false-position point c of the narrowed bracket; 1 = a sample landed on
    g = 0 (the root c, with its state); -1 = a partial step failed."""
    a0 = a
    span = b - a
    iters = 0
    E = np.nan
    for j in range(1, N_SCAN):
        c = a0 + span * j / N_SCAN
        it, E = _partial(s, c)
        if it < 0:
            return -1, c, a, ga, b, gb, E, iters - it
        iters += it
        gc = gap(s.qt, s.prm, s.mask)
        if gc < 0.0:
            b = c
            gb = gc
            break
        if gc > 0.0:
            a = c
            ga = gc
        else:
            return 1, c, a, ga, b, gb, E, iters
    return 0, (a * gb - b * ga) / (gb - ga), a, ga, b, gb, E, iters


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _refine_root(s, c, a, ga, b, gb):
    """From c in the bracket [a, b] (g(a) > 0 > g(b)): secant on the partial map's own g (Newton with
    the flow's slope for the first correction), safeguarded by the bracket: a step that leaves it, or
    a bracket that stops shrinking, falls back to Illinois / bisection. Stops when the correction is
    below a tenth of tol = event_tol * h, at an evaluated point (so the returned state is that of
    the returned tau). Returns (code, tau, E, iters) as collision_time."""
    tol = s.event_tol * s.h
    if not (c > a and c < b):
        c = 0.5 * (a + b)
    xp = np.nan  # previous evaluated point (secant)
    gp = np.nan
    side = 0
    width = b - a
    iters = 0
    E = np.nan
    for k in range(200):
        it, E = _partial(s, c)
        if it < 0:
            return -1, c, E, iters - it
        iters += it
        gc = gap(s.qt, s.prm, s.mask)
        if not math.isfinite(gc):
            return -1, c, E, iters
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
            return 1, c, E, iters
        if math.isfinite(xp) and gc != gp:
            step = gc * (c - xp) / (gc - gp)        # secant on the partial map's g
        else:
            step = gc / gap_slope(s.qt, s.pt, s.prm, s.mask)  # first correction: Newton with the flow's slope
        if math.isfinite(step) and abs(step) <= 0.1 * tol:
            # converged at an evaluated point (a tenth of the tolerance: the superlinear steps rarely
            # land between, and it keeps |phi| at the reported state near round-off)
            return 1, c, E, iters
        xn = c - step
        if k % 3 == 2:
            if b - a > 0.5 * width:                 # not shrinking: bisect
                xn = 0.5 * (a + b)
            width = b - a
        if not (math.isfinite(xn) and xn > a and xn < b):
            xn = (a * gb - b * ga) / (gb - ga)      # Illinois (false position) inside the bracket
            if not (xn > a and xn < b):
                xn = 0.5 * (a + b)
        if b - a <= tol:
            # bracket collapsed: report the end closer to the surface, with its state
            tau = a if abs(ga) < abs(gb) else b
            if tau != c:
                it, E = _partial(s, tau)
                iters += abs(it)
            return 1, tau, E, iters
        xp = c
        gp = gc
        c = xn
    return -2, c, E, iters
