"""One rewrite of the results file: what goes into the copy that replaces it (durable.replace_with_copy).

A writer rewrites the file when a session starts (the session recorded, a killed session's journal
folded in, damaged groups dropped), when it commits before its journal exists, and when it finishes
(the journal folded in). `Rewrite.write` is the HDF5 part, run in a forked child; `free_space_error`
and `failure` turn what can go wrong into one-line StorageErrors.
"""
from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import h5py

from ..core.sizes import format_bytes
from ..run.trajectory_files import encode_attr, group_attrs, storable
from .batches import count_items, delete_items, pack, stamped, write_batch
from .checks import FORMAT, LIBVER, SCHEMA_VERSION
from .errors import StorageError, one_line
from .journal import apply_journal
from .legacy_text import MARK, MARK_VALUE, fix_variable_text, has_variable_text
from .provenance import now_iso

__all__ = ["Pending", "Rewrite", "free_space_error", "failure"]


@dataclass
class Pending:
    """A queued group: a run or a reference, with its attributes and arrays."""
    kind: str  # "run" | "reference"
    key: str
    attrs: dict
    arrays: dict
    text: str | None = None   # the attributes encoded as a batch stores them (vcirun.io.batches.item_text)

    def item(self, stamp: str) -> tuple:
        """(key, encoded attributes or None, arrays, JSON text or None) for vcirun.io.batches.pack,
        with `committed_at`."""
        if self.text is not None:
            return self.key, None, self.arrays, stamped(self.text, "committed_at", stamp)
        return self.key, group_attrs({**self.attrs, "committed_at": stamp}), self.arrays


@dataclass
class Rewrite:
    path: Path           # the results file
    fresh: bool          # a new file, written from scratch (else the copy of the file is updated)
    config_key: str
    root_attrs: dict
    deletions: list      # item and batch paths to delete (vcirun.io.batches.delete_items)
    journals: list       # journals whose records to apply, in order
    pending: list        # queued groups (Pending), written after the journals
    history: list        # the root history after this rewrite
    token: str           # the journal that will extend the file ("" for none)
    final_hooks: tuple = ()  # callables f(h5py.File) run last, on the open copy

    def write(self, tmp: Path) -> None:
        """Write everything that changes into the copy `tmp`."""
        with h5py.File(tmp, "w" if self.fresh else "a", libver=LIBVER) as f:
            if self.fresh:
                f.attrs["format"] = storable(FORMAT)
                f.attrs["config_key"] = storable(self.config_key)
            elif has_variable_text(f):   # a file of an earlier vcirun (its text was read in time at the start)
                fix_variable_text(f)
            f.attrs[MARK] = storable(MARK_VALUE)   # every text of the file is fixed-length
            f.attrs["schema_version"] = SCHEMA_VERSION  # what this writer adds is in batches
            for key, value in self.root_attrs.items():
                f.attrs[key] = storable(encode_attr(key, value))
            delete_items(f, self.deletions)
            for j in self.journals:
                apply_journal(f, j, self.path)
            stamp = now_iso()
            for kind in ("reference", "run"):
                items = [p.item(stamp) for p in self.pending if p.kind == kind]
                for b in pack(items):
                    write_batch(f, kind, b)
            f.attrs["history"] = storable(encode_attr("history", self.history))
            f.attrs["updated"] = storable(now_iso())
            f.attrs["n_runs_complete"] = count_items(f, "run")
            f.attrs["journal"] = storable(self.token)
            f.attrs["journal_applied"] = 0  # a new journal (or none): nothing of it is in the file yet
            for hook in self.final_hooks:
                hook(f)


def free_space_error(path: Path, need: int) -> StorageError | None:
    """The error to raise when the filesystem of `path` has less than `need` bytes free (None if it
    has them, or cannot tell)."""
    try:
        free = shutil.disk_usage(path.parent).free
    except OSError:
        return None
    if need <= free:
        return None
    return StorageError(f"{path}: not enough free space to write results (about {format_bytes(need)} needed, "
                        f"{format_bytes(free)} free in {path.parent}); every committed run is kept: free space "
                        "and rerun the same command to resume")


def failure(path: Path, e: BaseException) -> StorageError | None:
    """The StorageError of a rewrite that raised `e` (None: not a write failure, re-raise `e`): disk
    full, permissions and HDF5 I/O errors leave the live file holding every committed run; an HDF5
    error that is not I/O means the file's own structures are damaged."""
    if not isinstance(e, (OSError, RuntimeError, ValueError, KeyError)):
        return None
    if isinstance(e, OSError) or getattr(e, "io_failure", False) or "errno" in str(e):
        return StorageError(f"{path}: cannot write results ({one_line(e)}); the file and its journal still hold "
                            "every run committed before this error: fix the cause and rerun the same command to "
                            "resume")
    return StorageError(f"{path}: cannot update the results file ({one_line(e)}); it looks damaged: move it "
                        "away or rerun with --force to start over")
