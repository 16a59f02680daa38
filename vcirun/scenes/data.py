"""The built-in scenes' numeric parts, without sympy: parameter defaults, initial-condition maps,
default states and descriptions (`vcirun.scenes.declarations` adds the symbolic M, V, phi and
forcing on top of them). A warm start resolves a scene by name from here alone.
"""
from __future__ import annotations

import math

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
                    "corners are the contacts, restitution e, frictionless: it slides as it bounces and settles "
                    "(the block rocking on its corners without sliding: rocking_block_friction) (declared by bodies)")


def link_chain_start(n: int, height: float):
    """(q0, qdot0) of a chain of n links: a tilted zigzag (theta_k = 0.3 (-1)^k + 0.05: the ends at
    different heights), its first end at (0, height), at rest (link_chain and link_chain_friction)."""
    angles = [0.3 * (-1) ** k + 0.05 for k in range(1, int(n) + 1)]
    return np.array([0.0, float(height)] + angles), np.zeros(int(n) + 2)


def link_chain(n: int = 5, **overrides) -> SystemData:
    n = int(n)
    prm = merge_params({"m": 0.2, "l": 0.3, "g": 9.81, "e": 0.3}, overrides)
    q0 = link_chain_start(n, 0.5)[0]
    return SystemData(
        name=f"link_chain_{n}", n=n + 2, params=prm, restitution=_EVERY_CONTACT, default_q0=q0,
        default_p0=np.zeros(n + 2),
        ic_map=lambda beta: link_chain_start(n, beta),
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


# --- the scenes with Coulomb friction -----------------------------------------------------------------
# Their physics (M, V, the contacts with their friction) is vcirun.scenes.friction's, whose constructors
# take their start states from the functions below (one definition, without sympy); the parameter
# defaults here are the constructors' (tests/scenes/test_friction_scenes.py holds them equal).

def block_corner(theta, a, b, side):
    """The corner (side b/2, -a/2) of a block at angle theta, relative to its centre."""
    cx, cy = side * b / 2.0, -a / 2.0
    return cx * math.cos(theta) - cy * math.sin(theta), cx * math.sin(theta) + cy * math.cos(theta)


def spinning_ball_start(w0, h=1.0, v0=0.0):
    """(q0, qdot0) of the spinning ball: centre at height h, horizontal velocity v0, spin w0."""
    return np.array([0.0, float(h), 0.0]), np.array([float(v0), 0.0, float(w0)])


def incline_start(theta, v0=0.0):
    """(q0, qdot0) of the block on the incline: at the origin (on the slope), velocity v0 up the slope."""
    return np.zeros(2), float(v0) * np.array([math.cos(theta), math.sin(theta)])


def coulomb_oscillator_start(x0=1.0, v0=0.0):
    """(q0, qdot0) of the Coulomb oscillator: on the floor at x0 with velocity v0."""
    return np.array([float(x0), 0.0]), np.array([float(v0), 0.0])


def rocking_block_friction_start(theta0, a, b):
    """(q0, qdot0) of the block at rest on one corner at the tilt theta0 (the left corner for theta0 >
    0), that corner exactly on the floor y = 0."""
    rx, ry = block_corner(theta0, a, b, -1 if theta0 > 0 else 1)
    return np.array([-rx, -ry, float(theta0)]), np.zeros(3)


def painleve_rod_start(theta0, xdot0, thetadot0, l):
    """(q0, qdot0) of the rod with its end A on the floor at the tilt theta0: centre velocity (xdot0,
    l cos(theta0) thetadot0) (A's normal velocity zero), angular velocity thetadot0."""
    return (np.array([0.0, l * math.sin(theta0), float(theta0)]),
            np.array([float(xdot0), l * math.cos(theta0) * thetadot0, float(thetadot0)]))


def spinning_ball(**overrides) -> SystemData:
    prm = merge_params({"m": 1.0, "R": 0.1, "mu": 0.2, "g": 9.81}, overrides)
    return SystemData(
        name="spinning_ball", n=3, params=prm, ic_map=lambda beta: spinning_ball_start(beta), default_beta=50.0,
        description="ball (radius R, inertia 2/5 m R^2) dropped from centre height 1 with spin beta onto the "
                    "floor y = 0: plastic impact with Coulomb friction mu (Capobianco et al. 2021, 10.1); the "
                    "contact sticks at impact iff (2/7) R beta <= mu v_n, else it slides, then rolls "
                    "(declared by bodies)")


def incline(**overrides) -> SystemData:
    prm = merge_params({"m": 1.0, "g": 9.81, "theta": 0.3, "mu": 0.2, "mu_s": 0.2}, overrides)
    return SystemData(
        name="incline", n=2, params=prm, ic_map=lambda beta, p: incline_start(p["theta"], beta), ic_map_params=True,
        default_beta=2.0,
        description="block (a point mass) on an incline of angle theta, launched uphill at beta m/s with "
                    "Coulomb friction mu: it stops, then sticks if tan theta <= mu_s, else slides back")


def coulomb_oscillator(**overrides) -> SystemData:
    prm = merge_params({"m": 1.0, "k": 10.0, "g": 9.81, "mu": 0.1, "mu_s": 0.1}, overrides)
    return SystemData(
        name="coulomb_oscillator", n=2, params=prm, ic_map=lambda beta: coulomb_oscillator_start(beta),
        default_beta=1.0,
        description="block on the floor y = 0 on a spring k to x = 0, released at x = beta: Coulomb friction "
                    "mu takes 2 mu m g / k of amplitude each half period pi sqrt(m/k); it sticks at the first "
                    "turning point with |x| <= mu_s m g / k")


def rocking_block_friction(**overrides) -> SystemData:
    prm = merge_params({"m": 1.0, "a": 1.0, "b": 0.4, "g": 9.81, "mu": 0.8, "mu_s": 0.8}, overrides)
    return SystemData(
        name="rocking_block_friction", n=3, params=prm, ic_map_params=True, default_beta=0.1,
        ic_map=lambda beta, p: rocking_block_friction_start(beta, p["a"], p["b"]),
        description="Housner's rocking block (width b, height a) released at rest on a corner at the tilt "
                    "beta: it rocks on its corners without sliding (friction mu, mu_s), plastic corner impacts, "
                    "the angular velocity times 1 - 3/2 sin^2 alpha (alpha = atan(b/a)) at each (declared by "
                    "bodies)")


def painleve_rod(**overrides) -> SystemData:
    prm = merge_params({"m": 1.0, "l": 1.0, "g": 9.81, "mu": 1.5, "mu_s": 1.5}, overrides)
    return SystemData(
        name="painleve_rod", n=3, params=prm, ic_map=lambda beta, p: painleve_rod_start(beta, -1.0, 0.0, p["l"]),
        ic_map_params=True, default_beta=0.9,
        description="uniform rod (length 2 l) sliding on one end at 1 m/s from the tilt beta, friction mu: "
                    "where B = 1 + 3 cos^2 theta - 3 mu sin theta cos theta <= 0 (mu > 4/3) the held contact "
                    "has no unique force (Painleve's paradox) and the run ends with status painleve "
                    "(declared by bodies)")


def link_chain_friction(n: int = 5, **overrides) -> SystemData:
    n = int(n)
    prm = merge_params({"m": 0.2, "l": 0.3, "g": 9.81, "e": 0.3, "mu": 0.5}, overrides)
    q0, qdot0 = link_chain_start(n, 0.5)
    return SystemData(
        name=f"link_chain_friction_{n}", n=n + 2, params=prm, restitution=_EVERY_CONTACT, default_q0=q0,
        default_p0=qdot0, ic_map=lambda beta: link_chain_start(n, beta),
        description=f"the chain of {n} links of link_chain_{n} with Coulomb friction mu at the link ends: it lands, "
                    "its ends stick and slip, it does not skate (declared by bodies)")


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
    "rocking_block_friction": rocking_block_friction,
    "spinning_ball": spinning_ball,
    "incline": incline,
    "coulomb_oscillator": coulomb_oscillator,
    "painleve_rod": painleve_rod,
    "link_chain_friction": link_chain_friction,
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
