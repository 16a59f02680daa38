# numba source unit: the contacts: the gap min_i phi_i over the contacts that are not touching
# (touching = phi_i within round-off or the event tolerance of 0 and not approaching, or approaching
# by less than the round-off of phi_i within a step: two balls at rest against each other, or moving
# together, would pin the gap at 0), and the impact law at a collision found by the
# event search: which contacts take part, their impulses, the direction of the momentum jump and
# the energy Newton's law removes.
# Contract: vcirun.codegen.units. Derivations: docs/derivations/contacts.md.
#
#   impact_direction(q, pm, h, event_tol, prm, d, lam, active) -> (k, s0, dE)
#     q, pm: the impact configuration and momentum before the impact. On return d (n) holds the
#     direction of the jump, p+ = pm + s d, s0 the multiplier of Newton's law (so pm + s0 d is R^CVA's
#     p+ with restitution), lam (NCON) the per-contact impulses of p+ = pm + s0 d = pm + G^T lam
#     (lam_i of a contact not at the impact is 0), active (NCON) 1 for the contacts at the impact, dE
#     the continuous energy Newton's law removes, H(q, pm) - H(q, pm + s0 d) >= 0 (0 for elastic
#     impacts). k: the number of contacts at the impact, 0 if none approaches (no impact), < 0 if the
#     complementarity problem has no solution.
#
# One constraint (NCON == 1): d = grad phi, s0 = (1 + e)/2 times R^CVA's elastic multiplier (the
# paper's lam for e = 1, bit for bit), dE = (1 - e^2) u^2 / (2 W) with u = grad phi . M^-1 pm and
# W = grad phi . M^-1 grad phi. Several: the contacts whose own root lies within the event tolerance
# of this one, or touching (phi_i <= touch_tolerance), Moreau's law on them (impact_law), d =
# G_A^T lam_A, s0 = 1.
import math

import numpy as np
from numba import njit

from vcirun.codegen.frame import scratch, scratch2, scratch_i
from vcirun.codegen.roles import (
    NDOF, NCON, BAND, DPHI_NNZ, DPHI_ROW, DPHI_COL, sys_M, sys_phi, sys_phis, sys_dphis, sys_dphis_nz, sys_restitution,
)
from vcirun.collision.impact_law import impact_law
from vcirun.maps.dynamics import cva_lambda, delassus, gdot
from vcirun.maps.linalg import solve_band, STACK_DOUBLES


@njit(cache=True, nogil=True, error_model="numpy")
def impact_direction(q, pm, h, event_tol, prm, d, lam, active):
    e = scratch(NCON)
    sys_restitution(prm, e)
    for i in range(NCON):
        lam[i] = 0.0
        active[i] = 0
    if NCON == 1:
        s0 = cva_lambda(q, pm, prm, d)  # d = grad phi
        if s0 == 0.0 or not math.isfinite(s0):
            return 0, s0, 0.0
        if e[0] != 1.0:
            s0 *= 0.5 * (1.0 + e[0])
        lam[0] = s0
        active[0] = 1
        return 1, s0, _newton_loss_one(q, pm, prm, d, e[0])
    return _impact_several(q, pm, h, event_tol, prm, e, d, lam, active)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _newton_loss_one(q, pm, prm, g, e):
    """(1 - e^2) u^2 / (2 W) of one contact with gradient g (0.0 exactly for e = 1)."""
    if e == 1.0:
        return 0.0
    A = scratch2(NDOF, NDOF)
    sys_M(q, prm, A)
    x = scratch(NDOF)
    for i in range(NDOF):
        x[i] = g[i]
    if not solve_band(A, x, NDOF, BAND, 0.0):
        return 0.0
    W = 0.0
    u = 0.0
    for i in range(NDOF):
        W += g[i] * x[i]
        u += x[i] * pm[i]
    return (1.0 - e * e) * u * u / (2.0 * W)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _impact_several(q, pm, h, event_tol, prm, e, d, lam, active):
    phis = scratch(NCON)
    G = scratch2(NCON, NDOF)
    sys_phis(q, prm, phis)
    sys_dphis(q, prm, G)
    A = scratch2(NDOF, NDOF)
    sys_M(q, prm, A)
    every = scratch_i(NCON)
    for i in range(NCON):
        every[i] = i
    if NCON * NCON <= STACK_DOUBLES:
        X = scratch2(NCON, NDOF)  # rows M^-1 grad phi_i
        D = scratch2(NCON, NCON)  # the Delassus matrix of every contact
    else:
        X = np.empty((NCON, NDOF))
        D = np.empty((NCON, NCON))
    delassus(A, G, every, NCON, X, D)
    u = scratch(NCON)
    for i in range(NCON):
        s = 0.0
        for j in range(NDOF):
            s += X[i, j] * pm[j]
        u[i] = s
    idx = scratch_i(NCON)
    k, approaching = touching_set(q, phis, G, u, h, event_tol, idx)
    if not approaching:
        return 0, 0.0, 0.0
    W = scratch2(k, k) if k * k <= STACK_DOUBLES else np.empty((k, k))
    um = scratch(k)
    ea = scratch(k)
    for a in range(k):
        um[a] = u[idx[a]]
        # a touching contact that separates takes no restitution: with e > 0 a coupled separating
        # contact could end up approaching and gain energy (docs/derivations/contacts.md, section 1.5)
        ea[a] = e[idx[a]] if um[a] <= 0.0 else 0.0
        for b in range(k):
            W[a, b] = D[idx[a], idx[b]]
    la = scratch(k)
    case = impact_law(W, um, ea, la)
    if case < 0:
        return case, 0.0, 0.0
    for j in range(NDOF):
        d[j] = 0.0
    for a in range(k):
        i = idx[a]
        lam[i] = la[a]
        active[i] = 1
        for j in range(NDOF):
            d[j] += la[a] * G[i, j]
    if k == 1:  # one contact at the impact: the closed form (exactly 0 for e = 1)
        return 1, 1.0, _newton_loss_one(q, pm, prm, G[idx[0]], ea[0])
    # the energy Newton's law removes, -1/2 sum_i lam_i (1 - e_i) u-_i (docs/derivations/contacts.md, (2.2)):
    # exactly 0 when every e_i = 1, and no cancellation of two energies
    dE = 0.0
    for a in range(k):
        dE -= 0.5 * la[a] * (1.0 - ea[a]) * um[a]
    return k, 1.0, max(dE, 0.0)


@njit(cache=True, nogil=True, error_model="numpy")
def touching_set(q, phis, G, u, h, event_tol, idx):
    """The contacts at an impact, idx[:k]: the one the search located (smallest phi) and every other
    whose own root lies within the event tolerance of it, approaching or not (separating ones get
    lam = 0). phis, G = grad phi and u = G M^-1 p- at q are the caller's. Returns (k, whether one of
    them approaches). Moreau's law here and the frictional law (collision/impact_friction.py) take
    the same set."""
    i0 = 0
    for i in range(1, NCON):
        if phis[i] < phis[i0]:
            i0 = i
    k = 0
    for i in range(NCON):
        if i == i0 or phis[i] <= _touch_tolerance_row(q, G, i, u[i], h, event_tol):
            idx[k] = i
            k += 1
    approaching = False
    for a in range(k):
        if u[idx[a]] < 0.0:
            approaching = True
    return k, approaching


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def touch_tolerance(q, prm, i, u, h, event_tol):
    """How close to phi_i = 0 counts as touching: the event tolerance's worth of motion, or round-off
    of phi_i near q (64 eps (1 + |q| |grad phi_i|), as a start on the surface)."""
    gv = scratch(DPHI_NNZ)
    sys_dphis_nz(q, prm, gv)
    qn = 0.0
    for j in range(NDOF):
        qn = max(qn, abs(q[j]))
    return _touch_tolerance_nz(qn, gv, i, u, h, event_tol)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _touch_tolerance_row(q, G, i, u, h, event_tol):
    """touch_tolerance with the constraint Jacobian G at q given (loops over the contacts build it
    once: O(m n), not O(m^2 n))."""
    qn = 0.0
    for j in range(NDOF):
        qn = max(qn, abs(q[j]))
    return _touch_tolerance_qn(qn, G, i, u, h, event_tol)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _touch_tolerance_qn(qn, G, i, u, h, event_tol):
    """_touch_tolerance_row with qn = max_j |q_j| given (the loops over every contact take it once)."""
    gq = 0.0
    for j in range(NDOF):
        gq = max(gq, abs(G[i, j]))
    return _touch_tolerance_of(qn, gq, u, h, event_tol)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _touch_tolerance_nz(qn, gv, i, u, h, event_tol):
    """_touch_tolerance_qn over row i's structural nonzeros gv (sys_dphis_nz): the same number (the
    zeros leave max_j |G_ij| where it is), O(row) instead of O(n)."""
    gq = 0.0
    for k in range(DPHI_ROW[i], DPHI_ROW[i + 1]):
        gq = max(gq, abs(gv[k]))
    return _touch_tolerance_of(qn, gq, u, h, event_tol)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _touch_tolerance_of(qn, gq, u, h, event_tol):
    return max(4.0 * event_tol * h * abs(u), 64.0 * 2.220446049250313e-16 * (1.0 + qn * gq))


# --- contact geometry: the gap over the contacts not touching (shared by the event search and the
# exact reference)

@njit(cache=True, nogil=True, error_model="numpy")
def gap(q, prm, mask):
    """min over the constraints not masked of phi_i(q) (+inf if all are masked)."""
    if NCON == 1:
        return sys_phi(q, prm) if mask[0] == 0 else np.inf
    phis = scratch(NCON)
    sys_phis(q, prm, phis)
    g = np.inf
    for i in range(NCON):
        if mask[i] == 0 and phis[i] < g:
            g = phis[i]
    return g


@njit(cache=True, nogil=True, error_model="numpy")
def gap_slope(q, p, prm, mask):
    """d/dtau of the gap along the flow through (q, p): grad phi_k . M^-1 p, k its smallest unmasked phi_i."""
    if NCON == 1:
        return gdot(q, p, prm) if mask[0] == 0 else np.nan
    phis = scratch(NCON)
    sys_phis(q, prm, phis)
    k = -1
    for i in range(NCON):
        if mask[i] == 0 and (k < 0 or phis[i] < phis[k]):
            k = i
    if k < 0:
        return np.nan
    u = scratch(NCON)
    _normal_velocities_into(q, p, prm, u)
    return u[k]


@njit(cache=True, nogil=True, error_model="numpy")
def normal_velocities(q, p, prm):
    """u_i = grad phi_i(q) . M(q)^-1 p for every constraint (a new array)."""
    u = np.empty(NCON)
    _normal_velocities_into(q, p, prm, u)
    return u


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _normal_velocities_into(q, p, prm, u):
    gv = scratch(DPHI_NNZ)
    sys_dphis_nz(q, prm, gv)
    _normal_velocities_nz(q, p, prm, gv, u)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _normal_velocities_nz(q, p, prm, gv, u):
    """u = G M(q)^-1 p with G's structural nonzeros gv at q given (sys_dphis_nz). Row i's sum takes
    its nonzeros in column order: the dense sum's terms but for its zero products, which leave a
    finite sum unchanged (the same numbers where M^-1 p is finite)."""
    A = scratch2(NDOF, NDOF)
    x = scratch(NDOF)
    for i in range(NDOF):
        x[i] = p[i]
    sys_M(q, prm, A)
    if not solve_band(A, x, NDOF, BAND, 0.0):
        for i in range(NCON):
            u[i] = np.nan
        return
    for i in range(NCON):
        s = 0.0
        for k in range(DPHI_ROW[i], DPHI_ROW[i + 1]):
            s += gv[k] * x[DPHI_COL[k]]
        u[i] = s


@njit(cache=True, nogil=True, error_model="numpy")
def touching_mask(q, p, h, event_tol, prm, mask, held):
    """mask[i] = 1 for the contacts touching at (q, p) and not approaching, or approaching by less
    than the round-off of phi_i within a step (see the unit's header), and for the held ones (they
    move on phi_i = 0); returns how many. For one constraint nothing but a held contact is masked."""
    k = 0
    for i in range(NCON):
        mask[i] = 1 if held[i] != 0 else 0
        k += mask[i]
    if NCON == 1:
        return k
    phis = scratch(NCON)
    sys_phis(q, prm, phis)
    gv = scratch(DPHI_NNZ)
    sys_dphis_nz(q, prm, gv)
    u = scratch(NCON)
    _normal_velocities_nz(q, p, prm, gv, u)
    qn = 0.0
    for j in range(NDOF):
        qn = max(qn, abs(q[j]))
    for i in range(NCON):
        if mask[i] != 0:
            continue
        if u[i] >= 0.0:
            # (the tolerance is >= 0: a contact at or below its surface needs no tolerance, O(row) each)
            touching = phis[i] <= 0.0 or phis[i] <= _touch_tolerance_nz(qn, gv, i, u[i], h, event_tol)
        else:
            # approaching by less than its gap's round-off within a step: the search cannot resolve
            # that approach (docs/derivations/contacts.md 1.8): touching as well
            r = _touch_tolerance_nz(qn, gv, i, 0.0, h, 0.0)
            touching = phis[i] <= r and -u[i] * h <= r
        if touching:
            mask[i] = 1
            k += 1
    return k


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def unmask_penetrating(q0, q1, prm, mask, held):
    """Unmask the masked contacts (held ones aside) that the motion from q0 to q1 drives into their
    constraint: phi_i(q1) below min(phi_i(q0), 0) by more than the round-off of phi_i at q1. A
    contact whose gap only carries the rounding of bodies moving together stays masked however that
    rounding has accumulated (docs/derivations/contacts.md 1.8). Returns how many."""
    if NCON == 1:
        return 0
    phis = scratch(NCON)
    sys_phis(q1, prm, phis)
    phis0 = scratch(NCON)
    gv = scratch(DPHI_NNZ)
    have_G = False  # built at the first candidate: only a negative phi_i can be below -tolerance
    qn = 0.0
    k = 0
    for i in range(NCON):
        if mask[i] == 1 and held[i] == 0 and phis[i] < 0.0:
            if not have_G:
                sys_dphis_nz(q1, prm, gv)
                sys_phis(q0, prm, phis0)
                for j in range(NDOF):
                    qn = max(qn, abs(q1[j]))
                have_G = True
            if phis[i] < min(phis0[i], 0.0) - _touch_tolerance_nz(qn, gv, i, 0.0, 1.0, 0.0):
                mask[i] = 0
                k += 1
    return k
