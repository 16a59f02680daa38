"""The solve_ivp baselines of the work-precision study (vcirun.experiments.baselines): correctness only.

They must solve the same nonsmooth problem as the exact reference (vcirun.reference: DOP853 at
rtol 1e-13, self-checked), report it on the same grid as a vcirun run, and converge to it as rtol
decreases. No timing is asserted (benchmarks live in bench/).

Observed on the cart-pendulum (beta = 3.2, T = 5, h = 1e-2, three impacts), L2 error against the
reference: DOP853 1.2e-5 (rtol 1e-8), 9.1e-8 (1e-10), 2.6e-10 (1e-12); Radau 1.1e-7 (1e-8).
The error over 5 s is a few hundred to a thousand times rtol: the impacts amplify the local errors.
"""
from __future__ import annotations

import numpy as np
import pytest

import vcirun
from vcirun.experiments.baselines import BASELINES, solve_ivp_run
from vcirun.scenes.oracles import oscillator_wall_exact

T, BETA, H = 5.0, 3.2, 1e-2


@pytest.fixture(scope="module")
def ref():
    return vcirun.reference("cart_pendulum", T=T, beta=BETA)


@pytest.fixture(scope="module")
def dop():
    return {rtol: solve_ivp_run("cart_pendulum", "DOP853", h=H, T=T, beta=BETA, rtol=rtol)
            for rtol in (1e-8, 1e-10, 1e-12)}


def test_grid_and_record_match_a_vcirun_run(dop):
    b = dop[1e-10]
    tr = vcirun.simulate("cart_pendulum", "CVA", h=H, T=T, beta=BETA)
    assert b.status == "ok", b.message
    np.testing.assert_array_equal(b.t, tr.t)
    assert b.q.shape == tr.q.shape and b.p.shape == tr.p.shape and b.H.shape == tr.H.shape
    np.testing.assert_array_equal(b.q[0], tr.q[0])
    np.testing.assert_array_equal(b.p[0], tr.p[0])
    assert len(b.impacts) == len(tr.impacts) == 3
    # each impact is marked in the grid step that contains it
    assert b.impact_step.sum() == 3
    for ti in b.impacts:
        k = int(np.floor(ti / H))
        assert b.impact_step[k] and b.t[k] <= ti <= b.t[k + 1]
    assert b.wall_time > 0 and b.options["nfev"] > 0


def test_dop853_agrees_with_the_exact_reference_to_its_tolerance(dop, ref):
    errs = {rtol: vcirun.l2_error(b, ref) for rtol, b in dop.items()}
    # the reference is itself good to ~1e-10 (ref.accuracy): the tightest solve is limited by it
    assert ref.accuracy < 1e-9
    assert errs[1e-12] < 1e-8
    assert errs[1e-10] < 1e-6
    assert errs[1e-8] < 1e-4
    assert errs[1e-12] < errs[1e-10] < errs[1e-8]          # converges as rtol decreases
    for rtol, b in dop.items():
        assert np.max(np.abs(b.impacts - ref.impacts)) < 1e4 * rtol
        # the reset is exact, so H only drifts with the smooth integration error
        assert np.max(np.abs(b.H - b.H[0])) < 1e4 * rtol * abs(b.H[0])


def test_reset_is_the_exact_elastic_reflection(dop):
    from vcirun.run.resolve import resolve_system
    from vcirun.codegen.build import load_module
    from vcirun.methods.table import METHODS

    b = dop[1e-12]
    s = resolve_system("cart_pendulum")
    prm = s.param_values(None)
    mod = load_module(s, METHODS["CVA"].kernel_set())
    for q, pm, pp in zip(b.impact_q, b.impact_p_minus, b.impact_p_plus):
        assert abs(q[0]) < 1e-9                                         # on the surface y = 0
        g = np.empty(2)
        mod.sys_dphi(q, prm, g)
        M = np.empty((2, 2))
        mod.sys_M(q, prm, M)
        W = np.linalg.inv(M)
        assert g @ W @ pm < 0 < g @ W @ pp                              # in, then out
        np.testing.assert_allclose(g @ W @ pp, -(g @ W @ pm), rtol=1e-12)  # normal velocity reversed
        assert abs(mod.hamiltonian(q, pp, prm) - mod.hamiltonian(q, pm, prm)) < 1e-12


def test_radau_agrees_with_the_exact_reference(ref):
    b = solve_ivp_run("cart_pendulum", "Radau", h=H, T=T, beta=BETA, rtol=1e-8)
    assert b.status == "ok" and len(b.impacts) == 3
    assert vcirun.l2_error(b, ref) < 1e-5
    assert np.max(np.abs(b.impacts - ref.impacts)) < 1e-6


def test_numpy_kernels_give_the_same_solution(dop):
    b = solve_ivp_run("cart_pendulum", "DOP853", h=H, T=T, beta=BETA, rtol=1e-8, kernels="numpy")
    a = dop[1e-8]
    assert b.status == "ok"
    np.testing.assert_allclose(b.q, a.q, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.impacts, a.impacts, rtol=0, atol=1e-10)


def test_double_pendulum_agrees_with_its_reference():
    ref = vcirun.reference("double_pendulum", T=10.0)
    b = solve_ivp_run("double_pendulum", "DOP853", h=1e-2, T=10.0, rtol=1e-11)
    assert b.status == "ok" and len(b.impacts) == len(ref.impacts) == 3
    assert vcirun.l2_error(b, ref) < 1e-6


def test_oscillator_against_the_closed_form():
    b = solve_ivp_run("oscillator_wall", "DOP853", h=0.05, T=30.0, q0=np.array([1.0]), p0=np.array([0.0]),
                      rtol=1e-11)
    x, _, t_imp = oscillator_wall_exact(b.t, 1.0, 0.0)
    assert b.status == "ok" and len(b.impacts) == len(t_imp) == 7
    assert np.max(np.abs(b.q[:, 0] - x)) < 1e-8
    assert np.max(np.abs(b.impacts - t_imp)) < 1e-8


def test_restart_steps_off_the_surface_so_no_impact_is_missed():
    # A naive restart right after the reset starts the event function at phi ~ -1e-17; solve_ivp then
    # sees no crossing when the next hop is shorter than its first step, and the cart falls through
    # the floor (observed at rtol 1e-3 after 26 impacts). The escape micro step prevents that.
    kw = dict(h=1e-2, T=300.0, beta=3.2, rtol=1e-3, energies=False)
    naive = solve_ivp_run("cart_pendulum", "DOP853", escape=False, **kw)
    fixed = solve_ivp_run("cart_pendulum", "DOP853", **kw)
    assert naive.q[:, 0].min() < -100.0                   # the documented failure of the naive restart
    assert fixed.status == "ok" and fixed.q[:, 0].min() > -0.5 and len(fixed.impacts) > 200


def test_bad_input_raises_naming_the_field():
    for kw, field in [({"method": "RK45"}, "method"), ({"h": 0.0}, "h"), ({"T": -1.0}, "T"), ({"rtol": 0.0}, "rtol")]:
        args = dict(method="DOP853", h=H, T=T, beta=BETA, rtol=1e-6) | kw
        method = args.pop("method")
        with pytest.raises(ValueError, match=f"^{field}:"):
            solve_ivp_run("cart_pendulum", method, **args)
    assert set(BASELINES) == {"DOP853", "Radau"}


# --- the work-precision study around the baselines (vcirun.experiments.workprecision) ----------------

def test_shipped_study_configs_load():
    from pathlib import Path

    from vcirun.experiments.studies.schema import load_study

    root = Path(__file__).resolve().parents[2]
    for name, study in [("work_precision", "work_precision"), ("work_precision_double", "work_precision"),
                        ("long_horizon", "long_horizon")]:
        cfg = load_study(root / "configs" / f"{name}.yaml")
        assert cfg.study == study and cfg.name == name
        assert {b.split("/")[0] for b in cfg.baselines} <= set(BASELINES)
        if study == "work_precision":   # the study's rule: at least 6 steps from 1e-1 down to 1e-4, rtol 1e-3 .. 1e-12
            assert len(cfg.h) >= 6 and max(cfg.h) >= 1e-1 and min(cfg.h) <= 1e-4
            assert min(cfg.baselines["DOP853"]) <= 1e-12 and max(cfg.baselines["DOP853"]) >= 1e-3
        else:
            assert min(cfg.horizons()) >= 1000


def test_matching_on_the_pareto_front():
    from vcirun.experiments.workprecision import _front, time_at_error

    # (time, error): the slower, less accurate run is not on the front
    front = _front([(1.0, 1e-2), (2.0, 1e-4), (1.5, 1e-1), (4.0, 1e-6)])
    assert front == [(1.0, 1e-2), (2.0, 1e-4), (4.0, 1e-6)]
    t, how = time_at_error(front, 1e-3)          # halfway in log error -> halfway in log time
    assert how == "interpolated" and t == pytest.approx(np.sqrt(2.0))
    assert time_at_error(front, 1e-1) == (1.0, "cheapest_more_accurate")
    assert time_at_error(front, 1e-8) == (4.0, "not_reached")


def test_a_tiny_study_runs_end_to_end(tmp_path):
    from vcirun.experiments import workprecision as wp
    from vcirun.experiments.studies.schema import WorkPrecisionStudy

    cfg = WorkPrecisionStudy(study="work_precision", name="tiny", system="cart_pendulum", beta=[3.2], T=1.0,
                         methods=["CVA"], h=[1e-2, 5e-3], baselines={"DOP853": [1e-4, 1e-8]}, repeats=1,
                         baseline_repeats=1, output=str(tmp_path / "tiny.json"))
    res = wp.run_study(cfg, log=lambda m: None)
    path = wp.save(res, cfg.output)
    back = wp.load(path)
    cva = [p for p in back["summary"] if p["label"] == "CVA"]
    assert len(cva) == 2 and all(p["all_ok"] and p["err"] > 0 for p in cva)
    assert cva[0]["err"] / cva[1]["err"] == pytest.approx(4.0, rel=0.3)    # second order, one impact
    assert {r["label"] for r in back["ratios"]} == {"CVA"}
    assert all(r["DOP853_wall_how"] in ("interpolated", "cheapest_more_accurate", "not_reached")
               for r in back["ratios"])
    from vcirun.experiments.wp_figures import is_study_file, plot_study

    assert is_study_file(path)
    written = plot_study(path, tmp_path / "fig")
    assert {p.suffix for p in written} == {".png", ".pdf", ".md"} and all(p.stat().st_size > 0 for p in written)
