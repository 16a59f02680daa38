"""User-declared systems from YAML (or an equivalent mapping).

    name: spring_cart
    coordinates: [x, theta]
    parameters: {m: 1.0, k: 4.0}
    mass_matrix: [["m", "0"], ["0", "m"]]
    potential: "0.5*k*x**2"
    constraint: "x + 1"                # phi(q) >= 0 (one elastic constraint), or several:
    # constraints: ["x + 1", {name: floor, phi: "theta + 1", restitution: 0.9}]   (restitution: a
    #   number in [0, 1] or a parameter name; default 1; Coulomb friction: friction: mu, a number >= 0
    #   or a parameter name, static_friction: mu_s >= mu, and the slip row: slip: [W_t(q), one
    #   expression per coordinate] or tangent_gap: psi(q), whose gradient is the row; see
    #   vcirun.mechanics.friction)
    forcing: ["-0.1*x_dot", "0"]        # optional f(q, qdot, t); velocities are <coord>_dot
    q0: [0.5, 0.0]                       # optional default initial state (with p0 or qdot0)
    qdot0: [0.0, 1.0]
    draw: {points: {mass: [x, 0]}, dots: [mass]}   # optional, what `vcirun animate` draws (vcirun.mechanics.drawing)

Every expression goes through the whitelist parser (never eval/sympify of user text). Files are
parsed like sweep configs (`vcirun.core.yaml_loader.yaml_load`: YAML 1.2 numbers such as 1e-3, duplicate
keys rejected, aliases and sizes capped); names must be ASCII and distinct after NFKC normalisation.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import sympy as sp
import yaml

from ..core.limits import check_count
from ..core.names import (
    check_description,
    check_distinct_names,
    check_identifier,
    check_system_name,
)
from ..core.values import describe
from ..core.yaml_loader import yaml_load
from .expressions import ALLOWED_FUNCTIONS, ExpressionError, parse_expression, parse_matrix
from .friction import FRICTION_KEYS, coefficient
from .hybrid import HYBRID_KEYS, check_constraint_hybrid, parse_hybrid
from .system import Constraint, MechanicalSystem

_KEYS = {"name", "coordinates", "parameters", "mass_matrix", "potential", "constraint", "constraints", "forcing",
         "q0", "p0", "qdot0", "description", "draw"}
_CONSTRAINT_KEYS = {"name", "phi", "restitution", *HYBRID_KEYS, *FRICTION_KEYS}


def load_system_yaml(source, field_prefix: str = "system") -> MechanicalSystem:
    """Build a MechanicalSystem from a YAML file path or a mapping; errors name the field."""
    data = _read_yaml(Path(source), field_prefix) if isinstance(source, (str, Path)) else source
    if not isinstance(data, dict):
        raise ValueError(f"{field_prefix}: expected a mapping with keys {', '.join(sorted(_KEYS))}")
    if "bodies" in data:  # a mechanism by bodies, joints and contact geometry
        from .bodies_yaml import load_bodies
        return load_bodies(data, field_prefix)
    extra = set(data) - _KEYS
    if extra:
        raise ValueError(f"{field_prefix}.{sorted(map(str, extra))[0]}: unknown key (allowed: {', '.join(sorted(_KEYS))})")
    for k in ("coordinates", "mass_matrix", "potential"):
        if k not in data:
            raise ValueError(f"{field_prefix}.{k}: required")
    if ("constraint" in data) == ("constraints" in data):
        raise ValueError(f"{field_prefix}.constraint: give exactly one of constraint (one expression) or "
                         "constraints (a list)")
    coords, params = _declared_names(data, field_prefix)
    q = [sp.Symbol(c) for c in coords]
    qd = [sp.Symbol(f"{c}_dot") for c in coords]
    sym = {s.name: s for s in q + [sp.Symbol(p) for p in params]}
    M = parse_matrix(data["mass_matrix"], sym, f"{field_prefix}.mass_matrix")
    V = parse_expression(_expression(data["potential"], f"{field_prefix}.potential"), sym, f"{field_prefix}.potential")
    constraints = _constraints(data, sym, params, field_prefix, qd)
    forcing = None
    if data.get("forcing") is not None:
        fs = data["forcing"]
        if not isinstance(fs, list) or len(fs) != len(q):
            raise ValueError(f"{field_prefix}.forcing: must be a list of {len(q)} expressions")
        fsym = sym | {s.name: s for s in qd} | {"t": sp.Symbol("t")}
        forcing = sp.Matrix([parse_expression(_expression(e, f"{field_prefix}.forcing[{i}]"), fsym,
                                              f"{field_prefix}.forcing[{i}]") for i, e in enumerate(fs)])
    n = len(q)
    if M.shape != (n, n):
        raise ValueError(f"{field_prefix}.mass_matrix: must be {n}x{n} for {n} coordinates")
    q0 = p0 = None
    if data.get("q0") is not None:
        q0 = _vector(data["q0"], n, f"{field_prefix}.q0")
        if data.get("p0") is not None:
            p0 = _vector(data["p0"], n, f"{field_prefix}.p0")
    system = MechanicalSystem(name=check_system_name(data.get("name", "user_system"), field_prefix), q=q, qd=qd,
                              params=params, M=M, V=V, constraints=constraints, forcing=forcing,
                              description=check_description(data.get("description", ""), field_prefix))
    if data.get("draw") is not None:   # what animations draw (vcirun.mechanics.drawing), not part of the dynamics
        from .drawing import from_yaml

        system.drawing = from_yaml(data["draw"], sym, q, len(constraints), f"{field_prefix}.draw")
    if q0 is not None:
        if p0 is None:
            qdot0 = _vector(data.get("qdot0", [0.0] * n), n, f"{field_prefix}.qdot0")
            system.check_hyperregular(q0)
            p0 = system.mass_matrix(q0) @ qdot0
        system.default_q0, system.default_p0 = q0, p0
        system.check_hyperregular(q0)
        check_constraint_hybrid(system)  # (again: its samples around the declared state)
    return system


def _constraints(data: dict, sym: dict, params: dict, field_prefix: str, qd: list) -> list:
    """The Constraint list of `constraint:` (one elastic) or `constraints:` (items: an expression, or
    {name, phi, restitution, reset, plastic, when, friction, static_friction, slip | tangent_gap};
    restitution a number in [0, 1] or a parameter name; reset, plastic, when:
    vcirun.mechanics.hybrid; friction and the slip row: vcirun.mechanics.friction)."""
    if "constraint" in data:
        fld = f"{field_prefix}.constraint"
        return [Constraint("phi", parse_expression(_expression(data["constraint"], fld), sym, fld))]
    items = data["constraints"]
    if not isinstance(items, list) or not items:
        raise ValueError(f"{field_prefix}.constraints: must be a non-empty list of expressions or "
                         "{name, phi, restitution} mappings")
    check_count("contacts", f"{field_prefix}.constraints", len(items))
    out, names = [], {}
    q = [sym[s.name[:-len("_dot")]] for s in qd]   # the coordinates (velocities are <coordinate>_dot)
    for i, item in enumerate(items):
        fld = f"{field_prefix}.constraints[{i}]"
        if isinstance(item, dict):
            extra = set(item) - _CONSTRAINT_KEYS
            if extra:
                raise ValueError(f"{fld}.{sorted(map(str, extra))[0]}: unknown key (allowed: "
                                 f"{', '.join(sorted(_CONSTRAINT_KEYS))})")
            if "phi" not in item:
                raise ValueError(f"{fld}.phi: required")
            name = item.get("name", f"c{i}")
            names[f"constraints[{i}].name"] = name if isinstance(name, str) else str(name)
            phi = parse_expression(_expression(item["phi"], f"{fld}.phi"), sym, f"{fld}.phi")
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
            hyb = parse_hybrid(item, len(qd), sym, {s.name: s for s in qd}, fld)
            fric = _friction(item, sym, params, fld, q)
        else:
            name, phi, e = f"c{i}", parse_expression(_expression(item, fld), sym, fld), sp.Integer(1)
            hyb, fric = {}, {}
        out.append(Constraint(name, phi, e, **hyb, **fric, field=fld))
    check_distinct_names(names, field_prefix)  # (they name contacts in records)
    return out


def _friction(item: dict, sym: dict, params: dict, fld: str, q: list) -> dict:
    """{friction, static_friction, slip} of one constraint mapping (vcirun.mechanics.friction); the row
    of `tangent_gap: psi` is grad psi."""
    out = {}
    if "friction" in item:
        out["friction"] = coefficient(item["friction"], params, f"{fld}.friction")
    if "static_friction" in item:
        out["static_friction"] = coefficient(item["static_friction"], params, f"{fld}.static_friction",
                                             "static_friction")
    if "slip" in item and "tangent_gap" in item:
        raise ValueError(f"{fld}.tangent_gap: give either slip (the row) or tangent_gap (its gradient is the "
                         "row), not both")
    if "slip" in item:
        row = item["slip"]
        if not isinstance(row, list) or len(row) != len(q):
            got = f"{len(row)} entries" if isinstance(row, list) else describe(row)
            raise ValueError(f"{fld}.slip: must be a list of {len(q)} expressions, one per coordinate "
                             f"({', '.join(map(str, q))}); got {got}")
        out["slip"] = tuple(parse_expression(_expression(e, f"{fld}.slip[{k}]"), sym, f"{fld}.slip[{k}]")
                            for k, e in enumerate(row))
    elif "tangent_gap" in item:
        psi = parse_expression(_expression(item["tangent_gap"], f"{fld}.tangent_gap"), sym, f"{fld}.tangent_gap")
        if not (psi.free_symbols & set(q)):
            raise ValueError(f"{fld}.tangent_gap: {item['tangent_gap']!r} does not depend on the coordinates; its "
                             "gradient (the slip row) would be zero")
        out["slip"] = tuple(sp.diff(psi, s) for s in q)
    return out


MAX_FILE_BYTES = 4_000_000  # a system file is a few kB


def _read_yaml(path: Path, field_prefix: str):
    """A system file's mapping, parsed like a sweep config (YAML 1.2 numbers, no duplicate keys, capped)."""
    if not path.is_file():
        raise ValueError(f"{field_prefix}: file not found: {path}" if not path.exists()
                         else f"{field_prefix}: not a regular file: {path}")
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise ValueError(f"{field_prefix}: {path} is {size:,} bytes; a system file is a few kB "
                             f"(limit {MAX_FILE_BYTES:,})")
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise ValueError(f"{field_prefix}: cannot read {path}: {' '.join(str(e).split())}") from None
    try:
        return yaml_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise ValueError(f"{field_prefix}: invalid YAML in {path}{where}: {problem}") from None


def _declared_names(data: dict, field_prefix: str) -> tuple[list, dict]:
    """(coordinates, parameters) after the name rules: ASCII identifiers, distinct after NFKC (also from
    the velocities <coord>_dot and the time t of forcing expressions), within the size caps."""
    coords = data["coordinates"]
    if not (isinstance(coords, list) and coords):
        raise ValueError(f"{field_prefix}.coordinates: must be a non-empty list of names")
    check_count("coordinates", f"{field_prefix}.coordinates", len(coords))
    params = data.get("parameters") or {}
    if not isinstance(params, dict):
        raise ValueError(f"{field_prefix}.parameters: must be a mapping name -> value")
    check_count("parameters", f"{field_prefix}.parameters", len(params))
    names = {f"coordinates[{i}]": c for i, c in enumerate(coords)}
    for i, c in enumerate(coords):
        if not isinstance(c, str):
            raise ValueError(f"{field_prefix}.coordinates[{i}]: must be a name (got {describe(c)})")
    for k in params:
        if not isinstance(k, str):
            raise ValueError(f"{field_prefix}.parameters: names must be strings (got {describe(k)})")
        names[f"parameters.{k}"] = k
    check_distinct_names({**names, "t (time)": "t",
                                     **{f"velocity of coordinates[{i}]": f"{c}_dot" for i, c in enumerate(coords)}},
                                    field_prefix)
    for fld, name in names.items():
        check_identifier(name, f"{field_prefix}.{fld}")
        if name in ALLOWED_FUNCTIONS:
            raise ValueError(f"{field_prefix}.{fld}: {name!r} is a function name; choose another name")
    for k, v in params.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(float(v)):
            raise ValueError(f"{field_prefix}.parameters.{k}: must be a finite number (got {describe(v)})")
    return list(coords), params


def _expression(value, field: str):
    """An expression as given (text or number); anything else (a list, a mapping, true) is refused here,
    before a str() of it could build a huge string."""
    if isinstance(value, bool):
        raise ExpressionError(field, str(value), f"boolean {str(value).lower()} is not an expression; write 1 or 0")
    if isinstance(value, (str, int, float)):
        return value
    raise ExpressionError(field, type(value).__name__,
                          f"must be an expression string or a number (got {describe(value)})")


def _vector(v, n, field):
    try:
        a = np.asarray(v, dtype=float).ravel()
    except (TypeError, ValueError):
        raise ValueError(f"{field}: must be a list of {n} numbers") from None
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{field}: must be a list of {n} finite numbers")
    return a


__all__ = ["load_system_yaml", "ExpressionError"]
