"""vcirun.open_results: a sweep file as an xarray Dataset over (method, h, beta); the summary group is
readable by plain xarray (h5netcdf) and h5py without vcirun."""
from __future__ import annotations

import subprocess
import sys

import h5py
import numpy as np
import xarray as xr
import pytest

import vcirun
from vcirun.io.reader import read_results
from vcirun.experiments.config import parse_config
from vcirun.experiments.sweep import run_sweep

CFG = {"name": "tinyx", "system": "cart_pendulum", "methods": ["CVA", {"name": "VCI", "label": "R-VCI"}],
       "h": [3.2e-2, 1.0e-2], "beta": {"start": 3.2, "stop": 4.2, "num": 3}, "T": 0.8, "timing_repeats": 1}


@pytest.fixture(scope="module")
def sweep_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("rx")
    cfg = parse_config(dict(CFG, output=str(d / "tinyx.h5")))
    s = run_sweep(cfg, workers=1, progress=False)
    assert s.computed == 12 and not s.summary_error
    return d / "tinyx.h5"


def test_open_results_dims_and_values(sweep_file):
    ds = vcirun.open_results(sweep_file)
    assert dict(ds.sizes) == {"method": 2, "h": 2, "beta": 3, "coordinate": 2}
    assert list(ds.method.values) == ["CVA", "R-VCI"]
    np.testing.assert_array_equal(ds.h.values, [3.2e-2, 1.0e-2])
    np.testing.assert_allclose(ds.beta.values, [3.2, 3.7, 4.2])
    curve = ds.l2_error.sel({"method": "CVA", "h": 0.01})
    assert curve.dims == ("beta",)
    # the keyword form, though `method` is also xarray's fill-method keyword (vcirun.io.xr)
    np.testing.assert_array_equal(ds.l2_error.sel(method="CVA", h=0.01).values, curve.values)
    np.testing.assert_array_equal(ds.sel(method="CVA", h=0.01).l2_error.values, curve.values)
    np.testing.assert_array_equal(ds.l2_error.sel(method="CVA").sel(h=0.01).values, curve.values)
    np.testing.assert_array_equal(ds.l2_error.loc["CVA", 0.01].values, curve.values)
    res = read_results(sweep_file)
    want = sorted((r.attrs["beta"], r.attrs["l2_error"]) for r in res.runs
                  if r.attrs["label"] == "CVA" and r.attrs["h"] == 0.01)
    np.testing.assert_array_equal(curve.values, [e for _, e in want])
    for name in ("wall_time", "n_steps", "n_impacts", "max_abs_dH", "t_end", "status", "run_id", "H0"):
        assert name in ds, name
    assert ds.n_steps.dtype == np.int64 and int(ds.n_steps.sel({"method": "CVA", "h": 0.01, "beta": 3.2})) == 80
    assert (ds.status == "ok").all()
    assert list(ds.coordinate.values) == ["y", "theta"] and ds.q0.dims == ("beta", "coordinate")
    assert "exact nonsmooth solution" in ds.attrs["reference"]
    # Table II's means in one line
    assert ds.wall_time.mean("beta").to_pandas().shape == (2, 2)


def test_missing_runs_are_marked(sweep_file, tmp_path):
    import shutil

    part = tmp_path / "part.h5"
    shutil.copyfile(sweep_file, part)
    from vcirun.io.batches import delete_items
    from vcirun.io.reader import read_results

    r = read_results(part).runs[0]
    label, h, beta = r.attrs["label"], r.attrs["h"], r.attrs["beta"]
    with h5py.File(part, "a") as f:
        delete_items(f, [f"runs/{r.run_id}"])
    ds = vcirun.open_results(part)
    cell = ds.sel({"method": label, "h": h, "beta": beta})
    assert str(cell.status.values) == "missing" and np.isnan(cell.l2_error) and np.isnan(cell.n_steps)
    assert ds.n_steps.dtype == np.float64 and ds.attrs["n_runs"] == 11


def test_summary_group_equals_open_results(sweep_file):
    """The summary group a sweep writes from its own record of the runs is the table vcirun.open_results
    reads back from the stored runs, every variable bit for bit."""
    ds = vcirun.open_results(sweep_file)
    sm = xr.open_dataset(sweep_file, group="summary", engine="h5netcdf")
    assert set(sm.data_vars) == set(ds.data_vars)
    for name in ds.data_vars:
        a, b = ds[name].values, sm[name].values
        if a.dtype.kind in "OUS" or b.dtype.kind in "OUS":
            assert [str(x) for x in a.ravel()] == [str(x) for x in b.ravel()], name
        else:
            np.testing.assert_array_equal(a, b, err_msg=name)


def test_summary_group_has_dimension_scales(sweep_file):
    with h5py.File(sweep_file, "r") as f:
        g = f["summary"]
        d = g["l2_error"]
        assert [dim[0].name.rsplit("/", 1)[1] for dim in d.dims] == ["method", "h", "beta"]
        assert [s.decode() if isinstance(s, bytes) else s for s in g["method"][()]] == ["CVA", "R-VCI"]


def test_xarray_reads_summary_without_vcirun(sweep_file):
    pytest.importorskip("h5netcdf")
    code = ("import sys; sys.modules['vcirun'] = None\n"      # any import of vcirun would fail
            "import xarray as xr\n"
            f"ds = xr.open_dataset({str(sweep_file)!r}, group='summary', engine='h5netcdf')\n"
            "c = ds.l2_error.sel({'method': 'CVA', 'h': 0.01})\n"
            "assert c.dims == ('beta',) and c.size == 3, c\n"
            "assert set(ds.l2_error.dims) == {'method', 'h', 'beta'}\n"
            "print(ds.sizes['method'], ds.sizes['h'], ds.sizes['beta'], float(c[0]))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    ds = vcirun.open_results(sweep_file)
    assert out.stdout.split()[:3] == ["2", "2", "3"]
    assert float(out.stdout.split()[3]) == float(ds.l2_error.loc["CVA", 0.01][0])


def test_open_results_bad_file(tmp_path):
    p = tmp_path / "junk.h5"
    p.write_bytes(b"not hdf5")
    with pytest.raises(ValueError, match="not a readable HDF5"):
        vcirun.open_results(p)


def test_sel_method_keyword_keeps_xarray_fill_methods(sweep_file):
    """`method=` is a label of the method dimension unless it is one of xarray's fill methods."""
    import pickle

    ds = vcirun.open_results(sweep_file)
    near = ds.l2_error.sel(method="CVA").sel(h=0.0101, method="nearest")   # xarray's inexact match
    np.testing.assert_array_equal(near.values, ds.l2_error.sel(method="CVA", h=0.01).values)
    with pytest.raises(ValueError, match="given twice"):
        ds.l2_error.sel({"method": "CVA"}, method="R-VCI")
    np.testing.assert_array_equal(ds.l2_error.sel(h=0.0101, method="nearest").sel(method="CVA").values,
                                  near.values)
    with pytest.raises(KeyError):
        ds.l2_error.sel(method="no such method")
    # the selection survives xarray operations and pickling (dask, multiprocessing)
    back = pickle.loads(pickle.dumps(ds))
    np.testing.assert_array_equal(back.wall_time.mean("beta").sel(method="R-VCI").values,
                                  ds.wall_time.mean("beta").sel({"method": "R-VCI"}).values)
    assert isinstance(ds.l2_error, xr.DataArray) and isinstance(ds, xr.Dataset)
