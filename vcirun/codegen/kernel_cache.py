"""The kernel cache of a process as one object: `KernelCache` builds, loads and remembers the modules of
(system, kernel set) pairs on both tiers (vcirun.codegen.tiers: the generated text each is made from,
the compiled modules, their shared cores, the interpreted modules), the warm index, and keeps what a
process learns about them (modules loaded, files set aside, builds announced, first calls made,
plans resolved, background compiles started). `default()` is the instance the public API uses; a caller that wants its own
memory (a test that starts "a new process", a substitute loader) makes another.

What a call built is returned to it, not kept in a log to be sliced: `with kc.report() as rep:` collects
the build entries of the modules loaded inside the block (`rep.compiled`: something was generated or
compiled). A substitute loader (`KernelCache(loader=f)`, f(symbolic system, kernel set) -> module, e.g.
vcirun.codegen.evaluate.python_module_for to run uncompiled) replaces building and loading; such a
cache has no warm index (its modules do not come from the disk cache).

The file formats, keys, seals and the checks a load makes are those of vcirun.codegen.modules (key
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

from ..core.environ import jit_disabled
from . import cache_lock, cache_store, numba_cache
from . import modules as build
from .cache_store import CacheDamage
from .kernel_set import KernelSet

__all__ = ["KernelCache", "BuildReport", "default", "of"]


@dataclass
class BuildReport:
    """What the kernel cache did while the report was open (`KernelCache.report`). entries: the build
    entries of the modules loaded, dicts with key, system, kernels, cached (the module file was in the
    cache), generate_s, warm_index and, shared build, link_s, core_key, core_cold (numba had not cached
    the core's loop); numba_compiles: (module label, function) numba compiled for want of cached code;
    unsaved: (module label, why) compiled code that could not be saved in the cache."""

    entries: list = field(default_factory=list)
    numba_compiles: list = field(default_factory=list)
    unsaved: list = field(default_factory=list)

    @property
    def generated(self) -> int:
        """Modules generated (sympy, the C compiler) during the report."""
        return sum(not e["cached"] for e in self.entries)

    @property
    def compiled(self) -> bool:
        """Something was generated or compiled during the report."""
        return bool(self.numba_compiles) or any(not e["cached"] or e.get("core_cold") for e in self.entries)


class KernelCache:
    """Building, loading and the warm index of the kernel cache, with what this process knows of it.

    loader: None (the disk cache: generate, compile, load; warm index on), or f(symbolic system,
    kernel set) -> module used instead (no disk cache, no warm index)."""

    def __init__(self, loader=None, background: bool = False):
        self.loader = loader
        self.background = background  # the background compile process itself (vcirun.codegen.background)
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
        self._generated: dict = {}    # module key -> (generated text, number of parameters)
        self._interpreted: dict = {}  # module key -> the interpreted tier's module
        self.started: dict = {}       # module key -> background compile process started by this cache
        self.told: set = set()        # ("tier" | "failed" | "specialized", module key) notices this cache said
        self.upgrades: dict = {}      # shared module key -> its specialized build (vcirun.codegen.specialize)
        # False: a module keeps the build its first run found (a sweep times its runs: one build per module)
        self.switch_builds = True
        self.specialize = True        # False: modules stay on the shared build (a sweep resumed on it)

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

    def _event(self, label: str, kind: str, detail: str) -> None:
        with self.lock:
            for rep in self._reports:
                (rep.numba_compiles if kind == "compiled" else rep.unsaved).append((label, detail))

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
        """The compiled module for (symbolic system, ks): from this cache's memory, from the disk cache
        (checked against its digests), or generated now; a damaged entry is set aside and generated again.
        With a substitute loader: what it returns."""
        if self.loader is not None:
            return self.loader(system, ks)
        return self.compiled(self.module_key(system, ks), system.name, ks, system)

    def generated(self, key: str, ks: KernelSet, system=None) -> tuple[str, int] | None:
        """(text, number of parameters) of the generated part of module `key` (vcirun.codegen.derive:
        all of its sympy work), the input of both tiers: from memory, from `vg_<key>.py` (sealed; a
        damaged file is set aside), else derived now from symbolic `system` and written (best effort);
        None when neither the file nor the system is at hand."""
        if key in self._generated:
            return self._generated[key]
        path = self.cache_dir() / f"vg_{key}.py"
        try:
            data = cache_store.read(path)
            found = None if data is None else cache_store.unseal_text(data, key)
        except CacheDamage as e:
            cache_store.quarantine(path, e.reason, rebuild="deriving it again")
            found = None
        except ValueError as e:
            cache_store.quarantine(path, str(e), rebuild="deriving it again")
            found = None
        if found is not None and isinstance(found[1].get("nprm"), int) and found[1].get("kernels") == ks.key_text():
            out = (found[0], found[1]["nprm"])
        elif system is None:
            return None
        else:
            from .derive import generated_source   # sympy work happens only here

            out = (generated_source(system, ks), len(system.param_symbols))
            try:
                cache_store.write_atomic(path, cache_store.seal_text(
                    out[0], {"key": key, "system": system.name, "kernels": ks.key_text(), "nprm": out[1]}),
                    what=path.name)
            except cache_store.CacheError:
                pass   # a read-only cache: this process keeps the text in memory
        self._generated[key] = out
        return out

    def compiled(self, key: str, system_name: str, ks: KernelSet, system=None):
        """The compiled tier's module `key`: from memory, from its file in the cache (checked), or made
        now from the generated part (`generated`; the C compiler, numba); a damaged entry is set aside and
        made again. A background compile of the same module in progress is waited for (its lock), not
        repeated. A module loaded from disk has its entry points compiled (or loaded) by numba and is
        marked compiled for the processes that choose a tier (`ready`)."""
        if key in self.loaded:
            return self.loaded[key]
        from . import background

        d = self.cache_dir()
        lock = contextlib.nullcontext() if self.background else cache_lock.held(
            background.lock_path(d, key), f"the compiled tier of {system_name}/{build.family(ks)}")
        with lock:
            mod = self._compiled_module(key, system_name, ks, system)
            # (no marker for a module run uncompiled: NUMBA_DISABLE_JIT=1 compiles nothing)
            if not self.background and not jit_disabled() and background.marker(d, key) is None:
                nprm = self._nprm(key, ks, system, mod)
                if nprm is not None:
                    self.finish(mod, key, system_name, ks, nprm)
        return mod

    def _nprm(self, key, ks, system, mod) -> int | None:
        if system is not None:
            return len(system.param_symbols)
        if hasattr(mod, "NPRM"):
            return int(mod.NPRM)
        gen = self.generated(key, ks)
        return None if gen is None else gen[1]

    def finish(self, mod, key: str, system_name: str, ks: KernelSet, nprm: int) -> None:
        """numba's first calls of the module's entry points (under the module's first-call lock), then
        its marker: the compiled tier of `key` is there."""
        from . import background
        from .compile_notes import first_call_lock, note_first_call

        t0 = time.perf_counter()
        with first_call_lock(mod, kc=self):
            background.exercise(mod, ks, nprm)
        note_first_call(mod, ks, time.perf_counter() - t0, kc=self)   # (the next estimate of this build)
        background.write_marker(self.cache_dir(), key, {
            "system": system_name, "family": build.family(ks), "kernels": ks.key_text(),
            "seconds": round(time.perf_counter() - t0, 2), "time": time.time()})
        background.forget_failure(self.cache_dir(), key)

    def _compiled_module(self, key: str, system_name: str, ks: KernelSet, system=None):
        if key in self.loaded:
            return self.loaded[key]
        path = self.cache_dir() / f"vk_{key}.py"
        for attempt in range(2):
            t0 = time.perf_counter()
            body = self._bodies.pop(key, None)   # (checked by warm_lookup just now)
            found = (body, {}) if body is not None else self._verified_entry(path, key)
            cached = found is not None
            if found is None:
                gen = self.generated(key, ks, system)
                if gen is None:
                    raise CacheDamage(path, "is missing or damaged")
                body = build.module_text(gen[0], ks, gen[1], self.cache_dir(), system_name)
                cache_store.write_atomic(path, cache_store.seal_text(
                    body, {"key": key, "system": system_name, "kernels": ks.key_text()}), what=path.name)
            else:
                body = found[0]
            try:
                return self._exec_module(key, path, body, system_name, ks, cached, time.perf_counter() - t0,
                                         system is None)
            except CacheDamage as e:   # a shared object that changed between its check and its load
                if attempt:
                    raise
                self._set_aside_so(e)
        raise AssertionError("unreachable")

    def interpreted(self, key: str, system_name: str, ks: KernelSet, system=None):
        """The interpreted tier's module `key`: the generated part with the units and bindings run as
        Python (vcirun.codegen.evaluate.run_as_python), from the generated text in memory or in the cache
        (`generated`; no numba compile, no C compiler). Its TIER is "interpreted"."""
        mod = self._interpreted.get(key)
        if mod is None:
            from .evaluate import run_as_python

            gen = self.generated(key, ks, system)
            if gen is None:
                raise CacheDamage(self.cache_dir() / f"vg_{key}.py", "is missing or damaged")
            mod = run_as_python(build.interpreted_text(gen[0], ks), f"vcirun_interpreted_{key}",
                                str(self.cache_dir() / f"vg_{key}.py"))
            mod.TIER = "interpreted"
            mod.CACHE_LABEL = f"kernels for {system_name}/{build.family(ks)} (interpreted)"
            self._interpreted[key] = mod
        return mod

    def ready(self, key: str) -> bool:
        """Is the compiled tier of module `key` there: loaded by this cache, or marked compiled in the
        cache by any process?"""
        from . import background

        return key in self.loaded or background.marker(self.cache_dir(), key) is not None

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
        owner = numba_cache.Owner(label, estimate, lambda kind, detail: self._event(label, kind, detail))
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
        else:   # the specialized build's module (the kernels and the loop in one module)
            if not jit_disabled():
                label += " (specialized build)"
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

    def any_core_compiled(self) -> bool:
        """Has numba's cache the loop of any shared core? (True where the cache cannot say)"""
        try:
            d = self.cache_dir() / "__pycache__"
        except cache_store.CacheError:
            return True
        if any(c[0] == d for c in self._compiled):
            return True
        try:
            names = os.listdir(d)
        except OSError:
            return False
        return any(n.startswith("core_") and n.endswith(".nbi") and (".integrate-" in n or ".hamiltonian-" in n)
                   for n in names)

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
        """The index entry of (ident, ks) whose module and shared objects (or, before the compiled tier is
        there, whose generated text) are in the cache and match their digests, or None. An entry that fails its seal, or names a module of another system or kernel set,
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
        if key in self.loaded or key in self._interpreted:
            return entry
        found = self._verified_entry(self.cache_dir() / f"vk_{key}.py", key)
        if found is None:   # no compiled module (yet): the generated text serves both tiers
            return entry if self.generated(key, ks) is not None else None
        body, meta = found
        if meta.get("kernels") != ks.key_text() or meta.get("system") != entry.get("name"):
            cache_store.quarantine(path, f"points at the module of {meta.get('system')}/{meta.get('kernels')}",
                                   rebuild="rebuilding it from the symbolic system")
            return None
        self._bodies[key] = body
        return entry

    def warm_record(self, ident: tuple, ks: KernelSet, key: str, data: dict, system=None) -> None:
        """Write the index entry of (ident, ks) -> module `key` with numeric `data` (sealed, atomic; best
        effort: a read-only or full cache only costs the next process the symbolic path). With the
        symbolic `system`, nothing is written unless `key` is still its module key: the index key hashes
        the package's files as they are now, and where they changed since `key` was made (vcirun
        upgraded or edited while this process compiled) an entry would send the new files to the old
        module."""
        if system is not None and build.module_key_of(system, ks, self.backend_id()) != key:
            return
        entry = {"format": build.WARM_FORMAT, "ident": list(ident), "kernels": ks.key_text(), "module": key} | data
        try:
            path = self.index_path(ident, ks)
            cache_store.write_atomic(path, cache_store.seal_json(entry), what=path.name)
        except (cache_store.CacheError, TypeError, ValueError):
            pass

    def load_cached_module(self, key: str, system_name: str, ks: KernelSet):
        """The compiled module with this key (the caller found it with `warm_lookup`): from memory, its
        file, or the generated text in the cache (no symbolic work); CacheDamage when none is usable."""
        return self.compiled(key, system_name, ks)


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
