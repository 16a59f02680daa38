"""What a user is told: did-you-mean for methods and bodies, the body without mass named, `python -m
vcirun`, the periodic orbit's default start and why a return failed, the velocities of a run and the
--qdot0 start, the rimless wheel's advice, the contacts figure's restitution value."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import vcirun

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("name, near", [("MCVAAA", "MCVAA"), ("mcvaa", "MCVAA"), ("cva4", "CVA4")])
def test_unknown_method_has_a_did_you_mean(name, near):
    from vcirun.methods.table import resolve_method

    with pytest.raises(ValueError, match=f"unknown method '{name}'; did you mean '{near}'"):
        resolve_method(name)


def test_body_declarations_name_typos_and_massless_bodies():
    from vcirun.mechanics.loader import load_system_yaml

    base = {"parameters": {"m": 1.0}, "gravity": 9.81,
            "bodies": [{"name": "upper", "mass": "m", "com": [1, 0]}, {"name": "lower", "mass": "m", "com": [1, 0]}],
            "joints": [{"type": "revolute", "body": "upper", "coordinate": "a"},
                       {"type": "revolute", "body": "lower", "parent": "uper", "at": [1, 0], "coordinate": "b"}],
            "contacts": [{"name": "floor", "body": "lower", "point": [1, 0], "line": {"point": [0, -3], "normal": [0, 1]}}],
            "q0": [0.0, 0.0]}
    with pytest.raises(ValueError, match=r"joints\[1\]\.parent: 'uper' is neither 'ground' nor a declared body; "
                                         r"did you mean 'upper'\?"):
        load_system_yaml(base)
    free = {"parameters": {"m": 0.0, "I": 0.1}, "gravity": 9.81,
            "bodies": [{"name": "puck", "mass": "m", "inertia": "I"}],
            "joints": [{"type": "free", "body": "puck", "coordinates": ["x", "y", "th"]}],
            "contacts": [{"name": "floor", "body": "puck"}], "q0": [0.0, 1.0, 0.0]}
    with pytest.raises(ValueError, match=r"system\.bodies: M\(q\) is not positive definite .* the coordinates x, y "
                                         r"carry no mass or inertia; give body 'puck' a mass"):
        load_system_yaml(free)


def test_python_dash_m_runs_the_cli():
    r = subprocess.run([sys.executable, "-m", "vcirun", "--version"], capture_output=True, text=True, cwd=ROOT,
                       env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0 and r.stdout.startswith("vcirun "), r.stderr


def test_periodic_orbit_starts_from_the_default_state_and_says_why_a_return_failed():
    from vcirun.scenes.registry import scene_data
    from vcirun.scenes.oracles import rimless_wheel_fixed_point

    o = vcirun.periodic_orbit("rimless_wheel", "CVA", h=2e-3)     # no guess: the scene's default gait
    exact = rimless_wheel_fixed_point(**scene_data("rimless_wheel").params)
    assert abs(o.fixed_point[1][0] - exact.omega) < 1e-4
    with pytest.raises(RuntimeError, match=r"no return to the section within T = .*: the run made 0 of the 1 "
                                           r"impact\(s\) on the section; over \[0, .*\] theta in \["):
        vcirun.periodic_orbit("rimless_wheel", "CVA", h=2e-3, guess=([-0.39], [0.05]), params={"gamma": 0.01},
                              T_max=64)
    with pytest.raises(ValueError, match="decrease alpha"):
        rimless_wheel_fixed_point(alpha=0.7, gamma=0.02, g=9.81, l=1.0)


def test_velocities_of_a_run_and_a_start_by_velocities():
    from typer.testing import CliRunner

    from vcirun.cli.main import app

    tr = vcirun.simulate("double_pendulum", "CVA", h=1e-2, T=1.0, q0=[-1.2, -1.0], p0=[0.3, 0.1])
    M = vcirun.run.resolve.resolve_system("double_pendulum").mass_matrix
    for k in (0, 37, 100):
        np.testing.assert_allclose(M(tr.q[k]) @ tr.qdot[k], tr.p[k], atol=1e-12)
    np.testing.assert_allclose(tr.velocity(tr.t[37]), tr.qdot[37], atol=1e-12)
    r = CliRunner().invoke(app, ["simulate", "--system", "double_pendulum", "--q0", "-1.2,-1.0", "--qdot0", "0.5,0",
                                 "--T", "0.5"], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    q0, v0 = np.array([-1.2, -1.0]), np.array([0.5, 0.0])
    same = vcirun.simulate("double_pendulum", "CVA", h=1e-2, T=0.5, q0=q0, p0=M(q0) @ v0)
    assert f"steps         {same.n_steps}" in r.stdout
    r = CliRunner().invoke(app, ["simulate", "--system", "n_pendulum", "--T", "0.1"], catch_exceptions=False)
    assert "note: n_pendulum is n_pendulum_2" in r.stderr


def test_contacts_figure_names_the_restitution_value():
    from vcirun.experiments.figures import _parameter_values

    assert _parameter_values({"name": "ball_in_box", "params": {}})["e"] == 1.0
    assert _parameter_values({"name": "ball_in_box", "params": {"e": 0.9}})["e"] == 0.9
