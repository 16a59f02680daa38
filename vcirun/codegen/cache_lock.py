"""Compile locks of the kernel cache that say who holds them.

`held(path, what)` takes an advisory lock (flock) on a file `kernels/<name>.lock` around a compile that
several processes may start at once (sweep workers, test workers, a shell loop): one compiles, the
others wait and then load what it cached. The kernel releases the lock when its holder dies, however
it dies. The holder writes into the lock file who it is (process id, host, command, what it
compiles) and touches the file every HEARTBEAT_S seconds from a background thread, so a waiter can
tell a holder at work from one that is not:

- after NOTE_AFTER_S seconds of waiting, one line names the holder and what it compiles;
- a holder that no longer runs (its descriptor inherited by a child that outlives it) is taken over at
  once;
- a holder that is stopped (SIGSTOP, Ctrl-Z) or whose heartbeat is older than STALL_S seconds (a hung
  network filesystem) is reported with the fix, and the waiter compiles without it;
- past `timeout_s` of waiting, or where locks cannot be made, the waiter goes ahead unlocked.

Going ahead without the lock costs time, never a result: every cache file is written atomically, and
two processes that compile the same code write the same files.
"""
from __future__ import annotations

import contextlib
import json
import os
import sys
import threading
import time
from pathlib import Path

from . import cache_store

NOTE_AFTER_S = 3.0
HEARTBEAT_S = 2.0
STALL_S = 30.0
POLL_S = 0.05
LOCK_TIMEOUT_S = 1800.0  # the longest cold build measured is MCVAA at n = 8 (~500 s)


def _command() -> str:
    return " ".join(os.path.basename(a) if i == 0 else a for i, a in enumerate(sys.argv[:4]))[:120] or "python"


def _record(fd: int, what: str) -> None:
    info = {"pid": os.getpid(), "host": os.uname().nodename, "what": what, "command": _command(),
            "since": time.time()}
    data = json.dumps(info).encode()
    os.ftruncate(fd, 0)
    os.pwrite(fd, data, 0)


def _holder(fd: int) -> dict | None:
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode())
        return info if isinstance(info, dict) and isinstance(info.get("pid"), int) else None
    except (OSError, ValueError, UnicodeDecodeError):
        return None


def _state(pid: int) -> str | None:
    """The process state letter of a local process (R, S, D, T, Z, ...), or None if it does not exist."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[-1].split()[0]
    except FileNotFoundError:
        return None
    except (OSError, IndexError):
        try:
            os.kill(pid, 0)
            return "?"
        except ProcessLookupError:
            return None
        except OSError:
            return "?"


def _describe(info: dict | None) -> str:
    if info is None:
        return "another process"
    host = "" if info.get("host") == os.uname().nodename else f" on {info.get('host')}"
    return f"process {info['pid']}{host} ({info.get('command', '?')})"


class _Heartbeat(threading.Thread):
    def __init__(self, fd: int):
        super().__init__(daemon=True, name="vcirun-lock-heartbeat")
        self.fd, self.stop = fd, threading.Event()

    def run(self):
        while not self.stop.wait(HEARTBEAT_S):
            try:
                os.utime(self.fd)
            except OSError:
                return


@contextlib.contextmanager
def held(path: Path, what: str, timeout_s: float = LOCK_TIMEOUT_S):
    """Hold the compile lock `path` (a file in the cache) while the block runs; see the module text for
    what a waiter does. `what` names the compile (it appears in the waiter's line)."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:
        fd = None
    if fd is None:
        yield
        return
    beat = None
    try:
        if _acquire(fd, Path(path), what, timeout_s):
            try:
                _record(fd, what)
            except OSError:
                pass
            beat = _Heartbeat(fd)
            beat.start()
        yield
    finally:
        if beat is not None:
            beat.stop.set()
            try:
                os.ftruncate(fd, 0)   # a free lock names no holder
            except OSError:
                pass
        try:
            os.close(fd)   # closing releases the lock
        except OSError:
            pass


def _acquire(fd: int, path: Path, what: str, timeout_s: float) -> bool:
    """True once the lock is ours; False when the waiter goes ahead without it."""
    try:
        import fcntl
    except ImportError:
        return False

    t0 = time.monotonic()
    noted = False
    gone = 0   # polls in a row that found the named holder gone (one could be a record not yet rewritten)
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            pass
        except OSError:
            return False   # a filesystem without locks
        waited = time.monotonic() - t0
        info = _holder(fd)
        local = info is not None and info.get("host") == os.uname().nodename
        if local and info["pid"] != os.getpid():
            st = _state(info["pid"])
            gone = gone + 1 if st is None or st == "Z" else 0
            if gone >= 3:
                cache_store.say(f"kernel cache: {_describe(info)}, which held the lock {path} for {info.get('what')}, "
                                f"no longer runs: compiling here")
                return False
            if st in ("T", "t") and waited >= min(NOTE_AFTER_S, 1.0):
                _stalled(info, path, "is stopped", f"resume it (kill -CONT {info['pid']}) or end it (kill {info['pid']})")
                return False
        if info is not None and waited >= STALL_S:
            try:
                idle = time.time() - os.fstat(fd).st_mtime
            except OSError:
                idle = 0.0
            if idle > STALL_S:
                fix = (f"end it (kill {info['pid']}) if it hangs" if local
                       else f"check process {info['pid']} on {info.get('host')}")
                _stalled(info, path, f"has shown no progress for {idle:.0f} s", fix + f", or remove {path}")
                return False
        if not noted and waited >= NOTE_AFTER_S:
            noted = True
            since = ""
            if info is not None and isinstance(info.get("since"), (int, float)):
                since = f" for {max(0.0, time.time() - info['since']):.0f} s"
            cache_store.say(f"waiting for {_describe(info)}, which has been compiling "
                            f"{(info or {}).get('what', what)}{since} (lock {path})")
        if waited > timeout_s:
            cache_store.say(f"kernel cache: waited {waited:.0f} s for the lock {path}; compiling here without it")
            return False
        time.sleep(POLL_S)


def _stalled(info: dict, path: Path, how: str, fix: str) -> None:
    cache_store.say(f"kernel cache: {_describe(info)} holds the compile lock {path} for {info.get('what')} but {how}: "
                    f"compiling here instead; {fix}")


@contextlib.contextmanager
def try_held(path: Path, what: str):
    """Hold the lock `path` while the block runs if it is free now: yields True (held, named, kept alive
    by the heartbeat) or False (another process holds it; nothing is waited for). Where locks cannot be
    made, yields True (the caller goes ahead: only time is lost then)."""
    try:
        import fcntl

        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except (ImportError, OSError):
        yield True
        return
    beat = None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            yield False
            return
        except OSError:
            yield True
            return
        try:
            _record(fd, what)
        except OSError:
            pass
        beat = _Heartbeat(fd)
        beat.start()
        yield True
    finally:
        if beat is not None:
            beat.stop.set()
            try:
                os.ftruncate(fd, 0)
            except OSError:
                pass
        os.close(fd)


def holder(path: Path) -> dict | None:
    """Who holds the lock `path` now ({pid, host, what, command, since}; {} when the holder wrote no
    record), or None when it is free or missing. Takes nothing: a free lock is released at once."""
    try:
        import fcntl

        fd = os.open(path, os.O_RDONLY)
    except (ImportError, OSError):
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _holder(fd) or {}
        except OSError:
            return None
        return None
    finally:
        os.close(fd)
