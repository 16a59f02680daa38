"""Faults: the journal (constant-cost commits, torn tails, stale journals, kills), resume
that verifies what it trusts, output paths that cannot be used, a full disk (a real tmpfs where
`unshare --mount` works here, else a simulated ENOSPC), an HDF5 crash kept out of the process, damaged
results files given to `info`/`plot`/`sweep`, and the sweep's memory and disk checks. Each failure is
one line naming the path or field; no committed run is ever lost."""
from __future__ import annotations

import errno
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from vcirun.cli.main import app
from vcirun.experiments import sweep
from vcirun.experiments.config import load_config
from vcirun.io.errors import StorageError
from vcirun.io.journal import read_journal
from vcirun.io.reader import load_trajectory, read_results
from vcirun.io.writer import ResultsWriter
from vcirun.experiments.sweep import expand, run_sweep
from vcirun.experiments.worker import SweepError

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "unit"))
from test_storage import KEY, make_traj, run_attrs  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]

TINY = """\
name: tiny
system: cart_pendulum
methods: [CVA, VCI]
h: [3.2e-2, 1.0e-2]
beta: {start: 3.2, stop: 4.2, num: 2}
T: 0.5
timing_repeats: 1
reference: {kind: exact, rtol: 1.0e-10}
"""


@pytest.fixture
def tiny(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    p = tmp_path / "tiny.yaml"
    p.write_text(TINY)
    return p


def cli(*args):
    r = CliRunner().invoke(app, [str(a) for a in args], catch_exceptions=False)
    return r


def one_line(r, *words):
    assert r.exit_code == 1, (r.exit_code, r.output)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    assert "Traceback" not in r.output
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


def file_runs(f) -> list:
    """Run ids the HDF5 file itself holds (its complete batches, not its journal), read with plain h5py."""
    out = []
    for name in sorted(f["run_batches"]) if "run_batches" in f else []:
        b = f["run_batches"][name]
        if b.attrs.get("complete"):
            out += list(b["key"].asstr()[()])
    return out


def replace_field(path, key, field, value):
    """Damage one stored run: its array `field` replaced by `value` (None: removed), the batch's row
    table kept consistent (what a tool that rewrote the batch wrongly would leave)."""
    from vcirun.io.batches import BATCH_GROUPS, Batch, read_batch, write_batch

    with h5py.File(path, "a") as f:
        for name in sorted(f[BATCH_GROUPS["run"]]):
            b = read_batch(f[f"run_batches/{name}"], data=True)
            if key not in b.keys:
                continue
            i, j = b.keys.index(key), b.fields.index(field)
            st = b.starts()
            parts = [b.data[field][st[k, j]:st[k + 1, j]] for k in range(len(b.keys))]
            parts[i] = np.zeros((0,) + b.data[field].shape[1:]) if value is None else np.asarray(value)
            rows = b.rows.copy()
            rows[i, j] = -1 if value is None else len(value)
            data = {**b.data, field: np.concatenate(parts).astype(b.data[field].dtype)}
            write_batch(f, "run", Batch(b.keys, b.attrs, b.fields, b.scalar, rows, data), name=name)
            return
    raise KeyError(key)


def runs(n, seed=0):
    out = {}
    for i in range(n):
        tr = make_traj(seed=seed + i)
        a, arr = run_attrs(tr, "CVA", tr.h, 3.2 + i)
        out[f"r{seed + i:04d}"] = ({**a, "run_id": f"r{seed + i:04d}"}, arr)
    return out


# --- the journal -------------------------------------------------------------------------------------------
def test_commits_append_to_the_journal_and_never_touch_the_file(tmp_path):
    path = tmp_path / "r.h5"
    w = ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY)
    w.acquire()
    w.start()
    before = (path.stat().st_ino, path.read_bytes())
    sizes = [w.journal_path.stat().st_size]
    for rid, (a, arr) in runs(6).items():
        w.add_run(rid, a, arr)
        w.commit()
        sizes.append(w.journal_path.stat().st_size)
    # each commit appended one run's record (the same size for equal runs) and left the HDF5 file alone
    assert (path.stat().st_ino, path.read_bytes()) == before
    steps = np.diff(sizes)
    assert np.all(steps > 0) and np.ptp(steps) < 64
    res = read_results(path)  # readers see the journalled runs at once
    assert len(res.runs) == 6 and res.in_journal == 6
    back = load_trajectory(path, "r0003")
    np.testing.assert_array_equal(back.q, make_traj(seed=3).q)
    with h5py.File(path, "r") as f:  # plain h5py: the file is valid, its runs come at compaction
        assert len(file_runs(f)) == 0 and f.attrs["journal"].decode() == w._token
    w.finish("complete")
    w.close()
    with h5py.File(path, "r") as f:
        assert len(file_runs(f)) == 6 and f.attrs["journal"].decode() == ""
    assert not w.journal_path.exists() and not w.tmp_path.exists()


@pytest.mark.parametrize("end", ["finish", "close"])
def test_queued_runs_are_journalled_before_waiting_for_a_compaction_round(tmp_path, monkeypatch, end):
    """finish() (and close()) stopped the autocommit, then waited for the background compaction round
    under way (seconds: it copies the whole file) and only then committed: the runs that reached the
    client meanwhile were not durable, and a kill lost the runs of the last 2 s of a 2000-run sweep.
    They are appended to the journal before the wait now."""
    path = tmp_path / "r.h5"
    w = ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY)
    w.acquire()
    w.start()
    for rid, (a, arr) in runs(2).items():
        w.add_run(rid, a, arr)
    w.commit()
    for rid, (a, arr) in runs(3, seed=2).items():  # reached the client after the last commit
        w.add_run(rid, a, arr)
    seen = []

    def waiting_for_the_compactor(*args, **kwargs):  # a kill here must not lose r0002..r0004
        j = read_journal(w.journal_path)  # (None at close() after finish: the journal is folded in)
        seen.append(sorted(k for r in j.records if r.kind == "batch" and r.key == "run" for k in r.header["keys"])
                    if j is not None else None)

    monkeypatch.setattr(w, "stop_background_compaction", waiting_for_the_compactor)
    getattr(w, end)(*(["complete"] if end == "finish" else []))
    if end == "finish":
        w.close()
    assert seen and seen[0] == [f"r{i:04d}" for i in range(5)]
    assert {r.run_id for r in read_results(path).runs} == {f"r{i:04d}" for i in range(5)}


def test_a_torn_journal_tail_is_ignored_and_resume_folds_the_rest_in(tmp_path):
    path = tmp_path / "r.h5"
    w = ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY)
    w.acquire()
    w.start()
    for rid, (a, arr) in runs(3).items():
        w.add_run(rid, a, arr)
    w.commit()
    good = w.journal_path.stat().st_size
    (rid, (a, arr)), = runs(1, seed=10).items()
    w.add_run(rid, a, arr)
    w.commit()
    w._close_journal()  # a kill: no finish, the lock dies with the process
    w._release_lock()
    with open(w.journal_path, "r+b") as fh:  # the kill hit the middle of the last append
        fh.truncate(good + 100)
    j = read_journal(w.journal_path)
    assert j.torn and sum(len(r.header["keys"]) for r in j.records if r.kind == "batch") == 3
    assert {r.run_id for r in read_results(path).runs} == {"r0000", "r0001", "r0002"}
    w2 = ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY).acquire()
    assert set(w2.complete_runs) == {"r0000", "r0001", "r0002"}
    w2.start()  # the old journal is folded into the file, a new one opened
    w2.finish("complete")
    w2.close()
    with h5py.File(path, "r") as f:
        assert sorted(file_runs(f)) == ["r0000", "r0001", "r0002"]
    hist = read_results(path).attrs["history"]
    assert [h["status"] for h in hist] == ["running", "complete"] and hist[0]["computed"] == 3  # the 4th run was torn


def test_a_stale_journal_is_ignored(tmp_path):
    path = tmp_path / "r.h5"
    w = ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY)
    w.acquire()
    w.start()
    for rid, (a, arr) in runs(2).items():
        w.add_run(rid, a, arr)
    w.commit()
    stale = w.journal_path.read_bytes()
    w.finish("complete")
    w.close()
    w.journal_path.write_bytes(stale)  # e.g. a kill between the final rename and the journal's removal
    assert len(read_results(path).runs) == 2  # its token is not the file's: not applied twice
    with ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY) as w2:
        assert len(w2.complete_runs) == 2
        w2.finish("complete")
    assert not w2.journal_path.exists()


def test_sigkill_leaves_an_h5py_readable_file_and_the_journal_holds_every_saved_run(tmp_path):
    """A writer process SIGKILLed after committing: plain h5py opens the file, `vcirun info` counts the
    journalled runs, and the next writer folds them in."""
    path = tmp_path / "r.h5"
    code = f"""
import sys, os, signal
sys.path.insert(0, {str(ROOT / 'tests' / 'unit')!r})
from test_storage import KEY, make_traj, run_attrs
from vcirun.io.writer import ResultsWriter
w = ResultsWriter({str(path)!r}, root_attrs={{"name": "t"}}, config_key=KEY)
w.acquire(); w.start()
for i in range(5):
    a, arr = run_attrs(make_traj(seed=i), "CVA", 0.01, 3.2 + i)
    w.add_run(f"r{{i}}", {{**a, "run_id": f"r{{i}}"}}, arr)
    w.commit()
print("saved", len(w.complete_runs), flush=True)
os.kill(os.getpid(), signal.SIGKILL)
"""
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=dict(
        os.environ, PYTHONPATH=str(ROOT)))
    assert p.returncode == -signal.SIGKILL and "saved 5" in p.stdout, p.stderr
    with h5py.File(path, "r") as f:
        assert f.attrs["format"].decode() == "vcirun-sweep" and not file_runs(f)
    r = cli("info", path)
    assert r.exit_code == 0 and "5 of" in r.output and "5 of them in the journal" in r.output
    with ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY) as w:
        assert len(w.complete_runs) == 5
        w.finish("complete")
    with h5py.File(path, "r") as f:
        assert len(file_runs(f)) == 5


def test_background_compaction_folds_the_journal_in_while_the_sweep_runs(tmp_path):
    import time

    path = tmp_path / "r.h5"
    w = ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY)
    w.acquire()
    w.start()
    w.start_background_compaction(min_interval=0.2)
    items = list(runs(6).items())
    for rid, (a, arr) in items[:4]:
        w.add_run(rid, a, arr)
        w.commit()
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:  # a round replaces the file with one holding the four runs
        with h5py.File(path, "r") as f:
            if len(file_runs(f)) == 4:
                assert f.attrs["journal_applied"] > 0 and f.attrs["journal"].decode() == w._token
                break
        time.sleep(0.1)
    else:
        raise AssertionError("no compaction round within 60 s")
    for rid, (a, arr) in items[4:]:
        w.add_run(rid, a, arr)
        w.commit()
    res = read_results(path)  # the file's four and the journal's tail, each once
    assert sorted(r.run_id for r in res.runs) == sorted(k for k, _ in items) and res.in_journal <= 2
    w.finish("complete")
    w.close()
    with h5py.File(path, "r") as f:
        assert sorted(file_runs(f)) == sorted(k for k, _ in items) and f.attrs["journal_applied"] == 0
    assert not w.compact_path.exists() and not w.journal_path.exists()


# --- resume verifies what it trusts ---------------------------------------------------------------------------
def test_resume_recomputes_runs_whose_datasets_are_missing_or_misshapen(tiny):
    out = tiny.parent / "r.h5"
    run_sweep(load_config(tiny), output=out, workers=1, progress=False)
    expected = {s.run_id for s in expand(load_config(tiny))}
    with h5py.File(out, "r") as f:
        names = sorted(file_runs(f))
    replace_field(out, names[0], "q", None)
    replace_field(out, names[1], "t", np.zeros(3))
    res = read_results(out)
    assert {r.run_id for r in res.runs} == expected - set(names[:2])
    assert "dataset q missing" in res.damaged[f"run_batches/00000001/{names[0]}"]
    assert "dataset t has shape (3,)" in res.damaged[f"run_batches/00000001/{names[1]}"]
    with pytest.raises(StorageError, match=r"run \w+ is damaged \(dataset q missing\)"):  # never a q of shape (0, n)
        load_trajectory(out, names[0])
    s = run_sweep(load_config(tiny), output=out, workers=1, progress=False)
    assert s.computed == 2 and s.deleted_incomplete == 2
    res = read_results(out)
    assert not res.damaged and not res.incomplete and {r.run_id for r in res.runs} == expected
    with h5py.File(out, "r") as f:
        assert sorted(file_runs(f)) == sorted(expected)


def test_a_lost_references_group_is_recreated_and_recomputed(tiny):
    out = tiny.parent / "r.h5"
    run_sweep(load_config(tiny), output=out, workers=1, progress=False)
    from vcirun.io.reader import load_reference

    before = {k: load_reference(out, k)["q"] for k in read_results(out).references}
    assert len(before) == 2
    with h5py.File(out, "a") as f:
        del f["reference_batches"]
    assert not read_results(out).references
    s = run_sweep(load_config(tiny), output=out, workers=1, progress=False)
    assert s.computed == 0  # every run was stored: only the references are recomputed
    assert set(read_results(out).references) == set(before)
    for k, q in before.items():
        np.testing.assert_array_equal(load_reference(out, k)["q"], q)


# --- output paths -----------------------------------------------------------------------------------------------
def test_unusable_outputs_are_one_line_and_leave_nothing(tiny, tmp_path):
    (tmp_path / "afile").write_text("x")
    (tmp_path / "adir").mkdir()
    before = set(tmp_path.rglob("*"))
    one_line(cli("sweep", tiny, "--output", tmp_path / "afile" / "r.h5", "-q"), "afile is a file, not a directory")
    one_line(cli("sweep", tiny, "--output", tmp_path / "adir", "-q"), "is a directory; give a file path")
    (tmp_path / "loop1").symlink_to(tmp_path / "loop2")
    (tmp_path / "loop2").symlink_to(tmp_path / "loop1")
    one_line(cli("sweep", tiny, "--output", tmp_path / "loop1", "-q"), "symbolic link loop")
    (tmp_path / "dangling.h5").symlink_to("/nonexistent-vcirun-test/x.h5")
    one_line(cli("sweep", tiny, "--output", tmp_path / "dangling.h5", "-q"), "whose directory does not exist")
    assert set(tmp_path.rglob("*")) - before == {tmp_path / "loop1", tmp_path / "loop2", tmp_path / "dangling.h5"}
    assert not Path("/nonexistent-vcirun-test").exists()


def test_output_names_the_os_refuses(tiny, tmp_path):
    with pytest.raises(StorageError, match="cannot contain a NUL character"):
        run_sweep(load_config(tiny), output="a\x00b.h5", workers=1, progress=False)
    one_line(cli("sweep", tiny, "--output", tmp_path / ("x" * 300 + ".h5"), "-q"), "File name too long")


def test_absurd_worker_counts_are_refused(tiny, tmp_path):
    with pytest.raises(SweepError, match=r"workers: 100000 local worker processes .* too many"):
        run_sweep(load_config(tiny), output=tmp_path / "r.h5", workers=100_000, progress=False)
    assert not (tmp_path / "r.h5").exists()


def test_a_symlinked_output_is_written_through(tiny, tmp_path):
    (tmp_path / "store").mkdir()
    link = tmp_path / "link.h5"
    link.symlink_to(tmp_path / "store" / "target.h5")
    assert cli("sweep", tiny, "--output", link, "-q", "--workers", "1").exit_code == 0
    assert cli("sweep", tiny, "--output", link, "-q", "--workers", "1", "--force").exit_code == 0
    assert link.is_symlink() and len(read_results(link).runs) == 8
    assert not list((tmp_path / "store").glob(".*"))  # no lock, journal or partial left beside the target


def test_a_new_output_directory_is_removed_when_nothing_was_written(tiny, tmp_path, monkeypatch):
    monkeypatch.setattr(sweep, "_preflight", lambda *a: (_ for _ in ()).throw(SweepError("methods[0]: rejected")))
    with pytest.raises(SweepError):
        run_sweep(load_config(tiny), output=tmp_path / "new" / "deeper" / "r.h5", workers=1, progress=False)
    assert not (tmp_path / "new").exists()


UNSHARE = None
if shutil.which("unshare"):
    for prefix in (["unshare", "--mount"], ["unshare", "--user", "--map-root-user", "--mount"]):
        if subprocess.run(prefix + ["sh", "-c", "mount -t tmpfs -o size=16k tmpfs /mnt"],
                          capture_output=True).returncode == 0:
            UNSHARE = prefix
            break
needs_mount = pytest.mark.skipif(UNSHARE is None, reason="no private mount namespace here (unshare --mount)")

NOCHECK = """\
import sys
from vcirun.experiments import sweep
from vcirun.io.writer import ResultsWriter
sweep._check_resources = lambda *a, **k: None           # meet the full disk in the writes themselves
ResultsWriter._space_needed = lambda self, j: 0
from vcirun.cli.main import app
sys.argv = ["vcirun"] + sys.argv[1:]
app()
"""


def in_namespace(setup: str, command: str, cwd: Path):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run(UNSHARE + ["sh", "-c", f"{setup} && {command}"], capture_output=True, text=True, env=env,
                          cwd=cwd, timeout=600)


@needs_mount
def test_read_only_directory(tiny, tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    p = in_namespace(f"mount --bind {ro} {ro} && mount -o remount,bind,ro {ro}",
                     f"{sys.executable} -m vcirun.cli.main sweep {tiny} --output {ro}/r.h5 -q", tmp_path)
    assert p.returncode == 1 and p.stderr.strip().count("\n") == 0, p.stderr
    assert "cannot write in" in p.stderr and "Read-only file system" in p.stderr


@needs_mount
@pytest.mark.parametrize("size,checks", [pytest.param("64k", True, marks=pytest.mark.slow), ("100k", False),
                                         pytest.param("12k", False, marks=pytest.mark.slow)])
def test_full_disk_is_one_line_and_keeps_every_committed_run(tiny, tmp_path, size, checks):
    """A real tmpfs: refused up front (checks on), or ENOSPC met in the journal (100k) or in the first
    HDF5 write (12k) with the free-space checks off; then the disk is enlarged and the sweep resumes."""
    tiny.write_text(TINY.replace("T: 0.5", "T: 5"))  # 8 runs of ~40 kB
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    (tmp_path / "nocheck.py").write_text(NOCHECK)
    exe = f"{sys.executable} -m vcirun.cli.main" if checks else f"{sys.executable} {tmp_path / 'nocheck.py'}"
    out = mnt / "r.h5"
    count = (f"{sys.executable} -c 'from vcirun.io.reader import read_results; import sys; "
             f"print(\"SAVED\", len(read_results(sys.argv[1]).runs))' {out} 2>/dev/null")
    p = in_namespace(f"mount -t tmpfs -o size={size} tmpfs {mnt}",
                     f"{exe} sweep {tiny} --output {out} -q --workers 1 2>{tmp_path}/err; echo RC=$?; {count}; "
                     f"ls -a {mnt}; mount -o remount,size=64m {mnt}; "
                     f"{sys.executable} -m vcirun.cli.main sweep {tiny} --output {out} -q --workers 1; echo RC2=$?; "
                     f"{sys.executable} -c 'from vcirun.io.reader import read_results; import sys; "
                     f"print(\"FINAL\", len(read_results(sys.argv[1]).runs))' {out}",
                     tmp_path)
    err = (tmp_path / "err").read_text()
    assert "RC=1" in p.stdout and err.count("\n") == 1 and err.startswith("error: "), (p.stdout, err)
    assert "Traceback" not in err and "Segmentation" not in err
    assert str(mnt) in err
    assert ".partial" not in p.stdout  # no partial copy left to fill the disk
    assert "RC2=0" in p.stdout and "FINAL 8" in p.stdout, (p.stdout, p.stderr)


def test_simulated_enospc_in_the_journal_truncates_it_and_keeps_every_commit(tmp_path, monkeypatch):
    path = tmp_path / "r.h5"
    w = ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY)
    w.acquire()
    w.start()
    items = list(runs(3).items())
    w.add_run(items[0][0], *items[0][1])
    w.commit()
    good = w.journal_path.stat().st_size
    real_write = os.write
    state = {"n": 0}

    def full(fd, data):  # the disk fills in the middle of the next record
        state["n"] += 1
        if state["n"] == 3:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(fd, data)

    monkeypatch.setattr(os, "write", full)
    w.add_run(items[1][0], *items[1][1])
    with pytest.raises(StorageError, match=r"\.r\.h5\.journal: cannot write results \(No space left on device\).*1 in"):
        w.commit()
    monkeypatch.undo()
    assert w.journal_path.stat().st_size == good  # cut back to the last complete record
    assert [r.run_id for r in read_results(path).runs] == [items[0][0]]
    w.commit()  # space again: the retry appends right after the last complete record
    assert {r.run_id for r in read_results(path).runs} == {items[0][0], items[1][0]}
    w.finish("complete")
    w.close()
    with h5py.File(path, "r") as f:
        assert sorted(file_runs(f)) == sorted([items[0][0], items[1][0]])


def test_an_hdf5_crash_during_a_rewrite_stays_in_the_child(tmp_path):
    """The final rewrite runs in a forked child: a segfault there (as HDF5 can do after ENOSPC) is one
    StorageError here, the live file and the journal untouched, and the next session completes."""
    path = tmp_path / "r.h5"
    w = ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY)
    w.acquire()
    w.start()
    for rid, (a, arr) in runs(3).items():
        w.add_run(rid, a, arr)
    w.commit()
    before = path.read_bytes()
    with pytest.raises(StorageError, match=r"the HDF5 library crashed \(signal 11\)"):
        w.finish("complete", final_hooks=[lambda f: os.kill(os.getpid(), signal.SIGSEGV)])
    w.close()
    assert path.read_bytes() == before and not w.tmp_path.exists()
    assert len(read_results(path).runs) == 3
    with ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY) as w2:
        w2.finish("complete")
    with h5py.File(path, "r") as f:
        assert len(file_runs(f)) == 3


# --- damaged files ----------------------------------------------------------------------------------------------------
def damaged_variants(good: Path, d: Path):
    data = good.read_bytes()
    rng = np.random.default_rng(22)

    def blocks(p):
        b = bytearray(data)
        for at in rng.integers(0, len(b) - 4096, 8):
            b[at:at + 4096] = rng.integers(0, 256, 4096, dtype=np.uint8).tobytes()
        p.write_bytes(bytes(b))

    def attr(name, value):
        def go(p):
            shutil.copyfile(good, p)
            with h5py.File(p, "a") as f:
                f.attrs[name] = value
        return go

    def runs_dataset(p):
        shutil.copyfile(good, p)
        with h5py.File(p, "a") as f:
            del f["run_batches"]
            f["run_batches"] = np.arange(3)

    for name, make in [("blocks", blocks), ("truncated", lambda p: p.write_bytes(data[: len(data) // 2])),
                       ("empty", lambda p: p.write_bytes(b"")), ("history", attr("history", "{not json")),
                       ("runs_dataset", runs_dataset)]:
        p = d / f"{name}.h5"
        make(p)
        yield name, p


def test_damaged_results_files_are_one_line_for_info_plot_and_sweep(tiny, tmp_path):
    good = tmp_path / "good.h5"
    run_sweep(load_config(tiny), output=good, workers=1, progress=False)
    for name, p in damaged_variants(good, tmp_path):
        for args in (["info", p], ["plot", p, "--out", tmp_path / "fig" / name],
                     ["sweep", tiny, "--output", p, "-q", "--workers", "1"]):
            r = cli(*args)
            assert "Traceback" not in r.output, (name, args[0], r.output)
            if r.exit_code != 0:
                one_line(r)
            elif args[0] == "sweep":  # repaired by the resume: every run there, each verified
                res = read_results(p)
                assert len(res.runs) == 8 and not res.damaged and not res.incomplete
                with h5py.File(p, "r") as f:
                    assert len(file_runs(f)) == 8


# --- the sweep's own checks ----------------------------------------------------------------------------------------
def test_not_enough_disk_is_refused_before_the_file_exists(tiny, tmp_path, monkeypatch):
    real = shutil.disk_usage
    monkeypatch.setattr(sweep.shutil, "disk_usage", lambda p: real(p)._replace(free=100_000))
    out = tmp_path / "r.h5"
    with pytest.raises(SweepError, match=r"r\.h5: the 8 pending runs need about .* on disk .*free"):
        run_sweep(load_config(tiny), output=out, workers=1, progress=False)
    assert not out.exists() and not list(tmp_path.glob(".r.h5*"))


def test_runs_in_flight_are_checked_against_the_memory_limit(tiny, tmp_path, monkeypatch):
    cfg = load_config(tiny).model_copy(update={"max_memory": "20kB"})
    with pytest.raises(SweepError, match=r"h: .* need about .* for 2 runs at once \(limit 19.5 KiB\).*2 worker"):
        run_sweep(cfg, output=tmp_path / "r.h5", workers=2, progress=False)
    assert not (tmp_path / "r.h5").exists()


def test_pool_workers_stream_each_run(tmp_path, monkeypatch):
    """One initial condition (one task per worker): the client still receives the runs as they finish
    (here one by one: every run is older than a STREAM_INTERVAL of 0 when it is sent)."""
    from vcirun.experiments import worker
    from vcirun.experiments.executors import LocalExecutor

    monkeypatch.setattr(worker, "STREAM_INTERVAL", 0.0)

    p = tmp_path / "one.yaml"
    p.write_text(TINY.replace("beta: {start: 3.2, stop: 4.2, num: 2}", "beta: [3.2]").replace(
        "reference: {kind: exact, rtol: 1.0e-10}", "reference: {kind: none}"))
    cfg = load_config(p)
    pending = expand(cfg)
    sweep._preflight(cfg, pending)
    ex = LocalExecutor(2)
    ex.start(cfg, pending, set(), False, cfg.T, min(cfg.h))
    try:
        got = list(ex.results())
    finally:
        ex.close()
    assert len(got) == len(pending) == 4 and all(len(r["runs"]) == 1 for r in got)
    assert {r["runs"][0]["run_id"] for r in got} == {s.run_id for s in pending}


# --- info / plot on unusual paths ----------------------------------------------------------------------------------
@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_a_fifo_given_to_info_or_plot_is_one_line_not_a_hang(tmp_path, monkeypatch):
    """`vcirun info FIFO` blocked in h5py's open until a writer appeared (forever)."""
    monkeypatch.chdir(tmp_path)
    fifo = tmp_path / "r.h5"
    os.mkfifo(fifo)
    for args in (["info", fifo], ["plot", fifo]):
        one_line(cli(*args), "not a regular file")
    with pytest.raises(StorageError, match="not a regular file"):
        read_results(fifo)


def test_plot_out_that_cannot_be_a_folder_names_it_and_leaves_nothing(tiny, tmp_path):
    """A --out under a file was reported as `good.h5: cannot read the results file ... it may be
    damaged`; a failed plot into a new --out left its empty folders behind."""
    good = tmp_path / "good.h5"
    run_sweep(load_config(tiny), output=good, workers=1, progress=False)
    (tmp_path / "afile").write_text("x")
    line = one_line(cli("plot", good, "--out", tmp_path / "afile" / "figs"), "--out", "cannot create the folder",
                    "choose another --out")
    assert "damaged" not in line and "good.h5" not in line
    one_line(cli("plot", good, "--out", tmp_path / "afile"), "is a file, not a folder")
    bad = tmp_path / "bad.h5"
    bad.write_text("not HDF5\n")
    before = set(tmp_path.rglob("*"))
    one_line(cli("plot", bad, "--out", tmp_path / "new" / "a" / "b"), "bad.h5")
    assert set(tmp_path.rglob("*")) == before


def test_resource_check_counts_every_contact(tmp_path, monkeypatch):
    """The preflight's memory and disk estimate sizes the per-contact fields (contact_active,
    contact_force) with the scene's m contacts: ball_in_box's four, not one."""
    p = tmp_path / "box.yaml"
    p.write_text(TINY.replace("system: cart_pendulum", "system: ball_in_box").replace(
        "beta: {start: 3.2, stop: 4.2, num: 2}\n", "").replace("methods: [CVA, VCI]", "methods: [CVA]").replace(
        "reference: {kind: exact, rtol: 1.0e-10}", "reference: {kind: none}"))
    cfg = load_config(p)
    pending = expand(cfg)
    assert sweep._preflight(cfg, pending)[:2] == (2, 4)
    seen = []
    real = sweep.stored_bytes
    monkeypatch.setattr(sweep, "stored_bytes", lambda N, n, m=1, **k: seen.append(m) or real(N, n, m, **k))
    writer = type("W", (), {"force": False})()
    sweep._check_resources(cfg, pending, 2, 4, 1, tmp_path / "r.h5", writer)
    assert seen and set(seen) == {4}
