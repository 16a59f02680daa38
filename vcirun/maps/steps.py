# numba source unit: the full step Phi_h of a discrete Lagrangian on (q, p) (the role `full` of
# vcirun.codegen.roles) and the partial map Phi^Ld_tau of CVA and VCI.
#
# Node data (vcirun.codegen: sys_node): the tensors of a point that a step kernel needs at a node
# there. A step keeps the node data of its start point q0, so the node at q0 (C = 0) costs nothing
# per Newton iteration; Pp writes the data of its end point, which is the start point of the next
# stage of a composition (the same bits). SVC stages: 3 node evaluations instead of 7, and the work
# arrays are on the step's stack frame (vcirun.codegen.frame: no allocation, no reference count).
import math

import numpy as np
from numba import njit

from vcirun.codegen.frame import scratch, scratch2
from vcirun.codegen.roles import NDOF, BAND, NODE_LEN, FULL_STAGES, FULL_FRACS, sys_node, sys_node_M, ld_PmJc, ld_Ppc, ld_Ed
from vcirun.maps.dynamics import velocity_from
from vcirun.maps.linalg import solve_band, copy_into


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def guess_from_node(c, p, v, A):
    """v = M(q)^{-1} p with M(q) from the node data c of q (A: n x n scratch, overwritten)."""
    sys_node_M(c, A)
    velocity_from(A, p, v)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def explicit_step(sid, q0, p0, h, t, prm, newton_tol, max_iter, v, q1, p1, c, cn, r, J):
    """One step of explicit discrete Lagrangian `sid`: solve Pm(q0, v, h) = p0 for the step velocity v
    (v holds the initial guess on entry) by Newton with the analytic Jacobian, then q1 = q0 + h v,
    p1 = Pp(q0, v, h). c holds the node data of q0 (sys_node), cn receives that of q1; r (n) and
    J (n x n) are work arrays. Returns the number of iterations, or -iterations if Newton did not
    converge."""
    it = 0
    converged = False
    dprev = np.inf
    while it < max_iter:
        it += 1
        ld_PmJc(sid, q0, v, h, t, prm, c, r, J)
        for i in range(NDOF):
            r[i] -= p0[i]
        if not solve_band(J, r, NDOF, BAND):
            break
        dn = 0.0
        vn = 0.0
        for i in range(NDOF):
            v[i] -= r[i]
            dn = max(dn, abs(r[i]))
            vn = max(vn, abs(v[i]))
        if not math.isfinite(dn):
            break
        if dn <= newton_tol * (1.0 + vn):
            converged = True
            break
        # Quadratic phase (exact Jacobian): with contraction theta = dn / dprev, the error left after
        # this correction is at most theta / (1 - theta) * dn (the bound under mere linear
        # convergence, so it is conservative; Hairer & Wanner's stopping rule for simplified
        # Newton). Once it is below newton_tol the next iteration could only confirm it: stopping
        # saves it (a third of a smooth step). The step then honours newton_tol, not round-off: the
        # map carries noise up to ~newton_tol relative (measured: symplecticity defect and orders
        # unchanged; a grid point exactly on phi = 0 needs a wider search, see
        # vcirun.experiments.studies.contact.boundary_start).
        theta = dn / dprev  # (dprev = inf on the first iteration: no rate known, theta = 0 ignored)
        if it >= 2 and theta < 0.1 and theta / (1.0 - theta) * dn <= newton_tol * (1.0 + vn):
            converged = True
            break
        # Round-off floor: past the quadratic phase (it >= 3) a correction that no longer decreases,
        # yet is below sqrt(newton_tol) relative, is rounding noise. With an ill-conditioned
        # Jacobian (nearly singular M, cond ~ 1e4 and up) that floor lies above newton_tol, and
        # without this test Newton cycles between two neighbouring floats until max_iter and reports
        # newton_failed on a regular step (double pendulum with m1 = 1e-4, cart-pendulum with
        # m2/m1 = 1e4).
        if it >= 3 and dn >= dprev and dn <= math.sqrt(newton_tol) * (1.0 + vn):
            converged = True
            break
        dprev = dn
    for i in range(NDOF):
        q1[i] = q0[i] + h * v[i]
    ld_Ppc(sid, q0, v, h, t, prm, c, p1, cn)
    return it if converged else -it


@njit(cache=True, nogil=True, error_model="numpy")
def ld_step(q0, p0, h, t, prm, ntol, maxit, q1, p1, vlast, want_E=True):
    """Phi_h of the scene's discrete Lagrangian (a composition of explicit stages, e.g. SVA =
    SE1 then SE2 half steps). Returns (iterations >= 0, or < 0 on failure, discrete energy -D3 Ld;
    NaN with want_E=False, which saves one kernel call per stage: 17 per SVC8 step).
    vlast receives the last stage's step velocity."""
    v = scratch(NDOF)
    c = scratch(NODE_LEN)
    cn = scratch(NODE_LEN)
    r = scratch(NDOF)
    J = scratch2(NDOF, NDOF)
    sys_node(q0, prm, c)
    guess_from_node(c, p0, v, J)  # (J as scratch: PmJc overwrites it)
    if FULL_STAGES.shape[0] == 1:  # explicit Ld: no intermediate nodes to copy
        it = explicit_step(FULL_STAGES[0], q0, p0, h, t, prm, ntol, maxit, v, q1, p1, c, cn, r, J)
        copy_into(vlast, v)
        if it < 0 or not want_E:
            return it, np.nan
        return it, ld_Ed(FULL_STAGES[0], q0, v, h, prm)
    qa = scratch(NDOF)
    pa = scratch(NDOF)
    copy_into(qa, q0)
    copy_into(pa, p0)
    vprev = scratch(NDOF)
    total = 0
    Ed = 0.0
    ts = t
    hprev = 0.0
    for s in range(FULL_STAGES.shape[0]):
        hs = FULL_FRACS[s] * h
        if s > 0:
            guess_from_node(c, pa, v, J)
            if hprev != 0.0:
                # The stage's mean velocity is ~ qdot(t_s + hs / 2). v = M^-1 p is qdot at the stage
                # start and the previous stage's mean velocity is qdot half a previous stage back, so
                # v + hs / hprev (v - vprev) is a second-order guess (any sign of hs, hprev): about one
                # Newton iteration less per stage of a many-stage composition (SVC6: 9 stages).
                rr = hs / hprev
                for i in range(NDOF):
                    v[i] += rr * (v[i] - vprev[i])
        it = explicit_step(FULL_STAGES[s], qa, pa, hs, ts, prm, ntol, maxit, v, q1, p1, c, cn, r, J)
        copy_into(vprev, v)
        hprev = hs
        if it < 0:
            return it - total, np.nan
        total += it
        # D3 of a composition: sum of fraction * D3 of the stages (interior nodes are stationary)
        if want_E:
            Ed += FULL_FRACS[s] * ld_Ed(FULL_STAGES[s], qa, v, hs, prm)
        else:
            Ed = np.nan
        ts += hs
        copy_into(qa, q1)
        copy_into(pa, p1)
        c, cn = cn, c  # the end point's node data is the next stage's start
    copy_into(vlast, v)
    return total, Ed


@njit(cache=True, nogil=True, error_model="numpy")
def ld_partial(q0, p0, tau, h, t, prm, ntol, maxit, q1, p1, vlast):
    """Phi^partial = Phi^full_tau (CVA, VCI): the same discrete Lagrangian at step tau."""
    return ld_step(q0, p0, tau, t, prm, ntol, maxit, q1, p1, vlast, np.bool_(True))
