"""HDF5 results files (vcirun.io): round trips, plain-h5py layout, incomplete groups, atomic commits,
locking, the journal format, the forked writer, output-path checks, and the metrics/figures/tables
built on stored runs (synthetic trajectories; no integrator runs)."""
from __future__ import annotations

import errno
import hashlib
import json
import math
import os
import re
import signal
import zlib
from pathlib import Path

import h5py
import numpy as np
import pytest
from scipy import stats

from vcirun.experiments import metrics
from vcirun.run.trajectory_files import energy_summary
from vcirun.io import rewrite
from vcirun.io.checks import resolve_output
from vcirun.io.durable import ChildFailed, run_isolated
from vcirun.io.errors import StorageError, one_line, os_text, write_error
from vcirun.io.journal import read_journal, record_pieces, write_all
from vcirun.io.provenance import environment_attrs, now_iso
from vcirun.io.reader import load_trajectory, read_results
from vcirun.io.writer import ResultsWriter
from vcirun.run.trajectory_files import IMPACT_ARRAYS, trajectory_payload
from vcirun.core import record
from vcirun.run.trajectory import Trajectory

KEY = "k" * 64


def make_traj(*, N=40, n=2, h=0.01, with_hmod=True, n_imp=2, status="ok", beta=3.2, seed=0) -> Trajectory:
    rng = np.random.default_rng(seed)
    t = h * np.arange(N + 1)
    imp_step = np.zeros(N, bool)
    imp_step[[k for k in (5, 17)[:n_imp] if k < N]] = True
    kw = dict(
        method="MCVAC" if with_hmod else "CVA", system="synthetic", h=h, T=N * h, t=t,
        q=rng.normal(size=(N + 1, n)), p=rng.normal(size=(N + 1, n)), H=10 + 0.01 * rng.normal(size=N + 1),
        Ed=10 + 0.02 * rng.normal(size=N + 1), impacts=np.sort(rng.uniform(0, N * h, n_imp)),
        impact_q=rng.normal(size=(n_imp, n)), impact_p_minus=rng.normal(size=(n_imp, n)),
        impact_p_plus=rng.normal(size=(n_imp, n)), impact_step=imp_step,
        partial_steps=rng.uniform(0, h, 2 * n_imp), newton_iters=rng.integers(1, 5, N),
        status=status, message="" if status == "ok" else "newton_failed in step 3 (t = 0.03)",
        fail_step=-1 if status == "ok" else 3, fail_time=math.nan if status == "ok" else 0.03,
        Hmod=10 + 1e-6 * rng.normal(size=N + 1) if with_hmod else None, beta=beta, wall_time=1.25e-3,
        tolerances={"newton_tol": 1e-12, "event_tol": 1e-13}, options={"params": {"m1": 1.0}, "constrained": True})
    # every other row of the run record at its declared length (resume verifies the lengths)
    length = {"grid": N + 1, "step": N, "impact": n_imp, "partial": 2 * n_imp, "release": 0, "mode": 0}
    for f in record.FIELDS:
        if f.name not in kw and f.only is None:
            kw[f.name] = np.zeros(f.shape(length[f.axis], n, 1), np.dtype(bool if f.dtype == "bool" else f.dtype))
    return Trajectory(**kw)


def run_attrs(traj, label, h, beta, index=0, ic_key=None):
    attrs, arrays = trajectory_payload(traj)
    attrs.update(run_id=None, label=label, method=label, method_index=index, ic_key=ic_key or f"beta={beta:g}",
                 ic_index=0, beta=beta, l2_error=1e-3 * h, method_spec={"name": label})
    return attrs, arrays


def assert_same_traj(a: Trajectory, b: Trajectory):
    for name in ("t", "q", "p", "H", "Ed", "impacts", "impact_q", "impact_p_minus", "impact_p_plus",
                 "impact_step", "partial_steps", "newton_iters"):
        x, y = getattr(a, name), getattr(b, name)
        assert np.asarray(x).shape == np.asarray(y).shape, name
        np.testing.assert_array_equal(x, y, err_msg=name)
    assert (a.Hmod is None) == (b.Hmod is None)
    if a.Hmod is not None:
        np.testing.assert_array_equal(a.Hmod, b.Hmod)
    for name in ("method", "system", "h", "T", "status", "message", "fail_step", "beta", "wall_time",
                 "tolerances", "options"):
        assert getattr(a, name) == getattr(b, name), name
    assert (math.isnan(a.fail_time) and math.isnan(b.fail_time)) or a.fail_time == b.fail_time


def write(path, runs, *, key=KEY, refs=(), root=None):
    with ResultsWriter(path, root_attrs=root or {"name": "t"}, config_key=key) as w:
        for rid, (attrs, arrays) in runs.items():
            w.add_run(rid, {**attrs, "run_id": rid}, arrays)
        for k, (attrs, arrays) in dict(refs).items():
            w.add_reference(k, attrs, arrays)
        w.finish("complete")
    return path


@pytest.mark.parametrize("with_hmod", [True, False])
def test_round_trip_preserves_every_field(tmp_path, with_hmod):
    tr = make_traj(with_hmod=with_hmod)
    path = write(tmp_path / "r.h5", {"abc": run_attrs(tr, "MCVAC", tr.h, 3.2)})
    back = load_trajectory(path, "abc")
    assert_same_traj(tr, back)
    assert back.impact_step.dtype == bool


def test_failed_run_and_missing_beta_round_trip(tmp_path):
    tr = make_traj(status="newton_failed", beta=None, N=3)
    path = write(tmp_path / "r.h5", {"f": run_attrs(tr, "CVA", tr.h, None, ic_key="state=0")})
    back = load_trajectory(path, "f")
    assert_same_traj(tr, back)
    res = read_results(path)
    a = res.runs[0].attrs
    assert a["status"] == "newton_failed" and "step 3" in a["message"]
    assert math.isnan(a["beta"]) and res.runs[0].beta_or_none is None


def test_without_trajectories_keeps_impacts_and_scalars(tmp_path):
    tr = make_traj()
    attrs, arrays = trajectory_payload(tr, store_arrays=False)
    assert set(arrays) == set(IMPACT_ARRAYS) - set(record.FRICTION_ROWS)   # a run without friction data
    path = write(tmp_path / "r.h5", {"x": ({**attrs, "label": "CVA", "method_index": 0}, arrays)})
    back = load_trajectory(path, "x")
    np.testing.assert_array_equal(back.impacts, tr.impacts)
    assert back.q.shape == (0, 2) and back.t.size == 0 and back.Hmod is None
    a = read_results(path).runs[0].attrs
    assert a["has_trajectory"] is False and a["n_steps"] == 40 and a["n_impacts"] == 2


def _plain_item(f, kind_group, key):
    """Item `key` of a results file read with plain h5py and json, as docs/reference/results_schema.md
    shows: its attributes and its arrays."""
    for name in sorted(f[kind_group]):
        b = f[kind_group][name]
        keys = list(b["key"].asstr()[()])
        if key not in keys:
            continue
        i = keys.index(key)
        fields = json.loads(b.attrs["fields"])
        rows = b["rows"][()]
        start = np.concatenate([np.zeros((1, len(fields)), int), np.cumsum(np.maximum(rows, 0), axis=0)])
        arrays = {n: b[n][start[i, j]:start[i, j] + rows[i, j]] for j, n in enumerate(fields) if rows[i, j] >= 0}
        return json.loads(b["attrs"].asstr()[i]), arrays, b
    raise KeyError(key)


def test_layout_is_readable_with_plain_h5py(tmp_path):
    tr = make_traj()
    ref_arrays = {"t": np.linspace(0, 1, 11), "q": np.zeros((11, 2)), "impacts": np.array([0.5])}
    path = write(tmp_path / "r.h5", {"r1": run_attrs(tr, "MCVAC", tr.h, 3.2),
                                     "r2": run_attrs(make_traj(with_hmod=False, N=7, seed=2), "CVA", tr.h, 3.2)},
                 refs={"beta=3.2": ({"kind": "exact", "accuracy": 1e-11, "beta": 3.2}, ref_arrays)},
                 root={"name": "t", "tolerances": {"newton_tol": 1e-12}, "config_yaml": "name: t\n"})
    with h5py.File(path, "r") as f:
        # text is fixed-length UTF-8 (no global-heap objects): h5py reads attributes of it as bytes
        assert f.attrs["format"].decode() == "vcirun-sweep" and f.attrs["schema_version"] == 2
        assert f.attrs["config_key"].decode() == KEY and f.attrs["config_yaml"].decode() == "name: t\n"
        assert json.loads(f.attrs["tolerances"]) == {"newton_tol": 1e-12}
        assert f.attrs["n_runs_complete"] == 2
        hist = json.loads(f.attrs["history"])
        assert hist[-1]["status"] == "complete" and hist[-1]["computed"] == 2
        a, arrays, b = _plain_item(f, "run_batches", "r1")
        assert b.attrs["complete"] == True and b.attrs["n_items"] == 2  # noqa: E712 - numpy bool
        assert arrays["q"].shape == (41, 2) and arrays["impact_step"].dtype == np.uint8
        np.testing.assert_array_equal(arrays["q"], tr.q)
        assert a["status"] == "ok" and a["label"] == "MCVAC" and json.loads(a["options"])["constrained"] is True
        a2, arrays2, _ = _plain_item(f, "run_batches", "r2")
        assert arrays2["q"].shape == (8, 2) and "Hmod" not in arrays2 and a2["label"] == "CVA"
        ra, rarr, rb = _plain_item(f, "reference_batches", "beta=3.2")
        assert rb.attrs["complete"] == True and ra["accuracy"] == 1e-11  # noqa: E712
        np.testing.assert_array_equal(rarr["impacts"], [0.5])


def test_fast_group_writer_makes_what_h5py_high_level_calls_make(tmp_path):
    """write_encoded uses h5py's low-level calls; every dataset and attribute it writes has the type,
    shape, value and creation properties that `create_dataset(data=...)` / `attrs[k] = storable(v)`
    give (text as fixed-length UTF-8 strings)."""
    from vcirun.run.trajectory_files import group_attrs, storable, write_encoded

    attrs, arrays = run_attrs(make_traj(), "MCVAC", 0.01, 3.2)
    attrs.update(message="niño \u2013 ok", fail_time=math.nan, q0=[0.1, -2.0], flag=np.bool_(False),
                 big=np.int64(2**40), empty_list=[])
    arrays.update(empty=np.zeros((0, 2)), scalar=np.array(3.5), i32=np.arange(3, dtype=np.int32))
    enc = group_attrs(attrs)
    with h5py.File(tmp_path / "a.h5", "w", libver="latest") as f:
        write_encoded(f, "runs/fast", enc, arrays.items())
        g = f.create_group("runs/slow")
        for name, value in arrays.items():
            g.create_dataset(name, data=np.asarray(value))
        for key, value in enc.items():
            g.attrs[key] = storable(value)
        g.attrs["complete"] = True
        fast, slow = f["runs/fast"], f["runs/slow"]
        assert sorted(fast) == sorted(slow) and sorted(fast.attrs) == sorted(slow.attrs)
        for name in slow:
            a, b = fast[name], slow[name]
            assert a.id.get_type().equal(b.id.get_type()) and a.shape == b.shape and a.dtype == b.dtype, name
            assert a.id.get_create_plist().get_layout() == b.id.get_create_plist().get_layout(), name
            assert a.id.get_create_plist().get_obj_track_times() == b.id.get_create_plist().get_obj_track_times()
            np.testing.assert_array_equal(a[()], b[()], err_msg=name)
        for key in slow.attrs:
            a, b = fast.attrs.get_id(key), slow.attrs.get_id(key)
            assert a.get_type().equal(b.get_type()) and a.shape == b.shape, key
            x, y = fast.attrs[key], slow.attrs[key]
            assert type(x) is type(y), key
            np.testing.assert_array_equal(x, y, err_msg=key)


def test_incomplete_groups_are_ignored_by_readers_and_dropped_on_resume(tmp_path):
    tr = make_traj()
    path = write(tmp_path / "r.h5", {"good": run_attrs(tr, "CVA", tr.h, 3.2)})
    # What a writer killed between its data and its marker would leave (e.g. another tool): a batch
    # without `complete`, and schema-1 groups without it
    with h5py.File(path, "a") as f:
        g = f.create_group("run_batches/00000099")
        g["q"] = np.zeros((3, 2))
        g = f.create_group("runs/half")
        g["q"] = np.zeros((3, 2))
        g.attrs["status"] = "ok"
        f.create_group("references/beta=9")
    res = read_results(path)
    assert [r.run_id for r in res.runs] == ["good"]
    assert sorted(res.incomplete) == ["references/beta=9", "run_batches/00000099", "runs/half"]

    w = ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY).acquire()
    try:
        assert set(w.complete_runs) == {"good"}
        assert sorted(w.incomplete) == ["references/beta=9", "run_batches/00000099", "runs/half"]
        w.start()  # the first commit deletes them
    finally:
        w.close()
    with h5py.File(path, "r") as f:
        assert set(f["run_batches"]) == {"00000001"} and not len(f["runs"]) and "beta=9" not in f["references"]
    assert [r.run_id for r in read_results(path).runs] == ["good"]
    hist = read_results(path).attrs["history"]
    assert len(hist) == 2  # both sessions recorded


def test_schema_1_files_are_read_and_resumed(tmp_path):
    """A file of schema 1 (a group per run) reads as before; a session resuming it adds batches, and
    forgetting a run deletes its group."""
    from vcirun.run.trajectory_files import write_group

    tr, tr2 = make_traj(), make_traj(seed=3, status="newton_failed")
    path = tmp_path / "v1.h5"
    with h5py.File(path, "w") as f:
        f.attrs.update(format="vcirun-sweep", schema_version=1, config_key=KEY, name="old")
        for rid, t in (("a", tr), ("b", tr2)):
            attrs, arrays = run_attrs(t, "CVA", t.h, 3.2)
            write_group(f, f"runs/{rid}", {**attrs, "run_id": rid}, arrays)
        f.create_group("references")
    assert {r.run_id for r in read_results(path).runs} == {"a", "b"}
    assert_same_traj(tr, load_trajectory(path, "a"))
    with ResultsWriter(path, root_attrs={"name": "old"}, config_key=KEY) as w:
        w.forget_runs(["b"])
        w.add_run("c", *run_attrs(make_traj(seed=4), "CVA", 0.01, 3.7))
        w.finish("complete")
    res = read_results(path)
    assert {r.run_id for r in res.runs} == {"a", "c"} and not res.incomplete
    with h5py.File(path, "r") as f:
        assert set(f["runs"]) == {"a"} and f.attrs["schema_version"] == 2 and f.attrs["n_runs_complete"] == 2
    assert_same_traj(tr, load_trajectory(path, "a"))


def test_batches_split_by_dtype_and_shape_and_keep_scalars(tmp_path):
    from vcirun.io.batches import pack

    items = [("a", {"x": 1.0}, {"q": np.zeros((3, 2)), "s": np.array(2.5)}),
             ("b", {"x": 2.0}, {"q": np.ones((1, 2)), "extra": np.arange(4)}),
             ("c", {"x": 3.0}, {"q": np.ones((2, 3))}),               # another trailing shape
             ("d", {"x": 4.0}, {"q": np.ones((2, 2), np.float32)})]   # another dtype
    batches = pack(items)
    assert [b.keys for b in batches] == [["a", "b"], ["c"], ["d"]]
    b = batches[0]
    assert b.fields == ["q", "s", "extra"] and b.scalar == ["s"] and b.rows.tolist() == [[3, 1, -1], [1, -1, 4]]
    a_arrays = dict(b.arrays(0))
    assert a_arrays["s"].shape == () and float(a_arrays["s"]) == 2.5 and "extra" not in a_arrays
    np.testing.assert_array_equal(dict(b.arrays(1))["extra"], np.arange(4))
    assert b.view(1).shape_of("q") == (1, 2) and b.view(1).shape_of("s") is None
    rest = b.select([1])
    assert rest.keys == ["b"] and rest.data["q"].shape == (1, 2) and rest.data["s"].shape == (0,)


def test_forgetting_one_run_rewrites_its_batch_without_it(tmp_path):
    runs = {f"r{i}": run_attrs(make_traj(seed=i, N=10 + i), "CVA", 0.01, 3.2 + i) for i in range(4)}
    path = write(tmp_path / "r.h5", runs)
    with ResultsWriter(path, root_attrs={}, config_key=KEY) as w:
        w.forget_runs(["r1", "r3"])
        w.finish("complete")
    assert [r.run_id for r in read_results(path).runs] == ["r0", "r2"]
    for rid in ("r0", "r2"):
        i = int(rid[1])
        np.testing.assert_array_equal(load_trajectory(path, rid).q, make_traj(seed=i, N=10 + i).q)
    with pytest.raises(StorageError, match="no run 'r1'"):
        load_trajectory(path, "r1")


def test_resume_refuses_a_file_from_another_config(tmp_path):
    path = write(tmp_path / "r.h5", {"a": run_attrs(make_traj(), "CVA", 0.01, 3.2)})
    with pytest.raises(StorageError, match="different configuration.*--force"):
        ResultsWriter(path, root_attrs={}, config_key="other").acquire()
    # --force replaces it (and only once the new file is committed)
    with ResultsWriter(path, root_attrs={"name": "n"}, config_key="other", force=True) as w:
        w.finish("complete")
    res = read_results(path)
    assert res.runs == [] and res.attrs["config_key"] == "other"


@pytest.mark.parametrize("content,match", [(b"not hdf5 at all", "not a readable HDF5"), (None, "not a vcirun")])
def test_unusable_files_are_reported(tmp_path, content, match):
    path = tmp_path / "x.h5"
    if content is None:
        with h5py.File(path, "w") as f:
            f["data"] = [1, 2, 3]
    else:
        path.write_bytes(content)
    with pytest.raises(StorageError, match=match):
        read_results(path)
    with pytest.raises(StorageError, match=match):
        ResultsWriter(path, root_attrs={}, config_key=KEY).acquire()
    with pytest.raises(StorageError, match="file not found"):
        read_results(tmp_path / "missing.h5")


def test_failed_commit_leaves_previous_file_intact(tmp_path, monkeypatch):
    path = write(tmp_path / "r.h5", {"a": run_attrs(make_traj(), "CVA", 0.01, 3.2)})
    before = path.read_bytes()
    # in this process (isolate=False), so that the writer sees the monkeypatched write_batch
    w = ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY, isolate=False).acquire()
    calls = []

    def boom(f, kind, batch, name=None):
        calls.append((kind, batch.keys))
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(rewrite, "write_batch", boom)
    w.add_run("b", *run_attrs(make_traj(seed=1), "CVA", 0.01, 3.7))
    with pytest.raises(StorageError, match="cannot write results .*disk full .*committed before"):
        w.commit()
    assert calls == [("run", ["b"])]
    assert path.read_bytes() == before  # the live file was never touched
    assert not w.tmp_path.exists()
    monkeypatch.undo()
    w.commit()  # the queue survived the failure
    w.close()
    assert {r.run_id for r in read_results(path).runs} == {"a", "b"}


def test_second_writer_is_locked_out_and_stale_partial_copy_is_removed(tmp_path):
    path = write(tmp_path / "r.h5", {"a": run_attrs(make_traj(), "CVA", 0.01, 3.2)})
    w1 = ResultsWriter(path, root_attrs={}, config_key=KEY).acquire()
    try:
        with pytest.raises(StorageError, match="another vcirun sweep"):
            ResultsWriter(path, root_attrs={}, config_key=KEY).acquire()
        assert read_results(path).runs  # readers are never locked out
    finally:
        w1.close()
    assert not w1.lock_path.exists()
    w1.tmp_path.write_bytes(b"half a copy from a killed commit")
    w2 = ResultsWriter(path, root_attrs={}, config_key=KEY).acquire()
    w2.close()
    assert not w2.tmp_path.exists()


def test_a_fresh_writer_creates_nothing_until_started(tmp_path):
    path = tmp_path / "sub" / "r.h5"
    w = ResultsWriter(path, root_attrs={}, config_key=KEY).acquire()
    w.close()
    assert not path.exists() and not path.parent.exists()  # an aborted sweep leaves no output, no directory


def test_forget_runs_for_retry(tmp_path):
    path = write(tmp_path / "r.h5", {"a": run_attrs(make_traj(), "CVA", 0.01, 3.2),
                                     "b": run_attrs(make_traj(status="newton_failed"), "CVA", 0.01, 3.7)})
    with ResultsWriter(path, root_attrs={}, config_key=KEY) as w:
        assert set(w.complete_runs) == {"a", "b"}
        w.forget_runs([r for r, a in w.complete_runs.items() if a["status"] != "ok"])
        w.finish("complete")
    assert [r.run_id for r in read_results(path).runs] == ["a"]


# --- the pieces: journal format, checks, forked writes, messages ------------------------------------------
def _journal(path, *records):
    """A journal file of an open record (token "tok") followed by `records` ((kind, key, attrs, arrays))."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        write_all(fd, record_pieces("open", "", extra={"token": "tok", "config_key": KEY})[0])
        for kind, key, attrs, arrays in records:
            write_all(fd, record_pieces(kind, key, attrs, arrays)[0])
    finally:
        os.close(fd)
    return path


def test_journal_record_bytes_are_fixed():
    """The record format is part of the file format: these bytes are what every version wrote."""
    pieces, n = record_pieces("run", "abc", {"h": 0.01, "q0": np.array([1.0, 2.0]), "status": "ok"},
                              [("q", np.arange(6.0).reshape(3, 2)), ("impact_step", np.array([True, False])),
                               ("newton_iters", np.array([1, 2, 3], np.int32))])
    data = b"".join(bytes(p) for p in pieces)
    assert n == len(data) == 328
    assert hashlib.sha256(data).hexdigest() == "2317531c5c5450137510c85849e07bb62a792e14a1feee6e4de0f71e85bef7dd"


def test_attrs_text_is_the_encoding_of_group_attrs():
    """The workers' one-pass encoding of a run's attributes equals the batch text of its encoded
    attributes, for every kind of value a run records."""
    from vcirun.io.batches import attrs_text, item_text
    from vcirun.run.trajectory_files import group_attrs

    attrs, _ = run_attrs(make_traj(status="newton_failed"), "MCVAC", 0.01, 3.2)
    attrs.update(message="niño \x00 \udcff", fail_time=math.nan, q0=np.array([0.1, -2.0]), p0=[1, 2],
                 flag=np.bool_(True), big=np.int64(2**40), f32=np.float32(0.5), none_text=None, l2_error=None,
                 complete=True, wall_time_repeats=[1e-3, 2e-3], ok=False)
    assert json.loads(attrs_text(attrs), parse_constant=str) == json.loads(item_text(group_attrs(attrs)),
                                                                            parse_constant=str)
    assert attrs_text(attrs) == item_text(group_attrs(attrs))


def test_batch_records_round_trip_through_the_journal(tmp_path):
    from vcirun.io.batches import pack
    from vcirun.io.journal import batch_pieces, overlay

    items = [("a", {"h": 0.01, "q0": np.array([1.0, 2.0]), "status": "ok"},
              {"q": np.arange(6.0).reshape(3, 2), "s": np.array(7)}),
             ("b", {"h": 0.02, "status": "ok"}, {"q": np.ones((1, 2))})]
    (b,) = pack(items)
    jp = tmp_path / "j"
    fd = os.open(jp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    write_all(fd, record_pieces("open", "", extra={"token": "tok", "config_key": KEY})[0])
    write_all(fd, batch_pieces("run", b)[0])
    write_all(fd, record_pieces("delete", "runs/a")[0])
    os.close(fd)
    j = read_journal(jp)
    assert [(r.kind, r.key) for r in j.records] == [("batch", "run"), ("delete", "runs/a")]
    with open(jp, "rb") as fh:
        back = j.records[0].batch(fh)
    assert back.keys == ["a", "b"] and back.rows.tolist() == b.rows.tolist() and back.scalar == ["s"]
    np.testing.assert_array_equal(dict(back.arrays(0))["q"], items[0][2]["q"])
    np.testing.assert_array_equal(back.attrs[0]["q0"], [1.0, 2.0])
    runs, refs = {}, {}
    assert overlay(j, runs, refs) == 2 and set(runs) == {"b"} and not refs   # a deleted, b held


def test_journal_round_trip_stops_at_a_torn_or_damaged_record(tmp_path):
    q = np.arange(6.0).reshape(3, 2)
    jp = _journal(tmp_path / "j", ("run", "a", {"h": 0.01, "q0": np.array([1.0, 2.0])}, [("q", q)]),
                  ("delete", "runs/old", None, ()), ("run", "b", {"h": 0.02}, [("q", 2 * q)]))
    j = read_journal(jp)
    assert (j.token, j.config_key, j.torn) == ("tok", KEY, False)
    assert [(r.kind, r.key) for r in j.records] == [("run", "a"), ("delete", "runs/old"), ("run", "b")]
    with open(jp, "rb") as fh:
        (name, back), = j.records[0].arrays(fh)
    assert name == "q" and back.dtype == q.dtype and np.array_equal(back, q)
    np.testing.assert_array_equal(j.records[0].attrs()["q0"], [1.0, 2.0])
    assert j.after(j.records[0].end).records == j.records[1:]

    size = jp.stat().st_size
    with open(jp, "ab") as fh:  # a kill in the middle of an append
        fh.write(bytes(record_pieces("run", "c", {}, [("q", q)])[0][0]) + b"\0" * 7)
    torn = read_journal(jp)
    assert torn.torn and torn.good_end == size and [r.key for r in torn.records] == ["a", "runs/old", "b"]

    data = bytearray(jp.read_bytes()[:size])
    data[j.records[1].end + 40] ^= 0xFF  # a byte of the last record's payload: its CRC fails
    jp.write_bytes(bytes(data))
    assert [r.key for r in read_journal(jp).records] == ["a", "runs/old"]

    assert read_journal(tmp_path / "none") is None
    fd = os.open(tmp_path / "foreign", os.O_WRONLY | os.O_CREAT, 0o644)
    write_all(fd, record_pieces("run", "x", {}, [])[0])  # no open record first: not a journal of ours
    os.close(fd)
    assert read_journal(tmp_path / "foreign") is None


def test_a_damaged_run_is_named_by_its_check(tmp_path):
    tr = make_traj()
    path = write(tmp_path / "r.h5", {"a": run_attrs(tr, "CVA", tr.h, 3.2), "b": run_attrs(tr, "CVA", tr.h, 3.7)})
    with h5py.File(path, "a") as f:   # b's attributes now declare 2 steps where its arrays hold 40
        g = f["run_batches/00000001"]
        texts = list(g["attrs"].asstr()[()])
        i = list(g["key"].asstr()[()]).index("b")
        a = json.loads(texts[i])
        a["n_steps"] = 2
        texts[i] = json.dumps(a)
        del g["attrs"]
        g.create_dataset("attrs", data=np.array(texts, dtype=object), dtype=h5py.string_dtype())
        crc = g["crc"][()]   # ... and checksums that agree (a writer that stored what it was given)
        crc[i, 0] = zlib.crc32(texts[i].encode(), zlib.crc32(b"b\0"))
        g["crc"][...] = crc
    res = read_results(path)
    assert [r.run_id for r in res.runs] == ["a"]
    assert res.damaged == {"run_batches/00000001/b": "dataset t has shape (41,), expected (3,)"}
    with pytest.raises(StorageError, match=r"run b is damaged \(dataset t has shape"):
        load_trajectory(path, "b")
    with ResultsWriter(path, root_attrs={}, config_key=KEY) as w:   # resume drops the damaged copy
        assert set(w.complete_runs) == {"a"} and w.incomplete == ["run_batches/00000001/b"]
        w.finish("complete")
    res = read_results(path)
    assert [r.run_id for r in res.runs] == ["a"] and not res.damaged and not res.incomplete


def test_a_batch_whose_table_disagrees_with_its_data_is_damaged_whole(tmp_path):
    tr = make_traj()
    path = write(tmp_path / "r.h5", {"a": run_attrs(tr, "CVA", tr.h, 3.2), "b": run_attrs(tr, "CVA", tr.h, 3.7)})
    with h5py.File(path, "a") as f:
        g = f["run_batches/00000001"]
        del g["q"]
        g["q"] = np.zeros((5, 2))
    res = read_results(path)
    assert not res.runs and res.damaged == {"run_batches/00000001": "dataset q has 5 rows, the table 82"}


def test_output_path_checks(tmp_path):
    (tmp_path / "file").write_text("x")
    (tmp_path / "d").mkdir()
    for given, match in ((tmp_path / "a\0b.h5", "NUL"), (tmp_path / "d", "is a directory"),
                         (tmp_path / "file" / "r.h5", "is a file, not a directory")):
        with pytest.raises(StorageError, match=match):
            resolve_output(given)
    target = tmp_path / "d" / "r.h5"
    (tmp_path / "link.h5").symlink_to(target)
    assert resolve_output(tmp_path / "link.h5") == target  # writes go to the link's target
    (tmp_path / "dangling.h5").symlink_to(tmp_path / "nowhere" / "r.h5")
    with pytest.raises(StorageError, match="whose directory does not exist"):
        resolve_output(tmp_path / "dangling.h5")


@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork here")
def test_run_isolated_reports_what_failed_in_the_child(tmp_path):
    def storage_error():
        raise StorageError("x.h5: refused")

    def os_error():
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(StorageError, match="^x.h5: refused$"):
        run_isolated(storage_error, tmp_path / "x.h5")
    with pytest.raises(ChildFailed) as e:
        run_isolated(os_error, tmp_path / "x.h5")
    assert e.value.io_failure and e.value.errno == errno.ENOSPC and "No space left" in str(e.value)
    with pytest.raises(ChildFailed, match=r"crashed \(signal 9\) while writing x.h5"):
        run_isolated(lambda: os.kill(os.getpid(), signal.SIGKILL), tmp_path / "x.h5")
    seen = []
    run_isolated(lambda: seen.append(1), tmp_path / "x.h5")
    assert seen == []  # the child's side effects stay in the child
    run_isolated(lambda: seen.append(1), tmp_path / "x.h5", isolate=False)
    assert seen == [1]


def test_messages_are_one_line():
    hdf5 = "Unable to synchronously create file (file write failed: time = now,\n errno = 28, error message = " \
           "'No space left on device', buf = 0x1)"
    assert one_line(OSError(hdf5)) == "HDF5: No space left on device, errno 28"
    assert one_line(ValueError("a" * 500), 20) == "a" * 17 + "..."
    assert os_text(OSError(errno.EACCES, "Permission denied")) == "Permission denied"
    err = write_error(Path("r.h5"), OSError(errno.ENOSPC, "No space left on device"), "append")
    assert str(err) == "r.h5: cannot append (No space left on device); free some space (or choose another --output)"


def test_environment_attrs_name_versions_and_commit():
    a = environment_attrs()
    assert a["versions"]["numpy"] == np.__version__ and a["numpy_version"] == np.__version__
    assert a["hdf5_version"] == h5py.version.hdf5_version and isinstance(a["git_commit"], str)
    assert a["git_dirty"] in ("", "yes", "no")
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00", now_iso())


# --- metrics on synthetic data -----------------------------------------------------------------------
def test_energy_summary_masks_impact_steps():
    tr = make_traj()
    tr.Ed[:] = 5.0
    tr.Ed[5] = 1e3   # trial step that hit the constraint: must not count
    tr.Ed[17] = -1e3
    tr.Ed[30] = 5.5
    tr.H[:] = 2.0
    tr.H[7] = 2.25
    s = energy_summary(tr)
    assert s["Ed_range"] == pytest.approx(0.5)
    assert s["max_abs_dH"] == pytest.approx(0.25) and s["H_range"] == pytest.approx(0.25) and s["H0"] == 2.0
    assert math.isfinite(s["Hmod_range"])
    assert math.isnan(energy_summary(make_traj(with_hmod=False))["Hmod_range"])


def test_mean_ci_matches_scipy_t_interval():
    x = np.random.default_rng(3).normal(2.0, 0.3, size=51)
    mean, half, n = metrics.mean_ci(x)
    lo, hi = stats.t.interval(0.95, len(x) - 1, loc=x.mean(), scale=stats.sem(x))
    assert n == 51 and mean == pytest.approx(x.mean()) and half == pytest.approx((hi - lo) / 2)
    m1, h1, n1 = metrics.mean_ci([1.0, float("nan")])
    assert (m1, n1) == (1.0, 1) and math.isnan(h1)


# --- figures and tables from a synthetic results file ---------------------------------------------------
def synthetic_results(tmp_path):
    runs = {}
    rng = np.random.default_rng(7)
    for mi, label in enumerate(["CVA", "MCVAA"]):
        for h in (3.2e-2, 1e-2):
            for bi, beta in enumerate(np.linspace(3.2, 5.2, 5)):
                tr = make_traj(with_hmod=label == "MCVAA", beta=float(beta), seed=bi)
                tr.wall_time = float(rng.uniform(1e-3, 2e-3))
                attrs, arrays = run_attrs(tr, label, h, float(beta), index=mi)
                attrs["h"] = h
                attrs["has_Hmod"] = label == "MCVAA"
                runs[f"{label}-{h}-{bi}"] = (attrs, arrays)
    # Figure 1 pair: the same method with and without the constraint
    for rid, constrained in (("dp-c", None), ("dp-free", False)):
        tr = make_traj(with_hmod=False, beta=None, n_imp=2 if constrained is None else 0)
        attrs, arrays = run_attrs(tr, "DP-CVA" if constrained is None else "DP-CVA (no impacts)", 0.01, None,
                                  index=2 if constrained is None else 3, ic_key="default")
        attrs["method_spec"] = {"name": "CVA", **({} if constrained is None else {"constrained": False})}
        runs[rid] = (attrs, arrays)
    return write(tmp_path / "syn.h5", runs, root={"name": "syn", "system": "synthetic", "T": 0.4,
                                                   "h_values": [3.2e-2, 1e-2]})


def test_figures_and_tables_from_stored_runs(tmp_path):
    from vcirun.experiments import figures, tables

    path = synthetic_results(tmp_path)
    res = read_results(path)
    written, skipped = figures.make_figures(res, tmp_path / "fig")
    names = {p.name for p in written}
    for stem in ("fig4_l2_error_vs_beta", "fig3_energy_evolution", "fig1_energy_with_without_impacts",
                 "work_precision"):
        assert {f"{stem}.png", f"{stem}.pdf"} <= names, (stem, skipped)
    assert all(p.stat().st_size > 1000 for p in written)
    t2 = tables.table2(res)
    assert t2.columns == ["Method", "h = 0.032", "h = 0.01"]
    assert [r[0] for r in t2.rows] == ["CVA", "MCVAA", "DP-CVA", "DP-CVA (no impacts)"]
    assert t2.rows[2][1] == ""  # the double-pendulum runs exist at h = 0.01 only
    cva = next(s for s in metrics.timing_stats(res.runs) if s.label == "CVA" and s.h == 1e-2)
    assert cva.n == 5 and cva.halfwidth > 0
    paths = tables.write_table(t2, tmp_path / "fig", "table2_timing")
    csv_text = paths[0].read_text()
    assert csv_text.splitlines()[0] == "method,h,n,mean_s,ci_halfwidth_s,std_s,n_failed,level"
    md = paths[1].read_text()
    assert "| Method | h = 0.032 | h = 0.01 |" in md and "±" in md


def test_figures_explain_what_they_cannot_draw(tmp_path):
    from vcirun.experiments import figures

    tr = make_traj(with_hmod=False)
    attrs, arrays = trajectory_payload(tr, store_arrays=False)
    attrs.update(label="CVA", method_index=0, ic_key="default", beta=None, l2_error=None)
    path = write(tmp_path / "one.h5", {"x": (attrs, arrays)})
    written, skipped = figures.make_figures(read_results(path), tmp_path / "fig")
    assert written == []
    assert set(skipped) == {"fig4", "fig3", "fig1", "work_precision", "contacts"}
    assert "beta" in skipped["fig4"] and "store_trajectories" in skipped["fig3"]


def test_the_journal_of_a_symlinked_results_file_is_beside_its_target(tmp_path):
    """The writer writes through a link to its target; readers given the link find the same journal."""
    from vcirun.io.journal import journal_path

    target = tmp_path / "data" / "r.h5"
    target.parent.mkdir()
    target.write_bytes(b"")
    link = tmp_path / "link.h5"
    link.symlink_to(target)
    assert journal_path(link) == journal_path(target) == target.parent / ".r.h5.journal"
