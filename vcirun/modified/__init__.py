"""Backward error analysis from the discrete Lagrangian and the MCVA family (Sections 3.4, 4.3-4.4).

Symbolic only (this package never imports vcirun.codegen or vcirun.methods.table):
- `series.py`: the symplectic-Euler backward-error functionals H_i[K], derived from the
  Hamilton-Jacobi equation (every VI is symplectic Euler applied to eta, eq. 23-24).
- `eta.py`: eta as a stationary value, its exact derivatives (implicit function theorem on a DAG
  of symbolic nodes) and H~^{O(h^s)} in them; vcirun/codegen/mh_kernels.py emits their kernels.
- the numba units that evaluate them live in vcirun/maps/gauss.py (mh_energy, gauss_partial) and
  vcirun/collision/reset_mcva.py (reset_mcva), compiled into the scene's module by vcirun.codegen.
The generated module executed uncompiled (tests, exploration): vcirun/codegen/evaluate.py.

`vcirun.methods.table.generalized_mcva(ld, mh_order, flow_order)` returns the Method of Section 4.4 (its
options checked by `check_mcva_options` here); MCVAA and MCVAC (Section 5.2) are entries of
vcirun.methods.table.METHODS.

What checking the paper found (tests/convergence/test_modified_series.py):
- H4 does NOT vanish for SVA (Section 5.2 claims it does). The eta-based series depends on h through
  eta itself, so the symmetric method's vanishing h^3 coefficient is shared between eta, H2, H3 and
  H4: H4[eta_SVA] -> H4[H] (SE1's h^3 term, ~6.5 at a generic cart-pendulum state) as h -> 0. Without
  H4 the SVA truncation is conserved to order 3, with it to order 4; MCVAA keeps H4.
- In n > 1 dimensions the mixed term of H3 is 4 sum_ij K_{q_i p_j} K_{p_i} K_{q_j} (the q-slot takes
  K_p); Appendix A's D1D2 eta (D1 eta, D2 eta) read literally contracts the other way (same for n = 1).
- Appendix A step 2 prints D_pp qbar and D_qp qbar with the wrong sign (finite differences decide);
  D_q qbar, D_p qbar and D_qq qbar (given the corrected D_qp qbar) are right. Nothing here uses them.
- mh_order = 1 (eta alone) makes every impact cost O(h): the reset conserves eta = H + O(h).
"""
from __future__ import annotations

from ..discrete.lagrangians import LIBRARY

SUPPORTED_MH_ORDERS = (1, 2, 3, 4)
# The discrete Lagrangians of the paper. The high-order SVC compositions (SVC4/6/8: 5, 9, 17 stages)
# would make eta a stationary value over 4-16 interior nodes; their MCVA is not derived.
MH_LDS = ("SE1", "SE2", "SVA", "SVB", "SVC", "midpoint")
FLOW_ORDERS = (4, 6)


def check_mcva_options(ld: str = "SVC", mh_order: int = 3, flow_order: int = 4, **unknown) -> tuple:
    """(ld, mh_order, flow_order) of a generalized MCVA (Section 4.4), validated: full steps of
    discrete Lagrangian `ld`, partial steps by the `flow_order` Gauss collocation flow of the truncated
    modified Hamiltonian H~^{O(h^mh_order)}, reset R^MCVA conserving that truncation. Raises ValueError
    naming the offending field. (vcirun.methods.table.generalized_mcva makes the Method.)"""
    if unknown:
        raise ValueError(f"options: {sorted(unknown)[0]!r} is not an option of method MCVA "
                         "(use ld=, mh_order=, flow_order=)")
    if not isinstance(ld, str) or ld not in LIBRARY:
        raise ValueError(f"ld: unknown discrete Lagrangian {ld!r} (choose one of {', '.join(LIBRARY)})")
    if ld not in MH_LDS:
        raise ValueError(f"ld: the modified Hamiltonian of {ld} (a {len(LIBRARY[ld].stages)}-stage composition) "
                         f"is not derived; MCVA takes one of {', '.join(MH_LDS)} (for {ld} with impacts use CVA)")
    if isinstance(mh_order, bool) or not isinstance(mh_order, int) or mh_order not in SUPPORTED_MH_ORDERS:
        raise ValueError(f"mh_order: {mh_order!r} is not supported (choose one of "
                         f"{', '.join(map(str, SUPPORTED_MH_ORDERS))}: the truncation H~^{{O(h^s)}} = eta + ... + "
                         "h^(s-1) H_s)")
    if isinstance(flow_order, bool) or not isinstance(flow_order, int) or flow_order not in FLOW_ORDERS:
        raise ValueError(f"flow_order: {flow_order!r} is not supported (choose one of "
                         f"{', '.join(map(str, FLOW_ORDERS))}: 2- or 3-stage Gauss collocation)")
    if flow_order < mh_order:
        raise ValueError(f"flow_order: {flow_order} is below mh_order {mh_order} (the partial flow must "
                         "solve the modified equations to at least the truncation's order)")
    return ld, mh_order, flow_order
