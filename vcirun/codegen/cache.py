"""The kernel cache on disk (`vcirun cache info|clear`) and what a cold build says about itself.

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

import contextlib
import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

from . import cache_lock, cache_store

__all__ = ["CacheInfo", "ClearResult", "info", "clear", "cache_root", "announce_if_cold", "note_first_call",
           "estimate_compile_s", "core_estimate_s", "cold_parts", "core_key_for", "tell", "listen", "first_call_lock"]

_log = logging.getLogger("vcirun.build")
_TIMES_FILE = cache_store.TIMES_FILE
# first estimates before this cache has timed a build (measured on this 2-core machine: CVA on the
# cart-pendulum 9 s, MCVAC 14-20 s)
_DEFAULT_S = {"CVA": 10.0, "VCI": 10.0, "MCVA": 20.0}
# shared build: a scene's kernels (cart-pendulum CVA 3.4 s, MCVAC 4.8 s) and a core (once per machine)
_DEFAULT_SCENE_S = {"CVA": 3.5, "VCI": 3.5, "MCVA": 5.5}
# first estimates of a core's compile (this machine, 2 cores): the general one, the lean one
# (vcirun.codegen.shared.LEAN), the system-only one general and lean (the cart-pendulum's exact
# reference, empty cache: 14.3 s and 5.0 s in all); the MCVA family's 5 s more
_DEFAULT_CORE_S = {"general": 50.0, "lean": 30.0, "system": 12.0, "system lean": 4.0}
LOCK_TIMEOUT_S = cache_lock.LOCK_TIMEOUT_S


def listen(callback) -> None:
    """Show build notices and cache notices through `callback(message) -> True` (the CLI prints them on
    stderr); once per callback. Without a listener, notices go to the logger "vcirun.build"."""
    if callback not in cache_store.LISTENERS:
        cache_store.LISTENERS.append(callback)


def cache_root() -> Path:
    """The cache directory (CacheError for an empty VCIRUN_CACHE_DIR)."""
    return cache_store.root()


def _times() -> dict:
    return cache_store.build_times()


def core_estimate_s(core_key: str, first: float = None) -> float:
    """Seconds numba takes to compile a shared core: this cache's record of it, else `first` (default a
    general core's first estimate)."""
    return float(_times().get(f"core|{core_key}", _DEFAULT_CORE_S["general"] if first is None else first))


def estimate_compile_s(ks, n: int, features: tuple = (), with_core: bool = True, kc=None) -> float:
    """Seconds a cold build of (ks, n) is expected to take: this cache's last build of the same family
    and size, else of the same family at another size (scaled linearly in n), else a first estimate.
    Shared build (vcirun.codegen.shared): the scene's kernels, plus the core if numba has not cached it
    and `with_core` (False: another build compiles it). `kc`: the kernel cache (default: the API's)."""
    from . import build

    kc = _kc(kc)
    times, kind = _times(), (ks.reset or "system").upper()
    if build.build_mode() != "shared":
        return _by_family(times, build.family(ks), n, _DEFAULT_S.get(kind, 15.0))
    key = kc.core_key_of(ks, n, features)
    first = _DEFAULT_CORE_S[("lean" if features else "general") if ks.full_stages else
                            ("system lean" if features else "system")]
    core = 0.0 if kc.core_compiled(key) or not with_core else \
        core_estimate_s(key, first + (5.0 if kind == "MCVA" else 0.0))
    return _by_family(times, "scene|" + build.family(ks), n, _DEFAULT_SCENE_S.get(kind, 3.5)) + core


def _by_family(times: dict, fam: str, n: int, first: float) -> float:
    """The recorded time of (fam, n), else of fam's largest recorded n scaled linearly, else `first`
    (a 2-DOF figure) scaled."""
    if f"{fam}|{n}" in times:
        return float(times[f"{fam}|{n}"])
    same = [(int(k.rsplit("|", 1)[1]), float(v)) for k, v in times.items()
            if k.rsplit("|", 1)[0] == fam and k.rsplit("|", 1)[1].isdigit()]
    m, v = max(same) if same else (2, first)
    return v * max(1.0, n / m)


def _kc(kc):
    from .kernel_cache import default

    return default() if kc is None else kc


def cold_parts(system, ks, kc=None) -> tuple[str, ...]:
    """What loading the module of symbolic `system` with `ks` has to compile: () when it is cached (or
    was loaded, or set aside and said), ("scene",) for its kernels, ("scene", "core") for its kernels
    and their shared core, ("core",) for the core alone (shared build). `kc`: the kernel cache."""
    from . import build

    kc = _kc(kc)
    key = kc.module_key(system, ks)
    if key in kc.loaded or key in kc.set_aside:   # (no file access on the path of every later call;
        return ()                                 # a module set aside was said when it was)
    parts = () if (kc.cache_dir() / f"vk_{key}.py").exists() else ("scene",)
    if build.build_mode() == "shared" and not kc.core_compiled(core_key_for(system, ks, kc)):
        parts += ("core",)
    return parts


def core_key_for(system, ks, kc=None) -> str:
    """The key of the shared core that serves symbolic `system` with `ks`."""
    from . import build

    return _kc(kc).core_key_of(ks, system.n, build.system_core_features(ks, system))


def announce_if_cold(system, ks, cores_covered=(), kc=None) -> bool:
    """Before loading the module of (system, ks): if it must be generated and compiled, say so
    ("compiling kernels for <scene>/<family> and their shared core (one contact, unforced) (first
    time, about N s)") to the logger and callbacks, once; `cores_covered`: core keys whose compile
    an earlier announcement of the same build named already."""
    from . import build
    from .shared import FEATURE_NAMES

    kc = _kc(kc)
    parts = cold_parts(system, ks, kc)
    if not parts:
        return False
    feats = build.system_core_features(ks, system)
    # a core another kernel set of the same build covers (CVA's and VCI's share one) is not repeated
    with_core = "core" in parts and (build.build_mode() != "shared"
                                     or core_key_for(system, ks, kc) not in cores_covered)
    core = (" and their shared core" + (f" ({FEATURE_NAMES[feats]})" if ks.full_stages else "")) if with_core else ""
    msg = (f"compiling kernels for {system.name}/{build.family(ks)}{core} (first time, about "
           f"{estimate_compile_s(ks, system.n, feats, with_core=with_core, kc=kc):.0f} s; cached in {cache_root()})")
    kc.announced.add(kc.module_key(system, ks))
    if build.build_mode() == "shared":
        kc.announced.add(core_key_for(system, ks, kc))
    tell(msg)
    return True


QUIET_ENV = "VCIRUN_QUIET"


def tell(msg: str) -> None:
    """A build notice ("compiling ... about N s", which tier runs): to the listeners (`listen`: the CLI
    prints them on stderr), else to the logger "vcirun.build" at INFO, which prints it on stderr unless
    logging is configured otherwise: off with VCIRUN_QUIET=1, or as any logger
    (logging.getLogger("vcirun").setLevel(logging.WARNING))."""
    if cache_store.LISTENERS:
        for cb in list(cache_store.LISTENERS):
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


def note_first_call(mod, ks, seconds: float, kc=None) -> None:
    """After numba's first call of a module's loop: if the module was generated by kernel cache `kc`,
    record generation + first call as the build time of its family and size (the next estimate)."""
    from . import build

    key = mod.__name__.rsplit("_", 1)[-1]
    entry = _kc(kc).entries.get(key)
    if entry is None or entry.get("noted") or (entry["cached"] and not entry.get("core_cold")):
        return
    entry["noted"] = True   # (the first calls that compiled are timed once: a later first call only loads)
    try:
        times = _times()
        if "link_s" in entry:   # shared build: the scene's kernels, and the core's first compile apart
            if not entry["cached"]:
                times[f"scene|{build.family(ks)}|{int(mod.NDOF)}"] = round(float(entry["generate_s"]) + float(entry["link_s"]), 2)
            if entry.get("core_cold"):
                times[f"core|{entry['core_key']}"] = round(float(seconds), 2)
        else:
            times[f"{build.family(ks)}|{int(mod.NDOF)}"] = round(float(entry["generate_s"]) + float(seconds), 2)
        cache_store.write_atomic(cache_root() / _TIMES_FILE, json.dumps(times, sort_keys=True), what=_TIMES_FILE)
    except (OSError, TypeError, ValueError, AttributeError):   # (CacheError is a ValueError): advisory
        pass


@contextlib.contextmanager
def first_call_lock(mod, timeout_s: float = LOCK_TIMEOUT_S, kc=None):
    """Held around numba's first call of a module's loop, across processes: the sweep workers (or
    test workers) that start on the same cold module wait for the one compiling it and then load its
    machine code from numba's cache, instead of each compiling the same code at once (2 workers, 2
    compiles of 30-100 s each). The lock `kernels/vk_<key>.lock` names its holder, is taken over when
    the holder no longer runs and is reported when the holder is stopped or hung
    (vcirun.codegen.cache_lock); past `timeout_s` of waiting, or where locks are unavailable, the call
    goes ahead unlocked (only time is lost then, never a result)."""
    # a shared-build module's loop is its kernel set's core (vcirun.codegen.shared): lock on that
    key = getattr(mod, "LOCK_KEY", None) or mod.__name__.rsplit("_", 1)[-1]
    try:
        path = _kc(kc).cache_dir() / f"vk_{key}.lock"
    except cache_store.CacheError:
        path = None
    if path is None:
        yield
        return
    with cache_lock.held(path, getattr(mod, "CACHE_LABEL", None) or f"module {key}", timeout_s=timeout_s):
        yield


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
