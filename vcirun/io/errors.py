"""The one error of the results files, `StorageError`, and the one-line texts its messages are made of.

Every failure a user can meet with a results file (unreadable, foreign, written by another config,
locked, damaged, a write that failed) is one `StorageError` whose text names the path and the fix;
the CLI prints it as it is.
"""
from __future__ import annotations

import errno
import re
from pathlib import Path

__all__ = ["StorageError", "os_text", "one_line", "short", "write_error"]


class StorageError(RuntimeError):
    """A results file that cannot be used (unreadable, foreign, written by another config, locked,
    damaged, or a write that failed: disk full, read-only, ...); one line naming the path."""


def os_text(e: BaseException) -> str:
    """The OS reason of an error in one line (strerror when there is one)."""
    text = getattr(e, "strerror", None) or str(e)
    return " ".join(str(text).split()) or type(e).__name__


# HDF5's "(file write failed: ..., errno = 28, error message = 'No space left on device', ...)"
_HDF5_REASON = re.compile(r"(?:errno = (\d+), )?error message = '([^']*)'")


def one_line(e, limit: int = 300) -> str:
    """An exception's text on one line, at most `limit` characters; an HDF5 error stack is reduced to
    the reason it carries."""
    s = " ".join(str(e).split()) or type(e).__name__
    m = _HDF5_REASON.search(s)
    if m:
        s = f"HDF5: {m.group(2)}" + (f", errno {m.group(1)}" if m.group(1) else "")
    return s if len(s) <= limit else s[: limit - 3] + "..."


def short(v) -> str:
    """repr(v), cut to 40 characters (a foreign attribute value quoted in a message)."""
    s = repr(v)
    return s if len(s) <= 40 else s[:37] + "..."


def write_error(path: Path, e: BaseException, doing: str) -> StorageError:
    """The StorageError of an OS error met while `doing` something to the results file `path`, with
    the fix for a full disk or a read-only place."""
    extra = ""
    if isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
        extra = "; free some space (or choose another --output)"
    elif isinstance(e, OSError) and e.errno in (errno.EROFS, errno.EACCES, errno.EPERM):
        extra = "; choose a writable --output"
    return StorageError(f"{path}: cannot {doing} ({os_text(e)}){extra}")
