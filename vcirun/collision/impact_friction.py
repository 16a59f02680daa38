# numba source unit: the impact with Coulomb friction (docs/derivations/friction.md, "Frictional
# impacts"): which contacts take part (the set collision/impact.py's touching_set gives the
# frictionless law: the contact the search located and every one touching), their normal and
# tangential impulses from the frictional impact law (collision/friction_law.py) on the normal rows
# grad phi_i and the slip rows W_t,i, the direction of the momentum jump and the energy the law removes.
# Contract: vcirun.codegen.units. The loop calls it for systems with friction (FRICTION) only.
#
#   friction_impact_direction(q, pm, h, event_tol, prm, d, lam, lamt, active) -> (k, s0, dE)
#     as collision/impact.py's impact_direction, with lamt (NCON) the tangential impulses:
#     p+ = pm + s0 d = pm + sum_i lam_i grad phi_i + lamt_i W_t,i, s0 = 1, dE = H(q, pm) - H(q, p+) >= 0
#     (the law never gains energy). k: contacts at the impact, 0 if none approaches, < 0 the law's
#     failure code.
import numpy as np
from numba import njit

from vcirun.codegen.frame import scratch, scratch2, scratch_i
from vcirun.codegen.roles import NDOF, NCON, sys_M, sys_phis, sys_dphis, sys_slips, sys_restitution, sys_friction
from vcirun.collision.friction_law import friction_impact_law
from vcirun.collision.impact import touching_set
from vcirun.maps.linalg import solve_small


@njit(cache=True, nogil=True, error_model="numpy")
def friction_impact_direction(q, pm, h, event_tol, prm, d, lam, lamt, active):
    e = scratch(NCON)
    sys_restitution(prm, e)
    mu = scratch(NCON)
    mus = scratch(NCON)
    sys_friction(prm, mu, mus)
    for i in range(NCON):
        lam[i] = 0.0
        lamt[i] = 0.0
        active[i] = 0
    phis = scratch(NCON)
    G = scratch2(NCON, NDOF)
    Wt = scratch2(NCON, NDOF)
    sys_phis(q, prm, phis)
    sys_dphis(q, prm, G)
    sys_slips(q, prm, Wt)
    A = scratch2(NDOF, NDOF)
    sys_M(q, prm, A)
    B = scratch2(NDOF, NDOF)
    x = scratch(NDOF)
    for i in range(NDOF):
        x[i] = pm[i]
        for j in range(NDOF):
            B[i, j] = A[i, j]
    if not solve_small(B, x, NDOF):   # x = M^-1 pm
        return -2, 0.0, 0.0
    u = scratch(NCON)
    for i in range(NCON):
        s = 0.0
        for j in range(NDOF):
            s += G[i, j] * x[j]
        u[i] = s
    idx = scratch_i(NCON)
    k, approaching = touching_set(q, phis, G, u, h, event_tol, idx)
    if not approaching:
        return 0, 0.0, 0.0
    # rows [normal_1..normal_k, tangent_1..tangent_k] and the Delassus matrix of the k contacts (on the
    # heap: an impact is rare against the steps, and k may be large)
    R = np.empty((2 * k, NDOF))
    X = np.empty((2 * k, NDOF))
    for a in range(k):
        for j in range(NDOF):
            R[a, j] = G[idx[a], j]
            R[k + a, j] = Wt[idx[a], j]
    for r in range(2 * k):
        for j in range(NDOF):
            X[r, j] = R[r, j]
            for l in range(NDOF):
                B[j, l] = A[j, l]
        if not solve_small(B, X[r], NDOF):
            return -2, 0.0, 0.0
    W = np.empty((2 * k, 2 * k))
    u2 = np.empty(2 * k)
    for r in range(2 * k):
        s = 0.0
        for j in range(NDOF):
            s += R[r, j] * x[j]
        u2[r] = s
        for c in range(2 * k):
            w = 0.0
            for j in range(NDOF):
                w += R[r, j] * X[c, j]
            W[r, c] = w
    for r in range(2 * k):   # symmetric up to the round-off of R M^-1 R^T
        for c in range(r + 1, 2 * k):
            w = 0.5 * (W[r, c] + W[c, r])
            W[r, c] = w
            W[c, r] = w
    ea = np.empty(k)
    mua = np.empty(k)
    for a in range(k):
        # a touching contact that separates takes no restitution (as collision/impact.py)
        ea[a] = e[idx[a]] if u2[a] <= 0.0 else 0.0
        mua[a] = mu[idx[a]]
    la = np.empty(2 * k)
    case = friction_impact_law(W, u2, ea, mua, la)
    if case < 0:
        return case, 0.0, 0.0
    for j in range(NDOF):
        d[j] = 0.0
    for r in range(2 * k):
        for j in range(NDOF):
            d[j] += la[r] * R[r, j]
    # the kinetic energy the law removes: -(la . u- + 1/2 la^T W la) >= 0
    gain = 0.0
    for r in range(2 * k):
        wl = 0.0
        for c in range(2 * k):
            wl += W[r, c] * la[c]
        gain += la[r] * (u2[r] + 0.5 * wl)
    for a in range(k):
        i = idx[a]
        lam[i] = la[a]
        lamt[i] = la[k + a]
        active[i] = 1
    return k, 1.0, max(-gain, 0.0)
