"""Sweeps on a Dask cluster (`vcirun sweep --scheduler`, `executor: {kind: dask}`): the same file as the
local pool, bit for bit; a worker killed mid-sweep; the scheduler lost part-way, then a local resume;
and the executor's option handling. The clusters are `distributed.LocalCluster`s of 2 worker processes
(1 thread each) in this process; their workers inherit VCIRUN_CACHE_DIR, so they load the kernels the
client's preflight compiled (the shared cache) instead of compiling them."""
from __future__ import annotations

import os
import pickle
import signal
import sys
import threading
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

import vcirun
from vcirun.cli.main import app
from vcirun.experiments import executors
from vcirun.io.reader import Results, load_reference, load_trajectory, read_results
from vcirun.io.writer import ResultsWriter
from vcirun.experiments.config import ConfigError, load_config, parse_config
from vcirun.experiments.sweep import expand, run_sweep
from vcirun.experiments.worker import SweepError

distributed = pytest.importorskip("distributed")  # the `dask` extra; `make test` installs it

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")

CONFIG = """\
name: dasktest
system: cart_pendulum
methods: [CVA, VCI]
h: [3.2e-2, 1.0e-2]
beta: {{start: 3.2, stop: 4.2, num: {num}}}
T: 1
output: {output}
timing_repeats: 1
{extra}"""

DELAY = 0.04  # seconds added to every timed run on the workers: leaves work to interrupt


class SlowRuns(distributed.WorkerPlugin):
    """Slows every timed run (T >= 1) on a worker by DELAY seconds, including workers that a nanny
    restarts; teardown restores vcirun.simulate."""

    name = "vcirun-test-slow-runs"

    def __init__(self, delay: float):
        self.delay = delay

    def setup(self, worker):
        import time as _time

        import vcirun as _v

        original = getattr(_v, "_unslowed_simulate", _v.simulate)
        delay = self.delay

        def slow(*args, **kw):
            if kw.get("T", 0) >= 1:
                _time.sleep(delay)
            return original(*args, **kw)

        _v._unslowed_simulate = original
        _v.simulate = slow

    def teardown(self, worker):
        import vcirun as _v

        if hasattr(_v, "_unslowed_simulate"):
            _v.simulate = _v._unslowed_simulate


def _register_by_value():
    import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # workers cannot import this test module


def start_cluster(delay: float | None = None):
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                                       worker_dashboard_address=":0")
    client = distributed.Client(cluster, set_as_default=False)
    if delay:
        _register_by_value()
        client.register_plugin(SlowRuns(delay))
    return cluster, client


@pytest.fixture(scope="module")
def cluster():
    cluster, client = start_cluster(DELAY)
    yield cluster, client
    client.close()
    cluster.close()


def write_config(tmp_path: Path, num: int = 3, output: str = "results/dasktest.h5", extra: str = "") -> Path:
    path = tmp_path / "dasktest.yaml"
    path.write_text(CONFIG.format(num=num, output=output, extra=extra))
    return path


def invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args], catch_exceptions=False)


def worker_pids(client) -> dict:
    return client.run(os.getpid)


def check_file(path: Path, expected_ids: set) -> Results:
    with h5py.File(path, "r") as f:  # plain h5py opens it; every batch in it is complete
        batches = f["run_batches"] if "run_batches" in f else {}
        assert all(bool(batches[g].attrs["complete"]) for g in batches)
    res = read_results(path)
    ids = [r.run_id for r in res.runs]
    assert res.incomplete == [] and len(ids) == len(set(ids)) and set(ids) <= expected_ids
    return res


class FirstResult:
    """Calls `action` on a thread once the sweep's client has received its first result."""

    def __init__(self, monkeypatch, action):
        self.event = threading.Event()
        self.error = None
        original = ResultsWriter.add_run

        def add_run(writer, *a, **kw):
            self.event.set()
            return original(writer, *a, **kw)

        monkeypatch.setattr(ResultsWriter, "add_run", add_run)
        self.thread = threading.Thread(target=self._run, args=(action,), daemon=True)
        self.thread.start()

    def _run(self, action):
        if self.event.wait(120):
            try:
                action()
            except BaseException as e:  # noqa: BLE001 - reported by the test
                self.error = e

    def join(self):
        self.thread.join(60)
        assert self.error is None, self.error


# --- options and errors (no cluster; first, so that the fork pool below forks no cluster thread) ----
def assert_one_line_error(result, *words):
    assert result.exit_code == 1, (result.exit_code, result.output)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    for w in words:
        assert w in lines[0], lines[0]


def test_local_task_size_splits_tasks_and_gives_the_same_runs(tmp_path):
    cfg = load_config(write_config(tmp_path))
    s = run_sweep(cfg, output=tmp_path / "a.h5", workers=2, task_size=1, progress=False)
    assert s.computed == 12 and s.executor_stats["tasks"] == 12
    assert {r.run_id for r in read_results(tmp_path / "a.h5").runs} == {x.run_id for x in expand(cfg)}


def test_executor_section_of_the_config(tmp_path):
    base = dict(name="x", system="cart_pendulum", methods=["CVA"], h=[0.01], beta=[3.2], T=1)
    cfg = parse_config({**base, "executor": {"kind": "dask", "address": "tcp://10.0.0.5:8786", "task_size": 8,
                                             "cache_dir": "/shared/vcirun"}}, check_semantics=False)
    assert cfg.executor.kind == "dask" and cfg.executor.task_size == 8
    plain = parse_config(base, check_semantics=False)
    assert cfg.canonical_sha256() == plain.canonical_sha256()  # where runs are computed is not a result
    assert [s.run_id for s in expand(cfg)] == [s.run_id for s in expand(plain)]
    for bad, where, words in [
        ({"kind": "dask", "adress": "tcp://h:1"}, "executor.adress", "did you mean 'address'"),
        ({"kind": "slurm"}, "executor.kind", "must be one of"),
        ({"kind": "dask", "address": "not an address"}, "executor.address", "tcp://HOST:8786"),
        ({"kind": "dask", "task_size": 0}, "executor.task_size", "must be >= 1"),
        ({"kind": "local", "address": "tcp://h:1"}, "executor", "only for kind: dask"),
    ]:
        with pytest.raises(ConfigError) as e:
            parse_config({**base, "executor": bad}, source="c.yaml", check_semantics=False)
        msg = str(e.value)
        assert msg.startswith(f"c.yaml: {where}") and "\n" not in msg and all(w in msg for w in words), msg


def test_flag_wins_over_the_config():
    from vcirun.experiments.config import ExecutorSpec

    cfg_spec = ExecutorSpec(kind="dask", address="tcp://10.0.0.5:8786", task_size=4)
    s = executors.resolve_spec(cfg_spec, scheduler="tcp://127.0.0.1:9999", task_size=9)
    assert (s.kind, s.address, s.task_size) == ("dask", "tcp://127.0.0.1:9999", 9)
    s = executors.resolve_spec(cfg_spec, scheduler="local")
    assert (s.kind, s.address, s.task_size) == ("local", None, 4)
    assert executors.resolve_spec(None).kind == "local"
    with pytest.raises(SweepError, match="--scheduler: expected a Dask scheduler address"):
        executors.resolve_spec(None, scheduler="http//oops")


def test_bad_scheduler_input_is_one_line(tmp_path, monkeypatch):
    import dask

    monkeypatch.chdir(tmp_path)
    cfg = write_config(tmp_path)
    assert_one_line_error(invoke("sweep", cfg, "--scheduler", "nowhere"), "--scheduler", "tcp://HOST:8786")
    assert_one_line_error(invoke("sweep", cfg, "--worker-cache-dir", "/tmp/x"), "--worker-cache-dir")
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):  # nothing listens on port 9
        r = invoke("sweep", cfg, "--scheduler", "tcp://127.0.0.1:9")
    assert_one_line_error(r, "cannot connect to the Dask scheduler at tcp://127.0.0.1:9", "dask scheduler")
    # nothing written before the cluster is reached, and the lock is released (the output directory the
    # sweep created is removed again: nothing was written)
    assert not Path("results").exists() or sorted(p.name for p in Path("results").iterdir()) == []
    monkeypatch.setitem(sys.modules, "distributed", None)  # as if Dask were not installed
    assert_one_line_error(invoke("sweep", cfg, "--scheduler", "tcp://127.0.0.1:8786"),
                          "needs Dask", "pip install 'vcirun[dask]'")
    assert not Path("results").exists() or sorted(p.name for p in Path("results").iterdir()) == []


def test_task_size_model():
    # overhead 10 ms, 2 ms per run: 100 runs keep the overhead at 5%
    assert executors.choose_task_size(2e-3, 1e-2, remaining=100_000, workers=4) == 100
    # ... but at least 4 tasks per worker must remain
    assert executors.choose_task_size(2e-3, 1e-2, remaining=400, workers=4) == 25
    # long runs: one per task; no more than a minute per task
    assert executors.choose_task_size(5.0, 1e-2, remaining=1000, workers=2) == 1
    assert executors.choose_task_size(1e-3, 10.0, remaining=10**9, workers=1) == 60_000
    assert executors.choose_task_size(1e-3, 1e-2, remaining=3, workers=8) == 1
    # whole initial conditions (8 runs each) when enough tasks remain; the overhead may ask for more
    assert executors.choose_task_size(2e-2, 1e-2, remaining=400, workers=2, group=8) == 10
    assert executors.choose_task_size(2e-2, 1e-3, remaining=400, workers=2, group=8) == 8
    assert executors.choose_task_size(2e-2, 1e-3, remaining=40, workers=2, group=8) == 5


def test_tasks_ship_plain_data_only(tmp_path):
    """No sympy object travels with a task: the config (numbers and strings), run specs, a few numbers."""
    cfg = load_config(write_config(tmp_path))
    ex = executors.DaskExecutor("tcp://127.0.0.1:1", task_size=5)
    payload = executors.task_payload(cfg, 1.0, 0.01, fingerprint="f")
    groups = {}
    for s in expand(cfg):
        groups.setdefault(s.ic.key, []).append(s)
    from collections import deque

    ex._queue = deque([k, v] for k, v in groups.items())
    ex._refs_to_store = set(groups)
    unit = ex._next_unit(5)
    assert [(t.ic.key, len(t.runs), t.want_reference) for t in unit] == [("beta=3.2", 4, True)]  # 4 + 4 > 5
    unit2 = ex._next_unit(9)  # two whole initial conditions
    assert [(t.ic.key, len(t.runs), t.want_reference) for t in unit2] == [("beta=3.7", 4, True), ("beta=4.2", 4, True)]
    assert not ex._queue
    ex._queue = deque([k, v] for k, v in groups.items())
    ex._refs_to_store = set(groups)
    parts = [ex._next_unit(3) for _ in range(2)]  # an initial condition split: the reference goes with the first part
    assert [(t.ic.key, len(t.runs), t.want_reference) for u in parts for t in u] == [("beta=3.2", 3, True),
                                                                                       ("beta=3.2", 1, False)]
    blob = pickle.dumps((payload, unit))
    assert len(blob) < 20_000 and b"sympy" not in blob


# --- acceptance --------------------------------------------------------------------------------------
def test_dask_sweep_matches_the_local_pool_bit_for_bit(tmp_path, monkeypatch, cluster):
    cl, client = cluster
    monkeypatch.chdir(tmp_path)
    cfg = write_config(tmp_path)
    cache = str(Path(os.environ.get("VCIRUN_CACHE_DIR", Path.home() / ".cache" / "vcirun")).resolve())
    # local executor in this process (a fork pool here would fork the cluster's threads)
    local = invoke("sweep", cfg, "--workers", "1", "--quiet", "--output", "local.h5")
    assert local.exit_code == 0, local.output
    dask = invoke("sweep", cfg, "--scheduler", cl.scheduler_address, "--worker-cache-dir", cache,
                  "--output", "dask.h5")
    assert dask.exit_code == 0, dask.output
    assert "12 runs (12 computed, 0 already stored; 12 ok)" in dask.stdout
    assert "on 2 worker threads; measured" in dask.stdout  # tasks, task size and measured costs

    a, b = read_results("local.h5"), read_results("dask.h5")
    assert [r.run_id for r in a.runs] == [r.run_id for r in b.runs] == [s.run_id for s in expand(load_config(cfg))]
    assert [r.attrs["status"] for r in a.runs] == [r.attrs["status"] for r in b.runs]
    pids = set(worker_pids(client).values())
    assert {r.attrs["worker_pid"] for r in b.runs} <= pids  # computed on the cluster's workers
    for ra, rb in zip(a.runs, b.runs):
        assert ra.attrs["l2_error"] == rb.attrs["l2_error"] and ra.attrs["n_impacts"] == rb.attrs["n_impacts"]
        ta, tb = load_trajectory(a.path, ra.run_id), load_trajectory(b.path, rb.run_id)
        for name in ("t", "q", "p", "H", "impacts", "impact_q", "impact_p_plus"):
            np.testing.assert_array_equal(getattr(ta, name), getattr(tb, name), err_msg=name)
    assert a.references.keys() == b.references.keys()
    for key in a.references:
        ra, rb = load_reference(a.path, key), load_reference(b.path, key)
        np.testing.assert_array_equal(ra["q"], rb["q"])
    hist = b.attrs["history"][-1]
    assert hist["status"] == "complete" and hist["executor"]["kind"] == "dask"
    assert hist["executor"]["address"] == cl.scheduler_address and hist["executor"]["worker_threads"] == 2
    assert hist["executor"]["per_task_overhead_s"] > 0 and hist["executor"]["tasks"] >= 2
    # the option sets the workers' kernel cache; they keep it for later tasks
    assert set(client.run(lambda: os.environ.get("VCIRUN_CACHE_DIR")).values()) == {cache}
    # resume on the cluster: nothing left to compute
    again = invoke("sweep", cfg, "--scheduler", cl.scheduler_address, "--output", "dask.h5", "--quiet")
    assert again.exit_code == 0 and "0 computed, 12 already stored" in again.stdout
    # workers running other vcirun code than the client are refused before anything is written
    monkeypatch.setattr(executors, "source_fingerprint", lambda cached=True: "0" * 16)
    r = invoke("sweep", cfg, "--scheduler", cl.scheduler_address, "--output", "other.h5")
    assert_one_line_error(r, "runs a different vcirun than this client", "restart them")
    assert not Path("other.h5").exists()


def test_a_killed_worker_has_its_runs_retried_elsewhere(tmp_path, monkeypatch, cluster):
    cl, client = cluster
    # 40 runs, one per task; the executor from the config this time
    cfg = write_config(tmp_path, num=10, output=str(tmp_path / "kill.h5"),
                       extra=f"executor: {{kind: dask, address: '{cl.scheduler_address}', task_size: 1}}\n")
    victim = min(worker_pids(client).items())  # (address, pid)
    killed = []

    def kill():
        # the victim is killed while it holds tasks: after the first result the scheduler may not
        # have handed it the next ones yet, so wait (briefly) until it has some
        deadline = time.monotonic() + 10.0
        busy = ()
        while time.monotonic() < deadline:
            busy = client.processing(workers=[victim[0]]).get(victim[0], ())
            if busy:
                break
            time.sleep(0.01)
        os.kill(victim[1], signal.SIGKILL)
        killed.append(len(busy))

    hook = FirstResult(monkeypatch, kill)
    summary = run_sweep(load_config(cfg), progress=False)
    hook.join()
    assert killed and killed[0] > 0, "the worker was not killed while it held tasks"
    assert summary.ok and summary.computed == 40 and summary.executor == "dask"
    expected = {s.run_id for s in expand(load_config(cfg))}
    res = check_file(tmp_path / "kill.h5", expected)
    assert {r.run_id for r in res.runs} == expected  # every run exactly once
    assert all(r.attrs["status"] == "ok" for r in res.runs)
    with pytest.raises(ProcessLookupError):
        os.kill(victim[1], 0)  # it really died
    # the runs after the kill were computed by the surviving worker or the nanny's replacement
    assert summary.executor_stats["tasks"] == 40 and summary.executor_stats["task_size_mode"] == 1
    client.wait_for_workers(2, timeout=60)  # leave the module's cluster whole


def test_losing_the_scheduler_stops_cleanly_and_a_local_rerun_completes(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = write_config(tmp_path, num=8)  # 32 runs
    expected = {s.run_id for s in expand(load_config(cfg))}
    cl, client = start_cluster(DELAY)
    address = cl.scheduler_address

    def stop_scheduler():  # what a crashed scheduler node looks like to the sweep
        cl.sync(cl.scheduler.close)

    try:
        hook = FirstResult(monkeypatch, stop_scheduler)
        r = invoke("sweep", cfg, "--scheduler", address, "--task-size", "1", "--quiet")
        hook.join()
    finally:
        import dask

        client.close()
        with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):  # nannies give up on the scheduler
            cl.close()
    assert r.exit_code == 1, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: lost the Dask scheduler at {address}"), r.stderr
    assert "rerun the same command to resume" in lines[-1] and r.stdout == ""

    path = Path("results/dasktest.h5")
    res = check_file(path, expected)
    done = len(res.runs)
    assert 0 < done < len(expected), done
    assert f"{done} of {len(expected)} runs are saved in {path}" in lines[-1]
    assert res.attrs["history"][-1]["status"] == "scheduler_lost"
    assert all(r.attrs["status"] == "ok" and r.attrs["n_steps"] == round(1 / r.attrs["h"]) for r in res.runs)
    assert not Path("results/.dasktest.h5.lock").exists()

    # the same command without --scheduler: the local pool computes exactly the missing runs
    timed = []
    original = vcirun.simulate

    def counting(system, method, **kw):
        if kw.get("T", 0) >= 1:
            timed.append((method, kw.get("h"), kw.get("beta")))
        return original(system, method, **kw)

    monkeypatch.setattr(vcirun, "simulate", counting)
    r = invoke("sweep", cfg, "--workers", "1")
    assert r.exit_code == 0, r.output
    assert f"({len(expected) - done} computed, {done} already stored; {len(expected)} ok)" in r.stdout
    assert len(timed) == len(expected) - done
    final = check_file(path, expected)
    assert {x.run_id for x in final.runs} == expected
    assert [h["status"] for h in final.attrs["history"]] == ["scheduler_lost", "complete"]
    assert final.attrs["history"][-1]["executor"]["kind"] == "local"
