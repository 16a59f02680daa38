"""The kernel cache on disk (`vcirun cache info|clear`) and what a cold build says about itself.

One directory for every entry point (API, CLI, Makefile, tests): $VCIRUN_CACHE_DIR, else
~/.cache/vcirun (`vcirun.codegen.build.cache_dir`'s parent).

It holds one generated module per (system, kernel set) (`kernels/vk_<key>.py`), numba's compiled
code for it (`kernels/__pycache__/`), the warm-start index (`kernels/wi_<key>.json`) and the build
times that estimate the next cold build (`build_times.json`). Keys hash the package sources, so every
vcirun version adds modules and nothing removes old ones: the cache grows until cleared.
"""
from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

__all__ = ["CacheInfo", "info", "clear", "cache_root", "announce_if_cold", "note_first_call", "estimate_compile_s",
           "family", "COMPILE_CALLBACKS", "first_call_lock"]

COMPILE_CALLBACKS: list = []   # f(message) on a cold build; the CLI prints the message on stderr
_log = logging.getLogger("vcirun.build")
_TIMES_FILE = "build_times.json"
# first estimates before this cache has timed a build (measured on this 2-core machine: CVA on the
# cart-pendulum 9 s, MCVAC 14-20 s)
_DEFAULT_S = {"CVA": 10.0, "VCI": 10.0, "MCVA": 20.0}
# shared build: a scene's kernels (cart-pendulum CVA 3.4 s, MCVAC 4.8 s) and a core (50-60 s, once per machine)
_DEFAULT_SCENE_S = {"CVA": 3.5, "VCI": 3.5, "MCVA": 5.5}
_DEFAULT_CORE_S = 55.0
LOCK_TIMEOUT_S = 1800.0  # first_call_lock: the longest cold build measured is MCVAA at n = 8 (~500 s)


def cache_root() -> Path:
    from .build import cache_dir

    return cache_dir().parent


def family(ks) -> str:
    """Short name of a kernel set: CVA[SVC], VCI[SVC], MCVA[SVA,s=4], CVA[SVC x5] ..."""
    if ks.modified is not None:
        return f"MCVA[{ks.modified[0]},s={ks.modified[1]}]"
    if ks.reset is None:
        return "system"  # the system-only kernels (reference, dense output, verify)
    names = [s for s, _ in ks.full_stages]
    if len(names) == 1:
        stages = names[0]
    elif len(set(names)) == 1:
        stages = f"{names[0]} x{len(names)}"
    else:
        stages = ",".join(dict.fromkeys(names))
    return f"{ks.reset.upper()}[{stages}]"


def _times() -> dict:
    try:
        return json.loads((cache_root() / _TIMES_FILE).read_text())
    except (OSError, ValueError):
        return {}


def estimate_compile_s(ks, n: int) -> float:
    """Seconds a cold build of (ks, n) is expected to take: this cache's last build of the same family
    and size, else of the same family at another size (scaled linearly in n), else a first estimate.
    Shared build (vcirun.codegen.shared): the scene's kernels, plus the core if numba has not cached it."""
    from . import build

    times, kind = _times(), (ks.reset or "system").upper()
    if build.build_mode() != "shared":
        return _by_family(times, family(ks), n, _DEFAULT_S.get(kind, 15.0))
    key = build.core_key_of(ks, n)
    core = 0.0 if build.core_compiled(key) else float(times.get(f"core|{key}", _DEFAULT_CORE_S))
    return _by_family(times, "scene|" + family(ks), n, _DEFAULT_SCENE_S.get(kind, 3.5)) + core


def _by_family(times: dict, fam: str, n: int, first: float) -> float:
    """The recorded time of (fam, n), else of fam's largest recorded n scaled linearly, else `first`
    (a 2-DOF figure) scaled."""
    if f"{fam}|{n}" in times:
        return float(times[f"{fam}|{n}"])
    same = [(int(k.rsplit("|", 1)[1]), float(v)) for k, v in times.items() if k.rsplit("|", 1)[0] == fam]
    m, v = max(same) if same else (2, first)
    return v * max(1.0, n / m)


def announce_if_cold(system, ks) -> bool:
    """Before loading the module of (system, ks): if it must be generated and compiled, say so
    ("compiling kernels for <scene>/<family> (first time, about N s)") to the logger and callbacks."""
    from . import build

    key = build.module_key(system, ks)
    if key in build._loaded:   # (no file access on the path of every later call)
        return False
    if (build.cache_dir() / f"vk_{key}.py").exists():
        if build.build_mode() != "shared" or build.core_compiled(build.core_key_of(ks, system.n)):
            return False
    msg = (f"compiling kernels for {system.name}/{family(ks)} (first time, about "
           f"{estimate_compile_s(ks, system.n):.0f} s; cached in {cache_root()})")
    _log.info(msg)
    for cb in list(COMPILE_CALLBACKS):
        cb(msg)
    return True


def note_first_call(mod, ks, seconds: float) -> None:
    """After numba's first call of a module's loop: if the module was generated in this process,
    record generation + first call as the build time of its family and size (the next estimate)."""
    from . import build

    key = mod.__name__.rsplit("_", 1)[-1]
    entry = next((e for e in reversed(build.BUILD_LOG) if e["key"] == key), None)
    if entry is None or (entry["cached"] and not entry.get("core_cold")):
        return
    try:
        times = _times()
        if "link_s" in entry:   # shared build: the scene's kernels, and the core's first compile apart
            if not entry["cached"]:
                times[f"scene|{family(ks)}|{int(mod.NDOF)}"] = round(float(entry["generate_s"]) + float(entry["link_s"]), 2)
            if entry.get("core_cold"):
                times[f"core|{entry['core_key']}"] = round(float(seconds), 2)
        else:
            times[f"{family(ks)}|{int(mod.NDOF)}"] = round(float(entry["generate_s"]) + float(seconds), 2)
        path = cache_root() / _TIMES_FILE
        tmp = path.with_suffix(f".tmp{os.getpid()}")
        tmp.write_text(json.dumps(times, sort_keys=True))
        os.replace(tmp, path)
    except (OSError, TypeError, ValueError, AttributeError):
        pass


@contextlib.contextmanager
def first_call_lock(mod, timeout_s: float = LOCK_TIMEOUT_S):
    """Held around numba's first call of a module's loop, across processes: the sweep workers (or
    test workers) that start on the same cold module wait for the one compiling it and then load its
    machine code from numba's cache, instead of each compiling the same code at once (2 workers, 2
    compiles of 30-100 s each). An advisory lock on `kernels/vk_<key>.lock` (released by the kernel
    when its holder dies); past `timeout_s` of waiting, or where locks are unavailable, the call goes
    ahead unlocked (only time is lost then, never a result)."""
    from . import build

    # a shared-build module's loop is its kernel set's core (vcirun.codegen.shared): lock on that
    key = getattr(mod, "LOCK_KEY", None) or mod.__name__.rsplit("_", 1)[-1]
    fd = None
    try:
        import fcntl

        fd = os.open(build.cache_dir() / f"vk_{key}.lock", os.O_RDWR | os.O_CREAT, 0o644)
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    break
                time.sleep(0.05)
    except (ImportError, OSError):
        pass
    try:
        yield
    finally:
        if fd is not None:
            try:
                os.close(fd)  # closing releases the lock
            except OSError:
                pass


@dataclass
class CacheInfo:
    path: Path
    modules: int          # generated modules (vk_*.py)
    index_entries: int    # warm-start index entries (wi_*.json)
    files: int
    bytes: int
    cores: int = 0        # shared cores (core_*.py, vcirun.codegen.shared)


def _walk(root: Path):
    return [p for p in root.rglob("*") if p.is_file()] if root.is_dir() else []


def _size(p: Path) -> int:
    try:
        return p.stat().st_size
    except OSError:  # a temporary file another process just renamed
        return 0


def info() -> CacheInfo:
    root = cache_root()
    files = _walk(root)
    k = root / "kernels"
    return CacheInfo(root, len(list(k.glob("vk_*.py"))) if k.is_dir() else 0,
                     len(list(k.glob("wi_*.json"))) if k.is_dir() else 0, len(files),
                     sum(_size(p) for p in files), len(list(k.glob("core_*.py"))) if k.is_dir() else 0)


def clear() -> CacheInfo:
    """Remove every cached kernel (the next run of each system compiles again); returns what was removed.
    Modules already loaded by running processes are unaffected."""
    before = info()
    for p in (before.path / "kernels", before.path / _TIMES_FILE):
        if p.is_dir():
            shutil.rmtree(p, ignore_errors=True)
        elif p.exists():
            p.unlink()
    return before
