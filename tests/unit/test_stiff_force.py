"""A force that grows with the velocity faster than the step resolves ends the run with a status that
says so, never `ok` with a meaningless trajectory (vcirun/maps/steps.py step_resolves_force).

x'' = -x + c x' with c > 0 is negative damping: the motion grows like exp(c t). In an SVC step the
step velocity solves (m - h c / 2) v = p + O(h), so at h c / 2 >= m its root points against the
momentum: with c = 1e6, h = 1e-2 the loop used to end `ok` with x frozen at its start and p flipping
sign every step.
"""
from __future__ import annotations

import numpy as np
import pytest

import vcirun
from vcirun.mechanics.loader import load_system_yaml

OSC = load_system_yaml({"name": "velocity_fed_oscillator", "coordinates": ["x"],
                        "parameters": {"m": 1.0, "k": 1.0, "c": 1.0},
                        "mass_matrix": [["m"]], "potential": "0.5*k*x**2", "constraint": "x + 100",
                        "forcing": ["c*x_dot"], "q0": [0.5], "p0": [0.0]})


@pytest.mark.parametrize("c", [1e6, 1e3, 1e308])
def test_a_force_the_step_does_not_resolve_ends_the_run_and_says_why(c):
    tr = vcirun.simulate(OSC, "CVA", h=1e-2, T=1.0, q0=[0.5], p0=[0.1], params={"c": c})
    assert tr.status == "newton_failed", (c, tr.status, tr.q[-3:, 0], tr.p[-3:, 0])
    assert tr.fail_step == 0
    assert "faster than the step resolves" in tr.message and "step h too large" in tr.message, tr.message


def test_a_resolved_force_runs_and_grows_like_the_motion():
    """h c / 2 = 0.05 < m: the step resolves the force; the amplitude grows like the exact motion's,
    x = e^{c t / 2} (A cos(w t) + B sin(w t)), w = sqrt(1 - c^2 / 4), from x = 0.5, v = 0.1."""
    c, T = 10.0, 1.0
    tr = vcirun.simulate(OSC, "CVA", h=1e-3, T=T, q0=[0.5], p0=[0.1], params={"c": c})
    assert tr.status == "ok"
    r1, r2 = np.roots([1.0, -c, 1.0])          # x'' - c x' + x = 0
    a, b = np.linalg.solve([[1.0, 1.0], [r1, r2]], [0.5, 0.1])
    exact = a * np.exp(r1 * tr.t) + b * np.exp(r2 * tr.t)
    assert np.max(np.abs(tr.q[:, 0] - exact)) <= 1e-3 * np.max(np.abs(exact))


def test_strong_damping_is_resolved_at_any_step():
    """c < 0 (damping): M - a h c stays positive definite; the implicit step damps the motion, which
    creeps on the slow mode x' = -x / |c| (x(1) = 0.5 e^{-1e-6}; the start's velocity dies within ~1e-6)."""
    tr = vcirun.simulate(OSC, "CVA", h=1e-2, T=1.0, q0=[0.5], p0=[0.1], params={"c": -1e6})
    assert tr.status == "ok" and abs(tr.q[-1, 0] - 0.5 * np.exp(-1e-6)) < 1e-6
