# numba source unit: the reset R^CVA (eq. 32): the continuous-time elastic impact law.
# Signature shared by every reset: reset(q, pm, E_pre, vpre, dtau, tau_rem, h, t, prm, ntol, maxit, pp)
#   -> (iterations (< 0 on failure), lambda). q is the impact configuration at the impact time t,
#   pm = p(t_i^-); E_pre, vpre, dtau: discrete energy, mean velocity and length of the partial step
#   that reached the impact (R^VCI's energy condition; the others ignore them); pp receives p(t_i^+).
import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def reset_cva(q, pm, E_pre, vpre, dtau, tau_rem, h, t, prm, ntol, maxit, pp):
    """R^CVA: q unchanged, pp = pm + lam grad phi, H conserved, lam != 0 (an impulse: bounded forces
    do no work in zero time, so forcing does not enter)."""
    g = np.empty(NDOF)
    lam = cva_lambda(q, pm, prm, g)
    if lam == 0.0 or not math.isfinite(lam):
        return -1, lam  # zero normal velocity: no nontrivial reset exists
    for i in range(NDOF):
        pp[i] = pm[i] + lam * g[i]
    return 1, lam
