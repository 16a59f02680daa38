"""The friction rows of the run record (vcirun.core.record.FRICTION_ROWS) in results files: left out for
runs without friction data (every run of a frictionless system), stored for runs with it, and read back
bit for bit equal to the in-memory Trajectory either way -- through `Trajectory.save` / read_single
(`vcirun simulate --output`), a sweep's results file, and a killed session's journal."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

import vcirun
from vcirun.core import record, sizes
from vcirun.io.checks import run_problem
from vcirun.io.reader import load_trajectory, read_results
from vcirun.io.single import read_single
from vcirun.io.writer import ResultsWriter
from vcirun.run.trajectory_files import has_friction_data, trajectory_payload
from vcirun.scenes import friction as friction_scenes

KEY = "f" * 64


def same_record(a, b) -> list:
    """Names of the run-record rows whose dtype, shape or bytes differ between two Trajectories."""
    bad = []
    for f in record.FIELDS:
        x, y = getattr(a, f.name), getattr(b, f.name)
        if x is None or y is None:
            if (x is None) != (y is None):
                bad.append(f.name)
            continue
        x, y = np.asarray(x), np.asarray(y)
        if x.dtype != y.dtype or x.shape != y.shape or x.tobytes() != y.tobytes():
            bad.append(f.name)
    return bad


@pytest.fixture(scope="module")
def runs():
    """A frictionless run with held contacts (a plastic ball in a box comes to rest on the floor), one
    with impacts only, and two runs of friction scenes (slip, stick and frictional impacts)."""
    return {
        "box": vcirun.simulate("ball_in_box", "CVA", h=1e-3, T=1.5, params={"e": 0}),
        "cart": vcirun.simulate("cart_pendulum", "MCVAA", h=1e-2, T=3, beta=3.2),
        "incline": vcirun.simulate(friction_scenes.incline(), "CVA", h=1e-3, T=1),
        "ball": vcirun.simulate(friction_scenes.spinning_ball(), "CVA", h=1e-3, T=1),
    }


def test_which_runs_have_friction_data(runs):
    assert runs["box"].contact_active.any()   # held contacts, frictionless: contact_mode stays 0
    assert not has_friction_data(runs["box"]) and not has_friction_data(runs["cart"])
    assert has_friction_data(runs["incline"]) and has_friction_data(runs["ball"])
    for name, tr in runs.items():
        attrs, arrays = trajectory_payload(tr)
        with_friction = name in ("incline", "ball")
        assert attrs["friction_rows"] is with_friction
        assert (set(arrays) >= set(record.FRICTION_ROWS)) if with_friction else not set(arrays) & set(record.FRICTION_ROWS)


def test_one_run_files_read_back_bit_for_bit(runs, tmp_path):
    for name, tr in runs.items():
        path = tr.save(tmp_path / f"{name}.h5")
        with h5py.File(path, "r") as f:
            stored = set(f["trajectory"])
        assert bool(stored & set(record.FRICTION_ROWS)) is (name in ("incline", "ball")), name
        assert same_record(tr, read_single(path)) == [], name


def test_sweep_files_and_journals_read_back_bit_for_bit(runs, tmp_path):
    items = {}
    for name, tr in runs.items():
        attrs, arrays = trajectory_payload(tr)
        attrs.update(label="CVA", method="CVA", method_index=0, ic_key=name, ic_index=0, l2_error=0.0)
        items[name] = (attrs, arrays)
    path = tmp_path / "r.h5"
    with ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY) as w:
        for name, (a, arr) in items.items():
            w.add_run(name, {**a, "run_id": name}, arr)
        w.finish("complete")
    res = read_results(path)
    assert sorted(r.run_id for r in res.runs) == sorted(runs) and not res.damaged
    for name, tr in runs.items():
        assert same_record(tr, load_trajectory(path, name)) == [], name
    # a killed session: the runs are read from its journal
    jpath = tmp_path / "j.h5"
    w = ResultsWriter(jpath, root_attrs={"name": "t"}, config_key=KEY)
    w.acquire()
    w.start()
    for name, (a, arr) in items.items():
        w.add_run(name, {**a, "run_id": name}, arr)
    w.commit()
    w._close_journal()
    w._release_lock()
    assert read_results(jpath).in_journal == len(runs)
    for name, tr in runs.items():
        assert same_record(tr, load_trajectory(jpath, name)) == [], name


def test_a_run_whose_friction_rows_went_missing_is_damaged(runs):
    attrs, arrays = trajectory_payload(runs["incline"])

    class Group(dict):
        pass

    g = Group({k: v for k, v in arrays.items() if k != "friction_work"})
    g.attrs = attrs
    a = {**attrs, "q0": list(runs["incline"].q[0])}
    assert run_problem(g, a) == "dataset friction_work missing"
    assert run_problem(g, {**a, "friction_rows": False}) is None   # (left out on purpose: no friction data)


def test_the_size_estimate_counts_friction_rows_for_friction_systems_only():
    N, n, m = 1000, 3, 2
    without = sizes.stored_bytes(N, n, m, friction=False)
    rows = (N + 1) * m * 1 + N * 8   # contact_mode (int8 per contact per grid state), friction_work per step
    assert sizes.stored_bytes(N, n, m) - without == rows   # no impacts, no mode changes
    assert sizes.stored_bytes(N, n, m, impacts=4, mode_changes=3) - \
        sizes.stored_bytes(N, n, m, impacts=4, mode_changes=3, friction=False) == rows + 4 * 8 + 3 * (8 + 8 + 8)


def test_a_sweep_whose_reference_stops_at_painleve_stores_every_run(tmp_path):
    """Painleve's rod at beta = 0.9 has no consistent contact force at t = 0: the exact reference stops
    there (status painleve, T = 0), and has no values up to T. Its end is recorded as its failure and
    every run is stored: the Painleve start failed with its status, the other ok with its L2 error."""
    from vcirun.experiments.config import load_config
    from vcirun.experiments.sweep import run_sweep

    cfg = tmp_path / "pain.yaml"
    cfg.write_text(f"name: pain\nsystem: painleve_rod\nmethods: [CVA]\nh: [0.01]\nbeta: {{values: [0.9, 0.3]}}\n"
                   f"T: 0.5\noutput: {tmp_path / 'pain.h5'}\n")
    run_sweep(load_config(cfg), workers=1, progress=False)
    res = read_results(tmp_path / "pain.h5")
    status = sorted(r.attrs["status"] for r in res.runs)
    assert status == ["ok", "painleve"], status
    ok = next(r for r in res.runs if r.attrs["status"] == "ok")
    assert ok.attrs["l2_error"] is not None and ok.attrs["l2_error"] < 1e-3
