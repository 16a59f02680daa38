# numba source unit: the reset R^CVA (eq. 32): the continuous-time impact law.
# Signature shared by every reset:
#   reset(q, pm, d, s0, dE, E_pre, vpre, dtau, tau_rem, h, t, prm, ntol, maxit, pp) -> (iterations
#   (< 0 on failure), s), pp = pm + s d = p(t_i^+). q is the impact configuration at the impact time t,
#   pm = p(t_i^-); d, s0, dE: the impact law's direction, Newton multiplier and continuous energy loss
#   (collision/impact.py: d = grad phi, s0 = R^CVA's lambda for one elastic contact, dE = 0);
#   E_pre, vpre, dtau: discrete energy, mean velocity and length of the partial step that reached the
#   impact (R^VCI's energy condition; the others ignore them).
import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def reset_cva(q, pm, d, s0, dE, E_pre, vpre, dtau, tau_rem, h, t, prm, ntol, maxit, pp):
    """R^CVA: q unchanged, pp = pm + s0 d: Newton's law (elastic: H conserved, lam != 0; restitution e:
    u+ = -e u-; several contacts: Moreau's law), an impulse, so forcing does not enter."""
    for i in range(NDOF):
        pp[i] = pm[i] + s0 * d[i]
    return 1, s0
