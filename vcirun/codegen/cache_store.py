"""The kernel cache's files on disk: where the cache is, how a file is written and sealed, how a damaged
one is set aside.

Every file vcirun writes to the cache is written atomically (a temporary file in the same directory,
fsync, rename over the name, fsync of the directory): a crash leaves the old file or the new one,
never a prefix. It carries the digest of what it should hold, so that a load can check a file before
trusting it:

- generated modules (`vk_<key>.py`) end with a *seal* line, `# vcirun-seal {...}`: the module key, the
  system, the kernel set and the SHA-256 of the module key and the text above the line (`seal_text`);
- warm-index entries (`wi_<key>.json`) hold a `seal` field, the SHA-256 of the rest (`seal_json`);
- numba's index and data files start with a header line holding the SHA-256 of the file's name and
  the payload (vcirun.codegen.numba_cache);
- a C shared object (`vkc_<hash>.so`) has its digest in a sidecar `vkc_<hash>.so.sha256`, and in the
  module that loads it (vcirun.codegen.c_link).

A file that fails its check (truncated, zero-length, one flipped bit, edited, renamed) is moved to
`<cache>/quarantine/` and rebuilt, and the move is said on one line (`say`). A cache that cannot be
used at all (an empty VCIRUN_CACHE_DIR, a file where a directory should be, no permission, a full
disk) is a `CacheError`: one line naming the directory and the fix.
"""
from __future__ import annotations

import errno
import hashlib
import json
import logging
import os
import secrets
import signal
import threading
import time
from pathlib import Path

from ..core.fsync import fsync_path

ENV = "VCIRUN_CACHE_DIR"
QUARANTINE = "quarantine"
SEAL = "# vcirun-seal "
TMP_MARK = ".tmp."        # temporary files: .<name>.tmp.<pid>.<host>.<random>
BUILD_DIR_MARK = ".vkc_build."  # the C compiler's working directories: .vkc_build.<pid>.<host>.<random>
STALE_S = 3600.0          # a temporary file of a process on another host is stale after this long

_log = logging.getLogger("vcirun.build")


class CacheError(ValueError):
    """The kernel cache cannot be used as it is: the message names the directory and the fix."""


class CacheDamage(CacheError):
    """A cache file failed its check; `path` is the file. Raised where the caller rebuilds the entry
    (it names the file and the fix if it ever reaches the user)."""

    def __init__(self, path, reason: str):
        self.path, self.reason = Path(path), reason
        super().__init__(f"kernel cache file {path} {reason}: remove it or run `vcirun cache clear`")


# --- where the cache is -------------------------------------------------------------------------------

def root() -> Path:
    """The cache directory: $VCIRUN_CACHE_DIR (absolute), else ~/.cache/vcirun. An empty value is refused
    (it would put the cache into the current directory)."""
    v = os.environ.get(ENV)
    if v is None:
        base = Path.home() / ".cache" / "vcirun"
    elif not v.strip():
        raise CacheError(f"{ENV} is set but empty: unset it (the kernel cache is then ~/.cache/vcirun) or set "
                         f"it to a directory")
    else:
        base = Path(v).expanduser()
    return Path(os.path.abspath(base))


def kernels_dir() -> Path:
    """root()/kernels, created if missing. CacheError when it cannot exist as a directory. A read-only
    cache is returned: what it holds is loaded, and writing into it fails with a CacheError then."""
    r = root()
    k = r / "kernels"
    if k.is_dir():
        return k
    fix = f"set {ENV} to a writable directory"
    for p in (r, *r.parents):
        if p.exists() and not p.is_dir():
            raise CacheError(f"kernel cache {r}: {p} is a file, not a directory: remove or rename it, or {fix}")
    if k.exists() or k.is_symlink():
        raise CacheError(f"kernel cache {r}: {k} is not a directory: remove it (`vcirun cache clear` does), or {fix}")
    try:
        k.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise CacheError(f"cannot create the kernel cache {k} ({e.strerror or e}): {_fix_for(e, r)}") from None
    return k


def writable(d: Path) -> bool:
    return os.access(d, os.W_OK | os.X_OK)


def _fix_for(e: OSError, where: Path) -> str:
    if e.errno == errno.EFBIG:
        return f"raise the file-size limit (ulimit -f), or set {ENV} to a directory on another disk"
    if e.errno in (errno.ENOSPC, errno.EDQUOT):
        return f"free space on the disk of {where}, or set {ENV} to a directory on another disk"
    if e.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return f"make {where} writable, or set {ENV} to a writable directory"
    return f"check {where}, or set {ENV} to another directory"


def write_error(path: Path, e: OSError, what: str = "") -> CacheError:
    """The CacheError of a failed write of `path`."""
    r = _root_of(path)
    return CacheError(f"kernel cache {r}: cannot write {what or path.name} ({e.strerror or e}): {_fix_for(e, r)}")


def _root_of(path: Path) -> Path:
    for p in Path(path).parents:
        if p.name == "kernels":
            return p.parent
    return Path(path).parent


# --- what the cache says -------------------------------------------------------------------------------

_said: set = set()
LISTENERS: list = []   # f(message) -> True if it showed the message (vcirun.codegen.cache forwards to the CLI)


def say(message: str, once: str | None = None) -> None:
    """One line about the cache: to the listeners (the CLI prints it on stderr), else to the logger as a
    warning. `once`: a key said at most once per process."""
    if once is not None:
        if once in _said:
            return
        _said.add(once)
    shown = False
    for listener in list(LISTENERS):
        shown = bool(listener(message)) or shown
    if not shown:
        _log.warning(message)


def said(once: str) -> None:
    """Count `once` as said (a line that said the same in other words came first)."""
    _said.add(once)


QUIET_ENV = "VCIRUN_QUIET"


def listen(callback) -> None:
    """Show build notices and cache notices through `callback(message) -> True` (the CLI prints them on
    stderr); once per callback. Without a listener, notices go to the logger "vcirun.build"."""
    if callback not in LISTENERS:
        LISTENERS.append(callback)


def tell(msg: str) -> None:
    """A build notice ("compiling ... about N s", which tier runs): to the listeners (`listen`: the CLI
    prints them on stderr), else to the logger "vcirun.build" at INFO, which prints it on stderr unless
    logging is configured otherwise: off with VCIRUN_QUIET=1, or as any logger
    (logging.getLogger("vcirun").setLevel(logging.WARNING))."""
    if LISTENERS:
        for cb in list(LISTENERS):
            cb(msg)
        return
    if os.environ.get(QUIET_ENV, "").strip() not in ("", "0"):
        return
    top = logging.getLogger("vcirun")
    if not top.hasHandlers():   # nothing configured: the notice goes to stderr, as the CLI's do
        handler = logging.StreamHandler()
        handler.setFormatter(logging.Formatter("%(message)s"))
        top.addHandler(handler)
        if top.level == logging.NOTSET:
            top.setLevel(logging.INFO)
    _log.info(msg)


TIMES_FILE = "build_times.json"


def build_times() -> dict:
    """The recorded build times, {"<family>|<n>" or "core|<key>": seconds} (only well-formed entries:
    the file is advisory, a damaged one is ignored)."""
    try:
        raw = json.loads((root() / TIMES_FILE).read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return {}
    if not isinstance(raw, dict):
        return {}
    out = {}
    for k, v in raw.items():
        if isinstance(k, str) and "|" in k and isinstance(v, (int, float)) and not isinstance(v, bool) \
                and 0 <= v < 1e6:
            if k.startswith("core|") or k.rsplit("|", 1)[1].isdigit():
                out[k] = float(v)
    return out


# --- digests and seals ---------------------------------------------------------------------------------

def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def file_sha256(path: Path) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def seal_text(body: str, meta: dict) -> str:
    """A module's text with its seal line: meta (key, system, kernel set) and the SHA-256 of meta's
    key and the body."""
    if not body.endswith("\n"):
        body += "\n"
    meta = dict(meta, sha256=sha256(f"{meta['key']}\n".encode() + body.encode()))
    return body + SEAL + json.dumps(meta, sort_keys=True) + "\n"


def unseal_text(data: bytes, key: str) -> tuple[str, dict]:
    """(body, meta) of a sealed module of this key; CacheDamage's reason (a ValueError) if it is not."""
    if not data:
        raise ValueError("is empty")
    cut = data.rfind(SEAL.encode(), 0, len(data))
    if cut < 0 or (cut > 0 and data[cut - 1:cut] != b"\n") or not data.endswith(b"\n"):
        raise ValueError("has no seal line (truncated, or not written by this vcirun)")
    body = data[:cut]
    try:
        meta = json.loads(data[cut + len(SEAL):].decode())
    except (UnicodeDecodeError, ValueError):
        raise ValueError("has a damaged seal line") from None
    if not isinstance(meta, dict) or meta.get("key") != key:
        raise ValueError(f"is sealed for another key ({meta.get('key') if isinstance(meta, dict) else '?'})")
    if meta.get("sha256") != sha256(f"{key}\n".encode() + body):
        raise ValueError("does not match its digest (changed or damaged)")
    try:
        return body.decode(), meta
    except UnicodeDecodeError:
        raise ValueError("is not text") from None


def seal_json(entry: dict) -> str:
    rest = {k: v for k, v in entry.items() if k != "seal"}
    text = json.dumps(rest, sort_keys=True, separators=(",", ":"))
    return json.dumps(dict(rest, seal=sha256(text.encode())), sort_keys=True)


def unseal_json(data: bytes) -> dict:
    """The entry of a sealed JSON file; ValueError (the reason) if it fails its seal."""
    try:
        entry = json.loads(data.decode())
    except (UnicodeDecodeError, ValueError):
        raise ValueError("is not valid JSON (truncated or damaged)") from None
    if not isinstance(entry, dict) or "seal" not in entry:
        raise ValueError("has no seal (not written by this vcirun)")
    rest = {k: v for k, v in entry.items() if k != "seal"}
    if entry["seal"] != sha256(json.dumps(rest, sort_keys=True, separators=(",", ":")).encode()):
        raise ValueError("does not match its digest (changed or damaged)")
    return rest


# --- atomic writes -------------------------------------------------------------------------------------

def _ignore_sigxfsz() -> None:
    """A file-size limit (ulimit -f) makes a too-long write fail with EFBIG (reported) instead of killing
    the process with SIGXFSZ."""
    if threading.current_thread() is threading.main_thread() and hasattr(signal, "SIGXFSZ"):
        try:
            if signal.getsignal(signal.SIGXFSZ) == signal.SIG_DFL:
                signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        except (ValueError, OSError):
            pass


def host_tag() -> str:
    """A short tag of this host, in temporary names: a leftover is another host's or this one's."""
    return sha256(os.uname().nodename.encode())[:6]


def owner_tag() -> str:
    """<pid>.<host>.<random>: the end of a temporary name (`sweep_stale` reads the pid and host back)."""
    return f"{os.getpid()}.{host_tag()}.{secrets.token_hex(4)}"


def tmp_name(path: Path) -> Path:
    return path.with_name(f".{path.name}{TMP_MARK}{owner_tag()}")


def write_atomic(path: Path, data: bytes | str, what: str = "") -> None:
    """Write `data` to `path` atomically and durably (temporary file, fsync, rename, fsync of the
    directory). CacheError naming the cache and the fix when it cannot."""
    _ignore_sigxfsz()
    path = Path(path)
    if isinstance(data, str):
        data = data.encode()
    tmp = tmp_name(path)
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except OSError as e:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise write_error(path, e, what) from None
    fsync_path(path.parent, directory=True)


def publish(tmp: Path, path: Path, what: str = "") -> None:
    """Rename a finished temporary file (already fsynced) over `path` and fsync the directory."""
    try:
        os.replace(tmp, path)
    except OSError as e:
        raise write_error(path, e, what) from None
    fsync_path(path.parent, directory=True)


def read(path: Path) -> bytes | None:
    """The bytes of a cache file, None if it does not exist. A file that exists but cannot be read
    (permissions, a directory in its place) is CacheDamage."""
    try:
        with open(path, "rb") as f:
            return f.read()
    except FileNotFoundError:
        return None
    except OSError as e:
        raise CacheDamage(path, f"cannot be read ({e.strerror or e})") from None


# --- quarantine ----------------------------------------------------------------------------------------

def quarantine(path: Path, reason: str, *, rebuild: str = "rebuilding it", quiet: bool = False) -> None:
    """Move a damaged cache file aside (to <cache>/quarantine/) and say so on one line (unless `quiet`:
    a line about the same entry came first); where it cannot be moved (a read-only cache), it is ignored
    by this process."""
    path = Path(path)
    r = _root_of(path)
    qdir = r / QUARANTINE
    try:
        qdir.mkdir(exist_ok=True)
        os.replace(path, qdir / f"{path.name}.{int(time.time())}.{os.getpid()}")
        where = f"moved to {qdir}"
    except FileNotFoundError:
        if not path.exists() and not path.is_symlink():
            where = "gone"
        else:
            where = "left in place (cannot move it)"
    except OSError as e:
        try:
            os.unlink(path)   # e.g. a quarantine directory that cannot be made: the file goes
            where = "removed"
        except OSError:
            where = f"left in place ({e.strerror or e}; this process does not use it)"
    if not quiet:
        say(f"kernel cache: {path} {reason}; {where}; {rebuild}", once=f"quarantine|{path}|{where}")


# --- leftovers of killed processes ---------------------------------------------------------------------

def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    try:   # a zombie has released its files
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[-1].split()[0] != "Z"
    except OSError:
        return True


def sweep_stale(d: Path) -> int:
    """Remove the temporary files and C build directories of processes that no longer run (killed
    mid-write) from directory `d` (vcirun.codegen.kernel_cache sweeps each cache directory once per
    kernel cache). Returns how many were removed."""
    d = Path(d)
    import shutil

    n = 0
    now = time.time()
    try:
        entries = list(os.scandir(d))
    except OSError:
        return 0
    for e in entries:
        name = e.name
        if TMP_MARK in name and name.startswith("."):
            tag = name.rsplit(TMP_MARK, 1)[1]
        elif name.startswith(BUILD_DIR_MARK):
            tag = name[len(BUILD_DIR_MARK):]
        else:
            continue
        try:
            pid, host = tag.split(".")[:2]
            age = now - e.stat(follow_symlinks=False).st_mtime
            stale = (host == host_tag() and not _pid_alive(int(pid))) or age > STALE_S
        except (OSError, ValueError):
            continue
        if not stale:
            continue
        try:
            if e.is_dir(follow_symlinks=False):
                shutil.rmtree(e.path)
            else:
                os.unlink(e.path)
            n += 1
        except OSError:
            pass
    return n
