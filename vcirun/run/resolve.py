"""From what a user names (a built-in scene, a YAML file, a MechanicalSystem) to the numeric system
and its module on a tier (vcirun.codegen.tiers): the symbolic path (sympy, on a cache miss) or the
warm index (a built-in name or a YAML file whose module is cached starts without any symbolic work).
Used by vcirun.simulate and by a Trajectory that re-attaches its dynamics."""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from ..codegen import build
from ..codegen.kernel_cache import KernelCache, default
from ..codegen.tiers import Kernels
from ..core.environ import getenv
from ..core.system_data import SystemData, restitution_parameters
from ..scenes.registry import scene_args, scene_data


def _is_yaml_source(s: str) -> bool:
    """A YAML system file: a name ending in .yaml/.yml, or an existing file that is not a built-in
    scene's name (a built-in name always means the scene: no file-system lookup per call)."""
    return s.endswith((".yaml", ".yml")) or (scene_args(s) is None and Path(s).is_file())


def resolve_system(system, params: dict | None = None):
    """A MechanicalSystem from a built-in name, a YAML file path, or an instance (symbolic: imports sympy)."""
    from ..mechanics.system import MechanicalSystem

    if isinstance(system, MechanicalSystem):
        if params:
            system.param_values(params)  # validates the names
        return system
    if isinstance(system, (str, Path)):
        s = str(system)
        if _is_yaml_source(s):
            from ..mechanics.loader import load_system_yaml

            return load_system_yaml(s)
        from ..scenes.registry import get_scene

        return get_scene(s)
    raise ValueError(f"system: expected a built-in name, a YAML path or a MechanicalSystem, got {type(system).__name__}")


# --- warm start: a system given by name or file without the symbolic system ----------------

def _warmable(system) -> bool:
    """A built-in scene name or an existing file: something the warm index may know."""
    if not isinstance(system, (str, Path)):
        return False
    s = str(system)
    return Path(s).is_file() if _is_yaml_source(s) else scene_args(s) is not None


def _warm_ident(system):
    """(("scene", name) or ("yaml", sha256 of the file), file bytes or None) for a system the warm index
    can serve, else (None, None) (instances, unknown names, missing files: the symbolic path decides)."""
    if not isinstance(system, (str, Path)):
        return None, None
    s = str(system)
    if _is_yaml_source(s):
        try:
            data = Path(s).read_bytes()
        except OSError:
            return None, None
        return ("yaml", hashlib.sha256(data).hexdigest()), data
    if scene_args(s) is None:
        return None, None
    return ("scene", s), None


def _data_from_entry(ident, entry) -> SystemData | None:
    """The numeric system of a warm index entry (None if it does not fit: then the symbolic path runs)."""
    try:
        names = [k for k, _ in entry["params"]]
        if ident[0] == "scene":
            d = scene_data(ident[1])
            if d.name != entry["name"] or d.n != entry["n"] or list(d.params) != names:
                return None
            return d
        n = int(entry["n"])
        vec = lambda v: None if v is None else np.array(v, dtype=float)  # noqa: E731
        d = SystemData(name=str(entry["name"]), n=n, params={k: v for k, v in entry["params"]},
                       default_q0=vec(entry["default_q0"]), default_p0=vec(entry["default_p0"]),
                       description=str(entry.get("description", "")), coordinates=entry.get("coordinates"),
                       restitution=entry.get("restitution"))
        if (entry.get("ic_map") or (d.default_q0 is None) != (d.default_p0 is None)
                or any(a is not None and a.shape != (n,) for a in (d.default_q0, d.default_p0))
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in d.params.values())):
            return None
        return d
    except (KeyError, TypeError, ValueError):
        return None


def _entry_data(sysm) -> dict:
    """What the warm index stores about a symbolic system (built-in scenes take the rest from
    vcirun.scenes.registry; YAML systems have no initial-condition map)."""
    vec = lambda a: None if a is None else np.asarray(a, float).tolist()  # noqa: E731
    return {"name": sysm.name, "n": sysm.n, "params": [[k, v] for k, v in sysm.params.items()],
            "default_q0": vec(sysm.default_q0), "default_p0": vec(sysm.default_p0),
            "description": sysm.description, "ic_map": sysm.ic_map is not None,
            "coordinates": [str(c) for c in sysm.q], "restitution": restitution_parameters(sysm)}


def warm_memo(ident, ks: build.KernelSet) -> tuple:
    """The key of a kernel cache's warm hits (`KernelCache.warm_hits`) for a warm identity (("scene", name)
    of a built-in scene) and kernel set, under the build and kernel path set now."""
    return ident, ks, getenv("VCIRUN_KERNEL_PATH", ""), build.build_id()


def resolve_numeric(system, ks: build.KernelSet, kc: KernelCache | None = None):
    """(SystemData, kernels, symbolic system or None) for `system` (built-in name, YAML path or
    MechanicalSystem) and kernel set `ks`; kernels(tier=None) returns the module from kernel cache `kc`
    (default: the API's) on that tier (vcirun.codegen.tiers.Kernels; `kernels.tier` says which ran).

    A built-in name or a YAML file whose (identity, ks) is in the warm index is served from it:
    no symbolic system, no sympy. Otherwise (and always for a MechanicalSystem instance) the
    symbolic system is built and its module loaded or generated; names and files are then indexed.
    A kernel cache with a substitute loader (KernelCache(loader=...)) has no warm index."""
    kc = default() if kc is None else kc
    ident, raw = _warm_ident(system) if kc.warm else (None, None)
    if ident is not None:
        memo = warm_memo(ident, ks)
        hit = kc.warm_hits.get(memo)
        if hit is not None:   # this cache has read the entry already: no file access per call
            return hit
        entry = kc.warm_lookup(ident, ks)
        d = _data_from_entry(ident, entry) if entry is not None else None
        if d is not None:
            hit = (d, Kernels(kc, ks, d.name, len(d.params), key=entry["module"],
                              resolve=lambda: resolve_system(system)), None)
            kc.warm_hits[memo] = hit
            return hit
    sysm = resolve_system(system)
    d = SystemData.of(sysm)

    def indexed(tier):
        if ident is not None and (raw is None or _warm_ident(system)[1] == raw):  # the file we hashed
            kc.warm_record(ident, ks, kc.module_key(sysm, ks), _entry_data(sysm), system=sysm)

    return d, Kernels(kc, ks, sysm.name, len(sysm.param_symbols), sysm=sysm,
                      on_load=indexed if kc.warm else None), sysm
