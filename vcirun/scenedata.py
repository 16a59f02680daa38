"""The numeric side of a system, without sympy: sizes, parameter defaults, initial-condition maps.

`SystemData` is what `vcirun.simulate` needs besides the compiled kernel module: n, the parameter
names and default values, the scene's initial-condition map beta -> (q0, qdot0), a default state,
a description. The built-in scenes' numeric parts live here (`vcirun.mechanics.scenes` builds the
symbolic M, V, phi on top of them), so that a warm start (kernel module cached, see
`vcirun.codegen.build.warm_lookup`) resolves a scene by name without importing sympy.

This module is outside `vcirun.mechanics` on purpose: that package imports sympy on import.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(eq=False)
class SystemData:
    """name, n, params (ordered name -> default value), ic_map (beta -> (q0, qdot0)) or None,
    default_q0 / default_p0 or None, description."""

    name: str
    n: int
    params: dict
    ic_map: object = None
    default_q0: np.ndarray | None = None
    default_p0: np.ndarray | None = None
    description: str = ""
    coordinates: list | None = None   # coordinate names (None: vcirun.catalog's for built-in scenes)

    def param_values(self, overrides: dict | None = None) -> np.ndarray:
        """Parameter vector in declaration order, with overrides applied (unknown names rejected)."""
        return param_vector(self.name, self.params, overrides)

    @classmethod
    def of(cls, system) -> "SystemData":
        """The numeric view of a `MechanicalSystem` (or of anything with the same attributes)."""
        return cls(name=system.name, n=system.n, params=dict(system.params), ic_map=system.ic_map,
                   default_q0=system.default_q0, default_p0=system.default_p0, description=system.description,
                   coordinates=[str(c) for c in system.q])


def param_vector(name: str, params: dict, overrides: dict | None = None) -> np.ndarray:
    """Parameter vector in declaration order, with overrides applied (unknown names rejected);
    shared by SystemData and MechanicalSystem."""
    vals = dict(params)
    for k, v in (overrides or {}).items():
        if k not in vals:
            raise ValueError(f"params.{k}: unknown parameter of system {name} (known: {', '.join(vals)})")
        vals[k] = float(v)
    return np.array([float(vals[k]) for k in params], dtype=float)


def check_mass_matrix(name: str, q, Mq) -> None:
    """The Legendre transform must be invertible: M(q) finite, symmetric positive definite (the
    hyperregularity check of MechanicalSystem and of the warm path)."""
    q = np.asarray(q, float).tolist()
    if not np.all(np.isfinite(Mq)):
        raise ValueError(f"system {name}: mass_matrix is not finite at q0={q}")
    S = 0.5 * (Mq + Mq.T)
    try:
        np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        raise ValueError(f"system {name}: mass_matrix is not positive definite at q0={q} "
                         f"(eigenvalues {np.linalg.eigvalsh(S)}); the Lagrangian must be hyperregular") from None


def requested_start(d, beta=None, q0=None, p0=None) -> tuple:
    """The one rule for a run's initial state (vcirun.simulate and MechanicalSystem.initial_state):
    ("state", q0, p0) from explicit values or the system's default, or ("legendre", q0, qdot0) from
    its initial-condition map at beta (p0 = M(q0) qdot0 is the caller's: compiled or symbolic M).
    d: anything with name, n, ic_map, default_q0, default_p0. ValueError names what is missing."""
    if q0 is not None or p0 is not None:
        if q0 is None or p0 is None:
            raise ValueError("initial state: give both q0 and p0 (or beta)")
        kind, q0, p0 = "state", np.asarray(q0, float).ravel(), np.asarray(p0, float).ravel()
    elif beta is not None:
        if d.ic_map is None:
            raise ValueError(f"beta: system {d.name} has no initial-condition map; give q0 and p0")
        qq, qdot = d.ic_map(float(beta))
        kind, q0, p0 = "legendre", np.array(qq, dtype=float), np.array(qdot, dtype=float)
    elif d.default_q0 is not None:
        kind, q0, p0 = "state", np.array(d.default_q0, float), np.array(d.default_p0, float)
    else:
        raise ValueError(f"initial state: system {d.name} needs q0 and p0 (or beta)")
    if q0.shape != (d.n,) or p0.shape != (d.n,):
        raise ValueError(f"initial state: q0 and p0 must have length {d.n}")
    return kind, q0, p0


def start_tolerance(q0, grad_phi) -> float:
    """How far below 0 a start's phi(q0) may lie and still count as on the surface: round-off of
    phi near q0, 64 eps (1 + |q0| |grad phi|) (a state built on phi = 0 in floating point). Used by
    vcirun.simulate and vcirun.reference alike."""
    return 64 * np.finfo(float).eps * (1.0 + float(np.max(np.abs(q0))) * float(np.max(np.abs(grad_phi))))


def merge_params(defaults: dict, overrides: dict) -> dict:
    unknown = set(overrides) - set(defaults)
    if unknown:
        raise ValueError(f"params.{sorted(unknown)[0]}: unknown parameter (known: {', '.join(defaults)})")
    return {k: float(overrides.get(k, v)) for k, v in defaults.items()}


# --- the built-in scenes' numeric parts (symbolic parts: vcirun.mechanics.scenes) ------------------

def _cart_ic(beta):
    return np.array([beta, 0.0]), np.array([0.0, 3.5 - 0.18 * beta])


def cart_pendulum(**overrides) -> SystemData:
    return SystemData(
        name="cart_pendulum", n=2, params=merge_params({"m1": 1.0, "m2": 0.2, "L": 2.0, "g": 10.0}, overrides),
        ic_map=_cart_ic, description="vertical cart-pendulum with impacts on y = 0 (paper Section 5.1)")


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
        name="ball_in_box", n=2, params=prm, default_q0=q0, default_p0=prm["m"] * v0,
        description="point mass in the box 0 <= x <= width, 0 <= y <= height under gravity; four walls "
                    "(floor, ceiling, left, right) with restitution e (issue 17)")


def newton_cradle(n: int = 3, **overrides) -> SystemData:
    n = int(n)
    prm = merge_params({"m": 1.0, "d": 0.1, "e": 1.0}, overrides)
    q0 = np.array([-0.2] + [prm["d"] * k for k in range(1, n)])  # balls 2..N touching, ball 1 away
    p0 = np.zeros(n)
    p0[0] = prm["m"] * 1.0                                       # ... approaching at speed 1
    return SystemData(
        name=f"newton_cradle_{n}", n=n, params=prm, default_q0=q0, default_p0=p0,
        description=f"{n} equal balls of diameter d on a line, contacts between neighbours with restitution e; "
                    "balls 2..N touching, ball 1 approaching at speed 1 (issue 17)")


def double_pendulum_walls(**overrides) -> SystemData:
    # hanging straight down and kicked (the double pendulum's horizontal start would put the tip at
    # x = -2, inside the left wall x = -w): Xi(beta) = (0, 0), beta (2, 1); the default beta = 3 gives
    # three impacts in [0, 3], on the right, left and right walls
    return SystemData(
        name="double_pendulum_walls", n=2,
        params=merge_params({"m1": 1.0, "m2": 1.0, "l1": 1.0, "l2": 1.0, "g": 9.81, "w": 1.2, "e": 1.0}, overrides),
        ic_map=lambda beta: (np.zeros(2), beta * np.array([2.0, 1.0])),
        default_q0=np.zeros(2), default_p0=np.array([6.0, 3.0]),
        description="double pendulum whose second tip stays between the walls x = -w and x = w (restitution e)")


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
}
_SIZED = ("n_pendulum", "newton_cradle")  # scenes named <name>_K with K the size


def scene_args(name: str):
    """(factory name, positional args) of a built-in scene name (`n_pendulum_K` -> ('n_pendulum', (K,))),
    or None if `name` is not a built-in scene."""
    if not isinstance(name, str):
        return None
    for base in _SIZED:
        if name.startswith(base + "_") and name[len(base) + 1:].isdigit():
            return base, (int(name[len(base) + 1:]),)
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
