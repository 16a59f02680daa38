"""Declared resets and guards of a constraint: what happens at an impact besides (or instead of)
Newton's law, and where the constraint acts at all.

A constraint of a declaration may carry, next to `phi`:

    reset: {q: [expressions of q], qdot: [expressions of q and qdot]}
        the map of the state just before the impact (q-, qdot-) to the state just after (q+, qdot+),
        e.g. the relabelling of a walker's legs with its angular-momentum transition; velocities are
        <coordinate>_dot. Without `plastic` or `restitution` the map replaces the impact law; with
        them the impact law acts first and the map takes its result.
    plastic: true
        the contact point's normal velocity becomes zero (Newton's law with restitution 0).
    when: "<expression> > <expression>" (or <, >=, <=)
        the guard is armed only where the condition holds: elsewhere the constraint is absent (its
        gap reads GUARD_OFF > 0), e.g. the swing foot of a walker passing the stance foot at
        mid-stride without an impact.

The guarded gap is Piecewise((phi, condition), (GUARD_OFF, True)): the event search sees a sign
change only where the guard is armed. The checks (`check_constraint_hybrid`) run on every system,
declared or built in: the map's dimension and symbols, that the map leaves the configurations of
the armed surface near the declared state admissible, and that the guard is armed somewhere there.
"""
from __future__ import annotations

import ast

import numpy as np
import sympy as sp

from .expressions import ExpressionError, parse_expression

GUARD_OFF = sp.Integer(1)   # the gap of a constraint whose guard is not armed
HYBRID_KEYS = ("reset", "plastic", "when")
_OPS = {ast.Gt: 1, ast.GtE: 1, ast.Lt: -1, ast.LtE: -1}
ADMISSIBLE_TOL = 1e-9       # phi_i(q+) >= -ADMISSIBLE_TOL (1 + |q|) at the mapped surface points
N_SAMPLES = 4000            # configurations sampled around the declared state by the checks


def parse_when(text, symbols: dict, field: str, coordinates=None) -> sp.Expr:
    """The guard's arming function w(q) (armed where w > 0) of `when: "a > b"` (a - b) or "a < b" (b - a)."""
    if isinstance(text, bool) or not isinstance(text, str):
        raise ValueError(f"{field}: must be a condition text such as \"theta_s > 0\" (got {text!r})")
    try:
        tree = ast.parse(text.strip(), mode="eval").body
    except SyntaxError:
        tree = None
    if not (isinstance(tree, ast.Compare) and len(tree.ops) == 1 and type(tree.ops[0]) in _OPS):
        raise ValueError(f"{field}: must be one comparison <expression> > <expression> (or <, >=, <=), "
                         f"e.g. \"theta_s > 0\" (got {text!r})")
    src = text.strip()
    lhs = parse_expression(ast.get_source_segment(src, tree.left), symbols, field)
    rhs = parse_expression(ast.get_source_segment(src, tree.comparators[0]), symbols, field)
    w = (lhs - rhs) * _OPS[type(tree.ops[0])]
    coords = set(symbols.values()) if coordinates is None else set(coordinates)
    if not (w.free_symbols & coords):
        raise ValueError(f"{field}: the condition {text!r} does not depend on the coordinates: the guard "
                         "would be armed everywhere or never; drop `when` or write a condition on q")
    return sp.expand(w) if w.is_polynomial() else w


def parse_hybrid(item: dict, n: int, q_symbols: dict, qd_symbols: dict, field: str) -> dict:
    """{when, reset_q, reset_qd, plastic} of one constraint mapping (absent keys: None / False).
    q_symbols: coordinates and parameters; qd_symbols: the velocities <coordinate>_dot."""
    out = {"when": None, "reset_q": None, "reset_qd": None, "plastic": False}
    if "plastic" in item:
        if not isinstance(item["plastic"], bool):
            raise ValueError(f"{field}.plastic: must be true or false (got {item['plastic']!r})")
        out["plastic"] = item["plastic"]
        if out["plastic"] and "restitution" in item:
            raise ValueError(f"{field}.plastic: plastic: true is restitution 0; give one of plastic or restitution")
    if item.get("when") is not None:
        coords = [q_symbols[k[:-len("_dot")]] for k in qd_symbols]
        out["when"] = parse_when(item["when"], q_symbols, f"{field}.when", coords)
    if item.get("reset") is not None:
        r = item["reset"]
        if not isinstance(r, dict) or set(r) - {"q", "qdot"} or not r:
            raise ValueError(f"{field}.reset: must be a mapping {{q: [{n} expressions of q], qdot: [{n} expressions "
                             f"of q and qdot]}} (got {r!r})")
        if "q" in r:
            out["reset_q"] = _map_list(r["q"], n, q_symbols, f"{field}.reset.q")
        if "qdot" in r:
            out["reset_qd"] = _map_list(r["qdot"], n, q_symbols | qd_symbols, f"{field}.reset.qdot")
    return out


def _map_list(values, n: int, symbols: dict, field: str) -> tuple:
    if not isinstance(values, list) or len(values) != n:
        got = f"{len(values)} entries" if isinstance(values, list) else repr(values)
        raise ValueError(f"{field}: must be a list of {n} expressions, one per coordinate (got {got})")
    out = []
    for i, e in enumerate(values):
        if isinstance(e, bool) or not isinstance(e, (str, int, float)):
            raise ExpressionError(f"{field}[{i}]", type(e).__name__, "must be an expression string or a number")
        out.append(parse_expression(e, symbols, f"{field}[{i}]"))
    return tuple(out)


def guarded(phi: sp.Expr, when: sp.Expr | None) -> sp.Expr:
    """The gap the integrators follow: phi where the guard is armed (w > 0), GUARD_OFF elsewhere."""
    return phi if when is None else sp.Piecewise((phi, sp.StrictGreaterThan(when, 0)), (GUARD_OFF, True))


def reset_map_exprs(system) -> tuple | None:
    """(q+, qdot+) of the system's declared reset map as sympy lists in (q, qdot), None without one
    (plastic alone is the impact law with restitution 0: no map)."""
    mapped = [c for c in system.constraints if c.reset_q is not None or c.reset_qd is not None]
    if not mapped:
        return None
    c = mapped[0]
    q_plus = list(c.reset_q) if c.reset_q is not None else list(system.q)
    qd_plus = list(c.reset_qd) if c.reset_qd is not None else list(system.qd)
    return q_plus, qd_plus


def law_first(system) -> bool:
    """The impact law acts before the declared map (plastic: true, or a restitution given)."""
    mapped = [c for c in system.constraints if c.reset_q is not None or c.reset_qd is not None]
    return bool(mapped) and (mapped[0].plastic or mapped[0].restitution != 1)


def check_constraint_hybrid(system) -> None:
    """Refuse a declared reset or guard that cannot work, naming the field:
    constraints[i].reset: on a system with several constraints (one declared map per system), symbols
    that are not coordinates, parameters (or velocities in qdot);
    constraints[i].when: a guard armed at none of the sampled configurations around the declared
    state;
    constraints[i].reset.q: a map that takes a configuration of the armed surface phi_i = 0 near the
    declared state inside a constraint (some phi_j(q+) < 0)."""
    hyb = [(i, c) for i, c in enumerate(system.constraints) if c.reset_q is not None or c.reset_qd is not None]
    name = system.name
    if len(hyb) > 1 or (hyb and system.m > 1):
        i = hyb[-1][0]
        raise ValueError(f"system {name}: constraints[{i}].reset: a declared reset map needs a system with one "
                         f"constraint (this one has {system.m}); split the model or drop the map")
    allowed_q = set(system.q) | set(system.param_symbols)
    for i, c in hyb:
        for fld, exprs, allowed in (("q", c.reset_q, allowed_q), ("qdot", c.reset_qd, allowed_q | set(system.qd))):
            if exprs is None:
                continue
            if len(exprs) != system.n:
                raise ValueError(f"system {name}: constraints[{i}].reset.{fld}: must be a list of {system.n} "
                                 f"expressions (got {len(exprs)})")
            extra = sorted({str(s) for e in exprs for s in sp.sympify(e).free_symbols} - {str(s) for s in allowed})
            if extra:
                raise ValueError(f"system {name}: constraints[{i}].reset.{fld}: {', '.join(extra)} is neither a "
                                 "coordinate nor a parameter" + (" nor a velocity" if fld == "qdot" else
                                                                 " (velocities only in reset.qdot)"))
    guards = [(i, c) for i, c in enumerate(system.constraints) if c.when is not None]
    if not (hyb or guards):
        return
    rng = np.random.default_rng(0)
    q0 = np.zeros(system.n) if system.default_q0 is None else np.asarray(system.default_q0, float)
    prm = system.param_values()
    Q = q0 + rng.uniform(-1.0, 1.0, size=(N_SAMPLES, system.n)) * np.maximum(1.0, np.abs(q0))
    qs, ps = list(system.q), system.param_symbols
    for i, c in guards:
        w = sp.lambdify((qs, ps), c.when, "numpy")
        vals = np.broadcast_to(np.asarray(w(list(Q.T), list(prm)), float), (N_SAMPLES,))
        if not np.any(vals > 0.0):
            raise ValueError(f"system {name}: constraints[{i}].when: the guard is armed at none of {N_SAMPLES} "
                             f"configurations around the declared state {np.round(q0, 6).tolist()}: it would "
                             "never act; check the condition's sign")
    for i, c in hyb:
        if c.reset_q is None:
            continue
        surf = _armed_surface_points(system, c, Q, prm, rng)
        if not len(surf):
            continue
        qmap = sp.lambdify((qs, ps), list(c.reset_q), "numpy")
        phis = sp.lambdify((qs, ps), [k.phi for k in system.constraints], "numpy")
        for qm in surf:
            qp = np.array(qmap(list(qm), list(prm)), float).ravel()
            vals = np.array(phis(list(qp), list(prm)), float).ravel()
            if np.min(vals) < -ADMISSIBLE_TOL * (1.0 + np.max(np.abs(qp))):
                j = int(np.argmin(vals))
                raise ValueError(f"system {name}: constraints[{i}].reset.q: maps the impact configuration "
                                 f"q- = {np.round(qm, 6).tolist()} (phi = 0, guard armed) to q+ = "
                                 f"{np.round(qp, 6).tolist()}, inside constraint {system.constraints[j].name} "
                                 f"(phi = {vals[j]:.3g} < 0): the map must leave the state admissible")


def _armed_surface_points(system, c, Q, prm, rng, count: int = 40) -> list:
    """Points of phi = 0 with the guard armed, by bisection on segments between sampled configurations
    on either side of the (unguarded) surface."""
    qs, ps = list(system.q), system.param_symbols
    f = sp.lambdify((qs, ps), c.surface, "numpy")
    w = sp.lambdify((qs, ps), c.when, "numpy") if c.when is not None else None
    vals = np.broadcast_to(np.asarray(f(list(Q.T), list(prm)), float), (len(Q),))
    pos, neg = Q[vals > 0], Q[vals < 0]
    out = []
    if not (len(pos) and len(neg)):
        return out
    for _ in range(20 * count):
        a, b = pos[rng.integers(len(pos))], neg[rng.integers(len(neg))]
        for _ in range(60):
            m = 0.5 * (a + b)
            if float(f(list(m), list(prm))) > 0:
                a = m
            else:
                b = m
        if w is None or float(w(list(a), list(prm))) > 0:
            out.append(a)
            if len(out) >= count:
                break
    return out
