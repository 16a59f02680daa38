"""What `simulate(tol=...)` and `error_estimate` refuse, and what they pass on: a method whose runs the
choice cannot certify is refused by name; the tier reaches every run of the choice; a reference of
another start is refused."""
from __future__ import annotations

import warnings

import pytest

import vcirun


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


@pytest.mark.parametrize("system, kw, words", [
    ("cart_pendulum", dict(method="SVC"), "ignores the constraint"),
    ("cart_pendulum", dict(method="midpoint"), "ignores the constraint"),
    ("bouncing_ball", dict(method="CVA6", params={"c": 0.5}), "not verified"),
    ("cart_pendulum", dict(tier="bogus"), "tier"),
    ("cart_pendulum", dict(h=1e-7), "^h: .*more than tol='s limit"),   # 1e7 steps a run: 3.3 GB, minutes
])
def test_refused_by_name(system, kw, words):
    with pytest.raises(ValueError, match=words):
        vcirun.simulate(system, T=1, tol=1e-4, **kw)


def test_the_tier_reaches_every_run_and_the_trajectory_says_which():
    tr = vcirun.simulate("oscillator_wall", T=1, tol=1e-5, method="CVA", tier="interpreted")
    assert tr.tier == "interpreted" and tr.choice.status == "ok"
    tc = vcirun.simulate("oscillator_wall", T=1, tol=1e-5, method="CVA", tier="compiled")
    assert tc.tier == "compiled"
    # (the choices may differ: their costs per step are the tier's) the same run on either tier
    again = vcirun.simulate("oscillator_wall", tr.method, T=1, h=tr.h, tier="compiled")
    assert abs(again.q - tr.q).max() <= 1e-12


@pytest.mark.parametrize("kw, words", [
    (dict(companions=2.0), "companions"), (dict(companions=True), "companions"),
    (dict(reference="x"), "reference"),
])
def test_error_estimate_arguments(kw, words):
    tr = vcirun.simulate("cart_pendulum", "CVA", T=1, h=0.01)
    with pytest.raises(ValueError, match=words):
        tr.error_estimate(**kw)


def test_a_reference_of_another_start_is_refused_and_one_of_this_start_is_printed():
    tr = vcirun.simulate("cart_pendulum", "CVA4", T=2, h=0.01, beta=4.2)
    with pytest.raises(ValueError, match="reference: it is at q"):
        tr.error_estimate(reference=vcirun.reference("cart_pendulum", T=2, beta=3.2))
    est = tr.error_estimate(reference=vcirun.reference("cart_pendulum", T=2, beta=4.2))
    assert est.status == "ok" and str(est).startswith("error estimate (reference): L2 ")


def test_a_model_of_interpreted_costs_is_not_the_compiled_tiers():
    """The scene model keeps costs per step: one made on the interpreted tier (100-1000x slower) is kept
    apart, and the first compiled call pilots every candidate."""
    from vcirun.run.scene_model import _MODELS

    kept = dict(_MODELS)
    _MODELS.clear()   # (the process's models: this test starts without any)
    try:
        a = vcirun.simulate("oscillator_wall", T=0.75, tol=1e-5, tier="interpreted")
        assert a.tier == "interpreted" and "pilots of every candidate" in a.choice.reason
        b = vcirun.simulate("oscillator_wall", T=0.75, tol=1e-5, tier="compiled")
        assert b.tier == "compiled" and "pilots of every candidate" in b.choice.reason, b.choice.reason
        c = vcirun.simulate("oscillator_wall", T=0.75, tol=1e-5, tier="compiled")
        assert "pilots of every candidate" not in c.choice.reason, c.choice.reason
    finally:
        _MODELS.clear()
        _MODELS.update(kept)


def test_the_estimates_companions_run_on_the_calls_tier():
    tr = vcirun.simulate("oscillator_wall", "CVA", T=0.5, h=0.01, tier="interpreted")
    assert tr.run_args.tier == "interpreted"
    runner = tr.run_args.runner(0.5)
    assert runner.tier_used("CVA") == "interpreted"


def test_a_substitute_loader_keeps_no_scene_model():
    from vcirun.codegen.evaluate import python_module_for
    from vcirun.run.scene_model import _MODELS

    before = set(_MODELS)
    tr = vcirun.simulate("oscillator_wall", T=0.6, tol=1e-4, method="CVA", loader=python_module_for)
    assert tr.choice.status == "ok" and set(_MODELS) == before


def test_a_scan_with_a_candidate_on_the_interpreted_tier_files_its_costs_apart(monkeypatch):
    """Under the auto tier one candidate's compiled module may still be building while the others are
    compiled: that scan's costs per step go to the interpreted tier's model."""
    from vcirun.run import pilot
    from vcirun.run.choose import INTERPRETED_KEY
    from vcirun.run.scene_model import _MODELS

    real = pilot.Runner.tier_used
    monkeypatch.setattr(pilot.Runner, "tier_used",
                        lambda self, m: "interpreted" if getattr(m, "name", m) == "CVA4" else real(self, m))
    kept = dict(_MODELS)
    _MODELS.clear()
    try:
        vcirun.simulate("oscillator_wall", T=0.8, tol=1e-5)
        keys = list(_MODELS)
        assert len(keys) == 1 and keys[0][-1] == INTERPRETED_KEY, keys
    finally:
        _MODELS.clear()
        _MODELS.update(kept)


def test_not_reached_because_the_pilots_budget_ran_out_says_so():
    """A long horizon of the cart-pendulum: every candidate's pilots stop on their CPU budget before the
    impacts are resolved; the reason names the budget, not the step limit."""
    tr = vcirun.simulate("cart_pendulum", T=300, tol=1e-6)
    assert tr.choice.status == "not_reached"
    assert tr.choice.reason.startswith("no candidate resolved the motion before its pilots' budget ran out")


def test_a_first_call_on_the_interpreted_tier_reaches_tol(monkeypatch):
    """The README's example on the tier `auto` runs while the compiled one is built: the scan's pilots
    get INTERPRETED_SCAN_FACTOR times SCAN_BUDGET there (50 ms of interpreted pilots stop every
    candidate short of resolving the motion: not_reached). It reaches tol,
    checked against the exact reference."""
    from vcirun.run import choose

    monkeypatch.setattr(choose, "_MODELS", {})   # a first call: the scan, not a scene model's ranking
    tr = vcirun.simulate("cart_pendulum", T=5, beta=4.2, tol=1e-4, tier="interpreted")
    assert tr.tier == "interpreted" and tr.choice.status == "ok", tr.choice.reason
    assert vcirun.l2_error(tr, vcirun.reference("cart_pendulum", T=5, beta=4.2)) <= 1e-4


def test_a_tol_run_that_did_not_reach_tol_is_not_counted_ok(tmp_path):
    """A run of a tol: sweep that finished (status ok) without reaching tol (tol_status not_reached)
    counts as "tol not_reached", not ok (the summary, --strict, `info --failed`), and the table holds
    the choice's strings."""
    from types import SimpleNamespace

    from vcirun.experiments.sweep import _status_counts
    from vcirun.experiments.tables import run_status, runs_table
    from vcirun.io.reader import read_results
    from vcirun.io.writer import ResultsWriter
    from vcirun.run.estimate import sweep_attrs
    from vcirun.run.trajectory_files import trajectory_payload

    tr = vcirun.simulate("oscillator_wall", T=1, tol=1e-300, method="CVA")
    assert tr.status == "ok" and tr.choice.status != "ok"
    attrs, arrays = trajectory_payload(tr)
    attrs.update(sweep_attrs(tr, 1.0, False), label="tol=1e-300", method="auto", method_index=0, ic_key="default",
                 ic_index=0, l2_error=None, run_id="r0")
    path = tmp_path / "tol.h5"
    with ResultsWriter(path, root_attrs={"name": "t"}, config_key="f" * 64) as w:
        w.add_run("r0", attrs, arrays)
        w.finish("complete")
    res = read_results(path)
    a = res.runs[0].attrs
    assert run_status(a) == f"tol {tr.choice.status}"
    assert _status_counts(SimpleNamespace(complete_runs={"r0": a})) == {f"tol {tr.choice.status}": 1}
    table = runs_table(res, only_failed=True)
    assert len(table.rows) == 1 and table.rows[0][4] == f"tol {tr.choice.status}"
    assert float(table.rows[0][2]) == pytest.approx(tr.h)   # the step chosen, not the config's largest
    ds = vcirun.open_results(path)
    assert str(ds.tol_status.values.ravel()[0]) == tr.choice.status and "core_method" in ds


def test_an_estimate_of_a_run_that_ignores_the_constraint_says_so():
    """SVC on the cart-pendulum ignores the wall: its companions converge to the smooth motion, so the
    estimate (5e-4) is its error against that motion, while against the scene's motion it is 13. The
    estimate says which motion it is of."""
    tr = vcirun.simulate("cart_pendulum", "SVC", h=0.01, T=2)
    est = tr.error_estimate()
    assert est.status == "ok" and "ignores the scene's constraint" in est.note
    assert "ignores" not in (vcirun.simulate("cart_pendulum", "CVA", h=0.01, T=2).error_estimate().note or "")


def test_a_refused_system_does_not_stay_on_the_trajectory():
    tr = vcirun.simulate("cart_pendulum", "CVA", h=0.01, T=1)
    for call in (lambda: tr.error_estimate(system=3), lambda: tr.attach_dynamics("no_such_scene")):
        with pytest.raises(ValueError):
            call()
    assert tr.error_estimate().status in ("ok", "unresolved")
    assert tr.source == "cart_pendulum"


@pytest.mark.parametrize("tol, words", [([True], "tol: each entry must be a positive number"),
                                        ([1e-4, True], "tol: each entry"), (True, "tol: each entry"),
                                        ([1e-4, 1e-4], "tol: 0.0001 is listed twice")])
def test_a_bad_tol_list_is_named(tol, words):
    """A bad or repeated entry of `tol:` is named as such (not as the methods it would have made)."""
    from vcirun.experiments.config import ConfigError, parse_config

    with pytest.raises(ConfigError, match=words):
        parse_config({"name": "t", "system": "cart_pendulum", "tol": tol, "beta": [3.2], "T": 1})


def test_the_size_of_a_tol_sweep_is_bounded_by_the_step_limit():
    """A tol: sweep's h defaults to T, the largest step allowed: one step a run would estimate 8.3 KiB
    for a file of 257 MB. The runs' steps are chosen as they run: the estimate says so, gives the
    bound at the choice's step limit, and warns above 2 GiB."""
    from vcirun.experiments.config import parse_config
    from vcirun.experiments.store_size import TOL_MAX_STEPS, store_estimate_of
    from vcirun.run.choose import MAX_STEPS

    assert TOL_MAX_STEPS == MAX_STEPS
    cfg = parse_config({"name": "t", "system": "cart_pendulum", "tol": [1e-8], "methods": ["CVA"],
                        "beta": {"start": 3.0, "stop": 4.0, "num": 10}, "T": 5})
    est = store_estimate_of(cfg)
    assert est.tol_most > 1e9 and est.warn and "runs of tol:" in est.line() and "up to" in est.advice()
    plain = store_estimate_of(parse_config({"name": "p", "system": "cart_pendulum", "methods": ["CVA"], "h": [0.01],
                                            "beta": [3.2], "T": 5}))
    assert plain.tol_most == 0.0 and "tol" not in plain.line()


@pytest.mark.parametrize("system, method, words", [("cart_pendulum", "SVC", "ignores the constraint"),
                                                   ("damped_oscillator", "CVA6", "not verified")])
def test_validate_refuses_the_methods_tol_cannot_certify(system, method, words):
    """The refusals of simulate(tol=, method=) hold for a config's methods with tol: before it runs (the
    sweep's preflight made them; validate passed such configs)."""
    from vcirun.experiments.config import ConfigError, parse_config

    with pytest.raises(ConfigError, match=words):
        parse_config({"name": "t", "system": system, "tol": [1e-4], "methods": [method], "T": 1})
    parse_config({"name": "t", "system": system, "tol": [1e-4], "methods": ["CVA4"], "T": 1})


def test_a_small_largest_step_still_gets_a_ladder():
    """h = 1e-5 over T = 1 starts every ladder at 1e5 steps, whose first run costs most of the scan's
    CPU budget: the budget stopped the ladder after one run (not_reached, with an estimate of 2e-11
    for tol = 1e-3). A ladder that starts at the floor h sets makes three runs whatever they cost."""
    tr = vcirun.simulate("cart_pendulum", "CVA", T=1, tol=1e-3, h=1e-5)
    assert tr.choice.status == "ok", tr.choice.reason
    assert tr.h <= 1e-5 and tr.choice.estimate.l2 <= 1e-3


def test_a_long_call_says_what_it_has_made(monkeypatch, capsys):
    """A tol= call over a long horizon runs pilots of seconds each and returned after minutes with
    nothing said: once it has run PROGRESS_S it prints a line per PROGRESS_S on stderr (a fake clock
    here: 6 s a run)."""
    from vcirun.run import choose

    import itertools

    clock = itertools.count(0.0, 6.0)
    monkeypatch.setattr(choose.time, "monotonic", lambda: next(clock))
    vcirun.simulate("oscillator_wall", T=1, tol=1e-5, method="CVA")
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("tol = 1e-05: ")]
    assert lines and " runs in " in lines[0] and "the last CVA at N = " in lines[0]
    monkeypatch.undo()
    vcirun.simulate("oscillator_wall", T=1, tol=1e-5, method="CVA")   # a short call says nothing
    assert "tol = 1e-05: " not in capsys.readouterr().err
