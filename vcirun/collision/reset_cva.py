# numba source unit: the reset R^CVA (eq. 32): the continuous-time impact law. Its signature is the
# role `reset` of vcirun.codegen.roles (what every argument means); its row: roles.RESETS["cva"].
from numba import njit

from vcirun.codegen.roles import NDOF


@njit(cache=True, nogil=True, error_model="numpy")
def reset_cva(q, pm, d, s0, dE, E_pre, vpre, dtau, tau_rem, h, t, prm, ntol, maxit, pp):
    """R^CVA: q unchanged, pp = pm + s0 d: Newton's law (elastic: H conserved, lam != 0; restitution e:
    u+ = -e u-; several contacts: Moreau's law), an impulse, so forcing does not enter."""
    for i in range(NDOF):
        pp[i] = pm[i] + s0 * d[i]
    return 1, s0
