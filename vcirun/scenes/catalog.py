"""What the built-in scenes mean: coordinates, parameters, units (sympy-free; `vcirun systems`,
`Trajectory.to_xarray`).

The numbers (defaults, initial-condition maps) live in `vcirun.scenes.data`, the symbolic M, V, phi in
`vcirun.scenes.declarations`; this module only describes them. SI units throughout, angles in radians.
A YAML-declared system has coordinate names but no declared units (its units are the user's).
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["SceneInfo", "scene_info", "coordinate_names", "units_for", "momentum_unit", "BUILTIN_INFO"]


@dataclass(frozen=True)
class SceneInfo:
    """coordinates: ((name, unit, meaning), ...); params: {name: (unit, meaning)}; constraint and
    initial-condition map in words."""
    name: str
    coordinates: tuple
    params: dict
    constraint: str
    ic_map: str = ""
    default_state: str = ""


# Momentum units follow from p = M(q) qdot: a length coordinate has kg m/s, an angle kg m^2/s (J s).
_MOMENTUM = {"m": "kg m/s", "rad": "kg m^2/s"}


def momentum_unit(unit: str) -> str:
    return _MOMENTUM.get(unit, "")


def _pendulum_params(n: int) -> dict:
    out = {"g": ("m/s^2", "gravitational acceleration"),
           "w": ("m", "wall position: the tip cannot pass x = w")}
    for i in range(1, n + 1):
        out[f"m{i}"] = ("kg", f"point mass at the tip of link {i}")
    for i in range(1, n + 1):
        out[f"l{i}"] = ("m", f"length of link {i}")
    return out


BUILTIN_INFO = {
    "cart_pendulum": SceneInfo(
        "cart_pendulum",
        (("y", "m", "height of the cart on its vertical track"),
         ("theta", "rad", "pendulum angle from the downward vertical")),
        {"m1": ("kg", "cart mass"), "m2": ("kg", "pendulum point mass"), "L": ("m", "rod length"),
         "g": ("m/s^2", "gravitational acceleration")},
        "phi = y >= 0 (the cart hits the floor)",
        "Xi(beta) = FL([beta, 0], [0, 3.5 - 0.18 beta]) (paper Section 5.1); beta in [3.2, 5.2] for Figure 4",
        "none: give --beta (default 3.2 on the command line) or q0 and p0"),
    "double_pendulum": SceneInfo(
        "double_pendulum",
        (("theta1", "rad", "angle of link 1 from the downward vertical"),
         ("theta2", "rad", "angle of link 2 from the downward vertical")),
        {"m1": ("kg", "point mass at the tip of link 1"), "m2": ("kg", "point mass at the tip of link 2"),
         "l1": ("m", "length of link 1"), "l2": ("m", "length of link 2"),
         "g": ("m/s^2", "gravitational acceleration"), "w": ("m", "wall position x = w")},
        "phi = w - (l1 sin theta1 + l2 sin theta2) >= 0 (the second tip cannot pass the wall)",
        "beta scales the initial angles: theta = beta (-1, -1), at rest",
        "both links horizontal, away from the wall, at rest (paper Figure 1; our choice)"),
    "oscillator_wall": SceneInfo(
        "oscillator_wall", (("x", "m", "position of the mass"),),
        {"m": ("kg", "mass"), "k": ("N/m", "spring stiffness"), "d": ("m", "distance of the wall x = -d")},
        "phi = x + d >= 0 (elastic wall; closed-form solution)", "x = beta, at rest", "x = 1, at rest"),
    "damped_oscillator": SceneInfo(
        "damped_oscillator", (("x", "m", "position of the mass"),),
        {"m": ("kg", "mass"), "k": ("N/m", "spring stiffness"), "c": ("N s/m", "linear damping coefficient"),
         "d": ("m", "distance of the wall x = -d (far away by default)")},
        "phi = x + d >= 0", "", "x = 1, at rest"),
    "bouncing_ball": SceneInfo(
        "bouncing_ball", (("y", "m", "height of the ball above the floor"),),
        {"m": ("kg", "mass"), "g": ("m/s^2", "gravitational acceleration"),
         "c": ("N s/m", "linear air drag (impacts accumulate if c > 0)")},
        "phi = y >= 0 (elastic floor)", "drop height y = beta, at rest", "y = 1, at rest"),
}


def scene_info(name: str) -> SceneInfo | None:
    """The description of a built-in scene (`n_pendulum_K` for any K), or None."""
    if name in BUILTIN_INFO:
        return BUILTIN_INFO[name]
    if isinstance(name, str) and name.startswith("n_pendulum_") and name[len("n_pendulum_"):].isdigit():
        n = int(name[len("n_pendulum_"):])
        return SceneInfo(name, tuple((f"theta{i}", "rad", f"angle of link {i} from the downward vertical")
                                     for i in range(1, n + 1)),
                         _pendulum_params(n), "phi = w - sum_i l_i sin theta_i >= 0 (the tip cannot pass the wall)",
                         "beta scales the initial angles: theta_i = -beta, at rest",
                         "every link horizontal, away from the wall, at rest")
    return None


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
