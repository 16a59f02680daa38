# numba source unit: Algorithm 1 (event-driven collision integration), compiled as a whole so the
# event loop itself runs native. It knows only `full`, `partial`, `reset` (and the scene's phi, H and
# the optional modified energy); which method it runs is decided by what the module binds to them
# (vcirun.codegen.units). Its inputs, outputs and status codes are the rows of vcirun.core.record:
# settings[S_*], out[O_*], info[I_*], ST_*.
import math

import numpy as np
from numba import njit

from vcirun.codegen.frame import borrow, scratch, scratch_i
from vcirun.codegen.roles import (
    NDOF, NCON, FORCED, PARTIAL_IS_FULL, O_Q, O_P, O_H, O_ED, O_HMOD, O_IMPACTS, O_IMPACT_Q, O_IMPACT_P_MINUS,
    O_IMPACT_P_PLUS, O_IMPACT_IMPULSE, O_IMPACT_CONTACT, O_IMPACT_STEP, O_PARTIAL_STEPS, O_NEWTON_ITERS,
    O_CONTACT_ACTIVE, O_CONTACT_FORCE, O_RELEASES, O_RELEASE_CONTACT, O_IMPACT_IMPULSE_T, O_CONTACT_MODE,
    O_FRICTION_WORK, O_MODE_CHANGES, O_MODE_CHANGE_CONTACT, O_MODE_CHANGE_KIND, I_STATUS, I_FAIL_STEP, I_N_IMPACTS,
    I_N_PARTIAL, I_STEPS, I_N_RELEASES, I_N_MODE_CHANGES, S_CONSTRAINED, S_NEWTON_TOL, S_MAX_ITER, S_EVENT_TOL,
    S_MAX_IMPACTS_STEP, S_ENERGIES, S_RESTING_CONTACT, ST_OK, ST_NEWTON_FAILED, ST_EVENT_FAILED, ST_RESET_FAILED,
    ST_ACCUMULATION, ST_NONFINITE, ST_PAINLEVE, RESET_MAP, RESET_LAW_FIRST, FRICTION, sys_phi, sys_phis,
    sys_restitution, sys_friction, full, reset, modified_energy
)
from vcirun.collision.declared import declared_reset
from vcirun.collision.events import search_collision, step_admissible
from vcirun.collision.state import LoopState, N_COUNTS, N_FRESH, N_HELD, N_STEP
from vcirun.collision.impact import impact_direction, normal_velocities, touch_tolerance
from vcirun.collision.impact_friction import friction_impact_direction
from vcirun.maps.dynamics import hamiltonian, force_power, velocity_guess
from vcirun.maps.friction import (friction_forces, friction_project, mode_event_values, assign_modes,
                                  slipping, HELD_STICK, REST_REVERSED, FRICTION_PAINLEVE)
from vcirun.maps.held import held_step, contact_forces, project_momentum, normal_acceleration
from vcirun.maps.linalg import copy_into, set_row
from vcirun.maps.steps import step_resolves_force


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _finite(x):
    for i in range(x.shape[0]):
        if not math.isfinite(x[i]):
            return False
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def integrate(q0, p0, t0, h, N, prm, settings, out, info):
    """Run N grid steps of Algorithm 1 from (q0, p0) at t0.

    settings: the loop's scalar inputs (vcirun.core.record.SETTINGS: constrained, newton_tol, max_iter,
    event_tol, max_impacts_step, energies, resting_contact). out: one preallocated buffer per
    vcirun.core.record.FIELDS row, in table order (vcirun.core.record.allocate). info receives the counters
    (vcirun.core.record.COUNTERS). energies = 0 skips H, the discrete energy Ed and the modified energy
    along the grid (set at t0 only): a run that only needs the trajectory saves their per-step cost.

    Each grid step is one of the loop's cases, each a function over the loop's state (st, a
    LoopState: collision/state.py): a free flight (_free_flight: the full map) or, with contacts
    held, a hold (_hold: the constrained map); the step is taken when it stays admissible, else it
    is an event step (_event_step: partial steps to each collision and the impact there, _impact,
    which is one of _declared_reset, _touching, _impact_in_hold, _method_reset, then _after_impact);
    a held contact whose force turns tensile inside the step is released there (_release).

    Held contacts (resting_contact = 1; docs/derivations/contacts.md): a contact is held when the run
    starts resting on it, when its impacts accumulate, or when an impact with restitution e < 1
    leaves it a normal velocity below |d^2 phi/dt^2| h; while held every step is the constrained map
    (maps/held.py); it is released where its contact force would turn tensile (located within the
    step by the linear interpolation of the force), and the step goes on free from there."""
    constrained = settings[S_CONSTRAINED] != 0.0
    energies = settings[S_ENERGIES] != 0.0
    resting = constrained and settings[S_RESTING_CONTACT] != 0.0
    # (vcirun.codegen.frame) the caller's arrays borrowed and the loop's own on this frame: nothing
    # the loop passes down is reference-counted (about half the loop time otherwise)
    out = borrow(out)
    prm = borrow(prm)
    info = borrow(info)
    Q = out[O_Q]
    P = out[O_P]
    H = out[O_H]
    Ed = out[O_ED]
    Hmod = out[O_HMOD]
    impact_step = out[O_IMPACT_STEP]
    newton_iters = out[O_NEWTON_ITERS]
    q = scratch(NDOF)
    p = scratch(NDOF)
    qt = scratch(NDOF)
    pt = scratch(NDOF)
    vt = scratch(NDOF)
    qh = scratch(NDOF)
    ph = scratch(NDOF)
    pp = scratch(NDOF)
    d = scratch(NDOF)
    qn = scratch(NDOF)
    pmap = scratch(NDOF)
    held = scratch_i(NCON)
    mu = scratch(NCON)
    mu_end = scratch(NCON)
    imp = scratch(NCON)
    phis = scratch(NCON)
    lam = scratch(NCON)
    active = scratch_i(NCON)
    impt = scratch(NCON)
    lamt = scratch(NCON)
    lt = scratch(NCON)
    lt_end = scratch(NCON)
    ev = scratch(NCON)
    ev_end = scratch(NCON)
    fw = scratch(1)
    n = scratch_i(N_COUNTS)
    dense = scratch(3)
    st = LoopState(q, p, qt, pt, vt, qh, ph, pp, d, qn, pmap, held, mu, mu_end, imp, phis, lam, active,
                   impt, lamt, lt, lt_end, ev, ev_end, fw, n, dense,
                   out, info, prm, h, settings[S_NEWTON_TOL], int(settings[S_MAX_ITER]), settings[S_EVENT_TOL],
                   int(settings[S_MAX_IMPACTS_STEP]), resting)
    copy_into(q, q0)
    copy_into(p, p0)
    for j in range(NCON):
        held[j] = 0
        mu[j] = 0.0
        mu_end[j] = 0.0
        lamt[j] = 0.0
    fw[0] = 0.0
    n[N_FRESH] = 0
    for j in range(NDOF):   # row 0 (set_row(Q, 0, q) would compile set_row once more, for a literal 0)
        Q[0, j] = q[j]
        P[0, j] = p[j]
    info[I_N_IMPACTS] = 0
    info[I_N_PARTIAL] = 0
    info[I_N_RELEASES] = 0
    info[I_N_MODE_CHANGES] = 0
    n[N_HELD] = initially_held(q, p, t0, h, st.event_tol, prm, held) if resting else 0
    status = ST_OK
    if FRICTION and n[N_HELD] > 0 and assign_modes(q, p, t0, prm, held, -1, -1, mu, lt, p) == FRICTION_PAINLEVE:
        status = ST_PAINLEVE
    # accumulation across steps: dense = [time of the last impact, start of the current
    # run of impacts that each follow the previous one by less than one grid step h, its length]
    # (see _accumulating)
    dense[0] = -math.inf
    dense[1] = 0.0
    dense[2] = 0.0
    fail = -1 if status == ST_OK else 0
    i = 0
    while i < N and status == ST_OK:
        t = t0 + i * h
        n[N_STEP] = i
        nheld = n[N_HELD]
        if nheld > 0:  # (the rows start false / 0)
            if not _record_contacts(st, np.int64(i), t):
                status = ST_PAINLEVE
                fail = i
                break
            if FRICTION and _modes_stale(st):
                if not _reassign_modes(st, np.int64(i), t):
                    status = ST_PAINLEVE
                    fail = i
                    break
                set_row(P, i, p)
        n[N_FRESH] = 0
        if nheld == 0:
            it, E = _free_flight(st, t, energies or i == 0)
        else:
            it, E = _hold(st, h, t)
        if energies or i == 0:
            H[i] = hamiltonian(q, p, prm)
            Hmod[i] = modified_energy(q, p, h, prm)
        Ed[i] = E
        if it < 0 or (FORCED and not step_resolves_force(q, p, h, t, prm)):
            status = ST_NEWTON_FAILED   # (a stiff force: the step's root is not the motion either)
            fail = i
            break
        iters = it
        frac = -1.0
        c = -1
        kind = 0
        if nheld > 0:
            if FRICTION:
                if mode_event_values(qt, pt, t + h, prm, held, st.ev_end, mu_end, st.lt_end) == FRICTION_PAINLEVE:
                    status = ST_PAINLEVE
                    fail = i
                    break
                frac, c, kind = _mode_event_fraction(st, False)
            else:
                contact_forces(qt, pt, t + h, prm, held, mu_end)
                frac, c = _release_fraction(mu, mu_end, held)
        tau = -1.0   # where in the step Algorithm 1's event step starts (< 0: none)
        if FRICTION and c >= 0 and constrained and not (_phis_positive(qt, prm, phis) or step_admissible(
                q, p, qt, h, st.event_tol, prm, held, nheld, phis)):
            # a free contact reaches its surface inside the step as well: the event step from the
            # step's start finds that collision first and locates the mode events before it (a mode's
            # end taken first would carry the motion past the collision, into the constraint)
            c = -1
        if c >= 0:
            impact_step[i] = True  # a step with an event inside (a release, a friction mode's end)
            if FRICTION:
                status, tau, itc = _mode_change(st, t, frac * h, c, kind)
            else:
                status, tau, itc = _release(st, t, frac * h, c)
            iters += itc
        elif (not constrained) or ((sys_phi(qt, prm) > 0.0) if (NCON == 1 and nheld == 0) else (
                _phis_positive(qt, prm, phis) or step_admissible(q, p, qt, h, st.event_tol, prm, held, nheld, phis))):
            # (step_admissible's common cases first: one constraint, or every phi_i > 0 after the step)
            if FRICTION and nheld > 0:
                out[O_FRICTION_WORK][i] += fw[0]
                n[N_FRESH] = 1   # (mu_end, lt_end, ev_end) are the values at the new grid state
            copy_into(q, qt)
            copy_into(p, pt)
        else:
            impact_step[i] = True
            tau = 0.0
        # the event step: the whole step (a collision in it), or its rest after a release or a mode's
        # end at t + tau. Its one call site is here: a call from _release or _mode_change would link
        # its code into theirs, and numba would optimize and emit it there once more.
        if status == ST_OK and tau >= 0.0:
            status, itc = _event_step(st, h - tau, t + tau, PARTIAL_IS_FULL and nheld == 0)
            iters += itc
        if status != ST_OK:
            fail = i
            break
        if not (_finite(q) and _finite(p)):
            status = ST_NONFINITE
            fail = i
            break
        newton_iters[i] = iters
        set_row(Q, i + 1, q)
        set_row(P, i + 1, p)
        i += 1
    if status == ST_OK and n[N_HELD] > 0:
        if not _record_contacts(st, N, t0 + N * h):
            status = ST_PAINLEVE
            fail = N
    if status == ST_OK and energies:
        # energies at the last grid state (its discrete energy from one more trial step)
        if n[N_HELD] == 0:
            it, E = _free_flight(st, t0 + N * h, np.bool_(True))
        else:
            it, E = _hold(st, h, t0 + N * h)
        H[N] = hamiltonian(q, p, prm)
        Ed[N] = E
        Hmod[N] = modified_energy(q, p, h, prm)
    info[I_STATUS] = status
    info[I_FAIL_STEP] = fail
    info[I_STEPS] = i
    return status


# --- the cases of a grid step --------------------------------------------------------------------------

@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _free_flight(st, t, want_E):
    """The full map from the grid state (st.q, st.p) at t into (st.qt, st.pt, st.vt); no contact held.
    Returns (Newton iterations, < 0 on failure; the step's discrete energy, NaN unless want_E)."""
    return full(st.q, st.p, st.h, t, st.prm, st.ntol, st.maxit, st.qt, st.pt, st.vt, want_E)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _hold(st, tau, t):
    """The constrained map over tau with the held contacts on their surfaces (maps/held.py held_step;
    with friction in their slip and stick modes, its friction work in st.fw[0]) from (st.q, st.p) at t
    into (st.qt, st.pt, st.vt). Returns (Newton iterations, < 0 on failure; discrete energy)."""
    return held_step(st.q, st.p, tau, t, st.prm, st.ntol, st.maxit, st.held, st.qt, st.pt, st.vt, st.imp, st.impt,
                     st.fw)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _release(st, t, tau, c):
    """A grid step from t in which held contact c is released after tau: the constrained map to
    t + tau and the release (recorded); integrate takes the rest of the step as an event step from
    there. Returns (status, tau, iterations)."""
    it = 0
    if tau > 0.0:
        it, _ = _hold(st, tau, t)
        if it < 0:
            return ST_NEWTON_FAILED, tau, -it
        copy_into(st.q, st.qt)
        copy_into(st.p, st.pt)
    st.held[c] = 0
    st.n[N_HELD] -= 1
    _record_release(st, t + tau, c)
    return ST_OK, tau, it


# --- friction: the end of a held contact's mode, located inside the step ------------------------------

@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _mode_event_fraction(st, strict):
    """(fraction of the step, contact, kind) of the first event of a held contact inside the held step
    just taken, by linear interpolation between its values at the step's start (st.mu, st.ev) and end
    (st.mu_end, st.ev_end): kind 0 a release (normal force turning tensile), 1 a slip that stops, 2 a
    stick that ends (maps/friction.py mode_event_values); (-1, -1, 0) if none. The start of the
    located search (_locate_mode_event). strict: only a value positive at the start counts (the rest
    of a step after an event, where a mode just set can start at its root: a slip from rest)."""
    best = 2.0
    c = -1
    kind = 0
    for j in range(NCON):
        if st.held[j] == 0:
            continue
        if st.mu_end[j] < 0.0 and not (strict and not st.mu[j] > 0.0):
            f = 0.0 if st.mu[j] <= 0.0 else st.mu[j] / (st.mu[j] - st.mu_end[j])
            if f < best:
                best = f
                c = j
                kind = 0
        if st.ev_end[j] < 0.0 and not (strict and not (st.ev[j] > 0.0 and math.isfinite(st.ev[j]))):
            f = 0.0 if not st.ev[j] > 0.0 else (st.ev[j] / (st.ev[j] - st.ev_end[j]) if math.isfinite(st.ev[j])
                                                 else 1.0)
            if f < best:
                best = f
                c = j
                kind = 1 if slipping(st.held[j]) else 2
    return (best if c >= 0 else -1.0), c, kind


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _mode_event_value(st, te, c, kind, ev, lam, lt):
    """The event function of held contact c at (st.qt, st.pt), time te: its normal force (kind 0) or its
    mode event value (ev, lam, lt: scratch). NaN in Painleve's case."""
    code = mode_event_values(st.qt, st.pt, te, st.prm, st.held, ev, lam, lt)
    if code == FRICTION_PAINLEVE:
        return np.nan
    return lam[c] if kind == 0 else ev[c]


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _locate_mode_event(st, t, L, tau0, c, kind):
    """The root tau in [0, L] of held contact c's event function along the held step from (st.q, st.p)
    at t (positive at tau = 0 unless the event is at the start, negative at L), from the
    interpolated tau0: secant iterations on the held map's own value, safeguarded by the bracket
    (Illinois, and bisection when the iteration stalls: the collision search's rule for a bracket
    that stops shrinking, events.py _refine_root), to event_tol h, ending at an evaluated point. On
    return (st.qt, st.pt) hold the state at tau and st.fw[0] its friction work. Returns (status,
    tau, iterations).

    The event function can jump: a stuck contact's forces change model where a nearly dependent
    stuck slip row crosses maps/friction.py's DEPENDENT_TOL (the 5-link chain lying almost flat on
    two stuck ends: mu_s lam - |lt| from +0.19 to -3e8 within one partial step). Illinois alone
    creeps along such a jump (the far end weighs 1e9 times the near one: some 30 halvings of it per
    crossing; 100 evaluations were not enough). The safeguard bisects there, the bracket closes on
    the jump, and the search ends on its near side once the secant correction across it is below
    tol / 10 (the jump then known to 2e-9 and 4e-13, after 70 and 159 evaluations, for the 5-link
    chain with CVA and VCI at h = 1e-3): the cap is the collision search's, 200."""
    h = st.h
    ga = st.mu[c] if kind == 0 else st.ev[c]
    gb = st.mu_end[c] if kind == 0 else st.ev_end[c]
    ev = scratch(NCON)
    lam = scratch(NCON)
    lt = scratch(NCON)
    if not (ga > 0.0 and math.isfinite(ga)):
        copy_into(st.qt, st.q)
        copy_into(st.pt, st.p)
        st.fw[0] = 0.0
        return ST_OK, 0.0, 0
    a = 0.0
    b = L
    tol = st.event_tol * h
    x = tau0 if (tau0 > a and tau0 < b) else 0.5 * (a + b)
    xp = np.nan
    gp = np.nan
    side = 0
    width = b - a
    iters = 0
    for k in range(200):
        it, _E = _hold(st, x, t)
        if it < 0:
            return ST_NEWTON_FAILED, x, iters - it
        iters += it
        g = _mode_event_value(st, t + x, c, kind, ev, lam, lt)
        if g != g:
            return ST_PAINLEVE, x, iters
        if g > 0.0:
            a = x
            ga = g
            if side == 1:
                gb *= 0.5
            side = 1
        elif g < 0.0:
            b = x
            gb = g
            if side == -1:
                ga *= 0.5
            side = -1
        else:
            return ST_OK, x, iters
        step = g * (x - xp) / (g - gp) if (math.isfinite(xp) and g != gp) else np.nan
        if (math.isfinite(step) and abs(step) <= 0.1 * tol) or b - a <= tol:
            return ST_OK, x, iters
        xn = x - step
        if not (math.isfinite(xn) and xn > a and xn < b):
            xn = (a * gb - b * ga) / (gb - ga)
            if not (xn > a and xn < b):
                xn = 0.5 * (a + b)
        if k % 3 == 2:
            # stalling (the bracket not halved in three evaluations, nor the correction in the last
            # one: Illinois creeping along a jump, its steps doubling): bisect. A secant converging
            # from one side keeps its bracket but halves its corrections, and goes on untouched.
            if b - a > 0.5 * width and abs(xn - x) > 0.5 * abs(x - xp):
                xn = 0.5 * (a + b)
            width = b - a
        xp = x
        gp = g
        x = xn
    return ST_EVENT_FAILED, x, iters


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _mode_change(st, t, tau0, c, kind):
    """A grid step from t in which held contact c's mode ends (kind as _mode_event_fraction): the held
    map to the located event, the change there (kind 0: released; 1: its slip stopped, stuck if
    Coulomb's static bound holds, else slipping the other way; 2: its stick ended, slipping where the
    unbalanced force drives; the other held contacts' modes re-decided with it: maps/friction.py
    assign_modes) and recorded; integrate takes the rest of the step as an event step from there.
    Returns (status, tau, iterations)."""
    status, tau, it = _locate_mode_event(st, t, st.h, tau0, c, kind)
    if status != ST_OK:
        return status, tau, it
    status = _change_mode(st, t, tau, c, kind)
    return status, tau, it


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _change_mode(st, t, tau, c, kind):
    """The change of held contact c's mode (kind as _mode_event_fraction) at the located event t + tau,
    whose state _locate_mode_event left in (st.qt, st.pt) (with its friction work st.fw[0]): into
    (st.q, st.p), the change made and recorded. Returns the status."""
    if tau > 0.0:
        st.out[O_FRICTION_WORK][st.n[N_STEP]] += st.fw[0]
        copy_into(st.q, st.qt)
        copy_into(st.p, st.pt)
    te = t + tau
    before = scratch_i(NCON)
    for j in range(NCON):
        before[j] = st.held[j]
    if kind == 0:
        st.held[c] = 0
        st.n[N_HELD] -= 1
        _record_release(st, te, c)
        if st.n[N_HELD] > 0 and assign_modes(st.q, st.p, te, st.prm, st.held, -1, -1, st.mu, st.lt, st.p) == FRICTION_PAINLEVE:
            return ST_PAINLEVE
        _record_mode_changes(st, te, before, -1)
    else:
        rest = c if kind == 1 else -1
        moving = c if kind == 2 else -1
        if kind == 2:
            # slipping where the unbalanced tangential force drives: against the stuck force at the event
            if friction_forces(st.q, st.p, te, st.prm, st.held, st.mu, st.lt) == FRICTION_PAINLEVE:
                return ST_PAINLEVE
            st.held[c] = -1 if st.lt[c] > 0.0 else 1
        if assign_modes(st.q, st.p, te, st.prm, st.held, rest, moving, st.mu, st.lt, st.p) == FRICTION_PAINLEVE:
            return ST_PAINLEVE
        if _newly_stuck(st, before):
            # the slip velocity is zero to the event tolerance: zeroed (with the held normal velocities)
            _stick_projection(st)
        _record_mode_changes(st, te, before, c)
    return ST_OK


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _newly_stuck(st, before):
    for j in range(NCON):
        if st.held[j] == HELD_STICK and before[j] != HELD_STICK:
            return True
    return False


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _stick_projection(st):
    """The stuck contacts' slip velocities zeroed with the held normal velocities (maps/friction.py
    friction_project); the kinetic energy it removes is friction's, booked as the current step's
    friction work (a stop located to the event tolerance removes round-off; a stop found at a grid
    state, _reassign_modes, the slip that friction would have removed within the step)."""
    v = scratch(NDOF)
    velocity_guess(st.q, st.p, st.prm, v)
    T0 = 0.0
    for j in range(NDOF):
        T0 += 0.5 * st.p[j] * v[j]
    friction_project(st.q, st.p, st.prm, st.held, st.lam, st.lamt)
    velocity_guess(st.q, st.p, st.prm, v)
    T1 = 0.0
    for j in range(NDOF):
        T1 += 0.5 * st.p[j] * v[j]
    st.out[O_FRICTION_WORK][st.n[N_STEP]] += min(T1 - T0, 0.0)
    for j in range(NCON):
        st.lam[j] = 0.0
        st.lamt[j] = 0.0


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _record_mode_changes(st, t, before, c):
    """Record every held contact whose mode differs from before[] (contact c's first: the event's own),
    kind 1 stuck, 2 a stick ended, 3 a slip reversed."""
    order = scratch_i(NCON)
    k = 0
    if c >= 0:
        order[0] = c
        k = 1
    for j in range(NCON):
        if j != c:
            order[k] = j
            k += 1
    for a in range(NCON):
        j = order[a]
        if st.held[j] != before[j] and before[j] != 0 and st.held[j] != 0:
            _record_mode_change(st, t, j, 1 if st.held[j] == HELD_STICK else (2 if before[j] == HELD_STICK else 3))


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _modes_stale(st):
    """Does a held contact's mode contradict the grid state (st.ev from _record_contacts): a slip whose
    velocity has turned against its direction, or a stick past Coulomb's static bound? The partial
    held steps of an event step locate mode events whose value is positive at their start, up to
    max_impacts_step per step (_event_step); one past those (a mode set at its own root, as a slip
    from rest that reverses at once) is found here, at the next grid state."""
    for j in range(NCON):
        if st.held[j] != 0 and st.ev[j] < 0.0:
            return True
    return False


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _reassign_modes(st, k, t):
    """The held contacts' modes decided afresh at grid state k (time t) by maps/friction.py
    assign_modes, a slip whose velocity has turned against its direction tried stuck first (its slip
    stopped inside the step: it sticks where Coulomb's static bound holds, as at a located stop), the
    changes recorded; the contacts that stick have their slip velocities zeroed (_stick_projection,
    its energy booked as friction work). The record's row k is written again. Returns False in
    Painleve's case."""
    before = scratch_i(NCON)
    for j in range(NCON):
        before[j] = st.held[j]
    if assign_modes(st.q, st.p, t, st.prm, st.held, REST_REVERSED, -1, st.mu, st.lt, st.p) == FRICTION_PAINLEVE:
        return False
    if _newly_stuck(st, before):
        _stick_projection(st)
    _record_mode_changes(st, t, before, -1)
    st.n[N_FRESH] = 0
    return _record_contacts(st, k, t)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _record_mode_change(st, t, c, kind):
    k = st.info[I_N_MODE_CHANGES]
    if k < st.out[O_MODE_CHANGES].shape[0]:
        st.out[O_MODE_CHANGES][k] = t
        st.out[O_MODE_CHANGE_CONTACT][k] = c
        st.out[O_MODE_CHANGE_KIND][k] = kind
        st.info[I_N_MODE_CHANGES] = k + 1


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _event_step(st, tau_max, t, have_end):
    """Lines 5-17 of Algorithm 1: the step of length tau_max (<= the grid step h) from (st.q, st.p) at
    t whose full step left the admissible set, by partial steps to each collision and the impact
    there (_impact). have_end: (st.qt, st.pt, st.vt) hold that full step on entry (reused as the
    first partial step when the partial map is the full map). On success (st.q, st.p) hold the
    state at t + tau_max. With held contacts the partial steps are the constrained map. Returns
    (status, Newton iterations)."""
    copy_into(st.qh, st.q)
    copy_into(st.ph, st.p)
    tc = t
    k_imp = 0
    k_mode = 0
    iters = 0
    while tau_max > 0.0:
        nheld = st.n[N_HELD]
        # with friction, the held contacts' mode events inside each partial held step are located as
        # in a grid step (up to max_impacts_step of them per step; past that, or for a mode whose
        # value starts at its root, the grid state after the step finds it: _modes_stale)
        locate = FRICTION and nheld > 0 and k_mode < st.max_impacts_step
        if locate and mode_event_values(st.qh, st.ph, tc, st.prm, st.held, st.ev, st.mu, st.lt) == FRICTION_PAINLEVE:
            return ST_PAINLEVE, iters
        code, dtau, E_pre, itc = search_collision(st, tau_max, tc, have_end, nheld)
        have_end = False
        iters += itc
        if code < 0:
            return (ST_NEWTON_FAILED if code == -1 else ST_EVENT_FAILED), iters
        if locate and dtau > 0.0:
            if mode_event_values(st.qt, st.pt, tc + dtau, st.prm, st.held, st.ev_end, st.mu_end,
                                 st.lt_end) == FRICTION_PAINLEVE:
                return ST_PAINLEVE, iters
            frac, c, kind = _mode_event_fraction(st, True)
            if c >= 0:   # before the collision the search found, if any: located, changed, gone on from
                k_mode += 1
                copy_into(st.q, st.qh)
                copy_into(st.p, st.ph)
                status, tau, itl = _locate_mode_event(st, tc, dtau, frac * dtau, c, kind)
                iters += itl
                if status == ST_OK:
                    status = _change_mode(st, tc, tau, c, kind)
                if status != ST_OK:
                    return status, iters
                copy_into(st.qh, st.q)
                copy_into(st.ph, st.p)
                tau_max -= tau
                tc += tau
                continue
        if FRICTION and nheld > 0:   # the partial held step taken: its friction work
            st.out[O_FRICTION_WORK][st.n[N_STEP]] += st.fw[0]
        _log_partial(st, dtau)
        tau_rem = tau_max - dtau
        if code == 1:
            k_imp += 1
            status, itc, mapped = _impact(st, tc + dtau, dtau, tau_rem, E_pre, k_imp)
            iters += itc
            if status != ST_OK:
                return status, iters
            copy_into(st.qh, st.qn if mapped else st.qt)
            copy_into(st.ph, st.pp)
            tau_max = tau_rem
            tc += dtau
        else:
            copy_into(st.qh, st.qt)
            copy_into(st.ph, st.pt)
            tau_max = 0.0
    copy_into(st.q, st.qh)
    copy_into(st.p, st.ph)
    return ST_OK, iters


# --- the impact and its cases ---------------------------------------------------------------------------
# (inline="always": each has one call site, and a call passes the whole LoopState, some 60 arrays
# flattened into scalars and reference-count calls: about 1 us per impact as functions)

@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _impact(st, ti, dtau, tau_rem, E_pre, k_imp):
    """The impact at ti, where the search left the state just before it in (st.qt, st.pt) (the
    partial step of length dtau that reached it, its discrete energy E_pre and step velocity st.vt;
    tau_rem: the time left in the step): the impact law (collision/impact.py: which contacts, their
    impulses, the direction st.d, Newton's multiplier s0 and the energy it removes; one contact in
    closed form, several by Moreau's law), then one of the cases: a declared reset map, touching
    without approach, an impact during a hold, the method's reset. st.pp receives the momentum
    after it (with a declared map, st.qn the configuration). k_imp: the impacts of this grid step so
    far, this one included. Returns (status, iterations, mapped: the declared map moved q)."""
    if FRICTION:
        k, s0, dE = friction_impact_direction(st.qt, st.pt, st.h, st.event_tol, st.prm, st.d, st.lam, st.lamt,
                                              st.active)
    else:
        k, s0, dE = impact_direction(st.qt, st.pt, st.h, st.event_tol, st.prm, st.d, st.lam, st.active)
    nheld = st.n[N_HELD]
    mapped = RESET_MAP and nheld == 0 and k > 0
    if mapped:
        status, iters, s = _declared_reset(st, ti, dtau, tau_rem, E_pre, s0)
    elif k <= 0:
        status, iters, k, s, s0 = _touching(st, ti, k)
        if status == ST_OK and k == 0:
            # the law's degenerate case (touching, no impulse): no impact to record or count; a
            # search that stops at such contacts again and again within the step has failed
            return (ST_EVENT_FAILED if k_imp > st.max_impacts_step else ST_OK), iters, False
    elif nheld > 0:
        status, iters, s = _impact_in_hold(st, s0)
    else:
        status, iters, s = _method_reset(st, ti, dtau, tau_rem, E_pre, s0, dE)
    if status != ST_OK:
        return status, iters, mapped
    return _after_impact(st, ti, k, s, s0, mapped, k_imp), iters, mapped


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _declared_reset(st, ti, dtau, tau_rem, E_pre, s0):
    """A declared reset map (vcirun.mechanics.hybrid) at an impact with no contact held: the map
    takes (st.qt, st.pt) to (st.qn, st.pmap), then the method's reset at q+ from the map's p+ and
    along it, with the energy the map removes (R^CVA: the map itself; R^MCVA's target is the
    pre-impact H~ less it; docs/derivations/declared_resets.md). Returns (status, iterations, the
    record's multiplier: the impact law's s0 when it acts first, else 0)."""
    dEm = declared_reset(st.qt, st.pt, st.d, s0, st.prm, st.qn, st.pmap)
    Hm = modified_energy(st.qt, st.pt, st.h, st.prm)
    if Hm == Hm:  # (a modified energy: R^MCVA's target is the pre-impact H~ less dEm)
        dEm += modified_energy(st.qn, st.pmap, st.h, st.prm) - Hm
    itr, s = reset(st.qn, st.pmap, st.pmap, 0.0, dEm, E_pre, st.vt, dtau, tau_rem, st.h, ti, st.prm, st.ntol,
                   st.maxit, st.pp)
    if itr < 0:
        return ST_RESET_FAILED, -itr, 0.0
    return ST_OK, itr, (s0 if RESET_LAW_FIRST else 0.0)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _touching(st, ti, k_law):
    """The search stopped at contacts that the impact law finds not approaching (k_law = 0: normal
    velocity ~0, grazing or resting), or whose law has no solution (k_law < 0). With held contacts
    allowed, the touching contacts the motion presses into are held (the multiplier test of
    `initially_held`), as an impact of zero impulse. Else, with no contact held, several constraints
    and no approaching contact, a located contact whose normal velocity moves its gap by less than
    the gap's round-off within a grid step is the law's degenerate case (_unresolved_touch): touching,
    no impulse, the state goes on (returned as k = 0). Otherwise the run fails: no elastic reset
    exists. Returns (status, iterations, contacts held, s, s0)."""
    nheld = st.n[N_HELD]
    if st.resting:
        k = initially_held(st.qt, st.pt, ti, st.h, st.event_tol, st.prm, st.held)
        for j in range(NCON):
            st.active[j] = st.held[j]
            st.lam[j] = 0.0
        if k > 0:
            st.n[N_HELD] = _count(st.held)
            copy_into(st.pp, st.pt)
            if FRICTION:
                for j in range(NCON):
                    st.lamt[j] = 0.0
            return ST_OK, 0, k, 1.0, 1.0
    if k_law == 0 and nheld == 0 and _unresolved_touch(st):
        copy_into(st.pp, st.pt)
        return ST_OK, 0, 0, 0.0, 0.0
    return ST_RESET_FAILED, 0, 0, 0.0, 0.0


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _unresolved_touch(st):
    """Several constraints: at the search's root (st.qt, st.pt), every contact at or past its surface
    (phi_i <= 0; at least the smallest phi_i) has a normal velocity u_i >= 0 whose motion over a
    grid step, u_i h, is below the round-off of phi_i there, 64 eps (1 + max |q| max |grad phi_i|)
    (touch_tolerance's round-off term). The sign of those gaps within the step is then rounding, not
    motion: the root is not an event (bodies moving together, their relative velocities the noise
    of the previous impact's law; docs/derivations/contacts.md 1.8). One constraint: False (the
    paper's grazing failure)."""
    if NCON == 1:
        return False
    sys_phis(st.qt, st.prm, st.phis)
    i0 = 0
    for i in range(1, NCON):
        if st.phis[i] < st.phis[i0]:
            i0 = i
    u = normal_velocities(st.qt, st.pt, st.prm)
    for i in range(NCON):
        if i == i0 or st.phis[i] <= 0.0:
            if not (u[i] >= 0.0 and u[i] * st.h <= touch_tolerance(st.qt, st.prm, i, 0.0, st.h, 0.0)):
                return False
    return True


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _impact_in_hold(st, s0):
    """An impact of free contacts while others are held: the impact law's p+ = pt + s0 d (R^CVA with
    restitution; the paper's energy-based resets are not defined for the constrained map).
    Returns (status, iterations, s0)."""
    for j in range(NDOF):
        st.pp[j] = st.pt[j] + s0 * st.d[j]
    return ST_OK, 0, s0


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _method_reset(st, ti, dtau, tau_rem, E_pre, s0, dE):
    """The method's reset (the role `reset`: R^CVA, R^VCI, R^MCVA, ...) along the impact law's
    direction, one contact or several. An energy-based reset (R^VCI, R^MCVA) has no reflecting root
    at a slow or grazing impact: where its energy balance cannot matter (_law_suffices), the impact
    law's p+ is taken (as during a hold; docs/derivations/contacts.md 7.4), else the run fails.
    With friction, a plastic impact (every contact that takes an impulse leaves it with no normal
    velocity: e = 0, or the tangential impulse presses it in) takes the impact law's p+: the
    energy-based resets have a double root there and an O(h^(p/2)) multiplier
    (docs/derivations/contacts.md 2.4), which the tangential impulse would carry into the slip.
    Returns (status, iterations, the multiplier s of p+ = pt + s d)."""
    if FRICTION and _plastic(st.qt, st.pt, s0, st.d, st.prm, st.active, st.lam):
        for j in range(NDOF):
            st.pp[j] = st.pt[j] + s0 * st.d[j]
        return ST_OK, 0, s0
    itr, s = reset(st.qt, st.pt, st.d, s0, dE, E_pre, st.vt, dtau, tau_rem, st.h, ti, st.prm, st.ntol, st.maxit,
                   st.pp)
    if itr >= 0:
        return ST_OK, itr, s
    for j in range(NDOF):
        st.pp[j] = st.pt[j] + s0 * st.d[j]
    if not (st.resting and _law_suffices(st.qt, st.pt, st.pp, E_pre, ti, st.h, st.ntol, st.prm, st.active,
                                         st.lam)):
        return ST_RESET_FAILED, -itr, s0
    return ST_OK, -itr, s0


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _after_impact(st, ti, k, s, s0, mapped, k_imp):
    """What follows every impact: the accumulation test (impacts denser than the grid, or more than
    the cap in one step: held where energy leaves, else the run stops), the record's capacity, the
    holds and releases the impact settles (_settle), and its entries in the record. Returns the
    status."""
    accumulating = _accumulating(st.dense, ti, st.h, st.max_impacts_step) or k_imp > st.max_impacts_step
    # dense impacts settle only where energy leaves (restitution < 1 or a force): elastic
    # impacts of a conservative system stay the documented limit (docs/derivations/contacts.md 7.2)
    if accumulating and not (st.resting and _dissipative(st.qt, st.pt, ti, st.prm, st.active)):
        return ST_ACCUMULATION
    if st.info[I_N_IMPACTS] + k > st.out[O_IMPACTS].shape[0]:
        return ST_ACCUMULATION  # (the record is full: the caller reruns with room)
    if st.resting and not mapped and (accumulating or st.n[N_HELD] > 0 or _inelastic(st.prm, st.active)):
        # (_settle holds or releases nothing otherwise: skipped, the same result)
        st.n[N_HELD] = _settle(st, ti, s, s0, accumulating)
    _record_impacts(st, ti, s, s0)
    if FRICTION and st.n[N_HELD] > 0:
        # the held contacts' modes after the impulse (a stuck contact may be set slipping, a landing one
        # sticks where its slip velocity left the impact at rest, to the rounding of the momentum
        # before it, st.pt, and the static bound holds)
        if assign_modes(st.qt, st.pp, ti, st.prm, st.held, -1, -1, st.mu, st.lt, st.pt) == FRICTION_PAINLEVE:
            return ST_PAINLEVE
    return ST_OK


# --- helpers of the grid step ---------------------------------------------------------------------------

@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _record_contacts(st, k, t):
    """contact_active[k], contact_force[k] (and with friction contact_mode[k]) at grid state k (st.q,
    st.p); st.mu receives the held contacts' normal forces (with friction st.lt their tangential
    forces and st.ev their mode event values). Returns False in Painleve's case."""
    active = st.out[O_CONTACT_ACTIVE]
    force = st.out[O_CONTACT_FORCE]
    ok = True
    if st.n[N_HELD] > 0:
        if FRICTION and st.n[N_FRESH] == 1:
            # the step that reached this state computed them there (at t as t_k + h, which differs
            # from t only by rounding, seen by a time-dependent force alone): half the held step's
            # contact-force solves
            copy_into(st.mu, st.mu_end)
            copy_into(st.lt, st.lt_end)
            copy_into(st.ev, st.ev_end)
        elif FRICTION:
            ok = mode_event_values(st.q, st.p, t, st.prm, st.held, st.ev, st.mu, st.lt) != FRICTION_PAINLEVE
        else:
            contact_forces(st.q, st.p, t, st.prm, st.held, st.mu)
    else:
        for j in range(NCON):
            st.mu[j] = 0.0
    for j in range(NCON):
        active[k, j] = st.held[j] != 0
        force[k, j] = st.mu[j]
    if FRICTION:
        mode = st.out[O_CONTACT_MODE]
        for j in range(NCON):
            mode[k, j] = st.held[j]
    return ok


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _release_fraction(mu, mu_end, held):
    """(fraction of the step, contact) of the first held contact whose force turns tensile inside the
    step, by linear interpolation of its force between the step's start (mu) and end (mu_end): O(h^2)
    in the release time; (-1, -1) if none."""
    best = 2.0
    c = -1
    for j in range(NCON):
        if held[j] != 0 and mu_end[j] < 0.0:
            f = 0.0 if mu[j] <= 0.0 else mu[j] / (mu[j] - mu_end[j])
            if f < best:
                best = f
                c = j
    return (best if c >= 0 else -1.0), c


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _phis_positive(qt, prm, phis):
    """Every phi_i(qt) > 0 (phis: scratch): a full step with several contacts is admissible then,
    whatever is touching or held (step_admissible's first test, without its other arguments)."""
    sys_phis(qt, prm, phis)
    for j in range(NCON):
        if not phis[j] > 0.0:
            return False
    return True


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _dissipative(q, p, t, prm, active):
    """True if an impacting contact has restitution < 1 or friction, or the force does negative work at
    (q, p, t) (drag): dense impacts then accumulate (their energy goes) and are held; elastic impacts
    of a conservative frictionless motion are sustained (flights shorter than h, not a Zeno point)
    and are not."""
    v = scratch(NDOF)
    velocity_guess(q, p, prm, v)
    if FORCED and force_power(q, v, t, prm) < 0.0:
        return True
    if FRICTION:
        mu = scratch(NCON)
        mus = scratch(NCON)
        sys_friction(prm, mu, mus)
        for j in range(NCON):
            if active[j] != 0 and mu[j] > 0.0:
                return True
    return _inelastic(prm, active)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _plastic(q, p, s0, d, prm, active, lam):
    """Every contact of the impact that takes an impulse (lam_i > 0) leaves it with no normal velocity:
    restitution 0, or the law's p+ = p + s0 d at rest along grad phi_i, |u+_i| <= 1e-12 |u-_i| (a
    tangential impulse that presses the contact in stops its rebound whatever its restitution: the
    same double root of the energy-based resets' balance as at e = 0)."""
    e = scratch(NCON)
    sys_restitution(prm, e)
    hit = False
    elastic = False
    for j in range(NCON):
        if active[j] != 0 and lam[j] > 0.0:
            hit = True
            elastic = elastic or e[j] != 0.0
    if not (hit and elastic):
        return hit
    pp = scratch(NDOF)
    for j in range(NDOF):
        pp[j] = p[j] + s0 * d[j]
    um = normal_velocities(q, p, prm)
    up = normal_velocities(q, pp, prm)
    for j in range(NCON):
        if active[j] != 0 and lam[j] > 0.0 and e[j] != 0.0 and not abs(up[j]) <= 1e-12 * abs(um[j]):
            return False
    return True


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _inelastic(prm, active):
    """True if a contact of the impact has restitution < 1 (only those can come to rest in _settle)."""
    e = scratch(NCON)
    sys_restitution(prm, e)
    for j in range(NCON):
        if active[j] != 0 and e[j] < 1.0:
            return True
    return False


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _small_bounce(q, pp, t, h, prm, j, e_j, u_j):
    """Contact j leaves p+ = pp with a bounce that comes to rest: restitution e_j < 1 and a normal
    velocity u_j at most |d^2 phi_j/dt^2| h while pressed in (its next flight shorter than two steps;
    docs/derivations/contacts.md 7.2). The acceleration (a solve with M) only when e_j < 1."""
    if not e_j < 1.0:
        return False
    a = normal_acceleration(q, pp, t, prm, j)
    return a < 0.0 and u_j <= -a * h


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _law_suffices(q, pm, pp, E_pre, t, h, ntol, prm, active, lam):
    """After a reset without root, is the impact law's p+ = pp as good (docs/derivations/contacts.md
    7.4)? True if every contact that took an impulse (lam_i > 0) leaves with a bounce _settle holds
    (e_i < 1, normal velocity at most |d^2 phi_i/dt^2| h while pressed in: the reset's outcome would
    be projected away). With several contacts also if none took one (p+ = p-), or if the impact's
    normal kinetic energy, sum lam_i |u-_i| / (2 (1 + e_i)), is not large against the energy error
    the reset must absorb, |E_pre - H| (vcirun.run.diagnosis's test), or is below the resolution
    ntol |H| of the reset's energy equation (touching contacts whose normal velocities are the Newton
    noise of the previous reset: balls moving together after a simultaneous impact). One elastic
    contact, the paper's setting, keeps the paper's reset and its failure."""
    e = scratch(NCON)
    sys_restitution(prm, e)
    um = normal_velocities(q, pm, prm)
    u = normal_velocities(q, pp, prm)
    hit = False
    small = True
    ke = 0.0
    for j in range(NCON):
        if active[j] == 0 or not lam[j] > 0.0:
            continue
        hit = True
        ke += lam[j] * abs(um[j]) / (2.0 * (1.0 + e[j]))
        if small and not _small_bounce(q, pp, t, h, prm, j, e[j], u[j]):
            small = False
    if hit and small:
        return True
    if NCON == 1:
        return False  # (one contact, elastic or not settling: the paper's R^VCI / R^MCVA, no substitute)
    if not hit:
        return True   # (the law gives no contact an impulse, u- within round-off of 0: p+ = p-)
    H = hamiltonian(q, pm, prm)
    return ke <= 10.0 * (abs(E_pre - H) + ntol * abs(H))


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _count(held):
    k = 0
    for j in range(NCON):
        k += 1 if held[j] != 0 else 0
    return k


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _settle(st, t, s, s0, accumulating):
    """After an impact at t (p+ = st.pp at st.qt): hold the impact's contacts that come to rest -- all
    of them when impacts accumulate, else those with restitution < 1 left a normal velocity below
    |d^2 phi/dt^2| h while pressed in -- with a plastic projection (their normal velocities zeroed,
    the impulse added to the impact's record through st.lam); release the held contacts the impulse
    pulled away, but keep (and project) those whose flight would be one the small-bounce rule holds
    on landing. Returns the held count."""
    q = st.qt
    pp = st.pp
    held = st.held
    active = st.active
    lam = st.lam
    e = scratch(NCON)
    sys_restitution(st.prm, e)
    u = normal_velocities(q, pp, st.prm)
    changed = False
    for j in range(NCON):
        if active[j] == 0:
            continue
        if held[j] != 0:
            # pulled off its surface by the others' impulses: released, unless the flight would be
            # one that the rule below holds on landing (a rocking link's two ends alternating at an
            # accumulation point: one impact lifts the other end by less and less, without end)
            if u[j] > 0.0 and lam[j] == 0.0:
                if _small_bounce(q, pp, t, st.h, st.prm, j, e[j], u[j]):
                    changed = True
                else:
                    held[j] = 0
                    _record_release(st, t, j)
            continue
        if accumulating or _small_bounce(q, pp, t, st.h, st.prm, j, e[j], u[j]):
            held[j] = 1
            changed = True
    if changed:
        pi = scratch(NCON)
        project_momentum(q, pp, st.prm, held, pi)
        for j in range(NCON):
            if active[j] != 0:
                lam[j] += pi[j] * (s0 / s) if s != 0.0 else pi[j]
    return _count(held)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def initially_held(q, p, t, h, event_tol, prm, held):
    """Hold the contacts the state rests on: touching (phi_i within its tolerance), normal velocity
    at most |d^2 phi_i/dt^2| h, pressed in, and with a compressive multiplier when held together
    (contact_forces > 0; contacts whose multiplier is not are dropped, in turn). Returns the count."""
    phis = scratch(NCON)
    sys_phis(q, prm, phis)
    u = normal_velocities(q, p, prm)
    for j in range(NCON):
        held[j] = 0
        if phis[j] <= touch_tolerance(q, prm, j, u[j], h, event_tol) + abs(u[j]) * h:
            a = normal_acceleration(q, p, t, prm, j)
            if a < 0.0 and abs(u[j]) <= -a * h:
                held[j] = 1
    mu = scratch(NCON)
    for _ in range(NCON):
        if _count(held) == 0 or not contact_forces(q, p, t, prm, held, mu):
            break
        worst = -1
        for j in range(NCON):
            if held[j] != 0 and mu[j] <= 0.0 and (worst < 0 or mu[j] < mu[worst]):
                worst = j
        if worst < 0:
            break
        held[worst] = 0
    k = _count(held)
    if k > 0:
        pi = scratch(NCON)
        project_momentum(q, p, prm, held, pi)
    return k


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _record_release(st, t, c):
    k = st.info[I_N_RELEASES]
    if k < st.out[O_RELEASES].shape[0]:
        st.out[O_RELEASES][k] = t
        st.out[O_RELEASE_CONTACT][k] = c
        st.info[I_N_RELEASES] = k + 1


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _accumulating(dense, t_imp, h, max_impacts_step):
    """Impacts denser than the grid: dense[2] counts consecutive impacts that each follow
    the previous one by less than one grid step h, since dense[1]. Such a run longer than
    max_impacts_step steps is an accumulation, like more than max_impacts_step impacts inside one
    step: a motion settling into contact stops in bounded work even when no single step reaches the
    per-step cap (a short chatter burst does not). vcirun.run.api reads the onset off the impact times."""
    if t_imp - dense[0] < h:
        if dense[2] == 0.0:
            dense[1] = dense[0]
        dense[2] += 1.0
    else:
        dense[2] = 0.0
    dense[0] = t_imp
    return dense[2] > 0.0 and dense[0] - dense[1] > max_impacts_step * h


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _log_partial(st, dtau):
    log = st.out[O_PARTIAL_STEPS]
    k = st.info[I_N_PARTIAL]
    if k < log.shape[0]:
        log[k] = dtau
        st.info[I_N_PARTIAL] = k + 1


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _record_impacts(st, t_imp, s, s0):
    """One entry of every per-impact row of vcirun.core.record.FIELDS per contact that took an impulse
    (simultaneous impacts: one entry each, at the same time and state: st.qt, st.pt before, st.pp
    after). The reset's multiplier s scales the impact law's impulses st.lam: contact i took
    lam_i s / s0 (one contact: s itself)."""
    out = st.out
    for i in range(NCON):
        if st.active[i] == 0 or (NCON > 1 and not st.lam[i] > 0.0):
            continue
        k = st.info[I_N_IMPACTS]
        out[O_IMPACTS][k] = t_imp
        set_row(out[O_IMPACT_Q], k, st.qt)
        set_row(out[O_IMPACT_P_MINUS], k, st.pt)
        set_row(out[O_IMPACT_P_PLUS], k, st.pp)
        if FRICTION:   # (s0 = 1: the law's impulses scaled by the reset's multiplier)
            out[O_IMPACT_IMPULSE][k] = st.lam[i] * (s / s0)
            out[O_IMPACT_IMPULSE_T][k] = st.lamt[i] * (s / s0)
        else:
            out[O_IMPACT_IMPULSE][k] = s if NCON == 1 else st.lam[i] * (s / s0)
            out[O_IMPACT_IMPULSE_T][k] = 0.0
        out[O_IMPACT_CONTACT][k] = i
        st.info[I_N_IMPACTS] = k + 1


@njit(cache=True, nogil=True, error_model="numpy")
def no_modified_energy(q, p, h, prm):
    """The `modified_energy` role of methods without a modified Hamiltonian."""
    return np.nan
