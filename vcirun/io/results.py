"""A sweep's results as one labelled table: `vcirun.open_results(path)` -> xarray.Dataset.

Dimensions: `method` (the config's labels, in config order), `h` (the config's steps) and the
initial-condition axis: `beta` (its values) when the config sweeps beta, else `initial_condition`
(the run groups' ic keys: `state=0`, ..., or `default`). Every scalar a run records is a variable
over (method, h, <ic>) (`.sel(method="MCVAA", h=0.01)` selects on the method dimension: see
vcirun/io/xr.py): l2_error, wall_time, wall_time_call, n_steps, n_impacts, n_partial_steps,
newton_iters_total, H0, max_abs_dH, H_range, Ed_range, Hmod_range, fail_step, fail_time, t_end (the
grid's end N h), and the strings status, message, l2_note, run_id (and, where runs hold them, tier and
build, the compiled module's build: shared or specialized (vcirun.codegen.specialize); a tol: sweep's
core_method, tol_status, tol_reason and the estimates' est_kind, est_status, est_message).
Per initial condition: q0, p0
(over `coordinate`, named from the system), reference_accuracy, reference_n_impacts, reference_status,
reference_path.

A run that is not in the file (an interrupted sweep) has status "missing" and NaN numbers; integer
counts are int64 when every run is present, else float64 with NaN (a -1 placeholder would average
silently). Failed runs keep their numbers (n_steps up to the failure; l2_error NaN with l2_note).

`collect(results)` builds the same table with numpy only; `vcirun.experiments.summary` writes it into
the file's `summary` group with HDF5 dimension scales, so plain `xarray.open_dataset(path,
group="summary", engine="h5netcdf")` reads it without vcirun.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..run.trajectory_files import encode_attr

__all__ = ["open_results", "collect", "Table", "ResultsWarning", "METRICS"]

# run attributes that are bookkeeping, not metrics (indices, process ids, flags)
_SKIP = {"method_index", "ic_index", "worker_pid", "complete", "has_trajectory", "has_Hmod", "beta", "h",
         "T_requested", "committed_at"}
_STRINGS = ("status", "message", "l2_note", "run_id")
# strings a sweep of tol: or with error_estimate: true stores (vcirun.run.estimate.sweep_attrs): variables
# where some run holds them
_OPTIONAL_STRINGS = ("tier", "build", "core_method", "tol_status", "tol_reason", "est_kind", "est_status",
                     "est_message")
# the metrics every table has (the module docstring's list), whatever the file holds
METRICS = ("l2_error", "wall_time", "wall_time_call", "n_steps", "n_impacts", "n_partial_steps", "newton_iters_total",
           "H0", "max_abs_dH", "H_range", "Ed_range", "Hmod_range", "fail_step", "fail_time", "t_end")
_RENAME = {"T": "t_end"}
_ATTRS = {
    "l2_error": {"long_name": "L2 trajectory error sqrt(h sum_k |q_k - q_ref(t_k)|^2)"},
    "wall_time": {"units": "s", "long_name": "integration time (fastest of timing_repeats)"},
    "wall_time_call": {"units": "s", "long_name": "whole vcirun.simulate call"},
    "t_end": {"units": "s", "long_name": "end of the grid, N h with N = floor(T / h)"},
    "fail_time": {"units": "s"}, "H0": {"long_name": "H at t = 0"},
    "max_abs_dH": {"long_name": "max |H - H0| over the grid"},
    "H_range": {"long_name": "max - min of H"}, "Ed_range": {"long_name": "max - min of -D3 Ld, impact steps masked"},
    "Hmod_range": {"long_name": "max - min of the truncated modified Hamiltonian"},
    "n_steps": {"long_name": "grid steps taken"}, "n_impacts": {"long_name": "impacts located"},
}


@dataclass
class Table:
    """dims: {name: values}; variables: {name: (dims tuple, array, attrs)}; attrs: file facts."""
    dims: dict
    variables: dict
    attrs: dict = field(default_factory=dict)
    coord_attrs: dict = field(default_factory=dict)


def _ic_axis(res, ic_keys):
    betas = {}
    for r in res.runs:
        b = r.attrs.get("beta")
        if b is not None and np.isfinite(b):
            betas[r.attrs.get("ic_key")] = float(b)
    for k, a in res.references.items():
        b = a.get("beta")
        if b is not None and np.isfinite(b):
            betas.setdefault(k, float(b))
    if ic_keys and all(k.startswith("beta=") for k in ic_keys):
        vals = [betas.get(k, _beta_of_key(k)) for k in ic_keys]
        if all(v is not None and np.isfinite(v) for v in vals):
            return "beta", np.array(vals, float)
    return "initial_condition", np.array(ic_keys, dtype=object)


def _beta_of_key(key: str):
    try:
        return float(key.split("=", 1)[1])
    except (IndexError, ValueError):
        return None


def reference_note(results) -> str:
    """The reference the L2 errors were measured against, in words (from the stored config)."""
    from vcirun.run.plotting import fmt_h

    a = results.attrs
    spec = (a.get("config_canonical") or {}).get("reference") or {"kind": a.get("reference_kind", "?")}
    kind = spec.get("kind")
    if kind == "exact":
        refs = list(results.references.values())
        acc = [float(r.get("accuracy")) for r in refs
               if r.get("accuracy") is not None and np.isfinite(r.get("accuracy"))]
        paths = sorted({str(r.get("path")) for r in refs if r.get("path")})
        how = {"taylor": "Taylor (heyoka) with root isolation", "dop853": f"DOP853 at rtol {spec.get('rtol', 1e-13):g}"}
        txt = ("reference: exact nonsmooth solution (" + (", ".join(how.get(p, p) for p in paths) if paths else
               f"rtol {spec.get('rtol', 1e-13):g}") + ")")
        failed = sum(1 for r in refs if r.get("status") == "failed")
        return (txt + (f", self-reported accuracy <= {max(acc):.1e}" if acc else "")
                + (f", {failed} failed (their runs' L2 errors are NaN)" if failed else ""))
    if kind == "method":
        return f"reference: {spec.get('method', 'CVA')} at h = {fmt_h(float(spec.get('h')))}"
    return "no reference"


def collect(results) -> Table:
    """The (method, h, initial condition) table of a `vcirun.io.reader.Results` (or a path)."""
    from vcirun.scenes.registry import coordinate_names
    from vcirun.io.reader import Results, read_results

    res = results if isinstance(results, Results) else read_results(results)
    a = res.attrs
    labels = [m.get("label") for m in (a.get("methods") or []) if isinstance(m, dict)]
    for r in res.runs:  # runs of labels the root does not list (other tooling): appended
        if r.attrs.get("label") not in labels:
            labels.append(r.attrs.get("label"))
    hs = [float(h) for h in (a.get("h_values") or [])]
    for r in res.runs:
        if float(r.attrs["h"]) not in hs:
            hs.append(float(r.attrs["h"]))
    ic_keys = list(a.get("ic_keys") or [])
    for r in res.runs:
        if r.attrs.get("ic_key") not in ic_keys:
            ic_keys.append(r.attrs.get("ic_key"))
    ic_dim, ic_vals = _ic_axis(res, ic_keys)
    shape = (len(labels), len(hs), len(ic_keys))
    li = {x: i for i, x in enumerate(labels)}
    hi = {x: i for i, x in enumerate(hs)}
    ii = {x: i for i, x in enumerate(ic_keys)}

    cells = {}
    for r in res.runs:
        cells[(li[r.attrs["label"]], hi[float(r.attrs["h"])], ii[r.attrs["ic_key"]])] = r
    numeric, strings = {}, {s: np.full(shape, "missing" if s == "status" else "", dtype=object) for s in _STRINGS}
    for s_ in _OPTIONAL_STRINGS:
        if any(s_ in r.attrs for r in cells.values()):
            strings[s_] = np.full(shape, "", dtype=object)
    for idx, r in cells.items():
        for k, v in r.attrs.items():
            if k in strings:   # (as stored: text HDF5 can hold)
                strings[k][idx] = "" if v is None else encode_attr(k, str(v))
                continue
            t = type(v)   # (plain floats and ints first: most of a run's attributes)
            if k in _SKIP or not (t is float or t is int) and (
                    isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating))):
                continue
            col = numeric.get(_RENAME.get(k, k))
            if col is None:
                col = numeric[_RENAME.get(k, k)] = (np.full(shape, np.nan), [])
            col[0][idx] = float(v)
            col[1].append(t is int or isinstance(v, np.integer))
        strings["run_id"][idx] = r.run_id
    dims3 = ("method", "h", ic_dim)
    variables = {}
    for name in METRICS:   # every documented metric, NaN where no run holds it (a file with no complete run)
        numeric.setdefault(name, (np.full(shape, np.nan), [False]))
    complete = len(cells) == math.prod(shape)
    for name in sorted(numeric):
        arr, is_int = numeric[name]
        if complete and all(is_int) and np.all(np.isfinite(arr)):
            arr = arr.astype(np.int64)
        variables[name] = (dims3, arr, dict(_ATTRS.get(name, {})))
    for name in strings:
        variables[name] = (dims3, strings[name], {})

    # per initial condition: start state and the reference's facts
    # (q0, p0: lists as read from a file, arrays as a sweep's workers give them)
    n = next((len(r.attrs["q0"]) for r in res.runs if isinstance(r.attrs.get("q0"), (list, np.ndarray))), 0)
    if n:
        q0, p0 = np.full((len(ic_keys), n), np.nan), np.full((len(ic_keys), n), np.nan)
        for r in res.runs:
            if isinstance(r.attrs.get("q0"), (list, np.ndarray)) and isinstance(r.attrs.get("p0"), (list, np.ndarray)):
                q0[ii[r.attrs["ic_key"]]] = r.attrs["q0"]
                p0[ii[r.attrs["ic_key"]]] = r.attrs["p0"]
        variables["q0"] = ((ic_dim, "coordinate"), q0, {"long_name": "initial coordinates"})
        variables["p0"] = ((ic_dim, "coordinate"), p0, {"long_name": "initial momenta"})
    if res.references:
        acc, nimp = np.full(len(ic_keys), np.nan), np.full(len(ic_keys), np.nan)
        for k, ra in res.references.items():
            if k in ii:
                v = ra.get("accuracy")
                acc[ii[k]] = np.nan if v is None else float(v)
                m = ra.get("n_impacts")
                nimp[ii[k]] = np.nan if m is None else float(m)
        variables["reference_accuracy"] = ((ic_dim,), acc, {"long_name": "self-reported accuracy of the reference"})
        variables["reference_n_impacts"] = ((ic_dim,), nimp, {})
        status, path = np.full(len(ic_keys), "", dtype=object), np.full(len(ic_keys), "", dtype=object)
        for k, ra in res.references.items():
            if k in ii:
                status[ii[k]] = str(ra.get("status", ""))
                path[ii[k]] = str(ra.get("path", ""))
        variables["reference_status"] = ((ic_dim,), status, {"long_name": "ok, or failed (the runs' L2 errors NaN)"})
        variables["reference_path"] = ((ic_dim,), path, {"long_name": "the exact reference's integrator: taylor "
                                                                      "or dop853 (empty for a method reference)"})

    dims = {"method": np.array(labels, dtype=object), "h": np.array(hs, float), ic_dim: ic_vals}
    if n:
        dims["coordinate"] = np.array(coordinate_names(str(a.get("system", "")), n), dtype=object)
    coord_attrs = {"h": {"long_name": "step size", "units": "s"}}
    if ic_dim == "initial_condition":
        coord_attrs[ic_dim] = {"long_name": "initial-condition key (results group name)"}
    else:
        coord_attrs[ic_dim] = {"long_name": "initial-condition parameter beta of the scene's map"}
    attrs = {"name": res.name, "system": str(a.get("system", "")), "T": _float(a.get("T")),
             "reference": reference_note(res), "source": str(res.path),
             "n_runs": len(res.runs), "n_runs_expected": _count(a.get("n_runs_expected"), math.prod(shape)),
             "n_damaged": len(res.damaged)}
    if res.damaged:   # stored items that fail their checks (checksums, shapes): missing here, recomputed by a resume
        attrs["damaged"] = "; ".join(f"{p}: {why}" for p, why in res.damaged.items())
    if getattr(res, "notes", None):
        attrs["notes"] = "; ".join(res.notes)
    for k in ("vcirun_version", "git_commit", "created", "updated", "config_sha256"):
        if a.get(k) not in (None, ""):
            attrs[k] = str(a[k])
    return Table(dims, variables, attrs, coord_attrs)


def _float(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def _count(v, default: int) -> int:
    try:
        return int(v) if v is not None else int(default)
    except (TypeError, ValueError, OverflowError):
        return int(default)


class ResultsWarning(UserWarning):
    """Stored runs that fail their checks, or journal records skipped as damaged: not in the table."""


def open_results(path):
    """The results file at `path` as an xarray.Dataset over (method, h, beta | initial_condition):
    every scalar metric of every run (see the module docstring). Example::

        ds = vcirun.open_results("results/fig4.h5")
        ds.l2_error.sel({"method": "MCVAA", "h": 0.01})    # the Figure 4 curve, over beta
        ds.l2_error.loc["MCVAA", 0.01]                     # the same, by position of the dims
        ds.wall_time.mean("beta").to_pandas()              # Table II's means, method x h

    `method` is also the keyword of xarray's own `.sel(..., method="nearest")` (inexact matching).
    The Dataset returned here (and every DataArray taken from it) reads `.sel(method="MCVAA", h=0.01)`
    as a selection on the method dimension when the value is not one of xarray's fill methods
    (vcirun.io.xr); a fill method keeps xarray's meaning: `.sel(h=0.011, method="nearest")`.
    """
    from vcirun.io.errors import StorageError
    from vcirun.io.reader import read_results

    path = Path(path)
    try:
        res = read_results(path)
    except StorageError as e:
        raise ValueError(str(e)) from None
    tab = collect(res)
    if res.damaged or getattr(res, "notes", None):
        import warnings

        what = [f"{len(res.damaged)} stored item(s) fail their checks ({next(iter(res.damaged.items()))[0]}: "
                f"{next(iter(res.damaged.items()))[1]})" if res.damaged else "", *getattr(res, "notes", [])]
        warnings.warn(f"{path}: " + "; ".join(w for w in what if w) + "; they are missing from the table (status "
                      "'missing'; attrs['damaged'] lists them); `vcirun sweep` of the same config recomputes them",
                      ResultsWarning, stacklevel=2)
    coords = {k: (k, v if v.dtype != object else v.astype(str), tab.coord_attrs.get(k, {}))
              for k, v in tab.dims.items()}
    data = {}
    for name, (dims, arr, attrs) in tab.variables.items():
        data[name] = (dims, arr.astype(str) if arr.dtype == object else arr, attrs)
    from vcirun.io.xr import ResultsDataset

    return ResultsDataset(data, coords=coords, attrs=tab.attrs)
