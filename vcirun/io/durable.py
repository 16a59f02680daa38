"""Writes that survive a kill, a full disk and the HDF5 library's failure modes.

- (`vcirun.core.fsync.fsync_path` pushes a file, or a directory entry after a rename, to the disk.)
- `reserve`: allocate a file's blocks before HDF5 writes into them, so that a full disk is met with
  ENOSPC here and not inside the HDF5 library (which, under ENOSPC, prints errors from deallocators
  and can crash the process).
- `run_isolated`: the HDF5 writes of a rewrite in a forked child (`child_setup`): whatever the library
  does when a write fails, the parent only learns that the copy could not be written.
- `replace_with_copy`: a file is never written in place: its copy is written, fsynced and renamed
  over it (`os.replace`), so a kill leaves either the previous or the next complete file. (Writing
  HDF5 in place, even with a flush per run, is not enough: a kill inside its metadata write can leave
  a file that no longer opens.)
"""
from __future__ import annotations

import contextlib
import errno
import gc
import json
import os
import shutil
from pathlib import Path

from ..core.fsync import fsync_path
from .errors import StorageError, one_line

__all__ = ["reserve", "ChildFailed", "child_setup", "run_isolated", "replace_with_copy"]


def reserve(path: Path, nbytes: int) -> None:
    """Allocate the file's blocks up to nbytes (HDF5 writes into them and truncates the file to its end
    of allocation on close), so that a full disk is met here with ENOSPC, before the HDF5 library runs."""
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


class ChildFailed(RuntimeError):
    """A forked writer failed: `io_failure` when by an OSError or a crash (the write failed, not the
    file's own structures)."""

    def __init__(self, text: str, errno_: int | None = None, io_failure: bool = False):
        super().__init__(text)
        self.errno = errno_
        self.io_failure = io_failure


def child_setup(keep_fd: int, background: bool = False) -> None:
    """A forked HDF5 writer: dies with its parent, prints nothing (the parent reports), no crash dump,
    and holds none of the parent's descriptors but `keep_fd` (copies of sockets, e.g. a Dask client's,
    would keep connections open that the parent closes); in the background also deaf to Ctrl-C (the
    parent stops it). Not niced: on a busy machine a niced compactor starves, and the final compaction
    then has everything to do."""
    # The parent's heap (numba, LLVM, the kernels: hundreds of MB) is shared copy-on-write; a garbage
    # collection here would walk it and copy every page it touches (0.15 s of a 0.2 s rewrite of the
    # fig4 sweep). Frozen, only what the child allocates is collected.
    gc.freeze()
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
    """Run fn in a forked child that dies with this process (PR_SET_PDEATHSIG); its exception comes
    back through a pipe as one line of JSON."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # child: no atexit handlers, no stdio flushes, stderr silenced
        code = 0
        try:
            os.close(r)
            child_setup(w)
            fn()
        except BaseException as e:  # noqa: BLE001 - reported to the parent
            code = 1
            with contextlib.suppress(BaseException):
                os.write(w, json.dumps({"type": type(e).__name__, "errno": getattr(e, "errno", None),
                                        "text": one_line(e, 400), "storage": isinstance(e, StorageError)}).encode())
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
        raise ChildFailed(f"the HDF5 library crashed (signal {os.WTERMSIG(status)}) while writing {tmp.name}",
                          io_failure=True)
    if os.WEXITSTATUS(status) != 0:
        try:
            info = json.loads(b"".join(chunks) or b"{}")
        except ValueError:
            info = {}
        text = info.get("text") or f"the writer exited with status {os.WEXITSTATUS(status)}"
        if info.get("storage"):
            raise StorageError(text)
        raise ChildFailed(text, info.get("errno"), io_failure=info.get("type") in ("OSError", "FileNotFoundError",
                                                                              "PermissionError"))


def run_isolated(fn, path: Path, *, isolate: bool = True) -> None:
    """fn() (HDF5 writes that replace `path` atomically) in a forked child where fork exists and
    `isolate`; its failure is raised here (StorageError as such, anything else as RuntimeError), a
    crash as RuntimeError naming the signal."""
    if isolate and hasattr(os, "fork"):
        _in_child(fn, Path(path))
    else:
        fn()


def replace_with_copy(path: Path, tmp: Path, write, *, copy: bool = True, need: int = 0,
                      isolate: bool = False) -> None:
    """Replace `path` atomically by a new version written through `tmp` (beside it, so that the rename
    stays on one filesystem): with `copy`, copy the file to tmp and reserve `need` bytes for it; then
    write() (in a forked child with `isolate`, see run_isolated), fsync tmp, rename it over `path` and
    fsync the directory. `path` itself is never written; on failure the caller removes tmp."""
    if copy:
        shutil.copyfile(path, tmp)
        reserve(tmp, need)  # the space HDF5 writes into, taken now: a full disk fails here, cleanly
    run_isolated(write, tmp, isolate=isolate)
    fsync_path(tmp)
    os.replace(tmp, path)
    fsync_path(path.parent, directory=True)
