# numba source unit: the one stopping rule of the loop's Newton solves (the full map's explicit
# steps in maps/steps.py, the held stage in maps/held.py, R^VCI's joint solve in
# collision/reset_vci.py). It needs no generated name.
import math

from numba import njit

NEWTON_GO_ON = 0
NEWTON_CONVERGED = 1
NEWTON_DIVERGED = -1


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def newton_stop(it, dn, dprev, xn, ntol, contraction):
    """After Newton correction number `it` (1, 2, ...) of max-norm dn on an iterate of max-norm xn
    (dprev: the previous correction's norm, inf on the first): NEWTON_CONVERGED, NEWTON_DIVERGED
    (a correction that is not finite) or NEWTON_GO_ON. The tests, in order:

    - dn <= ntol (1 + xn): converged.
    - contraction (only where the caller asks for it; the full map's steps do): in the quadratic
      phase with the exact Jacobian and contraction theta = dn / dprev < 0.1, the error left after
      this correction is at most theta / (1 - theta) dn (the bound under mere linear convergence, so
      it is conservative; Hairer & Wanner's stopping rule for simplified Newton). Once it is below
      ntol (1 + xn) the next iteration could only confirm it: stopping saves it (a third of a smooth
      step). The map then honours ntol, not round-off: it carries noise up to ~ntol relative
      (measured: symplecticity defect and orders unchanged). The held stage and R^VCI's solve do not
      take this stop: they run the one more iteration (their trajectories are those of that rule).
    - the round-off floor: past the quadratic phase (it >= 3) a correction that no longer decreases
      yet is below sqrt(ntol) (1 + xn) is rounding noise. With an ill-conditioned Jacobian (nearly
      singular M, cond ~ 1e4 and up) the floor lies above ntol, and without this test Newton cycles
      between two neighbouring floats until its iteration cap and reports newton_failed on a regular
      step (double pendulum with m1 = 1e-4, cart-pendulum with m2/m1 = 1e4)."""
    if not math.isfinite(dn):
        return NEWTON_DIVERGED
    if dn <= ntol * (1.0 + xn):
        return NEWTON_CONVERGED
    if contraction:
        theta = dn / dprev  # (dprev = inf on the first iteration: no rate known, theta = 0 ignored)
        if it >= 2 and theta < 0.1 and theta / (1.0 - theta) * dn <= ntol * (1.0 + xn):
            return NEWTON_CONVERGED
    if it >= 3 and dn >= dprev and dn <= math.sqrt(ntol) * (1.0 + xn):
        return NEWTON_CONVERGED
    return NEWTON_GO_ON
