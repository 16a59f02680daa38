"""Interrupting a sweep subprocess part-way: SIGKILL, SIGINT and SIGTERM each leave a valid results
file with every finished run, and rerunning the same command completes it with every run present
exactly once (only the missing runs are computed). The interrupted sweep is a real `vcirun sweep`
process; the resume runs the same command in-process."""
from __future__ import annotations

import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import pytest

from vcirun.io.reader import Results, read_results
from vcirun.experiments.config import load_config
from vcirun.experiments.sweep import expand

ROOT = Path(__file__).resolve().parents[2]

CONFIG = """\
name: interrupt
system: cart_pendulum
methods: [CVA, VCI]
h: [3.2e-2, 1.0e-2]
beta: {start: 3.2, stop: 5.2, num: 16}
T: 0.5
reference: {kind: none}
output: results/interrupt.h5
"""

# The real CLI, with every timed run slowed down so that there is a "part-way" to interrupt.
# (Under fork, pool workers inherit the patched function.)
SLOW_CLI = """\
import sys, time
import vcirun
DELAY = float(sys.argv[1])
HOLD = 3.0
_simulate = vcirun.simulate
def slow(*args, **kw):
    if kw.get("T", 0) >= 0.5:
        time.sleep(DELAY)
        if abs(kw.get("beta", 0.0) - 5.2) < 1e-9:
            # the last initial condition holds its worker: the sweep cannot finish before the test's
            # signal, however its first commit and the signal are timed
            time.sleep(HOLD)
    return _simulate(*args, **kw)
vcirun.simulate = slow
from vcirun.cli.main import app
sys.argv = ["vcirun"] + sys.argv[2:]
app()
"""

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")


def env():
    e = dict(os.environ)
    e["PYTHONPATH"] = str(ROOT) + os.pathsep + e.get("PYTHONPATH", "")
    return e


def _default_sigint():
    # A process that starts with SIGINT ignored keeps ignoring it (Python installs its KeyboardInterrupt
    # handler only over the default disposition), and an ignored disposition survives exec: a test
    # runner's worker that ignores SIGINT would hand that to the sweep, which then ran to the end.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


class Sweep:
    """A sweep subprocess whose stderr progress lines are read on a thread."""

    # delay: seconds added to each timed run; the runs of the last beta are held for HOLD seconds (the
    # sweep could otherwise finish between its first reported commit and the signal, exiting 0)
    def __init__(self, tmp_path: Path, workers: int, delay: float = 0.05):
        (tmp_path / "slow_cli.py").write_text(SLOW_CLI)
        self.cfg = tmp_path / "interrupt.yaml"
        self.cfg.write_text(CONFIG)
        self.proc = subprocess.Popen(
            [sys.executable, str(tmp_path / "slow_cli.py"), str(delay), "sweep", str(self.cfg),
             "--workers", str(workers)],
            cwd=tmp_path, env=env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            preexec_fn=_default_sigint)
        self.lines: queue.Queue = queue.Queue()
        self.stderr: list[str] = []
        self._reader = threading.Thread(target=self._pump, daemon=True)
        self._reader.start()

    def _pump(self):
        for line in self.proc.stderr:
            self.stderr.append(line)
            self.lines.put(line)
        self.lines.put(None)

    def wait_until_saved(self, n: int = 1, timeout: float = 120) -> int:
        """Block until the sweep reports at least n runs committed to the file."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=1)
            except queue.Empty:
                continue
            if line is None:
                break
            m = re.search(r"; (\d+) committed", line)
            if m and int(m.group(1)) >= n:
                return int(m.group(1))
        self.proc.kill()
        raise AssertionError("sweep never reported a saved run:\n" + "".join(self.stderr))

    def finish(self, timeout: float = 60):
        out = self.proc.stdout.read()  # stderr belongs to the reader thread (communicate would race it)
        self.proc.wait(timeout=timeout)
        self._reader.join(timeout=timeout)
        return self.proc.returncode, out, "".join(self.stderr)


def worker_processes_of(cfg: Path) -> list[int]:
    """Processes (other than us) whose command line names this test's config: the sweep and its
    forked workers."""
    pids = []
    for d in Path("/proc").glob("[0-9]*"):
        try:
            if str(cfg) in (d / "cmdline").read_bytes().decode(errors="replace") and int(d.name) != os.getpid():
                pids.append(int(d.name))
        except OSError:
            continue
    return pids


def check_file(path: Path, expected_ids: set[str]) -> Results:
    with h5py.File(path, "r") as f:  # opens with plain h5py; every batch in it is complete
        batches = f["run_batches"] if "run_batches" in f else {}
        assert all(bool(batches[g].attrs["complete"]) for g in batches)
    res = read_results(path)
    assert res.incomplete == []
    ids = [r.run_id for r in res.runs]
    assert len(ids) == len(set(ids)) and set(ids) <= expected_ids
    return res


def resume(tmp_path: Path, cfg: Path, monkeypatch):
    """The same command again, in this process (saves a second interpreter start-up)."""
    from typer.testing import CliRunner

    from vcirun.cli.main import app

    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(app, ["sweep", str(cfg), "--workers", "1"], catch_exceptions=False)
    return subprocess.CompletedProcess(["vcirun", "sweep"], r.exit_code, r.stdout, r.stderr)


@pytest.mark.parametrize("workers", [1, 2])
def test_sigkill_then_resume(tmp_path, workers, monkeypatch):
    sweep = Sweep(tmp_path, workers)
    saved = sweep.wait_until_saved(1)
    sweep.proc.send_signal(signal.SIGKILL)
    sweep.proc.wait(timeout=30)
    assert sweep.proc.returncode == -signal.SIGKILL

    path = tmp_path / "results" / "interrupt.h5"
    expected = {s.run_id for s in expand(load_config(sweep.cfg))}
    res = check_file(path, expected)
    done = len(res.runs)
    assert saved <= done < len(expected), (saved, done)
    assert res.attrs["history"][-1]["status"] == "running"  # the killed session never finished
    if Path("/proc").is_dir():  # workers die with the parent (PR_SET_PDEATHSIG)
        deadline = time.monotonic() + 10
        while worker_processes_of(sweep.cfg) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert worker_processes_of(sweep.cfg) == []

    r = resume(tmp_path, sweep.cfg, monkeypatch)
    assert r.returncode == 0, r.stderr
    assert f"({len(expected) - done} computed, {done} already stored" in r.stdout
    final = check_file(path, expected)
    assert {x.run_id for x in final.runs} == expected  # every run exactly once
    before = {x.run_id: x.attrs["committed_at"] for x in res.runs}
    assert all(x.attrs["committed_at"] == before[x.run_id] for x in final.runs if x.run_id in before)
    assert [h["status"] for h in final.attrs["history"]] == ["running", "complete"]
    assert not (path.parent / ".interrupt.h5.partial").exists()
    assert not (path.parent / ".interrupt.h5.lock").exists()


@pytest.mark.parametrize("sig,code,workers", [(signal.SIGINT, 130, 2), (signal.SIGTERM, 143, 1)])
def test_sigint_sigterm_stop_cleanly(tmp_path, sig, code, workers, monkeypatch):
    sweep = Sweep(tmp_path, workers)
    sweep.wait_until_saved(1)
    sweep.proc.send_signal(sig)
    rc, out, err = sweep.finish()
    name = signal.Signals(sig).name
    assert rc == code, (rc, err)
    assert f"error: interrupted by {name}" in err and "run the same command again to resume" in err
    assert "Traceback" not in err

    path = tmp_path / "results" / "interrupt.h5"
    expected = {s.run_id for s in expand(load_config(sweep.cfg))}
    res = check_file(path, expected)
    m = re.search(r"(\d+) of (\d+) runs are saved", err)
    assert m and int(m.group(1)) == len(res.runs) and int(m.group(2)) == len(expected)
    assert 0 < len(res.runs) < len(expected)
    assert res.attrs["history"][-1]["status"] == "interrupted"
    assert not (path.parent / ".interrupt.h5.lock").exists()
    if Path("/proc").is_dir():
        assert worker_processes_of(sweep.cfg) == []

    r = resume(tmp_path, sweep.cfg, monkeypatch)
    assert r.returncode == 0, r.stderr
    assert {x.run_id for x in check_file(path, expected).runs} == expected
