# numba source unit: Algorithm 1 (event-driven collision integration), compiled as a whole so the
# event loop itself runs native. It knows only `full`, `partial`, `reset` (and the scene's phi, H and
# the optional modified energy); which method it runs is decided by what the module binds to them.
import math

import numpy as np
from numba import njit

ST_OK = 0
ST_NEWTON = 1
ST_EVENT = 2
ST_RESET = 3
ST_ACCUMULATION = 4
ST_NONFINITE = 5


@njit(cache=True, nogil=True, error_model="numpy")
def _finite(x):
    for i in range(x.shape[0]):
        if not math.isfinite(x[i]):
            return False
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def integrate(q0, p0, t0, h, N, prm, constrained, ntol, maxit, event_tol, max_impacts_step,
              Q, P, Hs, Eds, Hm, imp_t, imp_q, imp_pm, imp_pp, imp_step, partial_log, iters_log, info,
              energies=True):
    """Run N grid steps of Algorithm 1 from (q0, p0) at t0. Output arrays are preallocated by the
    caller; info receives [status, fail_step, n_impacts, n_partial, steps_done]. energies=False
    skips H, the discrete energy Ed and the modified energy along the grid (set at t0 only): a run
    that only needs the trajectory saves their per-step cost."""
    q = q0.copy()
    p = p0.copy()
    qt = np.empty(NDOF)
    pt = np.empty(NDOF)
    vt = np.empty(NDOF)
    qh = np.empty(NDOF)
    ph = np.empty(NDOF)
    pp = np.empty(NDOF)
    set_row(Q, 0, q)
    set_row(P, 0, p)
    n_imp = 0
    n_par = 0
    status = ST_OK
    fail = -1
    cap_imp = imp_t.shape[0]
    cap_par = partial_log.shape[0]
    # (issue 8) accumulation across steps: `dense` counts consecutive impacts that each follow the
    # previous one by less than one grid step h (impacts denser than the grid), since t_dense0. If
    # such a run lasts longer than max_impacts_step steps it is reported as ST_ACCUMULATION, like
    # more than max_impacts_step impacts inside one step: a motion settling into contact stops in
    # bounded work even when no single step reaches the per-step cap (a short chatter burst does
    # not). vcirun.api reads the onset (t_dense0) off the recorded impact times.
    t_prev_imp = -math.inf
    t_dense0 = 0.0
    dense = 0
    i = 0
    while i < N:
        t = t0 + i * h
        it, Ed = full(q, p, h, t, prm, ntol, maxit, qt, pt, vt, energies or i == 0)
        if energies or i == 0:
            Hs[i] = hamiltonian(q, p, prm)
            Hm[i] = modified_energy(q, p, h, prm)
        Eds[i] = Ed
        if it < 0:
            status = ST_NEWTON
            fail = i
            break
        iters = it
        if (not constrained) or sys_phi(qt, prm) > 0.0:
            copy_into(q, qt)
            copy_into(p, pt)
        else:
            imp_step[i] = True
            copy_into(qh, q)
            copy_into(ph, p)
            tau_max = h
            tc = t
            k_imp = 0
            # (qt, pt) hold the full step from (qh, ph): when the partial map is the full map the
            # search starts from it instead of recomputing it
            have_end = PARTIAL_IS_FULL
            while tau_max > 0.0:
                code, dtau, Epre, itc = search_collision(qh, ph, tau_max, h, tc, prm, ntol, maxit, event_tol,
                                                         qt, pt, vt, have_end)
                have_end = False
                iters += itc
                if code < 0:
                    status = ST_NEWTON if code == -1 else ST_EVENT
                    break
                if n_par < cap_par:
                    partial_log[n_par] = dtau
                    n_par += 1
                tau_rem = tau_max - dtau
                if code == 1:
                    itr, lam = reset(qt, pt, Epre, vt, dtau, tau_rem, h, tc + dtau, prm, ntol, maxit, pp)
                    iters += abs(itr)
                    if itr < 0:
                        status = ST_RESET
                        break
                    k_imp += 1
                    if tc + dtau - t_prev_imp < h:
                        if dense == 0:
                            t_dense0 = t_prev_imp
                        dense += 1
                    else:
                        dense = 0
                    t_prev_imp = tc + dtau
                    if (n_imp >= cap_imp or k_imp > max_impacts_step
                            or (dense > 0 and t_prev_imp - t_dense0 > max_impacts_step * h)):
                        status = ST_ACCUMULATION
                        break
                    imp_t[n_imp] = tc + dtau
                    set_row(imp_q, n_imp, qt)
                    set_row(imp_pm, n_imp, pt)
                    set_row(imp_pp, n_imp, pp)
                    n_imp += 1
                    copy_into(qh, qt)
                    copy_into(ph, pp)
                    tau_max = tau_rem
                    tc += dtau
                else:
                    copy_into(qh, qt)
                    copy_into(ph, pt)
                    tau_max = 0.0
            if status != ST_OK:
                fail = i
                break
            copy_into(q, qh)
            copy_into(p, ph)
        if not (_finite(q) and _finite(p)):
            status = ST_NONFINITE
            fail = i
            break
        iters_log[i] = iters
        set_row(Q, i + 1, q)
        set_row(P, i + 1, p)
        i += 1
    steps = i
    if status == ST_OK and energies:
        # energies at the last grid state (its discrete energy from one more trial step)
        it, Ed = full(q, p, h, t0 + N * h, prm, ntol, maxit, qt, pt, vt)
        Hs[N] = hamiltonian(q, p, prm)
        Eds[N] = Ed
        Hm[N] = modified_energy(q, p, h, prm)
    info[0] = status
    info[1] = fail
    info[2] = n_imp
    info[3] = n_par
    info[4] = steps
    return status
