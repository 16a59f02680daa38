"""What a cold build says about itself, for a kernel cache (vcirun.codegen.kernel_cache.KernelCache, passed
as `kc`): what loading a module has to compile (`cold_parts`), how long that takes (`estimate_compile_s`,
from this cache's recorded build times, `note_first_call`), the line that says so (`announce_if_cold`),
and the lock around numba's first call of a module's loop (`first_call_lock`). vcirun.codegen.cache
has the same functions with the API's kernel cache as the default."""
from __future__ import annotations

import contextlib
import json

from . import cache_lock, cache_store

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


def _times() -> dict:
    return cache_store.build_times()


def core_estimate_s(core_key: str, first: float = None) -> float:
    """Seconds numba takes to compile a shared core: this cache's record of it, else `first` (default a
    general core's first estimate)."""
    return float(_times().get(f"core|{core_key}", _DEFAULT_CORE_S["general"] if first is None else first))


def estimate_compile_s(ks, n: int, features: tuple = (), with_core: bool = True, *, kc) -> float:
    """Seconds a cold build of (ks, n) is expected to take: this cache's last build of the same family
    and size, else of the same family at another size (scaled linearly in n), else a first estimate.
    Shared build (vcirun.codegen.shared): the scene's kernels, plus the core if numba has not cached it
    and `with_core` (False: another build compiles it)."""
    from . import modules as build

    times, kind = _times(), (ks.reset or "system").upper()
    if build.build_mode() != "shared":
        return _by_family(times, build.family(ks), n, _DEFAULT_S.get(kind, 15.0))
    first = _DEFAULT_CORE_S[("lean" if features else "general") if ks.full_stages else
                            ("system lean" if features else "system")] + (5.0 if kind == "MCVA" else 0.0)
    if not with_core:
        core = 0.0
    elif not kc.any_core_compiled() and not any(k.startswith("core|") for k in times):
        # (a cache with no core compiled or timed, as a first run's: the core's key, whose text costs
        # ~0.3 s to assemble and check, is not needed for the first estimate)
        core = first
    else:
        key = kc.core_key_of(ks, n, features)
        core = 0.0 if kc.core_compiled(key) else core_estimate_s(key, first)
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


def cold_parts(system, ks, *, kc) -> tuple[str, ...]:
    """What loading the module of symbolic `system` with `ks` has to compile: () when it is cached (or
    was loaded, or set aside and said), ("scene",) for its kernels, ("scene", "core") for its kernels
    and their shared core, ("core",) for the core alone (shared build)."""
    from . import modules as build

    key = kc.module_key(system, ks)
    if key in kc.loaded or key in kc.set_aside:   # (no file access on the path of every later call;
        return ()                                 # a module set aside was said when it was)
    parts = () if (kc.cache_dir() / f"vk_{key}.py").exists() else ("scene",)
    if build.build_mode() == "shared" and not kc.core_compiled(core_key_for(system, ks, kc=kc)):
        parts += ("core",)
    return parts


def core_key_for(system, ks, *, kc) -> str:
    """The key of the shared core that serves symbolic `system` with `ks`."""
    from . import modules as build

    return kc.core_key_of(ks, system.n, build.system_core_features(ks, system))


def announce_if_cold(system, ks, cores_covered=(), *, kc) -> bool:
    """Before loading the module of (system, ks): if it must be generated and compiled, say so
    ("compiling kernels for <scene>/<family> and their shared core (one contact, unforced) (first
    time, about N s)") to the logger and callbacks, once; `cores_covered`: core keys whose compile
    an earlier announcement of the same build named already."""
    from . import modules as build
    from .shared import FEATURE_NAMES

    parts = cold_parts(system, ks, kc=kc)
    if not parts:
        return False
    feats = build.system_core_features(ks, system)
    # a core another kernel set of the same build covers (CVA's and VCI's share one) is not repeated
    with_core = "core" in parts and (build.build_mode() != "shared"
                                     or core_key_for(system, ks, kc=kc) not in cores_covered)
    core = (" and their shared core" + (f" ({FEATURE_NAMES[feats]})" if ks.full_stages else "")) if with_core else ""
    msg = (f"compiling kernels for {system.name}/{build.family(ks)}{core} (first time, about "
           f"{estimate_compile_s(ks, system.n, feats, with_core=with_core, kc=kc):.0f} s; cached in {cache_store.root()})")
    kc.announced.add(kc.module_key(system, ks))
    if build.build_mode() == "shared":
        kc.announced.add(core_key_for(system, ks, kc=kc))
    cache_store.tell(msg)
    return True


def note_first_call(mod, ks, seconds: float, *, kc) -> None:
    """After numba's first call of a module's loop: if the module was generated by kernel cache `kc`,
    record generation + first call as the build time of its family and size (the next estimate)."""
    from . import modules as build

    key = mod.__name__.rsplit("_", 1)[-1]
    entry = kc.entries.get(key)
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
        cache_store.write_atomic(cache_store.root() / cache_store.TIMES_FILE, json.dumps(times, sort_keys=True), what=cache_store.TIMES_FILE)
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
        path = (kc.cache_dir() if kc is not None else cache_store.kernels_dir()) / f"vk_{key}.lock"
    except cache_store.CacheError:
        path = None
    if path is None:
        yield
        return
    with cache_lock.held(path, getattr(mod, "CACHE_LABEL", None) or f"module {key}", timeout_s=timeout_s):
        yield
