"""The study system without running a study: the schema (one validated model per `study:` kind, one-line
errors naming the field), the report template syntax, and the closed-form oracles of vcirun.scenes.oracles."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from vcirun.experiments.config import ConfigError
from vcirun.experiments.studies.report import extremes_context, render, render_extremes
from vcirun.experiments.studies.schema import ExtremesStudy, WorkPrecisionStudy, load_study, parse_study
from vcirun.scenes.oracles import ball_exact, ball_exact_onset, ball_position

ROOT = Path(__file__).resolve().parents[2]
TEMPLATE = ROOT / "docs" / "templates" / "extremes.md"


# --- schema --------------------------------------------------------------------------------------------
def test_shipped_study_configs_pick_their_models():
    ex = load_study(ROOT / "configs" / "extremes.yaml")
    assert isinstance(ex, ExtremesStudy) and len(ex.sections()) == 11
    assert Path(ex.report.template).resolve() == TEMPLATE.resolve() and ex.report.output == "results/extremes.md"
    wp = load_study(ROOT / "configs" / "work_precision.yaml")
    assert isinstance(wp, WorkPrecisionStudy) and len(wp.betas()) == 5 and wp.betas()[0] == 3.2
    assert [m.display for m in wp.method_specs()][:4] == ["CVA", "VCI", "MCVAA", "MCVAC"]


BASE = {"study": "extremes", "name": "x", "methods": ["CVA"], "dense": {"scenes": [
    {"system": "bouncing_ball", "q0": [1e-4], "p0": [0.0], "h": 0.02, "T": 1}]}}


@pytest.mark.parametrize("change, words", [
    ({"methods": ["CVA", "CVX"]}, ["methods[1]: must be one of"]),
    ({"methods": ["CVA", "CVA"]}, ["methods[1]: duplicate method CVA"]),
    ({"dense": None}, ["no section to run"]),
    ({"grazing": {"h": 1e-3, "depths": [1e-4], "scenes": [{"system": "bouncing_ball"}]}},
     ["grazing.scenes[0].system: must be one of"]),
    ({"surface": {"h": 1e-2, "T": 1, "scenes": [{"system": "double_pendulum", "kinds": ["out", "rest"]}]}},
     ["surface.scenes[0].kinds[1]: rest has no construction on the double pendulum"]),
    ({"step_limit": {"h_min": 0.1, "h_max": 0.01, "scenes": [{"system": "cart_pendulum", "T": 1}]}},
     ["step_limit.h_max: must be > h_min"]),
    ({"boundary": {"h": 1e-2, "scenes": [{"system": "cart_pendulm", "k": 4, "T": 1}]}},
     ["boundary.scenes[0].system: unknown built-in system 'cart_pendulm'; did you mean 'cart_pendulum'?"]),
    ({"dense": {"scenes": [{"system": "bouncing_ball", "q0": [1e-4], "h": 0.02, "T": 1}]}},
     ["dense.scenes[0].p0: give q0 and p0 together"]),
    ({"dense": {"scenes": [{"system": "bouncing_ball", "h": 0.02, "T": 1, "params": {"mass": 2}}]}},
     ["dense.scenes[0].params: unknown parameter"]),
    ({"report": {"template": "nowhere.md", "output": "x.md"}}, ["report.template: template not found"]),
    ({"hygiene": {"scenes": [{"system": "oscillator_wall", "h": 0.1, "T": 1, "kw": {"beta": 1, "qq": 2}}]}},
     ["hygiene.scenes[0].kw.qq: unknown key"]),
])
def test_extremes_schema_names_the_field(change, words):
    data = {k: v for k, v in (BASE | change).items() if v is not None}
    with pytest.raises(ConfigError) as e:
        parse_study(data, source="s.yaml", base_dir=ROOT)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("s.yaml: ")
    for w in words:
        assert w in msg, msg


WP = {"study": "work_precision", "name": "w", "system": "cart_pendulum", "beta": [3.2], "T": 1, "methods": ["CVA"],
      "h": [1e-2]}


@pytest.mark.parametrize("change, words", [
    ({"baselines": {"RK45": [1e-6]}}, ["baselines.RK45: unknown solver"]),
    ({"baseline_max_T": {"Radau": 10}}, ["baseline_max_T.Radau: not a solver of baselines"]),
    ({"beta": {"start": 4, "stop": 3, "num": 2}}, ["beta: start (4) must be <= stop (3)"]),
    ({"methods": ["CVA", {"name": "CVA"}]}, ["methods[1]: duplicate label 'CVA'"]),
    ({"methods": [{"name": "VCI", "ld": "SVC4"}]}, ["methods[0]: VCI needs an explicit discrete Lagrangian"]),
    ({"system": "double_pendulum", "params": {"m9": 1}}, ["params: unknown parameter of system double_pendulum"]),
    ({"system": "damped_oscillator"}, ["beta: system damped_oscillator has no initial-condition map"]),
    ({"h": [1e-2, -1]}, ["h[1]: must be > 0"]),
    ({"h": [1e-2, 10]}, ["h[1]: 10 is longer than T = 1"]),
    ({"repeat": 3}, ["repeat: unknown key; did you mean 'repeats'?"]),
    ({"system": "incline", "beta": [0.5], "baselines": {"DOP853": [1e-6]}},
     ["baselines: the solve_ivp baselines take one elastic constraint; incline", "leave baselines out"]),
    ({"system": str(ROOT / "docs/examples/rocking_block.yaml")},
     ["system: this study starts every run from Xi(beta)", "has none", "initial_states"]),
])
def test_work_precision_schema_names_the_field(change, words):
    with pytest.raises(ConfigError) as e:
        parse_study(WP | change, source="w.yaml")
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("w.yaml: ")
    for w in words:
        assert w in msg, msg


# --- the template --------------------------------------------------------------------------------------
def test_template_blocks_placeholders_and_comments():
    t = "<!--# note -->\n# {{title}}\n<!-- if a -->\nA {{x}}\n<!-- end if -->\n<!-- if b -->\nB\n<!-- end if -->\nend\n"
    assert render(t, {"title": "T", "x": 1}, present={"a"}) == "# T\nA 1\nend\n"
    assert render(t, {"title": "T", "x": 1}, present={"b"}) == "# T\nB\nend\n"
    with pytest.raises(ValueError, match=r"unknown placeholder \{\{x\}\}"):
        render(t, {"title": "T"}, present={"a"})
    with pytest.raises(ValueError, match="not closed"):
        render("<!-- if a -->\nA\n", {}, present={"a"})
    with pytest.raises(ValueError, match="do not nest"):
        render("<!-- if a -->\n<!-- if b -->\n<!-- end if -->\n", {}, present={})


def _results():
    """Results of two sections in the shape run_extremes returns (numbers made up for the layout)."""
    return {"name": "x", "methods": ["CVA", "VCI"], "started": "2026-01-01 00:00:00", "wall_time": 3.0,
            "long_horizon": [{"system": "cart_pendulum", "method": m, "h": 0.01, "steps": 100000, "beta": 3.2,
                              "status": "ok", "impacts": 800, "wall_time": 0.1, "slope_H": 1e-5,
                              "maxdev_H": {"10000": 0.02, "100000": 0.03}} for m in ("CVA", "VCI")],
            "accumulation": [{"method": m, "h": 0.01, "T": 30.0, "c": 2.0, "status": "ok", "exact_onset": 6.8,
                              "impacts": 90} for m in ("CVA", "VCI")]}


def test_extremes_report_renders_present_sections_from_the_results():
    md = render_extremes(_results(), TEMPLATE, command="cmd", config="c.yaml", json_path="r.json")
    assert md.startswith("# Numerical stability at the extremes")
    assert "## Long horizon: 1e+05 steps" in md and "after 1e4, 1e5 steps (bounded error: the two stay alike" in md
    assert "| CVA | ok | 800 | 1.00e-05 | 0.02 / 0.03 |" in md
    assert "Dropped from y0 = 1 with drag c = 2.0 (m = 1, g = 10), T = 30." in md
    for absent in ("## Step size", "### Grazing contact", "### Floating-point hygiene", "### High energy"):
        assert absent not in md
    assert "{{" not in md and "<!--" not in md
    ctx = extremes_context(_results(), command="cmd", config="c.yaml", template="t", json_path="r.json")
    assert ctx["long_checkpoints"] == "1e4, 1e5" and ctx["step_h_min"] == "-"   # absent section: a dash


# --- oracles -------------------------------------------------------------------------------------------
def test_ball_without_drag_bounces_with_its_period():
    y0, g = 1e-4, 10.0
    times, speeds = ball_exact(y0, g, 0.0, 1.0)
    t1, v = math.sqrt(2 * y0 / g), math.sqrt(2 * g * y0)
    assert times[0] == pytest.approx(t1, rel=1e-15) and np.allclose(speeds, v, rtol=1e-15)
    assert np.allclose(np.diff(times), 2 * v / g, rtol=1e-12, atol=0)
    assert np.isnan(ball_exact_onset(times, 1e-3)) and ball_exact_onset(times, 0.02) == times[0]


def test_ball_with_drag_matches_an_ode_solve():
    """The closed form of y'' = -g - k y' with elastic impacts against DOP853 + event location."""
    from scipy.integrate import solve_ivp

    y0, g, k, T = 1.0, 10.0, 2.0, 2.5
    times, speeds = ball_exact(y0, g, k, T)

    def hit(t, y):
        return y[0]

    hit.terminal, hit.direction = True, -1
    t, y, ev = 0.0, [y0, 0.0], []
    tt = np.linspace(0.0, T, 501)
    ynum = np.full_like(tt, np.nan)
    while t < T:
        sol = solve_ivp(lambda s, z: [z[1], -g - k * z[1]], (t, T), y, method="DOP853", rtol=1e-13, atol=1e-13,
                        events=hit, dense_output=True)
        m = (tt >= t) & (tt <= sol.t[-1])
        ynum[m] = sol.sol(tt[m])[0]
        if not sol.t_events[0].size:
            break
        t = float(sol.t_events[0][0])
        ev.append(t)
        y = [0.0, -float(sol.y_events[0][0][1])]
    n = len(ev)
    assert n >= 4 and np.allclose(times[:n], ev, rtol=0, atol=1e-10)
    assert np.max(np.abs(ball_position(tt, y0, g, k, times, speeds) - ynum)) < 1e-10
    assert np.all(np.diff(speeds) < 0)      # drag: every bounce slower
