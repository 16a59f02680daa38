"""vcirun.periodic_orbit on the rimless wheel against its closed-form stride map
(vcirun.scenes.oracles.rimless_wheel_fixed_point): the fixed-point speed and the multiplier to 1e-10
with CVA4 at a fine step, and each method's error converging at its order."""
from __future__ import annotations

import numpy as np
import pytest

from vcirun.experiments.periodic import periodic_orbit
from vcirun.scenes.data import rimless_wheel
from vcirun.scenes.oracles import rimless_wheel_fixed_point

PRM = rimless_wheel().params
GAIT = rimless_wheel_fixed_point(**PRM)
ML2 = PRM["m"] * PRM["l"] ** 2


def _errors(method, h):
    orb = periodic_orbit("rimless_wheel", method, h=h, guess=([-PRM["alpha"]], [1.1 * ML2 * GAIT.omega]))
    (q, p), lam = orb.fixed_point, orb.eigenvalues
    assert q[0] == pytest.approx(-PRM["alpha"], abs=1e-13)          # on the section
    assert abs(lam[1]) < 1e-6                                        # the section's trivial multiplier
    return abs(p[0] / ML2 - GAIT.omega), abs(lam[0].real - GAIT.eigenvalue), abs(orb.period - GAIT.period)


def test_rimless_wheel_fixed_point_to_1e10():
    e_w, e_lam, e_T = _errors("CVA4", 2e-3)
    print(f"CVA4 h=2e-3: |omega - omega*| = {e_w:.2e}, |lambda - cos^2(2 alpha)| = {e_lam:.2e}, |T - T*| = {e_T:.2e}")
    assert e_w <= 1e-10 and e_lam <= 1e-10 and e_T <= 1e-10


@pytest.mark.parametrize("method, order", [("CVA", 2), ("VCI", 2), ("CVA4", 4), ("MCVAC", 2)])
def test_rimless_wheel_converges_at_the_method_order(method, order):
    hs = (0.04, 0.02, 0.01)
    errs = np.array([_errors(method, h) for h in hs])
    rates = np.log2(errs[:-1] / errs[1:])
    print(method, "errors (omega, lambda, T):", errs.tolist(), "rates:", rates.tolist())
    # speed, multiplier and period at (at least) the method's order; the multiplier's error is not
    # monotone in h (DP changes where the impact crosses a grid point) and mostly converges faster
    assert np.all(rates > order - 0.3), (method, rates)
