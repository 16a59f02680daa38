"""The single-writer lock of a results file: an flock on the hidden sibling `.NAME.lock`.

Readers never take it. The holder writes its pid into it and unlinks it on release; a writer that
finds the lock file replaced under it (a releasing writer unlinked it) backs off. Directories created
for the output are removed again when the session ends without having written the file.
"""
from __future__ import annotations

import contextlib
import errno
import os
from pathlib import Path

from .errors import StorageError, os_text

__all__ = ["WriterLock", "lock_path"]


def lock_path(path: Path) -> Path:
    return path.with_name(f".{path.name}.lock")


class WriterLock:
    """The lock of the results file `path` (use `acquire`, then `release`)."""

    def __init__(self, path: Path):
        self.path = path
        self.fd: int | None = None
        self._made_dirs: list[Path] = []  # innermost first

    @property
    def held(self) -> bool:
        return self.fd is not None

    def acquire(self) -> None:
        """Create the output's directory if needed and take the lock; StorageError naming the fix if
        another writer holds it or the place is not writable."""
        parent = self.path.parent
        lp = lock_path(self.path)
        missing = [d for d in [parent, *parent.parents] if not d.exists()]
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise StorageError(f"{self.path}: cannot create the directory {parent} ({os_text(e)}); choose "
                               "another --output") from None
        self._made_dirs = list(missing)  # removed again if the writing session ends without writing anything
        try:
            import fcntl
        except ImportError:  # pragma: no cover - non-POSIX: no guard against two concurrent writers
            return
        try:
            fd = os.open(lp, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            self._remove_made_dirs()
            raise StorageError(f"{self.path}: cannot write in {parent} ({os_text(e)}); choose a writable "
                               "--output") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            os.close(fd)
            if e.errno in (errno.EAGAIN, errno.EACCES):
                raise StorageError(f"{self.path}: another vcirun sweep is writing this file; wait for it or "
                                   "choose another --output") from None
            raise StorageError(f"{self.path}: cannot lock {lp} ({os_text(e)})") from None
        try:  # the lock file we hold must still be the one at lock_path (a releasing writer unlinks it)
            same = os.fstat(fd).st_ino == os.stat(lp).st_ino
        except OSError:
            same = False
        if not same:
            os.close(fd)
            raise StorageError(f"{self.path}: another vcirun sweep is starting or stopping on this file; "
                               "retry in a moment")
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        self.fd = fd

    def release(self) -> None:
        """Unlink and unlock; remove the directories `acquire` created if the file was never written."""
        if self.fd is not None:
            with contextlib.suppress(OSError):
                os.unlink(lock_path(self.path))
            os.close(self.fd)
            self.fd = None
            if not self.path.exists():
                self._remove_made_dirs()

    def _remove_made_dirs(self) -> None:
        for d in self._made_dirs:
            with contextlib.suppress(OSError):
                d.rmdir()
        self._made_dirs = []
