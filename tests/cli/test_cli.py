"""The CLI end to end on a tiny sweep (typer's CliRunner): sweep, info, plot, resume, --force,
failures recorded as data, and bad input (one-line errors, non-zero exit, no output file)."""
from __future__ import annotations

import json
import re
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

import vcirun
from vcirun.cli.main import app
from vcirun.io.errors import StorageError
from vcirun.io.reader import load_trajectory, read_results
from vcirun.experiments.config import load_config
from vcirun.experiments.sweep import expand, run_sweep

TINY = """\
name: tiny
system: cart_pendulum
methods: [CVA, VCI]
h: [3.2e-2, 1.0e-2]
beta: {{start: 3.2, stop: 4.2, num: 2}}
T: 0.5
output: {output}
timing_repeats: 1
{extra}"""


@pytest.fixture
def runner():
    return CliRunner()


@pytest.fixture
def tiny(tmp_path, monkeypatch):
    """A tiny config in a scratch working directory; results go to results/tiny.h5 there."""
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "tiny.yaml"
    path.write_text(TINY.format(output="results/tiny.h5", extra=""))
    return path


@pytest.fixture
def count_runs(monkeypatch):
    """Counts the timed vcirun.simulate calls (T = the sweep's T; warm-ups and preflight use T = h)."""
    calls = []
    original = vcirun.simulate

    def counting(system, method, **kw):
        if kw.get("T", 0) >= 0.5:
            calls.append((method, kw.get("h"), kw.get("beta")))
        return original(system, method, **kw)

    monkeypatch.setattr(vcirun, "simulate", counting)
    return calls


def invoke(runner, *args):
    return runner.invoke(app, [str(a) for a in args], catch_exceptions=False)


def assert_one_line_error(result, *words):
    assert result.exit_code == 1, (result.exit_code, result.output)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert "Traceback" not in result.output
    for w in words:
        assert w in lines[0], lines[0]


def test_sweep_info_plot_resume_force(runner, tiny, count_runs):
    out = Path("results/tiny.h5")
    r = invoke(runner, "sweep", tiny, "--workers", "1")
    assert r.exit_code == 0, r.output
    assert "8 runs (8 computed, 0 already stored; 8 ok)" in r.stdout
    assert len(count_runs) == 8 and len(set(count_runs)) == 8

    res = read_results(out)
    assert len(res.runs) == 8 and res.incomplete == []
    assert {r.run_id for r in res.runs} == {s.run_id for s in expand(load_config(tiny))}
    assert all(r.attrs["status"] == "ok" and np.isfinite(r.attrs["l2_error"]) for r in res.runs)
    # second-order methods: the error drops by about (3.2)^2 between the two steps
    l2 = {(r.attrs["label"], r.attrs["h"], r.attrs["beta"]): r.attrs["l2_error"] for r in res.runs}
    for m in ("CVA", "VCI"):
        for b in (3.2, 4.2):
            assert 4 < l2[(m, 0.032, b)] / l2[(m, 0.01, b)] < 30
    a = res.attrs
    assert a["config_yaml"] == tiny.read_text() and a["n_runs_expected"] == 8
    assert a["numpy_version"] == np.__version__ and a["h5py_version"] == h5py.__version__
    assert a["tolerances"]["newton_tol"] > 0 and a["vcirun_version"] == vcirun.__version__
    assert set(res.references) == {"beta=3.2", "beta=4.2"}
    for ref in res.references.values():
        assert ref["status"] == "ok" and ref["accuracy"] < 1e-8
    from vcirun.io.reader import load_reference, load_trajectory

    tr = load_trajectory(out, res.runs[0].run_id)  # trajectories on the grid, time-major
    n_steps = res.runs[0].attrs["n_steps"]
    assert tr.q.shape == (n_steps + 1, 2) and tr.t[-1] == pytest.approx(n_steps * tr.h)
    assert load_reference(out, "beta=3.2")["q"].shape[1] == 2
    stamps = {r.run_id: r.attrs["committed_at"] for r in res.runs}

    r = invoke(runner, "info", out)
    assert r.exit_code == 0, r.output
    assert "8 of 8 runs stored" in r.stdout and "tiny: 8 runs, by method and h" in r.stdout
    r = invoke(runner, "info", out, "--runs")
    assert r.exit_code == 0 and "tiny: 8 runs" in r.stdout
    assert all(rid in r.stdout for rid in stamps)

    r = invoke(runner, "plot")  # no argument: every results file under results/ (here one)
    assert r.exit_code == 0, r.output
    figdir = Path("results/figures/tiny")
    for name in ("fig4_l2_error_vs_beta.png", "fig4_l2_error_vs_beta.pdf", "work_precision.png",
                 "table1_methods.csv", "table1_methods.md", "table2_timing.csv", "table2_timing.md"):
        assert (figdir / name).stat().st_size > 0, name
        assert str(figdir / name) in r.stdout
    assert "skipped fig3" in r.stdout  # CVA and VCI have no modified Hamiltonian
    assert "Table II" in r.stdout and "Table I" in r.stdout

    # resume: nothing to compute, nothing rewritten
    count_runs.clear()
    before = out.stat().st_mtime_ns
    r = invoke(runner, "sweep", tiny, "--workers", "1")
    assert r.exit_code == 0 and "0 computed, 8 already stored" in r.stdout
    assert count_runs == [] and out.stat().st_mtime_ns == before
    assert {x.run_id: x.attrs["committed_at"] for x in read_results(out).runs} == stamps

    # --force recomputes everything into a new file
    r = invoke(runner, "sweep", tiny, "--workers", "1", "--force")
    assert r.exit_code == 0 and "8 computed, 0 already stored" in r.stdout
    assert len(count_runs) == 8
    assert len(read_results(out).runs) == 8
    assert read_results(out).attrs["history"][-1]["status"] == "complete"


def test_parallel_workers_give_identical_results(runner, tiny, tmp_path):
    one = invoke(runner, "sweep", tiny, "--workers", "1", "--quiet", "--output", tmp_path / "one.h5")
    two = invoke(runner, "sweep", tiny, "--workers", "2", "--quiet", "--output", tmp_path / "two.h5")
    assert one.exit_code == 0 and two.exit_code == 0, (one.output, two.output)
    a, b = read_results(tmp_path / "one.h5"), read_results(tmp_path / "two.h5")
    assert [r.run_id for r in a.runs] == [r.run_id for r in b.runs]
    assert {r.attrs["worker_pid"] for r in b.runs} != {r.attrs["worker_pid"] for r in a.runs}
    for ra, rb in zip(a.runs, b.runs):
        assert ra.attrs["l2_error"] == rb.attrs["l2_error"]
        ta, tb = load_trajectory(a.path, ra.run_id), load_trajectory(b.path, rb.run_id)
        np.testing.assert_array_equal(ta.q, tb.q)
        np.testing.assert_array_equal(ta.impacts, tb.impacts)


def test_resume_after_partial_sweep_computes_only_the_rest(tiny, count_runs, tmp_path):
    cfg = load_config(tiny)
    half = cfg.model_copy(update={"methods": cfg.methods[:1]})  # a different config: CVA only
    first = run_sweep(half, output=tmp_path / "part.h5", workers=1, progress=False)
    assert first.computed == 4
    # Same runs, other config key: refused, with the way out in the message.
    with pytest.raises(StorageError, match="--force"):
        run_sweep(cfg, output=tmp_path / "part.h5", workers=1, progress=False)
    count_runs.clear()
    full = run_sweep(cfg, output=tmp_path / "full.h5", workers=1, progress=False)
    assert full.computed == 8 and len(count_runs) == 8


def test_failed_runs_are_recorded_and_the_sweep_goes_on(runner, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = tmp_path / "fail.yaml"
    cfg.write_text(TINY.format(output="results/fail.h5", extra="tolerances: {max_iter: 1}\n"))
    original = vcirun.simulate

    def flaky(system, method, **kw):
        if method == "VCI" and kw.get("beta") == 4.2 and kw.get("T") == 0.5:
            raise RuntimeError("boom in the integrator")
        return original(system, method, **kw)

    monkeypatch.setattr(vcirun, "simulate", flaky)
    r = invoke(runner, "sweep", cfg, "--workers", "1")
    assert r.exit_code == 0, r.output
    assert "did not finish with status ok" in r.stdout
    res = read_results("results/fail.h5")
    assert len(res.runs) == 8
    by_status = {}
    for run in res.runs:
        by_status.setdefault(run.attrs["status"], []).append(run)
    assert sorted(by_status) == ["error", "newton_failed"] and len(by_status["error"]) == 2
    for run in by_status["newton_failed"]:
        assert "step 0" in run.attrs["message"] and not np.isfinite(run.attrs["l2_error"])
        assert "run failed" in run.attrs["l2_note"]
    err = by_status["error"][0].attrs
    assert err["message"] == "RuntimeError: boom in the integrator" and "Traceback" in err["traceback"]
    r = invoke(runner, "info", "results/fail.h5", "--failed")
    assert r.exit_code == 0 and "boom in the integrator" in r.stdout
    r = invoke(runner, "plot", "results/fail.h5")
    assert r.exit_code == 0 and "skipped fig4" in r.stdout
    table = Path("results/figures/tiny/table2_timing.md").read_text()  # folder named after the sweep
    assert "n/a (2 failed)" in table
    # --retry-failed recomputes exactly the failed runs (they fail again, deterministically)
    monkeypatch.setattr(vcirun, "simulate", original)
    r = invoke(runner, "sweep", cfg, "--workers", "1", "--retry-failed")
    assert r.exit_code == 0 and "8 computed, 0 already stored" in r.stdout


def test_bad_config_exits_1_with_one_line_and_writes_nothing(runner, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    bad = tmp_path / "bad.yaml"
    bad.write_text(TINY.format(output="results/bad.h5", extra="").replace("h: [3.2e-2, 1.0e-2]", "h: [3.2e-2, -1]"))
    for cmd in ("validate", "sweep"):
        r = invoke(runner, cmd, bad)
        assert_one_line_error(r, "bad.yaml: h[1]: must be > 0 (got -1)")
    assert not Path("results").exists()
    r = invoke(runner, "sweep", tmp_path / "missing.yaml")
    assert_one_line_error(r, "missing.yaml: file not found")
    assert not Path("results").exists()


def test_method_rejected_by_the_core_leaves_no_output(runner, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = tmp_path / "c.yaml"
    cfg.write_text(TINY.format(output="results/c.h5", extra=""))
    original = vcirun.simulate

    def picky(system, method, **kw):  # the core raising ValueError for input it cannot run
        if method == "VCI":
            raise ValueError("method: VCI does not support this (simulated)")
        return original(system, method, **kw)

    monkeypatch.setattr(vcirun, "simulate", picky)
    r = invoke(runner, "sweep", cfg, "--workers", "1")
    assert_one_line_error(r, "methods[1] (VCI):", "simulated")
    assert not Path("results/c.h5").exists()


def test_other_bad_input(runner, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert_one_line_error(invoke(runner, "info", "nope.h5"), "nope.h5: file not found")
    assert_one_line_error(invoke(runner, "plot"), "no results")
    Path("results").mkdir()
    Path("results/junk.h5").write_bytes(b"garbage")
    assert_one_line_error(invoke(runner, "plot"), "junk.h5", "not a readable HDF5")
    assert_one_line_error(invoke(runner, "info", "results/junk.h5"), "not a readable HDF5")
    assert_one_line_error(invoke(runner, "simulate", "--method", "FOO", "--T", "0.1"), "unknown method 'FOO'")
    assert_one_line_error(invoke(runner, "simulate", "--param", "m1", "--T", "0.1"), "NAME=VALUE")
    assert_one_line_error(invoke(runner, "simulate", "--param", "zz=1", "--T", "0.1"), "params.zz")
    assert_one_line_error(invoke(runner, "simulate", "--h", "-0.01"), "h:")
    r = invoke(runner, "sweep")
    assert r.exit_code == 2 and "Missing argument" in r.output  # usage errors: typer's exit status 2


def test_simulate_prints_a_summary(runner):
    r = invoke(runner, "simulate", "--h", "0.01", "--T", "1.0", "--param", "m2=0.2")
    assert r.exit_code == 0, r.output
    out = r.stdout
    assert re.search(r"steps\s+100\b", out) and re.search(r"impacts\s+1 at t = 0\.72", out)
    assert re.search(r"status\s+ok", out) and "max |H - H0|" in out and "wall time" in out
    assert "beta = 3.2" in out  # the cart-pendulum's default initial condition


def test_simulate_failure_exits_nonzero(runner):
    r = invoke(runner, "simulate", "--T", "0.1", "--newton-tol", "1e-300")
    assert r.exit_code == 1
    assert re.search(r"status\s+newton_failed", r.stdout)
    assert r.stderr.startswith("error: run ended with status newton_failed")


@pytest.mark.parametrize("command", ["simulate", "sweep", "plot", "validate", "info"])
def test_every_command_has_help_with_an_example(runner, command):
    r = invoke(runner, command, "--help")
    assert r.exit_code == 0
    assert "Example" in r.stdout and f"vcirun {command}" in r.stdout


def test_validate_summarises(runner, tiny):
    r = invoke(runner, "validate", tiny)
    assert r.exit_code == 0
    assert re.search(r"runs\s+8", r.stdout) and "CVA, VCI" in r.stdout and "results/tiny.h5" in r.stdout


def test_history_records_each_session(tiny, tmp_path):
    cfg = load_config(tiny)
    out = tmp_path / "h.h5"
    run_sweep(cfg, output=out, workers=1, progress=False, argv=["first"])
    run_sweep(cfg, output=out, workers=1, progress=False, argv=["second"], force=True)
    hist = read_results(out).attrs["history"]
    assert [h["argv"] for h in hist] == [["second"]]  # --force starts a new file
    with h5py.File(out, "r") as f:
        assert json.loads(f.attrs["history"])[0]["computed"] == 8


@pytest.mark.parametrize("workers", [1, 2])
def test_progress_bar_on_a_terminal(tiny, tmp_path, workers):
    import io

    from rich.console import Console

    buf = io.StringIO()
    console = Console(file=buf, force_terminal=True, width=120)
    s = run_sweep(load_config(tiny), output=tmp_path / "p.h5", workers=workers, console=console)
    assert s.computed == 8
    text = buf.getvalue()
    assert f"tiny: 8 runs on {workers} worker" in text and "ETA" in text and "8/8" in text


def test_a_dead_worker_stops_the_sweep_and_keeps_finished_runs(tiny, tmp_path, monkeypatch):
    import os

    from vcirun.experiments.worker import SweepError

    original = vcirun.simulate

    def crashing(system, method, **kw):  # a segfault-like death in one worker (fork inherits the patch)
        if method == "VCI" and kw.get("beta") == 4.2 and kw.get("T") == 0.5:
            os._exit(3)
        return original(system, method, **kw)

    monkeypatch.setattr(vcirun, "simulate", crashing)
    out = tmp_path / "crash.h5"
    with pytest.raises(SweepError, match=r"a worker process died unexpectedly .*rerun the same command"):
        run_sweep(load_config(tiny), output=out, workers=2, progress=False)
    res = read_results(out)
    assert res.attrs["history"][-1]["status"] == "worker_died" and res.incomplete == []
    assert len(res.runs) < 8
    monkeypatch.setattr(vcirun, "simulate", original)
    s = run_sweep(load_config(tiny), output=out, workers=2, progress=False)
    assert s.computed == 8 - len(res.runs) and len(read_results(out).runs) == 8


def test_timing_repeats_keep_the_fastest(tiny, tmp_path, count_runs):
    cfg = load_config(tiny).model_copy(update={"timing_repeats": 3})
    run_sweep(cfg, output=tmp_path / "rep.h5", workers=1, progress=False)
    assert len(count_runs) == 3 * 8 and len(set(count_runs)) == 8
    for r in read_results(tmp_path / "rep.h5").runs:
        reps = r.attrs["wall_time_repeats"]
        assert len(reps) == 3 and r.attrs["wall_time"] == min(reps)
