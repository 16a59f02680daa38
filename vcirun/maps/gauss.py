# numba source unit: the MCVA family's maps (Sections 4.3-4.4): the truncated modified Hamiltonian
# H~^{O(h^s)} of the scene's discrete Lagrangian (Newton for eta's stationary stage velocities) and
# the Gauss collocation partial flow of its Hamilton equations. R^MCVA: vcirun/collision/reset_mcva.py.
# The modified Hamiltonian's kernels: vcirun/codegen/mh_kernels.py (declared in vcirun.codegen.roles).
import math

import numpy as np
from numba import njit

from vcirun.codegen.frame import scratch, scratch2
from vcirun.codegen.roles import (
    NDOF, MH_M, FORCED, MH_ORDER, MH_NSTAGE, MH_FLOW_S, sys_force, sys_force_jac, mh_FA, mh_value, mh_grad, mh_hess
)
from vcirun.maps.dynamics import velocity_guess
from vcirun.maps.linalg import solve_small

# Gauss-Legendre collocation tableaux (Hairer-Wanner II, Table IV.5.1/5.2). D = b^T A^{-1}: the
# update y1 = y0 + sum_i D_i Z_i needs no extra evaluation of the vector field.
_S3 = math.sqrt(3.0)
_S15 = math.sqrt(15.0)
if MH_FLOW_S == 2:
    GAUSS_A = np.array([[0.25, 0.25 - _S3 / 6.0], [0.25 + _S3 / 6.0, 0.25]])
    GAUSS_B = np.array([0.5, 0.5])
    GAUSS_C = np.array([0.5 - _S3 / 6.0, 0.5 + _S3 / 6.0])
else:
    GAUSS_A = np.array([[5.0 / 36.0, 2.0 / 9.0 - _S15 / 15.0, 5.0 / 36.0 - _S15 / 30.0],
                        [5.0 / 36.0 + _S15 / 24.0, 2.0 / 9.0, 5.0 / 36.0 - _S15 / 24.0],
                        [5.0 / 36.0 + _S15 / 30.0, 2.0 / 9.0 + _S15 / 15.0, 5.0 / 36.0]])
    GAUSS_B = np.array([5.0 / 18.0, 4.0 / 9.0, 5.0 / 18.0])
    GAUSS_C = np.array([0.5 - _S15 / 10.0, 0.5, 0.5 + _S15 / 10.0])
GAUSS_D = np.linalg.solve(GAUSS_A.T, GAUSS_B)
MH_U_TOL = 1e-10   # Newton on u stops after a step this small (relative): the error is then ~1e-20
MH_U_MAXIT = 50


@njit(cache=True, nogil=True, error_model="numpy")
def mh_guess(q, p, prm, u):
    """Newton's start for u: the continuous velocity M(q)^{-1} p in every stage."""
    v = scratch(NDOF)
    velocity_guess(q, p, prm, v)
    for st in range(MH_NSTAGE):
        for i in range(NDOF):
            u[st * NDOF + i] = v[i]


@njit(cache=True, nogil=True, error_model="numpy")
def mh_solve(q, p, h, prm, u, W):
    """Stationary stage velocities u* of G(q, p, u) = p . v(u) - ell(q, u) (so qbar = q + h v(u*)) by
    Newton from the u given (mh_guess or a nearby solution); W = (dF/du)^{-1} at u*. Returns the
    number of iterations, < 0 on failure. (No flag arguments: a literal argument would make numba
    compile the whole call chain once more.)"""
    F = scratch(MH_M)
    A = scratch2(MH_M, MH_M)
    B = scratch2(MH_M, MH_M)
    x = scratch(MH_M)
    it = 0
    small = False
    while True:
        mh_FA(q, p, u, h, prm, F, A)
        if small:
            break
        if it >= MH_U_MAXIT:
            return -it
        it += 1
        for a in range(MH_M):
            for b in range(MH_M):
                B[a, b] = A[a, b]
        if not solve_small(B, F, MH_M):
            return -it
        dn = 0.0
        un = 0.0
        for k in range(MH_M):
            u[k] -= F[k]
            dn = max(dn, abs(F[k]))
            un = max(un, abs(u[k]))
        if not math.isfinite(dn):
            return -it
        small = dn <= MH_U_TOL * (1.0 + un)
    # A is at the final u: W = A^{-1} column by column
    for c in range(MH_M):
        for a in range(MH_M):
            x[a] = 1.0 if a == c else 0.0
            for b in range(MH_M):
                B[a, b] = A[a, b]
        if not solve_small(B, x, MH_M):
            return -it
        for a in range(MH_M):
            W[a, c] = x[a]
    return it


@njit(cache=True, nogil=True, error_model="numpy")
def mh_terms(q, p, h, prm, out):
    """out[i] = H_{i+1}(q, p) (out[0] = eta) for i < MH_ORDER, NaN beyond; returns H~^{O(h^s)}."""
    u = scratch(MH_M)
    W = scratch2(MH_M, MH_M)
    for i in range(out.shape[0]):
        out[i] = np.nan
    mh_guess(q, p, prm, u)
    if mh_solve(q, p, h, prm, u, W) < 0:
        return np.nan
    terms = scratch(MH_ORDER)
    val = mh_value(q, p, u, W, h, prm, terms)
    for i in range(min(MH_ORDER, out.shape[0])):
        out[i] = terms[i]
    return val


@njit(cache=True, nogil=True, error_model="numpy")
def mh_energy(q, p, h, prm):
    """H~^{O(h^s)}(q, p) = eta + h H2 + ... + h^{s-1} H_s (NaN if eta's stationary point is not found)."""
    u = scratch(MH_M)
    W = scratch2(MH_M, MH_M)
    mh_guess(q, p, prm, u)
    if mh_solve(q, p, h, prm, u, W) < 0:
        return np.nan
    terms = scratch(MH_ORDER)
    return mh_value(q, p, u, W, h, prm, terms)


@njit(cache=True, nogil=True, error_model="numpy")
def mh_gradient(q, p, h, prm, u, W, grad, hess):
    """(iterations (< 0 on failure), H~): grad = (dH~/dq, dH~/dp), hess = Hessian of eta in (q, p)
    unless hess is empty (shape (0, 0): the Gauss flow needs it once per partial step, the reset
    never). u: Newton's start on entry, the stationary stage velocities on exit."""
    it = mh_solve(q, p, h, prm, u, W)
    if it < 0:
        return it, np.nan
    if hess.shape[0] > 0:
        mh_hess(q, p, u, W, h, prm, hess)
    return it, mh_grad(q, p, u, W, h, prm, grad)


@njit(cache=True, nogil=True, error_model="numpy")
def mh_field(y, t, h, prm, u, W, grad, hess, f):
    """f = (dH~/dp, -dH~/dq + F(q, dH~/dp, t)) at y = (q, p), F the generalized force (forced
    modified equations, docs/derivations/forcing.md; FORCED False: the Hamiltonian field of H~). Returns the
    Newton iterations spent on u (< 0: failure)."""
    q = y[:NDOF]
    p = y[NDOF:]
    it, val = mh_gradient(q, p, h, prm, u, W, grad, hess)
    for i in range(NDOF):
        f[i] = grad[NDOF + i]
        f[NDOF + i] = -grad[i]
    if FORCED:
        fo = scratch(NDOF)
        sys_force(q, f[:NDOF], t, prm, fo)
        for i in range(NDOF):
            f[NDOF + i] += fo[i]
    if it >= 0 and not math.isfinite(val):
        return -1
    return it


@njit(cache=True, nogil=True, error_model="numpy")
def gauss_partial(q0, p0, tau, h, t, prm, ntol, maxit, q1, p1, vlast):
    """One step of length tau of the s-stage Gauss collocation method (order 2s; s = MH_FLOW_S) on
    Hamilton's equations of H~^{O(h^s)}(q, p; h) (h: the full step, a parameter of H~), with the
    generalized force F(q, dH~/dp, t) added to dp/dt for a forced system (stage times t + c_i tau).

    Stage equations Z_i = tau sum_j a_ij f(y0 + Z_j) solved by simplified Newton with the fixed matrix
    I - tau (A x J0), J0 = the Jacobian of eta's Hamiltonian field at y0 (= that of H~ up to O(h)),
    so each iteration contracts by O(tau (h + tau)); start Z_i = c_i tau f(y0). Stops when the
    update is below ntol (1 + |y|). Returns (Newton iterations, or < 0 on failure, NaN: the flow has
    no discrete energy). tau = 0 returns the input state."""
    nz = 2 * NDOF
    s = MH_FLOW_S
    for i in range(NDOF):
        q1[i] = q0[i]
        p1[i] = p0[i]
    if tau == 0.0:
        return 0, np.nan
    y0 = scratch(nz)
    for i in range(NDOF):
        y0[i] = q0[i]
        y0[NDOF + i] = p0[i]
    U = scratch2(s, MH_M)
    W = scratch2(MH_M, MH_M)
    grad = scratch(nz)
    hess = scratch2(nz, nz)
    f0 = scratch(nz)
    mh_guess(q0, p0, prm, U[0])
    it0 = mh_field(y0, t, h, prm, U[0], W, grad, hess, f0)
    if it0 < 0:
        return -1, np.nan
    for k in range(1, s):
        for i in range(MH_M):
            U[k, i] = U[0, i]
    # J0 = d/dy (H_p, -H_q + F(q, H_p, t)) with eta's Hessian for H~'s
    J0 = scratch2(nz, nz)
    for i in range(NDOF):
        for j in range(nz):
            J0[i, j] = hess[NDOF + i, j]
            J0[NDOF + i, j] = -hess[i, j]
    if FORCED:
        fq = scratch2(NDOF, NDOF)
        fv = scratch2(NDOF, NDOF)
        sys_force_jac(q0, f0[:NDOF], t, prm, fq, fv)
        for i in range(NDOF):
            for j in range(nz):
                acc = fq[i, j] if j < NDOF else 0.0
                for k in range(NDOF):
                    acc += fv[i, k] * J0[k, j]
                J0[NDOF + i, j] += acc
    m = s * nz
    N = scratch2(m, m)
    for a in range(s):
        for b in range(s):
            for i in range(nz):
                for j in range(nz):
                    N[a * nz + i, b * nz + j] = -tau * GAUSS_A[a, b] * J0[i, j] + (1.0 if (a == b and i == j) else 0.0)
    NN = scratch2(m, m)
    Z = scratch2(s, nz)
    for a in range(s):
        for i in range(nz):
            Z[a, i] = GAUSS_C[a] * tau * f0[i]
    Fs = scratch2(s, nz)
    nohess = scratch2(0, 0)  # J0 above is the only use of eta's Hessian
    Y = scratch(nz)
    R = scratch(m)
    ynorm = 0.0
    for i in range(nz):
        ynorm = max(ynorm, abs(y0[i]))
    it = 0
    ok = False
    while it < maxit:
        it += 1
        for a in range(s):
            for i in range(nz):
                Y[i] = y0[i] + Z[a, i]
            if mh_field(Y, t + GAUSS_C[a] * tau, h, prm, U[a], W, grad, nohess, Fs[a]) < 0:
                return -it, np.nan
        for a in range(s):
            for i in range(nz):
                acc = 0.0
                for b in range(s):
                    acc += GAUSS_A[a, b] * Fs[b, i]
                R[a * nz + i] = tau * acc - Z[a, i]
        for i in range(m):  # (explicit loops: numba's slice assignment costs seconds of compile time)
            for j in range(m):
                NN[i, j] = N[i, j]
        if not solve_small(NN, R, m):
            return -it, np.nan
        dn = 0.0
        for a in range(s):
            for i in range(nz):
                Z[a, i] += R[a * nz + i]
                dn = max(dn, abs(R[a * nz + i]))
        if not math.isfinite(dn):
            return -it, np.nan
        if dn <= ntol * (1.0 + ynorm):
            ok = True
            break
    for i in range(nz):
        acc = y0[i]
        for a in range(s):
            acc += GAUSS_D[a] * Z[a, i]
        if i < NDOF:
            q1[i] = acc
        else:
            p1[i - NDOF] = acc
    for i in range(NDOF):
        vlast[i] = Fs[s - 1, i]
    return (it if ok else -it), np.nan

