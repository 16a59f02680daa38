# numba source unit: held (resting) contacts (docs/derivations/contacts.md, "Held contacts").
# Contract: vcirun.codegen.units.
#
# While the contacts of a set A are held, phi_A(q) = 0 is a bilateral constraint and every method
# takes the constrained variational step of its discrete Lagrangian (RATTLE form, Marsden & West,
# Discrete mechanics and variational integrators, Sec. 3.5; Leimkuhler & Reich, Sec. 7): per explicit
# stage of length hs from (q0, p0),
#     Pm(q0, v, hs) = p0 + G_A(q0)^T lam          (forced DEL momentum, with the constraint impulse)
#     phi_A(q0 + hs v) = 0                         (solved for (v, lam) by Newton)
#     p1 = Pp(q0, v, hs) + G_A(q1)^T mu,  G_A(q1) M(q1)^-1 p1 = 0   (the hidden constraint)
# a symplectic map of the cotangent bundle of the constraint manifold (the discrete Lagrangian
# restricted to it), so the held phase keeps the VI structure. lam + mu is the stage's contact
# impulse. The instantaneous contact force of the continuous motion (the index-reduced multiplier,
# `contact_forces`) decides holding (compressive, > 0) and release (it would turn tensile).

import numpy as np
from numba import njit

from vcirun.codegen.frame import scratch, scratch2, scratch_i
from vcirun.codegen.roles import (
    NDOF, NCON, NODE_LEN, FULL_STAGES, FULL_FRACS, FRICTION, sys_M, sys_phis, sys_dphis, sys_ddphis, sys_Mdotv, sys_node,
    ld_PmJc, ld_Ppc, ld_Ed
)
from vcirun.maps.dynamics import delassus, dynamics_rhs, velocity_guess
from vcirun.maps.friction import friction_stage
from vcirun.maps.linalg import solve_small, copy_into, STACK_DOUBLES
from vcirun.maps.newton import NEWTON_CONVERGED, NEWTON_GO_ON, newton_stop


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _free_motion(q, p, t, prm, dd, G, A, w):
    """The terms of d^2 phi / dt^2 along the free motion through (q, p) at t, with v = M^-1 p and
    F = -dH/dq + f, into the caller's arrays: dd_i = v^T Hess phi_i v (NCON), G = grad phi
    (NCON x NDOF), A = M (NDOF x NDOF), w = F - Mdot v (NDOF)."""
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
    sys_ddphis(q, v, prm, dd)
    sys_dphis(q, prm, G)
    sys_M(q, prm, A)
    for j in range(NDOF):
        w[j] = f[NDOF + j] - mdv[j]


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _copy2(dst, src):
    for i in range(src.shape[0]):
        for j in range(src.shape[1]):
            dst[i, j] = src[i, j]


# The count comes from a call, so numba types it int64 from the start: a count started at 0 in the
# caller is first typed as the literal 0, and its first pass compiles the solvers once more for it.
@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _held_index(held, idx):
    """idx[:k] <- the held contacts' indices in order; returns k."""
    k = 0
    for i in range(NCON):
        if held[i] != 0:
            idx[k] = i
            k += 1
    return k


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def contact_forces(q, p, t, prm, held, mu):
    """mu_A: the multipliers of the held contacts in the continuous motion through (q, p) at t,
    pdot = F + G_A^T mu, F = -dH/dq + f, from d^2/dt^2 phi_A = 0 with v = M^-1 p:
        G M^-1 G^T mu = -(G M^-1 (F - Mdot v) + (v^T Hess phi_i v)_i).
    mu_i > 0 compresses (pushes along +grad phi_i); mu_i = 0 for contacts not held. Returns False
    if the held contacts' Delassus matrix is singular."""
    for i in range(NCON):
        mu[i] = 0.0
    idx = scratch_i(NCON)
    k = _held_index(held, idx)
    if k == 0:
        return True
    dd = scratch(NCON)
    G = scratch2(NCON, NDOF)
    A = scratch2(NDOF, NDOF)
    rhs = scratch(NDOF)
    _free_motion(q, p, t, prm, dd, G, A, rhs)
    if k * k <= STACK_DOUBLES:
        X = scratch2(k, NDOF)     # rows M^-1 grad phi_i
        W = scratch2(k, k)
    else:
        X = np.empty((k, NDOF))
        W = np.empty((k, k))
    if not delassus(A, G, idx, k, X, W):
        return False
    B = scratch2(NDOF, NDOF)
    _copy2(B, A)
    if not solve_small(B, rhs, NDOF):
        return False
    b = scratch(k)
    for a in range(k):
        s = dd[idx[a]]
        for j in range(NDOF):
            s += G[idx[a], j] * rhs[j]
        b[a] = -s
    if not solve_small(W, b, k):
        return False
    for a in range(k):
        mu[idx[a]] = b[a]
    return True


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def project_momentum(q, p, prm, held, imp):
    """p <- p + G_A^T pi with G_A M^-1 p = 0 after (the held contacts' normal velocities zeroed, a
    plastic impact on them); imp[i] receives pi_i (0 for contacts not held)."""
    for i in range(NCON):
        imp[i] = 0.0
    idx = scratch_i(NCON)
    k = _held_index(held, idx)
    if k == 0:
        return True
    G = scratch2(NCON, NDOF)
    sys_dphis(q, prm, G)
    A = scratch2(NDOF, NDOF)
    sys_M(q, prm, A)
    if k * k <= STACK_DOUBLES:
        X = scratch2(k, NDOF)
        W = scratch2(k, k)
    else:
        X = np.empty((k, NDOF))
        W = np.empty((k, k))
    if not delassus(A, G, idx, k, X, W):
        return False
    b = scratch(k)
    for a in range(k):
        s = 0.0
        for j in range(NDOF):
            s += X[a, j] * p[j]
        b[a] = -s
    if not solve_small(W, b, k):
        return False
    for a in range(k):
        imp[idx[a]] = b[a]
        for j in range(NDOF):
            p[j] += b[a] * G[idx[a], j]
    return True


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def held_stage(sid, q0, p0, hs, t, prm, ntol, maxit, held, v, q1, p1, imp):
    """One constrained explicit stage (see the unit's header); v: Newton's start on entry, the step
    velocity on exit; imp[i] += lam_i + mu_i. Returns Newton iterations (< 0 on failure)."""
    idx = scratch_i(NCON)
    k = _held_index(held, idx)
    m = NDOF + k
    x = scratch(m)
    for j in range(m):
        x[j] = v[j] if j < NDOF else 0.0
    c = scratch(NODE_LEN)
    cn = scratch(NODE_LEN)
    sys_node(q0, prm, c)
    r = scratch(NDOF)
    J = scratch2(NDOF, NDOF)
    G0 = scratch2(NCON, NDOF)
    G1 = scratch2(NCON, NDOF)
    phis = scratch(NCON)
    sys_dphis(q0, prm, G0)
    F = scratch(m)
    JJ = scratch2(m, m) if m * m <= STACK_DOUBLES else np.empty((m, m))
    qn = scratch(NDOF)
    it = 0
    ok = False
    dprev = np.inf
    while it < maxit:
        it += 1
        ld_PmJc(sid, q0, x[:NDOF], hs, t, prm, c, r, J)
        for j in range(NDOF):
            qn[j] = q0[j] + hs * x[j]
        sys_phis(qn, prm, phis)
        sys_dphis(qn, prm, G1)
        for i in range(NDOF):
            s = r[i] - p0[i]
            for a in range(k):
                s -= G0[idx[a], i] * x[NDOF + a]
            F[i] = s
            for j in range(NDOF):
                JJ[i, j] = J[i, j]
            for a in range(k):
                JJ[i, NDOF + a] = -G0[idx[a], i]
        for a in range(k):
            # phi(q0 + hs v) / hs, whose v-derivative is G(q1): regular as hs -> 0 (then G(q0) v)
            if hs != 0.0:
                F[NDOF + a] = phis[idx[a]] / hs
            else:
                s = 0.0
                for j in range(NDOF):
                    s += G0[idx[a], j] * x[j]
                F[NDOF + a] = s
            for j in range(NDOF):
                JJ[NDOF + a, j] = G1[idx[a], j]
            for b in range(k):
                JJ[NDOF + a, NDOF + b] = 0.0
        if not solve_small(JJ, F, m):
            break
        dn = 0.0
        xn = 0.0
        for j in range(m):
            x[j] -= F[j]
            dn = max(dn, abs(F[j]))
            xn = max(xn, abs(x[j]))
        stop = newton_stop(it, dn, dprev, xn, ntol, False)
        if stop != NEWTON_GO_ON:
            ok = stop == NEWTON_CONVERGED
            break
        dprev = dn
    for j in range(NDOF):
        v[j] = x[j]
        q1[j] = q0[j] + hs * x[j]
    ld_Ppc(sid, q0, x[:NDOF], hs, t, prm, c, p1, cn)
    pi = scratch(NCON)
    if not project_momentum(q1, p1, prm, held, pi):
        return -it
    for a in range(k):
        imp[idx[a]] += x[NDOF + a] + pi[idx[a]]
    return it if ok else -it


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def held_step(q0, p0, h, t, prm, ntol, maxit, held, q1, p1, vlast, imp, impt, work):
    """The constrained map of the scene's discrete Lagrangian (its explicit stages in turn, each
    constrained: held_stage, or with friction maps/friction.py friction_stage, which holds the
    contacts in their slip and stick modes) over h from (q0, p0) with the contacts `held` held; imp
    (NCON) receives the contact impulses, with friction impt (NCON) the tangential ones and work[0]
    the friction work (untouched without friction). Returns (iterations, < 0 on failure; discrete
    energy -D3 Ld of the stages)."""
    for i in range(NCON):
        imp[i] = 0.0
    if FRICTION:
        for i in range(NCON):
            impt[i] = 0.0
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
        if FRICTION:
            it = friction_stage(FULL_STAGES[s], qa, pa, hs, ts, prm, ntol, maxit, held, v, q1, p1, imp, impt, work)
        else:
            it = held_stage(FULL_STAGES[s], qa, pa, hs, ts, prm, ntol, maxit, held, v, q1, p1, imp)
        if it < 0:
            return it - total, np.nan
        total += it
        Ed += FULL_FRACS[s] * ld_Ed(FULL_STAGES[s], qa, v, hs, prm)
        ts += hs
        copy_into(qa, q1)
        copy_into(pa, p1)
    copy_into(vlast, v)
    return total, Ed


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def normal_acceleration(q, p, t, prm, i):
    """d^2 phi_i / dt^2 of the free (unheld) motion through (q, p): negative when the motion is pressed
    into contact i."""
    dd = scratch(NCON)
    G = scratch2(NCON, NDOF)
    A = scratch2(NDOF, NDOF)
    w = scratch(NDOF)
    _free_motion(q, p, t, prm, dd, G, A, w)
    if not solve_small(A, w, NDOF):
        return np.nan
    s = dd[i]
    for j in range(NDOF):
        s += G[i, j] * w[j]
    return s
