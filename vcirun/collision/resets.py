# numba source unit: reset maps R^CVA (eq. 32) and R^VCI (eq. 33).
# Signature shared by every reset: reset(q, pm, E_pre, tau_rem, h, t, prm, ntol, maxit, pp)
#   -> (iterations (< 0 on failure), lambda). q is the impact configuration, pm = p(t_i^-).
import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def cva_lambda(q, pm, prm, g):
    """Nontrivial root of H(q, pm + lam g) = H(q, pm): H is quadratic in p, so
    lam = -2 g^T M^-1 pm / g^T M^-1 g (the root lam = 0 is divided out)."""
    sys_dphi(q, prm, g)
    A = np.empty((NDOF, NDOF))
    sys_M(q, prm, A)
    x = g.copy()
    if not solve_small(A, x, NDOF):
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
def reset_cva(q, pm, E_pre, tau_rem, h, t, prm, ntol, maxit, pp):
    """R^CVA: q unchanged, pp = pm + lam grad phi, H conserved, lam != 0."""
    g = np.empty(NDOF)
    lam = cva_lambda(q, pm, prm, g)
    if lam == 0.0 or not math.isfinite(lam):
        return -1, lam  # zero normal velocity: no nontrivial reset exists
    for i in range(NDOF):
        pp[i] = pm[i] + lam * g[i]
    return 1, lam


@njit(cache=True, nogil=True, error_model="numpy")
def reset_vci(q, pm, E_pre, tau_rem, h, t, prm, ntol, maxit, pp):
    """R^VCI: pp = pm + lam grad phi with the discrete energy conserved across the impact,
    -D3 Ld(q_prev, q, tau_pre) = E_pre = -D3 Ld(q, q_next, tau_rem), pp = -D1 Ld(q, q_next, tau_rem),
    solved jointly for (w, lam), q_next = q + tau_rem w, by Newton from the R^CVA reflection (the
    root near lam = 0 is not a reflection and is rejected). The post-impact step is the remaining
    time tau_rem = tau_max - Delta tau (after the decrement of Algorithm 1, line 15), so the
    pre- and post-impact steps tile the grid step exactly."""
    g = np.empty(NDOF)
    lam0 = cva_lambda(q, pm, prm, g)
    if lam0 == 0.0 or not math.isfinite(lam0):
        return -1, lam0
    # Newton from the R^CVA reflection; near the fold (tiny normal velocity) it can fall onto the
    # non-reflecting root, so retry from larger reflections before giving up
    total = 0
    for scale in (1.0, 2.0, 4.0, 8.0, 0.5):
        it, lam = _vci_newton(q, pm, E_pre, tau_rem, t, prm, ntol, maxit, g, scale * lam0, pp)
        total += abs(it)
        if it > 0 and lam * lam0 > 0.0 and abs(lam) >= 1e-3 * abs(lam0):
            for i in range(NDOF):
                pp[i] = pm[i] + lam * g[i]
            return total, lam
    return -total, lam0


@njit(cache=True, nogil=True, error_model="numpy")
def _vci_newton(q, pm, E_pre, tau_rem, t, prm, ntol, maxit, g, lam_start, pp):
    """Newton on (w, lam) for eq. (33) from lam_start; returns (iterations or -iterations, lam)."""
    w = np.empty(NDOF)
    for i in range(NDOF):
        pp[i] = pm[i] + lam_start * g[i]
    velocity_guess(q, pp, prm, w)
    lam = lam_start
    m = NDOF + 1
    F = np.empty(m)
    JJ = np.empty((m, m))
    r = np.empty(NDOF)
    J = np.empty((NDOF, NDOF))
    ev = np.empty(NDOF)
    c = np.empty(NODE_LEN)
    sys_node(q, prm, c)  # q is fixed: its node data once, not per iteration
    it = 0
    ok = False
    dprev = np.inf
    while it < maxit:
        it += 1
        ld_PmJc(VCI_STAGE, q, w, tau_rem, t, prm, c, r, J)
        E = ld_Ed(VCI_STAGE, q, w, tau_rem, prm)
        ld_Edv(VCI_STAGE, q, w, tau_rem, prm, ev)
        for i in range(NDOF):
            F[i] = r[i] - pm[i] - lam * g[i]
            for j in range(NDOF):
                JJ[i, j] = J[i, j]
            JJ[i, NDOF] = -g[i]
            JJ[NDOF, i] = ev[i]
        JJ[NDOF, NDOF] = 0.0
        F[NDOF] = E - E_pre
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
        if not math.isfinite(dn):
            break
        if dn <= ntol * (1.0 + xn):
            ok = True
            break
        # (issue 8) round-off floor, as in explicit_step (vcirun/maps/steps.py)
        if it >= 3 and dn >= dprev and dn <= math.sqrt(ntol) * (1.0 + xn):
            ok = True
            break
        dprev = dn
    return (it if ok else -it), lam


@njit(cache=True, nogil=True, error_model="numpy")
def no_modified_energy(q, p, h, prm):
    return np.nan
