# numba source unit: the declared reset map of a constraint (vcirun.mechanics.hybrid) at an impact:
# the impact law's result (only when the constraint declares plastic or a restitution: RESET_LAW_FIRST)
# taken through the map (q-, qdot-) -> (q+, qdot+), and the continuous energy the map removes, which
# the method's reset then carries into its own energy condition (docs/derivations/declared_resets.md).
from numba import njit

from vcirun.codegen.frame import scratch, scratch2
from vcirun.codegen.roles import NDOF, RESET_LAW_FIRST, sys_M, sys_reset_map
from vcirun.maps.dynamics import hamiltonian, velocity_guess


@njit(cache=True, nogil=True, error_model="numpy")
def declared_reset(q, pm, d, s0, prm, qp, pmap):
    """(qp, pmap) = (q+, p+ = M(q+) qdot+) of the declared map at the impact (q, pm), from qdot- =
    M(q)^-1 (pm + s0 d) when the impact law acts first (s0, d: its multiplier and direction), from
    M(q)^-1 pm otherwise. Returns dE = H(q, pm) - H(q+, p+), the continuous energy the reset removes."""
    pl = scratch(NDOF)
    s = s0 if RESET_LAW_FIRST else 0.0
    for i in range(NDOF):
        pl[i] = pm[i] + s * d[i]
    v = scratch(NDOF)
    velocity_guess(q, pl, prm, v)
    vo = scratch(NDOF)
    sys_reset_map(q, v, prm, qp, vo)
    A = scratch2(NDOF, NDOF)
    sys_M(qp, prm, A)
    for i in range(NDOF):
        acc = 0.0
        for j in range(NDOF):
            acc += A[i, j] * vo[j]
        pmap[i] = acc
    return hamiltonian(q, pm, prm) - hamiltonian(qp, pmap, prm)
