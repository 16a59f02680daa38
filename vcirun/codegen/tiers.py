"""Two tiers of one module: interpreted at once, compiled as soon as it is there.

A module of (system, kernel set) runs on one of two tiers, with the same generated text
(vcirun.codegen.build: `interpreted_text`, `module_text`):

- "compiled": numba machine code (and C for the long leaf kernels), cached per machine; its first
  build takes 10-60 s;
- "interpreted": the same kernels, units and bindings run as Python (vcirun.codegen.evaluate), ready
  as soon as the kernels are derived (about a second for the paper's scenes); a run is 100-1000x
  slower than compiled, which is still milliseconds to a second for the runs people start with.

`tier` ("auto", "interpreted" or "compiled"; default VCIRUN_TIER, else "auto") chooses. "auto" runs the
compiled tier when it is there (loaded here, or marked compiled in the cache by any process), and
otherwise the interpreted tier while a background process builds the compiled one
(vcirun.codegen.background); later calls, here and in other processes, take the compiled tier once
it is marked. Where no background process can help (NUMBA_DISABLE_JIT=1, a read-only cache), "auto"
is "compiled". Both tiers compute the same arithmetic: trajectories agree to the bit where the
operations are the same (numba compiles without fused multiply-adds or reassociation, the C kernels
with -ffp-contract=off), and to 1e-12 otherwise (tests/unit/test_tiers.py, on bench/golden.py's cases).
"""
from __future__ import annotations

from ..core.environ import getenv, jit_disabled
from . import modules as build

__all__ = ["TIERS", "ENV", "requested", "Kernels", "load_module"]

TIERS = ("auto", "interpreted", "compiled")
ENV = "VCIRUN_TIER"


def requested(tier=None) -> str:
    """The tier asked for: `tier`, else $VCIRUN_TIER, else "auto" (ValueError naming the field)."""
    field = "tier"
    if tier is None:
        tier, field = getenv(ENV), ENV
        if tier is None:   # (every simulate call asks: the common cases first)
            return "auto"
        if tier in TIERS:
            return tier
        tier = tier.strip() or "auto"
    elif type(tier) is str and tier in TIERS:
        return tier
    if not isinstance(tier, str) or tier.strip().lower() not in TIERS:
        raise ValueError(f"{field}: {tier!r} is not a tier (use auto, interpreted or compiled)")
    return tier.strip().lower()


class Kernels:
    """The module of one (system, kernel set) in a kernel cache, on the tier asked for; `tier` is the
    tier of the module last returned ("compiled", "interpreted", or "substitute" for a cache with a
    substitute loader).

    key: the module key (a warm start knows it); sysm: the symbolic system when it is built; resolve:
    a function that builds it (called only when a file the cache needs is missing); nprm: its number of
    parameters; on_load(tier): called after each load (the warm index entry is written then)."""

    def __init__(self, kc, ks, name: str, nprm: int, *, key: str | None = None, sysm=None, resolve=None,
                 on_load=None):
        self.kc, self.ks, self.name, self.nprm = kc, ks, name, int(nprm)
        self._key, self.sysm, self._resolve, self.on_load = key, sysm, resolve, on_load
        self.tier = None

    def system(self):
        """The symbolic system (built now when this handle has only a way to build it)."""
        if self.sysm is None:
            self.sysm = self._resolve()
        return self.sysm

    @property
    def key(self) -> str:
        if self._key is None:
            self._key = self.kc.module_key(self.system(), self.ks)
        return self._key

    @property
    def label(self) -> str:
        return f"{self.name}/{build.family(self.ks)}"

    def ready(self) -> bool:
        """Is the compiled tier there (loaded by this cache, or marked compiled in the cache)?"""
        return self.kc.loader is None and self.kc.ready(self.key)

    def poll(self) -> bool:
        """`ready`, asked by a caller running on the interpreted tier before each run; when it is not, the
        background compile is started again if no process holds it (it was killed), and a failed one is
        said once."""
        if self.ready():
            return True
        self._background()
        return self.ready()

    def __call__(self, tier=None):
        kc = self.kc
        if kc.loader is not None:
            self.tier = "substitute"
            return kc.loader(self.system(), self.ks)
        tier = requested(tier)
        if tier == "auto":
            tier = "compiled" if (jit_disabled() or kc.background or self.ready()
                                  or not self._background()) else "interpreted"
        mod = self._compiled() if tier == "compiled" else self._interpreted()
        self.tier = tier
        if self.on_load is not None:
            self.on_load(tier)
        return mod

    def _compiled(self):
        from .cache_store import CacheDamage

        if self.sysm is not None and not self.ready():
            from .compile_notes import announce_if_cold

            announce_if_cold(self.sysm, self.ks, kc=self.kc)  # "compiling kernels for ... (first time, about N s)"
        try:
            return self.kc.compiled(self.key, self.name, self.ks, self.sysm)
        except CacheDamage:
            if self.sysm is not None or self._resolve is None:
                raise
            return self.kc.compiled(self.key, self.name, self.ks, self.system())   # (files gone since the lookup)

    def _interpreted(self):
        sysm = self.sysm if self.sysm is not None or self.kc.generated(self.key, self.ks) is not None \
            else self.system()
        return self.kc.interpreted(self.key, self.name, self.ks, sysm)

    def _background(self) -> bool:
        """The compiled tier is being built (here or by another process), or a build was started now (also
        again, after a kill); False when no background build can run (a read-only cache, no generated text
        to hand over). A failed build is said once and not started again (its record stays until the
        cache is cleared or the compiled tier is asked for and builds)."""
        from . import background
        from .cache_store import CacheError, writable

        kc, key = self.kc, self.key
        try:
            d = kc.cache_dir()
        except CacheError:
            return False
        if not writable(d):
            return False
        proc = kc.started.get(key)
        if proc is not None and proc.poll() is None:
            return True
        state = background.state(d, key)
        if state == "compiled":
            return False   # (marked since `ready` looked: the caller loads it)
        if state == "compiling":
            self._say_tier(d)
            return True
        if state == "failed":
            self._say_failure(d)
            return True
        # never started, or stopped without a record (killed): started (again) now
        if kc.generated(key, self.ks) is None:
            kc.generated(key, self.ks, self.system())   # derived now (sympy), written for the build
        if not (d / f"vg_{key}.py").is_file():
            return False   # (the text could not be written: nothing to hand over)
        try:
            kc.started[key] = background.start(background.Job(key, self.ks, self.name, self.nprm, d.parent,
                                                              build.family(self.ks)), d)
        except OSError:
            return False
        self._say_tier(d)
        return True

    def _say_failure(self, d) -> None:
        from . import background
        from .cache_store import tell

        if ("failed", self.key) in self.kc.told:
            return
        self.kc.told.add(("failed", self.key))
        f = background.failure(d, self.key) or {}
        tell(f"vcirun: the background compile of {self.label} failed ({f.get('reason', 'it stopped')}); its runs "
             f"stay on the interpreted tier (same numbers, slower). tier='compiled' (or VCIRUN_TIER=compiled) "
             f"compiles here and shows the error; log: {f.get('log', background.log_path(d, self.key))}")

    def _say_tier(self, d) -> None:
        from .cache_store import tell

        if ("tier", self.key) in self.kc.told:
            return
        self.kc.told.add(("tier", self.key))
        about = ""
        if self.sysm is not None:
            from .compile_notes import estimate_compile_s

            try:
                est = estimate_compile_s(self.ks, self.sysm.n, build.system_core_features(self.ks, self.sysm),
                                         kc=self.kc)
                about = f", about {est:.0f} s"
            except Exception:   # noqa: BLE001 - an estimate never stops a run
                about = ""
        tell(f"vcirun: {self.label} runs on the interpreted tier now; its compiled tier is being built in the "
             f"background{about} (`vcirun cache info` shows it), and later runs use it")


def load_module(system, ks, tier: str | None = "compiled", kc=None):
    """The module for (symbolic system, ks) from kernel cache `kc` (default: the API's) on `tier`:
    "compiled" (waiting for the compiler if need be), "interpreted", "auto", or None ($VCIRUN_TIER, else
    auto)."""
    from .kernel_cache import default

    kc = default() if kc is None else kc
    if tier == "compiled" or kc.loader is not None:
        return kc.load_module(system, ks)
    return Kernels(kc, ks, system.name, len(system.param_symbols), sysm=system)(tier)
