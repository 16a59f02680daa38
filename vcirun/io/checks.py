"""What a results file is and what its groups must hold before anyone trusts them.

- The file's identity: root attribute `format` = FORMAT, `schema_version` = SCHEMA_VERSION, written
  with HDF5 library version bounds LIBVER (layout: docs/reference/results_schema.md).
- `run_problem` / `reference_problem`: why a group marked complete cannot be trusted (datasets
  missing, shapes other than its attributes declare), or None; an item of a batch is also held to
  its checksums (vcirun.io.batches.data_problems: every byte of its key, attributes and arrays).
  Resume and the readers trust only what these verify; `scan_groups` sorts a file's groups into
  trusted, incomplete and damaged.
- `resolve_output`: the path a sweep writes (a symlink's target), checked for the usual mistakes.
"""
from __future__ import annotations

import os
from pathlib import Path

import h5py
import numpy as np

from ..core import record
from ..run.trajectory_files import decode_attr, decode_attrs
from .batches import BATCH_GROUPS, ITEM_GROUPS, checked_batch, data_problems
from .errors import StorageError, os_text

__all__ = ["FORMAT", "SCHEMA_VERSION", "LIBVER", "NUMERIC_KINDS", "run_problem", "reference_problem",
           "scan_groups", "resolve_output", "root_format"]

FORMAT = "vcirun-sweep"
SCHEMA_VERSION = 2   # 2: runs and references in batches (vcirun.io.batches); 1: a group each
LIBVER = "latest"
NUMERIC_KINDS = "biuf"  # the only array dtypes a results file or its journal holds

# rows every version of the schema wrote: a run without one of them is damaged; later rows (e.g.
# impact_impulse) are checked when present, the friction rows also required where the run's
# attribute friction_rows is true (where it is false they are left out: vcirun.core.record.FRICTION_ROWS)
_ALWAYS_WRITTEN = {"t", "q", "p", "H", "Ed", "Hmod", "impact_step", "newton_iters", "impacts", "impact_q",
                   "impact_p_minus", "impact_p_plus", "partial_steps"}


def _shape_of(g, name):
    """Shape of dataset `name` of a group (None if absent; text if it is not a numeric array). HDF5
    groups are read with the low-level API: a third of the high-level cost, which counts when a resume
    verifies thousands of runs. An item of a batch answers from its row table."""
    shape_of = getattr(g, "shape_of", None)
    if shape_of is not None:
        return shape_of(name)
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
        return tuple(d.shape) if d.dtype.kind in NUMERIC_KINDS else "not numeric"
    d = g.get(name) if hasattr(g, "get") else None
    if d is None:
        return None
    if not isinstance(d, (h5py.Dataset, np.ndarray)):
        return "not an array"
    if d.dtype.kind not in NUMERIC_KINDS:
        return "not numeric"
    return tuple(d.shape)


def root_format(f):
    """(the open file's root attribute `format` as str ("" if it has none), None), or (None, why) where
    the file has one that cannot be read (damaged attribute storage: the file is damaged, not foreign)."""
    try:
        if not h5py.h5a.exists(f.id, b"format"):
            return "", None
        return decode_attr("format", f.attrs["format"]), None
    except Exception as e:  # noqa: BLE001 - checksum failures, unreadable headers
        return None, " ".join(str(e).split())[:160]


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
    # n_releases, n_mode_changes and n_contacts are optional (a file whose schema has no release, mode or
    # per-contact rows):
    # without them those rows are not checked
    size = {"grid": N + 1, "step": N, "impact": m, "partial": k, "release": _int_attr(a, "n_releases"),
            "mode": _int_attr(a, "n_mode_changes")}
    every = _int_attr(a, "store_every")
    if every is not None and every > 1:   # store: {every: k}: every k-th grid state and the last, no step rows
        size["grid"], size["step"] = N // every + 1 + (1 if N % every else 0), None
    mc = _int_attr(a, "n_contacts")
    want = {"t": ((size["grid"],), True)} if a.get("has_trajectory") is True else {}
    for f in record.FIELDS:  # each stored row of the run record, at its declared length
        if f.stored == "no" or (f.stored == "trajectory" and a.get("has_trajectory") is not True) \
                or (f.only == "modified" and a.get("has_Hmod") is not True) or size[f.axis] is None \
                or (f.contacts and mc is None):
            continue
        want[f.name] = (f.shape(size[f.axis], n, mc or 0), f.name in _ALWAYS_WRITTEN or (
            f.name in record.FRICTION_ROWS and a.get("friction_rows") is True))
    for name, (shape, required) in want.items():
        got = _shape_of(g, name)
        if got is None and not required:
            continue  # a row the file's schema does not have
        if got != shape:
            return (f"dataset {name} missing" if got is None else
                    f"dataset {name} is {got}" if isinstance(got, str) else
                    f"dataset {name} has shape {got}, expected {shape}")
    return None


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


def scan_groups(f, path, fix: str, check: bool = True):
    """(runs, references, incomplete, damaged) of an open results file: {key: decoded attributes} of
    the items marked complete that pass their check, the paths of what fails (a group of schema 1
    "runs/NAME", a whole batch "run_batches/NAME", one batch's copy of an item "run_batches/NAME/KEY";
    vcirun.io.batches), and {path: problem} of what is marked complete but fails. Where a key is held
    twice the later batch's copy counts. A root entry `runs`, `references` or a batch group that is not
    a group is a StorageError ending with `fix`; a missing one holds nothing. `check=True` reads every
    item's data to verify its checksums. `check=False` trusts every item of a complete batch whose
    table agrees with its data (for a file whose items were verified when its session started, or
    written by that session)."""
    runs, refs, incomplete, damaged = {}, {}, [], {}
    stores = {"run": runs, "reference": refs}
    checks = {"run": run_problem, "reference": reference_problem}
    for kind, group in ITEM_GROUPS.items():   # schema 1: one group per item
        if group not in f:
            continue
        if not isinstance(f[group], h5py.Group):
            raise StorageError(f"{path}: damaged results file (/{group} is not a group); {fix}")
        for name, g in f[group].items():
            a = decode_attrs(g.attrs) if isinstance(g, h5py.Group) else {}
            if not a.get("complete", False):
                incomplete.append(f"{group}/{name}")
                continue
            problem = checks[kind](g, a)
            if problem:
                incomplete.append(f"{group}/{name}")
                damaged[f"{group}/{name}"] = problem
            else:
                stores[kind][name] = a
    for kind, group in BATCH_GROUPS.items():
        if group not in f:
            continue
        if not isinstance(f[group], h5py.Group):
            raise StorageError(f"{path}: damaged results file (/{group} is not a group); {fix}")
        for name in sorted(f[group]):
            bpath = f"{group}/{name}"
            g = f[bpath]
            if not isinstance(g, h5py.Group) or not bool(g.attrs.get("complete", False)):
                incomplete.append(bpath)
                continue
            b, problem = checked_batch(g)
            if problem:
                incomplete.append(bpath)
                damaged[bpath] = problem
                continue
            starts = b.starts()
            rot = data_problems(b) if check else {}
            for i, key in enumerate(b.keys):
                try:
                    a = decode_attrs(b.attrs[i])
                except Exception as e:  # noqa: BLE001
                    a, problem = {}, f"attributes unreadable ({type(e).__name__})"
                else:
                    problem = rot.get(i) or (checks[kind](b.view(i, starts), a) if check else None)
                if problem:
                    incomplete.append(f"{bpath}/{key}")
                    damaged[f"{bpath}/{key}"] = problem
                else:
                    stores[kind][key] = a
    return runs, refs, incomplete, damaged


# --- the output path -------------------------------------------------------------------------------
def resolve_output(path) -> Path:
    """The path to write: a symlink's target (the link then keeps pointing at the results), checked
    for the usual mistakes with a one-line message."""
    if "\x00" in str(path):
        raise StorageError(f"{str(path)!r}: a path cannot contain a NUL character; choose another --output")
    try:
        return _resolve_checked(Path(path), path)
    except OSError as e:  # a name too long, a component without permission, ...
        raise StorageError(f"{path}: cannot use this path ({os_text(e)}); choose another --output") from None


def _resolve_checked(p: Path, path) -> Path:
    if p.is_symlink():
        try:
            p = Path(os.path.realpath(p, strict=False))
        except (OSError, RuntimeError) as e:
            raise StorageError(f"{path}: cannot follow the symbolic link ({os_text(e)}); choose another "
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
