# numba source unit: the continuous dynamics of the system and its elastic impact law, from the
# system kernels alone: H, Hamilton's equations with the generalized force, the normal velocity
# d phi/dt, the elastic multiplier, the hyperregularity check. It needs no discrete Lagrangian, so
# the system-only module (vcirun.codegen.kernel_set.SYSTEM_KERNELS: the exact reference, baselines,
# studies, verify) is this unit, linalg and the system kernels.
import math

import numpy as np
from numba import njit

from vcirun.codegen.frame import scratch, scratch2
from vcirun.codegen.roles import NDOF, BAND, FORCED, sys_M, sys_V, sys_dphi, sys_dHq, sys_force
from vcirun.maps.linalg import solve_band, copy_into


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def velocity_from(A, p, v):
    """v = A^{-1} p for A = M(q) (destroyed; a band matrix of half-width BAND); v = 0 if A is singular (Newton then starts from rest)."""
    for i in range(NDOF):
        v[i] = p[i]
    if not solve_band(A, v, NDOF, BAND, 0.0):
        for i in range(NDOF):
            v[i] = 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def velocity_guess(q, p, prm, v):
    """v = M(q)^{-1} p: the continuous velocity, Newton's starting point for every step."""
    A = scratch2(NDOF, NDOF)
    sys_M(q, prm, A)
    velocity_from(A, p, v)


@njit(cache=True, nogil=True, error_model="numpy")
def hamiltonian(q, p, prm):
    """H(q, p) = 1/2 p^T M(q)^{-1} p + V(q)."""
    A = scratch2(NDOF, NDOF)
    x = scratch(NDOF)
    copy_into(x, p)
    sys_M(q, prm, A)
    solve_band(A, x, NDOF, BAND, 0.0)
    s = 0.0
    for i in range(NDOF):
        s += p[i] * x[i]
    return 0.5 * s + sys_V(q, prm)


@njit(cache=True, nogil=True, error_model="numpy")
def hamilton_rhs(y, prm, out):
    """Hamilton's equations (6)-(7) on y = (q, p): qdot = M^-1 p, pdot = -dH/dq."""
    q = y[:NDOF]
    p = y[NDOF:]
    A = scratch2(NDOF, NDOF)
    x = scratch(NDOF)
    copy_into(x, p)
    sys_M(q, prm, A)
    solve_band(A, x, NDOF, BAND, 0.0)
    g = scratch(NDOF)
    sys_dHq(q, x, prm, g)
    for i in range(NDOF):
        out[i] = x[i]
        out[NDOF + i] = -g[i]


@njit(cache=True, nogil=True, error_model="numpy")
def dynamics_rhs(t, y, prm, out):
    """The forced Hamilton's equations on y = (q, p): qdot = M^-1 p, pdot = -dH/dq + f(q, qdot, t)
    (= hamilton_rhs for an unforced system: FORCED is a module constant)."""
    hamilton_rhs(y, prm, out)
    if FORCED:
        f = scratch(NDOF)
        sys_force(y[:NDOF], out[:NDOF], t, prm, f)
        for i in range(NDOF):
            out[NDOF + i] += f[i]


@njit(cache=True, nogil=True, error_model="numpy")
def force_power(q, v, t, prm):
    """f(q, v, t) . v: the power of the generalized force at velocity v (0 for an unforced system)."""
    if not FORCED:
        return 0.0
    f = scratch(NDOF)
    sys_force(q, v, t, prm, f)
    s = 0.0
    for i in range(NDOF):
        s += f[i] * v[i]
    return s


@njit(cache=True, nogil=True, error_model="numpy")
def gdot(q, p, prm):
    """d/dtau phi(q(tau)) along the continuous flow through (q, p): grad phi(q) . M(q)^{-1} p. The
    partial map's own tau-derivative differs by O(tau^r) relatively (r its order): a model, never a
    decision (the bracket keeps the root search safe)."""
    A = scratch2(NDOF, NDOF)
    x = scratch(NDOF)
    copy_into(x, p)
    sys_M(q, prm, A)
    if not solve_band(A, x, NDOF, BAND, 0.0):
        return np.nan
    g = scratch(NDOF)
    sys_dphi(q, prm, g)
    s = 0.0
    for i in range(NDOF):
        s += g[i] * x[i]
    return s


@njit(cache=True, nogil=True, error_model="numpy")
def cva_lambda(q, pm, prm, g):
    """Nontrivial root of H(q, pm + lam g) = H(q, pm): H is quadratic in p, so
    lam = -2 g^T M^-1 pm / g^T M^-1 g (the root lam = 0 is divided out)."""
    sys_dphi(q, prm, g)
    A = scratch2(NDOF, NDOF)
    sys_M(q, prm, A)
    x = scratch(NDOF)
    copy_into(x, g)
    if not solve_band(A, x, NDOF, BAND, 0.0):
        return 0.0
    gWg = 0.0
    gWp = 0.0
    for i in range(NDOF):
        gWg += g[i] * x[i]
        gWp += x[i] * pm[i]
    if not gWg > 0.0:
        return 0.0
    return -2.0 * gWp / gWg


@njit(cache=True, nogil=True, error_model="numpy")
def delassus(A, G, idx, k, X, W):
    """The Delassus matrix of the k contacts idx[:k], from A = M(q) (kept) and G = grad phi (NCON x
    NDOF): X[a] = M^-1 grad phi_{idx[a]} and W[a, c] = grad phi_{idx[a]} . X[c], i.e.
    (G M^-1 G^T)_{idx[a] idx[c]}. Returns False if M(q) is singular (X and W are then not the
    matrix)."""
    B = scratch2(NDOF, NDOF)
    ok = True
    for a in range(k):
        for j in range(NDOF):
            X[a, j] = G[idx[a], j]
        for r in range(NDOF):
            for c in range(NDOF):
                B[r, c] = A[r, c]
        if not solve_band(B, X[a], NDOF, BAND, 0.0):
            ok = False
    for a in range(k):
        for c in range(k):
            w = 0.0
            for j in range(NDOF):
                w += G[idx[a], j] * X[c, j]
            W[a, c] = w
    return ok


@njit(cache=True, nogil=True, error_model="numpy")
def mass_matrix_ok(q, prm, A):
    """A = M(q); True if M(q) is finite and its symmetric part is positive definite (its Cholesky
    factorisation exists): the hyperregularity check of vcirun.run.api at the initial state, compiled
    because simulate runs it on every call (numpy's cholesky cost 10 us per call there)."""
    sys_M(q, prm, A)
    n = A.shape[0]
    for i in range(n):
        for j in range(n):
            if not math.isfinite(A[i, j]):
                return False
    L = np.zeros((n, n))
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return False
        L[j, j] = math.sqrt(s)
        for i in range(j + 1, n):
            s = 0.5 * (A[i, j] + A[j, i])
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    return True
