# numba source unit: Algorithm 1 (event-driven collision integration), compiled as a whole so the
# event loop itself runs native. It knows only `full`, `partial`, `reset` (and the scene's phi, H and
# the optional modified energy); which method it runs is decided by what the module binds to them
# (vcirun.codegen.units). Its inputs, outputs and status codes are the rows of vcirun.record:
# settings[S_*], out[O_*], info[I_*], ST_*.
import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def _finite(x):
    for i in range(x.shape[0]):
        if not math.isfinite(x[i]):
            return False
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def integrate(q0, p0, t0, h, N, prm, settings, out, info):
    """Run N grid steps of Algorithm 1 from (q0, p0) at t0.

    settings: the loop's scalar inputs (vcirun.record.SETTINGS: constrained, newton_tol, max_iter,
    event_tol, max_impacts_step, energies). out: one preallocated buffer per vcirun.record.FIELDS
    row, in table order (vcirun.record.allocate). info receives the counters (vcirun.record.COUNTERS:
    status, fail_step, n_impacts, n_partial, steps). energies = 0 skips H, the discrete energy Ed and
    the modified energy along the grid (set at t0 only): a run that only needs the trajectory saves
    their per-step cost."""
    constrained = settings[S_CONSTRAINED] != 0.0
    ntol = settings[S_NEWTON_TOL]
    maxit = int(settings[S_MAX_ITER])
    event_tol = settings[S_EVENT_TOL]
    max_impacts_step = int(settings[S_MAX_IMPACTS_STEP])
    energies = settings[S_ENERGIES] != 0.0
    Q = out[O_Q]
    P = out[O_P]
    H = out[O_H]
    Ed = out[O_ED]
    Hmod = out[O_HMOD]
    impact_step = out[O_IMPACT_STEP]
    newton_iters = out[O_NEWTON_ITERS]
    q = q0.copy()
    p = p0.copy()
    qt = np.empty(NDOF)
    pt = np.empty(NDOF)
    vt = np.empty(NDOF)
    work = np.empty((4, NDOF))
    set_row(Q, 0, q)
    set_row(P, 0, p)
    info[I_N_IMPACTS] = 0
    info[I_N_PARTIAL] = 0
    # (issue 8) accumulation across steps: dense = [time of the last impact, start of the current
    # run of impacts that each follow the previous one by less than one grid step h, its length]
    # (see _accumulating)
    dense = np.array([-math.inf, 0.0, 0.0])
    status = ST_OK
    fail = -1
    i = 0
    while i < N:
        t = t0 + i * h
        it, E = full(q, p, h, t, prm, ntol, maxit, qt, pt, vt, energies or i == 0)
        if energies or i == 0:
            H[i] = hamiltonian(q, p, prm)
            Hmod[i] = modified_energy(q, p, h, prm)
        Ed[i] = E
        if it < 0:
            status = ST_NEWTON_FAILED
            fail = i
            break
        iters = it
        if (not constrained) or step_admissible(q, p, qt, h, event_tol, prm):
            copy_into(q, qt)
            copy_into(p, pt)
        else:
            impact_step[i] = True
            status, itc = _impact_step(q, p, h, t, prm, ntol, maxit, event_tol, max_impacts_step, qt, pt, vt,
                                       work, dense, out, info)
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
    if status == ST_OK and energies:
        # energies at the last grid state (its discrete energy from one more trial step)
        it, E = full(q, p, h, t0 + N * h, prm, ntol, maxit, qt, pt, vt)
        H[N] = hamiltonian(q, p, prm)
        Ed[N] = E
        Hmod[N] = modified_energy(q, p, h, prm)
    info[I_STATUS] = status
    info[I_FAIL_STEP] = fail
    info[I_STEPS] = i
    return status


@njit(cache=True, nogil=True, error_model="numpy")
def _impact_step(q, p, h, t, prm, ntol, maxit, event_tol, max_impacts_step, qt, pt, vt, work, dense, out, info):
    """Lines 5-17 of Algorithm 1: the step from (q, p) at t whose full step left the admissible set,
    by partial steps to each collision and resets. (qt, pt, vt) hold that full step on entry (reused
    as the first partial step when the partial map is the full map); work: 4 x NDOF scratch. On
    success (q, p) hold the state at t + h. Returns (status, Newton iterations)."""
    qh = work[0]
    ph = work[1]
    pp = work[2]
    d = work[3]
    lam = np.empty(NCON)
    active = np.empty(NCON, dtype=np.int64)
    copy_into(qh, q)
    copy_into(ph, p)
    tau_max = h
    tc = t
    k_imp = 0
    iters = 0
    have_end = PARTIAL_IS_FULL
    while tau_max > 0.0:
        code, dtau, Epre, itc = search_collision(qh, ph, tau_max, h, tc, prm, ntol, maxit, event_tol,
                                                 qt, pt, vt, have_end)
        have_end = False
        iters += itc
        if code < 0:
            return (ST_NEWTON_FAILED if code == -1 else ST_EVENT_FAILED), iters
        _log_partial(out[O_PARTIAL_STEPS], info, dtau)
        tau_rem = tau_max - dtau
        if code == 1:
            # the impact law (which contacts, Newton's multiplier, the energy it removes), then the
            # method's reset along its direction
            k, s0, dE = impact_direction(qt, pt, h, event_tol, prm, d, lam, active)
            if k <= 0:
                return ST_RESET_FAILED, iters  # no approaching contact (grazing), or no LCP solution
            itr, s = reset(qt, pt, d, s0, dE, Epre, vt, dtau, tau_rem, h, tc + dtau, prm, ntol, maxit, pp)
            iters += abs(itr)
            if itr < 0:
                return ST_RESET_FAILED, iters
            k_imp += 1
            if (_accumulating(dense, tc + dtau, h, max_impacts_step) or k_imp > max_impacts_step
                    or info[I_N_IMPACTS] + k > out[O_IMPACTS].shape[0]):
                return ST_ACCUMULATION, iters
            _record_impacts(out, info, tc + dtau, qt, pt, pp, s, s0, lam, active)
            copy_into(qh, qt)
            copy_into(ph, pp)
            tau_max = tau_rem
            tc += dtau
        else:
            copy_into(qh, qt)
            copy_into(ph, pt)
            tau_max = 0.0
    copy_into(q, qh)
    copy_into(p, ph)
    return ST_OK, iters


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _accumulating(dense, t_imp, h, max_impacts_step):
    """(issue 8) Impacts denser than the grid: dense[2] counts consecutive impacts that each follow
    the previous one by less than one grid step h, since dense[1]. Such a run longer than
    max_impacts_step steps is an accumulation, like more than max_impacts_step impacts inside one
    step: a motion settling into contact stops in bounded work even when no single step reaches the
    per-step cap (a short chatter burst does not). vcirun.api reads the onset off the impact times."""
    if t_imp - dense[0] < h:
        if dense[2] == 0.0:
            dense[1] = dense[0]
        dense[2] += 1.0
    else:
        dense[2] = 0.0
    dense[0] = t_imp
    return dense[2] > 0.0 and dense[0] - dense[1] > max_impacts_step * h


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _log_partial(log, info, dtau):
    k = info[I_N_PARTIAL]
    if k < log.shape[0]:
        log[k] = dtau
        info[I_N_PARTIAL] = k + 1


@njit(cache=True, nogil=True, error_model="numpy")
def _record_impacts(out, info, t_imp, q, pm, pp, s, s0, lam, active):
    """One entry of every per-impact row of vcirun.record.FIELDS per contact that took an impulse
    (simultaneous impacts: one entry each, at the same time and state). The reset's multiplier s
    scales the impact law's impulses: contact i took lam_i s / s0 (one contact: s itself)."""
    for i in range(NCON):
        if active[i] == 0 or (NCON > 1 and not lam[i] > 0.0):
            continue
        k = info[I_N_IMPACTS]
        out[O_IMPACTS][k] = t_imp
        set_row(out[O_IMPACT_Q], k, q)
        set_row(out[O_IMPACT_P_MINUS], k, pm)
        set_row(out[O_IMPACT_P_PLUS], k, pp)
        out[O_IMPACT_IMPULSE][k] = s if NCON == 1 else lam[i] * (s / s0)
        out[O_IMPACT_CONTACT][k] = i
        info[I_N_IMPACTS] = k + 1


@njit(cache=True, nogil=True, error_model="numpy")
def no_modified_energy(q, p, h, prm):
    """The `modified_energy` role of methods without a modified Hamiltonian."""
    return np.nan
