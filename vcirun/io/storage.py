"""One HDF5 file per sweep, readable with plain h5py (layout: docs/results_schema.md).

Safety model (issue 22: bounded loss at a constant commit cost).

- The sweep's client process is the only writer (an flock on a hidden `.NAME.lock` sibling).
- A commit appends the finished runs to a journal beside the file (`.NAME.journal`) and fsyncs it:
  its cost is that of the new runs, independent of the file's size. Every record is framed (magic,
  length, CRC-32), so a kill in the middle of an append leaves a torn tail that readers ignore:
  everything before it is committed. Commits come every `commit_interval` seconds (default 1 s; a
  background thread commits while the client waits for results), so a SIGKILL at any moment loses at
  most the runs that reached the client in the last commit_interval plus one commit's duration.
- The HDF5 file is never written in place. A rewrite copies it to a hidden `.NAME.partial` sibling,
  applies the journal (and deletions) there, flushes, fsyncs and atomically renames it over the
  original (`os.replace`): a kill leaves either the previous or the next complete file. Rewrites
  happen when a session starts (recording it, and applying the journal a killed session left) and
  when it finishes ("compaction": the journal is folded in and removed). Writing HDF5 in place, even
  with a flush per run, is not enough: a kill inside its metadata write can leave a file that no
  longer opens (reproduced while designing the first version of this module).
- The file names the journal that extends it (root attribute `journal`, a random token that the
  journal's first record repeats); a journal with another token is stale (its records are already
  in the file, or belong to a file since replaced) and is ignored, then removed.
- `read_results`, `load_trajectory` and `load_reference` read the journal too, so a killed sweep's
  committed runs are visible at once; plain h5py sees them after the next `vcirun sweep` of the same
  config (which compacts first).
- Resume trusts only what it verifies: a run group counts as stored when `complete=True` was written
  last AND its datasets exist with the shapes its attributes declare (`run_problem`); anything else is
  deleted and recomputed. Missing `runs`/`references` groups are recreated (references recomputed).
- Disk full and other OS errors: one `StorageError` naming the path; a failed rewrite removes its
  partial copy, a failed append truncates the journal back to its last complete record; nothing
  committed is lost and the same command resumes. A rewrite first checks the free space it needs.
- The output may be a symlink: writes go to its target (the link keeps pointing at the results).
"""
from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import json
import os
import platform
import re
import shutil
import struct
import subprocess
import threading
import time
import uuid
import zlib
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path

import h5py
import numpy as np

from ..core import record
# the run-group codec is the Python API's (Trajectory.save writes the same group); re-exported here
from ..run.trajectory_files import (IMPACT_ARRAYS, TRAJECTORY_ARRAYS, _decode_attr, _encode_attr, _group_attrs, _write_encoded, _write_group, decode_attrs, trajectory_payload)
from ..run.trajectory import trajectory_from_group  # noqa: F401  (re-exported)

__all__ = ["FORMAT", "SCHEMA_VERSION", "StorageError", "ResultsWriter", "RunInfo", "Results", "read_results",
           "load_trajectory", "load_reference", "trajectory_payload", "trajectory_from_group",
           "environment_attrs", "find_newest_results", "run_problem", "reference_problem", "journal_path",
           "read_journal", "run_isolated"]

FORMAT = "vcirun-sweep"
SCHEMA_VERSION = 1
LIBVER = "latest"
DEFAULT_COMMIT_INTERVAL = 1.0  # seconds between journal commits (the loss bound of a hard kill)

class StorageError(RuntimeError):
    """A results file that cannot be used (unreadable, foreign, written by another config, locked,
    damaged, or a write that failed: disk full, read-only, ...); one line naming the path."""


def now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _os_text(e: BaseException) -> str:
    """The OS reason of an error in one line (strerror when there is one)."""
    text = getattr(e, "strerror", None) or str(e)
    return " ".join(str(text).split()) or type(e).__name__


# --- what a complete group must hold (resume trusts only what it verifies) ----------------------------
_NUMERIC_KINDS = "biuf"


def _shape_of(g, name):
    """Shape of dataset `name` of a group (None if absent; text if it is not a numeric array). HDF5
    groups are read with the low-level API: a third of the high-level cost, which counts when a resume
    verifies thousands of runs."""
    if isinstance(g, h5py.Group):
        key = name.encode()
        try:
            if not g.id.links.exists(key):
                return None
            d = h5py.h5o.open(g.id, key)
            if h5py.h5i.get_type(d) != h5py.h5i.DATASET:
                return "not an array"
        except (KeyError, ValueError, RuntimeError, OSError):
            return "unreadable"
        return tuple(d.shape) if d.dtype.kind in _NUMERIC_KINDS else "not numeric"
    d = g.get(name) if hasattr(g, "get") else None
    if d is None:
        return None
    if not isinstance(d, (h5py.Dataset, np.ndarray)):
        return "not an array"
    if d.dtype.kind not in _NUMERIC_KINDS:
        return "not numeric"
    return tuple(d.shape)


def _int_attr(a: dict, key: str):
    v = a.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v != int(v) or v < 0:
        return None
    return int(v)


def run_problem(g, attrs: dict | None = None) -> str | None:
    """Why a run group marked complete cannot be trusted (missing datasets, wrong shapes, unusable
    attributes), or None. The declared sizes are its attributes (`attrs`: decoded already, or read
    here): n_steps, n_impacts, n_partial_steps, has_trajectory, has_Hmod, and n from q0 (or impact_q)."""
    try:
        a = decode_attrs(g.attrs) if attrs is None else attrs
    except Exception as e:  # noqa: BLE001 - unreadable attributes
        return f"attributes unreadable ({type(e).__name__})"
    h = a.get("h")
    if isinstance(h, bool) or not isinstance(h, (int, float)) or not (np.isfinite(h) and h > 0):
        return "attribute h missing or not a positive number"
    status = a.get("status")
    if not isinstance(status, str) or not status:
        return "attribute status missing"
    if status == "error":
        return None  # a run that raised stores no arrays
    N, m = _int_attr(a, "n_steps"), _int_attr(a, "n_impacts")
    if N is None or m is None:
        return "attributes n_steps / n_impacts missing or not counts"
    q0 = a.get("q0")
    n = len(q0) if isinstance(q0, list) else None
    iq = _shape_of(g, "impact_q")
    if n is None and isinstance(iq, tuple) and len(iq) == 2:
        n = iq[1]
    if n is None or n < 1:
        return "cannot tell the number of coordinates (no q0 attribute nor impact_q dataset)"
    k = _int_attr(a, "n_partial_steps")
    # n_releases and n_contacts came with held contacts (issue 18): absent in older files, whose
    # release rows and per-contact rows are then not checked
    size = {"grid": N + 1, "step": N, "impact": m, "partial": k, "release": _int_attr(a, "n_releases")}
    mc = _int_attr(a, "n_contacts")
    want = {"t": ((N + 1,), True)} if a.get("has_trajectory") is True else {}
    for f in record.FIELDS:  # each stored row of the run record, at its declared length
        if f.stored == "no" or (f.stored == "trajectory" and a.get("has_trajectory") is not True) \
                or (f.only == "modified" and a.get("has_Hmod") is not True) or size[f.axis] is None \
                or (f.contacts and mc is None):
            continue
        want[f.name] = (f.shape(size[f.axis], n, mc or 0), f.name in _ALWAYS_WRITTEN)
    for name, (shape, required) in want.items():
        got = _shape_of(g, name)
        if got is None and not required:
            continue  # a row added to the record after this file was written
        if got != shape:
            return (f"dataset {name} missing" if got is None else
                    f"dataset {name} is {got}" if isinstance(got, str) else
                    f"dataset {name} has shape {got}, expected {shape}")
    return None


# rows every version of the schema wrote: a run without one of them is damaged; later rows (e.g.
# impact_impulse) are checked when present
_ALWAYS_WRITTEN = {"t", "q", "p", "H", "Ed", "Hmod", "impact_step", "newton_iters", "impacts", "impact_q",
                   "impact_p_minus", "impact_p_plus", "partial_steps"}


def reference_problem(g, attrs: dict | None = None) -> str | None:
    """Why a reference group marked complete cannot be trusted, or None."""
    try:
        a = decode_attrs(g.attrs) if attrs is None else attrs
    except Exception as e:  # noqa: BLE001
        return f"attributes unreadable ({type(e).__name__})"
    if a.get("status") != "ok":
        return None if isinstance(a.get("status"), str) else "attribute status missing"
    t, q, imp = _shape_of(g, "t"), _shape_of(g, "q"), _shape_of(g, "impacts")
    if not (isinstance(t, tuple) and len(t) == 1 and t[0] >= 1):
        return "dataset t missing or not a grid"
    if not (isinstance(q, tuple) and len(q) == 2 and q[0] == t[0]):
        return f"dataset q has shape {q}, expected ({t[0]}, n)"
    if not (isinstance(imp, tuple) and len(imp) == 1):
        return "dataset impacts missing"
    p = _shape_of(g, "p")
    if p is not None and p != q:
        return f"dataset p has shape {p}, expected {q}"
    return None


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


# --- journal ------------------------------------------------------------------------------------------
# A record: b"VJR1", u64 payload length, u32 CRC-32 of the payload, payload. The payload is a u32
# header length, the header (JSON: kind, key, encoded attributes, array table) and the arrays' bytes.
# Arrays are numeric only (dtype.str of kinds b/i/u/f), so reading a journal never unpickles anything.
_MAGIC = b"VJR1"
_REC = struct.Struct("<4sQI")
_HDR = struct.Struct("<I")
_MAX_HEADER = 64 * 2**20


def journal_path(path) -> Path:
    p = Path(path)
    return p.with_name(f".{p.name}.journal")


def _jsonable_attr(v):
    if isinstance(v, np.ndarray):
        return {"__ndarray__": v.dtype.str, "shape": list(v.shape), "data": v.ravel().tolist()}
    if isinstance(v, np.generic):
        return v.item()
    return v


def _attr_from_json(v):
    if isinstance(v, dict) and "__ndarray__" in v:
        dt = np.dtype(v["__ndarray__"])
        if dt.kind not in _NUMERIC_KINDS:
            raise ValueError("non-numeric array attribute")
        return np.asarray(v["data"], dtype=dt).reshape(v["shape"])
    return v


def _record_pieces(kind: str, key: str, enc_attrs: dict | None = None, arrays=(), extra: dict | None = None):
    """(list of byte pieces, total length) of one record; array bytes are not copied."""
    table, blobs, off = [], [], 0
    for name, value in arrays:
        a = np.ascontiguousarray(value)
        if a.dtype.kind not in _NUMERIC_KINDS:
            a = a.astype(float)
        mv = memoryview(a).cast("B") if a.size else memoryview(b"")
        table.append([name, a.dtype.str, list(a.shape), off, mv.nbytes])
        blobs.append(mv)
        off += mv.nbytes
    header = {"kind": kind, "key": key, "arrays": table, **(extra or {})}
    if enc_attrs is not None:
        header["attrs"] = {k: _jsonable_attr(v) for k, v in enc_attrs.items()}
    hb = json.dumps(header, allow_nan=True).encode()
    payload = [_HDR.pack(len(hb)), hb, *blobs]
    crc = 0
    for piece in payload:
        crc = zlib.crc32(piece, crc)
    length = _HDR.size + len(hb) + off
    return [_REC.pack(_MAGIC, length, crc), *payload], _REC.size + length


@dataclass
class JournalRecord:
    kind: str              # "open" | "run" | "reference" | "delete" | "session"
    key: str
    header: dict
    blob_offset: int       # where the arrays start in the journal file
    end: int               # offset just past this record

    def attrs(self) -> dict:
        return {k: _attr_from_json(v) for k, v in (self.header.get("attrs") or {}).items()}

    def arrays(self, fh) -> list:
        """(name, array) pairs, read from the open journal file `fh`."""
        out = []
        for name, dtype, shape, off, nbytes in self.header.get("arrays", []):
            dt = np.dtype(dtype)
            if dt.kind not in _NUMERIC_KINDS:
                raise ValueError(f"journal array {name}: non-numeric dtype {dtype}")
            fh.seek(self.blob_offset + off)
            buf = fh.read(nbytes)
            if len(buf) != nbytes:
                raise ValueError(f"journal array {name}: truncated")
            out.append((name, np.frombuffer(buf, dtype=dt).reshape(shape).copy()))
        return out


@dataclass
class Journal:
    path: Path
    token: str = ""
    config_key: str = ""
    records: list = field(default_factory=list)  # after the "open" record, in order
    good_end: int = 0     # offset past the last complete record
    torn: bool = False    # bytes after good_end (a kill or a disk-full in the middle of an append)
    applied: int = 0      # records ending at or before this offset are in the file already (see `after`)

    def after(self, offset: int) -> "Journal":
        """The records the file does not hold yet: those ending past `offset` (its `journal_applied`)."""
        if not offset:
            return self
        return Journal(self.path, self.token, self.config_key, [r for r in self.records if r.end > offset],
                       self.good_end, self.torn, max(self.applied, int(offset)))

    @property
    def new_bytes(self) -> int:
        return max(0, self.good_end - self.applied)


def read_journal(path, *, verify: bool = True) -> Journal | None:
    """The complete records of a journal file (None if there is none or it does not start with an
    "open" record). Stops at the first record that is truncated or fails its CRC: what follows was
    never committed."""
    jp = Path(path)
    try:
        fh = open(jp, "rb")
    except FileNotFoundError:
        return None
    except OSError as e:
        raise StorageError(f"{jp}: cannot read the journal ({_os_text(e)})") from None
    with fh:
        size = os.fstat(fh.fileno()).st_size
        j = Journal(jp)
        pos = 0
        while pos + _REC.size <= size:
            fh.seek(pos)
            magic, length, crc = _REC.unpack(fh.read(_REC.size))
            if magic != _MAGIC or pos + _REC.size + length > size or length < _HDR.size:
                break
            (hlen,) = _HDR.unpack(fh.read(_HDR.size))
            if hlen > min(length - _HDR.size, _MAX_HEADER):
                break
            hb = fh.read(hlen)
            c = zlib.crc32(_HDR.pack(hlen))
            c = zlib.crc32(hb, c)
            remaining = length - _HDR.size - hlen
            blob_offset = fh.tell()
            if verify:
                while remaining > 0:
                    chunk = fh.read(min(remaining, 1 << 20))
                    if not chunk:
                        break
                    c = zlib.crc32(chunk, c)
                    remaining -= len(chunk)
                if remaining or c != crc:
                    break
            try:
                header = json.loads(hb)
                kind, key = str(header["kind"]), str(header.get("key", ""))
            except (ValueError, KeyError, TypeError):
                break
            end = pos + _REC.size + length
            if not j.records and kind != "open" and not j.token:
                return None  # not a journal of ours
            if kind == "open":
                if j.token:
                    break  # a second open record: not a journal this module wrote
                j.token, j.config_key = str(header.get("token", "")), str(header.get("config_key", ""))
            else:
                j.records.append(JournalRecord(kind, key, header, blob_offset, end))
            j.good_end = end
            pos = end
        if not j.token:
            return None
        j.torn = j.good_end < size
        return j


def _overlay(journal: Journal | None, runs: dict, refs: dict, attrs: dict | None = None) -> int:
    """Apply a journal's records to {run_id: (source, attrs)} / {key: (source, attrs)} maps (source is
    a JournalRecord); returns how many runs the journal adds."""
    if journal is None:
        return 0
    added = 0
    for r in journal.records:
        if r.kind in ("run", "reference"):
            (runs if r.kind == "run" else refs)[r.key] = (r, decode_attrs(r.attrs()))
            added += r.kind == "run"
        elif r.kind == "delete":
            group, _, name = r.key.partition("/")
            (runs if group == "runs" else refs).pop(name, None)
        elif r.kind == "session" and attrs is not None:
            attrs["history"] = r.header.get("history") or attrs.get("history")
            attrs["updated"] = r.header.get("updated", attrs.get("updated"))
    return added


class _MemGroup:
    """A journal record seen like an h5py group (what trajectory_from_group and the checks read)."""

    def __init__(self, enc_attrs: dict, arrays: list):
        self.attrs = enc_attrs
        self._d = dict(arrays)

    def __contains__(self, name):
        return name in self._d

    def __getitem__(self, name):
        return self._d[name]

    def get(self, name, default=None):
        return self._d.get(name, default)

    def __iter__(self):
        return iter(self._d)


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


def _reserve(path: Path, nbytes: int) -> None:
    """Allocate the file's blocks up to nbytes (HDF5 writes into them and truncates the file to its end
    of allocation on close), so that a full disk is met here with ENOSPC, before the HDF5 library runs:
    HDF5 under ENOSPC prints errors from deallocators and can crash the process."""
    if not hasattr(os, "posix_fallocate"):
        return
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        os.posix_fallocate(fd, 0, max(int(nbytes), 1))
    except OSError as e:
        if e.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
            raise
        # EOPNOTSUPP, EINVAL (file systems without fallocate): no reservation, HDF5 errors still caught
    finally:
        os.close(fd)


class _ChildFailed(RuntimeError):
    def __init__(self, text: str, errno_: int | None = None, io_failure: bool = False):
        super().__init__(text)
        self.errno = errno_
        self.io_failure = io_failure  # an OSError in the child, or a crash: the write failed, not the file


def _child_setup(keep_fd: int, background: bool = False) -> None:
    """A forked HDF5 writer: dies with its parent, prints nothing (the parent reports), no crash dump,
    and holds none of the parent's descriptors but `keep_fd` (copies of sockets, e.g. a Dask client's,
    would keep connections open that the parent closes); in the background also deaf to Ctrl-C (the
    parent stops it). (Not niced: on a busy machine a niced compactor starved, and the final
    compaction then had everything to do.)"""
    with contextlib.suppress(Exception):
        import faulthandler

        faulthandler.disable()
    with contextlib.suppress(Exception):
        import ctypes

        ctypes.CDLL(None).prctl(1, 9)  # PR_SET_PDEATHSIG, SIGKILL
    devnull = os.open(os.devnull, os.O_RDWR)
    for fd in (0, 1, 2):
        os.dup2(devnull, fd)
    os.closerange(3, keep_fd)  # (devnull among them: 0, 1, 2 are copies of it now)
    os.closerange(keep_fd + 1, _max_fd())
    if background:
        import signal

        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_IGN)


def _max_fd() -> int:
    try:
        return int(min(os.sysconf("SC_OPEN_MAX"), 1 << 20))
    except (ValueError, OSError):
        return 4096


def _in_child(fn, tmp: Path) -> None:
    """Run fn (the HDF5 writes of a rewrite) in a forked child: whatever the HDF5 library does when a
    write fails (tracebacks printed from deallocators, a crash after ENOSPC), this process only learns
    that the copy could not be written. The child dies with this process (PR_SET_PDEATHSIG)."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # child: no atexit handlers, no stdio flushes, stderr silenced
        code = 0
        try:
            os.close(r)
            _child_setup(w)
            fn()
        except BaseException as e:  # noqa: BLE001 - reported to the parent
            code = 1
            with contextlib.suppress(BaseException):
                os.write(w, json.dumps({"type": type(e).__name__, "errno": getattr(e, "errno", None),
                                        "text": _one_line(e, 400), "storage": isinstance(e, StorageError)}).encode())
        finally:
            os._exit(code)
    os.close(w)
    chunks = []
    try:
        while True:
            b = os.read(r, 65536)
            if not b:
                break
            chunks.append(b)
    finally:
        os.close(r)
        _, status = os.waitpid(pid, 0)
    if os.WIFSIGNALED(status):
        raise _ChildFailed(f"the HDF5 library crashed (signal {os.WTERMSIG(status)}) while writing {tmp.name}",
                           io_failure=True)
    if os.WEXITSTATUS(status) != 0:
        try:
            info = json.loads(b"".join(chunks) or b"{}")
        except ValueError:
            info = {}
        text = info.get("text") or f"the writer exited with status {os.WEXITSTATUS(status)}"
        if info.get("storage"):
            raise StorageError(text)
        raise _ChildFailed(text, info.get("errno"), io_failure=info.get("type") in ("OSError", "FileNotFoundError",
                                                                               "PermissionError"))


def run_isolated(fn, path: Path, *, isolate: bool = True) -> None:
    """fn() (HDF5 writes that replace `path` atomically) in a forked child where fork exists and
    `isolate`; its failure is raised here (StorageError as such, anything else as RuntimeError), a
    crash as RuntimeError naming the signal."""
    if isolate and hasattr(os, "fork"):
        _in_child(fn, Path(path))
    else:
        fn()


def _write_all(fd: int, pieces) -> None:
    for piece in pieces:
        mv = memoryview(piece)
        while mv.nbytes:
            n = os.write(fd, mv)
            mv = mv[n:]


@dataclass
class _Pending:
    kind: str  # "run" | "reference"
    key: str
    attrs: dict
    arrays: dict


def _resolve_output(path) -> Path:
    """The path to write: a symlink's target (the link then keeps pointing at the results), checked
    for the usual mistakes with a one-line message."""
    if "\x00" in str(path):
        raise StorageError(f"{str(path)!r}: a path cannot contain a NUL character; choose another --output")
    try:
        return _resolve_checked(Path(path), path)
    except OSError as e:  # a name too long, a component without permission, ...
        raise StorageError(f"{path}: cannot use this path ({_os_text(e)}); choose another --output") from None


def _resolve_checked(p: Path, path) -> Path:
    if p.is_symlink():
        try:
            p = Path(os.path.realpath(p, strict=False))
        except (OSError, RuntimeError) as e:
            raise StorageError(f"{path}: cannot follow the symbolic link ({_os_text(e)}); choose another "
                               "--output") from None
        if p.is_symlink():  # a loop realpath gave up on
            raise StorageError(f"{path}: symbolic link loop; choose another --output")
        if not p.parent.is_dir():  # a dangling link: write where it points, but create no directories there
            raise StorageError(f"{path}: symbolic link to {p}, whose directory does not exist; create it or "
                               "choose another --output")
    if p.is_dir():
        raise StorageError(f"{p}: is a directory; give a file path such as {p / 'results.h5'}")
    if p.exists() and not p.is_file():
        raise StorageError(f"{p}: not a regular file; choose another --output")
    for parent in p.parents:
        if parent.exists():
            if not parent.is_dir():
                raise StorageError(f"{p}: {parent} is a file, not a directory; choose another --output")
            break
    return p


class ResultsWriter:
    """The single writer of one sweep's results file. Use as a context manager.

    `acquire()` takes the lock and checks an existing file (format; written by the same configuration:
    `config_key`; groups verified, see `run_problem`), collecting its runs and references, the runs a
    killed session left in the journal included; with `force` it starts a new file instead. `start()`
    rewrites the file once (this session in its history, the old journal folded in, damaged groups
    dropped) and opens a new journal. `add_run`/`add_reference` queue results; `commit()` appends the
    queue to the journal (before `start`: rewrites the file); `maybe_commit()` does so when
    `commit_interval` seconds have passed since the last commit; `start_autocommit()` runs that check on
    a thread. `finish(status)` commits, then compacts the journal into the file. Thread-safe.
    """

    def __init__(self, path, *, root_attrs: dict, config_key: str, force: bool = False,
                 commit_interval: float | None = None, session: dict | None = None, min_interval=None,
                 isolate: bool = True):
        self.requested_path = Path(path)
        self.path = _resolve_output(path)
        self.root_attrs = dict(root_attrs)
        self.config_key = config_key
        self.force = force
        interval = commit_interval if commit_interval is not None else min_interval
        if interval is None:
            interval = float(os.environ.get("VCIRUN_COMMIT_INTERVAL", DEFAULT_COMMIT_INTERVAL))
        self.commit_interval = max(0.0, float(interval))
        self.isolate = isolate  # HDF5 rewrites in a forked child (see _in_child); False: in this process
        self.session = dict(session or {})
        self.session.setdefault("started", now_iso())
        self.session.setdefault("status", "running")
        self.session.setdefault("computed", 0)
        self.complete_runs: dict[str, dict] = {}
        self.references: dict[str, dict] = {}
        self.incomplete: list[str] = []
        self.damaged: dict[str, str] = {}   # group path -> why it is not trusted
        self.prior_history: list = []
        self.n_commits = 0
        self.commit_times: list[float] = []  # seconds per journal commit (for the loss bound)
        self.final_hooks: list = []          # callables f(h5py.File) run inside a complete sweep's last rewrite
        self._pending: list[_Pending] = []
        self._pending_bytes = 0
        self._deletions: list[str] = []
        self._last_commit = time.monotonic()
        self._lock_fd = None
        self._fresh = force
        self._old_journal: Journal | None = None
        self._jfd: int | None = None         # this session's journal (after start)
        self._jend = 0
        self._token = ""
        self._failed: StorageError | None = None  # a write failed: no further HDF5 writes this session
        self._mutex = threading.RLock()
        self._auto: threading.Thread | None = None
        self._auto_stop = threading.Event()
        self._auto_error: BaseException | None = None
        self._made_dirs: list[Path] = []
        self._compactor: tuple | None = None  # (pid, pipe) of the background compaction child
        self._journal_base = 0                # journal offset past its open record
        self.compaction_rounds = 0            # (counted in the child; for tests that run it in-process)

    # the temporary copy lives next to the file so that os.replace stays on one filesystem
    @property
    def tmp_path(self) -> Path:
        return self.path.with_name(f".{self.path.name}.partial")

    @property
    def lock_path(self) -> Path:
        return self.path.with_name(f".{self.path.name}.lock")

    @property
    def journal_path(self) -> Path:
        return journal_path(self.path)

    @property
    def failed(self) -> bool:
        """A write failed this session (disk full, ...): nothing more is written."""
        return self._failed is not None

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def _where(self, e: BaseException, doing: str) -> StorageError:
        extra = ""
        if isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
            extra = "; free some space (or choose another --output)"
        elif isinstance(e, OSError) and e.errno in (errno.EROFS, errno.EACCES, errno.EPERM):
            extra = "; choose a writable --output"
        return StorageError(f"{self.path}: cannot {doing} ({_os_text(e)}){extra}")

    # -- lock ------------------------------------------------------------------------------------------
    def _acquire_lock(self) -> None:
        parent = self.path.parent
        missing = [d for d in [parent, *parent.parents] if not d.exists()]
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise StorageError(f"{self.path}: cannot create the directory {parent} ({_os_text(e)}); choose "
                               "another --output") from None
        self._made_dirs = list(missing)  # removed again if this session ends without writing anything
        try:
            import fcntl
        except ImportError:  # pragma: no cover - non-POSIX: no guard against two concurrent writers
            return
        try:
            fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            self._remove_made_dirs()
            raise StorageError(f"{self.path}: cannot write in {parent} ({_os_text(e)}); choose a writable "
                               "--output") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            os.close(fd)
            if e.errno in (errno.EAGAIN, errno.EACCES):
                raise StorageError(f"{self.path}: another vcirun sweep is writing this file; wait for it or "
                                   "choose another --output") from None
            raise StorageError(f"{self.path}: cannot lock {self.lock_path} ({_os_text(e)})") from None
        try:  # the lock file we hold must still be the one at lock_path (a releasing writer unlinks it)
            same = os.fstat(fd).st_ino == os.stat(self.lock_path).st_ino
        except OSError:
            same = False
        if not same:
            os.close(fd)
            raise StorageError(f"{self.path}: another vcirun sweep is starting or stopping on this file; "
                               "retry in a moment")
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        self._lock_fd = fd

    def _remove_made_dirs(self) -> None:
        for d in self._made_dirs:  # innermost first
            with contextlib.suppress(OSError):
                d.rmdir()
        self._made_dirs = []

    def _release_lock(self) -> None:
        if self._lock_fd is not None:
            with contextlib.suppress(OSError):
                os.unlink(self.lock_path)
            os.close(self._lock_fd)
            self._lock_fd = None
            if not self.path.exists():
                self._remove_made_dirs()

    # -- opening ---------------------------------------------------------------------------------------
    def acquire(self) -> "ResultsWriter":
        """Take the writer lock and read what an existing file already holds (nothing is written)."""
        self._acquire_lock()
        try:
            summary_tmp = self.path.with_name(f".{self.path.name}.summary-partial")  # (experiments.summary)
            for leftover in (self.tmp_path, self.compact_path, summary_tmp):  # of a rewrite killed before its rename
                with contextlib.suppress(FileNotFoundError):
                    leftover.unlink()
            self._fresh = self.force or not self.path.exists()
            if not self._fresh:
                self._read_existing()
        except BaseException:
            self._release_lock()
            raise
        return self

    def start(self) -> None:
        """Rewrite the file once (this session recorded, a killed session's journal folded in, damaged
        groups dropped), then open this session's journal."""
        if self._fresh:
            self.root_attrs.setdefault("created", now_iso())
        else:
            self.root_attrs.pop("created", None)  # keep the original creation time
        token = uuid.uuid4().hex
        self._rewrite(new_token=token)
        self._open_journal(token)

    def open(self) -> "ResultsWriter":
        self.acquire()
        try:
            self.start()
        except BaseException:
            self._release_lock()
            raise
        return self

    def has_changes(self) -> bool:
        return bool(self._pending or self._deletions or self._old_journal)

    def _read_existing(self) -> None:
        try:
            f = h5py.File(self.path, "r")
        except Exception as e:  # noqa: BLE001 - OSError, or anything a damaged superblock raises
            raise StorageError(f"{self.path}: not a readable HDF5 file ({_one_line(e)}); move it away "
                               "or rerun with --force to start over") from None
        try:
            with f:
                self._read_groups(f)
        except StorageError:
            raise
        except Exception as e:  # noqa: BLE001 - damaged metadata deeper in the file
            raise StorageError(f"{self.path}: damaged results file ({type(e).__name__}: {_one_line(e)}); move "
                               "it away or rerun with --force to start over") from None
        self._deletions.extend(self.incomplete)

    def _read_groups(self, f) -> None:
        fmt = _decode_attr("format", f.attrs.get("format", ""))
        if fmt != FORMAT:
            raise StorageError(f"{self.path}: not a vcirun sweep file (format {_short(fmt)}); choose another "
                               "--output or rerun with --force to overwrite it")
        key = _decode_attr("config_key", f.attrs.get("config_key", ""))
        if key != self.config_key:
            raise StorageError(f"{self.path}: written by a different configuration (config key {str(key)[:12]} "
                               f"!= {self.config_key[:12]}); rerun with --force to recompute everything, or "
                               "choose another --output")
        hist = _decode_attr("history", f.attrs.get("history", "[]"))
        self.prior_history = hist if isinstance(hist, list) else []
        for kind, group, store, check in (("run", "runs", self.complete_runs, run_problem),
                                          ("reference", "references", self.references, reference_problem)):
            if group not in f:
                continue  # recreated by the rewrite
            if not isinstance(f[group], h5py.Group):
                raise StorageError(f"{self.path}: damaged results file (/{group} is not a group); move it away "
                                   "or rerun with --force to start over")
            for name, g in f[group].items():
                a = decode_attrs(g.attrs) if isinstance(g, h5py.Group) else {}
                if not a.get("complete", False):
                    self.incomplete.append(f"{group}/{name}")
                    continue
                problem = check(g, a)
                if problem:
                    self.incomplete.append(f"{group}/{name}")
                    self.damaged[f"{group}/{name}"] = problem
                else:
                    store[name] = a
        # a killed session's journal: its runs count as stored (they were committed)
        j = read_journal(self.journal_path)
        expected = _decode_attr("journal", f.attrs.get("journal", ""))
        if j is not None and j.token and j.token == expected and j.config_key == self.config_key:
            j = j.after(_applied(f))
            self._old_journal = j
            sessions = [r for r in j.records if r.kind == "session"]
            if sessions and isinstance(sessions[-1].header.get("history"), list):
                self.prior_history = sessions[-1].header["history"]  # the killed session's own count
            runs = {k: (None, a) for k, a in self.complete_runs.items()}
            refs = {k: (None, a) for k, a in self.references.items()}
            _overlay(j, runs, refs)
            self.complete_runs = {k: a for k, (_, a) in runs.items()}
            self.references = {k: a for k, (_, a) in refs.items()}
            stale = {p for p in self.incomplete if p.partition("/")[2] in (runs if p.startswith("runs/") else refs)}
            self.incomplete = [p for p in self.incomplete if p not in stale or p in self.damaged]

    def forget_runs(self, run_ids) -> None:
        """Schedule runs for recomputation (e.g. --retry-failed): deleted at the next commit."""
        with self._mutex:
            for rid in run_ids:
                if self.complete_runs.pop(rid, None) is not None:
                    self._deletions.append(f"runs/{rid}")

    # -- queueing and committing ---------------------------------------------------------------------------
    def add_run(self, run_id: str, attrs: dict, arrays: dict) -> None:
        self._raise_auto_error()
        with self._mutex:
            self._pending.append(_Pending("run", run_id, attrs, arrays))
            self._pending_bytes += sum(int(np.asarray(a).nbytes) for a in arrays.values())

    def add_reference(self, key: str, attrs: dict, arrays: dict) -> None:
        with self._mutex:
            if key in self.references or any(p.kind == "reference" and p.key == key for p in self._pending):
                return  # computed once per initial condition and stored once
            self._pending.append(_Pending("reference", key, attrs, arrays))

    @property
    def n_pending(self) -> int:
        return len(self._pending)

    def maybe_commit(self) -> bool:
        """Commit if `commit_interval` has passed since the last commit (or the queue holds > 256 MB)."""
        self._raise_auto_error()
        with self._mutex:
            if not self._pending:
                return False
            if (time.monotonic() - self._last_commit >= self.commit_interval
                    or self._pending_bytes > 256 * 2**20):
                self.commit()
                return True
            return False

    def commit(self, *, force_write: bool = False) -> None:
        """Make the queued groups durable: appended to the journal (before `start`: a file rewrite)."""
        with self._mutex:
            if self._jfd is None:
                if self._pending or self._deletions or force_write:
                    self._rewrite(new_token=self._token)
                return
            if not (self._pending or self._deletions or force_write):
                return
            t0 = time.monotonic()
            n_runs = sum(p.kind == "run" for p in self._pending)
            session = {**self.session, "computed": int(self.session.get("computed", 0)) + n_runs,
                       "updated": now_iso()}
            pieces, total = [], 0
            stamp = now_iso()
            for path in self._deletions:
                pc, n = _record_pieces("delete", path)
                pieces += pc
                total += n
            for p in self._pending:
                enc = _group_attrs({**p.attrs, "committed_at": stamp})
                pc, n = _record_pieces(p.kind, p.key, enc, p.arrays.items())
                pieces += pc
                total += n
            pc, n = _record_pieces("session", "", extra={"history": list(self.prior_history) + [session],
                                                         "updated": stamp})
            pieces += pc
            total += n
            try:
                _write_all(self._jfd, pieces)
                os.fsync(self._jfd)
            except OSError as e:
                # a torn tail would be ignored by readers; cut it so the journal stays clean
                with contextlib.suppress(OSError):
                    os.ftruncate(self._jfd, self._jend)
                    os.lseek(self._jfd, self._jend, os.SEEK_SET)  # a retry appends right after it
                err = StorageError(f"{self.journal_path}: cannot write results ({_os_text(e)}); every run committed "
                                   f"before this error is kept ({len(self.complete_runs)} in {self.path} and its "
                                   "journal): free space and rerun the same command to resume")
                self._failed = err
                raise err from None
            self._jend += total
            self._failed = None
            self.session = session
            for p in self._pending:
                (self.complete_runs if p.kind == "run" else self.references)[p.key] = {**p.attrs,
                                                                                       "committed_at": stamp}
            self._pending.clear()
            self._pending_bytes = 0
            self._deletions.clear()
            self._last_commit = time.monotonic()
            self.commit_times.append(self._last_commit - t0)
            self.n_commits += 1

    # -- background commits ----------------------------------------------------------------------------------
    def start_autocommit(self) -> None:
        """Commit from a thread every commit_interval while the client waits for results (a result that
        arrives just after a commit would otherwise wait for the next arrival)."""
        if self._auto is not None or self._jfd is None:
            return
        self._auto_stop.clear()

        def loop():
            tick = max(0.05, min(self.commit_interval, 1.0) / 2)
            while not self._auto_stop.wait(tick):
                try:
                    self.maybe_commit()
                except BaseException as e:  # noqa: BLE001 - re-raised in the client's thread
                    self._auto_error = e
                    return

        self._auto = threading.Thread(target=loop, name="vcirun-commit", daemon=True)
        self._auto.start()

    def stop_autocommit(self) -> None:
        if self._auto is not None:
            self._auto_stop.set()
            self._auto.join()
            self._auto = None

    def _raise_auto_error(self) -> None:
        if self._auto_error is not None and threading.current_thread() is not self._auto:
            e, self._auto_error = self._auto_error, None
            raise e

    # -- journal and rewrite ------------------------------------------------------------------------------------
    def _open_journal(self, token: str) -> None:
        jp = self.journal_path
        try:
            fd = os.open(jp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            try:
                pieces, n = _record_pieces("open", "", extra={"token": token, "config_key": self.config_key,
                                                              "created": now_iso(), "pid": os.getpid()})
                _write_all(fd, pieces)
                os.fsync(fd)
            except BaseException:
                os.close(fd)
                raise
        except OSError as e:
            with contextlib.suppress(OSError):
                jp.unlink()
            # the file was rewritten and names this journal: without it the session cannot commit
            err = self._where(e, "create the journal " + jp.name)
            self._failed = err  # finish() must not try another rewrite on this (likely full) disk
            raise err from None
        _fsync_path(jp.parent, directory=True)
        self._jfd, self._jend, self._token, self._journal_base = fd, n, token, n

    def _close_journal(self) -> None:
        if self._jfd is not None:
            with contextlib.suppress(OSError):
                os.close(self._jfd)
            self._jfd = None

    def _space_needed(self, journals) -> int:
        size = self.path.stat().st_size if not self._fresh and self.path.exists() else 0
        extra = sum(j.new_bytes for j in journals if j is not None)
        extra += sum(sum(int(np.asarray(a).nbytes) for a in p.arrays.values()) for p in self._pending)
        return size + 2 * extra + 2**20  # the copy, what it gains (HDF5 overhead included), slack

    def _rewrite(self, *, new_token: str, journals=None, final_hooks=()) -> None:
        """Copy the file, apply journals, deletions and the queue to the copy, fsync it and rename it over
        the file. Never touches the live file; on any failure the copy is removed."""
        journals = [self._old_journal] if journals is None else journals
        journals = [j for j in journals if j is not None]
        t0 = time.monotonic()
        tmp = self.tmp_path
        fresh = self._fresh or not self.path.exists()
        need = self._space_needed(journals)
        with contextlib.suppress(OSError):
            free = shutil.disk_usage(self.path.parent).free
            if need > free:
                raise StorageError(f"{self.path}: not enough free space to write results (about "
                                   f"{_fmt_bytes(need)} needed, {_fmt_bytes(free)} free in {self.path.parent}); every "
                                   "committed run is kept: free space and rerun the same command to resume")
        n_runs = sum(p.kind == "run" for p in self._pending)
        session = {**self.session, "computed": int(self.session.get("computed", 0)) + n_runs, "updated": now_iso()}
        try:
            if not fresh:
                shutil.copyfile(self.path, tmp)
            if not fresh:  # (h5py's "w" would truncate a reservation away; a fresh file is small)
                _reserve(tmp, need)  # the space HDF5 writes into, taken now: a full disk fails here, cleanly
            write = lambda: self._write_copy(tmp, fresh, journals, session, new_token, final_hooks)  # noqa: E731
            if self.isolate and hasattr(os, "fork"):
                _in_child(write, tmp)
            else:
                write()
            _fsync_path(tmp)
            os.replace(tmp, self.path)
            _fsync_path(self.path.parent, directory=True)
        except StorageError:
            with contextlib.suppress(OSError):
                tmp.unlink()
            raise
        except BaseException as e:
            with contextlib.suppress(OSError):
                tmp.unlink()
            if isinstance(e, (OSError, RuntimeError, ValueError, KeyError)):
                # disk full, permissions, HDF5 errors: the live file still holds every committed run.
                # No further HDF5 write in this process (h5py's state after a failed write is suspect).
                if isinstance(e, OSError) or getattr(e, "io_failure", False) or "errno" in str(e):
                    err = StorageError(f"{self.path}: cannot write results ({_one_line(e)}); the file and its "
                                       "journal still hold every run committed before this error: fix the cause and "
                                       "rerun the same command to resume")
                else:  # HDF5 refused to update the copy: the file's own structures are damaged
                    err = StorageError(f"{self.path}: cannot update the results file ({_one_line(e)}); it looks "
                                       "damaged: move it away or rerun with --force to start over")
                self._failed = err
                raise err from e
            raise
        self._failed = None
        self.session = session
        for p in self._pending:
            (self.complete_runs if p.kind == "run" else self.references)[p.key] = dict(p.attrs)
        self._pending.clear()
        self._pending_bytes = 0
        self._deletions.clear()
        self._fresh = False
        self._last_commit = time.monotonic()
        self.n_commits += 1
        self._rewrite_seconds = self._last_commit - t0
        if self._old_journal is not None and self._old_journal in journals:
            self._old_journal = None
        if self._jfd is None:  # any journal beside the file is now applied or stale
            with contextlib.suppress(OSError):
                self.journal_path.unlink()

    def _write_copy(self, tmp: Path, fresh: bool, journals, session: dict, new_token: str, final_hooks) -> None:
        """The HDF5 part of a rewrite: everything that changes goes into the copy `tmp`."""
        with h5py.File(tmp, "w" if fresh else "a", libver=LIBVER) as f:
            if fresh:
                f.attrs["format"] = FORMAT
                f.attrs["schema_version"] = SCHEMA_VERSION
                f.attrs["config_key"] = self.config_key
            for group in ("runs", "references"):
                if group not in f:
                    f.create_group(group)  # a file that lost one gets it back
            for key, value in self.root_attrs.items():
                f.attrs[key] = _encode_attr(key, value)
            for path in self._deletions:
                if path in f:
                    del f[path]
            for j in journals:
                self._apply_journal(f, j)
            stamp = now_iso()
            for p in self._pending:
                group = "runs" if p.kind == "run" else "references"
                _write_group(f, f"{group}/{p.key}", {**p.attrs, "committed_at": stamp}, p.arrays)
            history = list(self.prior_history) + [session]
            f.attrs["history"] = _encode_attr("history", history)
            f.attrs["updated"] = now_iso()
            f.attrs["n_runs_complete"] = len(f["runs"])  # all groups here are complete
            f.attrs["journal"] = new_token
            f.attrs["journal_applied"] = 0  # a new journal (or none): nothing of it is in the file yet
            for hook in final_hooks:
                hook(f)

    def _apply_journal(self, f, j: Journal) -> None:
        try:
            fh = open(j.path, "rb")
        except OSError as e:
            raise self._where(e, f"read the journal {j.path.name}") from None
        with fh:
            for r in j.records:
                if r.kind in ("run", "reference"):
                    group = "runs" if r.kind == "run" else "references"
                    _write_encoded(f, f"{group}/{r.key}", r.attrs(), r.arrays(fh))
                elif r.kind == "delete" and r.key in f:
                    del f[r.key]

    # -- background compaction -------------------------------------------------------------------------------
    @property
    def compact_path(self) -> Path:
        return self.path.with_name(f".{self.path.name}.compacting")

    def start_background_compaction(self, min_interval: float = 10.0) -> None:
        """Fold the journal into the HDF5 file from a forked child while the sweep runs, so that plain h5py
        sees the runs committed up to a round ago and the final compaction only has the tail to do. Each
        round copies the file, applies the new records, records how far (`journal_applied`) and atomically
        replaces the file; rounds are at least `min_interval` and 4 round durations apart. The commits and the loss bound do not depend on it: a failed or killed
        round changes nothing (readers and resumes apply the journal past `journal_applied`)."""
        if self._compactor is not None or self._jfd is None or not (self.isolate and hasattr(os, "fork")):
            return
        r, w = os.pipe()
        pid = os.fork()
        if pid == 0:
            code = 0
            try:
                os.close(w)
                _child_setup(r, background=True)
                self._jfd = None  # (closed by _child_setup; the child reads the journal by its path)
                self._compact_loop(r, float(min_interval))
            except BaseException:  # noqa: BLE001 - the parent's final compaction does what is left
                code = 1
            finally:
                os._exit(code)
        os.close(r)
        self._compactor = (pid, w)

    def _compact_loop(self, stop_fd: int, min_interval: float) -> None:
        import select

        applied, interval = self._journal_base, min_interval
        while True:
            if select.select([stop_fd], [], [], interval)[0]:
                return  # the parent closed the pipe: stop between rounds
            j = read_journal(self.journal_path)
            if j is None or j.token != self._token:
                return
            new = j.after(applied)
            if not any(r.kind != "session" for r in new.records):
                continue
            t0 = time.monotonic()
            tmp = self.compact_path
            shutil.copyfile(self.path, tmp)
            _reserve(tmp, tmp.stat().st_size + 2 * new.new_bytes + 2**20)
            with h5py.File(tmp, "a", libver=LIBVER) as f:
                self._apply_journal(f, new)
                sessions = [r for r in new.records if r.kind == "session"]
                if sessions and isinstance(sessions[-1].header.get("history"), list):
                    f.attrs["history"] = _encode_attr("history", sessions[-1].header["history"])
                    f.attrs["updated"] = str(sessions[-1].header.get("updated", now_iso()))
                f.attrs["n_runs_complete"] = len(f["runs"])
                f.attrs["journal_applied"] = int(new.good_end)
            _fsync_path(tmp)
            os.replace(tmp, self.path)
            _fsync_path(self.path.parent, directory=True)
            applied = new.good_end
            self.compaction_rounds += 1
            interval = max(min_interval, 4.0 * (time.monotonic() - t0))

    def stop_background_compaction(self, grace: float = 120.0) -> None:
        """Ask the compactor to stop between rounds (a round under way is finished: its work is work the
        final compaction would do); one still running after `grace` s is abandoned (the file is then the
        previous round's, which is consistent)."""
        if self._compactor is None:
            return
        pid, w = self._compactor
        self._compactor = None
        with contextlib.suppress(OSError):
            os.close(w)
        deadline = time.monotonic() + grace
        while True:
            done, _ = os.waitpid(pid, os.WNOHANG)
            if done:
                break
            if time.monotonic() > deadline:
                with contextlib.suppress(OSError):
                    os.kill(pid, 9)
                os.waitpid(pid, 0)
                break
            time.sleep(0.02)
        with contextlib.suppress(OSError):
            self.compact_path.unlink()

    def _file_applied(self) -> int:
        try:
            with h5py.File(self.path, "r") as f:
                return _applied(f)
        except Exception:  # noqa: BLE001 - then the whole journal is applied (idempotent)
            return 0

    # -- finishing ------------------------------------------------------------------------------------------
    def finish(self, status: str, final_hooks=None) -> None:
        """Commit what is queued, record how this session ended ('complete', 'interrupted', ...) and
        compact: the journal is folded into the file and removed. `final_hooks` (default
        `self.final_hooks`) run inside that last rewrite, on the open file, when status is 'complete'.
        After a failed write nothing more is written (the file and journal keep every committed run)."""
        self.stop_autocommit()
        try:
            self._commit_before_waiting()
        finally:
            self.stop_background_compaction()
        with self._mutex:
            if self._failed is not None:
                return
            self.session["status"] = status
            self.session["finished"] = now_iso()
            hooks = list(self.final_hooks if final_hooks is None else final_hooks) if status == "complete" else []
            if self._jfd is None:
                self.commit(force_write=True)
                return
            self.commit(force_write=True)
            journal = read_journal(self.journal_path)
            if journal is None or journal.token != self._token:
                raise StorageError(f"{self.journal_path}: the journal of this session is missing or was replaced; "
                                   "rerun the same command to resume")
            # what a background compaction folded in already is skipped
            self._rewrite(new_token="", journals=[journal.after(self._file_applied())], final_hooks=hooks)
            self._close_journal()
            with contextlib.suppress(OSError):
                self.journal_path.unlink()
            _fsync_path(self.path.parent, directory=True)

    def _commit_before_waiting(self) -> None:
        """Append what is queued to the journal before waiting for a background compaction round to end:
        a round takes seconds (the whole file is copied), and the runs that reached the client meanwhile
        were not durable while finish() waited with the autocommit stopped (a kill then lost the runs of
        the last 2 s of a 2000-run sweep, beyond commit_interval + one commit)."""
        with self._mutex:
            if (self._jfd is not None and self._failed is None and self._lock_fd is not None
                    and (self._pending or self._deletions)):
                self.commit()

    def close(self) -> None:
        self.stop_autocommit()
        try:
            with contextlib.suppress(StorageError):
                self._commit_before_waiting()
        finally:
            self.stop_background_compaction()
        try:
            if self._pending and self._lock_fd is not None and self._failed is None:
                with contextlib.suppress(StorageError):
                    self.commit()
        finally:
            self._close_journal()
            with contextlib.suppress(OSError):
                self.tmp_path.unlink()
            self._release_lock()


def _one_line(e, limit: int = 300) -> str:
    s = " ".join(str(e).split()) or type(e).__name__
    m = _HDF5_REASON.search(s)  # HDF5's "(file write failed: ..., error message = 'No space left ...', ...)"
    if m:
        s = f"HDF5: {m.group(2)}" + (f", errno {m.group(1)}" if m.group(1) else "")
    return s if len(s) <= limit else s[: limit - 3] + "..."


_HDF5_REASON = re.compile(r"(?:errno = (\d+), )?error message = '([^']*)'")


def _short(v) -> str:
    s = repr(v)
    return s if len(s) <= 40 else s[:37] + "..."


def _fmt_bytes(b: float) -> str:
    from vcirun.core.validation import format_bytes

    return format_bytes(b)


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
        return None if not isinstance(b, (int, float)) or not np.isfinite(b) else float(b)


@dataclass
class Results:
    path: Path
    attrs: dict
    runs: list[RunInfo]
    references: dict[str, dict]
    incomplete: list[str] = field(default_factory=list)
    in_journal: int = 0   # runs committed to the journal of a session that did not finish (not yet in the HDF5 file)
    damaged: dict = field(default_factory=dict)  # group path -> why it is not trusted

    @property
    def name(self) -> str:
        return str(self.attrs.get("name") or self.path.stem)


def _open_read(path) -> h5py.File:
    path = Path(path)
    if not path.exists():
        raise StorageError(f"{path}: file not found")
    if path.is_dir():
        raise StorageError(f"{path}: is a directory, not a results file")
    if not path.is_file():  # a FIFO: opening it blocks until someone writes (`vcirun info FIFO` hung)
        raise StorageError(f"{path}: not a regular file (a FIFO, device or socket), not a results file")
    try:
        f = h5py.File(path, "r")
    except Exception as e:  # noqa: BLE001 - OSError, or anything a damaged superblock raises
        raise StorageError(f"{path}: not a readable HDF5 file ({_one_line(e)})") from None
    try:
        fmt = _decode_attr("format", f.attrs.get("format", ""))
    except Exception:  # noqa: BLE001
        fmt = "?"
    if fmt != FORMAT:
        f.close()
        raise StorageError(f"{path}: not a vcirun sweep results file (format {_short(fmt)})")
    return f


def _damaged(path, e: BaseException) -> StorageError:
    return StorageError(f"{path}: damaged results file ({type(e).__name__}: {_one_line(e, 200)}); rerun the sweep "
                        "(it recomputes what is missing) or move the file away")


def _file_journal(path, f) -> Journal | None:
    """The journal that extends this file (a killed session's committed runs), or None."""
    expected = _decode_attr("journal", f.attrs.get("journal", ""))
    if not expected:
        return None
    try:
        j = read_journal(journal_path(path))
    except StorageError:
        return None
    if j is None or j.token != expected or j.config_key != _decode_attr("config_key", f.attrs.get("config_key", "")):
        return None
    return j.after(_applied(f))


def _applied(f) -> int:
    """How much of its journal the file holds already (a background compaction's progress)."""
    v = _decode_attr("journal_applied", f.attrs.get("journal_applied", 0))
    return int(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0 else 0


def read_results(path) -> Results:
    """Root attributes, complete runs (attributes only) and references of a results file, with the runs
    a killed session committed to its journal; groups that fail verification are listed in `incomplete`."""
    with _open_read(path) as f:
        try:
            attrs = decode_attrs(f.attrs)
            runs, refs, incomplete, damaged = {}, {}, [], {}
            for group, store, check in (("runs", runs, run_problem), ("references", refs, reference_problem)):
                if group not in f:
                    continue
                if not isinstance(f[group], h5py.Group):
                    raise StorageError(f"{path}: damaged results file (/{group} is not a group); rerun the sweep "
                                       "with --force or move the file away")
                for name, g in f[group].items():
                    a = decode_attrs(g.attrs) if isinstance(g, h5py.Group) else {}
                    if not a.get("complete", False):
                        incomplete.append(f"{group}/{name}")
                        continue
                    problem = check(g, a)
                    if problem:
                        incomplete.append(f"{group}/{name}")
                        damaged[f"{group}/{name}"] = problem
                    else:
                        store[name] = (None, a)
            in_journal = _overlay(_file_journal(path, f), runs, refs, attrs)
        except StorageError:
            raise
        except Exception as e:  # noqa: BLE001 - damaged metadata, attributes of the wrong type, ...
            raise _damaged(path, e) from None
    incomplete = [p for p in incomplete if p.partition("/")[2] not in (runs if p.startswith("runs/") else refs)]
    run_list = [RunInfo(k, a) for k, (_, a) in runs.items()]
    # config order: method, then h, then initial condition
    ic_keys = attrs.get("ic_keys") if isinstance(attrs.get("ic_keys"), list) else []
    h_values = attrs.get("h_values") if isinstance(attrs.get("h_values"), list) else []
    ic_order = {k: i for i, k in enumerate(ic_keys) if isinstance(k, str)}
    h_order = {}
    for i, h in enumerate(h_values):
        with contextlib.suppress(TypeError, ValueError):
            h_order[float(h)] = i

    def order(r):
        a = r.attrs
        mi = a.get("method_index", 0)
        return (mi if isinstance(mi, (int, float)) else 0, h_order.get(_as_float(a.get("h")), 0),
                ic_order.get(a.get("ic_key"), 0), r.run_id)

    run_list.sort(key=order)
    return Results(Path(path), attrs, run_list, {k: a for k, (_, a) in refs.items()}, incomplete,
                   in_journal=in_journal, damaged=damaged)


def _as_float(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


def _find_group(path, f, group: str, key: str):
    """(group-like, problem) of runs/<key> or references/<key>: the journal's last record wins."""
    j = _file_journal(path, f)
    rec = None
    if j is not None:
        for r in j.records:
            if (r.kind == "run" and group == "runs" or r.kind == "reference" and group == "references") \
                    and r.key == key:
                rec = r
            elif r.kind == "delete" and r.key == f"{group}/{key}":
                rec = "deleted"
    if rec == "deleted":
        return None
    if rec is not None:
        with open(j.path, "rb") as fh:
            return _MemGroup(rec.attrs(), rec.arrays(fh))
    if group in f and key in f[group] and isinstance(f[group][key], h5py.Group):
        g = f[group][key]
        return g if bool(g.attrs.get("complete", False)) else None
    return None


def load_trajectory(path, run_id: str):
    """The `Trajectory` of one stored run (StorageError if it is missing or fails verification)."""
    with _open_read(path) as f:
        try:
            g = _find_group(path, f, "runs", run_id)
            if g is None:
                raise StorageError(f"{path}: no run {run_id!r}")
            problem = run_problem(g)
            if problem:
                raise StorageError(f"{path}: run {run_id} is damaged ({problem}); rerun the sweep to recompute it")
            return trajectory_from_group(g)
        except StorageError:
            raise
        except Exception as e:  # noqa: BLE001
            raise _damaged(path, e) from None


def load_reference(path, key: str) -> dict:
    """A stored reference: {'attrs': ..., 't', 'q', 'p', 'impacts'} (arrays that exist)."""
    with _open_read(path) as f:
        try:
            g = _find_group(path, f, "references", key)
            if g is None:
                raise StorageError(f"{path}: no reference {key!r}")
            problem = reference_problem(g)
            if problem:
                raise StorageError(f"{path}: reference {key} is damaged ({problem}); rerun the sweep to recompute it")
            out = {name: g[name][()] for name in g}
            out["attrs"] = decode_attrs(g.attrs)
            return out
        except StorageError:
            raise
        except Exception as e:  # noqa: BLE001
            raise _damaged(path, e) from None


def find_newest_results(directory="results") -> Path:
    d = Path(directory)
    files = [p for p in d.rglob("*.h5") if not p.name.startswith(".")] if d.is_dir() else []
    if not files:
        raise StorageError(f"no results (*.h5) under {d}/; run `vcirun sweep CONFIG` first or name a file")
    return max(files, key=lambda p: p.stat().st_mtime)
