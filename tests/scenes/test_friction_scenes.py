"""The friction scenes as built-in systems (`--system rocking_block_friction`, ...): their numeric parts
(vcirun.scenes.registry.scene_data, sympy-free) hold the defaults of the constructors in
vcirun.scenes.friction, which build the same physics from other starts; the symbolic systems are those constructors; `vcirun systems` describes them; and
by name they run to their closed forms (vcirun.scenes.friction_oracles)."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import vcirun
from vcirun.scenes import friction
from vcirun.scenes import friction_oracles as fo
from vcirun.scenes.registry import describe, listed_scenes
from vcirun.scenes.registry import scene_data
from vcirun.scenes.registry import get_scene

# name -> (the constructor at its own defaults, the constructor's start arguments at the scene's default beta)
SCENES = {
    "rocking_block_friction": (friction.rocking_block_friction, lambda b: {"theta0": b}),
    "spinning_ball": (friction.spinning_ball, lambda b: {"w0": b}),
    "incline": (friction.incline, lambda b: {"v0": b}),
    "coulomb_oscillator": (friction.coulomb_oscillator, lambda b: {"x0": b}),
    "painleve_rod": (friction.painleve_rod, lambda b: {"theta0": b}),
}


@pytest.mark.parametrize("name", list(SCENES))
def test_data_defaults_are_the_constructors_and_the_start_is_theirs(name):
    """data.py's copy of the parameters (order and values) equals the constructor's defaults, and the
    built-in's start (its initial-condition map at its default beta, p0 = M(q0) qdot0) is the start
    the constructor builds from the same argument."""
    make, start = SCENES[name]
    d = scene_data(name)
    assert list(d.params.items()) == list(make().params.items())
    s = get_scene(name)
    assert s.name == d.name == name and s.params == d.params
    ref = make(**start(d.default_beta))
    q0, p0 = s.initial_state()
    np.testing.assert_array_equal(q0, ref.default_q0)
    np.testing.assert_allclose(p0, ref.default_p0, rtol=1e-15, atol=1e-15)
    # the physics is the constructor's: the same constraints with the same friction
    assert [(c.name, str(c.friction), str(c.static_friction)) for c in s.constraints] == \
        [(c.name, str(c.friction), str(c.static_friction)) for c in ref.constraints]
    assert s.M == ref.M and s.V == ref.V


@pytest.mark.parametrize("k", [1, 3, 5])
def test_link_chain_friction_family(k):
    d = scene_data(f"link_chain_friction_{k}")
    ref = friction.link_chain_friction(k)
    assert list(d.params.items()) == list(ref.params.items())
    np.testing.assert_array_equal(d.default_q0, ref.default_q0)
    np.testing.assert_array_equal(d.default_p0, ref.default_p0)
    # the frictionless chain starts where the friction chain does
    np.testing.assert_array_equal(d.default_q0, scene_data(f"link_chain_{k}").default_q0)
    assert scene_data("link_chain_friction").name == "link_chain_friction_5"
    with pytest.raises(ValueError, match="link_chain_friction_K takes K from 1 to 30"):
        scene_data("link_chain_friction_31")


def test_overridden_parameters_move_the_start_with_them():
    """A start that depends on a parameter (the slope, the block's corners, the rod's length) follows its
    override: still on the contact surface, moving along it."""
    s = get_scene("incline", theta=0.5)
    q0, p0 = s.initial_state()
    assert abs(-np.sin(0.5) * p0[0] + np.cos(0.5) * p0[1]) < 1e-15 and np.hypot(*p0) == pytest.approx(2.0)
    for a, b, th in ((2.0, 0.5, 0.1), (1.0, 0.4, -0.2)):
        q0, _ = get_scene("rocking_block_friction", a=a, b=b).initial_state(beta=th)
        side = -1 if th > 0 else 1
        corner = friction.block_corner(th, a, b, side)
        assert q0[1] + corner[1] == pytest.approx(0.0, abs=1e-15)
    q0, _ = get_scene("painleve_rod", l=2.0).initial_state()
    assert q0[1] - 2.0 * np.sin(q0[2]) == pytest.approx(0.0, abs=1e-15)
    # the same through a run's parameter vector (vcirun.simulate, `--param`): the built-in's start is built
    # at the run's parameters
    s = get_scene("incline")
    q0, p0 = s.initial_state(params=s.param_values({"theta": 0.5}))
    assert abs(-np.sin(0.5) * p0[0] + np.cos(0.5) * p0[1]) < 1e-15


def test_geometry_overrides_run_from_a_start_on_the_surface():
    """`--param theta=0.5` on the incline and `--param a=2` on the rocking block: no impact at t = 0, the
    closed forms at the overridden geometry."""
    inc = vcirun.simulate("incline", "CVA", h=1e-2, T=1.0, params={"theta": 0.5})
    cf = fo.incline(0.5, mu=0.2, mu_s=0.2, v0=2.0)
    assert inc.ok and len(inc.impacts) == 0 and inc.mode_changes[0] == pytest.approx(cf.t_stop, abs=1e-9)
    tr = vcirun.simulate("rocking_block_friction", "CVA", h=1e-3, T=1.5, params={"a": 2.0})
    hz = fo.housner_rocking(0.1, a=2.0, b=0.4, impacts=2)
    assert tr.ok and tr.impacts[0] > 0.1
    np.testing.assert_allclose(tr.impacts[:2], hz.impact_times, atol=1e-5)


def test_the_numeric_parts_import_no_sympy():
    code = ("import sys, json; from vcirun.scenes.registry import scene_data\n"
            "from vcirun.core.system_data import requested_start\n"
            "ds = [scene_data(n) for n in ('rocking_block_friction', 'spinning_ball', 'incline', "
            "'coulomb_oscillator', 'painleve_rod', 'link_chain_friction_4')]\n"
            "print(json.dumps({'sympy': 'sympy' in sys.modules, 'n': [d.n for d in ds], "
            "'q0': [requested_start(d, params=d.param_values({'mu': 0.9, 'mu_s': 1.0} if 'mu_s' in d.params "
            "else None))[1].tolist() for d in ds]}))")
    out = json.loads(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout)
    assert out["sympy"] is False and out["n"] == [3, 3, 2, 2, 3, 6]
    assert out["q0"][2] == [0.0, 0.0] and out["q0"][4][2] == 0.9


def test_systems_lists_and_describes_them():
    listed = listed_scenes()
    for name in ("rocking_block_friction", "spinning_ball", "incline", "coulomb_oscillator", "painleve_rod",
                 "link_chain_friction_3"):
        assert name in listed
        lines = describe(name)
        text = "\n".join(lines)
        assert "mu = " in text and "friction" in text and "[m]" in text, text
        assert lines[-1].lstrip().startswith(f"example      vcirun simulate --system {name}")
    assert "theta [rad] tilt of the block" in "\n".join(describe("rocking_block_friction"))
    assert "mu_s = 0.2  (static friction coefficient (>= mu))" in "\n".join(describe("incline"))
    # the frictionless block says what it is and where the rocking one is
    assert "rocking_block_friction" in describe("rocking_block")[0]
    assert "painleve" in describe("painleve_rod")[-1]


def test_bad_overrides_name_the_field():
    with pytest.raises(ValueError, match="params.nu: unknown parameter"):
        get_scene("incline", nu=0.1)
    with pytest.raises(ValueError, match="params.nu: unknown parameter of system spinning_ball"):
        scene_data("spinning_ball").param_values({"nu": 0.1})
    with pytest.raises(ValueError, match=r"params.e: value 1.5 is the restitution coefficient"):
        scene_data("link_chain_friction_3").param_values({"e": 1.5})


def test_an_override_that_puts_mu_above_mu_s_is_refused_before_the_run():
    """mu_s >= mu holds at the defaults; an override of mu alone can break it, and a run never starts
    with mu_s < mu (plan.ready_start: the exact reference's check, for every run of simulate, ensemble,
    sweeps and pilots)."""
    with pytest.raises(ValueError, match=r"mu_s = 0.2 < mu = 0.3 .*give mu_s a value >= mu"):
        vcirun.simulate("incline", "CVA", h=1e-2, T=0.1, params={"mu": 0.3})
    assert vcirun.simulate("incline", "CVA", h=1e-2, T=0.1, params={"mu": 0.3, "mu_s": 0.3}).status == "ok"


@pytest.mark.slow   # four scenes' kernels: about 4 min of CPU on an empty cache
def test_builtin_rocking_and_sliding_follow_their_closed_forms():
    """By name, on the compiled path: Housner's corner impacts (times and the angular-velocity ratio
    1 - 3/2 sin^2 alpha), the incline's stop, the oscillator's turning points, the ball's rolling start."""
    tr = vcirun.simulate("rocking_block_friction", "CVA", h=1e-3, T=1.0)
    hz = fo.housner_rocking(0.1, a=1.0, b=0.4, impacts=4)
    assert tr.ok and len(tr.impacts) == 4
    np.testing.assert_allclose(tr.impacts, hz.impact_times, atol=1e-5)
    inertia = (1.0 ** 2 + 0.4 ** 2) / 12   # M = diag(m, m, I_C): the free joint at the centre of mass
    wm, wp = tr.impact_p_minus[:, 2] / inertia, tr.impact_p_plus[:, 2] / inertia
    np.testing.assert_allclose(np.abs(wm), hz.omega_minus, rtol=1e-4)
    np.testing.assert_allclose(wp / wm, fo.housner_ratio(1.0, 0.4), rtol=1e-12)
    assert len(tr.mode_changes) == 0          # the corners stick throughout
    inc = vcirun.simulate("incline", "CVA", h=1e-2, T=1.0)
    cf = fo.incline(0.3, mu=0.2, mu_s=0.2, v0=2.0)
    assert inc.ok and len(inc.mode_changes) == 1 and inc.mode_change_kind[0] == 3
    assert inc.mode_changes[0] == pytest.approx(cf.t_stop, abs=1e-9)
    osc = vcirun.simulate("coulomb_oscillator", "CVA", h=1e-2, T=6.0)
    co = fo.coulomb_oscillator(1.0, m=1.0, k=10.0, mu=0.1, g=9.81)
    assert osc.ok and list(osc.mode_change_kind) == [3, 3, 3, 3, 1]
    np.testing.assert_allclose(osc.mode_changes, [t for t, _ in co.turns], atol=1e-3)
    ball = vcirun.simulate("spinning_ball", "CVA", h=1e-3, T=1.0)
    sb = fo.spinning_ball(50.0)
    assert ball.ok and ball.impacts[0] == pytest.approx(sb.t1, abs=1e-9)
    assert list(ball.mode_change_kind) == [1] and ball.mode_changes[0] == pytest.approx(sb.t_roll, abs=1e-3)


def test_builtin_painleve_rod_ends_with_its_status():
    tr = vcirun.simulate("painleve_rod", "CVA", h=1e-3, T=0.5)
    assert tr.status == "painleve" and "B = " in tr.message and "contact 0" in tr.message
    B = fo.painleve_B(0.9, 1.5, -1)
    assert B < 0 and f"{B:.6g}" in tr.message
    ok = vcirun.simulate("painleve_rod", "CVA", h=1e-3, T=0.2, beta=0.5)   # B(0.5) > 0: it slides
    assert ok.ok
