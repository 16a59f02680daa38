"""Declared resets and guards (vcirun.mechanics.hybrid): parsed and checked with errors naming the
field; a declared map run through Algorithm 1 (the event located, the map applied, the step
completed) against closed forms; the built-in walkers' maps."""
from __future__ import annotations

import numpy as np
import pytest

import vcirun
from vcirun.codegen.evaluate import python_module_for
from vcirun.mechanics.loader import load_system_yaml


def _osc(**constraint):
    """x'' = -x from x = 1 at rest, the wall x = -1/2 (phi = x + d), with the constraint's extra keys."""
    return {"name": "osc_reset", "coordinates": ["x"], "parameters": {"m": 1.0, "k": 1.0, "d": 0.5, "e": 0.5},
            "mass_matrix": [["m"]], "potential": "k*x**2/2", "q0": [1.0], "qdot0": [0.0],
            "constraints": [{"name": "wall", "phi": "x + d", **constraint}]}


T_STAR = 2 * np.pi / 3          # x = cos t reaches -1/2 at 2 pi / 3 with xdot = -sqrt(3)/2
V_STAR = -np.sqrt(3) / 2


@pytest.fixture
def uncompiled():
    """simulate's loader for the generated module run as Python."""
    return python_module_for


def _run(system, method="CVA", h=1e-2, T=4.0, loader=None):
    tr = vcirun.simulate(system, method, h=h, T=T, loader=loader)
    assert tr.ok, tr.message
    return tr


def test_velocity_map_against_closed_form(uncompiled):
    """reset: {qdot: [-e x_dot]}: x = cos t, then -cos(s)/2 - e V_STAR sin(s), s = t - t*."""
    s = load_system_yaml(_osc(reset={"qdot": ["-e*x_dot"]}))
    tr = _run(s, loader=uncompiled)
    assert tr.impacts.shape == (1,)
    assert abs(tr.impacts[0] - T_STAR) < 1e-4
    assert tr.impact_p_plus[0, 0] == pytest.approx(-0.5 * tr.impact_p_minus[0, 0], rel=1e-13)
    sft = tr.t - T_STAR
    exact = np.where(sft < 0, np.cos(tr.t), -0.5 * np.cos(sft) - 0.5 * V_STAR * np.sin(sft))
    assert np.max(np.abs(tr.q[:, 0] - exact)) < 2e-4      # second order (SVC)
    after = sft > 1e-2
    H_after = 0.5 * (0.5 * V_STAR) ** 2 + 0.5 * 0.25
    assert np.max(np.abs(tr.H[after] - H_after)) < 1e-4


def test_configuration_map_against_closed_form(uncompiled):
    """reset: {q: [x + 1], qdot: [-x_dot]}: from the wall to x = 1/2 moving right: x = cos(s)/2 -
    V_STAR sin(s) until the wall is reached again."""
    s = load_system_yaml(_osc(reset={"q": ["x + 1"], "qdot": ["-x_dot"]}))
    tr = _run(s, T=3.5, loader=uncompiled)
    assert abs(tr.impacts[0] - T_STAR) < 1e-4
    sft = tr.t - T_STAR
    exact = np.where(sft < 0, np.cos(tr.t), 0.5 * np.cos(sft) - V_STAR * np.sin(sft))
    assert np.max(np.abs(tr.q[:, 0] - exact)) < 2e-4


def test_plastic_then_map(uncompiled):
    """plastic: true and a map: the impact law (zero normal velocity) first, then the map: at rest,
    moved to x = 1/2: x = cos(s)/2 after the impact."""
    s = load_system_yaml(_osc(plastic=True, reset={"q": ["x + 1"]}))
    tr = _run(s, T=3.0, loader=uncompiled)
    assert abs(tr.impact_p_plus[0, 0]) < 1e-12
    sft = tr.t - tr.impacts[0]
    exact = np.where(sft < 0, np.cos(tr.t), 0.5 * np.cos(sft))
    assert np.max(np.abs(tr.q[:, 0] - exact)) < 2e-4


def test_guard_acts_only_where_armed(uncompiled):
    """when: the wall acts where the guard is armed at the crossing (x > -0.9 there: one impact) and
    is absent where it is not (x > -0.4 fails at x = -1/2: the oscillator passes through, x = cos t)."""
    armed = _run(load_system_yaml(_osc(when="x > -0.9", reset={"qdot": ["-x_dot"]})), T=3.0, loader=uncompiled)
    assert armed.impacts.shape == (1,)
    off = _run(load_system_yaml(_osc(when="x > -0.4", reset={"qdot": ["-x_dot"]})), T=3.0, loader=uncompiled)
    assert off.impacts.shape == (0,)
    assert np.max(np.abs(off.q[:, 0] - np.cos(off.t))) < 1e-3


@pytest.mark.parametrize("extra, field, words", [
    ({"reset": {"q": ["x", "x"]}}, "constraints[0].reset.q", "list of 1 expressions"),
    ({"reset": {"qdot": ["y_dot"]}}, "constraints[0].reset.qdot[0]", "y_dot"),
    ({"reset": {"q": ["x_dot"]}}, "constraints[0].reset.q[0]", "x_dot"),
    ({"reset": {"p": ["x"]}}, "constraints[0].reset", "mapping"),
    ({"reset": {"q": ["x - 1"]}}, "constraints[0].reset.q", "inside constraint wall"),
    ({"when": "x > 100"}, "constraints[0].when", "never act"),
    ({"when": "d > 0"}, "constraints[0].when", "does not depend on the coordinates"),
    ({"when": "x"}, "constraints[0].when", "one comparison"),
    ({"plastic": "yes"}, "constraints[0].plastic", "true or false"),
    ({"plastic": True, "restitution": 0.5}, "constraints[0].plastic", "one of plastic or restitution"),
    ({"bounce": 1}, "constraints[0].bounce", "unknown key"),
])
def test_bad_resets_are_errors_naming_the_field(extra, field, words):
    with pytest.raises(ValueError) as err:
        load_system_yaml(_osc(**extra))
    msg = str(err.value)
    assert field in msg and words in msg, msg


def test_rimless_wheel_strides(uncompiled):
    """At each impact theta = alpha, and the map: theta+ = -alpha, thetadot+ = cos(2 alpha) thetadot-."""
    from vcirun.scenes.registry import get_scene

    a = get_scene("rimless_wheel").params["alpha"]
    tr = _run("rimless_wheel", h=1e-2, T=2.0, loader=uncompiled)
    assert len(tr.impacts) >= 2
    np.testing.assert_allclose(tr.impact_q[:, 0], a, atol=1e-12)
    np.testing.assert_allclose(tr.impact_p_plus[:, 0], np.cos(2 * a) * tr.impact_p_minus[:, 0], rtol=1e-14)


_VCI_IRREGULAR = pytest.mark.xfail(strict=True, reason=(
    "VCI's reset after a declared map aims at the discrete energy of the step that reached the impact, "
    "which jumps by O(h^2) as the impact crosses a grid point: the measured rates (0.76, 2.9 at "
    "h = 0.04, 0.02, 0.01) are not yet a clean order 2"))


@pytest.mark.parametrize("method", ["CVA", pytest.param("VCI", marks=_VCI_IRREGULAR), "MCVAC", "CVA4"])
def test_orders_through_a_declared_reset(method):
    """The velocity map qdot+ = -e qdot- (e = 1/2) against the closed form: each method's global
    error (max over the grid to T = 4, one impact) converges at its order through the reset (CVA,
    VCI, MCVAC: 2; CVA4: 4)."""
    order = {"CVA4": 4}.get(method, 2)
    s = load_system_yaml(_osc(reset={"qdot": ["-e*x_dot"]}))
    errs = []
    for h in (0.04, 0.02, 0.01):
        tr = _run(s, method, h=h)
        sft = tr.t - T_STAR
        exact = np.where(sft < 0, np.cos(tr.t), -0.5 * np.cos(sft) - 0.5 * V_STAR * np.sin(sft))
        errs.append(np.max(np.abs(tr.q[:, 0] - exact)))
    rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    print(method, "errors:", errs, "rates:", rates.tolist())
    assert np.all(rates > order - 0.3), rates
