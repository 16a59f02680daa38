"""The numeric side of a system, without sympy: what a run needs besides the compiled kernel module.

`SystemData` holds n, the parameter names and default values, an initial-condition map
beta -> (q0, qdot0), the default start (a state, or a beta of the map) and a description. A `MechanicalSystem` (symbolic) and a
built-in scene's numeric data (`vcirun.scenes.scene.Scene.data`) both reduce to it, so a warm start (kernel
module cached, see `vcirun.codegen.kernel_cache.KernelCache.warm_lookup`) resolves a system without importing sympy.
The rules for a run's initial state (`requested_start`, `check_mass_matrix`, `start_tolerance`)
live here once, for the symbolic and the numeric paths alike.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(eq=False)
class SystemData:
    """name, n, params (ordered name -> default value), ic_map (beta -> (q0, qdot0)) or None,
    default_q0 / default_p0 or None, default_beta (the start of a scene without a default state:
    ic_map at this beta) or None, description."""

    name: str
    n: int
    params: dict
    ic_map: object = None
    default_q0: np.ndarray | None = None
    default_p0: np.ndarray | None = None
    description: str = ""
    coordinates: list | None = None   # coordinate names (None: the scene's, vcirun.scenes.registry, for built-in scenes)
    default_beta: float | None = None
    restitution: dict | None = None   # parameter name -> the constraints it is the restitution coefficient of
    ic_map_params: bool = False       # ic_map takes (beta, {parameter: value}): a start that moves with them

    def param_values(self, overrides: dict | None = None) -> np.ndarray:
        """Parameter vector in declaration order, with overrides applied (unknown names rejected, a
        restitution coefficient outside [0, 1] refused)."""
        return param_vector(self.name, self.params, overrides, self.restitution)

    @classmethod
    def of(cls, system) -> "SystemData":
        """The numeric view of a `MechanicalSystem` (or of anything with the same attributes)."""
        return cls(name=system.name, n=system.n, params=dict(system.params), ic_map=system.ic_map,
                   default_q0=system.default_q0, default_p0=system.default_p0, description=system.description,
                   coordinates=[str(c) for c in system.q], default_beta=getattr(system, "default_beta", None),
                   restitution=restitution_parameters(system),
                   ic_map_params=bool(getattr(system, "ic_map_params", False)))


def restitution_parameters(system) -> dict:
    """{parameter name: ["constraint <name>", ...]} of the constraints whose restitution is a parameter."""
    out: dict = {}
    for c in getattr(system, "constraints", None) or ():
        e = getattr(c, "restitution", None)
        if getattr(e, "is_Symbol", False) and str(e) in system.params:
            out.setdefault(str(e), []).append(f"constraint {c.name}")
    return out


def param_vector(name: str, params: dict, overrides: dict | None = None, restitution: dict | None = None) -> np.ndarray:
    """Parameter vector in declaration order, with overrides applied (unknown names rejected);
    shared by SystemData and MechanicalSystem. `restitution` ({parameter: constraints}): parameters
    that are restitution coefficients, refused outside [0, 1] (above 1 every impact adds energy, and
    the impact law finds no post-impact state)."""
    vals = dict(params)
    for k, v in (overrides or {}).items():
        if k not in vals:
            raise ValueError(f"params.{k}: unknown parameter of system {name} (known: {', '.join(vals)})")
        vals[k] = float(v)
    for k, cons in (restitution or {}).items():
        v = float(vals.get(k, 0.0))
        if not 0.0 <= v <= 1.0:
            where = "default value" if k not in (overrides or {}) else "value"
            raise ValueError(f"params.{k}: {where} {v:g} is the restitution coefficient of {', '.join(cons)} of "
                             f"system {name}; it must be in [0, 1] (0: plastic, 1: elastic)")
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


def start_beta(d, beta=None, q0=None, p0=None):
    """The beta a run starts from: `beta` if given, the system's default beta if neither a state nor a
    beta is given and it has no default state, else None (the run starts from a state)."""
    if beta is not None or q0 is not None or p0 is not None or getattr(d, "default_q0", None) is not None:
        return beta
    return getattr(d, "default_beta", None) if d.ic_map is not None else None


def requested_start(d, beta=None, q0=None, p0=None, params=None) -> tuple:
    """The one rule for a run's initial state (vcirun.simulate, MechanicalSystem.initial_state, and so
    the CLI, the sweeps and vcirun.verify): ("state", q0, p0) from explicit values or the system's
    default state, or ("legendre", q0, qdot0) from its initial-condition map at beta (given, or the
    system's `default_beta`; p0 = M(q0) qdot0 is the caller's: compiled or symbolic M).
    d: anything with name, n, ic_map, default_q0, default_p0 (and optionally default_beta, and
    ic_map_params: its ic_map takes the parameter values too, e.g. a block started on its corner, so that a
    start on a contact surface stays on it when a parameter is overridden); params: the run's parameter
    vector in d.params' order (None: the defaults). ValueError names what is missing."""
    beta = start_beta(d, beta, q0, p0)
    if q0 is not None or p0 is not None:
        if q0 is None or p0 is None:
            raise ValueError("initial state: give both q0 and p0 (or beta)")
        kind, q0, p0 = "state", np.asarray(q0, float).ravel(), np.asarray(p0, float).ravel()
    elif beta is not None:
        if d.ic_map is None:
            raise ValueError(f"beta: system {d.name} has no initial-condition map; give q0 and p0")
        if getattr(d, "ic_map_params", False):
            vals = list(d.params.values()) if params is None else [float(v) for v in params]
            qq, qdot = d.ic_map(float(beta), dict(zip(d.params, vals)))
        else:
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


def friction_at(mod, prm, name: str, contacts=None) -> tuple:
    """(mu, mu_s) of every contact at a run's parameter values, from the compiled module's
    sys_friction (zeros without FRICTION), checked: finite, mu >= 0 and mu_s >= mu (a parameter
    override may break what the declaration's defaults satisfied). contacts: names for the message."""
    m = int(getattr(mod, "NCON", 1))
    mu, mu_s = np.zeros(m), np.zeros(m)
    if getattr(mod, "FRICTION", False):
        mod.sys_friction(np.ascontiguousarray(prm, dtype=float), mu, mu_s)
    for i in range(m):
        who = f"contact {contacts[i]!r}" if contacts is not None else f"contact {i}"
        a, b = float(mu[i]), float(mu_s[i])
        if not (np.isfinite(a) and np.isfinite(b)) or a < 0.0 or b < 0.0:
            raise ValueError(f"params: system {name}: {who} has friction mu = {a!r}, mu_s = {b!r} at these "
                             "parameters; give its friction parameters finite values >= 0")
        if b < a:
            raise ValueError(f"params: system {name}: {who} has static friction mu_s = {b!r} < mu = {a!r} at these "
                             "parameters; the static coefficient is at least the kinetic one: give mu_s a value >= mu too")
    return mu, mu_s


def merge_params(defaults: dict, overrides: dict) -> dict:
    unknown = set(overrides) - set(defaults)
    if unknown:
        raise ValueError(f"params.{sorted(unknown)[0]}: unknown parameter (known: {', '.join(defaults)})")
    return {k: float(overrides.get(k, v)) for k, v in defaults.items()}
