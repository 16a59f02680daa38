"""Observed orders of the smooth one-step maps and of the forced
(Lagrange-d'Alembert) SVC on a damped oscillator.

Error = max over the common grid t = k * h_coarse of |q - q_ref|, with q_ref the smooth solution of
Hamilton's equations by DOP853 at rtol 1e-13 (constraint ignored), or the closed-form damped
solution. Orders are fitted by the one estimator `fit_order` (round-off plateau masked).
"""
from __future__ import annotations

import numpy as np
import pytest

import vcirun
from convergence.helpers import exact_smooth, fit_order, run_map
from vcirun.discrete.lagrangians import LIBRARY

EXPECTED_ORDER = {"SE1": 1, "SE2": 1, "SVA": 2, "SVB": 2, "SVC": 2, "midpoint": 2}
# smooth scenes: the cart-pendulum from Xi(1) with the constraint ignored (y goes negative, the
# pendulum swings widely: fully nonseparable), the double pendulum from its Figure-1 state.
SCENES = {"cart_pendulum": dict(beta=1.0), "double_pendulum": dict()}
T = 2.0
NS = (50, 100, 200, 400, 800)  # h = 0.04 ... 0.0025
TOL = 0.15


def observed_order(compiled, system_name, method):
    system, mod, prm = compiled(system_name, method)
    q0, p0 = system.initial_state(**SCENES[system_name])
    tc = np.linspace(0.0, T, NS[0] + 1)
    qref, _ = exact_smooth(mod, prm, q0, p0, tc)
    hs, errs = [], []
    for N in NS:
        Q, _ = run_map(mod, prm, q0, p0, T / N, N)
        hs.append(T / N)
        errs.append(float(np.max(np.abs(Q[:: N // NS[0]] - qref))))
    slope, used = fit_order(hs, errs, scale=float(np.max(np.abs(qref))))
    return slope, used, errs


@pytest.mark.parametrize("method", list(EXPECTED_ORDER))
@pytest.mark.parametrize("system_name", list(SCENES))
def test_observed_order_on_smooth_trajectory(system_name, method, compiled):
    assert LIBRARY[method].order == EXPECTED_ORDER[method]
    slope, used, errs = observed_order(compiled, system_name, method)
    msg = f"{system_name}/{method}: slope {slope:.3f} from errors {['%.2e' % e for e in errs]} (used {used})"
    assert abs(slope - EXPECTED_ORDER[method]) < TOL, msg
    assert used.sum() >= 4, msg  # the range is asymptotic, not plateau-dominated


def test_run_map_harness_is_the_simulate_api(compiled):
    """The Python loop over mod.ld_step used above reproduces vcirun.simulate (same compiled map)."""
    system, mod, prm = compiled("cart_pendulum", "SVC")
    q0, p0 = system.initial_state(beta=1.0)
    tr = vcirun.simulate("cart_pendulum", "SVC", h=0.02, T=T, beta=1.0, constrained=False)
    assert tr.ok
    Q, P = run_map(mod, prm, q0, p0, 0.02, 100)
    assert np.max(np.abs(tr.q - Q)) < 1e-13 and np.max(np.abs(tr.p - P)) < 1e-13


@pytest.mark.parametrize(
    "hs, errs, expect_slope, expect_used",
    [
        # clean order 2, then the error stalls (local slope 0.27, then rising): plateau, masked
        ([0.1, 0.05, 0.025, 0.0125, 0.00625, 0.003125], [1e-4, 2.5e-5, 6.25e-6, 1.5625e-6, 1.3e-6, 1.4e-6], 2.0,
         [True, True, True, True, False, False]),
        # given in any order (fine to coarse here)
        ([0.025, 0.05, 0.1, 0.2], [1e-3, 2e-3, 4e-3, 8e-3], 1.0, [True, True, True, True]),
        # errors below 1e3 eps are plateau even if still decreasing
        ([0.1, 0.05, 0.025, 0.0125], [1e-6, 5e-7, 2.5e-7, 1e-14], 1.0, [True, True, True, False]),
    ],
)
def test_fit_order_masks_the_round_off_plateau(hs, errs, expect_slope, expect_used):
    slope, used = fit_order(hs, errs)
    assert abs(slope - expect_slope) < 1e-6
    assert used.tolist() == expect_used


def test_fit_order_refuses_too_few_points():
    with pytest.raises(AssertionError, match="fewer than 3"):
        fit_order([0.1, 0.05, 0.025], [1e-3, 2e-3, 3e-3])


# --- forced example: linearly damped oscillator, m x'' = -k x - c x' --------------------------
def damped_exact(t, m=1.0, k=1.0, c=0.1, x0=1.0, v0=0.0):
    """Closed-form underdamped solution: (x(t), p(t) = m x'(t))."""
    g = c / (2 * m)
    wd = np.sqrt(k / m - g * g)
    A, B = x0, (v0 + g * x0) / wd
    e = np.exp(-g * t)
    x = e * (A * np.cos(wd * t) + B * np.sin(wd * t))
    v = e * ((-g * A + wd * B) * np.cos(wd * t) - (g * B + wd * A) * np.sin(wd * t))
    return x, m * v


def test_forced_svc_converges_at_order_2_and_energy_decreases():
    """SVC with trapezoidal discrete forces f^-/+ = h/2 f (discrete Lagrange-d'Alembert) on the
    damped_oscillator (m = k = 1, c = 0.1, x0 = 1, p0 = 0), T = 10, against the exact solution."""
    Tf = 10.0
    hs, eq, ep = [], [], []
    for N in (50, 100, 200, 400, 800):
        tr = vcirun.simulate("damped_oscillator", "SVC", h=Tf / N, T=Tf)
        assert tr.ok and tr.options["params"]["c"] == 0.1
        x, p = damped_exact(tr.t)
        step = N // 50
        hs.append(Tf / N)
        eq.append(float(np.max(np.abs(tr.q[::step, 0] - x[::step]))))
        ep.append(float(np.max(np.abs(tr.p[::step, 0] - p[::step]))))
        if N == 200:  # h = 0.05: the energy decreases at every step, to the exact final value
            H = tr.H
            assert np.all(np.diff(H) < 0), f"H increases at steps {np.flatnonzero(np.diff(H) >= 0)}"
            H_exact = 0.5 * (x[-1] ** 2 + p[-1] ** 2)
            assert abs(H[-1] - H_exact) < 1e-3 * H_exact
            assert H[-1] < 0.4 * H[0]  # the exact decay over T = 10 is to 0.385 H0
    sq, _ = fit_order(hs, eq)
    sp_, _ = fit_order(hs, ep)
    assert abs(sq - 2) < TOL and abs(sp_ - 2) < TOL, (sq, sp_, eq, ep)
