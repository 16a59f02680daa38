"""Step size and horizon at the extremes.

Step size: from h = 1e-5 up to the largest h at which every run still returns ok (Newton converges
in every full/partial step and reset), for the cart-pendulum (Xi(3.2)) and the double pendulum
(default release), T = 5; just past that limit the run returns a failure status with step, time
and state, never an exception. The limits are those measured by bench/extremes_study.py
(docs/extremes.md); the fast test checks a coarse scan against them, the slow test redoes the
bisection. Long horizon: 1e6 steps of the cart-pendulum with impacts (slow), 1e5 steps (fast).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import vcirun
from vcirun.experiments.studies import step_size

METHODS = ["CVA", "VCI", "MCVAA", "MCVAC"]
SCENES = {"cart_pendulum": dict(beta=3.2), "double_pendulum": {}}
FAILURES = ("newton_failed", "event_failed", "reset_failed", "accumulation", "nonfinite")
# h* measured by the study (bisection to 0.1 %); None: no failure up to h = 2
H_LIMIT = {
    ("cart_pendulum", "CVA"): None, ("cart_pendulum", "VCI"): 0.540, ("cart_pendulum", "MCVAA"): 0.1266,
    ("cart_pendulum", "MCVAC"): 0.2298, ("double_pendulum", "CVA"): 0.2731, ("double_pendulum", "VCI"): 0.2852,
    ("double_pendulum", "MCVAA"): 0.08372, ("double_pendulum", "MCVAC"): 0.1226,
}


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("scene", list(SCENES))
def test_smallest_step(scene, method):
    tr = vcirun.simulate(scene, method, h=1e-5, T=0.3, **SCENES[scene])
    assert tr.status == "ok" and tr.n_steps == 30_000
    assert np.max(np.abs(tr.H - tr.H[0])) < 1e-7


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("scene", list(SCENES))
def test_coarse_scan_to_h_2(scene, method):
    """h = 10^(k/4) from 1e-2 to 2: no exception anywhere; every failure is a failure status whose
    message starts with status, step and time; the first failing h of the scan lies within a factor
    2 of the documented limit (non-monotone: ok runs can reappear above it)."""
    first_fail = None
    for k in range(-8, 2):
        h = 10 ** (k / 4)
        tr = vcirun.simulate(scene, method, h=h, T=5.0, **SCENES[scene])
        if tr.status != "ok":
            assert tr.status in FAILURES
            assert tr.message.startswith(f"{tr.status} in step {tr.fail_step} (t = ")
            assert len(tr.t) == tr.fail_step + 1 and np.all(np.isfinite(tr.q))
            first_fail = first_fail or h
    lim = H_LIMIT[(scene, method)]
    if lim is None:
        assert first_fail is None
    else:
        assert first_fail is not None and 0.5 * lim <= first_fail <= 2 * lim, first_fail


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("scene", list(SCENES))
def test_step_limit_bisection(scene, method):
    r = step_size.step_limit(scene, method, T=5.0, h_min=1e-5, h_max=2.0, per_decade=4, rel=1e-3, **SCENES[scene])
    assert not r["crashes"]
    lim = H_LIMIT[(scene, method)]
    if lim is None:
        assert r["h_past"] is None
    else:
        assert r["h_limit"] == pytest.approx(lim, rel=0.1)
        assert r["status_past"] in FAILURES and r["message_past"].startswith(r["status_past"])


# --- long horizons ------------------------------------------------------------------------------

# 1e6 steps, h = 1e-2, Xi(3.2) (T = 1e4 s, ~8400 impacts). Measured (docs/extremes.md):
#   method  slope H (J/s)  max|H-H0| @1e4/1e5/1e6   slope Hmod   max|Hmod-Hmod0| @1e4/1e5/1e6
#   CVA     -2.2e-5        0.028 / 0.033 / 0.22
#   VCI     -2.1e-5        0.079 / 0.16 / 0.81
#   MCVAA   -3.6e-8        0.019 / 0.020 / 0.020    -3.2e-8      8.6e-5 / 2.4e-4 / 5.1e-4
#   MCVAC   -9.8e-6        0.023 / 0.036 / 0.093    -9.7e-6      0.0078 / 0.018 / 0.093
#   (2026-12-01, another realization: MCVAC -2.0e-5 J/s, max|Hmod - Hmod0| 0.01 / 0.016 / 0.19;
#    MCVAA -9.4e-8 J/s, 7.6e-5 / 3.5e-4 / 1.0e-3)
LONG_BOUNDS = {  # method: (|slope H|, max|H - H0| at the end, |slope Hmod|, max|Hmod - Hmod0| at the end)
    "CVA": (1e-4, 1.0, None, None), "VCI": (1e-4, 2.0, None, None),
    "MCVAA": (1e-6, 0.05, 1e-6, 2e-3), "MCVAC": (5e-5, 0.3, 5e-5, 0.3),
}


def _check_long(r, steps, slope_factor=1.0):
    """slope_factor: over 1e5 steps the fitted slope is dominated by the O(h^2) fluctuation of H
    (VCI: 1.4e-4 J/s), not by the drift; the slope bounds are for 1e6 steps."""
    assert r["status"] == "ok", r
    assert r["steps_done"] == steps and r["impacts"] >= 0.8 * 0.0084 * steps
    sH, dH, sM, dM = LONG_BOUNDS[r["method"]]
    assert abs(r["slope_H"]) <= sH * slope_factor and max(r["maxdev_H"].values()) <= dH, r
    if sM is not None:
        assert abs(r["slope_Hmod"]) <= sM * slope_factor and max(r["maxdev_Hmod"].values()) <= dM, r


@pytest.mark.parametrize("method", METHODS)
def test_long_horizon_1e5_steps(method):
    _check_long(step_size.long_run("cart_pendulum", method, h=1e-2, steps=100_000, beta=3.2), 100_000, 10.0)


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
def test_long_horizon_1e6_steps(method):
    r = step_size.long_run("cart_pendulum", method, h=1e-2, steps=1_000_000, beta=3.2)
    _check_long(r, 1_000_000)


# The cart-pendulum with impacts is chaotic over 1e6 steps (T = 1e4, ~8000 impacts): an ulp of
# difference anywhere (initial state, kernel path, Newton stopping) gives another realization, so
# these bounds are set on the spread of realizations measured (7 for MCVAA: 5.1e-4 .. 2.6e-3 J after
# 1e6 steps, x2.1 .. x4.7 from 1e5 steps), not on one run. A drift would grow x10 over that decade.
@pytest.mark.slow
def test_mcvaa_modified_hamiltonian_grows_sublinearly():
    r = step_size.long_run("cart_pendulum", "MCVAA", h=1e-2, steps=1_000_000, beta=3.2)
    d = r["maxdev_Hmod"]
    assert d[1_000_000] <= 6 * d[100_000] and d[1_000_000] <= 1e-4 * abs(r["H0"]), d


@pytest.mark.slow
def test_mcvac_modified_hamiltonian_stays_within_one_percent():
    """MCVAC's truncation H~^{O(h^3)} is coarser (errors ~0.03-0.2 J) and its growth over the decade
    1e5 -> 1e6 steps differs between realizations (a change of one ulp anywhere gives another one): x2.3 .. x12 (up to
    0.016 -> 0.19 J, slope -2.0e-5 J/s). Sub-linear growth is
    therefore not asserted for MCVAC (it is for MCVAA above); what every realization kept is an error
    below 1 % of H0 (0.38 J)."""
    r = step_size.long_run("cart_pendulum", "MCVAC", h=1e-2, steps=1_000_000, beta=3.2)
    d = r["maxdev_Hmod"]
    assert d[1_000_000] <= 1e-2 * abs(r["H0"]), d


def test_drift_slope_is_least_squares():
    t = np.linspace(0, 10, 101)
    assert step_size.drift_slope(t, 3.0 + 0.25 * t + 0.01 * np.sin(7 * t)) == pytest.approx(0.25, abs=2e-3)
    assert math.isnan(step_size.drift_slope(t[:1], t[:1]))
