# numba source unit: the reset R^MCVA (eq. 34) of the MCVA family, conserving the truncated modified
# Hamiltonian H~^{O(h^s)} (with restitution: losing what Newton's law removes from H, docs/derivations/contacts.md).
# Signature: the role `reset` of vcirun.codegen.roles; row: roles.RESETS["mcva"].
import math

from numba import njit

from vcirun.codegen.frame import scratch, scratch2
from vcirun.codegen.roles import NDOF, MH_M, RESET_MAP
from vcirun.maps.gauss import mh_guess, mh_gradient

MH_RESET_ETOL = 8.0 * 2.220446049250313e-16  # R^MCVA accepts lam once H~ is conserved to this (relative)


@njit(cache=True, nogil=True, error_model="numpy")
def reset_mcva(q, pm, d, s0, dE, E_pre, vpre, dtau, tau_rem, h, t, prm, ntol, maxit, pp):
    """R^MCVA (eq. 34): pp = pm + lam d with H~^{O(h^s)}(q, pp) = H~^{O(h^s)}(q, pm) - dE, lam != 0
    (d = grad phi(q) for one contact; dE = 0 for elastic impacts: the paper's reset).
    Newton on F(lam) = [H~(q, pm + lam d) - H~(q, pm) + dE] / lam, whose root set excludes the trivial
    root lam = 0 (F(0) = dH~/dp . d, the normal velocity, is nonzero at a transversal elastic impact);
    F'(lam) = (dH~/dp . d - F) / lam. Start: the impact law's s0 (exact for H, H~ = H + O(h)).
    Converged when the Newton step is below ntol (1 + |lam|), or when H~ is already conserved to
    8 eps (relative): at small lam, F = dE / lam is only known to ~eps |H~| / lam. Failure (< 0) when
    Newton does not converge or lam has not the sign of the reflection (then lam is returned too).
    Forcing does not enter: the reset is an impulse, and bounded forces do no work in zero time."""
    g = d
    lam0 = s0
    if RESET_MAP and lam0 == 0.0:
        # only a system with a declared map asks for its root near 0; elsewhere s0 = 0 is a grazing
        # contact, a failure rather than the trivial root
        return _mcva_declared(q, pm, d, dE, h, prm, ntol, maxit, pp)
    if not math.isfinite(lam0):
        return -1, lam0
    nz = 2 * NDOF
    u = scratch(MH_M)
    W = scratch2(MH_M, MH_M)
    grad = scratch(nz)
    hess = scratch2(0, 0)  # not needed by the reset
    mh_guess(q, pm, prm, u)
    it0, E0 = mh_gradient(q, pm, h, prm, u, W, grad, hess)
    if it0 < 0 or not math.isfinite(E0):
        return -1, lam0
    lam = lam0
    it = 0
    ok = False
    while it < maxit:
        it += 1
        for i in range(NDOF):
            pp[i] = pm[i] + lam * g[i]
        if it == 1:
            mh_guess(q, pp, prm, u)  # later iterates start from the previous stationary point
        itu, E = mh_gradient(q, pp, h, prm, u, W, grad, hess)
        if itu < 0 or not math.isfinite(E):
            break
        gap = E - E0 + dE
        if abs(gap) <= MH_RESET_ETOL * max(1.0, abs(E0)):
            ok = True  # balanced to round-off (a small lam pins F = gap / lam only to ~eps |E| / lam)
            break
        Fl = gap / lam
        gp = 0.0
        for i in range(NDOF):
            gp += grad[NDOF + i] * g[i]
        dF = (gp - Fl) / lam
        if dF == 0.0 or not math.isfinite(dF):
            break
        step = Fl / dF
        lam -= step
        if abs(step) <= ntol * (1.0 + abs(lam)):
            ok = True
            break
    if not ok or not (lam * lam0 > 0.0):
        # no reflection: lam of the other sign means the modified dynamics already leaves the wall
        # (possible at grazing, |normal velocity| ~ h); lam = 0 cannot be returned as a success
        return -it, lam
    for i in range(NDOF):
        pp[i] = pm[i] + lam * g[i]
    return it, lam


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _mcva_declared(q, pm, d, dE, h, prm, ntol, maxit, pp):
    """R^MCVA after a declared reset map (collision/declared.py): pm = d = the map's p+ at the
    post-impact q, and the caller's dE makes the target H~(q, pm) - dE the pre-impact H~ less the
    energy the map removes (docs/derivations/declared_resets.md). Newton on H~(q, pm + lam d) =
    H~(q, pm) - dE from lam = 0 (the root is O(h^r)); returns (iterations, < 0 on failure; lam)."""
    nz = 2 * NDOF
    u = scratch(MH_M)
    W = scratch2(MH_M, MH_M)
    grad = scratch(nz)
    hess = scratch2(0, 0)
    mh_guess(q, pm, prm, u)
    it0, E0 = mh_gradient(q, pm, h, prm, u, W, grad, hess)
    if it0 < 0 or not math.isfinite(E0):
        return -1, 0.0
    target = E0 - dE
    lam = 0.0
    it = 0
    while it < maxit:
        it += 1
        for i in range(NDOF):
            pp[i] = pm[i] + lam * d[i]
        itu, E = mh_gradient(q, pp, h, prm, u, W, grad, hess)
        if itu < 0 or not math.isfinite(E):
            return -it, lam
        gap = E - target
        if abs(gap) <= MH_RESET_ETOL * max(1.0, abs(E0)):
            return it, lam
        gp = 0.0
        for i in range(NDOF):
            gp += grad[NDOF + i] * d[i]
        if gp == 0.0 or not math.isfinite(gp):
            return -it, lam
        step = gap / gp
        lam -= step
        if abs(step) <= ntol * (1.0 + abs(lam)):
            for i in range(NDOF):
                pp[i] = pm[i] + lam * d[i]
            return it, lam
    return -it, lam
