"""Assemble, cache and load the compiled module of a (scene, kernel set).

Two builds (`build_mode`, VCIRUN_BUILD):

- "shared" (default, issue 21): the scene's module file holds the generated kernels alone
  (`derive.scene_source`); the numba *source units* of the numeric layers (vcirun/maps,
  vcirun/collision) with the bindings `full`, `partial`, `reset`, `modified_energy` are the kernel
  set's *shared core* (`load_core`, vcirun.codegen.shared: one file `core_<key>.py` per family,
  compiled once per machine), which calls the scene's kernels by address; `shared.link` joins the two.
- "specialized": one file per (scene, kernel set) = generated kernels + units + bindings, compiled
  together (the loop ~15 % faster, 35-40 s per scene cold).

Either way the whole event loop is compiled and cached by numba: numba cannot cache a function that
takes another jitted function as an argument, and a compiled loop calling compiled kernels is what
makes a 500-step simulation take microseconds.

Cache key = hash(system's symbolic content, kernel set, source of the units and of this package's
code generator, vcirun and numba versions). A warm start finds the file by key before any symbolic
work is done.

Warm index (issue 7): the key needs the symbolic system (its fingerprint), and building that imports
sympy. So next to the modules, `wi_<warm key>.json` maps a system *given by name or file* -- a
built-in scene name or the bytes of a YAML system file -- plus the kernel set to the module key and
the numeric data `vcirun.simulate` needs (n, parameter names and defaults, default state). The
warm key hashes everything the module key hashes except the fingerprint (kernel set, units,
generator files, versions) plus the files that turn a name or a YAML file into a symbolic system
and the sympy and PyYAML versions, so an entry goes stale whenever the module key could change. Any miss (no entry, unreadable entry,
module file gone) takes the symbolic path, which writes the entry again.
"""
from __future__ import annotations

import functools
import hashlib
import importlib.util
import json
import os
import sys
import time
from pathlib import Path

import numba

from .. import __version__
from .kernel_set import KernelSet

_PKG = Path(__file__).resolve().parent.parent
# files whose text changes the generated code: hashed into the key
_GENERATOR_FILES = ["codegen/kernels.py", "codegen/printer.py", "codegen/build.py", "codegen/derive.py",
                    "codegen/kernel_set.py",
                    "codegen/tensor.py", "codegen/units.py", "core/record.py", "codegen/c_emit.py", "codegen/cc.py",
                    "codegen/c_translate.py",
                    "codegen/shared.py", "codegen/kcall.py", "codegen/frame.py", "codegen/roles.py",
                    "discrete/lagrangians.py",
                    "mechanics/system.py"]
# ... and, only for the MCVA family's modules (so that editing them does not invalidate CVA/VCI caches)
_MODIFIED_GENERATOR_FILES = ["codegen/mh_kernels.py", "modified/eta.py", "modified/series.py"]
# ... and, for the warm index only: the files that turn a scene name or a YAML file into a symbolic system
_SYSTEM_FILES = ["core/system_data.py", "scenes/data.py", "scenes/declarations.py", "mechanics/loader.py",
                 "mechanics/expressions.py"]
WARM_FORMAT = 1

_loaded: dict[str, object] = {}
BUILD_LOG: list[dict] = []  # (key, symbolic seconds, write seconds, cached?) for benchmarks


def cache_dir() -> Path:
    d = Path(os.environ.get("VCIRUN_CACHE_DIR", Path.home() / ".cache" / "vcirun")) / "kernels"
    d.mkdir(parents=True, exist_ok=True)
    return d




def _units(ks: KernelSet) -> list[str]:
    """The numba source units of the module of `ks`, chosen by the contract (vcirun.codegen.units)."""
    from .units import select_units

    return [u.path for u in select_units(ks)]


_keys: dict = {}


def module_key(system, ks: KernelSet) -> str:
    memo = (id(system), system.fingerprint(), ks, os.environ.get("VCIRUN_KERNEL_PATH", ""), build_id())
    if memo not in _keys:
        _keys[memo] = _module_key(system, ks)
    return _keys[memo]


def _key_files(ks: KernelSet) -> set:
    files = set(_units(ks)) | set(_GENERATOR_FILES)
    if ks.modified is not None:
        files |= set(_MODIFIED_GENERATOR_FILES)
    return files


def build_mode() -> str:
    """"shared" (default): a scene module holds only its kernels and links to the shared core of its
    kernel set (vcirun.codegen.shared), compiled once per machine; "specialized": one module with the
    scene's kernels and every unit compiled together (a faster loop, a cold build of 35-40 s per
    scene). VCIRUN_BUILD selects it; uncompiled runs (NUMBA_DISABLE_JIT=1) are always specialized,
    since the core calls kernels by machine address."""
    mode = os.environ.get("VCIRUN_BUILD", "shared").strip().lower() or "shared"
    if mode not in ("shared", "specialized"):
        raise ValueError(f"VCIRUN_BUILD: {mode!r} is not a build mode (use shared or specialized)")
    if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return "specialized"
    return mode


def _core_ndof() -> str:
    """VCIRUN_CORE_NDOF: "" / "runtime" (default: one core per family, n read at run time) or "fixed"."""
    v = os.environ.get("VCIRUN_CORE_NDOF", "").strip().lower()
    if v not in ("", "runtime", "fixed"):
        raise ValueError(f"VCIRUN_CORE_NDOF: {v!r} is not a choice (use runtime or fixed)")
    return "fixed" if v == "fixed" else ""


def build_id() -> str:
    """The build mode with the core's NDOF choice (VCIRUN_CORE_NDOF): what keys and memos must tell apart."""
    return f"{build_mode()}|core_ndof={_core_ndof()}"


def _versions() -> bytes:
    # + the step-kernel path (codegen.derive: tensor or expanded), so the two never share a module,
    # + the kernel backend (codegen.cc: numba, or C with this compiler and flags), + the build mode
    path = os.environ.get("VCIRUN_KERNEL_PATH", "")
    return (f"{__version__}|{numba.__version__}|{sys.version_info[:2]}|kernels={path}|{_backend_id()}"
            f"|build={build_id()}").encode()


def _backend_id() -> str:
    from . import cc  # no sympy: compiler discovery only

    key = (os.environ.get("CC"), os.environ.get(cc.BACKEND_ENV), os.environ.get("PATH"),
           os.environ.get("VCIRUN_C_MIN_STATEMENTS"))
    if key not in _BACKEND_IDS:
        _BACKEND_IDS[key] = cc.identity()
    return _BACKEND_IDS[key]


_BACKEND_IDS: dict = {}


def _module_key(system, ks: KernelSet) -> str:
    h = hashlib.sha256()
    h.update(system.fingerprint().encode())
    h.update(ks.key_text().encode())
    h.update(_versions())
    for rel in sorted(_key_files(ks)):  # every listed file exists (a missing one is a packaging error)
        h.update((_PKG / rel).read_bytes())
    return h.hexdigest()[:20]


def _import(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def _exec_module(key: str, path: Path, system_name: str, ks: KernelSet, cached: bool, generate_s: float,
                 warm_index: bool):
    name = f"vcirun_kernels_{key}"
    extra = {}
    if _is_scene_file(path):
        from . import shared

        t0 = time.perf_counter()
        scene = _import(f"vcirun_scene_{key}", path)
        core = load_core(ks, int(scene.NDOF))
        mod = shared.link(name, scene, core, ks)   # compiles (or loads) the scene's kernels
        extra = {"link_s": time.perf_counter() - t0, "core_key": core.CORE_KEY,
                 "core_cold": not core_compiled(core.CORE_KEY)}
    else:
        mod = _import(name, path)
    BUILD_LOG.append({"key": key, "system": system_name, "kernels": ks.key_text(), "cached": cached,
                      "generate_s": generate_s, "warm_index": warm_index, **extra})
    _loaded[key] = mod
    return mod


def load_module(system, ks: KernelSet):
    """The compiled module for (system, ks): from memory, from the disk cache, or generated now."""
    key = module_key(system, ks)
    if key in _loaded:
        return _loaded[key]
    path = cache_dir() / f"vk_{key}.py"
    t0 = time.perf_counter()
    cached = path.exists()
    if not cached:
        from .derive import module_source  # sympy work happens only here, on a cache miss

        if build_mode() == "shared":
            from .derive import scene_source

            text = scene_source(system, ks, c_dir=cache_dir())
        else:
            text = module_source(system, ks, c_dir=cache_dir())
        tmp = path.with_suffix(f".tmp{os.getpid()}")
        tmp.write_text(text)
        os.replace(tmp, path)  # atomic: parallel workers never import a half-written file
    return _exec_module(key, path, system.name, ks, cached, time.perf_counter() - t0, False)


def _is_scene_file(path: Path) -> bool:
    from .shared import SCENE_MARK

    with open(path) as f:
        return f.readline().startswith(SCENE_MARK)


_cores: dict = {}      # core key -> module
_core_keys: dict = {}  # (kernel set, fixed n) -> core key
_core_texts: dict = {}  # core key -> module text


def core_compiled(core_key: str) -> bool:
    """Has numba's cache the core's loop (its index file for `integrate`, or for the system-only
    core's `hamiltonian`)?"""
    d = cache_dir() / "__pycache__"
    return any(d.glob(f"core_{core_key}.integrate-*.nbi")) or any(d.glob(f"core_{core_key}.hamiltonian-*.nbi"))


def core_key_of(ks: KernelSet, n: int) -> str:
    """The key of the shared core of (ks, n) (vcirun.codegen.shared): one per kernel-set family, or
    per (family, n) with VCIRUN_CORE_NDOF=fixed, which makes n a compile-time constant of the core."""
    from . import shared

    ndof = n if _core_ndof() == "fixed" else None
    memo = (ks, ndof)
    if memo not in _core_keys:
        text = shared.core_source(ks, ndof)
        # numba's cache of the core is stamped by the core file alone: the intrinsics' code generation
        # (kcall.py, frame.py) is part of the key, so changing it makes a new core
        key = hashlib.sha256(_versions() + text.encode() + (_PKG / "codegen/kcall.py").read_bytes()
                             + (_PKG / "codegen/frame.py").read_bytes()).hexdigest()[:20]
        _core_keys[memo] = key
        _core_texts[key] = text
    return _core_keys[memo]


def load_core(ks: KernelSet, n: int):
    """The shared core of (ks, n): from memory, or its module file in the cache (written now if
    missing); numba compiles it on its first call, or loads it from its cache."""
    key = core_key_of(ks, n)
    if key not in _cores:   # kernel sets with the same units and bindings share the core
        text = _core_texts[key]
        path = cache_dir() / f"core_{key}.py"
        if not path.exists() or path.read_text() != text:
            tmp = path.with_suffix(f".tmp{os.getpid()}")
            tmp.write_text(text)
            os.replace(tmp, path)
        _cores[key] = _import(f"vcirun_core_{key}", path)
        _cores[key].CORE_KEY = key
    return _cores[key]


# --- warm index: name or YAML file -> module key and numeric data, without the symbolic system ----

@functools.lru_cache(maxsize=None)
def _dependency_stamp() -> bytes:
    """The versions of sympy and PyYAML, found without importing them: the fingerprint (sympy's srepr)
    and the YAML parse depend on them."""
    out = []
    for name, rel in (("sympy", "release.py"), ("yaml", "__init__.py")):
        try:
            spec = importlib.util.find_spec(name)
            out.append(hashlib.sha256((Path(spec.origin).parent / rel).read_bytes()).hexdigest())
        except (ImportError, AttributeError, TypeError, ValueError, OSError):
            out.append(f"no {name}")
    return "|".join(out).encode()


def warm_key(ident: tuple, ks: KernelSet) -> str:
    """Index key of a system identity (("scene", name) or ("yaml", sha256 of the file's bytes)) with
    a kernel set: everything of the module key but the fingerprint, plus the system-defining files
    and the sympy and PyYAML versions."""
    h = hashlib.sha256()
    h.update(f"warm index {WARM_FORMAT}|{ident!r}|{ks.key_text()}|".encode())
    h.update(_versions())
    h.update(_dependency_stamp())
    for rel in sorted(_key_files(ks) | set(_SYSTEM_FILES)):
        h.update(f"|{rel}|".encode())
        h.update((_PKG / rel).read_bytes())
    return h.hexdigest()[:24]


def _index_path(ident: tuple, ks: KernelSet) -> Path:
    return cache_dir() / f"wi_{warm_key(ident, ks)}.json"


def warm_lookup(ident: tuple, ks: KernelSet) -> dict | None:
    """The index entry of (ident, ks) whose module file exists, or None (never raises on a bad entry)."""
    try:
        entry = json.loads(_index_path(ident, ks).read_text())
        key = entry["module"]
        if (entry.get("format") != WARM_FORMAT or entry.get("ident") != list(ident)
                or entry.get("kernels") != ks.key_text() or not isinstance(key, str)
                or len(key) != 20 or any(c not in "0123456789abcdef" for c in key)):
            return None
        if key not in _loaded and not (cache_dir() / f"vk_{key}.py").is_file():
            return None
        return entry
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None


def warm_record(ident: tuple, ks: KernelSet, key: str, data: dict) -> None:
    """Write the index entry of (ident, ks) -> module `key` with numeric `data` (atomic; best effort:
    a read-only or full cache only costs the next process the symbolic path)."""
    entry = {"format": WARM_FORMAT, "ident": list(ident), "kernels": ks.key_text(), "module": key} | data
    try:
        path = _index_path(ident, ks)
        tmp = path.with_suffix(f".tmp{os.getpid()}")
        tmp.write_text(json.dumps(entry))
        os.replace(tmp, path)
    except (OSError, TypeError, ValueError):
        pass


def load_cached_module(key: str, system_name: str, ks: KernelSet):
    """The module with this key from memory or from the disk cache (no generation; the caller has
    checked that the file exists, see `warm_lookup`)."""
    if key in _loaded:
        return _loaded[key]
    return _exec_module(key, cache_dir() / f"vk_{key}.py", system_name, ks, True, 0.0, True)
