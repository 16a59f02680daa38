"""The built-in scenes' numeric parts, without sympy: parameter defaults, initial-condition maps,
default states and descriptions (`vcirun.scenes.declarations` adds the symbolic M, V, phi and
forcing on top of them). A warm start resolves a scene by name from here alone.
"""
from __future__ import annotations

import numpy as np

from ..core.limits import sized_family
from ..core.system_data import SystemData, merge_params

_EVERY_CONTACT = {"e": ["every contact"]}   # the scenes whose contacts share the restitution parameter e


def _cart_ic(beta):
    return np.array([beta, 0.0]), np.array([0.0, 3.5 - 0.18 * beta])


def cart_pendulum(**overrides) -> SystemData:
    return SystemData(
        name="cart_pendulum", n=2, params=merge_params({"m1": 1.0, "m2": 0.2, "L": 2.0, "g": 10.0}, overrides),
        ic_map=_cart_ic, default_beta=3.2,   # the paper's Figure 3 start
        description="vertical cart-pendulum with impacts on y = 0 (paper Section 5.1)")


def double_pendulum(**overrides) -> SystemData:
    q0 = np.array([-np.pi / 2, -np.pi / 2])
    return SystemData(
        name="double_pendulum", n=2,
        params=merge_params({"m1": 1.0, "m2": 1.0, "l1": 1.0, "l2": 1.0, "g": 9.81, "w": 1.2}, overrides),
        ic_map=lambda beta: (beta * q0 / (np.pi / 2), np.zeros(2)),
        default_q0=q0, default_p0=np.zeros(2),
        description="double pendulum whose second tip cannot pass the wall x = w (paper Figure 1)")


def _ic_1d(beta):
    return np.array([beta]), np.array([0.0])


def oscillator_wall(**overrides) -> SystemData:
    return SystemData(
        name="oscillator_wall", n=1, params=merge_params({"m": 1.0, "k": 1.0, "d": 0.5}, overrides),
        ic_map=_ic_1d, default_q0=np.array([1.0]), default_p0=np.array([0.0]),
        description="harmonic oscillator against a wall at x = -d (exact oracle)")


def damped_oscillator(**overrides) -> SystemData:
    return SystemData(
        name="damped_oscillator", n=1, params=merge_params({"m": 1.0, "k": 1.0, "c": 0.1, "d": 100.0}, overrides),
        default_q0=np.array([1.0]), default_p0=np.array([0.0]),
        description="linearly damped harmonic oscillator (forced DEL)")


def bouncing_ball(**overrides) -> SystemData:
    return SystemData(
        name="bouncing_ball", n=1, params=merge_params({"m": 1.0, "g": 10.0, "c": 0.0}, overrides),
        ic_map=_ic_1d, default_q0=np.array([1.0]), default_p0=np.array([0.0]),
        description="ball on the floor y = 0 with linear drag c (forced DEL); impacts accumulate if c > 0")


def n_pendulum(n: int = 2, **overrides) -> SystemData:
    n = int(n)
    defaults = {"g": 9.81, "w": 0.8 * n} | {f"m{i + 1}": 1.0 for i in range(n)} | {f"l{i + 1}": 1.0 for i in range(n)}
    q0 = np.full(n, -np.pi / 2)
    return SystemData(
        name=f"n_pendulum_{n}", n=n, params=merge_params(defaults, overrides),
        default_q0=q0, default_p0=np.zeros(n),
        ic_map=lambda beta: (beta * q0 / (np.pi / 2), np.zeros(n)),
        description=f"{n}-link pendulum against the wall x = w")


def ball_in_box(**overrides) -> SystemData:
    q0, v0 = np.array([0.3, 0.6]), np.array([0.7, 0.0])
    prm = merge_params({"m": 1.0, "g": 9.81, "width": 1.0, "height": 1.0, "e": 1.0}, overrides)
    return SystemData(
        name="ball_in_box", n=2, params=prm, restitution=_EVERY_CONTACT, default_q0=q0, default_p0=prm["m"] * v0,
        description="point mass in the box 0 <= x <= width, 0 <= y <= height under gravity; four walls "
                    "(floor, ceiling, left, right) with restitution e")


def newton_cradle(n: int = 3, **overrides) -> SystemData:
    n = int(n)
    prm = merge_params({"m": 1.0, "d": 0.1, "e": 1.0}, overrides)
    q0 = np.array([-0.2] + [prm["d"] * k for k in range(1, n)])  # balls 2..N touching, ball 1 away
    p0 = np.zeros(n)
    p0[0] = prm["m"] * 1.0                                       # ... approaching at speed 1
    return SystemData(
        name=f"newton_cradle_{n}", n=n, params=prm, restitution=_EVERY_CONTACT, default_q0=q0, default_p0=p0,
        description=f"{n} equal balls of diameter d on a line, contacts between neighbours with restitution e; "
                    "balls 2..N touching, ball 1 approaching at speed 1")


def double_pendulum_walls(**overrides) -> SystemData:
    # hanging straight down and kicked (the double pendulum's horizontal start would put the tip at
    # x = -2, inside the left wall x = -w): Xi(beta) = (0, 0), beta (2, 1); the default beta = 3 gives
    # three impacts in [0, 3], on the right, left and right walls
    return SystemData(
        name="double_pendulum_walls", n=2, restitution=_EVERY_CONTACT,
        params=merge_params({"m1": 1.0, "m2": 1.0, "l1": 1.0, "l2": 1.0, "g": 9.81, "w": 1.2, "e": 1.0}, overrides),
        ic_map=lambda beta: (np.zeros(2), beta * np.array([2.0, 1.0])),
        default_q0=np.zeros(2), default_p0=np.array([6.0, 3.0]),
        description="double pendulum whose second tip stays between the walls x = -w and x = w (restitution e)")


def rocking_block(**overrides) -> SystemData:
    prm = merge_params({"m": 1.0, "a": 1.0, "b": 0.4, "g": 9.81, "e": 0.5}, overrides)
    return SystemData(
        name="rocking_block", n=3, params=prm, restitution=_EVERY_CONTACT, default_q0=np.array([0.0, 0.7, 0.2]),
        default_p0=np.zeros(3),
        ic_map=lambda beta: (np.array([0.0, beta, 0.2]), np.zeros(3)),
        description="rectangular block (width b, height a) dropped tilted on the floor y = 0; its two lower "
                    "corners are the contacts, restitution e (declared by bodies)")


def link_chain(n: int = 5, **overrides) -> SystemData:
    n = int(n)
    prm = merge_params({"m": 0.2, "l": 0.3, "g": 9.81, "e": 0.3}, overrides)
    angles = [0.3 * (-1) ** k + 0.05 for k in range(1, n + 1)]  # a tilted zigzag: the ends at different heights
    q0 = np.array([0.0, 0.5] + angles)
    return SystemData(
        name=f"link_chain_{n}", n=n + 2, params=prm, restitution=_EVERY_CONTACT, default_q0=q0,
        default_p0=np.zeros(n + 2),
        ic_map=lambda beta: (np.array([0.0, beta] + angles), np.zeros(n + 2)),
        description=f"chain of {n} links (revolute joints, the first on a free joint) falling on the floor "
                    "y = 0; the link ends are the contacts, restitution e (declared by bodies)")


def cradle(n: int = 5, **overrides) -> SystemData:
    n = int(n)
    prm = merge_params({"m": 0.1, "r": 0.05, "L": 1.0, "g": 9.81, "e": 1.0}, overrides)
    q0 = np.zeros(n)
    q0[0] = -0.3
    return SystemData(
        name=f"cradle_{n}", n=n, params=prm, restitution=_EVERY_CONTACT, default_q0=q0, default_p0=np.zeros(n),
        ic_map=lambda beta: (np.array([-beta] + [0.0] * (n - 1)), np.zeros(n)),
        description=f"Newton's cradle of {n} touching balls (radius r, strings of length L, pivots 2r apart), "
                    "circle contacts between neighbours, restitution e; ball 1 released from theta1 = -0.3: "
                    "Moreau's simultaneous impact law on the touching row (balls 2..N move on together; the "
                    f"swing-out of a real cradle: cradle_gap_{n}) (declared by bodies)")


def cradle_gap(n: int = 5, **overrides) -> SystemData:
    n = int(n)
    prm = merge_params({"m": 0.1, "r": 0.05, "gap": 0.001, "L": 1.0, "g": 9.81, "e": 1.0}, overrides)
    q0 = np.zeros(n)
    q0[0] = -0.3
    return SystemData(
        name=f"cradle_gap_{n}", n=n, params=prm, default_q0=q0, default_p0=np.zeros(n),
        ic_map=lambda beta: (np.array([-beta] + [0.0] * (n - 1)), np.zeros(n)),
        description=f"Newton's cradle of {n} balls hung with small gaps (pivots 2r + gap apart), restitution e; "
                    "ball 1 released from theta1 = -0.3: the impacts run down the row one pair at a time and "
                    "the last ball swings out (declared by bodies)")


def rimless_wheel(**overrides) -> SystemData:
    """A point mass m on massless spokes of length l, 2 alpha apart, rolling down a slope gamma. q =
    theta, the stance spoke's angle from the slope normal (forward positive); Xi(beta): just after an
    impact (theta = -alpha) with angular velocity beta; the default state is the closed-form gait's
    (vcirun.scenes.oracles.rimless_wheel_fixed_point)."""
    prm = merge_params({"m": 1.0, "l": 1.0, "alpha": float(np.pi / 8), "gamma": 0.1, "g": 9.81}, overrides)
    m, l, a, gam, g = (prm[k] for k in ("m", "l", "alpha", "gamma", "g"))
    c2 = np.cos(2 * a) ** 2
    w = np.sqrt(c2 * 4 * g / l * np.sin(a) * np.sin(gam) / (1 - c2))
    return SystemData(
        name="rimless_wheel", n=1, params=prm,
        ic_map=lambda beta: (np.array([-a]), np.array([float(beta)])),
        default_q0=np.array([-a]), default_p0=np.array([m * l * l * w]),
        description="rimless wheel on a slope: plastic spoke impacts as a declared reset (closed-form stride map)")


def _compass_M(q, prm):
    m, mh, a, b = prm["m"], prm["mH"], prm["a"], prm["b"]
    l = a + b
    c = -m * l * b * np.cos(q[0] - q[1])
    return np.array([[(mh + m) * l * l + m * a * a, c], [c, m * b * b]])


# the period-one gait at the default slope (3 degrees), on the section just after heel strike
_COMPASS_Q0 = (-0.271016, 0.271016)
_COMPASS_QDOT0 = (1.092571, 0.377537)


def compass_gait(**overrides) -> SystemData:
    """The compass gait of Goswami, Thuilot and Espiau (1998): legs with point masses m at a from the
    foot (b from the hip), a hip mass mH, on a slope gamma. q = (theta_s, theta_ns), the stance and
    swing legs' angles from the slope normal (forward positive); heel strike (the swing foot reaches
    the slope ahead of the stance foot) is a plastic impact and the exchange of the legs, a declared
    reset. Xi(beta): the default state with its velocities scaled by beta."""
    prm = merge_params({"m": 5.0, "mH": 10.0, "a": 0.5, "b": 0.5, "gamma": float(np.deg2rad(3.0)), "g": 9.81},
                       overrides)
    q0, v0 = np.array(_COMPASS_Q0), np.array(_COMPASS_QDOT0)
    return SystemData(
        name="compass_gait", n=2, params=prm,
        ic_map=lambda beta: (q0.copy(), float(beta) * v0),
        default_q0=q0, default_p0=_compass_M(q0, prm) @ v0,
        description="compass-gait walker (Goswami et al.) on a slope gamma: heel strike as a declared reset")


BUILTIN_SCENE_DATA = {
    "cart_pendulum": cart_pendulum,
    "double_pendulum": double_pendulum,
    "oscillator_wall": oscillator_wall,
    "damped_oscillator": damped_oscillator,
    "bouncing_ball": bouncing_ball,
    "n_pendulum": n_pendulum,
    "ball_in_box": ball_in_box,
    "newton_cradle": newton_cradle,
    "double_pendulum_walls": double_pendulum_walls,
    "rocking_block": rocking_block,
    "link_chain": link_chain,
    "cradle": cradle,
    "cradle_gap": cradle_gap,
    "rimless_wheel": rimless_wheel,
    "compass_gait": compass_gait,
}
def scene_args(name: str):
    """(factory name, positional args) of a built-in scene name (`n_pendulum_K` -> ('n_pendulum', (K,))),
    or None if `name` is not a built-in scene. A family's K outside its range (the caps table,
    vcirun.core.limits.FAMILY_SIZES) is a ValueError naming the system, before anything is built."""
    if not isinstance(name, str):
        return None
    sized = sized_family(name)
    if sized is not None:
        return sized[0], (sized[1],)
    if name in BUILTIN_SCENE_DATA:
        return name, ()
    return None


def unknown_scene_error(name) -> ValueError:
    return ValueError(f"system: unknown built-in system {name!r} (choose one of {', '.join(BUILTIN_SCENE_DATA)}, "
                      "or give a YAML file path)")


def scene_data(name: str, **params) -> SystemData:
    """The numeric part of a built-in scene by name (no sympy)."""
    args = scene_args(name)
    if args is None:
        raise unknown_scene_error(name)
    return BUILTIN_SCENE_DATA[args[0]](*args[1], **params)
