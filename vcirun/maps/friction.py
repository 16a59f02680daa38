# numba source unit: held contacts with Coulomb friction (docs/derivations/friction.md, "Held contacts
# with friction"). Contract: vcirun.codegen.units.
#
# A held contact j (held[j] != 0) is in one of two modes:
#   held[j] == +1 or -1 (slip): it slides in the direction s_j = held[j] of its slip velocity
#       v_t,j = W_j(q) qdot (W_j: the slip row, sys_slips); the friction force -mu_j lam_j s_j W_j^T goes
#       with its normal force lam_j G_j^T (a frictionless held contact is a slip contact with mu = 0,
#       held[j] = 1: every frictionless rule of the loop reads held[j] != 0 as held);
#   held[j] == HELD_STICK (2): its slip row is held too, W_j qdot = 0, with a tangential force lt_j W_j^T
#       that Coulomb's static law bounds: |lt_j| <= mu_s,j lam_j.
# Per explicit stage of length hs from (q0, p0) the held step of vcirun/maps/held.py becomes (the
# force row D_j = G_j - mu_j s_j W_j of a slipping contact, G_j of a stuck one):
#     Pm(q0, v, hs) = p0 + sum_A D_j(q0)^T lam_j + sum_S W_j(q0)^T lt_j
#     phi_A(q0 + hs v) = 0,   W_S(q0 + hs v / 2) v = 0                          (v, lam, lt by Newton)
#     p1 = Pp(q0, v, hs) + sum_A D_j(q1)^T mu_j + sum_S W_j(q1)^T mt_j,  [G_A; W_S](q1) M(q1)^-1 p1 = 0
# The friction impulse of a slip contact is exactly mu_j times its normal impulse over the stage.
#
# Stuck contacts whose slip rows depend on the others' rows (a block standing on two corners: both
# corners slide together) are statically indeterminate: only the independent rows are held (the
# others' slip velocities vanish with them), chosen by a pivoted Cholesky factorisation of
# C M^-1 C^T in contact order, and the tangential force of each dependent contact's group (the
# independent contact whose row is most parallel to its own, in the M^-1 metric) is shared in
# proportion to the members' bounds mu_s lam: the one split under which the group sticks exactly
# when its total fits the sum of their bounds.
import math

import numpy as np
from numba import njit

from vcirun.codegen.frame import scratch, scratch2, scratch_i
from vcirun.codegen.roles import (
    NDOF, NCON, NODE_LEN, sys_M, sys_phis, sys_dphis, sys_ddphis, sys_Mdotv, sys_node,
    sys_slips, sys_dslips, sys_friction, ld_PmJc, ld_Ppc
)
from vcirun.maps.dynamics import dynamics_rhs, velocity_guess
from vcirun.maps.linalg import solve_small, copy_into, STACK_DOUBLES
from vcirun.maps.newton import NEWTON_CONVERGED, NEWTON_GO_ON, newton_stop

HELD_STICK = 2
REST_REVERSED = -2       # assign_modes' `rest` for a grid state whose slips reversed unlocated (see there)
FRICTION_OK = 0
FRICTION_SINGULAR = 1     # the held contacts' contact matrix is singular (dependent normal rows)
FRICTION_PAINLEVE = 2     # a slipping contact's B = G M^-1 (G - mu s W)^T <= 0: no or several solutions
DEPENDENT_TOL = 1e-10     # a stuck row whose Cholesky pivot is below this times its norm^2 depends on the others


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def slipping(mode):
    """A held contact in the slip mode (held[j] = +1 or -1, its direction)."""
    return mode == 1 or mode == -1


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _minv_rows(A, R, r, X):
    """X[c] = M^-1 R[c] for the first r rows (A = M, kept). Returns False if M is singular."""
    B = scratch2(NDOF, NDOF)
    for c in range(r):
        for i in range(NDOF):
            X[c, i] = R[c, i]
            for l in range(NDOF):
                B[i, l] = A[i, l]
        if not solve_small(B, X[c], NDOF):
            return False
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def contact_rows(q, prm, held, A, G, W, idx, sidx, lead):
    """The rows of the held contacts at q (A = M(q), G = grad phi, W = the slip rows, all filled here):
    idx[:k] the held contacts, sidx[:ks] the stuck ones whose slip rows are independent of the held
    normal rows and of the stuck rows before them (pivoted Cholesky of C M^-1 C^T), lead[j] for every
    stuck contact j the independent stuck contact whose tangential force it shares (itself when
    independent; -1 if none: a stuck row dependent on the normal rows alone, which W qdot = 0 then
    holds already). Returns (k, ks); k = -1 if M is singular."""
    sys_M(q, prm, A)
    sys_dphis(q, prm, G)
    sys_slips(q, prm, W)
    k = 0
    nst = 0
    for j in range(NCON):
        lead[j] = -1
        if held[j] != 0:
            idx[k] = j
            k += 1
            if held[j] == HELD_STICK:
                nst += 1
    if nst == 0:
        return k, 0
    r = k + nst
    R = scratch2(2 * NCON, NDOF)
    X = scratch2(2 * NCON, NDOF)
    owner = scratch_i(2 * NCON)
    for a in range(k):
        owner[a] = idx[a]
        for i in range(NDOF):
            R[a, i] = G[idx[a], i]
    b = k
    for j in range(NCON):
        if held[j] == HELD_STICK:
            owner[b] = j
            for i in range(NDOF):
                R[b, i] = W[j, i]
            b += 1
    if not _minv_rows(A, R, r, X):
        return -1, 0
    # pivoted (in order) Cholesky of K = R M^-1 R^T: L (r x r), a row with a vanishing pivot is skipped
    L = scratch2(r, r) if r * r <= STACK_DOUBLES else np.empty((r, r))
    keep = scratch_i(2 * NCON)
    for a in range(r):
        keep[a] = 0
        d = 0.0
        for i in range(NDOF):
            d += R[a, i] * X[a, i]
        s = d
        for c in range(a):
            if keep[c] != 0:
                s -= L[a, c] * L[a, c]
        if s > DEPENDENT_TOL * d and d > 0.0:
            keep[a] = 1
            L[a, a] = math.sqrt(s)
            for e in range(a + 1, r):
                kk = 0.0
                for i in range(NDOF):
                    kk += R[e, i] * X[a, i]
                for c in range(a):
                    if keep[c] != 0:
                        kk -= L[e, c] * L[a, c]
                L[e, a] = kk / L[a, a]
        else:
            for e in range(a + 1, r):
                L[e, a] = 0.0
    ks = 0
    for a in range(k, r):
        if keep[a] != 0:
            sidx[ks] = owner[a]
            lead[owner[a]] = owner[a]
            ks += 1
    # a dependent stuck row joins the independent stuck row most parallel to it in the M^-1 metric
    for a in range(k, r):
        if keep[a] != 0:
            continue
        best = 0.0
        for c in range(k, r):
            if keep[c] == 0:
                continue
            num = 0.0
            na = 0.0
            nc = 0.0
            for i in range(NDOF):
                num += R[a, i] * X[c, i]
                na += R[a, i] * X[a, i]
                nc += R[c, i] * X[c, i]
            cos = abs(num) / math.sqrt(na * nc) if na > 0.0 and nc > 0.0 else 0.0
            if cos > best:
                best = cos
                lead[owner[a]] = owner[c]
    return k, ks


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _force_rows(G, W, held, mu, idx, k, sidx, ks, D):
    """D (k + ks rows): the force rows of the held contacts (G_j - mu_j s_j W_j slipping, G_j stuck),
    then the independent stuck contacts' slip rows W_j."""
    for a in range(k):
        j = idx[a]
        f = mu[j] * held[j] if slipping(held[j]) else 0.0
        for i in range(NDOF):
            D[a, i] = G[j, i] - f * W[j, i] if f != 0.0 else G[j, i]
    for b in range(ks):
        j = sidx[b]
        for i in range(NDOF):
            D[k + b, i] = W[j, i]


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _constraint_rows(G, W, idx, k, sidx, ks, C):
    """C (k + ks rows): the held contacts' normal rows G_j, then the independent stuck slip rows W_j."""
    for a in range(k):
        for i in range(NDOF):
            C[a, i] = G[idx[a], i]
    for b in range(ks):
        for i in range(NDOF):
            C[k + b, i] = W[sidx[b], i]


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _contact_matrix(A, C, D, r, X, K):
    """X[c] = M^-1 D_c^T (A = M, kept) and K[a, c] = C_a . X[c]: the contact matrix C M^-1 D^T of the r
    rows (symmetric without slipping contacts). Returns False if M is singular."""
    if not _minv_rows(A, D, r, X):
        return False
    for a in range(r):
        for c in range(r):
            s = 0.0
            for i in range(NDOF):
                s += C[a, i] * X[c, i]
            K[a, c] = s
    return True


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _share(held, lead, lam, mus, lt):
    """The tangential forces (or impulses) lt of the independent stuck contacts shared within their
    groups in proportion to mu_s lam (equal shares where those vanish)."""
    for j in range(NCON):
        if held[j] != HELD_STICK or lead[j] != j:
            continue
        tot = 0.0
        cnt = 0
        for i in range(NCON):
            if held[i] == HELD_STICK and lead[i] == j:
                tot += mus[i] * max(lam[i], 0.0)
                cnt += 1
        if cnt < 2:
            continue
        T = lt[j]
        for i in range(NCON):
            if held[i] == HELD_STICK and lead[i] == j:
                lt[i] = T * (mus[i] * max(lam[i], 0.0) / tot if tot > 0.0 else 1.0 / cnt)


@njit(cache=True, nogil=True, error_model="numpy")
def friction_project(q, p, prm, held, lam, lt):
    """p <- p + sum_A D_j^T lam_j + sum_S W_j^T lt_j with [G_A; W_S] M^-1 p = 0 after: the held contacts'
    normal velocities and the stuck contacts' slip velocities zeroed, a slipping contact's normal
    impulse carrying its friction impulse. lam, lt (NCON) receive the impulses (0 elsewhere).
    Returns False if the contact matrix or M is singular."""
    idx = scratch_i(NCON)
    sidx = scratch_i(NCON)
    lead = scratch_i(NCON)
    for j in range(NCON):
        lam[j] = 0.0
        lt[j] = 0.0
    A = scratch2(NDOF, NDOF)
    G = scratch2(NCON, NDOF)
    W = scratch2(NCON, NDOF)
    k, ks = contact_rows(q, prm, held, A, G, W, idx, sidx, lead)
    if k < 0:
        return False
    r = k + ks
    if r == 0:
        return True
    mu = scratch(NCON)
    mus = scratch(NCON)
    sys_friction(prm, mu, mus)
    C = scratch2(2 * NCON, NDOF)
    D = scratch2(2 * NCON, NDOF)
    _constraint_rows(G, W, idx, k, sidx, ks, C)
    _force_rows(G, W, held, mu, idx, k, sidx, ks, D)
    X = scratch2(2 * NCON, NDOF)
    K = scratch2(r, r) if r * r <= STACK_DOUBLES else np.empty((r, r))
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
    _share(held, lead, lam, mus, lt)
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def friction_stage(sid, q0, p0, hs, t, prm, ntol, maxit, held, v, q1, p1, imp, impt, work):
    """One explicit stage of the held step with friction (the unit's header); v: Newton's start on
    entry, the step velocity on exit; imp[j] += the normal impulse of held contact j, impt[j] += its
    tangential (friction) impulse; work[0] += the work of the friction forces over the stage (<= 0),
    the friction impulses against the stage's mean slip velocity W_j(q0 + hs v / 2) v. Returns Newton
    iterations (< 0 on failure). The stuck rows' Jacobian omits the O(hs) term of dW/dq: the residual
    is exact, Newton contracts by O(hs) there (the stopping rule watches the contraction)."""
    idx = scratch_i(NCON)
    sidx = scratch_i(NCON)
    lead = scratch_i(NCON)
    A = scratch2(NDOF, NDOF)
    G0 = scratch2(NCON, NDOF)
    W0 = scratch2(NCON, NDOF)
    k, ks = contact_rows(q0, prm, held, A, G0, W0, idx, sidx, lead)
    if k < 0:
        return -1
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
    G1 = scratch2(NCON, NDOF)
    Wm = scratch2(NCON, NDOF)
    D0 = scratch2(2 * NCON, NDOF)
    phis = scratch(NCON)
    _force_rows(G0, W0, held, mu, idx, k, sidx, ks, D0)
    F = scratch(NDOF + 2 * NCON)
    JJ = scratch2(m, m) if m * m <= STACK_DOUBLES else np.empty((m, m))
    qn = scratch(NDOF)
    qm = scratch(NDOF)
    # a stage so short that hs v moves q by fewer than ~1e8 of its ulps (a partial step to an event
    # at the step's start): phi(q0 + hs v) / hs is then phi's rounding over hs, which Newton cannot
    # settle; the held rows take their hs -> 0 limit G(q0) v = 0 there, which moves phi by
    # O(hs^2 |v|^2 |phi''|), below its round-off
    vmax = 0.0
    qmax = 0.0
    for j in range(NDOF):
        vmax = max(vmax, abs(v[j]))
        qmax = max(qmax, abs(q0[j]))
    # (|hs|: a composition's stages can be negative, CVA4's middle one)
    limit = hs == 0.0 or abs(hs) * (1.0 + vmax) <= 1e8 * 2.220446049250313e-16 * (1.0 + qmax)
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
            if not limit:
                F[NDOF + a] = phis[j] / hs
                for l in range(NDOF):
                    JJ[NDOF + a, l] = G1[j, l]
            else:
                s = 0.0
                for l in range(NDOF):
                    s += G0[j, l] * x[l]
                    JJ[NDOF + a, l] = G0[j, l]
                F[NDOF + a] = s
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
        stop = newton_stop(it, dn, dprev, xn, ntol, True)
        if stop != NEWTON_GO_ON:
            ok = stop == NEWTON_CONVERGED
            break
        dprev = dn
    for j in range(NDOF):
        v[j] = x[j]
        q1[j] = q0[j] + hs * x[j]
        qm[j] = q0[j] + 0.5 * hs * x[j]
    ld_Ppc(sid, q0, x[:NDOF], hs, t, prm, c, p1, cn)
    pi = scratch(NCON)
    pt = scratch(NCON)
    if not friction_project(q1, p1, prm, held, pi, pt):
        return -it
    sys_slips(qm, prm, Wm)
    for a in range(k):
        j = idx[a]
        ln = x[NDOF + a] + pi[j]
        imp[j] += ln
        if slipping(held[j]) and mu[j] != 0.0:
            ft = -mu[j] * held[j] * ln
            impt[j] += ft
            s = 0.0
            for l in range(NDOF):
                s += Wm[j, l] * x[l]
            work[0] += ft * s
    for b in range(ks):
        impt[sidx[b]] += x[NDOF + k + b]
    for j in range(NCON):
        if held[j] == HELD_STICK:
            impt[j] += pt[j]
    return it if ok else -it


@njit(cache=True, nogil=True, error_model="numpy")
def friction_forces(q, p, t, prm, held, lam, lt):
    """The held contacts' forces in the continuous motion through (q, p) at t with their modes:
    M qddot = F - Mdot v + sum_A D_j^T lam_j + sum_S W_j^T lt_j, F = -dH/dq + f, v = M^-1 p, from
    d^2 phi_A / dt^2 = 0 and d/dt (W_S v) = 0:
        C M^-1 D^T (lam, lt) = -(C M^-1 (F - Mdot v) + (v^T Hess phi_j v)_A, (v^T dW_j/dq v)_S).
    lam_j > 0 compresses; a slipping contact's lt_j = -mu_j s_j lam_j, a stuck one's its tangential
    force (shared within a dependent group). Returns FRICTION_OK, FRICTION_SINGULAR or
    FRICTION_PAINLEVE (a slipping contact's own coefficient B_j = (C M^-1 D^T)_jj <= 0: Painleve's
    case, no or several solutions)."""
    idx = scratch_i(NCON)
    sidx = scratch_i(NCON)
    lead = scratch_i(NCON)
    for j in range(NCON):
        lam[j] = 0.0
        lt[j] = 0.0
    A = scratch2(NDOF, NDOF)
    G = scratch2(NCON, NDOF)
    W = scratch2(NCON, NDOF)
    k, ks = contact_rows(q, prm, held, A, G, W, idx, sidx, lead)
    if k < 0:
        return FRICTION_SINGULAR
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
    C = scratch2(2 * NCON, NDOF)
    D = scratch2(2 * NCON, NDOF)
    _constraint_rows(G, W, idx, k, sidx, ks, C)
    _force_rows(G, W, held, mu, idx, k, sidx, ks, D)
    X = scratch2(2 * NCON, NDOF)
    K = scratch2(r, r) if r * r <= STACK_DOUBLES else np.empty((r, r))
    if not _contact_matrix(A, C, D, r, X, K):
        return FRICTION_SINGULAR
    for a in range(k):
        if slipping(held[idx[a]]) and mu[idx[a]] != 0.0 and not K[a, a] > 0.0:
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
        if slipping(held[j]):
            lt[j] = -mu[j] * held[j] * b[a]
    for c in range(ks):
        lt[sidx[c]] = b[k + c]
    _share(held, lead, lam, mus, lt)
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
def mode_event_values(q, p, t, prm, held, ev, lam, lt):
    """ev_j: positive while held contact j keeps its mode, its sign change the mode's end: s_j v_t,j
    for a slipping contact with friction (slip stops: stick or reversal), mu_s,j lam_j - |lt_j| for a
    stuck one (stick ends: slip); +inf for the others (free, or slipping without friction). lam, lt
    receive friction_forces' forces (lam_j's sign change: a release, the caller's). Returns
    friction_forces' code."""
    code = friction_forces(q, p, t, prm, held, lam, lt)
    mu = scratch(NCON)
    mus = scratch(NCON)
    sys_friction(prm, mu, mus)
    vt = scratch(NCON)
    slip_velocities(q, p, prm, vt)
    for j in range(NCON):
        ev[j] = np.inf
        if slipping(held[j]) and mu[j] > 0.0:
            ev[j] = held[j] * vt[j]
        elif held[j] == HELD_STICK:
            ev[j] = mus[j] * lam[j] - abs(lt[j])
    return code


@njit(cache=True, nogil=True, error_model="numpy")
def slip_tolerance(q, p, prm, j):
    """How close to 0 a slip velocity counts as rest: the round-off of W_j M^-1 p, 64 eps |W_j|_1
    max_i |v_i| with v = M^-1 p. The velocity's largest component, not the components W_j weighs: a
    contact point at rest on a moving mechanism (a stance foot) has W_j v = 0 from components that
    carry the solve's rounding of the whole v. After an impulse, p is the momentum before it: the
    slip velocities the impulse leaves carry the rounding of that one (a box that lands flat and
    sticks is at rest after the impact, its corners' slip velocities are the rounding of its
    landing velocity, 1e-17, not 0)."""
    v = scratch(NDOF)
    velocity_guess(q, p, prm, v)
    W = scratch2(NCON, NDOF)
    sys_slips(q, prm, W)
    vmax = 0.0
    w = 0.0
    for i in range(NDOF):
        vmax = max(vmax, abs(v[i]))
        w += abs(W[j, i])
    return 64.0 * 2.220446049250313e-16 * w * vmax


@njit(cache=True, nogil=True, error_model="numpy")
def assign_modes(q, p, t, prm, held, rest, moving, lam, lt, p_round):
    """The modes of the held contacts at (q, p) (they touch and are pressed in), by an active set: each
    contact with friction whose slip velocity is at rest (within slip_tolerance, or the contact
    `rest` whose slip has just stopped and every one at most 4x as fast as its residue; with rest =
    REST_REVERSED every slipping contact whose slip velocity has turned against its direction: its
    slip stopped inside the step, unlocated) starts stuck, the others slip in the direction of their slip
    velocity (the contact `moving`, whose stick has just ended, in the direction held[moving] gives);
    then, while a stuck contact violates Coulomb's static bound, the one with the largest
    excess |lt_j| / (mu_s,j lam_j) slips, in the direction the unbalanced force drives
    (s_j = -sign(lt_j)). Frictionless held contacts slip (held[j] = 1). lam, lt: the final forces.
    p_round: the momentum whose rounding the slip velocities carry (slip_tolerance): p, or after an
    impulse the momentum before it. Returns friction_forces' code in the modes chosen."""
    mu = scratch(NCON)
    mus = scratch(NCON)
    sys_friction(prm, mu, mus)
    vt = scratch(NCON)
    slip_velocities(q, p, prm, vt)
    # at a located stop the resolution of a slip velocity is the stopped contact's own residue: the
    # others as slow (a body whose contacts' slip rows coincide, as a chain lying flat) stop with it
    vrest = 4.0 * abs(vt[rest]) if rest >= 0 else 0.0
    reversed_rest = rest == REST_REVERSED
    for j in range(NCON):
        if held[j] == 0:
            continue
        if not (mu[j] > 0.0 or mus[j] > 0.0):
            held[j] = 1
        elif j == moving:
            continue
        elif (j == rest or abs(vt[j]) <= max(slip_tolerance(q, p, prm, j), slip_tolerance(q, p_round, prm, j)) + vrest
              or (reversed_rest and slipping(held[j]) and held[j] * vt[j] < 0.0)):
            held[j] = HELD_STICK
        else:
            held[j] = 1 if vt[j] > 0.0 else -1
    code = FRICTION_OK
    for _ in range(NCON + 1):
        code = friction_forces(q, p, t, prm, held, lam, lt)
        if code != FRICTION_OK:
            return code
        worst = -1
        excess = 1.0
        for j in range(NCON):
            if held[j] != HELD_STICK:
                continue
            cap = mus[j] * max(lam[j], 0.0)
            x = abs(lt[j]) / cap if cap > 0.0 else (np.inf if lt[j] != 0.0 else 0.0)
            if x > excess:
                excess = x
                worst = j
        if worst < 0:
            return code
        held[worst] = -1 if lt[worst] > 0.0 else 1
    return code
