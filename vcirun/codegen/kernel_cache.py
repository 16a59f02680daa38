"""The kernel cache of a process as one object: `KernelCache` builds, loads and remembers the compiled
modules of (system, kernel set) pairs, their shared cores and the warm index, and keeps what a
process learns about them (modules loaded, files set aside, builds announced, first calls made,
plans resolved). `default()` is the instance the public API uses; a caller that wants its own
memory (a test that starts "a new process", a substitute loader) makes another.

What a call built is returned to it, not kept in a log to be sliced: `with kc.report() as rep:` collects
the build entries of the modules loaded inside the block (`rep.compiled`: something was generated or
compiled). A substitute loader (`KernelCache(loader=f)`, f(symbolic system, kernel set) -> module, e.g.
vcirun.codegen.evaluate.python_module_for to run uncompiled) replaces building and loading; such a
cache has no warm index (its modules do not come from the disk cache).

The file formats, keys, seals and the checks a load makes are those of vcirun.codegen.build (key
functions, generation) and vcirun.codegen.cache_store (atomic writes, seals, quarantine)."""
from __future__ import annotations

import contextlib
import hashlib
import os
import sys
import threading
import time
import types
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import llvmlite
import numba

from . import build, cache_store, numba_cache
from .cache_store import CacheDamage
from .kernel_set import KernelSet

__all__ = ["KernelCache", "BuildReport", "default", "of"]


@dataclass
class BuildReport:
    """The build entries of the modules loaded while the report was open (`KernelCache.report`): dicts
    with key, system, kernels, cached (the module file was in the cache), generate_s, warm_index and,
    shared build, link_s, core_key, core_cold (numba had not cached the core's loop)."""

    entries: list = field(default_factory=list)

    @property
    def generated(self) -> int:
        """Modules generated (sympy, the C compiler) during the report."""
        return sum(not e["cached"] for e in self.entries)

    @property
    def compiled(self) -> bool:
        """Something was generated, or a shared core was compiled, during the report."""
        return any(not e["cached"] or e.get("core_cold") for e in self.entries)


class KernelCache:
    """Building, loading and the warm index of the kernel cache, with what this process knows of it.

    loader: None (the disk cache: generate, compile, load; warm index on), or f(symbolic system,
    kernel set) -> module used instead (no disk cache, no warm index)."""

    def __init__(self, loader=None):
        self.loader = loader
        self.lock = threading.RLock()
        self.loaded: dict = {}        # module key -> module
        self.set_aside: set = set()   # module keys whose file was found damaged and set aside here
        self.announced: set = set()   # module and core keys whose cold build this cache announced
        self.entries: dict = {}       # module key -> its build entry (the last load of it)
        self.first_calls: set = set()  # module names whose loop had numba's first call here (vcirun.run.plan)
        self.warm_hits: dict = {}     # (ident, ks, kernel path, build id) -> resolve_numeric's answer
        self.plans = OrderedDict()    # vcirun.run.plan's kept plans, least recently used first
        self._reports: list = []
        self._keys: dict = {}
        self._backend_ids: dict = {}
        self._cores: dict = {}        # core key -> module
        self._core_keys: dict = {}    # (kernel set, fixed n, features) -> core key
        self._core_texts: dict = {}   # core key -> module text
        self._compiled: set = set()   # (numba cache dir, core key) found compiled: advisory
        self._bodies: dict = {}       # module key -> verified text, from warm_lookup to load_cached_module
        self._dirs: set = set()       # kernel directories swept of dead processes' leftovers

    @property
    def warm(self) -> bool:
        """Does this cache serve the warm index (no substitute loader)?"""
        return self.loader is None

    # --- reports -----------------------------------------------------------------------------------

    @contextlib.contextmanager
    def report(self):
        """A BuildReport of the modules loaded while the block runs (in any thread)."""
        rep = BuildReport()
        with self.lock:
            self._reports.append(rep)
        try:
            yield rep
        finally:
            with self.lock:
                self._reports.remove(rep)

    def _record(self, entry: dict) -> None:
        with self.lock:
            self.entries[entry["key"]] = entry
            for rep in self._reports:
                rep.entries.append(entry)

    # --- where, and keys ---------------------------------------------------------------------------

    def cache_dir(self) -> Path:
        """The cache's `kernels` directory (CacheError when unusable); the first time this cache uses a
        directory, the leftovers of processes killed mid-write are removed from it."""
        d = build.cache_dir()
        if d not in self._dirs:
            self._dirs.add(d)
            cache_store.sweep_stale(d)
            cache_store.sweep_stale(d.parent)   # (build_times.json is written there)
        return d

    def backend_id(self) -> str:
        from . import cc  # no sympy: compiler discovery only

        key = (os.environ.get("CC"), os.environ.get(cc.BACKEND_ENV), os.environ.get("PATH"),
               os.environ.get("VCIRUN_C_MIN_STATEMENTS"))
        if key not in self._backend_ids:
            self._backend_ids[key] = cc.identity()
        return self._backend_ids[key]

    def module_key(self, system, ks: KernelSet) -> str:
        memo = (id(system), system.fingerprint(), ks, os.environ.get("VCIRUN_KERNEL_PATH", ""), build.build_id())
        if memo not in self._keys:
            self._keys[memo] = build.module_key_of(system, ks, self.backend_id())
        return self._keys[memo]

    def warm_key(self, ident: tuple, ks: KernelSet) -> str:
        return build.warm_key_of(ident, ks, self.backend_id())

    def index_path(self, ident: tuple, ks: KernelSet) -> Path:
        return self.cache_dir() / f"wi_{self.warm_key(ident, ks)}.json"

    # --- modules -----------------------------------------------------------------------------------

    def load_module(self, system, ks: KernelSet):
        """The module for (symbolic system, ks): from this cache's memory, from the disk cache (checked
        against its digests), or generated now; a damaged entry is set aside and generated again. With a
        substitute loader: what it returns."""
        if self.loader is not None:
            return self.loader(system, ks)
        key = self.module_key(system, ks)
        if key in self.loaded:
            return self.loaded[key]
        path = self.cache_dir() / f"vk_{key}.py"
        for attempt in range(2):
            t0 = time.perf_counter()
            found = self._verified_entry(path, key)
            cached = found is not None
            if found is None:
                body = build.generate(system, ks, self.cache_dir())
                cache_store.write_atomic(path, cache_store.seal_text(
                    body, {"key": key, "system": system.name, "kernels": ks.key_text()}), what=path.name)
            else:
                body = found[0]
            try:
                return self._exec_module(key, path, body, system.name, ks, cached, time.perf_counter() - t0, False)
            except CacheDamage as e:   # a shared object that changed between its check and its load
                if attempt:
                    raise
                self._set_aside_so(e)
        raise AssertionError("unreachable")

    def is_loaded(self, key: str) -> bool:
        return key in self.loaded

    def _import(self, name: str, path: Path, body: str, owner: numba_cache.Owner):
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

    def _owner(self, label: str, key: str, estimate) -> numba_cache.Owner:
        owner = numba_cache.Owner(label, estimate)
        owner.announced = key in self.announced   # a cold build said so already
        return owner

    def _exec_module(self, key: str, path: Path, body: str, system_name: str, ks: KernelSet, cached: bool,
                     generate_s: float, warm_index: bool):
        from . import shared

        name = f"vcirun_kernels_{key}"
        label = f"kernels for {system_name}/{build.family(ks)}"
        extra = {}
        if body.startswith(shared.SCENE_MARK):
            t0 = time.perf_counter()
            scene = self._import(f"vcirun_scene_{key}", path, body, self._owner(label, key, None))
            core = self.load_core(ks, int(scene.NDOF), shared.scene_features(ks, scene))
            mod = shared.link(name, scene, core, ks)   # compiles (or loads) the scene's kernels
            mod.CACHE_LABEL = core.CACHE_LABEL
            extra = {"link_s": time.perf_counter() - t0, "core_key": core.CORE_KEY,
                     "core_cold": not self.core_compiled(core.CORE_KEY)}
        else:
            mod = self._import(name, path, body, self._owner(label, key, None))
            mod.CACHE_LABEL = label
        self._record({"key": key, "system": system_name, "kernels": ks.key_text(), "cached": cached,
                      "generate_s": generate_s, "warm_index": warm_index, **extra})
        self.loaded[key] = mod
        return mod

    def _verified_entry(self, path: Path, key: str) -> tuple[str, dict] | None:
        """(text, seal) of the module file of `key` and its shared objects, all matching their digests;
        None when the module is missing or something failed its check (that is set aside, said on one
        line)."""
        try:
            data = cache_store.read(path)
        except CacheDamage as e:
            cache_store.quarantine(path, e.reason, rebuild="generating it again")
            self.set_aside.add(key)
            return None
        if data is None:
            return None
        try:
            body, meta = cache_store.unseal_text(data, key)
        except ValueError as e:
            cache_store.quarantine(path, str(e), rebuild="generating it again")
            self.set_aside.add(key)
            return None
        from . import c_link

        for so_name, digest in c_link.shared_objects(body).items():
            try:
                c_link.verify(path.parent / so_name, digest)
            except CacheDamage as e:
                self._set_aside_so(e)
                return None
        return body, meta

    @staticmethod
    def _set_aside_so(e: CacheDamage) -> None:
        from . import c_link

        said = f"so|{e.path}"   # one line per shared object, also when the check runs twice
        if e.path.exists():
            c_link.set_aside(e.path, e.reason)
            cache_store.said(said)
        else:
            cache_store.say(f"kernel cache: {e.path} {e.reason}; compiling it again", once=said)

    # --- shared cores ------------------------------------------------------------------------------

    def core_compiled(self, core_key: str) -> bool:
        """Has numba's cache the core's loop (its index file for `integrate`, or for the system-only
        core's `hamiltonian`)?"""
        d = self.cache_dir() / "__pycache__"
        if (d, core_key) in self._compiled:   # (a listing of a large cache costs tens of ms)
            return True
        try:
            names = os.listdir(d)
        except OSError:
            return False
        heads = (f"core_{core_key}.integrate-", f"core_{core_key}.hamiltonian-")
        if any(n.endswith(".nbi") and n.startswith(heads) for n in names):
            self._compiled.add((d, core_key))
            return True
        return False

    def core_key_of(self, ks: KernelSet, n: int, features: tuple = ()) -> str:
        """The key of the shared core of (ks, n, features) (vcirun.codegen.shared): one per kernel-set
        family and feature variant (the lean core or the general one), or per (family, variant, n) with
        VCIRUN_CORE_NDOF=fixed, which makes n a compile-time constant of the core.

        It hashes what the core's machine code depends on: its text (units, bindings, constants, stubs),
        the intrinsics it imports (kcall.py, frame.py) and the numba, llvmlite and Python versions. Not the
        C compiler or the kernel path, which change the scene modules only (the core calls their kernels
        by address): a compiler upgrade recompiles no core."""
        from . import shared

        ndof = n if build.core_ndof() == "fixed" else None
        memo = (ks, ndof, features)
        if memo not in self._core_keys:
            text = shared.core_source(ks, ndof, features)
            stamp = f"core|{numba.__version__}|{llvmlite.__version__}|{sys.version_info[:2]}|".encode()
            key = hashlib.sha256(stamp + text.encode() + (build._PKG / "codegen/kcall.py").read_bytes()
                                 + (build._PKG / "codegen/frame.py").read_bytes()).hexdigest()[:20]
            self._core_keys[memo] = key
            self._core_texts[key] = text
        return self._core_keys[memo]

    def load_core(self, ks: KernelSet, n: int, features: tuple = ()):
        """The shared core of (ks, n, features): from memory, or its module file in the cache (written now
        if missing; a file whose bytes differ from the key's text is set aside and written again); numba
        compiles it on its first call, or loads it from its cache."""
        from . import shared

        key = self.core_key_of(ks, n, features)
        if key not in self._cores:   # kernel sets with the same units and bindings share the core
            text = self._core_texts[key]
            path = self.cache_dir() / f"core_{key}.py"
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
            label = f"the shared core of {build.family(ks)}" + (
                f" ({shared.FEATURE_NAMES[features]})" if ks.full_stages else "")
            core = self._import(f"vcirun_core_{key}", path, text,
                                self._owner(label, key, lambda: cache_store.build_times().get(f"core|{key}")))
            core.CORE_KEY = key
            core.FEATURES = features
            core.CACHE_LABEL = label
            self._cores[key] = core
        return self._cores[key]

    # --- warm index: name or YAML file -> module key and numeric data, without the symbolic system ----

    def warm_lookup(self, ident: tuple, ks: KernelSet) -> dict | None:
        """The index entry of (ident, ks) whose module and shared objects are in the cache and match their
        digests, or None. An entry that fails its seal, or names a module of another system or kernel set,
        is set aside (said on one line); the caller then takes the symbolic path, which writes it again."""
        path = self.index_path(ident, ks)
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
            if (entry.get("format") != build.WARM_FORMAT or entry.get("ident") != list(ident)
                    or entry.get("kernels") != ks.key_text() or not isinstance(key, str)
                    or len(key) != 20 or any(c not in "0123456789abcdef" for c in key)):
                raise ValueError("does not describe this system and kernel set")
        except (ValueError, KeyError, TypeError) as e:
            reason = str(e) if isinstance(e, ValueError) else f"lacks a field ({type(e).__name__}: {e})"
            cache_store.quarantine(path, reason, rebuild="rebuilding it from the symbolic system")
            return None
        if key in self.loaded:
            return entry
        found = self._verified_entry(self.cache_dir() / f"vk_{key}.py", key)
        if found is None:
            return None
        body, meta = found
        if meta.get("kernels") != ks.key_text() or meta.get("system") != entry.get("name"):
            cache_store.quarantine(path, f"points at the module of {meta.get('system')}/{meta.get('kernels')}",
                                   rebuild="rebuilding it from the symbolic system")
            return None
        self._bodies[key] = body
        return entry

    def warm_record(self, ident: tuple, ks: KernelSet, key: str, data: dict) -> None:
        """Write the index entry of (ident, ks) -> module `key` with numeric `data` (sealed, atomic; best
        effort: a read-only or full cache only costs the next process the symbolic path)."""
        entry = {"format": build.WARM_FORMAT, "ident": list(ident), "kernels": ks.key_text(), "module": key} | data
        try:
            path = self.index_path(ident, ks)
            cache_store.write_atomic(path, cache_store.seal_json(entry), what=path.name)
        except (cache_store.CacheError, TypeError, ValueError):
            pass

    def load_cached_module(self, key: str, system_name: str, ks: KernelSet):
        """The module with this key from memory or from the disk cache (no generation; the caller found it
        with `warm_lookup`, which checked it)."""
        if key in self.loaded:
            return self.loaded[key]
        path = self.cache_dir() / f"vk_{key}.py"
        body = self._bodies.pop(key, None)
        if body is None:
            found = self._verified_entry(path, key)
            if found is None:
                raise CacheDamage(path, "is missing or damaged")
            body = found[0]
        return self._exec_module(key, path, body, system_name, ks, True, 0.0, True)


_DEFAULT = KernelCache()


def default() -> KernelCache:
    """The kernel cache of the public API (vcirun.simulate, vcirun.reference, the CLI, sweeps)."""
    return _DEFAULT


def of(loader=None) -> KernelCache:
    """The kernel cache a call uses for its `loader=` argument: None, the default; a KernelCache, itself;
    a function f(symbolic system, kernel set) -> module, a new KernelCache around it (nothing kept
    between calls: a call that wants its loader's memory passes a KernelCache)."""
    if loader is None:
        return _DEFAULT
    if isinstance(loader, KernelCache):
        return loader
    if not callable(loader):
        raise ValueError(f"loader: expected a KernelCache or a function (system, kernel set) -> module, got "
                         f"{type(loader).__name__}")
    return KernelCache(loader=loader)
