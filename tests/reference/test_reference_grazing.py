"""The exact reference finds near-grazing impacts (a dip below phi = 0 shorter than one DOP853 step)
and short hops after a reset, against the oscillator's closed form. A sign test between steps alone
misses such a dip (2 of the 3 impacts at eps = 1e-4, all 3 at eps = 1e-6); the Taylor path isolates
every root of phi in each step."""
from __future__ import annotations

import numpy as np
import pytest

import vcirun
from vcirun.scenes.oracles import oscillator_wall_exact


@pytest.mark.parametrize("eps", [1e-2, 1e-4, 1e-6, 1e-8])
def test_near_grazing_impacts_are_found(eps):
    A = 0.5 * (1 + eps)      # amplitude just above the wall distance d = 0.5: the dip lasts ~2 sqrt(2 eps)
    T = 20.0
    ref = vcirun.reference("oscillator_wall", T=T, q0=np.array([A]), p0=np.array([0.0]))
    tt = np.linspace(0.0, T, 20001)
    x, _, ti = oscillator_wall_exact(tt, A, 0.0)
    ti = ti[ti <= T]
    assert len(ref.impacts) == len(ti) == 3
    np.testing.assert_allclose(ref.impacts, ti, rtol=0, atol=1e-7)
    # near grazing the impact time is ill conditioned (d t_impact / d A ~ 1 / sqrt(eps))
    assert np.max(np.abs(ref(tt)[:, 0] - x)) < 1e-9 / np.sqrt(eps) * 1e-1 + 1e-10
