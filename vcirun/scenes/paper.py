"""The paper's scenes and the oracle scenes, each declared once (vcirun.scenes.scene.Scene): the
vertical cart-pendulum (Section 5.1), a double pendulum against a wall (Figure 1), a harmonic
oscillator against a wall (closed-form oracle), a linearly damped oscillator (forced DEL check), a
bouncing ball with drag (impact accumulation) and an n-link pendulum (scaling).

No sympy at import: each symbolic builder imports it when it runs."""
from __future__ import annotations

import math

import numpy as np

from .scene import Param, Scene, StudyHooks

_G = Param(9.81, "m/s^2", "gravitational acceleration")


# --- the cart-pendulum ----------------------------------------------------------------------------

def _cart_symbolic(x):
    """Section 5.1: cart of mass m1 on a vertical track, pendulum point mass m2 on a rod of length L.
    q = (y, theta); phi = y >= 0. Initial-condition family Xi(beta) = FL([beta, 0], [0, 3.5 - 0.18 beta])."""
    import sympy as sp

    from .symbolic import system

    (y, th), p = x.q, x.p
    m1, m2, L, g = p.m1, p.m2, p.L, p.g
    M = sp.Matrix([[m1 + m2, m2 * L * sp.sin(th)], [m2 * L * sp.sin(th), m2 * L**2]])
    V = (m1 + m2) * g * y - m2 * g * L * sp.cos(th)
    w = L / 10
    draw = dict(points={"cart": (0, y), "bob": (L * sp.sin(th), y - L * sp.cos(th)), "c1": (-w, y), "c2": (w, y),
                        "c3": (w, y + 2 * w), "c4": (-w, y + 2 * w)},
                polygons=[("c1", "c2", "c3", "c4")], segments=[("cart", "bob")], dots=["bob"],
                lines=[((0, 0), (0, 1))], contacts=["cart"])
    return system(x.d, [y, th], M, V, y, draw=draw)


def _cart_graze(q0, params, phimin, depth):
    q0[0] -= phimin + depth         # phi = y: shift the whole motion down (y is cyclic)
    return q0, params


def _cart_surface(kind, p):
    """On y = 0: moving away, into the floor, at rest (held by gravity), or lifting off tangentially."""
    q = np.array([0.0, {"lift": np.pi}.get(kind, 0.3)])
    qd = {"out": [1.0, 0.5], "in": [-1.0, 0.5], "rest": [0.0, 0.0], "lift": [0.0, 10.0]}[kind]
    return q, qd


CART_PENDULUM = Scene(
    "cart_pendulum",
    description="vertical cart-pendulum with impacts on y = 0 (paper Section 5.1)",
    coordinates=(("y", "m", "height of the cart on its vertical track"),
                 ("theta", "rad", "pendulum angle from the downward vertical")),
    params={"m1": Param(1.0, "kg", "cart mass"), "m2": Param(0.2, "kg", "pendulum point mass"),
            "L": Param(2.0, "m", "rod length"), "g": Param(10.0, "m/s^2", "gravitational acceleration")},
    constraint="phi = y >= 0 (the cart hits the floor)",
    ic_text="Xi(beta) = FL([beta, 0], [0, 3.5 - 0.18 beta]) (paper Section 5.1); beta in [3.2, 5.2] for Figure 4",
    default_text="beta = 3.2: Xi(3.2), the paper's Figure 3 start",
    symbolic=_cart_symbolic,
    # the paper's Figure 3 start
    start=lambda p: dict(ic_map=lambda beta: (np.array([beta, 0.0]), np.array([0.0, 3.5 - 0.18 * beta])),
                         default_beta=3.2),
    example=("--beta 3.2", "3 impacts of the cart on the floor"),
    study=StudyHooks(graze=_cart_graze, surface=_cart_surface, label="cart"))


# --- the double pendulum against a wall -----------------------------------------------------------

def double_pendulum_M_V(x):
    """M and V of the planar double pendulum (absolute angles from the downward vertical, point masses at
    the link tips): shared by double_pendulum and double_pendulum_walls."""
    import sympy as sp

    (t1, t2), p = x.q, x.p
    m1, m2, l1, l2, g = p.m1, p.m2, p.l1, p.l2, p.g
    c = sp.cos(t1 - t2)
    M = sp.Matrix([[(m1 + m2) * l1**2, m2 * l1 * l2 * c], [m2 * l1 * l2 * c, m2 * l2**2]])
    V = -(m1 + m2) * g * l1 * sp.cos(t1) - m2 * g * l2 * sp.cos(t2)
    return M, V


def _double_symbolic(x):
    """Planar double pendulum, absolute angles from the downward vertical, point masses at the link
    tips; the second tip cannot pass the vertical wall x = w: phi = w - (l1 sin th1 + l2 sin th2).
    The paper gives neither parameters nor the initial state of its Figure 1; these are our choice:
    unit masses and lengths, g = 9.81, wall at w = 1.2, released from rest at th = (-pi/2, -pi/2)
    (both links horizontal, pointing away from the wall). beta scales the initial angles."""
    import sympy as sp

    from .symbolic import chain, system

    (t1, t2), p = x.q, x.p
    l1, l2, w = p.l1, p.l2, p.w
    M, V = double_pendulum_M_V(x)
    phi = w - (l1 * sp.sin(t1) + l2 * sp.sin(t2))
    p1, p2 = chain([t1, t2], [l1, l2])
    draw = dict(points={"pivot": (0, 0), "tip1": p1, "tip2": p2}, segments=[("pivot", "tip1"), ("tip1", "tip2")],
                dots=["tip1", "tip2"], pivots=["pivot"], lines=[((w, 0), (-1, 0))], contacts=["tip2"])
    return system(x.d, [t1, t2], M, V, phi, draw=draw)


def _double_start(p):
    q0 = np.array([-np.pi / 2, -np.pi / 2])
    return dict(ic_map=lambda beta: (beta * q0 / (np.pi / 2), np.zeros(2)), default_q0=q0, default_p0=np.zeros(2))


_FAR_WALL = 100.0   # the double pendulum's wall out of reach: its unconstrained motion


def _double_graze(q0, params, phimin, depth):
    params["w"] = _FAR_WALL - phimin - depth   # phi = w - x_tip: move the wall
    return q0, params


def _double_surface(kind, p):
    """The second tip on the wall x = w (l1 = l2 = 1): moving away, into the wall, or lifting off
    tangentially (no 'rest': gravity pulls the tip away from the wall)."""
    th1 = 0.3
    th2 = math.asin(p["w"] - math.sin(th1))    # l1 = l2 = 1: tip exactly at x = w
    q = np.array([th1, th2])
    # normal direction of the tip: d x_tip = cos th1 dth1 + cos th2 dth2
    qd = {"out": [0.0, -1.0], "in": [0.0, 1.0], "lift": [-1.0, math.cos(th1) / math.cos(th2)]}[kind]
    return q, qd


DOUBLE_PENDULUM_COORDINATES = (("theta1", "rad", "angle of link 1 from the downward vertical"),
                               ("theta2", "rad", "angle of link 2 from the downward vertical"))
DOUBLE_PENDULUM_PARAMS = {
    "m1": Param(1.0, "kg", "point mass at the tip of link 1"), "m2": Param(1.0, "kg", "point mass at the tip of link 2"),
    "l1": Param(1.0, "m", "length of link 1"), "l2": Param(1.0, "m", "length of link 2"), "g": _G,
    "w": Param(1.2, "m", "wall position x = w")}

DOUBLE_PENDULUM = Scene(
    "double_pendulum",
    description="double pendulum whose second tip cannot pass the wall x = w (paper Figure 1)",
    coordinates=DOUBLE_PENDULUM_COORDINATES,
    params=DOUBLE_PENDULUM_PARAMS,
    constraint="phi = w - (l1 sin theta1 + l2 sin theta2) >= 0 (the second tip cannot pass the wall)",
    ic_text="beta scales the initial angles: theta = beta (-1, -1), at rest",
    default_text="both links horizontal, away from the wall, at rest (paper Figure 1; our choice)",
    symbolic=_double_symbolic, start=_double_start,
    example=("", "the second tip hits the wall twice in 5 s"),
    study=StudyHooks(free_params={"w": _FAR_WALL}, graze=_double_graze, surface=_double_surface,
                     refused={"rest": "rest has no construction on the double pendulum (gravity pulls its tip off "
                                      "the wall)"}))


# --- the oscillators ------------------------------------------------------------------------------

def _ic_1d(beta):
    return np.array([beta]), np.array([0.0])


def _at_one(p):
    return dict(default_q0=np.array([1.0]), default_p0=np.array([0.0]))


def _oscillator_symbolic(x):
    """1-DOF harmonic oscillator m xdd = -k x against a wall at x = -d: phi = x + d.
    Closed-form solution with elastic impacts (see vcirun.scenes.oracles.oscillator_wall_exact)."""
    import sympy as sp

    from .symbolic import system

    (q,), p = x.q, x.p
    m, k, dd = p.m, p.k, p.d
    draw = dict(points={"mass": (q, 0), "anchor": (2 * dd + 1, 0), "low": (-dd, -0.2), "high": (-dd, 0.2)},
                springs=[("anchor", "mass")], dots=["mass"], pivots=["anchor"], lines=[((-dd, 0), (1, 0))],
                contacts=["mass"])
    return system(x.d, [q], sp.Matrix([[m]]), k * q**2 / 2, q + dd, draw=draw)


OSCILLATOR_WALL = Scene(
    "oscillator_wall",
    description="harmonic oscillator against a wall at x = -d (exact oracle)",
    coordinates=(("x", "m", "position of the mass"),),
    params={"m": Param(1.0, "kg", "mass"), "k": Param(1.0, "N/m", "spring stiffness"),
            "d": Param(0.5, "m", "distance of the wall x = -d")},
    constraint="phi = x + d >= 0 (elastic wall; closed-form solution)", ic_text="x = beta, at rest",
    default_text="x = 1, at rest",
    symbolic=_oscillator_symbolic, start=lambda p: dict(ic_map=_ic_1d, **_at_one(p)),
    example=("", "the mass hits the wall once in 5 s"))


def _damped_symbolic(x):
    """Linearly damped oscillator m xdd = -k x - c xd (forcing f = -c xd through the discrete
    Lagrange-d'Alembert principle); the wall x = -d is far away unless d is overridden."""
    import sympy as sp

    from .symbolic import system

    (q,), (qd,), p = x.q, x.qd, x.p
    m, k, c, dd = p.m, p.k, p.c, p.d
    draw = dict(points={"mass": (q, 0), "anchor": (2, 0), "low": (-1.5, -0.2)}, springs=[("anchor", "mass")],
                dots=["mass"], pivots=["anchor"], lines=[((-dd, 0), (1, 0))], contacts=["mass"])
    return system(x.d, [q], sp.Matrix([[m]]), k * q**2 / 2, q + dd, qd=[qd], forcing=sp.Matrix([-c * qd]), draw=draw)


DAMPED_OSCILLATOR = Scene(
    "damped_oscillator",
    description="linearly damped harmonic oscillator (forced DEL)",
    coordinates=(("x", "m", "position of the mass"),),
    params={"m": Param(1.0, "kg", "mass"), "k": Param(1.0, "N/m", "spring stiffness"),
            "c": Param(0.1, "N s/m", "linear damping coefficient"),
            "d": Param(100.0, "m", "distance of the wall x = -d (far away by default)")},
    constraint="phi = x + d >= 0", default_text="x = 1, at rest",
    symbolic=_damped_symbolic, start=_at_one,
    example=("--param d=0.5", "the wall moved from 100 m to 0.5 m: one impact, then damping"))


# --- the bouncing ball ----------------------------------------------------------------------------

def _ball_symbolic(x):
    """A ball of mass m above the floor y = 0 under gravity with linear air drag f = -c ydot (forced
    DEL) and elastic impacts: phi = y. With c > 0 the bounces shrink until impacts are denser than
    any grid (the accumulation case of the extremes study, vcirun.experiments.studies.contact); with
    c = 0 it bounces forever to the same height (closed form, vcirun.scenes.oracles.ball_exact).
    beta = drop height."""
    import sympy as sp

    from .symbolic import system

    (y,), (yd,), p = x.q, x.qd, x.p
    m, g, c = p.m, p.g, p.c
    draw = dict(points={"ball": (0, y), "low": (-0.5, 0), "high": (0.5, 0)}, dots=["ball"],
                lines=[((0, 0), (0, 1))], contacts=["ball"])
    return system(x.d, [y], sp.Matrix([[m]]), m * g * y, y, qd=[yd], forcing=sp.Matrix([-c * yd]), draw=draw)


def _ball_closed_form(q0, p, T, t):
    """The bounces from rest at height q0[0] (vcirun.scenes.oracles.ball_exact): impact times up to T
    and the height on the times t."""
    from .oracles import ball_exact, ball_position

    y0 = float(q0[0])
    times, speeds = ball_exact(y0, p["g"], p["c"] / p["m"], T)
    times = times[times <= T]
    return times, ball_position(t, y0, p["g"], p["c"] / p["m"], times, speeds)


BOUNCING_BALL = Scene(
    "bouncing_ball",
    description="ball on the floor y = 0 with linear drag c (forced DEL); impacts accumulate if c > 0",
    coordinates=(("y", "m", "height of the ball above the floor"),),
    params={"m": Param(1.0, "kg", "mass"), "g": Param(10.0, "m/s^2", "gravitational acceleration"),
            "c": Param(0.0, "N s/m", "linear air drag (impacts accumulate if c > 0)")},
    constraint="phi = y >= 0 (elastic floor)", ic_text="drop height y = beta, at rest", default_text="y = 1, at rest",
    symbolic=_ball_symbolic, start=lambda p: dict(ic_map=_ic_1d, **_at_one(p)),
    example=("", "elastic bounces on the floor"),
    study=StudyHooks(closed_form=_ball_closed_form, label="ball"))


# --- the n-link pendulum --------------------------------------------------------------------------

def _n_pendulum_params(n):
    return ({"g": _G, "w": Param(0.8 * n, "m", "wall position: the tip cannot pass x = w")}
            | {f"m{i}": Param(1.0, "kg", f"point mass at the tip of link {i}") for i in range(1, n + 1)}
            | {f"l{i}": Param(1.0, "m", f"length of link {i}") for i in range(1, n + 1)})


def _n_pendulum_symbolic(x):
    """n-link planar pendulum (absolute angles, unit point masses at the joints) whose tip cannot
    pass the wall x = w. Used to measure how symbolic and numeric cost grow with the dimension."""
    import sympy as sp

    from .symbolic import chain, system

    n, th, p = x.k, x.q, x.p
    ms = [p[f"m{i}"] for i in range(1, n + 1)]
    ls = [p[f"l{i}"] for i in range(1, n + 1)]
    g, w = p.g, p.w
    tail = [sum(ms[k] for k in range(i, n)) for i in range(n)]  # mass outboard of joint i
    M = sp.Matrix(n, n, lambda i, j: tail[max(i, j)] * ls[i] * ls[j] * sp.cos(th[i] - th[j]))
    V = -g * sum(tail[i] * ls[i] * sp.cos(th[i]) for i in range(n))
    phi = w - sum(ls[i] * sp.sin(th[i]) for i in range(n))
    pts = chain(th, ls)
    names = ["pivot"] + [f"joint{i + 1}" for i in range(n)]
    draw = dict(points={"pivot": (0, 0), **{names[i + 1]: pts[i] for i in range(n)}},
                segments=list(zip(names[:-1], names[1:])), dots=names[1:], pivots=["pivot"],
                lines=[((w, 0), (-1, 0))], contacts=[names[-1]])
    return system(x.d, list(th), M, V, phi, draw=draw)


def _n_pendulum_start(p, n):
    q0 = np.full(n, -np.pi / 2)
    return dict(default_q0=q0, default_p0=np.zeros(n), ic_map=lambda beta: (beta * q0 / (np.pi / 2), np.zeros(n)))


N_PENDULUM = Scene(
    "n_pendulum", size=2,
    description=lambda n: f"{n}-link pendulum against the wall x = w",
    coordinates=lambda n: tuple((f"theta{i}", "rad", f"angle of link {i} from the downward vertical")
                                for i in range(1, n + 1)),
    params=_n_pendulum_params,
    constraint="phi = w - sum_i l_i sin theta_i >= 0 (the tip cannot pass the wall)",
    ic_text="beta scales the initial angles: theta_i = -beta, at rest",
    default_text="every link horizontal, away from the wall, at rest",
    symbolic=_n_pendulum_symbolic, start=_n_pendulum_start,
    example=("", "the tip hits the wall"))

SCENES = (CART_PENDULUM, DOUBLE_PENDULUM, OSCILLATOR_WALL, DAMPED_OSCILLATOR, BOUNCING_BALL, N_PENDULUM)
