"""User-declared systems from YAML (or an equivalent mapping).

    name: spring_cart
    coordinates: [x, theta]
    parameters: {m: 1.0, k: 4.0}
    mass_matrix: [["m", "0"], ["0", "m"]]
    potential: "0.5*k*x**2"
    constraint: "x + 1"                # phi(q) >= 0 (one elastic constraint), or several:
    # constraints: ["x + 1", {name: floor, phi: "theta + 1", restitution: 0.9}]   (restitution: a
    #   number in [0, 1] or a parameter name; default 1)
    forcing: ["-0.1*x_dot", "0"]        # optional f(q, qdot, t); velocities are <coord>_dot
    q0: [0.5, 0.0]                       # optional default initial state (with p0 or qdot0)
    qdot0: [0.0, 1.0]

Every expression goes through the whitelist parser (never eval/sympify of user text).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import sympy as sp
import yaml

from .expressions import ExpressionError, parse_expression, parse_matrix
from .system import Constraint, MechanicalSystem

_KEYS = {"name", "coordinates", "parameters", "mass_matrix", "potential", "constraint", "constraints", "forcing",
         "q0", "p0", "qdot0", "description"}
_CONSTRAINT_KEYS = {"name", "phi", "restitution"}


def load_system_yaml(source, field_prefix: str = "system") -> MechanicalSystem:
    """Build a MechanicalSystem from a YAML file path or a mapping; errors name the field."""
    if isinstance(source, (str, Path)):
        path = Path(source)
        if not path.is_file():
            raise ValueError(f"{field_prefix}: file not found: {path}")
        try:
            data = yaml.safe_load(path.read_text())
        except yaml.YAMLError as e:
            raise ValueError(f"{field_prefix}: invalid YAML in {path}: {str(e).splitlines()[0]}") from None
    else:
        data = source
    if not isinstance(data, dict):
        raise ValueError(f"{field_prefix}: expected a mapping with keys {', '.join(sorted(_KEYS))}")
    extra = set(data) - _KEYS
    if extra:
        raise ValueError(f"{field_prefix}.{sorted(extra)[0]}: unknown key (allowed: {', '.join(sorted(_KEYS))})")
    for k in ("coordinates", "mass_matrix", "potential"):
        if k not in data:
            raise ValueError(f"{field_prefix}.{k}: required")
    if ("constraint" in data) == ("constraints" in data):
        raise ValueError(f"{field_prefix}.constraint: give exactly one of constraint (one expression) or "
                         "constraints (a list)")
    coords = data["coordinates"]
    if not (isinstance(coords, list) and coords and all(isinstance(c, str) and c.isidentifier() for c in coords)):
        raise ValueError(f"{field_prefix}.coordinates: must be a non-empty list of names")
    params = data.get("parameters") or {}
    if not isinstance(params, dict):
        raise ValueError(f"{field_prefix}.parameters: must be a mapping name -> value")
    for k, v in params.items():
        if not isinstance(k, str) or not k.isidentifier() or k.startswith("_"):
            raise ValueError(f"{field_prefix}.parameters.{k}: not a valid name")
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"{field_prefix}.parameters.{k}: must be a number (got {v!r})")
    names = list(coords) + list(params)
    if len(set(names)) != len(names) or {"t"} & set(names):
        raise ValueError(f"{field_prefix}: coordinate and parameter names must be distinct and not 't'")
    q = [sp.Symbol(c) for c in coords]
    qd = [sp.Symbol(f"{c}_dot") for c in coords]
    sym = {s.name: s for s in q + [sp.Symbol(p) for p in params]}
    M = parse_matrix(data["mass_matrix"], sym, f"{field_prefix}.mass_matrix")
    V = parse_expression(str(data["potential"]), sym, f"{field_prefix}.potential")
    constraints = _constraints(data, sym, params, field_prefix)
    forcing = None
    if data.get("forcing") is not None:
        fs = data["forcing"]
        if not isinstance(fs, list) or len(fs) != len(q):
            raise ValueError(f"{field_prefix}.forcing: must be a list of {len(q)} expressions")
        fsym = sym | {s.name: s for s in qd} | {"t": sp.Symbol("t")}
        forcing = sp.Matrix([parse_expression(str(e), fsym, f"{field_prefix}.forcing[{i}]") for i, e in enumerate(fs)])
    n = len(q)
    if M.shape != (n, n):
        raise ValueError(f"{field_prefix}.mass_matrix: must be {n}x{n} for {n} coordinates")
    q0 = p0 = None
    if data.get("q0") is not None:
        q0 = _vector(data["q0"], n, f"{field_prefix}.q0")
        if data.get("p0") is not None:
            p0 = _vector(data["p0"], n, f"{field_prefix}.p0")
    system = MechanicalSystem(name=str(data.get("name", "user_system")), q=q, qd=qd, params=params, M=M, V=V,
                              constraints=constraints, forcing=forcing, description=str(data.get("description", "")))
    if q0 is not None:
        if p0 is None:
            qdot0 = _vector(data.get("qdot0", [0.0] * n), n, f"{field_prefix}.qdot0")
            system.check_hyperregular(q0)
            p0 = system.mass_matrix(q0) @ qdot0
        system.default_q0, system.default_p0 = q0, p0
        system.check_hyperregular(q0)
    return system


def _constraints(data: dict, sym: dict, params: dict, field_prefix: str) -> list:
    """The Constraint list of `constraint:` (one elastic) or `constraints:` (items: an expression, or
    {name, phi, restitution}; restitution a number in [0, 1] or a parameter name)."""
    if "constraint" in data:
        return [Constraint("phi", parse_expression(str(data["constraint"]), sym, f"{field_prefix}.constraint"))]
    items = data["constraints"]
    if not isinstance(items, list) or not items:
        raise ValueError(f"{field_prefix}.constraints: must be a non-empty list of expressions or "
                         "{name, phi, restitution} mappings")
    out = []
    for i, item in enumerate(items):
        fld = f"{field_prefix}.constraints[{i}]"
        if isinstance(item, dict):
            extra = set(item) - _CONSTRAINT_KEYS
            if extra:
                raise ValueError(f"{fld}.{sorted(map(str, extra))[0]}: unknown key (allowed: name, phi, restitution)")
            if "phi" not in item:
                raise ValueError(f"{fld}.phi: required")
            name = str(item.get("name", f"c{i}"))
            phi = parse_expression(str(item["phi"]), sym, f"{fld}.phi")
            e = item.get("restitution", 1.0)
            if isinstance(e, str):
                if e not in params:
                    raise ValueError(f"{fld}.restitution: {e!r} is not a parameter (declared: "
                                     f"{', '.join(params) or 'none'}); give a number in [0, 1] or a parameter name")
                e = sp.Symbol(e)
            elif isinstance(e, bool) or not isinstance(e, (int, float)) or not 0.0 <= float(e) <= 1.0:
                raise ValueError(f"{fld}.restitution: must be a number in [0, 1] or a parameter name (got {e!r})")
            else:
                e = sp.Float(float(e)) if float(e) != 1.0 else sp.Integer(1)
        else:
            name, phi, e = f"c{i}", parse_expression(str(item), sym, fld), sp.Integer(1)
        out.append(Constraint(name, phi, e))
    return out


def _vector(v, n, field):
    try:
        a = np.asarray(v, dtype=float).ravel()
    except (TypeError, ValueError):
        raise ValueError(f"{field}: must be a list of {n} numbers") from None
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{field}: must be a list of {n} finite numbers")
    return a


__all__ = ["load_system_yaml", "ExpressionError"]
