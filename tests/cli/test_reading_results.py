"""Reading results on the command line: `info`, `plot` and `animate` on a file of one run and on a
sweep's results file; `info`'s summary fits 80 columns; `store: {every: k}` stores every k-th state and
the file reads back; `validate` estimates the stored size and warns above the threshold."""
from __future__ import annotations


import numpy as np
import pytest
from typer.testing import CliRunner

from vcirun.cli.main import app

TINY = """\
name: tiny
system: cart_pendulum
methods: [CVA, VCI]
h: [3.2e-2, 1.0e-2]
beta: {start: 3.2, stop: 4.2, num: 2}
T: 0.5
timing_repeats: 1
"""


def invoke(*args, env=None):
    return CliRunner().invoke(app, [str(a) for a in args], catch_exceptions=False, env=env)


def one_line_error(r, *words):
    assert r.exit_code == 1, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    for w in words:
        assert w in lines[0], lines[0]


@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory):
    """A tiny sweep stored every 5th grid state, in a scratch working directory."""
    import os

    d = tmp_path_factory.mktemp("tiny")
    (d / "tiny.yaml").write_text(TINY + "store: {every: 5}\n")
    old = os.getcwd()
    os.chdir(d)
    try:
        r = invoke("sweep", "tiny.yaml", "--workers", "1", "--quiet")
        assert r.exit_code == 0, r.output
    finally:
        os.chdir(old)
    return d


def test_store_every_keeps_every_kth_state(sweep_dir):
    from vcirun.io.reader import load_trajectory, read_results

    path = sweep_dir / "results" / "tiny.h5"
    res = read_results(path)
    assert len(res.runs) == 8 and not res.incomplete
    for run in res.runs:
        tr = load_trajectory(path, run.run_id)
        N = run.attrs["n_steps"]
        assert run.attrs["store_every"] == 5
        want = np.append(np.arange(0, N + 1, 5), [N] if N % 5 else [])
        np.testing.assert_allclose(tr.t, want * run.attrs["h"], rtol=0, atol=1e-12)
        assert tr.q.shape == (len(want), 2) and len(tr.newton_iters) == 0


def test_info_summary_fits_80_columns_and_lists_runs_on_request(sweep_dir):
    path = sweep_dir / "results" / "tiny.h5"
    r = invoke("info", path, env={"COLUMNS": "80"})
    assert r.exit_code == 0, r.output
    table = r.output.split("by method and h")[1]
    assert max(len(line) for line in table.splitlines()) <= 80
    rows = [line.split() for line in table.splitlines() if line.strip().startswith(("CVA", "VCI"))]
    assert [(x[0], x[1], x[2], x[3]) for x in rows] == [("CVA", "0.032", "2", "2"), ("CVA", "0.01", "2", "2"),
                                                        ("VCI", "0.032", "2", "2"), ("VCI", "0.01", "2", "2")]
    assert all("..." not in line and "…" not in line for line in table.splitlines())
    r = invoke("info", path, "--runs", env={"COLUMNS": "80"})
    assert r.exit_code == 0 and "8 runs" in r.output
    body = r.output.split("tiny: 8 runs")[1]
    assert len([x for x in body.splitlines() if " ok " in x]) == 8
    assert max(len(line) for line in body.splitlines()) <= 80 and "…" not in body


def test_animate_a_run_of_a_results_file(sweep_dir, tmp_path):
    path = sweep_dir / "results" / "tiny.h5"
    one_line_error(invoke("animate", path), "8 runs match", "--run")   # 2 methods x 2 h x 2 beta, some listed
    one_line_error(invoke("animate", path, "--method", "VCI"), "4 runs match", "--beta")
    r = invoke("animate", path, "--method", "CVA", "--h", "0.01", "--beta", "4.2", "--output", tmp_path / "a.gif")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "a.gif").stat().st_size > 10_000 and "saved" in r.stdout
    one_line_error(invoke("animate", path, "--method", "MCVAA"), "no stored run has method MCVAA")
    one_line_error(invoke("animate", path, "--run", "nope"), "--run: 'nope' is not a run")


def test_one_run_file_info_plot_animate(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = invoke("simulate", "--system", "rocking_block", "--h", "1e-3", "--T", "1", "--output", "run.h5")
    assert r.exit_code == 0, r.output
    r = invoke("info", "run.h5")
    assert r.exit_code == 0, r.output
    assert "rocking_block" in r.output and "impact law" in r.output and "energy error" in r.output
    r = invoke("plot", "run.h5")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "figures" / "run" / "trajectory.png").stat().st_size > 10_000
    rows = (tmp_path / "figures" / "run" / "energy_account.csv").read_text().splitlines()
    assert rows[0] == "t,H,impact_law,rest" and len(rows) == 1002
    assert -1.962 < float(rows[-1].split(",")[2]) < -1.9   # the restitution loss by t = 1 (1.962 J to rest)
    r = invoke("animate", "run.h5", "--fps", "10", "--output", "run.gif")
    assert r.exit_code == 0, r.output
    from PIL import Image

    with Image.open(tmp_path / "run.gif") as im:
        assert im.n_frames == 11
    one_line_error(invoke("animate", "run.h5", "--method", "CVA"), "holds one run")
    one_line_error(invoke("info", "run.h5", "--runs"), "holds one run")
    one_line_error(invoke("animate", "--run", "x"), "--run")
    one_line_error(invoke("animate", "run.h5", "--output", "run.avi"), "--output", ".gif or .mp4")


def test_animate_a_run_made_here(tmp_path):
    out = tmp_path / "dp.gif"
    r = invoke("animate", "--system", "double_pendulum", "--q0", "0,0", "--p0", "1,0", "--T", "0.2", "--output", out)
    assert r.exit_code == 0, r.output
    assert out.stat().st_size > 5000 and "7 frames" in r.stderr


def test_validate_estimates_the_stored_size_and_warns(tmp_path):
    small = tmp_path / "small.yaml"
    small.write_text(TINY)
    r = invoke("validate", small)
    assert r.exit_code == 0 and "size      about" in r.stdout and "every grid state" in r.stdout
    assert "warning" not in r.stderr
    big = tmp_path / "big.yaml"
    big.write_text(TINY.replace("h: [3.2e-2, 1.0e-2]", "h: [1e-4, 2e-4]").replace("T: 0.5", "T: 50")
                   .replace("num: 2", "num: 20").replace("[CVA, VCI]", "[CVA, VCI, MCVAA, MCVAC]"))
    r = invoke("validate", big)
    assert r.exit_code == 0, r.output
    assert "about 4.58 GiB for 160 runs" in r.stdout        # 39.1 MiB the largest run (h = 1e-4, T = 50)
    assert r.stderr.startswith("warning:") and "store: {every:" in r.stderr and "store: metrics" in r.stderr
    thin = tmp_path / "thin.yaml"
    thin.write_text(big.read_text() + "store: {every: 10}\n")
    r = invoke("validate", thin)
    assert "every 10th grid state" in r.stdout and "warning" not in r.stderr
    bad = tmp_path / "bad.yaml"
    bad.write_text(TINY + "store: {every: 1}\n")
    one_line_error(invoke("validate", bad), "store: must be full, metrics or {every: k}")


def variable_length_objects(path) -> list:
    """Every attribute and dataset of an HDF5 file whose type is variable-length (string or sequence):
    what lives in the file's global heap."""
    import h5py

    out = []

    def variable(tid):
        c = tid.get_class()
        return c == h5py.h5t.VLEN or (c == h5py.h5t.STRING and tid.is_variable_str())

    def visit(name, o):
        out.extend(f"{name}@{k}" for k in o.attrs if variable(o.attrs.get_id(k).get_type()))
        if isinstance(o, h5py.Dataset) and variable(o.id.get_type()):
            out.append(name)

    with h5py.File(path, "r") as f:
        visit("/", f)
        f.visititems(visit)
    return out


def test_files_vcirun_writes_hold_no_variable_length_text(sweep_dir, tmp_path, monkeypatch):
    """Text is fixed-length everywhere: the only objects in a sweep file's global heap are the summary's
    dimension-scale lists (HDF5's own DIMENSION_LIST, which vcirun's readers never open); a one-run file
    has no global heap at all."""
    path = sweep_dir / "results" / "tiny.h5"
    found = variable_length_objects(path)
    assert found and all(x.startswith("summary/") and x.endswith("@DIMENSION_LIST") for x in found), found
    import h5py

    with h5py.File(path, "r") as f:
        assert f.attrs["format"] == b"vcirun-sweep" and f["summary/method"].asstr()[()].tolist() == ["CVA", "VCI"]
    monkeypatch.chdir(tmp_path)
    r = invoke("simulate", "--system", "cart_pendulum", "--beta", "3.2", "--h", "1e-2", "--T", "1", "--output",
               "run.h5")
    assert r.exit_code == 0, r.output
    assert variable_length_objects(tmp_path / "run.h5") == [] and b"GCOL" not in (tmp_path / "run.h5").read_bytes()
