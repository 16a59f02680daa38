"""Reading a sweep's results file: `read_results` (attributes of every trusted run and reference),
`load_trajectory` (one run's arrays), `load_reference`, `find_newest_results`.

The readers see the journal too (see vcirun.io.journal), so a killed sweep's committed runs are
visible at once; plain h5py sees them after the next `vcirun sweep` of the same config (which
compacts first). Groups that fail verification (vcirun.io.checks) are listed, never returned.
Every failure is a one-line StorageError naming the path.
"""
from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from ..run.trajectory import trajectory_from_group
from ..run.trajectory_files import decode_attrs
from .batches import (BATCH_GROUPS, ITEM_GROUPS, batch_keys, batch_names, checked_batch, data_problems, item_path,
                      split_item_path)
from .checks import FORMAT, reference_problem, root_format, run_problem, scan_groups
from .errors import StorageError, one_line, short
from .journal import Journal, MemGroup, file_journal, overlay
from .legacy_text import check_variable_text

__all__ = ["RunInfo", "Results", "read_results", "results_of", "load_trajectory", "load_reference", "find_newest_results"]


@dataclass
class RunInfo:
    """Attributes of one stored run (arrays stay on disk; see `load_trajectory`)."""
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
    notes: list = field(default_factory=list)    # what the readers could not show (damaged journal records)

    @property
    def name(self) -> str:
        return str(self.attrs.get("name") or self.path.stem)


def _open_read(path) -> h5py.File:
    path = Path(path)
    if not path.exists():
        raise StorageError(f"{path}: file not found")
    if path.is_dir():
        raise StorageError(f"{path}: is a directory, not a results file")
    if not path.is_file():  # opening a FIFO would block until someone writes to it
        raise StorageError(f"{path}: not a regular file (a FIFO, device or socket), not a results file")
    try:
        f = h5py.File(path, "r")
    except Exception as e:  # noqa: BLE001 - OSError, or anything a damaged superblock raises
        raise StorageError(f"{path}: not a readable HDF5 file ({one_line(e)})") from None
    try:   # (a file of an earlier vcirun with variable-length text: read in a child with a deadline first)
        check_variable_text(path, f, "rerun the sweep (it recomputes what is missing) or move the file away")
    except StorageError:
        f.close()
        raise
    fmt, why = root_format(f)
    if fmt is None:
        f.close()
        raise StorageError(f"{path}: damaged results file (its root attribute format cannot be read: {why}); "
                           "rerun the sweep with --force or move the file away")
    if fmt != FORMAT:
        f.close()
        raise StorageError(f"{path}: not a vcirun sweep results file (format {short(fmt)})")
    return f


def _damaged(path, e: BaseException) -> StorageError:
    return StorageError(f"{path}: damaged results file ({type(e).__name__}: {one_line(e, 200)}); rerun the sweep "
                        "(it recomputes what is missing) or move the file away")


def _journal_of(path, f, notes: list | None = None) -> Journal | None:
    """The journal records that extend this file, or None; a journal that cannot be read, or records
    of it skipped as damaged, are said in `notes`."""
    try:
        j = file_journal(path, f)
    except StorageError as e:
        if notes is not None:
            notes.append(f"{e}; the runs committed there are not shown")
        return None
    if j is not None and j.skipped and notes is not None:
        notes.append(j.skipped_text())
    return j


def read_results(path) -> Results:
    """Root attributes, complete runs (attributes only) and references of a results file, with the runs
    a killed session committed to its journal; groups that fail verification are listed in `incomplete`."""
    with _open_read(path) as f:
        return results_of(f, path)


def results_of(f, path, check: bool = True) -> Results:
    """`read_results` of the open results file `f` at `path` (e.g. a copy being written, whose
    `journal` attribute names no journal); `check`: see vcirun.io.checks.scan_groups."""
    try:
        attrs = decode_attrs(f.attrs)
        run_attrs, ref_attrs, incomplete, damaged = scan_groups(
            f, path, "rerun the sweep with --force or move the file away", check=check)
        runs = {k: (None, a) for k, a in run_attrs.items()}
        refs = {k: (None, a) for k, a in ref_attrs.items()}
        notes: list = []
        in_journal = overlay(_journal_of(path, f, notes), runs, refs, attrs)
    except StorageError:
        raise
    except Exception as e:  # noqa: BLE001 - damaged metadata, attributes of the wrong type, ...
        raise _damaged(path, e) from None
    incomplete = [p for p in incomplete if not _held(p, runs, refs)]
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
                   in_journal=in_journal, damaged=damaged, notes=notes)


def _held(path: str, runs: dict, refs: dict) -> bool:
    """Whether the item a failed path names is held all the same (by the journal, or another batch)."""
    s = split_item_path(path)
    return s is not None and s[1] in (runs if s[0] == "run" else refs)


def _as_float(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


def _find_group(path, f, group: str, key: str, problems: list | None = None):
    """The group-like object of item `key` of `group` ("runs" | "references"), or None if absent or
    not trusted: the journal's last record wins, then the file's latest batch copy that passes its
    check (checksums included), then a group of schema 1. `problems` collects why copies were not
    trusted."""
    kind = "run" if group == "runs" else "reference"
    j = _journal_of(path, f)
    rec = None
    if j is not None:
        for r in j.records:
            if r.kind in ("batch", "run", "reference") and r.item_kind == kind:
                if r.kind != "batch":
                    rec = (r, 0) if r.key == key else rec
                elif key in (r.header.get("keys") or ()):
                    rec = (r, list(r.header["keys"]).index(key))
            elif r.kind == "delete" and r.key == item_path(kind, key):
                rec = "deleted"
    if rec == "deleted":
        return None
    if rec is not None:
        r, i = rec
        with open(j.path, "rb") as fh:
            b = r.batch(fh)
        return MemGroup(b.attrs[i], b.arrays(i))
    check = run_problem if kind == "run" else reference_problem
    for name in reversed(batch_names(f, kind)):
        g = f[f"{BATCH_GROUPS[kind]}/{name}"]
        if not isinstance(g, h5py.Group) or not bool(g.attrs.get("complete", False)) or "key" not in g:
            continue
        try:
            keys = batch_keys(g)
        except Exception:  # noqa: BLE001 - a damaged batch: not trusted
            continue
        if key not in keys:
            continue
        b, problem = checked_batch(g)
        if problem:
            if problems is not None:
                problems.append(problem)
            continue
        i = keys.index(key)
        v = b.view(i)
        problem = data_problems(b, [i]).get(i) or check(v, decode_attrs(v.attrs))
        if problem:
            if problems is not None:
                problems.append(problem)
            continue  # a damaged copy: an earlier one may hold the item
        return MemGroup(v.attrs, b.arrays(i))
    group_name = ITEM_GROUPS[kind]
    if group_name in f and key in f[group_name] and isinstance(f[group_name][key], h5py.Group):
        g = f[group_name][key]
        return g if bool(g.attrs.get("complete", False)) else None
    return None


def load_trajectory(path, run_id: str):
    """The `Trajectory` of one stored run (StorageError if it is missing or fails verification)."""
    with _open_read(path) as f:
        try:
            problems = []
            g = _find_group(path, f, "runs", run_id, problems)
            if g is None and problems:
                raise StorageError(f"{path}: run {run_id} is damaged ({problems[0]}); rerun the sweep to recompute it")
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
            problems = []
            g = _find_group(path, f, "references", key, problems)
            if g is None and problems:
                raise StorageError(f"{path}: reference {key} is damaged ({problems[0]}); rerun the sweep to "
                                   "recompute it")
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
    """The most recently modified results file (*.h5, not hidden) under `directory`."""
    d = Path(directory)
    files = [p for p in d.rglob("*.h5") if not p.name.startswith(".")] if d.is_dir() else []
    if not files:
        raise StorageError(f"no results (*.h5) under {d}/; run `vcirun sweep CONFIG` first or name a file")
    return max(files, key=lambda p: p.stat().st_mtime)
