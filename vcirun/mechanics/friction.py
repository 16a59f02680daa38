"""Coulomb friction declared on a contact: its coefficients and its slip row.

A constraint phi_i(q) >= 0 may carry, next to its restitution:

    friction: mu          the kinetic (sliding) coefficient, a number >= 0 or a parameter name
                          (default 0: frictionless)
    static_friction: mu_s the static coefficient, mu_s >= mu (default: mu)
    slip: W_t(q)          the tangential slip row, n expressions in q and the parameters: the slip
                          velocity of the contact is v_t = W_t(q) qdot, and the friction force opposes
                          it (in the hand-written form also `tangent_gap: psi(q)`, whose gradient is the
                          row; the bodies form derives the row from the contact geometry and the
                          bodies' spin, vcirun.mechanics.bodies)

A contact with friction must be able to slide: a slip row is required, and a row that is zero at
every sampled configuration, or parallel to grad phi_i there (then v_t is a multiple of the normal
velocity, zero while the contact is held), is refused with the field named. A slip row on a
frictionless contact is accepted and unused.

Numbers enter as sympy numbers and parameters as symbols (a parameter change recompiles nothing);
the values of parameters are checked where they are known: the declared defaults here, overrides
by `check_friction_values` (vcirun.core.system_data).
"""
from __future__ import annotations

import math

import numpy as np
import sympy as sp

FRICTION_KEYS = ("friction", "static_friction", "slip", "tangent_gap")   # of a hand-written constraint
N_SAMPLES = 64          # configurations at which a slip row is tested for zero / parallel to grad phi
ZERO_TOL = 1e-12        # |W_t| <= ZERO_TOL (1 + |grad phi|): zero at that configuration
PARALLEL_TOL = 1e-9     # |W_t - (W_t.g / g.g) g| <= PARALLEL_TOL |W_t|: parallel to g = grad phi there


def coefficient(value, params: dict, fld: str, what: str = "friction") -> sp.Expr:
    """A friction coefficient as a sympy number or parameter symbol, checked: a finite number >= 0, or
    the name of a declared parameter whose default value is >= 0."""
    if isinstance(value, sp.Symbol):
        value = value.name
    if isinstance(value, str):
        if value not in params:
            raise ValueError(f"{fld}: {value!r} is not a parameter (declared: {', '.join(params) or 'none'}); "
                             f"give {what} as a number >= 0 or a parameter name")
        v = float(params[value])
        if not (math.isfinite(v) and v >= 0.0):
            raise ValueError(f"{fld}: parameter {value} = {v!r}; a friction coefficient is a finite number >= 0 "
                             f"(fix parameters.{value})")
        return sp.Symbol(value)
    if isinstance(value, sp.Basic) and value.is_number:
        value = float(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{fld}: must be a number >= 0 or a parameter name (got {value!r})")
    v = float(value)
    if math.isnan(v):
        raise ValueError(f"{fld}: is NaN; give a finite number >= 0 (0: frictionless) or a parameter name")
    if math.isinf(v):
        raise ValueError(f"{fld}: is infinite; give a finite number >= 0 (a contact that never slides is a "
                         "large finite mu_s, or a joint)")
    if v < 0.0:
        raise ValueError(f"{fld}: {v!r} < 0; a friction coefficient is >= 0 (0: frictionless)")
    return sp.Integer(0) if v == 0.0 else sp.Integer(int(v)) if v == int(v) else sp.Float(v)


def has_friction(c) -> bool:
    """The contact has a friction coefficient (kinetic or static) that is not literally zero: a number
    > 0 or a parameter."""
    return sp.sympify(c.friction) != 0 or (c.static_friction is not None and sp.sympify(c.static_friction) != 0)


def static_coefficient(c) -> sp.Expr:
    """mu_s of a constraint: static_friction, or mu where it is not given."""
    return sp.sympify(c.friction) if c.static_friction is None else sp.sympify(c.static_friction)


def _value(expr, params: dict) -> float:
    return float(sp.sympify(expr).subs({sp.Symbol(k): float(v) for k, v in params.items()}))


def where(system, i: int, c) -> str:
    """The field a constraint's friction errors name: its declaration field, or the system and index."""
    return c.field or f"system {system.name}: constraints[{i}] ({c.name})"


def check_constraint_friction(system) -> None:
    """Refuse friction declarations that cannot work, naming the field (see the module docstring):
    coefficients (numbers >= 0 or parameters with values >= 0), static_friction >= friction at the
    declared parameters, a slip row of n expressions in q and the parameters, friction without a slip
    row, a slip row that is zero or parallel to grad phi at every sampled configuration."""
    n, allowed = system.n, set(system.q) | set(system.param_symbols)
    sampled = []
    for i, c in enumerate(system.constraints):
        f = where(system, i, c)
        mu = coefficient(c.friction, system.params, f"{f}.friction")
        mus = mu if c.static_friction is None else coefficient(c.static_friction, system.params,
                                                                f"{f}.static_friction", "static_friction")
        if c.static_friction is not None:
            vm, vs = _value(mu, system.params), _value(mus, system.params)
            if vs < vm:
                raise ValueError(f"{f}.static_friction: mu_s = {vs:g} < friction mu = {vm:g}; the static "
                                 "coefficient is at least the kinetic one (omit static_friction: it defaults "
                                 "to friction)")
        if c.slip is not None:
            if len(c.slip) != n:
                raise ValueError(f"{f}.slip: must be a list of {n} expressions, one per coordinate "
                                 f"({', '.join(map(str, system.q))}); got {len(c.slip)}")
            extra = sorted({str(s) for e in c.slip for s in sp.sympify(e).free_symbols if s not in allowed})
            if extra:
                raise ValueError(f"{f}.slip: {', '.join(extra[:3])} is neither a coordinate "
                                 f"({', '.join(map(str, system.q))}) nor a parameter "
                                 f"({', '.join(system.params) or 'none'}); the slip row is W_t(q), its slip "
                                 "velocity W_t(q) qdot")
        if not has_friction(c):
            continue
        if c.slip is None:
            raise ValueError(f"{f}.friction: friction on a contact without a slip row; give slip: [W_t(q), one "
                             "expression per coordinate] (slip velocity W_t(q) qdot) or tangent_gap: psi(q) "
                             "(the row grad psi); the bodies form derives the row from the geometry")
        if all(sp.sympify(e) == 0 for e in c.slip):
            raise ValueError(f"{f}.slip: the slip row is zero: the contact cannot slide, so friction on it does "
                             "nothing; give the tangential row or drop friction")
        sampled.append((i, c))
    if sampled:
        _check_slidable(system, sampled)


def _check_slidable(system, items) -> None:
    """A slip row that is zero or parallel to grad phi at every sampled configuration cannot slide."""
    rng = np.random.default_rng(0)
    n = system.n
    q0 = np.zeros(n) if system.default_q0 is None else np.asarray(system.default_q0, float)
    Q = q0 + rng.uniform(-1.5, 1.5, size=(N_SAMPLES, n)) * np.maximum(1.0, np.abs(q0))
    prm = list(system.param_values())
    qs, ps = list(system.q), system.param_symbols
    for i, c in items:
        W = sp.lambdify((qs, ps), list(c.slip), "numpy")
        g = sp.lambdify((qs, ps), [sp.diff(c.surface, s) for s in qs], "numpy")
        seen = zero = parallel = 0
        with np.errstate(all="ignore"):
            for q in Q:
                w = np.asarray(W(list(q), prm), float).ravel()
                gv = np.asarray(g(list(q), prm), float).ravel()
                if not (np.all(np.isfinite(w)) and np.all(np.isfinite(gv))) or not np.any(gv):
                    continue
                seen += 1
                nw = float(np.linalg.norm(w))
                if nw <= ZERO_TOL * (1.0 + float(np.linalg.norm(gv))):
                    zero += 1
                    continue
                perp = w - (w @ gv) / (gv @ gv) * gv
                if np.linalg.norm(perp) <= PARALLEL_TOL * nw:
                    parallel += 1
        if not seen:
            continue   # no configuration where both are defined: nothing to decide here
        f = where(system, i, c)
        if zero == seen:
            raise ValueError(f"{f}.slip: the slip row is zero at all {seen} sampled configurations: the contact "
                             "cannot slide, so friction on it does nothing; give the tangential row or drop "
                             "friction")
        if zero + parallel == seen:
            raise ValueError(f"{f}.slip: the slip row is parallel to grad phi at all {seen} sampled "
                             "configurations: its slip velocity is a multiple of the normal velocity, zero while "
                             "the contact is held, so the contact cannot slide; give the tangential row (a "
                             "direction along the contact surface) or drop friction")
