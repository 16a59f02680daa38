"""Damaged results files and journals: a flipped byte in a stored array fails the item's checksum
(reported by the readers, never served as data, recomputed by a resume); a damaged journal record in
the middle is skipped and the intact records after it are read, and the readers say how many were
skipped; files written before the checksums existed still read."""
from __future__ import annotations

import sys
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

import vcirun
from vcirun.cli.main import app
from vcirun.io.batches import checksums, data_problems, pack, read_batch
from vcirun.io.errors import StorageError
from vcirun.io.journal import batch_pieces, read_journal
from vcirun.io.reader import load_trajectory, read_results
from vcirun.io.results import METRICS, ResultsWarning
from vcirun.io.writer import ResultsWriter

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_storage import KEY, make_traj, run_attrs, write  # noqa: E402


def runs(n, seed=0):
    out = {}
    for i in range(n):
        tr = make_traj(seed=seed + i)
        a, arr = run_attrs(tr, "CVA", tr.h, 3.2 + i, ic_key=f"beta={3.2 + i:g}")
        out[f"r{seed + i:04d}"] = ({**a, "run_id": f"r{seed + i:04d}"}, arr)
    return out


def flip_in_file(path, batch: str, key: str, field: str, row: int = 3, byte: int = 6):
    """Flip one byte of item `key`'s array `field` where it lies in the file (no HDF5 call writes it):
    what a bad disk block or a cosmic ray does. Returns (value before, value after) of that number."""
    with h5py.File(path, "r") as f:
        g = f[batch]
        b = read_batch(g)
        i, j = b.keys.index(key), b.fields.index(field)
        start = int(b.starts()[i, j])
        d = g[field]
        row_bytes = d.dtype.itemsize * int(np.prod(d.shape[1:]))
        off = d.id.get_offset() + (start + row) * row_bytes + byte
        before = np.array(d[start + row]).ravel()[0]
    data = bytearray(Path(path).read_bytes())
    data[off] ^= 0x10
    Path(path).write_bytes(bytes(data))
    with h5py.File(path, "r") as f:
        after = np.array(f[batch][field][start + row]).ravel()[0]
    return before, after


ROOT = {"name": "t", "methods": [{"label": "CVA"}], "h_values": [0.01], "ic_keys": ["beta=3.2", "beta=4.2", "beta=5.2"]}


def test_a_flipped_byte_in_a_stored_array_is_reported_and_recomputed(tmp_path):
    path = write(tmp_path / "r.h5", runs(3), root=ROOT)
    before, after = flip_in_file(path, "run_batches/00000001", "r0001", "q")
    assert before != after   # the stored number changed: plain h5py would serve it
    res = read_results(path)
    assert [r.run_id for r in res.runs] == ["r0000", "r0002"]
    assert res.damaged == {"run_batches/00000001/r0001": "dataset q fails its checksum (the stored data changed "
                                                         "since they were written)"}
    with pytest.raises(StorageError, match="run r0001 is damaged .dataset q fails its checksum"):
        load_trajectory(path, "r0001")
    load_trajectory(path, "r0002")   # the others load
    with pytest.warns(ResultsWarning, match="1 stored item.s. fail their checks"):
        ds = vcirun.open_results(path)
    assert ds.attrs["n_damaged"] == 1 and "r0001" in ds.attrs["damaged"]
    assert sorted(ds.status.values.ravel().tolist()) == ["missing", "ok", "ok"]
    r = CliRunner().invoke(app, ["info", str(path)])
    assert r.exit_code == 0 and "1 stored item(s) fail their checks" in r.output and "r0001" in r.output
    with ResultsWriter(path, root_attrs=ROOT, config_key=KEY) as w:   # a resume drops it ...
        assert set(w.complete_runs) == {"r0000", "r0002"} and w.incomplete == ["run_batches/00000001/r0001"]
        (rid, (a, arr)), = runs(1, seed=1).items()   # ... and recomputes it
        w.add_run(rid, a, arr)
        w.finish("complete")
    res = read_results(path)
    assert [r.run_id for r in res.runs] == ["r0000", "r0001", "r0002"] and not res.damaged
    np.testing.assert_array_equal(load_trajectory(path, "r0001").q, runs(1, seed=1)["r0001"][1]["q"])


@pytest.mark.parametrize("field", ["impacts", "H", "impact_step"])
def test_every_stored_field_is_checked(tmp_path, field):
    path = write(tmp_path / "r.h5", runs(2))
    flip_in_file(path, "run_batches/00000001", "r0000", field, row=1, byte=0)
    assert read_results(path).damaged == {
        "run_batches/00000001/r0000": f"dataset {field} fails its checksum (the stored data changed since they were "
                                      "written)"}


def test_a_flipped_byte_in_the_attributes_text_is_caught(tmp_path):
    path = write(tmp_path / "r.h5", runs(2))
    with h5py.File(path, "a") as f:   # l2_error 0.001 * h -> a different digit, still valid JSON
        g = f["run_batches/00000001"]
        texts = list(g["attrs"].asstr()[()])
        i = list(g["key"].asstr()[()]).index("r0001")
        assert '"l2_error": 1e-05' in texts[i]
        texts[i] = texts[i].replace('"l2_error": 1e-05', '"l2_error": 7e-05')
        g["attrs"][i] = texts[i]
    res = read_results(path)
    assert [r.run_id for r in res.runs] == ["r0000"]
    assert "key or attributes fail their checksum" in res.damaged["run_batches/00000001/r0001"]


def test_files_without_checksums_still_read(tmp_path):
    path = write(tmp_path / "r.h5", runs(2))
    with h5py.File(path, "a") as f:   # what a writer before the checksums left
        del f["run_batches/00000001/crc"]
    res = read_results(path)
    assert [r.run_id for r in res.runs] == ["r0000", "r0001"] and not res.damaged
    load_trajectory(path, "r0001")
    with ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY) as w:
        assert set(w.complete_runs) == {"r0000", "r0001"} and not w.incomplete
        w.finish("complete")


def test_a_batch_rewritten_without_one_item_keeps_the_others_checksums(tmp_path):
    """Deleting an item rewrites its batch from the stored data: the rest keep the checksums they were
    written with, so rot in another item is not laundered into a fresh checksum."""
    path = write(tmp_path / "r.h5", runs(3))
    flip_in_file(path, "run_batches/00000001", "r0002", "p")
    with ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY) as w:
        w.forget_runs(["r0000"])   # (--retry-failed does this) and r0002 is damaged: both deleted
        assert set(w.complete_runs) == {"r0001"}
        w.finish("complete")
    assert [r.run_id for r in read_results(path).runs] == ["r0001"]
    path2 = write(tmp_path / "s.h5", runs(3))
    flip_in_file(path2, "run_batches/00000001", "r0002", "p")
    from vcirun.io.batches import delete_items

    with h5py.File(path2, "a") as f:   # a rewrite that is told to drop r0000 only
        delete_items(f, ["runs/r0000"])
    assert list(read_results(path2).damaged) == ["run_batches/00000001/r0002"]


def test_checksums_travel_from_the_packed_items_through_the_journal(tmp_path):
    items = [(k, None, arr, "{}") for k, (_, arr) in runs(2).items()]
    b, = pack(items)
    table = b.checksums()
    assert table.shape == (2, len(b.fields) + 1) and table.dtype == np.uint32 and np.all(table[:, 0] != 0)
    np.testing.assert_array_equal(checksums(b), table)
    pieces, _ = batch_pieces("run", b, "tok")
    assert b.crc is table   # computed once, when packed
    from vcirun.io.journal import record_pieces, write_all
    import os

    jp = tmp_path / "j"
    fd = os.open(jp, os.O_WRONLY | os.O_CREAT, 0o644)
    write_all(fd, record_pieces("open", "", extra={"token": "tok", "config_key": KEY})[0])
    write_all(fd, pieces)
    os.close(fd)
    j = read_journal(jp)
    with open(jp, "rb") as fh:
        back = j.records[0].batch(fh)
    np.testing.assert_array_equal(back.crc, table)
    assert data_problems(back) == {}
    back.data["q"] = back.data["q"].copy()
    back.data["q"][1, 0] += 1e-12   # one ulp-sized change in item 0's rows
    assert list(data_problems(back)) == [0]


# --- the journal ---------------------------------------------------------------------------------------------
def killed_session(path, commits):
    """A session that committed `commits` (lists of run dicts) to its journal, then was killed."""
    w = ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY)
    w.acquire()
    w.start()
    for batch in commits:
        for rid, (a, arr) in batch.items():
            w.add_run(rid, a, arr)
        w.commit()
    w._close_journal()   # a kill: no finish, the lock dies with the process
    w._release_lock()
    return w.journal_path


@pytest.mark.parametrize("where", ["payload", "length", "magic"])
def test_a_damaged_journal_record_in_the_middle_is_skipped(tmp_path, where):
    path = tmp_path / "r.h5"
    jp = killed_session(path, [runs(2, seed=0), runs(2, seed=10), runs(2, seed=20)])
    j = read_journal(jp)
    batches = [r for r in j.records if r.kind == "batch"]
    assert [r.header["keys"] for r in batches] == [["r0000", "r0001"], ["r0010", "r0011"], ["r0020", "r0021"]]
    middle = batches[1]
    start = j.records[j.records.index(middle) - 1].end   # where the middle batch record begins
    data = bytearray(jp.read_bytes())
    off = {"payload": (start + middle.end) // 2, "length": start + 5, "magic": start}[where]
    data[off] ^= 0x01
    jp.write_bytes(bytes(data))

    j = read_journal(jp)
    assert j.skipped == 1 and not j.torn
    kept = [r.header["keys"] for r in j.records if r.kind == "batch"]
    assert kept == [["r0000", "r0001"], ["r0020", "r0021"]]
    res = read_results(path)
    assert {r.run_id for r in res.runs} == {"r0000", "r0001", "r0020", "r0021"}
    assert len(res.notes) == 1 and "1 damaged record" in res.notes[0] and "skipped" in res.notes[0]
    r = CliRunner().invoke(app, ["info", str(path)])
    assert r.exit_code == 0 and "1 damaged record" in r.output
    with pytest.warns(ResultsWarning, match="damaged record"):
        vcirun.open_results(path)
    w = ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY).acquire()   # a resume
    assert set(w.complete_runs) == {"r0000", "r0001", "r0020", "r0021"}
    assert len(w.notes) == 1 and "1 damaged record" in w.notes[0]
    w.start()
    w.finish("complete")
    w.close()
    assert {r.run_id for r in read_results(path).runs} == {"r0000", "r0001", "r0020", "r0021"}


def test_a_damaged_open_record_loses_nothing(tmp_path):
    path = tmp_path / "r.h5"
    jp = killed_session(path, [runs(2), runs(1, seed=5)])
    data = bytearray(jp.read_bytes())
    data[30] ^= 0x01   # inside the open record (its token and config key)
    jp.write_bytes(bytes(data))
    j = read_journal(jp)
    assert j.skipped == 1 and j.config_key is None and j.token
    assert {r.run_id for r in read_results(path).runs} == {"r0000", "r0001", "r0005"}


def test_a_torn_tail_is_not_counted_as_skipped(tmp_path):
    path = tmp_path / "r.h5"
    jp = killed_session(path, [runs(2), runs(1, seed=5)])
    size = jp.stat().st_size
    with open(jp, "r+b") as fh:
        fh.truncate(size - 40)   # the kill hit the last append (the session record)
    j = read_journal(jp)
    assert j.torn and j.skipped == 0
    res = read_results(path)
    assert {r.run_id for r in res.runs} == {"r0000", "r0001", "r0005"} and not res.notes


def test_open_results_of_a_file_without_complete_runs_has_every_metric(tmp_path):
    path = tmp_path / "r.h5"
    write(path, {})
    with warnings.catch_warnings():
        warnings.simplefilter("error", ResultsWarning)
        ds = vcirun.open_results(path)
    for name in METRICS:
        assert name in ds, name
    assert ds.l2_error.size == 0 or np.all(np.isnan(ds.l2_error.values))
