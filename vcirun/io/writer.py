"""`ResultsWriter`: the single writer of a sweep's results file (layout: docs/reference/results_schema.md).

Safety model: bounded loss at a constant commit cost.

- The sweep's client process is the only writer (`lock.WriterLock`).
- A commit appends the finished runs to the journal beside the file (`journal`) and fsyncs it: its
  cost is that of the new runs, independent of the file's size. Commits come every `commit_interval`
  seconds (default 1 s; a background thread commits while the client waits for results), so a
  SIGKILL at any moment loses at most the runs that reached the client in the last commit_interval
  plus one commit's duration.
- The HDF5 file is never written in place (`durable.replace_with_copy`). Rewrites happen when a
  session starts (recording it, and applying the journal a killed session left) and when it finishes
  ("compaction": the journal is folded in and removed); `compaction` folds it in during the session.
- Resume trusts only what it verifies (`checks.run_problem`): anything else is deleted and recomputed.
  Missing `runs`/`references` groups are recreated (references recomputed).
- Disk full and other OS errors: one `StorageError` naming the path; a failed rewrite removes its
  partial copy, a failed append truncates the journal back to its last complete record; nothing
  committed is lost and the same command resumes. A rewrite first checks the free space it needs.
- The output may be a symlink: writes go to its target (the link keeps pointing at the results).
"""
from __future__ import annotations

import contextlib
import math
import os
import threading
import time
import uuid
from pathlib import Path

import h5py
import numpy as np

from .checks import resolve_output
from .compaction import BackgroundCompactor, compact_path
from ..core.fsync import fsync_path
from .durable import replace_with_copy
from .errors import StorageError, os_text, write_error
from .batches import item_path, pack
from .journal import Journal, applied, batch_pieces, journal_path, read_journal, record_pieces, write_all
from .lock import WriterLock, lock_path
from .provenance import now_iso
from .resume import read_existing
from .rewrite import Pending, Rewrite, failure, free_space_error

__all__ = ["ResultsWriter", "DEFAULT_COMMIT_INTERVAL"]

DEFAULT_COMMIT_INTERVAL = 1.0  # seconds between journal commits (the loss bound of a hard kill)
# A queue of this many items is committed at once: the commits of a fast sweep then happen while its
# workers compute, not all in the serial finish (one batch group per commit; 4 for the fig4 sweep).
COMMIT_RUNS = 128


class ResultsWriter:
    """The single writer of one sweep's results file. Use as a context manager.

    `acquire()` takes the lock and checks an existing file (format; written by the same configuration:
    `config_key`; groups verified, see `checks.run_problem`), collecting its runs and references, the
    runs a killed session left in the journal included; with `force` it starts a new file instead.
    `start()` rewrites the file once (the current session in its history, a killed session's journal folded
    in, damaged groups dropped) and opens a new journal. `add_run`/`add_reference` queue results;
    `commit()` appends the queue to the journal (before `start`: rewrites the file); `maybe_commit()`
    does so when `commit_interval` seconds have passed since the last commit; `start_autocommit()` runs
    that check on a thread. `finish(status)` commits, then compacts the journal into the file. Thread-safe.
    """

    def __init__(self, path, *, root_attrs: dict, config_key: str, force: bool = False,
                 commit_interval: float | None = None, session: dict | None = None, isolate: bool = True):
        self.path = resolve_output(path)
        self.root_attrs = dict(root_attrs)
        self.config_key = config_key
        self.force = force
        if commit_interval is None:
            commit_interval = os.environ.get("VCIRUN_COMMIT_INTERVAL", DEFAULT_COMMIT_INTERVAL)
            field = "VCIRUN_COMMIT_INTERVAL"
        else:
            field = "commit_interval"
        try:
            self.commit_interval = float(commit_interval)
        except (TypeError, ValueError):
            self.commit_interval = math.nan
        if not (math.isfinite(self.commit_interval) and self.commit_interval >= 0):
            raise StorageError(f"{field}: must be a number of seconds >= 0, e.g. 1 (got {commit_interval!r})")
        self.isolate = isolate  # HDF5 rewrites in a forked child (durable.run_isolated); False: in this process
        self.session = dict(session or {})
        self.session.setdefault("started", now_iso())
        self.session.setdefault("status", "running")
        self.session.setdefault("computed", 0)
        self.complete_runs: dict[str, dict] = {}
        self.references: dict[str, dict] = {}
        self.incomplete: list[str] = []
        self.damaged: dict[str, str] = {}   # group path -> why it is not trusted
        self.notes: list[str] = []           # what a resume found damaged beyond groups (journal records)
        self.prior_history: list = []
        self.final_hooks: list = []          # callables f(h5py.File) run inside the session's last rewrite
        self._pending: list[Pending] = []
        self._pending_bytes = 0
        self._deletions: list[str] = []
        self._last_commit = time.monotonic()
        self._lock = WriterLock(self.path)
        self._fresh = force
        self._old_journal: Journal | None = None
        self._jfd: int | None = None         # the current session's journal (after start)
        self._jend = 0
        self._token = ""
        self._failed: StorageError | None = None  # a write failed: no further HDF5 writes in the current session
        self._mutex = threading.RLock()
        self._auto: threading.Thread | None = None
        self._auto_stop = threading.Event()
        self._auto_error: BaseException | None = None
        self._compactor: BackgroundCompactor | None = None
        self._journal_base = 0                # journal offset past its open record

    # the temporary copy lives next to the file so that os.replace stays on one filesystem
    @property
    def tmp_path(self) -> Path:
        return self.path.with_name(f".{self.path.name}.partial")

    @property
    def lock_path(self) -> Path:
        return lock_path(self.path)

    @property
    def journal_path(self) -> Path:
        return journal_path(self.path)

    @property
    def compact_path(self) -> Path:
        return compact_path(self.path)

    @property
    def failed(self) -> bool:
        """A write failed in the current session (disk full, ...): nothing more is written."""
        return self._failed is not None

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def _release_lock(self) -> None:
        self._lock.release()

    # -- opening ---------------------------------------------------------------------------------------
    def acquire(self) -> "ResultsWriter":
        """Take the writer lock and read what an existing file already holds (nothing is written)."""
        self._lock.acquire()
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
        """Rewrite the file once (the current session recorded, a killed session's journal folded in, damaged
        groups dropped), then open the current session's journal."""
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
        e = read_existing(self.path, self.config_key)
        self.prior_history, self.complete_runs, self.references = e.history, e.runs, e.references
        self.incomplete, self.damaged, self._old_journal = e.incomplete, e.damaged, e.journal
        self.notes = [e.journal.skipped_text()] if e.journal is not None and e.journal.skipped else []
        self._deletions.extend(self.incomplete)

    def forget_runs(self, run_ids) -> None:
        """Schedule runs for recomputation (e.g. --retry-failed): deleted at the next commit."""
        with self._mutex:
            for rid in run_ids:
                if self.complete_runs.pop(rid, None) is not None:
                    self._deletions.append(item_path("run", rid))

    # -- queueing and committing ---------------------------------------------------------------------------
    def add_run(self, run_id: str, attrs: dict, arrays: dict, text: str | None = None) -> None:
        """Queue a run; `text`: its attributes encoded already (vcirun.io.batches.item_text of
        group_attrs(attrs)), as the sweep's workers send them (the client then does not encode them)."""
        self._raise_auto_error()
        with self._mutex:
            self._pending.append(Pending("run", run_id, attrs, arrays, text))
            self._pending_bytes += sum(a.nbytes if isinstance(a, np.ndarray) else np.asarray(a).nbytes
                                       for a in arrays.values())

    def add_reference(self, key: str, attrs: dict, arrays: dict) -> None:
        with self._mutex:
            if key in self.references or any(p.kind == "reference" and p.key == key for p in self._pending):
                return  # computed once per initial condition and stored once
            self._pending.append(Pending("reference", key, attrs, arrays))

    def maybe_commit(self) -> bool:
        """Commit if `commit_interval` has passed since the last commit, or the queue holds COMMIT_RUNS
        items or 256 MB."""
        self._raise_auto_error()
        with self._mutex:
            if not self._pending:
                return False
            if (time.monotonic() - self._last_commit >= self.commit_interval
                    or len(self._pending) >= COMMIT_RUNS or self._pending_bytes > 256 * 2**20):
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
            n_runs = sum(p.kind == "run" for p in self._pending)
            session = {**self.session, "computed": int(self.session.get("computed", 0)) + n_runs,
                       "updated": now_iso()}
            pieces, total = [], 0
            stamp = now_iso()
            tok = {"token": self._token}   # (each record names its session: see vcirun.io.journal)
            for path in self._deletions:
                pc, n = record_pieces("delete", path, extra=tok)
                pieces += pc
                total += n
            for kind in ("reference", "run"):   # the commit's items: one record per batch
                items = [p.item(stamp) for p in self._pending if p.kind == kind]
                for b in pack(items):
                    pc, n = batch_pieces(kind, b, self._token)
                    pieces += pc
                    total += n
            pc, n = record_pieces("session", "", extra={"history": list(self.prior_history) + [session],
                                                        "updated": stamp, **tok})
            pieces += pc
            total += n
            try:
                write_all(self._jfd, pieces)
                os.fsync(self._jfd)
            except OSError as e:
                # a torn tail would be ignored by readers; cut it so the journal stays clean
                with contextlib.suppress(OSError):
                    os.ftruncate(self._jfd, self._jend)
                    os.lseek(self._jfd, self._jend, os.SEEK_SET)  # a retry appends right after it
                err = StorageError(f"{self.journal_path}: cannot write results ({os_text(e)}); every run committed "
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
                pieces, n = record_pieces("open", "", extra={"token": token, "config_key": self.config_key,
                                                             "created": now_iso(), "pid": os.getpid()})
                write_all(fd, pieces)
                os.fsync(fd)
            except BaseException:
                os.close(fd)
                raise
        except OSError as e:
            with contextlib.suppress(OSError):
                jp.unlink()
            # the file was rewritten and names this journal: without it the session cannot commit
            err = write_error(self.path, e, "create the journal " + jp.name)
            self._failed = err  # finish() must not try another rewrite on this (likely full) disk
            raise err from None
        fsync_path(jp.parent, directory=True)
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
        tmp = self.tmp_path
        fresh = self._fresh or not self.path.exists()
        need = self._space_needed(journals)
        err = free_space_error(self.path, need)
        if err is not None:
            raise err
        n_runs = sum(p.kind == "run" for p in self._pending)
        session = {**self.session, "computed": int(self.session.get("computed", 0)) + n_runs, "updated": now_iso()}
        change = Rewrite(self.path, fresh, self.config_key, self.root_attrs, self._deletions, journals,
                         self._pending, list(self.prior_history) + [session], new_token, tuple(final_hooks))
        try:
            # a fresh file is small and written from scratch: no copy, no reservation (h5py's "w" would
            # truncate it away)
            replace_with_copy(self.path, tmp, lambda: change.write(tmp), copy=not fresh, need=need,
                              isolate=self.isolate)
        except StorageError:
            with contextlib.suppress(OSError):
                tmp.unlink()
            raise
        except BaseException as e:
            with contextlib.suppress(OSError):
                tmp.unlink()
            err = failure(self.path, e)
            if err is None:
                raise
            self._failed = err  # no further HDF5 write in this process (h5py's state after a failed write is suspect)
            raise err from e
        self._failed = None
        self.session = session
        for p in self._pending:
            (self.complete_runs if p.kind == "run" else self.references)[p.key] = dict(p.attrs)
        self._pending.clear()
        self._pending_bytes = 0
        self._deletions.clear()
        self._fresh = False
        self._last_commit = time.monotonic()
        if self._old_journal is not None and self._old_journal in journals:
            self._old_journal = None
        if self._jfd is None:  # any journal beside the file is now applied or stale
            with contextlib.suppress(OSError):
                self.journal_path.unlink()

    # -- background compaction -------------------------------------------------------------------------------
    def start_background_compaction(self, min_interval: float = 10.0) -> None:
        """Fold the journal into the HDF5 file from a forked child while the sweep runs (see
        vcirun.io.compaction), in rounds at least `min_interval` s apart."""
        if self._compactor is not None or self._jfd is None or not (self.isolate and hasattr(os, "fork")):
            return
        self._compactor = BackgroundCompactor(self.path, self._token, self._journal_base)
        self._compactor.start(min_interval)

    def stop_background_compaction(self, grace: float = 120.0) -> None:
        """Stop the compaction child between rounds (killed after `grace` s)."""
        if self._compactor is not None:
            compactor, self._compactor = self._compactor, None
            compactor.stop(grace)

    def _file_applied(self) -> int:
        try:
            with h5py.File(self.path, "r") as f:
                return applied(f)
        except Exception:  # noqa: BLE001 - then the whole journal is applied (idempotent)
            return 0

    # -- finishing ------------------------------------------------------------------------------------------
    def finish(self, status: str, final_hooks=None) -> None:
        """Commit what is queued, record how the current session ended ('complete', 'interrupted', ...) and
        compact: the journal is folded into the file and removed. `final_hooks` (default
        `self.final_hooks`) run inside that last rewrite, on the open file, whatever the status.
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
            hooks = list(self.final_hooks if final_hooks is None else final_hooks)
            if self._jfd is None:
                self.commit(force_write=True)
                return
            self.commit(force_write=True)
            journal = read_journal(self.journal_path)
            if journal is None or journal.token != self._token:
                raise StorageError(f"{self.journal_path}: the journal of the current session is missing or was replaced; "
                                   "rerun the same command to resume")
            # what a background compaction folded in already is skipped
            self._rewrite(new_token="", journals=[journal.after(self._file_applied())], final_hooks=hooks)
            self._close_journal()
            with contextlib.suppress(OSError):
                self.journal_path.unlink()
            fsync_path(self.path.parent, directory=True)

    def _commit_before_waiting(self) -> None:
        """Append what is queued to the journal before waiting for a background compaction round to end:
        a round takes seconds (the whole file is copied), and the runs that reach the client meanwhile
        would not be durable while finish() waits with the autocommit stopped (a kill would then lose
        more than commit_interval + one commit)."""
        with self._mutex:
            if (self._jfd is not None and self._failed is None and self._lock.held
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
            if self._pending and self._lock.held and self._failed is None:
                with contextlib.suppress(StorageError):
                    self.commit()
        finally:
            self._close_journal()
            with contextlib.suppress(OSError):
                self.tmp_path.unlink()
            self._release_lock()
