"""What the module of a (scene, kernel set) is: its build mode, its cache key, its texts (the generated
part, made on a cache miss; the compiled tier's and the interpreted tier's module text) and its
warm-index key. Loading, the memory of what a process loaded and the warm index itself are
vcirun.codegen.kernel_cache.KernelCache's; vcirun.codegen.build is the entry point other layers import.

Two builds (`build_mode`, VCIRUN_BUILD):

- "shared" (default): the scene's module file holds the generated kernels alone
  (`derive.scene_source`); the numba *source units* of the numeric layers (vcirun/maps,
  vcirun/collision) with the bindings `full`, `partial`, `reset`, `modified_energy` are the kernel
  set's *shared core* (`KernelCache.load_core`, vcirun.codegen.shared: one file `core_<key>.py` per family,
  compiled once per machine), which calls the scene's kernels by address; `shared.link` joins the two.
- "specialized": one file per (scene, kernel set) = generated kernels + units + bindings, compiled
  together (a loop 1.3-1.6 times faster, 35-40 s per scene cold).
- "auto" (default): the shared build first; a module whose loop has run HOT_S seconds in one process
  gets its specialized build compiled in the background, and later runs take it
  (vcirun.codegen.specialize). Both builds compute the same bits (bench/golden.py checks it).

A specialized module's key is derived from its shared module's (`specialized_key`), so a process
finds it from the shared key alone (no sympy) and a pinned VCIRUN_BUILD=specialized shares it.

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

import contextlib
import contextvars
import functools
import hashlib
import importlib.util
import os
import sys
from pathlib import Path

import numba

from .. import __version__
from . import cache_store
from .cache_store import CacheError
from .kernel_set import KernelSet

_PKG = Path(__file__).resolve().parent.parent
# files whose text changes the generated code: hashed into the key
_GENERATOR_FILES = ["codegen/kernels.py", "codegen/printer.py", "codegen/modules.py", "codegen/derive.py",
                    "codegen/kernel_set.py",
                    "codegen/tensor.py", "codegen/units.py", "core/record.py", "codegen/c_emit.py", "codegen/cc.py",
                    "codegen/c_translate.py", "codegen/c_link.py",
                    "codegen/shared.py", "codegen/kcall.py", "codegen/frame.py", "codegen/roles.py",
                    "discrete/lagrangians.py",
                    "mechanics/system.py"]
# ... and, only for the MCVA family's modules (so that editing them does not invalidate CVA/VCI caches)
_MODIFIED_GENERATOR_FILES = ["codegen/mh_kernels.py", "modified/eta.py", "modified/series.py"]
# ... and, for the warm index only: the files that turn a scene name or a YAML file into a symbolic system
_SYSTEM_FILES = ["core/system_data.py", "scenes/scene.py", "scenes/registry.py", "scenes/symbolic.py",
                 "scenes/paper.py", "scenes/contacts.py", "scenes/walkers.py", "scenes/friction.py",
                 "mechanics/loader.py", "mechanics/expressions.py"]
WARM_FORMAT = 2


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


def _key_files(ks: KernelSet) -> set:
    files = set(_units(ks)) | set(_GENERATOR_FILES)
    if ks.modified is not None:
        files |= set(_MODIFIED_GENERATOR_FILES)
    return files


BUILDS = ("auto", "shared", "specialized")
# the build a block of code makes and loads (`building`): a specialized build started by the auto policy
_BUILDING = contextvars.ContextVar("vcirun_building", default=None)


def build_policy() -> str:
    """VCIRUN_BUILD: "auto" (default), "shared" or "specialized" (ValueError naming the variable)."""
    mode = os.environ.get("VCIRUN_BUILD", "auto").strip().lower() or "auto"
    if mode not in BUILDS:
        raise ValueError(f"VCIRUN_BUILD: {mode!r} is not a build mode (use auto, shared or specialized)")
    return mode


def build_mode() -> str:
    """The build a module is made in: "shared" (a scene module holds only its kernels and links to the
    shared core of its kernel set (vcirun.codegen.shared), compiled once per machine) or "specialized"
    (one module with the scene's kernels and every unit compiled together: a faster loop, a cold build
    of 35-40 s per scene). Inside `building(mode)`, that mode; else VCIRUN_BUILD, whose "auto" starts
    shared. Uncompiled runs (NUMBA_DISABLE_JIT=1) are always specialized, since the core calls kernels
    by machine address."""
    if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return "specialized"
    mode = _BUILDING.get() or build_policy()
    return "shared" if mode == "auto" else mode


@contextlib.contextmanager
def building(mode: str):
    """Keys, texts and loads inside the block are those of build `mode` ("shared" or "specialized")."""
    token = _BUILDING.set(mode)
    try:
        yield
    finally:
        _BUILDING.reset(token)


def core_ndof() -> str:
    """VCIRUN_CORE_NDOF: "" / "runtime" (default: one core per family, n read at run time) or "fixed"."""
    v = os.environ.get("VCIRUN_CORE_NDOF", "").strip().lower()
    if v not in ("", "runtime", "fixed"):
        raise ValueError(f"VCIRUN_CORE_NDOF: {v!r} is not a choice (use runtime or fixed)")
    return "fixed" if v == "fixed" else ""


def build_id() -> str:
    """The build mode with the core's NDOF choice (VCIRUN_CORE_NDOF): what keys and memos must tell apart."""
    return f"{build_mode()}|core_ndof={core_ndof()}"


def _versions(backend: str, build: str | None = None) -> bytes:
    # + the step-kernel path (codegen.derive: tensor or expanded), so the two never share a module,
    # + the kernel backend (codegen.cc: numba, or C with this compiler and flags: `backend_id`), + the
    # build (`build_id` unless given)
    path = os.environ.get("VCIRUN_KERNEL_PATH", "")
    return (f"{__version__}|{numba.__version__}|{sys.version_info[:2]}|kernels={path}|{backend}"
            f"|build={build_id() if build is None else build}").encode()


def backend_id() -> str:
    """What the key records of the kernel backend (vcirun.codegen.cc.identity: no subprocess)."""
    from . import cc  # no sympy: compiler discovery only

    return cc.identity()


def module_key_of(system, ks: KernelSet, backend: str | None = None) -> str:
    """The module key of (symbolic system, ks) in the build made now (`build_mode`; `backend`: backend_id(),
    passed by a caller that keeps it): the shared module's key hashes everything its text and machine
    code depend on; the specialized module's is derived from it (`specialized_key`)."""
    h = hashlib.sha256()
    h.update(system.fingerprint().encode())
    h.update(ks.key_text().encode())
    h.update(_versions(backend_id() if backend is None else backend, f"shared|core_ndof={core_ndof()}"))
    for rel in sorted(_key_files(ks)):  # every listed file exists (a missing one is a packaging error)
        h.update((_PKG / rel).read_bytes())
    key = h.hexdigest()[:20]
    return key if build_mode() == "shared" else specialized_key(key)


def specialized_key(shared_key: str) -> str:
    """The key of the specialized module of the same (system, kernel set, versions, files) as the shared
    module `shared_key`: both are made from the same generated text."""
    return hashlib.sha256(f"specialized|{shared_key}".encode()).hexdigest()[:20]


def generate(system, ks: KernelSet, d: Path) -> str:
    """The module text of (system, ks), generated now (sympy; the C compiler for its leaf kernels, whose
    shared objects go to the kernel directory `d`)."""
    from .derive import generated_source  # sympy work happens only here, on a cache miss

    return module_text(generated_source(system, ks), ks, len(system.param_symbols), d, system.name)


def module_text(generated: str, ks: KernelSet, nprm: int, d: Path, system_name: str) -> str:
    """The compiled tier's module text from the generated part of (system, ks) (`derive.generated_source`,
    which is all the sympy work): its leaf kernels compiled by the C compiler into `d` when there is one
    (vcirun.codegen.cc.backend), then the scene module of the shared build (those kernels, the number
    of parameters, the pointer wrappers) or the specialized module (with the units and bindings)."""
    from . import cc, units

    if not cache_store.writable(d):
        raise CacheError(f"kernel cache {d.parent}: {d} is read-only and holds no usable kernels for {system_name}/"
                         f"{family(ks)}: make it writable (or run once where it is), or set "
                         f"{cache_store.ENV} to a writable directory")
    if cc.backend() == "c":
        from .c_link import c_kernels

        generated = c_kernels(generated, d)
    if build_mode() == "shared":
        from .shared import SCENE_MARK, pointer_wrappers

        return (f"{SCENE_MARK}: the kernels of one scene; the loop is the shared core's\n" + generated
                + f"\n\nNPRM = {nprm}\n\n" + pointer_wrappers(ks))
    return units.assemble(generated, ks)


def interpreted_text(generated: str, ks: KernelSet) -> str:
    """The interpreted tier's module text: the generated part with the units and bindings, every kernel
    numba source (run as Python by vcirun.codegen.evaluate): the specialized module without C. The
    package's units are not checked against the contract here (units.assemble): 0.5-1 s of a first
    call on an empty cache."""
    from . import units

    return units.assemble(generated, ks, check_package=False)


def system_core_features(ks: KernelSet, system) -> tuple:
    """The features of the core that serves `system` (vcirun.codegen.shared.core_features)."""
    from . import shared

    return shared.core_features(ks, system.m, system.is_forced, system.reset_map is not None,
                                system.reset_law_first, system.has_friction)


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


def warm_key_of(ident: tuple, ks: KernelSet, backend: str | None = None) -> str:
    """Index key of a system identity (("scene", name) or ("yaml", sha256 of the file's bytes)) with
    a kernel set: everything of the module key but the fingerprint, plus the system-defining files
    and the sympy and PyYAML versions."""
    h = hashlib.sha256()
    h.update(f"warm index {WARM_FORMAT}|{ident!r}|{ks.key_text()}|".encode())
    h.update(_versions(backend_id() if backend is None else backend))
    h.update(_dependency_stamp())
    for rel in sorted(_key_files(ks) | set(_SYSTEM_FILES)):
        h.update(f"|{rel}|".encode())
        h.update((_PKG / rel).read_bytes())
    return h.hexdigest()[:24]
