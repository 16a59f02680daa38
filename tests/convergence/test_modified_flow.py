"""The MCVA partial flow and reset:

- Gauss collocation (2 stages / 3 stages) on Hamilton's equations of H~^{O(h^s)} shows order 4 / 6
  and conserves its own H~ to round-off at small steps; tau = 0 is the identity; the simplified
  Newton iteration converges at the step sizes Algorithm 1 uses (up to h = 3.2e-2).
- R^MCVA conserves H~^{O(h^s)} to 1e-12 (relative) and never returns lambda = 0; at a grazing contact
  (zero normal velocity) it reports failure instead of the trivial root.

Uncompiled generated code (vcirun.codegen.evaluate.python_module): no numba compile here.
"""
from __future__ import annotations

import numpy as np
import pytest

from convergence.helpers import fit_order
from vcirun.scenes.registry import get_scene
from vcirun.codegen.evaluate import python_module

SYSTEM = get_scene("cart_pendulum")
PRM = SYSTEM.param_values()
Y0 = (np.array([0.7, 0.4]), np.array([-1.3, 2.1]))


def flow(mod, q, p, tau, N, h, ntol=1e-15):
    q, p = q.copy(), p.copy()
    q1, p1, v = np.empty(2), np.empty(2), np.empty(2)
    iters = []
    for _ in range(N):
        it, E = mod.gauss_partial(q, p, tau, h, 0.0, PRM, ntol, 50, q1, p1, v)
        assert it >= 0 and np.isnan(E)
        iters.append(it)
        q, p = q1.copy(), p1.copy()
    return q, p, iters


@pytest.mark.parametrize("ld, s, flow_order", [("SVC", 3, 4), ("SVC", 3, 6), ("SVA", 4, 4), ("SVA", 4, 6)])
def test_gauss_order(ld, s, flow_order):
    """Self-convergence over [0, 0.4]: |y_N - y_2N| ~ (0.4/N)^order."""
    mod = python_module(SYSTEM, ld, s, flow_order)
    h = 0.02
    Ns = [2, 4, 8, 16, 32, 64]
    ys = [np.r_[flow(mod, *Y0, 0.4 / N, N, h)[:2]] for N in Ns]
    diffs = [np.abs(ys[i] - ys[i + 1]).max() for i in range(len(Ns) - 1)]
    taus = [0.4 / N for N in Ns[:-1]]
    slope, used = fit_order(taus, diffs, scale=4.0)
    assert abs(slope - flow_order) <= 0.3, (slope, diffs)


@pytest.mark.parametrize("flow_order", [4, 6])
def test_gauss_conserves_its_hamiltonian_at_small_steps(flow_order):
    mod = python_module(SYSTEM, "SVC", 3, flow_order)
    h = 0.02
    E0 = mod.mh_energy(*Y0, h, PRM)
    for tau in (1e-3, 1e-4):
        q, p = Y0[0].copy(), Y0[1].copy()
        dE = 0.0
        for _ in range(20):
            q, p, _ = flow(mod, q, p, tau, 1, h, ntol=1e-12)
            dE = max(dE, abs(mod.mh_energy(q, p, h, PRM) - E0))
        assert dE <= 1e-13 * abs(E0), (tau, dE)


def test_gauss_tau_zero_and_tiny():
    mod = python_module(SYSTEM, "SVA", 4, 4)
    q1, p1, v = np.empty(2), np.empty(2), np.empty(2)
    assert mod.gauss_partial(*Y0, 0.0, 0.01, 0.0, PRM, 1e-12, 50, q1, p1, v)[0] == 0
    np.testing.assert_array_equal(q1, Y0[0])
    np.testing.assert_array_equal(p1, Y0[1])
    it, _ = mod.gauss_partial(*Y0, 1e-14, 0.01, 0.0, PRM, 1e-12, 50, q1, p1, v)
    assert it >= 0
    np.testing.assert_allclose(q1, Y0[0], atol=1e-12)
    np.testing.assert_allclose(p1, Y0[1], atol=1e-12)


@pytest.mark.parametrize("ld, s", [("SVA", 4), ("SVC", 3)])
@pytest.mark.parametrize("h", [1e-2, 3.2e-2])
def test_gauss_converges_at_full_step(ld, s, h):
    """tau up to the full step h on the Figure 3 states: simplified Newton needs only a few iterations."""
    mod = python_module(SYSTEM, ld, s, 4)
    for beta in (3.2, 5.2):
        q0, p0 = SYSTEM.initial_state(beta=beta)
        p0 = p0 + np.array([-8.0, 0.0])  # moving fast towards the wall, as just before an impact
        _, _, iters = flow(mod, q0, p0, h, 1, h, ntol=1e-12)
        assert 0 < iters[0] <= 8


# ---- R^MCVA ---------------------------------------------------------------------------------------
def _reset(mod, q, pm, h):
    pp = np.empty(2)
    n, m = len(q), int(mod.NCON)
    d, lmb, act = np.empty(n), np.empty(m), np.empty(m, dtype=np.int64)
    _, s0, dE = mod.impact_direction(q, pm, h, 1e-13, PRM, d, lmb, act)  # the impact law
    it, lam = mod.reset_mcva(q, pm, d, s0, dE, np.nan, pm, 0.0, 0.5 * h, h, 0.0, PRM, 1e-12, 50, pp)
    return it, lam, pp


def _normal_velocity(mod, q, p, h):
    """dH~/dp . grad phi: the normal velocity of the modified dynamics (grad phi = (1, 0))."""
    u, W, g, He = np.empty(mod.MH_M), np.empty((mod.MH_M, mod.MH_M)), np.empty(4), np.empty((4, 4))
    mod.mh_guess(q, p, PRM, u)
    assert mod.mh_gradient(q, p, h, PRM, u, W, g, He)[0] >= 0
    return g[2]


@pytest.mark.parametrize("ld, s", [("SVA", 4), ("SVC", 3), ("midpoint", 2), ("SE1", 1)])
def test_reset_conserves_truncated_mh_and_lambda_nonzero(ld, s, rng):
    mod = python_module(SYSTEM, ld, s, 4)
    h = 0.02
    n_ok = 0
    for _ in range(24):
        q = np.array([0.0, rng.uniform(-3, 3)])
        vy = -rng.choice([1e-3, 0.1, 1.0, 10.0]) * rng.uniform(0.5, 1.0)  # normal velocity < 0
        vth = rng.uniform(-4, 4)
        p = SYSTEM.mass_matrix(q) @ np.array([vy, vth])
        it, lam, pp = _reset(mod, q, p, h)
        if _normal_velocity(mod, q, p, h) >= 0.0:
            # at |v_y| ~ h the modified dynamics may already move away from the wall: no reflection
            assert it < 0
            continue
        n_ok += 1
        assert it > 0, (q, p, it, lam)
        assert lam != 0.0 and lam > 0.0  # grad phi = (1, 0): the impulse pushes out of the wall
        E0, E1 = mod.mh_energy(q, p, h, PRM), mod.mh_energy(q, pp, h, PRM)
        assert abs(E1 - E0) <= 1e-12 * max(1.0, abs(E0)), (E0, E1)
        np.testing.assert_allclose(pp, p + lam * np.array([1.0, 0.0]), rtol=0, atol=0)
        assert _normal_velocity(mod, q, pp, h) > 0.0   # the reflection reverses the normal velocity
    assert n_ok >= 18


def test_reset_grazing_is_a_failure_not_the_trivial_root():
    mod = python_module(SYSTEM, "SVC", 3, 4)
    q = np.array([0.0, 0.3])
    p = SYSTEM.mass_matrix(q) @ np.array([0.0, 1.5])   # tangential: M^-1 p . grad phi = 0
    it, lam, _ = _reset(mod, q, p, 0.02)
    assert it < 0
