"""The built-in scenes by name: one registry of `Scene` declarations (vcirun.scenes.scene), and the
views every other module asks it through: the numeric part (`scene_data`, no sympy: a warm start
resolves a scene from here alone), the symbolic system (`get_scene`), and what the scene means
(`scene_info`, `describe`, `coordinate_names`, `units_for`: `vcirun systems`, `Trajectory.to_xarray`).

A family is named <family>_K (`n_pendulum_3`, `link_chain_friction_4`; K's range is
vcirun.core.limits.FAMILY_SIZES); the family's bare name is its default size. SI units throughout,
angles in radians; a YAML-declared system has coordinate names but no declared units (its units are
the user's).
"""
from __future__ import annotations

import functools

from ..core.limits import FAMILY_SIZES, sized_family
from ..core.system_data import SystemData
from . import contacts, friction, paper, walkers
from .scene import Scene, SceneInfo

__all__ = ["BUILTIN_SCENES", "Scene", "SceneInfo", "coordinate_names", "describe", "example_command",
           "find_scene", "get_scene", "listed_scenes", "momentum_unit", "scene_args", "scene_data", "scene_info",
           "unknown_scene_error", "units_for"]

# name -> Scene, in the order `vcirun systems` lists them
BUILTIN_SCENES: dict[str, Scene] = {s.name: s for s in paper.SCENES + contacts.SCENES
                                    + walkers.SCENES + friction.SCENES}


def scene_args(name: str):
    """(scene name, (K,) or ()) of a built-in scene name (`n_pendulum_K` -> ('n_pendulum', (K,))), or
    None if `name` is not a built-in scene. A family's K outside its range (the caps table,
    vcirun.core.limits.FAMILY_SIZES) is a ValueError naming the system, before anything is built."""
    if not isinstance(name, str):
        return None
    sized = sized_family(name)
    if sized is not None:
        return sized[0], (sized[1],)
    if name in BUILTIN_SCENES:
        return name, ()
    return None


def find_scene(name) -> tuple[Scene, int | None] | None:
    """(Scene, K or None) of a built-in scene name, or None."""
    args = scene_args(str(name))
    if args is None:
        return None
    return BUILTIN_SCENES[args[0]], (args[1][0] if args[1] else None)


def unknown_scene_error(name) -> ValueError:
    return ValueError(f"system: unknown built-in system {name!r} (choose one of {', '.join(BUILTIN_SCENES)}, "
                      "or give a YAML file path)")


def _found(name) -> tuple[Scene, int | None]:
    found = find_scene(name)
    if found is None:
        raise unknown_scene_error(name)
    return found


def scene_data(name: str, **params) -> SystemData:
    """The numeric part of a built-in scene by name (no sympy)."""
    scene, k = _found(name)
    return scene.data(k, **params)


def get_scene(name: str, **params):
    """The symbolic MechanicalSystem of a built-in scene by name; `n_pendulum_K` selects the K-link
    pendulum. Scenes without parameter overrides are built once per process (parameter values are
    runtime inputs anyway)."""
    if not params:
        return _scene_cached(name)
    scene, k = _found(name)
    return scene.system(k, **params)


@functools.lru_cache(maxsize=None)
def _scene_cached(name: str):
    scene, k = _found(name)
    return scene.system(k)


# --- what the scenes mean -------------------------------------------------------------------------------

# Momentum units follow from p = M(q) qdot: a length coordinate has kg m/s, an angle kg m^2/s (J s).
_MOMENTUM = {"m": "kg m/s", "rad": "kg m^2/s"}


def momentum_unit(unit: str) -> str:
    return _MOMENTUM.get(unit, "")


def listed_scenes() -> list[str]:
    """Every built-in scene, the sized ones as <name>_3 (`vcirun systems`)."""
    return [f"{nm}_3" if s.size is not None else nm for nm, s in BUILTIN_SCENES.items()]


def scene_info(name: str) -> SceneInfo | None:
    """The description of a built-in scene (`n_pendulum_K`, `newton_cradle_K`, `link_chain_K`,
    `cradle_K` for K in the family's range, vcirun.core.limits.FAMILY_SIZES; the bare sized name is its
    default size), or None."""
    found = find_scene(name)
    return None if found is None else found[0].info(found[1])


def _family(name: str, bare: bool = False) -> str | None:
    """The sized family of `name` (<family>_K, K in range or not; with bare, the family's own name too), else None."""
    return next((b for b, s in BUILTIN_SCENES.items() if s.size is not None and (
        (name.startswith(b + "_") and name[len(b) + 1:].isdigit()) or (bare and name == b))), None)


def describe(name: str) -> list[str]:
    """The lines `vcirun systems NAME` prints for a built-in scene (ValueError naming the choices)."""
    info = scene_info(name)
    if info is None:
        raise ValueError(f"system: unknown built-in system {name!r} (choose one of {', '.join(listed_scenes())}; "
                         "the sized ones with K in their range, e.g. cradle_20)")
    d = scene_data(name)
    sized = _family(name)
    coords = ", ".join(f"{c} [{u}] {m}" for c, u, m in info.coordinates)
    lines = [f"{name}  {d.description}" + (f"  ({sized}_K: K from {FAMILY_SIZES[sized][0]} to "
                                           f"{FAMILY_SIZES[sized][1]})" if sized else ""),
             f"  coordinates  {coords}; momenta p = M(q) qdot in "
             + ", ".join(momentum_unit(u) for _, u, _ in info.coordinates),
             "  parameters   " + "; ".join(f"{k} = {v:g} {info.params.get(k, ('', ''))[0]} "
                                          f"({info.params.get(k, ('', ''))[1]})" for k, v in d.params.items()),
             f"  constraint   {info.constraint}"]
    if info.ic_map:
        lines.append(f"  --beta       {info.ic_map}")
    if info.default_state:
        lines.append(f"  default      {info.default_state}")
    lines.append(f"  example      {example_command(name)}")
    return lines


def example_command(name: str) -> str:
    """The `vcirun simulate` line `vcirun systems` shows for a built-in scene, with what it shows (each
    scene's `example`: the arguments that show the impacts it is there for; tests/cli/test_examples.py
    runs every example and counts them)."""
    scene = BUILTIN_SCENES.get(name) or BUILTIN_SCENES.get(_family(name, bare=True) or "")
    args, what = scene.example if scene is not None else ("", "")
    cmd = f"vcirun simulate --system {name}" + (f" {args}" if args else "")
    return cmd + (f"   ({what})" if what else "   (the default state)")


def coordinate_names(system: str, n: int, declared=None) -> list[str]:
    """Names of the n coordinates: declared (a YAML system's), the scene's, else q0 .. q{n-1}."""
    if declared is not None and len(declared) == n:
        return [str(c) for c in declared]
    info = scene_info(system)
    if info is not None and len(info.coordinates) == n:
        return [c[0] for c in info.coordinates]
    return [f"q{i}" for i in range(n)]


def units_for(system: str, names) -> list[str]:
    """SI unit of each named coordinate of a built-in scene ("" where unknown, e.g. YAML systems)."""
    info = scene_info(system)
    known = {c[0]: c[1] for c in info.coordinates} if info is not None else {}
    return [known.get(str(c), "") for c in names]
