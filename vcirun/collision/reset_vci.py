# numba source unit: the reset R^VCI (eq. 33), with forcing (docs/derivations/forcing.md) and restitution
# (docs/derivations/contacts.md). Signature: the role `reset` of vcirun.codegen.roles; row: roles.RESETS["vci"].
import math

import numpy as np
from numba import njit

from vcirun.codegen.frame import scratch, scratch2
from vcirun.codegen.roles import (
    NDOF, NODE_LEN, FORCED, EDV_STAGE, FORCE_A, FORCE_B, sys_node, sys_force, sys_force_jac, ld_PmJc, ld_Ed, ld_Edv, RESET_MAP
)
from vcirun.maps.dynamics import velocity_guess, force_power
from vcirun.maps.linalg import solve_small
from vcirun.maps.newton import NEWTON_CONVERGED, NEWTON_GO_ON, newton_stop


@njit(cache=True, nogil=True, error_model="numpy")
def reset_vci(q, pm, d, s0, dE, E_pre, vpre, dtau, tau_rem, h, t, prm, ntol, maxit, pp):
    """R^VCI: pp = pm + s d with the discrete energy balanced across the impact,
    -D3 Ld(q, q_next, tau_rem) = E_pre + W^+ + W^- - dE, pp = -D1 Ld(q, q_next, tau_rem) - f^-,
    solved jointly for (w, s), q_next = q + tau_rem w, by Newton from the impact law's s0 (the root
    near s = 0 is not a reflection and is rejected). The post-impact step is the remaining time
    tau_rem = tau_max - Delta tau (after the decrement of Algorithm 1, line 15), so the pre- and
    post-impact steps tile the grid step exactly.

    Forcing (docs/derivations/forcing.md): the discrete Lagrange-d'Alembert principle with the impact time as a
    variable gives the energy condition E^+ = E^- + f^+_pre . v_pre + f^-_post . v_post, the discrete
    work of the force over the half of each partial step next to the impact, W^+ = b dtau f(q, vpre,
    t) . vpre and W^-(w) = a tau_rem f(q, w, t) . w with the Ld's discrete-force weights (a, b).
    Restitution (docs/derivations/contacts.md): the discrete energy loses what Newton's law removes from H, dE
    (0 for elastic impacts). Unforced and elastic: the paper's eq. (33). s0 = 0: a declared reset
    map, whose p+ is pm (and d) at the post-impact q; the root near 0 is wanted."""
    if not math.isfinite(s0):
        return -1, s0
    E_target = E_pre - dE
    if FORCED:
        E_target += FORCE_B[EDV_STAGE] * dtau * force_power(q, vpre, t, prm)
    if RESET_MAP and s0 == 0.0:
        # a declared reset map (collision/declared.py): pm is the map's p+ at the post-impact q and d
        # = pm; the root near lam = 0 (pp = (1 + lam) p+, lam = O(h^2)) balances the discrete energy
        # with the energy the map removes (docs/derivations/declared_resets.md)
        it, lam = _vci_newton(q, pm, E_target, tau_rem, t, prm, ntol, maxit, d, 0.0, pp)
        if it < 0:
            return it, lam
        for i in range(NDOF):
            pp[i] = pm[i] + lam * d[i]
        return it, lam
    # Newton from the impact law's multiplier; near the fold (tiny normal velocity) it can fall onto
    # the non-reflecting root, so retry from larger multipliers before giving up
    total = 0
    for scale in (1.0, 2.0, 4.0, 8.0, 0.5):
        it, lam = _vci_newton(q, pm, E_target, tau_rem, t, prm, ntol, maxit, d, scale * s0, pp)
        total += abs(it)
        if it > 0 and lam * s0 > 0.0 and abs(lam) >= 1e-3 * abs(s0):
            for i in range(NDOF):
                pp[i] = pm[i] + lam * d[i]
            return total, lam
    return -total, s0


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _vci_newton(q, pm, E_target, tau_rem, t, prm, ntol, maxit, g, lam_start, pp):
    """Newton on (w, lam) for eq. (33) (forced: its energy condition with the work terms, see
    reset_vci) from lam_start; returns (iterations or -iterations, lam)."""
    w = scratch(NDOF)
    for i in range(NDOF):
        pp[i] = pm[i] + lam_start * g[i]
    velocity_guess(q, pp, prm, w)
    lam = lam_start
    m = NDOF + 1
    F = scratch(m)
    JJ = scratch2(m, m)
    r = scratch(NDOF)
    J = scratch2(NDOF, NDOF)
    ev = scratch(NDOF)
    c = scratch(NODE_LEN)
    fo = scratch(NDOF)
    fq = scratch2(NDOF, NDOF)
    fv = scratch2(NDOF, NDOF)
    aw = FORCE_A[EDV_STAGE] * tau_rem  # W^-(w) = aw f(q, w, t) . w
    sys_node(q, prm, c)  # q is fixed: its node data once, not per iteration
    it = 0
    ok = False
    dprev = np.inf
    while it < maxit:
        it += 1
        ld_PmJc(EDV_STAGE, q, w, tau_rem, t, prm, c, r, J)
        E = ld_Ed(EDV_STAGE, q, w, tau_rem, prm)
        ld_Edv(EDV_STAGE, q, w, tau_rem, prm, ev)
        if FORCED and aw != 0.0:
            sys_force(q, w, t, prm, fo)
            sys_force_jac(q, w, t, prm, fq, fv)
            for j in range(NDOF):
                dW = fo[j]
                for i in range(NDOF):
                    dW += fv[i, j] * w[i]
                E -= aw * fo[j] * w[j]
                ev[j] -= aw * dW
        for i in range(NDOF):
            F[i] = r[i] - pm[i] - lam * g[i]
            for j in range(NDOF):
                JJ[i, j] = J[i, j]
            JJ[i, NDOF] = -g[i]
            JJ[NDOF, i] = ev[i]
        JJ[NDOF, NDOF] = 0.0
        F[NDOF] = E - E_target
        if not solve_small(JJ, F, m):
            break
        dn = 0.0
        xn = abs(lam)
        for i in range(NDOF):
            w[i] -= F[i]
            dn = max(dn, abs(F[i]))
            xn = max(xn, abs(w[i]))
        lam -= F[NDOF]
        dn = max(dn, abs(F[NDOF]))
        stop = newton_stop(it, dn, dprev, xn, ntol, False)
        if stop != NEWTON_GO_ON:
            ok = stop == NEWTON_CONVERGED
            break
        dprev = dn
    return (it if ok else -it), lam
