"""Contacts that meet at a normal velocity at the rounding level of the state are the impact law's
degenerate case (touching, no impulse), never a failure (docs/derivations/contacts.md 1.8).

After the first impact of newton_cradle_100 balls 2..100 move together at 2/N, their velocities equal
to the error of the law's solution (~1e-13 relative); with h = 1e-3 two of them "meet" at t = 0.374
at a normal velocity of 1e-15, and their gaps random-walk by rounding: the touching mask keeps them
out of the event search (collision/impact.py touching_mask, unmask_penetrating).
"""
from __future__ import annotations

import numpy as np
import pytest

import vcirun

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("h", [1e-2, 1e-3, 1e-4])
@pytest.mark.parametrize("method", ["CVA", "VCI", "MCVAA", "MCVAC", "CVA4"])
def test_the_100_ball_cradle_runs_through_bodies_moving_together(method, h):
    N, T = 100, 1.0
    tr = vcirun.simulate("newton_cradle_100", method, h=h, T=T, energies=False)
    assert tr.status == "ok", tr.message
    # the first hit is Moreau's (1.4): ball 1 at (2 - N) / N, the others at 2 / N; nothing after it
    # changes the velocities beyond the law's rounding (every later event is balls moving together)
    v = tr.p[-1] / 1.0
    assert abs(v[0] - (2.0 - N) / N) < 1e-9 and np.max(np.abs(v[1:] - 2.0 / N)) < 1e-9
    assert abs(np.sum(tr.p[-1]) - np.sum(tr.p[0])) < 1e-10   # momentum (G^T has zero column sums)
