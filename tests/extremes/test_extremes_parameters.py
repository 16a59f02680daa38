"""Energies and parameters at the extremes: high energy (Xi(beta), beta up to 100), mass
ratios m2/m1 = 1e-4 .. 1e4, a nearly singular mass matrix. Each either runs correctly (L2 error
against the exact reference within the stated bound) or stops with a status whose message names
the cause (vcirun.run.api appends '; cause: ...'). Measured values in comments (docs/extremes.md).
"""
from __future__ import annotations

import numpy as np
import pytest

import vcirun
from vcirun.experiments.studies import parameters

METHODS = ["CVA", "VCI", "MCVAA", "MCVAC"]
FAILURES = ("newton_failed", "event_failed", "reset_failed", "accumulation", "nonfinite")


@pytest.fixture(scope="module")
def ref_beta100():
    return vcirun.reference("cart_pendulum", T=5.0, beta=100.0)


@pytest.mark.parametrize("method", METHODS)
def test_beta_100_pendulum_rotates(method, ref_beta100):
    """Xi(100): H0 = 1280 J, cart dropped from 100 m, pendulum spinning at 14.5 rad/s (the exact angle
    sweeps 95.7 rad in 5 s). L2 at h = 1e-3: 0.0020 .. 0.0035 (second order, see the slow test)."""
    th = ref_beta100(np.linspace(0, 5, 2001))[:, 1]
    assert np.ptp(th) > 10 * 2 * np.pi
    tr = vcirun.simulate("cart_pendulum", method, h=1e-3, T=5.0, beta=100.0)
    assert tr.status == "ok"
    assert len(tr.impacts) == len(ref_beta100.impacts) == 1
    assert vcirun.l2_error(tr, ref_beta100) <= 5e-3


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("beta", [3.2, 10.0, 30.0, 100.0])
def test_high_energy_second_order(method, beta):
    r = parameters.energy_case(method, beta, hs=[1e-2, 1e-3, 1e-4], T=5.0)
    assert all(x["status"] == "ok" for x in r["runs"])
    assert r["runs"][-1]["order"] > 1.8 and r["runs"][-1]["l2"] <= 5e-5


@pytest.mark.parametrize("method", METHODS)
def test_tiny_mass_ratio(method):
    """m2/m1 = 1e-4 (cond(M) up to 2.5e3): L2 at h = 1e-3 is 9.6e-4 .. 1.1e-3, second order."""
    r = parameters.mass_ratio_case(method, 1e-4, hs=[1e-2, 1e-3], T=5.0)
    assert [x["status"] for x in r["runs"]] == ["ok", "ok"]
    assert r["runs"][1]["l2"] <= 2e-3 and r["runs"][1]["order"] > 1.9


@pytest.mark.parametrize("method", ["CVA", "MCVAC"])
def test_large_mass_ratio(method):
    """m2/m1 = 1e4: a light cart under a heavy spinning bob; at theta = pi/2 the fastest local mode
    has omega ~ 3e6 and cond(M) ~ 6e3. h = 1e-2 stops (newton_failed; CVA's cause: the motion had
    diverged / M nearly singular); h = 1e-5 runs, L2 0.10 against an 8-impact exact motion."""
    r = parameters.mass_ratio_case(method, 1e4, hs=[1e-2, 1e-5], T=5.0)
    bad, good = r["runs"]
    assert bad["status"] in FAILURES
    assert good["status"] == "ok" and good["l2"] <= 0.15 and good["impacts"] == r["ref_impacts"]


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("ratio", [1e-4, 1e-2, 1.0, 1e2, 1e4])
def test_mass_ratios_converge(method, ratio):
    r = parameters.mass_ratio_case(method, ratio, hs=[1e-4, 1e-5], T=5.0)
    last = r["runs"][-1]
    assert last["status"] == "ok"
    assert last["l2"] <= (0.15 if ratio >= 1e4 else 1e-3)


@pytest.mark.parametrize("method", METHODS)
def test_nearly_singular_mass_matrix_runs_at_small_h(method):
    """Double pendulum with m1 = 1e-4, released with aligned links: cond(M) = 4e4. Before the Newton
    round-off floor (vcirun/maps/steps.py) every step size stopped with newton_failed at t ~ 0.1 (the
    correction cycled between two floats above newton_tol = 1e-12). Now h = 1e-5 runs: L2 0.021 ..
    0.030 over [0, 2] (one impact; the impact excites a fast mode, omega ~ 270)."""
    r = parameters.singular_mass_case(method, 1e-4, hs=[1e-5], T=2.0)
    assert r["cond0"] > 3e4 and r["ref_accuracy"] < 1e-5
    x = r["runs"][0]
    assert x["status"] == "ok" and x["l2"] <= 0.05


@pytest.mark.parametrize("method", METHODS)
def test_nearly_singular_mass_matrix_stops_with_cause(method):
    """m1 = 1e-8 (cond(M) = 4e8) at h = 1e-3, and m1 = 1e-4 at h = 1e-2: a failure status whose cause
    names the mass matrix or the step size."""
    for m1, h in ((1e-8, 1e-3), (1e-4, 1e-2)):
        x = parameters.singular_mass_case(method, m1, hs=[h], T=2.0, with_reference=False)["runs"][0]
        assert x["status"] in FAILURES, x
        assert "mass matrix nearly singular" in x["cause"] or "step h too large" in x["cause"], x


def test_singular_mass_matrix_at_input_is_rejected():
    with pytest.raises(ValueError, match="mass_matrix is not positive definite"):
        vcirun.simulate("double_pendulum", "CVA", h=1e-2, T=1.0, params={"m1": 0.0})


@pytest.mark.parametrize("method", METHODS)
def test_singular_mass_matrix_along_the_motion_stops_with_cause(method):
    """m1 = 0 from a non-aligned start: M is singular whenever the links align (the exact solution
    stops existing at t = 0.3346, where DOP853 gives up). h = 1e-2: a failure naming the mass
    matrix (or a diverged motion)."""
    x = parameters.singular_mass_case(method, 0.0, hs=[1e-2], T=2.0, q0=np.array([-1.0, 0.5]), p0=np.zeros(2),
                                  with_reference=False)["runs"][0]
    assert x["status"] in FAILURES
    assert "mass matrix nearly singular" in x["cause"] or "diverged" in x["cause"]


@pytest.mark.xfail(strict=True, reason=(
    "known gap (docs/extremes.md): with m1 = 0 from a non-aligned start, CVA/VCI/MCVAC at h <= 1e-4 "
    "step across the singular configuration (links aligned at t ~ 0.33, where no continuation exists) "
    "and return ok with max |H - H0| ~ 170 J; simulate() checks hyperregularity only at q0"))
def test_singular_mass_matrix_is_never_silently_crossed():
    tr = vcirun.simulate("double_pendulum", "CVA", h=1e-4, T=2.0, params={"m1": 0.0}, q0=np.array([-1.0, 0.5]),
                         p0=np.zeros(2))
    assert tr.status != "ok"
