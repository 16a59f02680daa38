"""The exact reference's energy account with friction: the friction-work term is integrated from the
friction forces and slip velocities along the solve (vcirun.run.accounts.reference_account), so it is
checked against the closed form of the incline (-mu m g cos(theta) times the distance slid) on starts
drawn at random, and the rest of the account (H's change less the law's loss, the friction work and
the forcing work) stays at the solve's tolerance, with and without a force."""
from __future__ import annotations

import math

import numpy as np
import pytest

import vcirun
from vcirun.scenes import friction as scenes
from vcirun.scenes import friction_oracles as oracles

_RNG = np.random.default_rng(20261206)
# (theta, mu, v0): uphill and downhill starts, stopping and sticking, or sliding back down
CASES = [(float(_RNG.uniform(-0.4, 0.5)), float(_RNG.uniform(0.1, 0.6)), float(_RNG.uniform(-3.0, 3.0)))
         for _ in range(4)]


def _distance(motion, T):
    """The path length of the oracle's along-slope motion over [0, T]."""
    d = 0.0
    for t0, t1, s0, v0, a in motion.pieces:
        if t0 >= T:
            break
        tau = min(t1, T) - t0
        d += abs(v0 * tau + a * tau * tau / 2)   # (a piece never reverses: stops end pieces)
    return d


@pytest.mark.parametrize("theta, mu, v0", CASES)
def test_incline_friction_work_is_the_closed_form(theta, mu, v0):
    m, g, T = 1.3, 9.81, 1.5
    ref = vcirun.reference(scenes.incline(theta, mu=mu, v0=v0, m=m, g=g), T=T)
    acc = ref.energy_account()
    want = -mu * m * g * math.cos(theta) * _distance(oracles.incline(theta, mu=mu, v0=v0, g=g), T)
    got = acc.total("friction work")
    assert got == pytest.approx(want, rel=1e-8, abs=1e-10)
    assert abs(acc.error) <= 1e-8 * max(1.0, abs(want))


def test_pushed_block_account_closes_with_force_and_friction():
    """A force does work and friction removes it while the block slides: the two terms and H's change
    leave a rest at the solve's tolerance."""
    ref = vcirun.reference(scenes.pushed_block(), T=3.0)
    acc = ref.energy_account()
    names = {x.name for x in acc.terms}
    assert {"friction work", "forcing work"} <= names
    assert acc.total("friction work") < 0.0
    assert abs(acc.error) <= 1e-7 * max(1.0, abs(acc.total("friction work")))
