"""simulate(energies=False): the same trajectory, H, Ed and Hmod skipped along the grid (the
timed comparison with solve_ivp, whose timed call does not evaluate H either)."""
from __future__ import annotations

import numpy as np
import pytest

import vcirun


@pytest.mark.parametrize("method", ["CVA", "MCVAC"])
def test_energies_off_gives_the_same_trajectory(method):
    a = vcirun.simulate("cart_pendulum", method, h=2e-2, T=2.0, beta=3.2)
    b = vcirun.simulate("cart_pendulum", method, h=2e-2, T=2.0, beta=3.2, energies=False)
    assert a.status == b.status == "ok" and len(a.impacts) == len(b.impacts) >= 1
    for f in ("q", "p", "impacts", "impact_p_plus"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    assert np.all(np.isfinite(a.H)) and b.H[0] == a.H[0] and np.all(np.isnan(b.H[1:]))
    assert np.all(np.isfinite(a.Ed)) and b.Ed[0] == a.Ed[0] and np.all(np.isnan(b.Ed[1:]))
    if method == "MCVAC":
        assert b.Hmod[0] == a.Hmod[0] and np.all(np.isnan(b.Hmod[1:]))
