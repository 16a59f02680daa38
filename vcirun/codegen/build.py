"""Assemble, cache and load the compiled module of a (scene, kernel set).

Two builds (`build_mode`, VCIRUN_BUILD):

- "shared" (default): the scene's module file holds the generated kernels alone
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

Warm index: the key needs the symbolic system (its fingerprint), and building that imports
sympy. So next to the modules, `wi_<warm key>.json` maps a system *given by name or file* -- a
built-in scene name or the bytes of a YAML system file -- plus the kernel set to the module key and
the numeric data `vcirun.simulate` needs (n, parameter names and defaults, default state). The
warm key hashes everything the module key hashes except the fingerprint (kernel set, units,
generator files, versions) plus the files that turn a name or a YAML file into a symbolic system
and the sympy and PyYAML versions, so an entry goes stale whenever the module key could change. Any miss (no entry, unreadable entry,
module file gone) takes the symbolic path, which writes the entry again.

Trust: every file is written atomically and sealed with its digest (vcirun.codegen.cache_store); a
load checks the module's seal, the digests of its shared objects (vcirun.codegen.c_link) and of
numba's files (vcirun.codegen.numba_cache) before it uses them, and a file that fails is set aside
and rebuilt, said on one line. The module is executed from the checked text (no bytecode file).
"""
from __future__ import annotations

import functools
import hashlib
import importlib.util
import os
import sys
import time
import types
from pathlib import Path

import llvmlite
import numba

from .. import __version__
from . import cache_store, numba_cache
from .cache_store import CacheDamage, CacheError
from .kernel_set import KernelSet

_PKG = Path(__file__).resolve().parent.parent
# files whose text changes the generated code: hashed into the key
_GENERATOR_FILES = ["codegen/kernels.py", "codegen/printer.py", "codegen/build.py", "codegen/derive.py",
                    "codegen/kernel_set.py",
                    "codegen/tensor.py", "codegen/units.py", "core/record.py", "codegen/c_emit.py", "codegen/cc.py",
                    "codegen/c_translate.py", "codegen/c_link.py",
                    "codegen/shared.py", "codegen/kcall.py", "codegen/frame.py", "codegen/roles.py",
                    "discrete/lagrangians.py",
                    "mechanics/system.py"]
# ... and, only for the MCVA family's modules (so that editing them does not invalidate CVA/VCI caches)
_MODIFIED_GENERATOR_FILES = ["codegen/mh_kernels.py", "modified/eta.py", "modified/series.py"]
# ... and, for the warm index only: the files that turn a scene name or a YAML file into a symbolic system
_SYSTEM_FILES = ["core/system_data.py", "scenes/data.py", "scenes/declarations.py", "mechanics/loader.py",
                 "mechanics/expressions.py"]
WARM_FORMAT = 2

_loaded: dict[str, object] = {}
SET_ASIDE: set = set()   # module keys whose file this process found damaged and set aside (it regenerates them)
ANNOUNCED: set = set()   # module and core keys whose cold build this process announced (vcirun.codegen.cache)
BUILD_LOG: list[dict] = []  # (key, symbolic seconds, write seconds, cached?) for benchmarks


def cache_dir() -> Path:
    """The cache's `kernels` directory (vcirun.codegen.cache_store.kernels_dir: CacheError when unusable)."""
    return cache_store.kernels_dir()


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


def _import(name: str, path: Path, body: str, owner: numba_cache.Owner):
    """Execute `body` (the verified text of the module file at `path`) as module `name`: compiled from
    the checked text itself (no bytecode file is read or written), its numba functions cached through
    vcirun.codegen.numba_cache."""
    numba_cache.claim(path, owner)
    mod = types.ModuleType(name)
    mod.__file__ = str(path)
    code = compile(body, str(path), "exec")
    sys.modules[name] = mod
    try:
        exec(code, mod.__dict__)  # noqa: S102 - the generated module, checked against its seal
    except BaseException:
        sys.modules.pop(name, None)
        raise
    numba_cache.adopt(mod, path, owner)
    return mod


def _owner(label: str, key: str, estimate) -> numba_cache.Owner:
    owner = numba_cache.Owner(label, estimate)
    owner.announced = key in ANNOUNCED   # a cold build said so already
    return owner


def _exec_module(key: str, path: Path, body: str, system_name: str, ks: KernelSet, cached: bool,
                 generate_s: float, warm_index: bool):
    from . import shared

    name = f"vcirun_kernels_{key}"
    label = f"kernels for {system_name}/{family(ks)}"
    extra = {}
    if body.startswith(shared.SCENE_MARK):
        t0 = time.perf_counter()
        scene = _import(f"vcirun_scene_{key}", path, body, _owner(label, key, None))
        core = load_core(ks, int(scene.NDOF), shared.scene_features(ks, scene))
        mod = shared.link(name, scene, core, ks)   # compiles (or loads) the scene's kernels
        mod.CACHE_LABEL = core.CACHE_LABEL
        extra = {"link_s": time.perf_counter() - t0, "core_key": core.CORE_KEY,
                 "core_cold": not core_compiled(core.CORE_KEY)}
    else:
        mod = _import(name, path, body, _owner(label, key, None))
        mod.CACHE_LABEL = label
    BUILD_LOG.append({"key": key, "system": system_name, "kernels": ks.key_text(), "cached": cached,
                      "generate_s": generate_s, "warm_index": warm_index, **extra})
    _loaded[key] = mod
    return mod


def _verified_entry(path: Path, key: str) -> tuple[str, dict] | None:
    """(text, seal) of the module file of `key` and its shared objects, all matching their digests; None
    when the module is missing or something failed its check (that is set aside, said on one line)."""
    try:
        data = cache_store.read(path)
    except CacheDamage as e:
        cache_store.quarantine(path, e.reason, rebuild="generating it again")
        SET_ASIDE.add(key)
        return None
    if data is None:
        return None
    try:
        body, meta = cache_store.unseal_text(data, key)
    except ValueError as e:
        cache_store.quarantine(path, str(e), rebuild="generating it again")
        SET_ASIDE.add(key)
        return None
    from . import c_link

    for so_name, digest in c_link.shared_objects(body).items():
        try:
            c_link.verify(path.parent / so_name, digest)
        except CacheDamage as e:
            _set_aside_so(e)
            return None
    return body, meta


def _set_aside_so(e: CacheDamage) -> None:
    from . import c_link

    said = f"so|{e.path}"   # one line per shared object, also when the check runs twice
    if e.path.exists():
        c_link.set_aside(e.path, e.reason)
        cache_store.said(said)
    else:
        cache_store.say(f"kernel cache: {e.path} {e.reason}; compiling it again", once=said)


def _generate(system, ks: KernelSet) -> str:
    """The module text of (system, ks), generated now (sympy; the C compiler for its leaf kernels)."""
    from .derive import module_source  # sympy work happens only here, on a cache miss

    d = cache_dir()
    if not cache_store.writable(d):
        raise CacheError(f"kernel cache {d.parent}: {d} is read-only and holds no usable kernels for {system.name}/"
                         f"{family(ks)}: make it writable (or run once where it is), or set "
                         f"{cache_store.ENV} to a writable directory")
    if build_mode() == "shared":
        from .derive import scene_source

        return scene_source(system, ks, c_dir=d)
    return module_source(system, ks, c_dir=d)


def load_module(system, ks: KernelSet):
    """The compiled module for (system, ks): from memory, from the disk cache (checked against its
    digests), or generated now; a damaged entry is set aside and generated again."""
    key = module_key(system, ks)
    if key in _loaded:
        return _loaded[key]
    path = cache_dir() / f"vk_{key}.py"
    for attempt in range(2):
        t0 = time.perf_counter()
        found = _verified_entry(path, key)
        cached = found is not None
        if found is None:
            body = _generate(system, ks)
            cache_store.write_atomic(path, cache_store.seal_text(
                body, {"key": key, "system": system.name, "kernels": ks.key_text()}), what=path.name)
        else:
            body = found[0]
        try:
            return _exec_module(key, path, body, system.name, ks, cached, time.perf_counter() - t0, False)
        except CacheDamage as e:   # a shared object that changed between its check and its load
            if attempt:
                raise
            _set_aside_so(e)
    raise AssertionError("unreachable")


_cores: dict = {}      # core key -> module
_core_keys: dict = {}  # (kernel set, fixed n) -> core key
_core_texts: dict = {}  # core key -> module text


def core_compiled(core_key: str) -> bool:
    """Has numba's cache the core's loop (its index file for `integrate`, or for the system-only
    core's `hamiltonian`)?"""
    d = cache_dir() / "__pycache__"
    if (d, core_key) in _compiled:   # (a listing of a large cache costs tens of ms)
        return True
    try:
        names = os.listdir(d)
    except OSError:
        return False
    heads = (f"core_{core_key}.integrate-", f"core_{core_key}.hamiltonian-")
    if any(n.endswith(".nbi") and n.startswith(heads) for n in names):
        _compiled.add((d, core_key))
        return True
    return False


_compiled: set = set()   # (numba cache dir, core key) found compiled: advisory (announcements, parallel builds)


def system_core_features(ks: KernelSet, system) -> tuple:
    """The features of the core that serves `system` (vcirun.codegen.shared.core_features)."""
    from . import shared

    return shared.core_features(ks, system.m, system.is_forced, system.reset_map is not None,
                                system.reset_law_first, system.has_friction)


def core_key_of(ks: KernelSet, n: int, features: tuple = ()) -> str:
    """The key of the shared core of (ks, n, features) (vcirun.codegen.shared): one per kernel-set
    family and feature variant (the lean core or the general one), or per (family, variant, n) with
    VCIRUN_CORE_NDOF=fixed, which makes n a compile-time constant of the core.

    It hashes what the core's machine code depends on: its text (units, bindings, constants, stubs),
    the intrinsics it imports (kcall.py, frame.py) and the numba, llvmlite and Python versions. Not the
    C compiler or the kernel path, which change the scene modules only (the core calls their kernels
    by address): a compiler upgrade recompiles no core."""
    from . import shared

    ndof = n if _core_ndof() == "fixed" else None
    memo = (ks, ndof, features)
    if memo not in _core_keys:
        text = shared.core_source(ks, ndof, features)
        stamp = f"core|{numba.__version__}|{llvmlite.__version__}|{sys.version_info[:2]}|".encode()
        key = hashlib.sha256(stamp + text.encode() + (_PKG / "codegen/kcall.py").read_bytes()
                             + (_PKG / "codegen/frame.py").read_bytes()).hexdigest()[:20]
        _core_keys[memo] = key
        _core_texts[key] = text
    return _core_keys[memo]


def load_core(ks: KernelSet, n: int, features: tuple = ()):
    """The shared core of (ks, n, features): from memory, or its module file in the cache (written now if
    missing; a file whose bytes differ from the key's text is set aside and written again); numba
    compiles it on its first call, or loads it from its cache."""
    from . import shared

    key = core_key_of(ks, n, features)
    if key not in _cores:   # kernel sets with the same units and bindings share the core
        text = _core_texts[key]
        path = cache_dir() / f"core_{key}.py"
        try:
            data = cache_store.read(path)
        except CacheDamage as e:
            cache_store.quarantine(path, e.reason, rebuild="writing it again")
            data = None
        if data != text.encode():
            if data is not None:
                cache_store.quarantine(path, "differs from the text of its key (changed or damaged)",
                                       rebuild="writing it again")
            cache_store.write_atomic(path, text, what=path.name)
        label = f"the shared core of {family(ks)}" + (f" ({shared.FEATURE_NAMES[features]})" if ks.full_stages else "")
        core = _import(f"vcirun_core_{key}", path, text,
                       _owner(label, key, lambda: cache_store.build_times().get(f"core|{key}")))
        core.CORE_KEY = key
        core.FEATURES = features
        core.CACHE_LABEL = label
        _cores[key] = core
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


_bodies: dict = {}   # module key -> verified text, from warm_lookup to load_cached_module


def warm_lookup(ident: tuple, ks: KernelSet) -> dict | None:
    """The index entry of (ident, ks) whose module and shared objects are in the cache and match their
    digests, or None. An entry that fails its seal, or names a module of another system or kernel set,
    is set aside (said on one line); the caller then takes the symbolic path, which writes it again."""
    path = _index_path(ident, ks)
    try:
        data = cache_store.read(path)
    except CacheDamage as e:
        cache_store.quarantine(path, e.reason, rebuild="rebuilding it from the symbolic system")
        return None
    if data is None:
        return None
    try:
        entry = cache_store.unseal_json(data)
        key = entry["module"]
        if (entry.get("format") != WARM_FORMAT or entry.get("ident") != list(ident)
                or entry.get("kernels") != ks.key_text() or not isinstance(key, str)
                or len(key) != 20 or any(c not in "0123456789abcdef" for c in key)):
            raise ValueError("does not describe this system and kernel set")
    except (ValueError, KeyError, TypeError) as e:
        reason = str(e) if isinstance(e, ValueError) else f"lacks a field ({type(e).__name__}: {e})"
        cache_store.quarantine(path, reason, rebuild="rebuilding it from the symbolic system")
        return None
    if key in _loaded:
        return entry
    found = _verified_entry(cache_dir() / f"vk_{key}.py", key)
    if found is None:
        return None
    body, meta = found
    if meta.get("kernels") != ks.key_text() or meta.get("system") != entry.get("name"):
        cache_store.quarantine(path, f"points at the module of {meta.get('system')}/{meta.get('kernels')}",
                               rebuild="rebuilding it from the symbolic system")
        return None
    _bodies[key] = body
    return entry


def warm_record(ident: tuple, ks: KernelSet, key: str, data: dict) -> None:
    """Write the index entry of (ident, ks) -> module `key` with numeric `data` (sealed, atomic; best
    effort: a read-only or full cache only costs the next process the symbolic path)."""
    entry = {"format": WARM_FORMAT, "ident": list(ident), "kernels": ks.key_text(), "module": key} | data
    try:
        path = _index_path(ident, ks)
        cache_store.write_atomic(path, cache_store.seal_json(entry), what=path.name)
    except (CacheError, TypeError, ValueError):
        pass


def load_cached_module(key: str, system_name: str, ks: KernelSet):
    """The module with this key from memory or from the disk cache (no generation; the caller found it
    with `warm_lookup`, which checked it)."""
    if key in _loaded:
        return _loaded[key]
    path = cache_dir() / f"vk_{key}.py"
    body = _bodies.pop(key, None)
    if body is None:
        found = _verified_entry(path, key)
        if found is None:
            raise CacheDamage(path, "is missing or damaged")
        body = found[0]
    return _exec_module(key, path, body, system_name, ks, True, 0.0, True)
