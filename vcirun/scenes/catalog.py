"""What the built-in scenes mean: coordinates, parameters, units (sympy-free; `vcirun systems`,
`Trajectory.to_xarray`).

The numbers (defaults, initial-condition maps) live in `vcirun.scenes.data`, the symbolic M, V, phi in
`vcirun.scenes.declarations`; this module only describes them. SI units throughout, angles in radians.
A YAML-declared system has coordinate names but no declared units (its units are the user's).
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["SceneInfo", "scene_info", "describe", "listed_scenes", "coordinate_names", "units_for", "momentum_unit",
           "example_command", "BUILTIN_INFO"]


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


_E = ("", "restitution coefficient of every contact")
BUILTIN_INFO |= {
    "ball_in_box": SceneInfo(
        "ball_in_box", (("x", "m", "horizontal position of the ball"), ("y", "m", "height of the ball")),
        {"m": ("kg", "mass"), "g": ("m/s^2", "gravitational acceleration"), "width": ("m", "box width"),
         "height": ("m", "box height"), "e": _E},
        "4 contacts: floor y >= 0, ceiling height - y >= 0, left x >= 0, right width - x >= 0", "",
        "x = 0.3, y = 0.6, moving right at 0.7 m/s"),
    "double_pendulum_walls": SceneInfo(
        "double_pendulum_walls", BUILTIN_INFO["double_pendulum"].coordinates,
        BUILTIN_INFO["double_pendulum"].params | {"w": ("m", "walls at x = -w and x = w"), "e": _E},
        "2 contacts: right w - x_tip >= 0, left x_tip + w >= 0 (x_tip = l1 sin theta1 + l2 sin theta2)",
        "hanging down, kicked: theta = (0, 0), thetadot = beta (2, 1)", "hanging down, p = (6, 3)"),
    "rocking_block": SceneInfo(
        "rocking_block", (("x", "m", "horizontal position of the block's centre"),
                          ("y", "m", "height of the block's centre"), ("theta", "rad", "tilt of the block")),
        {"m": ("kg", "mass"), "a": ("m", "block height"), "b": ("m", "block width"),
         "g": ("m/s^2", "gravitational acceleration"), "e": _E},
        "2 contacts: the lower corners (-b/2, -a/2) and (b/2, -a/2) above the floor y = 0 (declared by bodies)",
        "drop height of the centre y = beta, theta = 0.2, at rest", "y = 0.7, theta = 0.2, at rest"),
    "rimless_wheel": SceneInfo(
        "rimless_wheel", (("theta", "rad", "stance spoke's angle from the slope normal, forward positive"),),
        {"m": ("kg", "point mass at the hub"), "l": ("m", "spoke length"),
         "alpha": ("rad", "half the angle between two spokes"), "gamma": ("rad", "slope angle"),
         "g": ("m/s^2", "gravitational acceleration")},
        "phi = alpha - theta >= 0 (the next spoke touches down at theta = alpha); declared plastic reset "
        "theta+ = theta - 2 alpha, thetadot+ = cos(2 alpha) thetadot",
        "just after a touchdown: theta = -alpha, thetadot = beta",
        "the closed-form period-one gait just after a touchdown"),
    "compass_gait": SceneInfo(
        "compass_gait", (("theta_s", "rad", "stance leg's angle from the slope normal, forward positive"),
                         ("theta_ns", "rad", "swing leg's angle from the slope normal, forward positive")),
        {"m": ("kg", "point mass on each leg"), "mH": ("kg", "hip mass"),
         "a": ("m", "leg mass to foot"), "b": ("m", "leg mass to hip"), "gamma": ("rad", "slope angle"),
         "g": ("m/s^2", "gravitational acceleration")},
        "phi = (a + b)(cos theta_s - cos theta_ns) >= 0 once theta_s > 0 (heel strike); declared reset: "
        "plastic impact of the swing foot and exchange of the legs (Goswami et al. 1998)",
        "the default state with its velocities scaled by beta",
        "the period-one gait at gamma = 3 deg just after heel strike"),
}
_MU = ("", "Coulomb (kinetic) friction coefficient")
_MU_S = ("", "static friction coefficient (>= mu)")
_BLOCK = (("x", "m", "horizontal position of the block's centre"), ("y", "m", "height of the block's centre"),
          ("theta", "rad", "tilt of the block"))
BUILTIN_INFO |= {
    "rocking_block_friction": SceneInfo(
        "rocking_block_friction", _BLOCK,
        {"m": ("kg", "mass"), "a": ("m", "block height"), "b": ("m", "block width"),
         "g": ("m/s^2", "gravitational acceleration"), "mu": _MU, "mu_s": _MU_S},
        "2 contacts: the lower corners (-b/2, -a/2) and (b/2, -a/2) above the floor y = 0, plastic, with "
        "friction (declared by bodies)",
        "at rest on a corner at the tilt theta = beta (the left corner for beta > 0), that corner on the floor",
        "beta = 0.1"),
    "spinning_ball": SceneInfo(
        "spinning_ball", (("x", "m", "horizontal position of the centre"), ("y", "m", "height of the centre"),
                          ("phi", "rad", "angle of the ball")),
        {"m": ("kg", "mass"), "R": ("m", "radius"), "mu": _MU, "g": ("m/s^2", "gravitational acceleration")},
        "1 contact: the rim above the floor, y - R >= 0, plastic, with friction (the slip velocity xdot + R phidot "
        "includes the spin)",
        "dropped from centre height 1, at rest but for the spin phidot = beta",
        "beta = 50 (slides through the impact; beta = 10 sticks)"),
    "incline": SceneInfo(
        "incline", (("x", "m", "horizontal position"), ("y", "m", "height")),
        {"m": ("kg", "mass"), "g": ("m/s^2", "gravitational acceleration"), "theta": ("rad", "slope angle"),
         "mu": _MU, "mu_s": _MU_S},
        "1 contact: -sin(theta) x + cos(theta) y >= 0 (the slope through the origin), plastic, with friction "
        "along (cos theta, sin theta)",
        "at the origin, launched up the slope at beta m/s",
        "beta = 2 (stops at t = 0.419 s, then slides back: tan theta > mu_s)"),
    "coulomb_oscillator": SceneInfo(
        "coulomb_oscillator", (("x", "m", "position along the floor (the spring's rest point x = 0)"),
                               ("y", "m", "height above the floor")),
        {"m": ("kg", "mass"), "k": ("N/m", "spring stiffness"), "g": ("m/s^2", "gravitational acceleration"),
         "mu": _MU, "mu_s": _MU_S},
        "1 contact: the floor y >= 0, plastic, with friction along x",
        "on the floor at x = beta, at rest", "beta = 1 (five half swings, then it sticks)"),
    "painleve_rod": SceneInfo(
        "painleve_rod", (("x", "m", "horizontal position of the rod's centre"),
                         ("y", "m", "height of the rod's centre"), ("theta", "rad", "angle of the rod from the floor")),
        {"m": ("kg", "mass"), "l": ("m", "half length"), "g": ("m/s^2", "gravitational acceleration"),
         "mu": _MU, "mu_s": _MU_S},
        "1 contact: the lower end C - l (cos theta, sin theta) above the floor y = 0, plastic, with friction "
        "(declared by bodies)",
        "its end on the floor at the tilt theta = beta, the centre moving at xdot = -1 m/s, not turning",
        "beta = 0.9 (B < 0 there for mu = 1.5: status painleve)"),
}

_SIZED_INFO = ("n_pendulum", "newton_cradle", "link_chain", "cradle_gap", "cradle", "link_chain_friction")  # listed as <name>_3 (K: FAMILY_SIZES)


def _sized_info(base: str, n: int) -> SceneInfo:
    name = f"{base}_{n}"
    if base == "n_pendulum":
        return SceneInfo(name, tuple((f"theta{i}", "rad", f"angle of link {i} from the downward vertical")
                                     for i in range(1, n + 1)),
                         _pendulum_params(n), "phi = w - sum_i l_i sin theta_i >= 0 (the tip cannot pass the wall)",
                         "beta scales the initial angles: theta_i = -beta, at rest",
                         "every link horizontal, away from the wall, at rest")
    if base == "newton_cradle":
        return SceneInfo(name, tuple((f"x{i}", "m", f"position of ball {i}") for i in range(1, n + 1)),
                         {"m": ("kg", "mass of each ball"), "d": ("m", "ball diameter"), "e": _E},
                         f"{n - 1} contacts c{{i}}{{i+1}}: x_(i+1) - x_i - d >= 0", "",
                         "balls 2..N touching at rest, ball 1 0.2 m away approaching at 1 m/s")
    if base in ("link_chain", "link_chain_friction"):
        fr = base == "link_chain_friction"
        return SceneInfo(name, (("x", "m", "first end of link 1, horizontal"), ("y", "m", "first end of link 1, height"))
                         + tuple((f"theta{i}", "rad", f"absolute angle of link {i} from the horizontal")
                                 for i in range(1, n + 1)),
                         {"m": ("kg", "mass of each link"), "l": ("m", "length of each link"),
                          "g": ("m/s^2", "gravitational acceleration"), "e": _E, **({"mu": _MU} if fr else {})},
                         f"{n + 1} contacts end0..end{n}: the link ends above the floor y = 0"
                         + (", with friction mu" if fr else "") + " (declared by bodies)",
                         "height of the first end y = beta, tilted zigzag, at rest",
                         "y = 0.5, theta_k = 0.3 (-1)^k + 0.05, at rest")
    gap = base == "cradle_gap"
    return SceneInfo(name, tuple((f"theta{i}", "rad", f"angle of string {i} from the downward vertical")
                                 for i in range(1, n + 1)),
                     {"m": ("kg", "mass of each ball"),
                      "r": ("m", "ball radius" + (" (pivots 2r + gap apart)" if gap else " (pivots 2r apart)")),
                      **({"gap": ("m", "distance between neighbouring balls at rest")} if gap else {}),
                      "L": ("m", "string length"), "g": ("m/s^2", "gravitational acceleration"), "e": _E},
                     f"{n - 1} circle contacts c1..c{n - 1}: |C_i - C_(i+1)| - 2 r >= 0 (declared by bodies)",
                     "ball 1 released from theta1 = -beta, the others hanging at rest, "
                     + ("gap apart" if gap else "touching"),
                     "theta1 = -0.3, the others 0, at rest")


def listed_scenes() -> list[str]:
    """Every built-in scene, the sized ones as <name>_3 (`vcirun systems`)."""
    from .data import BUILTIN_SCENE_DATA

    return [f"{nm}_3" if nm in _SIZED_INFO else nm for nm in BUILTIN_SCENE_DATA]


def scene_info(name: str) -> SceneInfo | None:
    """The description of a built-in scene (`n_pendulum_K`, `newton_cradle_K`, `link_chain_K`,
    `cradle_K` for K in the family's range, vcirun.core.limits.FAMILY_SIZES; the bare sized name is its
    default size), or None."""
    if name in BUILTIN_INFO:
        return BUILTIN_INFO[name]
    from .data import scene_args

    args = scene_args(name)
    if args is None or args[0] not in _SIZED_INFO:
        return None
    if not args[1]:
        from .data import scene_data

        return _sized_info(args[0], scene_data(name).n - (2 if args[0].startswith("link_chain") else 0))
    return _sized_info(args[0], args[1][0])


def describe(name: str) -> list[str]:
    """The lines `vcirun systems NAME` prints for a built-in scene (ValueError naming the choices)."""
    from ..core.limits import FAMILY_SIZES
    from .data import scene_data

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


# What each scene's example adds to `vcirun simulate --system NAME` so that it shows the impacts it is
# there for (tests/cli/test_examples.py runs every example and counts them); the default state otherwise.
_EXAMPLE_ARGS = {
    "cart_pendulum": ("--beta 3.2", "3 impacts of the cart on the floor"),
    "double_pendulum": ("", "the second tip hits the wall twice in 5 s"),
    "oscillator_wall": ("", "the mass hits the wall once in 5 s"),
    "damped_oscillator": ("--param d=0.5", "the wall moved from 100 m to 0.5 m: one impact, then damping"),
    "bouncing_ball": ("", "elastic bounces on the floor"),
    "ball_in_box": ("", "bounces off floor, walls and ceiling"),
    "double_pendulum_walls": ("", "the tip bounces between the walls"),
    "rocking_block": ("--h 0.001 --T 3", ("23 corner impacts, then at rest; frictionless, the corners slide: "
                                          "rocking_block_friction rocks")),
    "rocking_block_friction": ("--h 0.001 --T 1", ("Housner's rocking: corner impacts at t = 0.2238, 0.551, "
                                                   "0.7995, 0.9919 s, the corners sticking")),
    "spinning_ball": ("--h 0.001 --T 1", ("slides through the impact at t = 0.4284, rolls from t = 0.7281 "
                                          "(slip -> stick); --beta 10 sticks at the impact")),
    "incline": ("--h 0.01 --T 1", "stops at t = 0.419 s, slides back (slip reversed); --param mu_s=0.4 sticks"),
    "coulomb_oscillator": ("--h 0.01 --T 6", "four slip reversals, sticks at t = 4.97 s"),
    "painleve_rod": ("--h 0.001 --T 0.5", "B < 0 at the start: the run ends with status painleve (exit code 1)"),
    "rimless_wheel": ("--h 0.001 --T 3", "a spoke impact every 0.4 s"),
    "compass_gait": ("--h 0.001 --T 3", "a heel strike every 0.73 s"),
}
_SIZED_EXAMPLE_ARGS = {"link_chain": ("--h 0.001 --T 2", "the link ends hit the floor, then rest"),
                       "link_chain_friction": ("--h 0.001 --T 1", "the link ends hit the floor, stick and slip"),
                       "cradle": ("--h 0.001 --T 2", "ball 1 hits the touching row: Moreau's simultaneous law, "
                                                     "balls 2..N move on together"),
                       "cradle_gap": ("--h 0.001 --T 2", "pairwise impacts down the row, the last ball swings out"),
                       "newton_cradle": ("", "ball 1 hits the touching row"),
                       "n_pendulum": ("", "the tip hits the wall")}


def _family(name: str, bare: bool = False) -> str | None:
    """The sized family of `name` (<family>_K; with bare, the family's own name too), else None."""
    return next((b for b in _SIZED_INFO if (name.startswith(b + "_") and name[len(b) + 1:].isdigit())
                 or (bare and name == b)), None)


def example_command(name: str) -> str:
    """The `vcirun simulate` line `vcirun systems` shows for a built-in scene, with what it shows."""
    sized = _family(name, bare=True)
    args, what = _EXAMPLE_ARGS.get(name) or (_SIZED_EXAMPLE_ARGS.get(sized) if sized else None) or ("", "")
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
