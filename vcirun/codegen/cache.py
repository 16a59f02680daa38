"""The kernel cache on disk (`vcirun cache info|clear`), and what a cold build says about itself
(vcirun.codegen.compile_notes, here with the API's kernel cache as the default).

One directory for every entry point (API, CLI, Makefile, tests): $VCIRUN_CACHE_DIR, else
~/.cache/vcirun (vcirun.codegen.cache_store.root; an empty VCIRUN_CACHE_DIR is refused).

It holds one generated module per (system, kernel set) (`kernels/vk_<key>.py`), the shared cores
(`kernels/core_<key>.py`), the C kernels' shared objects (`kernels/vkc_<hash>.so` and their digests),
numba's compiled code for all of them (`kernels/__pycache__/`, also when NUMBA_CACHE_DIR is set:
vcirun.codegen.numba_cache), the warm-start index (`kernels/wi_<key>.json`), the compile locks
(`kernels/*.lock`), the files set aside by a failed check (`quarantine/`) and the build times that
estimate the next cold build (`build_times.json`). Keys hash the package sources, so every vcirun
version adds modules and nothing removes old ones: the cache grows until cleared.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from . import cache_lock, cache_store, compile_notes
from .cache_store import listen, tell  # noqa: F401 - the notices' entry points

__all__ = ["CacheInfo", "ClearResult", "info", "clear", "cache_root", "announce_if_cold", "note_first_call",
           "estimate_compile_s", "core_estimate_s", "cold_parts", "core_key_for", "tell", "listen", "first_call_lock"]

_TIMES_FILE = cache_store.TIMES_FILE
LOCK_TIMEOUT_S = cache_lock.LOCK_TIMEOUT_S


def cache_root() -> Path:
    """The cache directory (CacheError for an empty VCIRUN_CACHE_DIR)."""
    return cache_store.root()


# vcirun.codegen.compile_notes with the API's kernel cache (vcirun.codegen.kernel_cache.default) when no
# `kc` is given

def _kc(kc):
    from .kernel_cache import default

    return default() if kc is None else kc


def core_estimate_s(core_key: str, first: float = None) -> float:
    """compile_notes.core_estimate_s."""
    return compile_notes.core_estimate_s(core_key, first)


def estimate_compile_s(ks, n: int, features: tuple = (), with_core: bool = True, kc=None) -> float:
    """compile_notes.estimate_compile_s."""
    return compile_notes.estimate_compile_s(ks, n, features, with_core, kc=_kc(kc))


def cold_parts(system, ks, kc=None) -> tuple[str, ...]:
    """compile_notes.cold_parts."""
    return compile_notes.cold_parts(system, ks, kc=_kc(kc))


def core_key_for(system, ks, kc=None) -> str:
    """compile_notes.core_key_for."""
    return compile_notes.core_key_for(system, ks, kc=_kc(kc))


def announce_if_cold(system, ks, cores_covered=(), kc=None) -> bool:
    """compile_notes.announce_if_cold."""
    return compile_notes.announce_if_cold(system, ks, cores_covered, kc=_kc(kc))


def note_first_call(mod, ks, seconds: float, kc=None) -> None:
    """compile_notes.note_first_call."""
    compile_notes.note_first_call(mod, ks, seconds, kc=_kc(kc))


def first_call_lock(mod, timeout_s: float = LOCK_TIMEOUT_S, kc=None):
    """compile_notes.first_call_lock."""
    return compile_notes.first_call_lock(mod, timeout_s, kc=kc)


@dataclass
class CacheInfo:
    path: Path
    modules: int          # generated modules (vk_*.py)
    index_entries: int    # warm-start index entries (wi_*.json)
    files: int
    bytes: int
    cores: int = 0        # shared cores (core_*.py, vcirun.codegen.shared)
    shared_objects: int = 0   # C kernels (vkc_*.so)
    numba_files: int = 0      # numba's compiled code (kernels/__pycache__/)
    quarantined: int = 0      # files set aside by a failed check (quarantine/)
    compiled: list = field(default_factory=list)   # "system/family" of the modules marked compiled
    building: list = field(default_factory=list)   # (what, holder info) of the compiles in progress
    failed: list = field(default_factory=list)     # (system, reason, log) of background compiles that failed


def _walk(root: Path) -> list:
    """Every file below root (symbolic links as files, never followed)."""
    out = []
    for dirpath, dirnames, filenames in os.walk(root, onerror=None, followlinks=False):
        out += [Path(dirpath) / f for f in filenames]
        out += [Path(dirpath) / d for d in dirnames if (Path(dirpath) / d).is_symlink()]
    return out


def _size(p: Path) -> int:
    try:
        return p.lstat().st_size
    except OSError:  # a temporary file another process just renamed
        return 0


def _check_root(root: Path) -> None:
    if root.exists() and not root.is_dir():
        raise cache_store.CacheError(f"kernel cache {root} is a file, not a directory: remove or rename it, or set "
                                     f"{cache_store.ENV} to a directory")


def info() -> CacheInfo:
    """What the cache holds, what is compiled and what is being compiled (nothing is created)."""
    from . import background

    root = cache_root()
    _check_root(root)
    files = _walk(root) if root.is_dir() else []
    k = root / "kernels"
    top = [p for p in files if p.parent == k]
    out = CacheInfo(root, sum(p.name.startswith("vk_") and p.suffix == ".py" for p in top),
                    sum(p.name.startswith("wi_") and p.suffix == ".json" for p in top), len(files),
                    sum(_size(p) for p in files), sum(p.name.startswith("core_") and p.suffix == ".py" for p in top),
                    sum(p.name.startswith("vkc_") and p.suffix == ".so" for p in top),
                    sum(p.parent == k / "__pycache__" for p in files),
                    sum(p.parent == root / cache_store.QUARANTINE for p in files))
    for p in sorted(top):
        name = p.name
        if name.startswith("vk_") and name.endswith(".ready"):
            m = background.marker(k, name[3:-6])
            if m is not None:
                out.compiled.append(f"{m.get('system')}/{m.get('family')}")
        elif name.endswith(".lock") and (name.startswith("bg_") or name.startswith("vk_")) \
                and not name.startswith("bg_slot"):
            who = cache_lock.holder(p)
            if who is not None:
                out.building.append((who.get("what", name[:-5]), who))
        elif name.startswith("bg_") and name.endswith(".failed"):
            f = background.failure(k, name[3:-7])
            if f is not None:
                out.failed.append((f.get("system"), f.get("reason"), f.get("log")))
    return out


@dataclass
class ClearResult:
    before: CacheInfo
    removed_files: int = 0
    removed_bytes: int = 0
    failed: list = field(default_factory=list)   # [(path, reason)]

    @property
    def path(self) -> Path:
        return self.before.path


def clear() -> ClearResult:
    """Remove every cached kernel, numba file, index entry, lock, quarantined file and build time (the
    next run of each system compiles again). Reports what was removed and what could not be: a file
    that is still there afterwards is a failure, whatever the file system said. Modules already loaded
    by running processes are unaffected."""
    before = info()
    res = ClearResult(before)
    root = before.path
    targets = [root / "kernels", root / cache_store.QUARANTINE, root / _TIMES_FILE]
    for t in targets:
        if t.is_symlink() or t.is_file():
            _remove(t, res)
        elif t.is_dir():
            for p in _walk(t):
                _remove(p, res)
            for dirpath, dirnames, _ in sorted(os.walk(t, followlinks=False), key=lambda e: -len(e[0])):
                for d in dirnames:
                    dp = Path(dirpath) / d
                    if not dp.is_symlink():
                        try:
                            dp.rmdir()
                        except OSError:
                            pass
            try:
                t.rmdir()
            except OSError:
                pass
    return res


def _remove(p: Path, res: ClearResult) -> None:
    size = _size(p)
    try:
        p.unlink()
    except FileNotFoundError:
        return
    except OSError as e:
        res.failed.append((p, e.strerror or str(e)))
        return
    if os.path.lexists(p):
        res.failed.append((p, "still there after removal"))
        return
    res.removed_files += 1
    res.removed_bytes += size
