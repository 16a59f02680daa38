"""The `summary` group of a results file: every run's scalar metrics over (method, h, initial
condition) as plain HDF5 datasets with dimension scales, so that readers that know nothing of vcirun
see named dimensions:

    xarray.open_dataset("results/fig4.h5", group="summary", engine="h5netcdf")   # no vcirun needed
    h5py: f["summary/l2_error"].dims[0][0] is f["summary/method"]

Written once when a sweep finishes (also after an interruption: it covers the runs the file holds),
from `vcirun.io.results.collect`, the table behind `vcirun.open_results`: inside the writer's last
rewrite of the file (`summary_hook`, no second copy of the file), or, where that did not leave one,
by `write_summary` on its own (atomic like the sweep's commits: copy, write, fsync, rename), while the
sweep still holds the file's lock. Strings are fixed-length UTF-8 (attribute `_Encoding`, which xarray
decodes by); missing runs are NaN / "missing" (see vcirun.io.results). The dimension scales'
DIMENSION_LIST attributes (HDF5's own, variable-length object references) are the only objects of a
results file in its global heap; vcirun's readers never open them.
"""
from __future__ import annotations

import contextlib
import os
import shutil
from pathlib import Path

import h5py
import numpy as np

from ..io.checks import LIBVER
from ..core.fsync import fsync_path
from ..io.errors import StorageError
from ..io.reader import read_results, results_of
from ..run.trajectory_files import fixed_text, fixed_texts, storable

__all__ = ["write_summary", "summary_hook", "has_summary", "GROUP"]

GROUP = "summary"


def _dataset(g, name, arr):
    if arr.dtype == object or arr.dtype.kind == "U":
        d = g.create_dataset(name, data=fixed_texts([str(x) for x in arr.ravel()]).reshape(arr.shape))
        d.attrs["_Encoding"] = fixed_text("utf-8")   # (xarray decodes the bytes of fixed-length text by it)
        return d
    return g.create_dataset(name, data=arr)


def _write_group(f: h5py.File, tab) -> None:
    if GROUP in f:
        del f[GROUP]
    g = f.create_group(GROUP)
    scales = {}
    for name, values in tab.dims.items():
        d = _dataset(g, name, np.asarray(values))
        for k, v in tab.coord_attrs.get(name, {}).items():
            d.attrs[k] = storable(v)
        d.make_scale(name)
        scales[name] = d
    for name, (dims, arr, attrs) in tab.variables.items():
        d = _dataset(g, name, np.asarray(arr))
        for i, dim in enumerate(dims):
            d.dims[i].attach_scale(scales[dim])
        for k, v in attrs.items():
            d.attrs[k] = storable(v)
    for k, v in tab.attrs.items():
        g.attrs[k] = storable(v)


def summary_hook(path, held=None):
    """A final hook of the results writer (f(h5py.File) on the file's last copy): the summary group
    of what that copy holds. `held`: a callable returning ({run id: attributes}, {key: reference
    attributes}) of exactly the items the copy holds (the writer's own record of them, in the forked
    writer's memory), so that nothing is read back; else they are read from the copy (without
    re-checking: they were verified when the session started or written by it). It never fails the
    rewrite (the runs matter more): on an error it leaves no summary group, and the sweep then writes
    one apart with `write_summary`, which reports why."""
    from vcirun.io.reader import Results, RunInfo
    from vcirun.io.results import collect
    from vcirun.run.trajectory_files import decode_attrs

    def results(f):
        if held is None:
            return results_of(f, Path(path), check=False)
        runs, refs = held()
        return Results(Path(path), decode_attrs(f.attrs), [RunInfo(k, a) for k, a in runs.items()], dict(refs))

    def hook(f) -> None:
        try:
            _write_group(f, collect(results(f)))
        except Exception:  # noqa: BLE001 - see the docstring
            with contextlib.suppress(Exception):
                if GROUP in f:
                    del f[GROUP]

    return hook


def has_summary(path) -> bool:
    """Whether the results file at `path` has a summary group (False if it cannot be read)."""
    try:
        with h5py.File(path, "r") as f:
            return GROUP in f
    except OSError:
        return False


def write_summary(path, if_missing: bool = False) -> Path:
    """(Re)write the summary group of the results file at `path` atomically (with `if_missing`, only
    if the file has none); returns the path. StorageError if the file cannot be read or written (the
    file is then unchanged)."""
    from vcirun.io.results import collect

    path = Path(path)
    if if_missing and has_summary(path):
        return path
    res = read_results(path)   # (a file that cannot be read: a StorageError naming it)
    tab = collect(res)
    tmp = path.with_name(f".{path.name}.summary-partial")
    try:
        shutil.copyfile(path, tmp)
        with h5py.File(tmp, "a", libver=LIBVER) as f:
            _write_group(f, tab)
        fsync_path(tmp)
        os.replace(tmp, path)
        fsync_path(path.parent, directory=True)
    except OSError as e:
        raise StorageError(f"{path}: cannot write the summary group ({' '.join(str(e).split())}); "
                           "the runs are unaffected") from e
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
    return path
