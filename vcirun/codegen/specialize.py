"""The auto build: a module whose loop runs long in a process is compiled again as one specialized module.

With VCIRUN_BUILD=auto (the default) every module starts in the shared build (vcirun.codegen.modules):
the scene's kernels alone, linked to its family's shared core, which is compiled once per machine, so a
new scene's first run waits for its kernels only. That loop calls the kernels by machine address and
takes about 1.4 times the time of a loop compiled together with them (docs/performance.md, the loop's
targets). Once the loops of one module have run HOT_S seconds in a process (a sweep worker, an
ensemble, a long study), its specialized module (the same generated text, with the units compiled
together with the kernels) is built by a background process at low priority (vcirun.codegen.background,
the same machinery as the compiled tier's), and the runs after its marker appears take it: in this
process at the next poll, in later processes from their first run. A sweep, which times its runs,
takes the specialized modules built before it starts (`take_built`) and holds each module on the
build it starts on (`KernelCache.switch_builds`; a sweep resumed over runs of the shared build stays
on it, `KernelCache.specialize`; the runs record theirs), so that no table of one method's times
mixes the two; a build it starts serves the next sweep. An ensemble holds its module too
(vcirun.run.plan.Plan.hold). A marker whose module or numba code is gone is dropped and the module
built again in the background, so a load finds its machine code there (only a damaged entry of
numba's cache is compiled again in the caller's process, by numba).

The two builds compute the same bits (numba compiles both without fused multiply-adds or
reassociation; bench/golden.py compares every golden case of each build with the same capture), so a
sweep's results do not depend on when its workers switched. A failed or impossible specialized build
leaves the runs on the shared one, said once.
"""
from __future__ import annotations

import time

from . import background, cache_store, numba_cache
from . import modules as build

__all__ = ["HOT_S", "POLL_S", "Upgrade", "upgrade", "take_built"]

HOT_S = 10.0   # seconds of one module's compiled loops in a process before its specialized build starts
POLL_S = 1.0   # seconds between two looks for the marker of a specialized build in progress
_STARTS = 2    # background builds one process starts for a module (a second after a kill without a record)


class Upgrade:
    """The specialized build of one shared module of kernel cache `kc` (`load`: the shared module's
    vcirun.codegen.tiers.Kernels). `seconds`: the module's loop time in this process so far, added by
    the runs (vcirun.run.plan.Plan.ran); `mod`: the specialized module once it is loaded."""

    def __init__(self, kc, load):
        self.kc, self.load = kc, load
        self.key = build.specialized_key(load.key)
        self.seconds = 0.0
        self.state = "waiting"   # waiting (for HOT_S), building, held (built, not taken yet), ready, off
        self.mod = None
        self._next_poll = 0.0
        self._starts = 0

    def due(self) -> bool:
        """Is a look for the specialized module due (hot or being built, not ready, not given up, not held;
        POLL_S since the last)?"""
        s = self.state
        return (s == "building" or (s == "waiting" and self.seconds >= HOT_S)
                or (s == "held" and self.kc.switch_builds)) and time.monotonic() >= self._next_poll

    def poll(self, first: bool = False):
        """The specialized module when it is there (loaded now if need be), else None; its build is
        started here once the shared module is hot and no process builds it. A cache that holds builds
        (`KernelCache.switch_builds` False) loads it only at the module's first use (`first`)."""
        if self.state == "ready":
            return self.mod
        if self.state == "off":
            return None
        self._next_poll = time.monotonic() + POLL_S
        try:
            d = self.kc.cache_dir()
        except cache_store.CacheError:
            self.state = "off"
            return None
        state = background.state(d, self.key)
        if state == "compiled" and not self._built(d):
            state = "none"   # (a marker whose module or machine code is gone: built again once hot)
        if state == "compiled":
            if first or self.kc.switch_builds:
                return self._load()
            self.state = "held"   # (built, not taken while the cache holds builds)
            return None
        if state == "compiling":
            self.state = "building"   # (by this or another process: watched from now on)
        elif state == "failed" and first:
            self.state = "off"   # (said by the process whose build failed; `vcirun cache info` lists it)
        elif state == "failed":
            self._off(f"its build failed ({(background.failure(d, self.key) or {}).get('reason', 'it stopped')}; "
                      f"log: {background.log_path(d, self.key)})")
        elif state == "none":
            proc = self.kc.started.get(self.key)
            if self.seconds < HOT_S:
                self.state = "waiting"   # (another process's build stopped: this one is not hot yet)
            elif proc is None or proc.poll() is not None:
                self._start(d)
        return None

    def _built(self, d) -> bool:
        """Are the module file and numba's code of its loop there (else the marker is dropped), so that a
        load does not compile the specialized module in the caller's process?"""
        path = d / f"vk_{self.key}.py"
        try:
            data = cache_store.read(path)
            ok = data is not None and numba_cache.index_exists(path, "integrate",
                                                                cache_store.unseal_text(data, self.key)[0])
        except (cache_store.CacheError, ValueError, OSError):
            ok = False   # (a damaged file: the load would set it aside and compile it here)
        if not ok:
            try:
                background.marker_path(d, self.key).unlink()
            except OSError:
                pass
        return ok

    def _start(self, d) -> None:
        if self._starts >= _STARTS:
            self._off("its background build stopped without a record")
            return
        self._starts += 1
        ks, key = self.load.ks, self.load.key
        gen = self.kc.generated(key, ks)
        if gen is None:
            gen = self.kc.generated(key, ks, self.load.system())   # (sympy: once, for a module this hot)
        path = d / f"vg_{self.key}.py"
        try:
            cache_store.write_atomic(path, cache_store.seal_text(
                gen[0], {"key": self.key, "system": self.load.name, "kernels": ks.key_text(), "nprm": gen[1]}),
                what=path.name)
            self.kc.started[self.key] = background.start(background.Job(
                self.key, ks, self.load.name, gen[1], d.parent, build.family(ks), build="specialized"), d)
        except (cache_store.CacheError, OSError) as e:
            self._off(f"its build could not start ({e})")
            return
        self.state = "building"

    def _load(self):
        try:
            with build.building("specialized"):
                mod = self.kc.compiled(self.key, self.load.name, self.load.ks)
        except (cache_store.CacheError, OSError) as e:
            self._off(f"it could not be loaded ({e})")
            return None
        self.mod, self.state = mod, "ready"
        return mod

    def _off(self, why: str) -> None:
        self.state = "off"
        if ("specialized", self.key) not in self.kc.told:
            self.kc.told.add(("specialized", self.key))
            cache_store.tell(f"vcirun: the specialized build of {self.load.label} is not used: {why}; its runs "
                             f"stay on the shared build (the same numbers, a slower loop)")


def module_build(mod) -> str:
    """The build a compiled module was made by: "shared" (a scene's kernels linked to a shared core,
    which marks the module with SHARED_CORE) or "specialized"."""
    return "shared" if hasattr(mod, "SHARED_CORE") else "specialized"


def upgrade(kc, load, tier: str):
    """The Upgrade of the shared module `load` (vcirun.codegen.tiers.Kernels) in `kc`, kept per module, or
    None where there is none: a substitute loader, VCIRUN_BUILD other than auto, uncompiled runs, the
    interpreted tier asked for. A new one looks once for a specialized module another process built
    (`Upgrade.mod` is then set)."""
    if tier == "interpreted" or kc.loader is not None or not kc.specialize or build.build_policy() != "auto" \
            or build.build_mode() != "shared":
        return None
    key = load.key
    up = kc.upgrades.get(key)
    if up is None:
        up = kc.upgrades[key] = Upgrade(kc, load)
        up.poll(first=True)
    return up


def take_built(kc) -> None:
    """Take every specialized module built since this cache's modules were first used (a sweep starts:
    its runs then keep the build they start on; forked workers inherit it)."""
    for up in list(kc.upgrades.values()):
        if up.state in ("waiting", "building", "held"):
            up.poll(first=True)
