"""Built-in scenes: the paper's vertical cart-pendulum, a double pendulum against a wall (Figure 1),
a harmonic oscillator against a wall (closed-form oracle), an n-link pendulum (scaling), a
linearly damped oscillator (forced DEL check) and a bouncing ball with drag (impact accumulation)."""
from __future__ import annotations

import functools

import numpy as np
import sympy as sp

from .system import MechanicalSystem


def _merge(defaults: dict, overrides: dict) -> dict:
    unknown = set(overrides) - set(defaults)
    if unknown:
        raise ValueError(f"params.{sorted(unknown)[0]}: unknown parameter (known: {', '.join(defaults)})")
    return {k: float(overrides.get(k, v)) for k, v in defaults.items()}


def cart_pendulum(**overrides) -> MechanicalSystem:
    """Section 5.1: cart of mass m1 on a vertical track, pendulum point mass m2 on a rod of length L.
    q = (y, theta); phi = y >= 0. Initial-condition family Xi(beta) = FL([beta, 0], [0, 3.5 - 0.18 beta])."""
    params = _merge({"m1": 1.0, "m2": 0.2, "L": 2.0, "g": 10.0}, overrides)
    y, th = sp.symbols("y theta")
    m1, m2, L, g = sp.symbols("m1 m2 L g")
    M = sp.Matrix([[m1 + m2, m2 * L * sp.sin(th)], [m2 * L * sp.sin(th), m2 * L**2]])
    V = (m1 + m2) * g * y - m2 * g * L * sp.cos(th)
    return MechanicalSystem(
        name="cart_pendulum", q=[y, th], params=params, M=M, V=V, phi=y,
        ic_map=lambda beta: (np.array([beta, 0.0]), np.array([0.0, 3.5 - 0.18 * beta])),
        description="vertical cart-pendulum with impacts on y = 0 (paper Section 5.1)")


def double_pendulum(**overrides) -> MechanicalSystem:
    """Planar double pendulum, absolute angles from the downward vertical, point masses at the link
    tips; the second tip cannot pass the vertical wall x = w: phi = w - (l1 sin th1 + l2 sin th2).
    The paper gives neither parameters nor the initial state of its Figure 1; these are our choice:
    unit masses and lengths, g = 9.81, wall at w = 1.2, released from rest at th = (-pi/2, -pi/2)
    (both links horizontal, pointing away from the wall). beta scales the initial angles."""
    params = _merge({"m1": 1.0, "m2": 1.0, "l1": 1.0, "l2": 1.0, "g": 9.81, "w": 1.2}, overrides)
    t1, t2 = sp.symbols("theta1 theta2")
    m1, m2, l1, l2, g, w = sp.symbols("m1 m2 l1 l2 g w")
    c = sp.cos(t1 - t2)
    M = sp.Matrix([[(m1 + m2) * l1**2, m2 * l1 * l2 * c], [m2 * l1 * l2 * c, m2 * l2**2]])
    V = -(m1 + m2) * g * l1 * sp.cos(t1) - m2 * g * l2 * sp.cos(t2)
    phi = w - (l1 * sp.sin(t1) + l2 * sp.sin(t2))
    q0 = np.array([-np.pi / 2, -np.pi / 2])
    return MechanicalSystem(
        name="double_pendulum", q=[t1, t2], params=params, M=M, V=V, phi=phi,
        ic_map=lambda beta: (beta * q0 / (np.pi / 2), np.zeros(2)),
        default_q0=q0, default_p0=np.zeros(2),
        description="double pendulum whose second tip cannot pass the wall x = w (paper Figure 1)")


def oscillator_wall(**overrides) -> MechanicalSystem:
    """1-DOF harmonic oscillator m xdd = -k x against a wall at x = -d: phi = x + d.
    Closed-form solution with elastic impacts (see vcirun.reference.oscillator_wall_exact)."""
    params = _merge({"m": 1.0, "k": 1.0, "d": 0.5}, overrides)
    x = sp.Symbol("x")
    m, k, d = sp.symbols("m k d")
    return MechanicalSystem(
        name="oscillator_wall", q=[x], params=params, M=sp.Matrix([[m]]), V=k * x**2 / 2, phi=x + d,
        ic_map=lambda beta: (np.array([beta]), np.array([0.0])),
        default_q0=np.array([1.0]), default_p0=np.array([0.0]),
        description="harmonic oscillator against a wall at x = -d (exact oracle)")


def damped_oscillator(**overrides) -> MechanicalSystem:
    """Linearly damped oscillator m xdd = -k x - c xd (forcing f = -c xd through the discrete
    Lagrange-d'Alembert principle); the wall x = -d is far away unless d is overridden."""
    params = _merge({"m": 1.0, "k": 1.0, "c": 0.1, "d": 100.0}, overrides)
    x, xd = sp.Symbol("x"), sp.Symbol("x_dot")
    m, k, c, d = sp.symbols("m k c d")
    return MechanicalSystem(
        name="damped_oscillator", q=[x], qd=[xd], params=params, M=sp.Matrix([[m]]), V=k * x**2 / 2,
        phi=x + d, forcing=sp.Matrix([-c * xd]),
        default_q0=np.array([1.0]), default_p0=np.array([0.0]),
        description="linearly damped harmonic oscillator (forced DEL)")


def bouncing_ball(**overrides) -> MechanicalSystem:
    """A ball of mass m above the floor y = 0 under gravity with linear air drag f = -c ydot (forced
    DEL) and elastic impacts: phi = y. With c > 0 the bounces shrink until impacts are denser than
    any grid (the accumulation case of the stress suite, vcirun.stress); with c = 0 it bounces
    forever to the same height (closed form, vcirun.stress.ball_exact). beta = drop height."""
    params = _merge({"m": 1.0, "g": 10.0, "c": 0.0}, overrides)
    y, yd = sp.Symbol("y"), sp.Symbol("y_dot")
    m, g, c = sp.symbols("m g c")
    return MechanicalSystem(
        name="bouncing_ball", q=[y], qd=[yd], params=params, M=sp.Matrix([[m]]), V=m * g * y, phi=y,
        forcing=sp.Matrix([-c * yd]),
        ic_map=lambda beta: (np.array([beta]), np.array([0.0])),
        default_q0=np.array([1.0]), default_p0=np.array([0.0]),
        description="ball on the floor y = 0 with linear drag c (forced DEL); impacts accumulate if c > 0")


def n_pendulum(n: int = 2, **overrides) -> MechanicalSystem:
    """n-link planar pendulum (absolute angles, unit point masses at the joints) whose tip cannot
    pass the wall x = w. Used to measure how symbolic and numeric cost grow with the dimension."""
    n = int(n)
    defaults = {"g": 9.81, "w": 0.8 * n} | {f"m{i + 1}": 1.0 for i in range(n)} | {f"l{i + 1}": 1.0 for i in range(n)}
    params = _merge(defaults, overrides)
    th = sp.symbols(f"theta1:{n + 1}")
    ms = sp.symbols(f"m1:{n + 1}")
    ls = sp.symbols(f"l1:{n + 1}")
    g, w = sp.symbols("g w")
    tail = [sum(ms[k] for k in range(i, n)) for i in range(n)]  # mass outboard of joint i
    M = sp.Matrix(n, n, lambda i, j: tail[max(i, j)] * ls[i] * ls[j] * sp.cos(th[i] - th[j]))
    V = -g * sum(tail[i] * ls[i] * sp.cos(th[i]) for i in range(n))
    phi = w - sum(ls[i] * sp.sin(th[i]) for i in range(n))
    q0 = np.full(n, -np.pi / 2)
    return MechanicalSystem(
        name=f"n_pendulum_{n}", q=list(th), params=params, M=M, V=V, phi=phi,
        default_q0=q0, default_p0=np.zeros(n),
        ic_map=lambda beta: (beta * q0 / (np.pi / 2), np.zeros(n)),
        description=f"{n}-link pendulum against the wall x = w")


BUILTIN_SCENES = {
    "cart_pendulum": cart_pendulum,
    "double_pendulum": double_pendulum,
    "oscillator_wall": oscillator_wall,
    "damped_oscillator": damped_oscillator,
    "bouncing_ball": bouncing_ball,
    "n_pendulum": n_pendulum,
}


def get_scene(name: str, **params) -> MechanicalSystem:
    """Built-in scene by name; `n_pendulum_K` selects the K-link pendulum. Scenes without parameter
    overrides are built once per process (parameter values are runtime inputs anyway)."""
    if not params:
        return _scene_cached(name)
    return _build_scene(name, **params)


@functools.lru_cache(maxsize=None)
def _scene_cached(name: str) -> MechanicalSystem:
    return _build_scene(name)


def _build_scene(name: str, **params) -> MechanicalSystem:
    if name.startswith("n_pendulum_") and name[len("n_pendulum_"):].isdigit():
        return n_pendulum(int(name[len("n_pendulum_"):]), **params)
    if name not in BUILTIN_SCENES:
        raise ValueError(f"system: unknown built-in system {name!r} (choose one of {', '.join(BUILTIN_SCENES)}, "
                         "or give a YAML file path)")
    return BUILTIN_SCENES[name](**params)
