"""What an existing results file holds for a session that resumes it (`read_existing`).

The file must be a vcirun sweep file written by the same configuration (its `config_key`); its groups
count only when they pass verification (vcirun.io.checks), and the runs a killed session committed
to the file's journal count as stored. Everything else is listed for deletion and recomputed.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import h5py

from ..run.trajectory_files import decode_attr
from .batches import split_item_path
from .checks import FORMAT, root_format, scan_groups
from .errors import StorageError, one_line, short
from .journal import Journal, file_journal, overlay
from .legacy_text import check_variable_text

__all__ = ["Existing", "read_existing"]


@dataclass
class Existing:
    history: list = field(default_factory=list)   # the root history (a killed session's own count included)
    runs: dict = field(default_factory=dict)      # run_id -> decoded attributes
    references: dict = field(default_factory=dict)
    incomplete: list = field(default_factory=list)  # group paths to delete
    damaged: dict = field(default_factory=dict)   # group path -> why it is not trusted
    journal: Journal | None = None                # the killed session's records the file does not hold yet


def read_existing(path: Path, config_key: str) -> Existing:
    """The verified contents of the results file `path` (StorageError naming the fix if it is not a
    readable vcirun sweep file of this configuration)."""
    try:
        f = h5py.File(path, "r")
    except Exception as e:  # noqa: BLE001 - OSError, or anything a damaged superblock raises
        raise StorageError(f"{path}: not a readable HDF5 file ({one_line(e)}); move it away "
                           "or rerun with --force to start over") from None
    try:
        with f:
            check_variable_text(path, f, "move it away or rerun with --force to start over")
            return _read(f, path, config_key)
    except StorageError:
        raise
    except Exception as e:  # noqa: BLE001 - damaged metadata deeper in the file
        raise StorageError(f"{path}: damaged results file ({type(e).__name__}: {one_line(e)}); move "
                           "it away or rerun with --force to start over") from None


def _read(f, path: Path, config_key: str) -> Existing:
    fmt, why = root_format(f)
    if fmt is None:
        raise StorageError(f"{path}: damaged results file (its root attribute format cannot be read: {why}); "
                           "move it away or rerun with --force to start over")
    if fmt != FORMAT:
        raise StorageError(f"{path}: not a vcirun sweep file (format {short(fmt)}); choose another "
                           "--output or rerun with --force to overwrite it")
    key = decode_attr("config_key", f.attrs.get("config_key", ""))
    if key != config_key:
        raise StorageError(f"{path}: written by a different configuration (config key {str(key)[:12]} "
                           f"!= {config_key[:12]}); rerun with --force to recompute everything, or "
                           "choose another --output")
    hist = decode_attr("history", f.attrs.get("history", "[]"))
    out = Existing(hist if isinstance(hist, list) else [])
    out.runs, out.references, out.incomplete, out.damaged = scan_groups(
        f, path, "move it away or rerun with --force to start over")
    j = file_journal(path, f)  # a killed session's journal: its runs count as stored (they were committed)
    if j is None:
        return out
    out.journal = j
    sessions = [r for r in j.records if r.kind == "session"]
    if sessions and isinstance(sessions[-1].header.get("history"), list):
        out.history = sessions[-1].header["history"]  # the killed session's own count
    runs = {k: (None, a) for k, a in out.runs.items()}
    refs = {k: (None, a) for k, a in out.references.items()}
    overlay(j, runs, refs)
    out.runs = {k: a for k, (_, a) in runs.items()}
    out.references = {k: a for k, (_, a) in refs.items()}
    held = [(p, split_item_path(p)) for p in out.incomplete]
    stale = {p for p, s in held if s is not None and s[1] in (runs if s[0] == "run" else refs)}
    out.incomplete = [p for p in out.incomplete if p not in stale or p in out.damaged]
    return out
