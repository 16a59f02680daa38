"""One HDF5 file per sweep, readable with plain h5py (layout: docs/results_schema.md).

Safety model. The sweep's client process is the only writer. It never writes the live file in
place: each commit copies the file to a hidden sibling, writes the new run groups there, flushes,
fsyncs and atomically renames it over the original (`os.replace`). A hard kill at any instant
therefore leaves either the previous or the next complete file, never a half-written one. (Writing
in place, even with a flush after every run, is not enough: a kill inside HDF5's metadata write
can leave a file that no longer opens, and with libver='latest' a file killed while open refuses to
open at all until `h5clear` resets its consistency flags; both were reproduced while designing this.)
Inside a commit a run group's `complete` attribute is written last, after a flush of everything
else, so any reader that meets a group without `complete=True` (e.g. a file written by other
tooling) treats it as missing; `ResultsWriter` deletes such groups and the sweep recomputes them.
Commits are rate-limited so that copying stays a small fraction of the sweep's time.
"""
from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import json
import os
import platform
import shutil
import subprocess
import time
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path

import h5py
import numpy as np

from .. import record
from .metrics import energy_summary

__all__ = ["FORMAT", "SCHEMA_VERSION", "StorageError", "ResultsWriter", "RunInfo", "Results", "read_results",
           "load_trajectory", "load_reference", "trajectory_payload", "trajectory_from_group",
           "environment_attrs", "find_newest_results"]

FORMAT = "vcirun-sweep"
SCHEMA_VERSION = 1
LIBVER = "latest"

# Attributes holding JSON text (decoded by the readers here; plain h5py users call json.loads).
JSON_ATTRS = {"tolerances", "options", "method_spec", "history", "config_canonical", "versions", "h_values",
              "methods", "ic_keys", "system_spec", "resolved_method"}
# Per-step arrays dropped when store_trajectories is false; the impact record is always kept.
# the run record's rows (vcirun.record.FIELDS): per-step arrays with store_trajectories, the impact
# record always
TRAJECTORY_ARRAYS = ("t",) + record.stored_names("trajectory")
IMPACT_ARRAYS = record.stored_names("impacts")


class StorageError(RuntimeError):
    """A results file that cannot be used (unreadable, foreign, written by another config, locked)."""


def now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


# --- attribute encoding -----------------------------------------------------------------------------
def _encode_attr(key, value):
    if key in JSON_ATTRS:
        return json.dumps(value, sort_keys=True, default=_json_default)
    if value is None:
        return np.nan if key in _FLOAT_ATTRS else ""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (list, tuple)):
        return np.asarray(value, dtype=float)
    return value


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def _decode_attr(key, value):
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    if key in JSON_ATTRS and isinstance(value, str):
        try:
            return json.loads(value)
        except ValueError:
            return value
    if isinstance(value, np.ndarray):
        return value.tolist() if value.ndim else value.item()
    if isinstance(value, np.generic):
        return value.item()
    return value


def decode_attrs(attrs) -> dict:
    return {k: _decode_attr(k, v) for k, v in attrs.items()}


_FLOAT_ATTRS = {"beta", "l2_error", "fail_time", "H0", "max_abs_dH", "H_range", "Ed_range", "Hmod_range",
                "accuracy", "rtol", "ref_h", "wall_time", "wall_time_call", "T", "T_requested", "h"}


# --- Trajectory <-> HDF5 -----------------------------------------------------------------------------
def trajectory_payload(traj, *, store_arrays: bool = True) -> tuple[dict, dict]:
    """(attrs, arrays) of a `vcirun.trajectory.Trajectory` for one run group."""
    attrs = {
        "core_method": traj.method, "system": traj.system, "h": float(traj.h), "T": float(traj.T),
        "status": traj.status, "message": " ".join(str(traj.message).split()),
        "fail_step": int(traj.fail_step), "fail_time": float(traj.fail_time),
        "beta": float("nan") if traj.beta is None else float(traj.beta),
        "wall_time": float(traj.wall_time), "n_steps": int(len(traj.t) - 1), "n_impacts": int(len(traj.impacts)),
        "n_partial_steps": int(len(traj.partial_steps)),
        "newton_iters_total": int(np.sum(traj.newton_iters)) if len(traj.newton_iters) else 0,
        "has_Hmod": traj.Hmod is not None, "has_trajectory": bool(store_arrays),
        "tolerances": dict(traj.tolerances), "options": dict(traj.options),
    }
    attrs.update(energy_summary(traj))
    arrays = {name: getattr(traj, name) for name in IMPACT_ARRAYS}
    if store_arrays:
        for name in TRAJECTORY_ARRAYS:
            value = getattr(traj, name)
            if value is None:
                continue
            if name in record.FIELD and record.FIELD[name].dtype == "bool":
                value = np.asarray(value, dtype=np.uint8)  # 0/1: portable, unlike HDF5's bool enum
            arrays[name] = value
    return attrs, {k: np.asarray(v) for k, v in arrays.items()}


def trajectory_from_group(g):
    """Rebuild a `Trajectory` from a run group (arrays that were not stored come back empty)."""
    from vcirun.trajectory import Trajectory

    a = decode_attrs(g.attrs)
    n = int(g["impact_q"].shape[1]) if "impact_q" in g and g["impact_q"].ndim == 2 else 0

    def arr(name, shape=(0,), dtype=float):
        return g[name][()] if name in g else np.zeros(shape, dtype)

    beta = a.get("beta", float("nan"))
    arrays = {}
    for f in record.FIELDS:  # one per row of the run record; a row not stored comes back empty
        if f.only is not None:
            arrays[f.name] = g[f.name][()] if f.name in g else None
            continue
        dt = np.uint8 if f.dtype == "bool" else np.dtype(f.dtype)
        value = arr(f.name, f.shape(0, n, 0), dt)
        arrays[f.name] = value.astype(bool) if f.dtype == "bool" else value
    return Trajectory(
        method=a.get("core_method", a.get("method", "")), system=a.get("system", ""), h=float(a["h"]),
        T=float(a["T"]), t=arr("t"), **arrays,
        status=a.get("status", ""), message=a.get("message", ""), fail_step=int(a.get("fail_step", -1)),
        fail_time=float(a.get("fail_time", float("nan"))),
        beta=None if beta is None or not np.isfinite(beta) else float(beta), wall_time=float(a.get("wall_time", 0.0)),
        tolerances=a.get("tolerances") or {}, options=a.get("options") or {})


def _write_group(f: h5py.File, path: str, attrs: dict, arrays: dict) -> None:
    """Write one run/reference group; `complete` goes last, after a flush of everything else."""
    if path in f:
        del f[path]
    g = f.create_group(path)
    for name, value in arrays.items():
        g.create_dataset(name, data=np.asarray(value))
    for key, value in attrs.items():
        if key == "complete" or (value is None and key not in _FLOAT_ATTRS):
            continue  # absent rather than a placeholder; float attributes use NaN
        g.attrs[key] = _encode_attr(key, value)
    f.flush()
    g.attrs["complete"] = True
    f.flush()


# --- environment --------------------------------------------------------------------------------------
def _version(dist: str) -> str:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return ""


def git_commit(start: Path | None = None) -> tuple[str, bool | None]:
    """(commit, dirty) of the repository holding the vcirun package, or ('', None). Read-only git calls."""
    start = start or Path(__file__).resolve().parents[2]
    try:
        commit = subprocess.run(["git", "-C", str(start), "rev-parse", "HEAD"], capture_output=True, text=True,
                                timeout=5, check=True).stdout.strip()
        status = subprocess.run(["git", "--no-optional-locks", "-C", str(start), "status", "--porcelain",
                                 "--untracked-files=no"], capture_output=True, text=True, timeout=5, check=True)
        return commit, bool(status.stdout.strip())
    except (OSError, subprocess.SubprocessError):
        return "", None


def environment_attrs() -> dict:
    """Package and library versions, git commit and platform, as root attributes."""
    import vcirun

    commit, dirty = git_commit()
    versions = {name: _version(name) for name in ("numpy", "scipy", "numba", "h5py", "sympy", "pydantic",
                                                  "matplotlib")}
    versions["hdf5"] = h5py.version.hdf5_version
    versions["python"] = platform.python_version()
    return {
        "vcirun_version": getattr(vcirun, "__version__", _version("vcirun")),
        "git_commit": commit, "git_dirty": "" if dirty is None else ("yes" if dirty else "no"),
        "python_version": platform.python_version(), "numpy_version": versions["numpy"],
        "scipy_version": versions["scipy"], "numba_version": versions["numba"], "h5py_version": versions["h5py"],
        "hdf5_version": versions["hdf5"], "sympy_version": versions["sympy"], "versions": versions,
        "platform": platform.platform(), "hostname": platform.node(),
    }


# --- writer ------------------------------------------------------------------------------------------
def _fsync_path(path: Path, directory: bool = False) -> None:
    flags = os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if directory else 0)
    try:
        fd = os.open(path, flags)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@dataclass
class _Pending:
    kind: str  # "run" | "reference"
    key: str
    attrs: dict
    arrays: dict


class ResultsWriter:
    """The single writer of one sweep's results file. Use as a context manager.

    `open()` checks an existing file (format, and that it was written by the same configuration:
    `config_key`), collects its complete runs and references, and schedules incomplete groups for
    deletion; with `force` it starts a new file instead. `add_run`/`add_reference` queue results;
    `commit()` writes the queue atomically; `maybe_commit()` does so when enough time has passed that
    the copy costs at most ~5% of the wall time.
    """

    def __init__(self, path, *, root_attrs: dict, config_key: str, force: bool = False,
                 min_interval: float = 0.5, session: dict | None = None):
        self.path = Path(path)
        self.root_attrs = dict(root_attrs)
        self.config_key = config_key
        self.force = force
        self.min_interval = min_interval
        self.session = dict(session or {})
        self.session.setdefault("started", now_iso())
        self.session.setdefault("status", "running")
        self.session.setdefault("computed", 0)
        self.complete_runs: dict[str, dict] = {}
        self.references: dict[str, dict] = {}
        self.incomplete: list[str] = []
        self._pending: list[_Pending] = []
        self._deletions: list[str] = []
        self._last_commit = 0.0
        self._last_cost = 0.0
        self._lock_fd = None
        self._fresh = force
        self.prior_history: list = []
        self.n_commits = 0

    # the temporary copy lives next to the file so that os.replace stays on one filesystem
    @property
    def tmp_path(self) -> Path:
        return self.path.with_name(f".{self.path.name}.partial")

    @property
    def lock_path(self) -> Path:
        return self.path.with_name(f".{self.path.name}.lock")

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def _acquire_lock(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            import fcntl
        except ImportError:  # pragma: no cover - non-POSIX: no guard against two concurrent writers
            return
        fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            os.close(fd)
            if e.errno in (errno.EAGAIN, errno.EACCES):
                raise StorageError(f"{self.path}: another vcirun sweep is writing this file; wait for it or "
                                   "choose another --output") from None
            raise
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._lock_fd = fd

    def _release_lock(self) -> None:
        if self._lock_fd is not None:
            with contextlib.suppress(OSError):
                os.unlink(self.lock_path)
            os.close(self._lock_fd)
            self._lock_fd = None

    def acquire(self) -> "ResultsWriter":
        """Take the writer lock and read what an existing file already holds (nothing is written)."""
        self._acquire_lock()
        try:
            with contextlib.suppress(FileNotFoundError):
                self.tmp_path.unlink()  # leftover of a commit that was killed before its rename
            self._fresh = self.force or not self.path.exists()
            if not self._fresh:
                self._read_existing()
        except BaseException:
            self._release_lock()
            raise
        return self

    def start(self) -> None:
        """Create the file (or record this session in the existing one) and drop incomplete groups."""
        if self._fresh:
            self.root_attrs.setdefault("created", now_iso())
        else:
            self.root_attrs.pop("created", None)  # keep the original creation time
        self.commit(force_write=True)

    def open(self) -> "ResultsWriter":
        self.acquire()
        try:
            self.start()
        except BaseException:
            self._release_lock()
            raise
        return self

    def has_changes(self) -> bool:
        return bool(self._pending or self._deletions)

    def _read_existing(self) -> None:
        try:
            f = h5py.File(self.path, "r")
        except OSError as e:
            raise StorageError(f"{self.path}: not a readable HDF5 file ({' '.join(str(e).split())}); move it away "
                               "or rerun with --force to start over") from None
        with f:
            fmt = _decode_attr("format", f.attrs.get("format", ""))
            if fmt != FORMAT:
                raise StorageError(f"{self.path}: not a vcirun sweep file (format {fmt!r}); choose another "
                                   "--output or rerun with --force to overwrite it")
            key = _decode_attr("config_key", f.attrs.get("config_key", ""))
            if key != self.config_key:
                raise StorageError(f"{self.path}: written by a different configuration (config key {key[:12]} "
                                   f"!= {self.config_key[:12]}); rerun with --force to recompute everything, or "
                                   "choose another --output")
            self.prior_history = decode_attrs(f.attrs).get("history") or []
            for kind, group, store in (("run", "runs", self.complete_runs), ("reference", "references",
                                                                              self.references)):
                if group not in f:
                    continue
                for name, g in f[group].items():
                    if bool(g.attrs.get("complete", False)):
                        store[name] = decode_attrs(g.attrs)
                    else:
                        self.incomplete.append(f"{group}/{name}")
        self._deletions.extend(self.incomplete)

    def forget_runs(self, run_ids) -> None:
        """Schedule runs for recomputation (e.g. --retry-failed): deleted at the next commit."""
        for rid in run_ids:
            if self.complete_runs.pop(rid, None) is not None:
                self._deletions.append(f"runs/{rid}")

    def add_run(self, run_id: str, attrs: dict, arrays: dict) -> None:
        self._pending.append(_Pending("run", run_id, attrs, arrays))

    def add_reference(self, key: str, attrs: dict, arrays: dict) -> None:
        if key in self.references or any(p.kind == "reference" and p.key == key for p in self._pending):
            return  # computed once per initial condition and stored once
        self._pending.append(_Pending("reference", key, attrs, arrays))

    @property
    def n_pending(self) -> int:
        return len(self._pending)

    def maybe_commit(self) -> bool:
        if not self._pending:
            return False
        interval = max(self.min_interval, 20.0 * self._last_cost)
        if time.monotonic() - self._last_commit >= interval:
            self.commit()
            return True
        return False

    def commit(self, *, force_write: bool = False) -> None:
        """Write queued groups to a copy of the file and atomically replace the original."""
        if not (self._pending or self._deletions or force_write):
            return
        t0 = time.monotonic()
        tmp = self.tmp_path
        fresh = self._fresh or not self.path.exists()
        if not fresh:
            shutil.copyfile(self.path, tmp)
        n_runs = sum(p.kind == "run" for p in self._pending)
        try:
            with h5py.File(tmp, "w" if fresh else "a", libver=LIBVER) as f:
                if fresh:
                    f.attrs["format"] = FORMAT
                    f.attrs["schema_version"] = SCHEMA_VERSION
                    f.attrs["config_key"] = self.config_key
                    f.create_group("runs")
                    f.create_group("references")
                for key, value in self.root_attrs.items():
                    f.attrs[key] = _encode_attr(key, value)
                for path in self._deletions:
                    if path in f:
                        del f[path]
                for p in self._pending:
                    group = "runs" if p.kind == "run" else "references"
                    _write_group(f, f"{group}/{p.key}", {**p.attrs, "committed_at": now_iso()}, p.arrays)
                session = {**self.session, "computed": int(self.session.get("computed", 0)) + n_runs,
                           "updated": now_iso()}
                history = list(self.prior_history) + [session]
                f.attrs["history"] = _encode_attr("history", history)
                f.attrs["updated"] = now_iso()
                f.attrs["n_runs_complete"] = len(f["runs"])  # all groups here are complete
            _fsync_path(tmp)
            os.replace(tmp, self.path)
            _fsync_path(self.path.parent, directory=True)
        except OSError as e:  # disk full, permissions, ...: the live file is still the previous commit
            with contextlib.suppress(OSError):
                tmp.unlink()
            raise StorageError(f"{self.path}: cannot write results ({' '.join(str(e).split())}); the file still "
                               "holds every run committed before this error") from e
        except BaseException:
            with contextlib.suppress(OSError):
                tmp.unlink()
            raise
        self.session = session
        for p in self._pending:
            store = self.complete_runs if p.kind == "run" else self.references
            store[p.key] = dict(p.attrs)
        self._pending.clear()
        self._deletions.clear()
        self._fresh = False
        self._last_commit = time.monotonic()
        self._last_cost = self._last_commit - t0
        self.n_commits += 1

    def finish(self, status: str) -> None:
        """Commit what is queued and record how this session ended ('complete', 'interrupted', ...)."""
        self.session["status"] = status
        self.session["finished"] = now_iso()
        self.commit(force_write=True)

    def close(self) -> None:
        try:
            if self._pending and self._lock_fd is not None:
                self.commit()
        finally:
            with contextlib.suppress(FileNotFoundError):
                self.tmp_path.unlink()
            self._release_lock()


# --- readers ----------------------------------------------------------------------------------------
@dataclass
class RunInfo:
    """Attributes of one complete run group (arrays stay on disk; see `load_trajectory`)."""
    run_id: str
    attrs: dict

    def __getattr__(self, name):
        try:
            return self.__dict__["attrs"][name]
        except KeyError:
            raise AttributeError(name) from None

    @property
    def beta_or_none(self):
        b = self.attrs.get("beta")
        return None if b is None or not np.isfinite(b) else float(b)


@dataclass
class Results:
    path: Path
    attrs: dict
    runs: list[RunInfo]
    references: dict[str, dict]
    incomplete: list[str] = field(default_factory=list)

    @property
    def name(self) -> str:
        return str(self.attrs.get("name") or self.path.stem)


def _open_read(path) -> h5py.File:
    path = Path(path)
    if not path.exists():
        raise StorageError(f"{path}: file not found")
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise StorageError(f"{path}: not a readable HDF5 file ({' '.join(str(e).split())})") from None
    fmt = _decode_attr("format", f.attrs.get("format", ""))
    if fmt != FORMAT:
        f.close()
        raise StorageError(f"{path}: not a vcirun sweep results file (format {fmt!r})")
    return f


def read_results(path) -> Results:
    """Root attributes, complete runs (attributes only) and references of a results file."""
    with _open_read(path) as f:
        attrs = decode_attrs(f.attrs)
        runs, incomplete = [], []
        for name, g in f.get("runs", {}).items():
            if bool(g.attrs.get("complete", False)):
                runs.append(RunInfo(name, decode_attrs(g.attrs)))
            else:
                incomplete.append(f"runs/{name}")
        refs = {}
        for name, g in f.get("references", {}).items():
            if bool(g.attrs.get("complete", False)):
                refs[name] = decode_attrs(g.attrs)
            else:
                incomplete.append(f"references/{name}")
    # config order: method, then h, then initial condition
    ic_order = {k: i for i, k in enumerate(attrs.get("ic_keys") or [])}
    h_order = {float(h): i for i, h in enumerate(attrs.get("h_values") or [])}
    runs.sort(key=lambda r: (r.attrs.get("method_index", 0), h_order.get(float(r.attrs.get("h", 0.0)), 0),
                             ic_order.get(r.attrs.get("ic_key"), 0), r.run_id))
    return Results(Path(path), attrs, runs, refs, incomplete)


def load_trajectory(path, run_id: str):
    with _open_read(path) as f:
        if f"runs/{run_id}" not in f:
            raise StorageError(f"{path}: no run {run_id!r}")
        return trajectory_from_group(f[f"runs/{run_id}"])


def load_reference(path, key: str) -> dict:
    """A stored reference: {'attrs': ..., 't', 'q', 'p', 'impacts'} (arrays that exist)."""
    with _open_read(path) as f:
        if f"references/{key}" not in f:
            raise StorageError(f"{path}: no reference {key!r}")
        g = f[f"references/{key}"]
        out = {name: g[name][()] for name in g}
        out["attrs"] = decode_attrs(g.attrs)
        return out


def find_newest_results(directory="results") -> Path:
    d = Path(directory)
    files = [p for p in d.rglob("*.h5") if not p.name.startswith(".")] if d.is_dir() else []
    if not files:
        raise StorageError(f"no results (*.h5) under {d}/; run `vcirun sweep CONFIG` first or name a file")
    return max(files, key=lambda p: p.stat().st_mtime)
