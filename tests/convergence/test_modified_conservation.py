"""Truncated modified Hamiltonians along smooth trajectories of the full-step maps: the
variation max - min of H~^{O(h^s)} over a fixed time interval shrinks like h^s.

Trajectories: the cart-pendulum from Xi(3.2) with the constraint ignored, over [0, 0.7] (up to just
before the first impact of the constrained motion), full steps of the Ld's own map. The generated code
runs uncompiled (vcirun.codegen.evaluate.python_module), so no numba compile is needed here.
"""
from __future__ import annotations

import numpy as np
import pytest

from convergence.helpers import fit_order
from vcirun.scenes.registry import get_scene
from vcirun.codegen.evaluate import python_module

SYSTEM = get_scene("cart_pendulum")
PRM = SYSTEM.param_values()
Q0, P0 = SYSTEM.initial_state(beta=3.2)
T = 0.7
HS = (0.02, 0.01, 0.005, 0.0025)
TOL = 0.3

_traj_cache: dict = {}


def trajectory(ld, h):
    """Grid states of Phi_h^{Ld} on [0, T] (constraint ignored)."""
    if (ld, h) not in _traj_cache:
        mod = python_module(SYSTEM, ld, 1, 4)
        N = int(round(T / h))
        Q, P = np.empty((N + 1, 2)), np.empty((N + 1, 2))
        Q[0], P[0] = Q0, P0
        q1, p1, v = np.empty(2), np.empty(2), np.empty(2)
        for k in range(N):
            it, _ = mod.ld_step(Q[k], P[k], h, k * h, PRM, 1e-14, 50, q1, p1, v)
            assert it >= 0
            Q[k + 1], P[k + 1] = q1, p1
        _traj_cache[ld, h] = (Q, P)
    return _traj_cache[ld, h]


def variation(ld, s, h):
    mod = python_module(SYSTEM, ld, s, 4)
    Q, P = trajectory(ld, h)
    Hm = np.array([mod.mh_energy(q, p, h, PRM) for q, p in zip(Q, P)])
    assert np.all(np.isfinite(Hm))
    return float(np.ptp(Hm)), float(np.mean(np.abs(Hm)))


@pytest.mark.parametrize("s", [1, 2, 3, 4])
@pytest.mark.parametrize("ld", ["SVC", "midpoint", "SVA"])
def test_truncated_mh_variation_order(ld, s):
    res = [variation(ld, s, h) for h in HS]
    errs = [r[0] for r in res]
    slope, used = fit_order(HS, errs, scale=res[0][1])
    assert used.sum() >= 3
    assert abs(slope - s) <= TOL, f"{ld} s={s}: slope {slope:.3f}, variations {errs}"


def test_mcvaa_truncation_reaches_order_4_and_beats_order_3():
    """MCVAA's H~^{O(h^4)} (with H4) conserves to order 4; without H4 only to order 3 (H4 != 0)."""
    v3 = [variation("SVA", 3, h)[0] for h in HS]
    v4 = [variation("SVA", 4, h)[0] for h in HS]
    s3, _ = fit_order(HS, v3)
    s4, _ = fit_order(HS, v4)
    assert abs(s4 - 4) <= TOL and abs(s3 - 3) <= TOL
    assert v4[-1] < 0.05 * v3[-1]


def test_truncated_mh_beats_H_and_eta():
    """At h = 0.01 the third-order truncation of SVC varies far less than H (order 2) along the same
    trajectory, and eta alone (order 1) far more: the series is what makes the MH useful."""
    h = 0.01
    Q, P = trajectory("SVC", h)
    mod = python_module(SYSTEM, "SVC", 3, 4)
    H = np.array([mod.hamiltonian(q, p, PRM) for q, p in zip(Q, P)])
    v1, v3 = variation("SVC", 1, h)[0], variation("SVC", 3, h)[0]
    assert v3 < 0.2 * np.ptp(H) < 0.2 * v1
