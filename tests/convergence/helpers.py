"""Numerical helpers for the convergence and structure tests.

They live in the package (vcirun.verification) so that the test suite and `vcirun verify` share
one implementation; this module keeps the names the tests import:

fit_order     : the ONE observed-order estimator used by every order test (round-off plateau masked)
exact_smooth  : DOP853 (rtol 1e-13) on Hamilton's equations from the compiled hamilton_rhs
step, run_map : one step / N steps of a compiled one-step map Phi_h (mod.ld_step) from Python
map_jacobian  : d Phi_h / d(q, p) by a 4th-order central difference stencil
omega, symplecticity_defect : max |J^T Omega J - Omega|
drift_slope   : least-squares slope (with 95% CI) of windowed max |H - H0| against time
"""
from __future__ import annotations

from vcirun.verification.fd import map_jacobian, omega, symplecticity_defect
from vcirun.verification.harness import exact_smooth, run_map, step
from vcirun.verification.orders import EPS, drift_slope, fit_order

__all__ = ["EPS", "fit_order", "exact_smooth", "step", "run_map", "map_jacobian", "omega", "symplecticity_defect",
           "drift_slope"]
