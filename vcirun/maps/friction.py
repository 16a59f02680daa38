# numba source unit: held contacts with Coulomb friction (docs/derivations/friction.md, "Held contacts
# with friction"). Contract: vcirun.codegen.units.
#
# A held contact j (held[j] != 0) is in one of two modes:
#   held[j] == HELD_SLIP (1): it slides in the direction sgn[j] = +-1 of its slip velocity
#       v_t,j = W_j(q) qdot (W_j: the slip row, sys_slips); the friction force -mu_j lam_j sgn_j W_j^T
#       goes with its normal force lam_j G_j^T (a frictionless held contact is a slip contact with mu = 0);
#   held[j] == HELD_STICK (2): its slip row is held too, W_j qdot = 0, with a tangential force lam_t,j W_j^T
#       that Coulomb's static law bounds: |lam_t,j| <= mu_s,j lam_j.
# Per explicit stage of length hs from (q0, p0) the held step of vcirun/maps/held.py becomes (the
# forces of each contact along its "force row" D_j = G_j - mu_j sgn_j W_j for a slip contact, G_j for a
# stuck one, and W_j for a stuck contact's tangential force):
#     Pm(q0, v, hs) = p0 + sum_A D_j(q0)^T lam_j + sum_S W_j(q0)^T lt_j
#     phi_A(q0 + hs v) = 0,   W_S(q0 + hs v / 2) v = 0                          (v, lam, lt by Newton)
#     p1 = Pp(q0, v, hs) + sum_A D_j(q1)^T mu_j + sum_S W_j(q1)^T mt_j,  [G_A; W_S](q1) M(q1)^-1 p1 = 0
# so the friction impulse of a slip contact is exactly mu_j times its normal impulse over the stage, and
# with mu = 0 and no stuck contact the stage is maps/held.py's (the loop calls this unit only for
# systems with friction: FRICTION). Mode changes are events located inside the step by the caller
# (`mode_event_values` gives the functions whose sign change marks them).
import math

import numpy as np
from numba import njit

from vcirun.codegen.frame import scratch, scratch2, scratch_i
from vcirun.codegen.roles import (
    NDOF, NCON, NODE_LEN, FULL_STAGES, FULL_FRACS, sys_M, sys_phis, sys_dphis, sys_ddphis, sys_Mdotv, sys_node,
    sys_slips, sys_dslips, sys_friction, ld_PmJc, ld_Ppc, ld_Ed
)
from vcirun.maps.dynamics import dynamics_rhs, velocity_guess
from vcirun.maps.linalg import solve_small, copy_into

HELD_SLIP = 1
HELD_STICK = 2
FRICTION_OK = 0
FRICTION_SINGULAR = 1     # the held contacts' contact matrix is singular (dependent rows)
FRICTION_PAINLEVE = 2     # a slipping contact's B = G M^-1 (G - mu sgn W)^T <= 0: no or several solutions


@njit(cache=True, nogil=True, error_model="numpy")
def _held_rows(held, idx, sidx):
    """idx[:k]: the held contacts; sidx[:ks]: the stuck ones. Returns (k, ks)."""
    k = 0
    ks = 0
    for j in range(NCON):
        if held[j] != 0:
            idx[k] = j
            k += 1
            if held[j] == HELD_STICK:
                sidx[ks] = j
                ks += 1
    return k, ks


@njit(cache=True, nogil=True, error_model="numpy")
def _force_rows(G, W, held, sgn, mu, idx, k, sidx, ks, D):
    """D (k + ks rows): the force rows of the held contacts (G_j - mu_j sgn_j W_j slipping, G_j stuck),
    then the stuck contacts' slip rows W_j."""
    for a in range(k):
        j = idx[a]
        f = mu[j] * sgn[j] if held[j] == HELD_SLIP else 0.0
        for i in range(NDOF):
            D[a, i] = G[j, i] - f * W[j, i] if f != 0.0 else G[j, i]
    for b in range(ks):
        j = sidx[b]
        for i in range(NDOF):
            D[k + b, i] = W[j, i]


@njit(cache=True, nogil=True, error_model="numpy")
def _constraint_rows(G, W, idx, k, sidx, ks, C):
    """C (k + ks rows): the held contacts' normal rows G_j, then the stuck contacts' slip rows W_j."""
    for a in range(k):
        for i in range(NDOF):
            C[a, i] = G[idx[a], i]
    for b in range(ks):
        for i in range(NDOF):
            C[k + b, i] = W[sidx[b], i]


@njit(cache=True, nogil=True, error_model="numpy")
def _contact_matrix(A, C, D, r, X, K):
    """X[c] = M^-1 D_c^T (A = M, kept) and K[a, c] = C_a . X[c]: the contact matrix C M^-1 D^T of the r
    rows (symmetric without slipping contacts). Returns False if M is singular."""
    B = scratch2(NDOF, NDOF)
    for c in range(r):
        for i in range(NDOF):
            X[c, i] = D[c, i]
            for l in range(NDOF):
                B[i, l] = A[i, l]
        if not solve_small(B, X[c], NDOF):
            return False
    for a in range(r):
        for c in range(r):
            s = 0.0
            for i in range(NDOF):
                s += C[a, i] * X[c, i]
            K[a, c] = s
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def friction_project(q, p, prm, held, sgn, lam, lt):
    """p <- p + sum_A D_j^T lam_j + sum_S W_j^T lt_j with [G_A; W_S] M^-1 p = 0 after: the held contacts'
    normal velocities and the stuck contacts' slip velocities zeroed, a slipping contact's normal
    impulse carrying its friction impulse. lam, lt (NCON) receive the impulses (0 elsewhere).
    Returns False if the contact matrix or M is singular."""
    idx = scratch_i(NCON)
    sidx = scratch_i(NCON)
    for j in range(NCON):
        lam[j] = 0.0
        lt[j] = 0.0
    k, ks = _held_rows(held, idx, sidx)
    r = k + ks
    if r == 0:
        return True
    mu = scratch(NCON)
    mus = scratch(NCON)
    sys_friction(prm, mu, mus)
    G = scratch2(NCON, NDOF)
    W = scratch2(NCON, NDOF)
    sys_dphis(q, prm, G)
    sys_slips(q, prm, W)
    A = scratch2(NDOF, NDOF)
    sys_M(q, prm, A)
    C = scratch2(2 * NCON, NDOF)
    D = scratch2(2 * NCON, NDOF)
    _constraint_rows(G, W, idx, k, sidx, ks, C)
    _force_rows(G, W, held, sgn, mu, idx, k, sidx, ks, D)
    X = scratch2(2 * NCON, NDOF)
    K = scratch2(2 * NCON, 2 * NCON)
    if not _contact_matrix(A, C, D, r, X, K):
        return False
    x = scratch(NDOF)
    copy_into(x, p)
    B = scratch2(NDOF, NDOF)
    for i in range(NDOF):
        for l in range(NDOF):
            B[i, l] = A[i, l]
    if not solve_small(B, x, NDOF):
        return False
    y = scratch(2 * NCON)
    for a in range(r):
        s = 0.0
        for i in range(NDOF):
            s += C[a, i] * x[i]
        y[a] = -s
    if not solve_small(K[:r, :r], y[:r], r):
        return False
    for c in range(r):
        for i in range(NDOF):
            p[i] += y[c] * D[c, i]
    for a in range(k):
        lam[idx[a]] = y[a]
    for b in range(ks):
        lt[sidx[b]] = y[k + b]
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def friction_stage(sid, q0, p0, hs, t, prm, ntol, maxit, held, sgn, v, q1, p1, imp, impt, work):
    """One explicit stage of the held step with friction (the unit's header); v: Newton's start on
    entry, the step velocity on exit; imp[j] += the normal impulse of held contact j, impt[j] += its
    tangential (friction) impulse; work[0] += the work of the friction forces over the stage (<= 0),
    the friction impulses against the stage's mean slip velocity W_j(q0 + hs v / 2) v. Returns Newton
    iterations (< 0 on failure). The stuck rows' Jacobian omits the O(hs) term of dW/dq: the residual
    is exact, Newton contracts by O(hs) there (the stopping rule watches the contraction)."""
    idx = scratch_i(NCON)
    sidx = scratch_i(NCON)
    k, ks = _held_rows(held, idx, sidx)
    m = NDOF + k + ks
    mu = scratch(NCON)
    mus = scratch(NCON)
    sys_friction(prm, mu, mus)
    x = scratch(NDOF + 2 * NCON)
    for j in range(m):
        x[j] = v[j] if j < NDOF else 0.0
    c = scratch(NODE_LEN)
    cn = scratch(NODE_LEN)
    sys_node(q0, prm, c)
    r = scratch(NDOF)
    J = scratch2(NDOF, NDOF)
    G0 = scratch2(NCON, NDOF)
    W0 = scratch2(NCON, NDOF)
    G1 = scratch2(NCON, NDOF)
    Wm = scratch2(NCON, NDOF)
    D0 = scratch2(2 * NCON, NDOF)
    phis = scratch(NCON)
    sys_dphis(q0, prm, G0)
    sys_slips(q0, prm, W0)
    _force_rows(G0, W0, held, sgn, mu, idx, k, sidx, ks, D0)
    F = scratch(NDOF + 2 * NCON)
    JJ = scratch2(NDOF + 2 * NCON, NDOF + 2 * NCON)
    qn = scratch(NDOF)
    qm = scratch(NDOF)
    it = 0
    ok = False
    dprev = np.inf
    while it < maxit:
        it += 1
        ld_PmJc(sid, q0, x[:NDOF], hs, t, prm, c, r, J)
        for j in range(NDOF):
            qn[j] = q0[j] + hs * x[j]
            qm[j] = q0[j] + 0.5 * hs * x[j]
        sys_phis(qn, prm, phis)
        sys_dphis(qn, prm, G1)
        if ks > 0:
            sys_slips(qm, prm, Wm)
        for i in range(NDOF):
            s = r[i] - p0[i]
            for a in range(k + ks):
                s -= D0[a, i] * x[NDOF + a]
            F[i] = s
            for j in range(NDOF):
                JJ[i, j] = J[i, j]
            for a in range(k + ks):
                JJ[i, NDOF + a] = -D0[a, i]
        for a in range(k):
            j = idx[a]
            if hs != 0.0:
                F[NDOF + a] = phis[j] / hs
            else:
                s = 0.0
                for l in range(NDOF):
                    s += G0[j, l] * x[l]
                F[NDOF + a] = s
            for l in range(NDOF):
                JJ[NDOF + a, l] = G1[j, l]
            for b in range(k + ks):
                JJ[NDOF + a, NDOF + b] = 0.0
        for b in range(ks):
            j = sidx[b]
            s = 0.0
            for l in range(NDOF):
                s += Wm[j, l] * x[l]
                JJ[NDOF + k + b, l] = Wm[j, l]
            F[NDOF + k + b] = s
            for a in range(k + ks):
                JJ[NDOF + k + b, NDOF + a] = 0.0
        if not solve_small(JJ[:m, :m], F[:m], m):
            break
        dn = 0.0
        xn = 0.0
        for j in range(m):
            x[j] -= F[j]
            dn = max(dn, abs(F[j]))
            xn = max(xn, abs(x[j]))
        if not math.isfinite(dn):
            break
        if dn <= ntol * (1.0 + xn):
            ok = True
            break
        theta = dn / dprev
        if it >= 2 and theta < 0.1 and theta / (1.0 - theta) * dn <= ntol * (1.0 + xn):
            ok = True
            break
        if it >= 3 and dn >= dprev and dn <= math.sqrt(ntol) * (1.0 + xn):  # round-off floor
            ok = True
            break
        dprev = dn
    for j in range(NDOF):
        v[j] = x[j]
        q1[j] = q0[j] + hs * x[j]
        qm[j] = q0[j] + 0.5 * hs * x[j]
    ld_Ppc(sid, q0, x[:NDOF], hs, t, prm, c, p1, cn)
    pi = scratch(NCON)
    pt = scratch(NCON)
    if not friction_project(q1, p1, prm, held, sgn, pi, pt):
        return -it
    sys_slips(qm, prm, Wm)
    for a in range(k):
        j = idx[a]
        ln = x[NDOF + a] + pi[j]
        imp[j] += ln
        if held[j] == HELD_SLIP and mu[j] != 0.0:
            ft = -mu[j] * sgn[j] * ln
            impt[j] += ft
            s = 0.0
            for l in range(NDOF):
                s += Wm[j, l] * x[l]
            work[0] += ft * s
    for b in range(ks):
        impt[sidx[b]] += x[NDOF + k + b] + pt[sidx[b]]
    return it if ok else -it


@njit(cache=True, nogil=True, error_model="numpy")
def friction_step(q0, p0, h, t, prm, ntol, maxit, held, sgn, q1, p1, vlast, imp, impt, work):
    """The held step with friction over h (the scene's Ld's explicit stages in turn, each a
    friction_stage) from (q0, p0): imp, impt (NCON) receive the normal and tangential impulses, work[0]
    the friction work (both reset here). Returns (iterations, < 0 on failure; discrete energy of the
    stages)."""
    for j in range(NCON):
        imp[j] = 0.0
        impt[j] = 0.0
    work[0] = 0.0
    v = scratch(NDOF)
    velocity_guess(q0, p0, prm, v)
    qa = scratch(NDOF)
    pa = scratch(NDOF)
    copy_into(qa, q0)
    copy_into(pa, p0)
    total = 0
    Ed = 0.0
    ts = t
    for s in range(FULL_STAGES.shape[0]):
        hs = FULL_FRACS[s] * h
        if s > 0:
            velocity_guess(qa, pa, prm, v)
        it = friction_stage(FULL_STAGES[s], qa, pa, hs, ts, prm, ntol, maxit, held, sgn, v, q1, p1, imp, impt, work)
        if it < 0:
            return it - total, np.nan
        total += it
        Ed += FULL_FRACS[s] * ld_Ed(FULL_STAGES[s], qa, v, hs, prm)
        ts += hs
        copy_into(qa, q1)
        copy_into(pa, p1)
    copy_into(vlast, v)
    return total, Ed


@njit(cache=True, nogil=True, error_model="numpy")
def friction_forces(q, p, t, prm, held, sgn, lam, lt):
    """The held contacts' forces in the continuous motion through (q, p) at t with their modes:
    M qddot = F - Mdot v + sum_A D_j^T lam_j + sum_S W_j^T lt_j, F = -dH/dq + f, v = M^-1 p, from
    d^2 phi_A / dt^2 = 0 and d/dt (W_S v) = 0:
        C M^-1 D^T (lam, lt) = -(C M^-1 (F - Mdot v) + (v^T Hess phi_j v)_A, (v^T dW_j/dq v)_S).
    lam_j > 0 compresses; a slipping contact's lt_j = -mu_j sgn_j lam_j, a stuck one's its tangential
    force. Returns FRICTION_OK, FRICTION_SINGULAR or FRICTION_PAINLEVE (a slipping contact's own
    coefficient B_j = (C M^-1 D^T)_jj <= 0: Painleve's case, no or several solutions)."""
    idx = scratch_i(NCON)
    sidx = scratch_i(NCON)
    for j in range(NCON):
        lam[j] = 0.0
        lt[j] = 0.0
    k, ks = _held_rows(held, idx, sidx)
    r = k + ks
    if r == 0:
        return FRICTION_OK
    mu = scratch(NCON)
    mus = scratch(NCON)
    sys_friction(prm, mu, mus)
    y = scratch(2 * NDOF)
    f = scratch(2 * NDOF)
    for j in range(NDOF):
        y[j] = q[j]
        y[NDOF + j] = p[j]
    dynamics_rhs(t, y, prm, f)          # f[:n] = v, f[n:] = F
    v = scratch(NDOF)
    mdv = scratch(NDOF)
    for j in range(NDOF):
        v[j] = f[j]
    sys_Mdotv(q, v, prm, mdv)
    w = scratch(NDOF)
    for j in range(NDOF):
        w[j] = f[NDOF + j] - mdv[j]
    dd = scratch(NCON)
    ds = scratch(NCON)
    sys_ddphis(q, v, prm, dd)
    sys_dslips(q, v, prm, ds)
    G = scratch2(NCON, NDOF)
    W = scratch2(NCON, NDOF)
    sys_dphis(q, prm, G)
    sys_slips(q, prm, W)
    A = scratch2(NDOF, NDOF)
    sys_M(q, prm, A)
    C = scratch2(2 * NCON, NDOF)
    D = scratch2(2 * NCON, NDOF)
    _constraint_rows(G, W, idx, k, sidx, ks, C)
    _force_rows(G, W, held, sgn, mu, idx, k, sidx, ks, D)
    X = scratch2(2 * NCON, NDOF)
    K = scratch2(2 * NCON, 2 * NCON)
    if not _contact_matrix(A, C, D, r, X, K):
        return FRICTION_SINGULAR
    for a in range(k):
        if held[idx[a]] == HELD_SLIP and not K[a, a] > 0.0:
            return FRICTION_PAINLEVE
    B = scratch2(NDOF, NDOF)
    for i in range(NDOF):
        for l in range(NDOF):
            B[i, l] = A[i, l]
    if not solve_small(B, w, NDOF):
        return FRICTION_SINGULAR
    b = scratch(2 * NCON)
    for a in range(r):
        s = dd[idx[a]] if a < k else ds[sidx[a - k]]
        for i in range(NDOF):
            s += C[a, i] * w[i]
        b[a] = -s
    if not solve_small(K[:r, :r], b[:r], r):
        return FRICTION_SINGULAR
    for a in range(k):
        j = idx[a]
        lam[j] = b[a]
        if held[j] == HELD_SLIP:
            lt[j] = -mu[j] * sgn[j] * b[a]
    for c in range(ks):
        lt[sidx[c]] = b[k + c]
    return FRICTION_OK


@njit(cache=True, nogil=True, error_model="numpy")
def slip_velocities(q, p, prm, vt):
    """vt_j = W_j(q) M(q)^-1 p: every contact's slip velocity."""
    v = scratch(NDOF)
    velocity_guess(q, p, prm, v)
    W = scratch2(NCON, NDOF)
    sys_slips(q, prm, W)
    for j in range(NCON):
        s = 0.0
        for i in range(NDOF):
            s += W[j, i] * v[i]
        vt[j] = s


@njit(cache=True, nogil=True, error_model="numpy")
def mode_event_values(q, p, t, prm, held, sgn, ev):
    """ev_j: positive while held contact j keeps its mode, its sign change the mode's end: sgn_j v_t,j
    for a slipping contact with friction (slip stops: stick or reversal), mu_s,j lam_j - |lt_j| for a
    stuck one (stick ends: slip); +inf for the others (free, or slipping without friction). The normal
    force lam_j (release at 0) is the caller's (friction_forces). Returns friction_forces' code."""
    lam = scratch(NCON)
    lt = scratch(NCON)
    code = friction_forces(q, p, t, prm, held, sgn, lam, lt)
    mu = scratch(NCON)
    mus = scratch(NCON)
    sys_friction(prm, mu, mus)
    vt = scratch(NCON)
    slip_velocities(q, p, prm, vt)
    for j in range(NCON):
        ev[j] = np.inf
        if held[j] == HELD_SLIP and mu[j] > 0.0:
            ev[j] = sgn[j] * vt[j]
        elif held[j] == HELD_STICK:
            ev[j] = mus[j] * lam[j] - abs(lt[j])
    return code


@njit(cache=True, nogil=True, error_model="numpy")
def choose_mode(q, p, t, prm, held, sgn, j, vtol):
    """The mode of held contact j at (q, p) (it touches and is pressed in): stuck if its slip velocity
    is within vtol of 0 and Coulomb's static bound holds with it stuck (|lt_j| <= mu_s,j lam_j), else
    slipping in the direction of its slip velocity, or, from rest, in the direction its stuck
    tangential force would have to exceed (sgn_j = -sign(lt_j)). Sets held[j], sgn[j]; returns
    friction_forces' code of the chosen mode."""
    mu = scratch(NCON)
    mus = scratch(NCON)
    sys_friction(prm, mu, mus)
    vt = scratch(NCON)
    slip_velocities(q, p, prm, vt)
    lam = scratch(NCON)
    lt = scratch(NCON)
    if not mu[j] > 0.0 and not mus[j] > 0.0:
        held[j] = HELD_SLIP
        sgn[j] = 1.0
        return friction_forces(q, p, t, prm, held, sgn, lam, lt)
    if abs(vt[j]) > vtol:
        held[j] = HELD_SLIP
        sgn[j] = 1.0 if vt[j] > 0.0 else -1.0
        return friction_forces(q, p, t, prm, held, sgn, lam, lt)
    held[j] = HELD_STICK
    code = friction_forces(q, p, t, prm, held, sgn, lam, lt)
    if code == FRICTION_OK and abs(lt[j]) <= mus[j] * lam[j]:
        return code
    held[j] = HELD_SLIP
    sgn[j] = -1.0 if lt[j] > 0.0 else 1.0
    return friction_forces(q, p, t, prm, held, sgn, lam, lt)
