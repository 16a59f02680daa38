"""Background compaction: a forked child folds a running session's journal into the HDF5 file, so
that plain h5py sees the runs committed up to a round ago and the final compaction only has the tail
to do.

Each round copies the file, applies the journal's new records, records how far (`journal_applied`)
and atomically replaces the file; rounds are at least `min_interval` and 4 round durations apart. The
commits and their loss bound do not depend on it: a failed or killed round changes nothing (readers
and resumes apply the journal past `journal_applied`).
"""
from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path

import h5py

from ..run.trajectory_files import encode_attr, storable
from .batches import count_items
from .checks import LIBVER
from .durable import child_setup, replace_with_copy
from .journal import apply_journal, journal_path, read_journal
from .provenance import now_iso

__all__ = ["BackgroundCompactor", "compact_path"]


def compact_path(path: Path) -> Path:
    """The compactor's copy of the results file `path` (a hidden sibling)."""
    return path.with_name(f".{path.name}.compacting")


class BackgroundCompactor:
    """The compaction child of the session whose journal (token `token`) extends `path`; `base` is the
    journal offset past its open record."""

    def __init__(self, path: Path, token: str, base: int):
        self.path, self.token, self.base = path, token, base
        self._child: tuple | None = None  # (pid, write end of the pipe whose closing stops it)

    def start(self, min_interval: float) -> None:
        r, w = os.pipe()
        pid = os.fork()
        if pid == 0:
            code = 0
            try:
                os.close(w)
                child_setup(r, background=True)
                self._loop(r, float(min_interval))
            except BaseException:  # noqa: BLE001 - the parent's final compaction does what is left
                code = 1
            finally:
                os._exit(code)
        os.close(r)
        self._child = (pid, w)

    def _loop(self, stop_fd: int, min_interval: float) -> None:
        import select

        applied, interval = self.base, min_interval
        while True:
            if select.select([stop_fd], [], [], interval)[0]:
                return  # the parent closed the pipe: stop between rounds
            j = read_journal(journal_path(self.path))
            if j is None or j.token != self.token:
                return
            new = j.after(applied)
            if not any(r.kind != "session" for r in new.records):
                continue
            t0 = time.monotonic()

            def write():
                with h5py.File(compact_path(self.path), "a", libver=LIBVER) as f:
                    apply_journal(f, new, self.path)
                    sessions = [r for r in new.records if r.kind == "session"]
                    if sessions and isinstance(sessions[-1].header.get("history"), list):
                        f.attrs["history"] = storable(encode_attr("history", sessions[-1].header["history"]))
                        f.attrs["updated"] = storable(str(sessions[-1].header.get("updated", now_iso())))
                    f.attrs["n_runs_complete"] = count_items(f, "run")
                    f.attrs["journal_applied"] = int(new.good_end)

            replace_with_copy(self.path, compact_path(self.path), write,
                              need=self.path.stat().st_size + 2 * new.new_bytes + 2**20)
            applied = new.good_end
            interval = max(min_interval, 4.0 * (time.monotonic() - t0))

    def stop(self, grace: float) -> None:
        """Ask the child to stop between rounds (a round under way is finished: its work is work the
        final compaction would do); one still running after `grace` s is killed (the file is then the
        previous round's, which is consistent)."""
        if self._child is None:
            return
        pid, w = self._child
        self._child = None
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
            time.sleep(0.002)  # (the child exits as soon as it sees the pipe closed)
        with contextlib.suppress(OSError):
            compact_path(self.path).unlink()
