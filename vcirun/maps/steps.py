# numba source unit: the full step Phi_h of a discrete Lagrangian on (q, p) (the role `full` of
# vcirun.codegen.roles) and the partial map Phi^Ld_tau of CVA and VCI.
#
# Node data (vcirun.codegen: sys_node): the tensors of a point that a step kernel needs at a node
# there. A step keeps the node data of its start point q0, so the node at q0 (C = 0) costs nothing
# per Newton iteration; Pp writes the data of its end point, which is the start point of the next
# stage of a composition (the same bits). SVC stages: 3 node evaluations instead of 7, and the work
# arrays are on the step's stack frame (vcirun.codegen.frame: no allocation, no reference count).
import numpy as np
from numba import njit

from vcirun.codegen.frame import scratch, scratch2
from vcirun.codegen.roles import (
    NDOF, BAND, NODE_LEN, FORCED, FULL_STAGES, FULL_FRACS, FORCE_A, sys_M, sys_node, sys_node_M, sys_force_jac, ld_PmJc,
    ld_Ppc, ld_Ed
)
from vcirun.maps.dynamics import velocity_from, velocity_guess
from vcirun.maps.linalg import positive_definite, solve_band, copy_into
from vcirun.maps.newton import NEWTON_CONVERGED, NEWTON_GO_ON, newton_stop


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
        if not solve_band(J, r, NDOF, BAND, 0.0):
            break
        dn = 0.0
        vn = 0.0
        for i in range(NDOF):
            v[i] -= r[i]
            dn = max(dn, abs(r[i]))
            vn = max(vn, abs(v[i]))
        stop = newton_stop(it, dn, dprev, vn, newton_tol, True)
        if stop != NEWTON_GO_ON:
            converged = stop == NEWTON_CONVERGED
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


@njit(cache=True, nogil=True, error_model="numpy")
def step_resolves_force(q, p, h, t, prm):
    """Whether a step h from (q, p) at t resolves the force's dependence on the velocity. In a stage of
    length h_s the step velocity v solves Pm(q, v, h_s) = p, whose v-Jacobian is M(q) - a h_s
    df/dqdot + O(h_s) (a: the stage's weight of f^- = a h_s f(q, v, t), FORCE_A). While the symmetric
    part of M - a h_s df/dqdot is positive definite, v follows the momentum as M^-1 does; once
    h_s |df/dqdot| reaches the mass (a force that grows with the velocity faster than the step
    resolves, e.g. f = c qdot with a h c >= m), the root of the step equation no longer describes the
    motion (one degree of freedom: v = p / (m - a h c) points against p, q stalls and p flips sign
    every step while the motion grows like exp(c t / m)). Checked at the extreme stage weights of
    the full map (the set of weights with a positive definite matrix is an interval around 0), with
    df/dqdot at the state's velocity M^-1 p. True for an unforced system."""
    if not FORCED:
        return True
    cmax = 0.0
    cmin = 0.0
    for s in range(FULL_STAGES.shape[0]):
        c = FORCE_A[FULL_STAGES[s]] * FULL_FRACS[s] * h
        cmax = max(cmax, c)
        cmin = min(cmin, c)
    v = scratch(NDOF)
    velocity_guess(q, p, prm, v)
    fq = scratch2(NDOF, NDOF)
    fv = scratch2(NDOF, NDOF)
    sys_force_jac(q, v, t, prm, fq, fv)
    M = scratch2(NDOF, NDOF)
    A = scratch2(NDOF, NDOF)
    sys_M(q, prm, M)
    for c in (cmax, cmin):
        if c == 0.0:
            continue
        for i in range(NDOF):
            for j in range(NDOF):
                A[i, j] = M[i, j] - c * fv[i, j]
        if not positive_definite(A, NDOF):
            return False
    return True
