"""Planar mechanisms declared by bodies, joints and contact geometry; the result is an ordinary
`MechanicalSystem` (docs/bodies.md).

    Body(name, mass, inertia=0, com=(0, 0), radius=None, outline=None)   rigid body, frame attached to
        its joint; outline: corners in its frame, drawn by animations (vcirun.mechanics.drawing)
    Joint(kind, body, parent="ground", at=(0, 0), coordinate=, coordinates=, axis=, absolute=False)
        revolute : one angle; the body's frame origin sits at `at` (parent frame); its angle is the
                   parent's plus the coordinate, or the coordinate itself with absolute=True
        prismatic: one length along `axis` (parent frame, normalised); the body keeps the parent's angle
        free    : three coordinates (x, y, theta), x and y along the parent's axes from `at`
    PointContact(name, body, point=(0, 0), radius=0, line_point=(0, 0), normal=(0, 1), restitution=1,
                 friction=0, static_friction=None)
        the point (or the rim of the circle of that radius around it) of a body stays on the side of
        the ground line through line_point where `normal` points: phi = n.(P - line_point)/|n| - radius
    CircleContact(name, bodies=(A, B), centers=(com, com), radii=(rA, rB), restitution=1, friction=0,
                  static_friction=None)
        two circles stay apart: phi = |C_A - C_B| - r_A - r_B
    friction (mu) and static_friction (mu_s >= mu; default mu) of a contact: Coulomb friction
        (vcirun.mechanics.friction), its slip row from the geometry and the bodies' spin (`slip_row`)
    Spring(a, b, k, length=0, point_a=, point_b=), Damper(a, b, c, point_a=, point_b=): between two
        points (body or "ground"): V += k (l - length)^2 / 2; forcing -c (dl/dt) grad l.
    gravity: g (acceleration g along -y) or a vector (gx, gy): V = -sum m_b g . com_b.

Every scalar is a number, a sympy expression or a text parsed by the whitelist parser against the
parameters and the coordinates (`planar_system(..., params=)`); errors name the field.

Derivation: the project's own planar kinematics, not sympy.physics.mechanics. A point of body b is a
sum of phasors c_k exp(i a_k) (c_k complex, in the coordinates of prismatic and free joints; a_k the
absolute angle of a frame, linear in the angle coordinates). Its velocity Jacobian is again such a
sum, and an entry of M = sum_b m_b Re(J_i conj J_j) + I_b a_i a_j comes out directly as
sum_kl Re(c_k conj c_l) cos(a_k - a_l) - Im(c_k conj c_l) sin(a_k - a_l), collected by angle
difference: the compact form of a hand derivation (cos(theta1 - theta2) for the double pendulum)
without any trigsimp. sympy.physics.mechanics (LagrangesMethod on the same chains) gives the mass
matrix as products of sines and cosines of each angle (e.g. l1 l2 m2 (sin th1 sin th2 + cos th1
cos th2)). Measured with sympy.count_ops (bench/bodies_derivation.py) on a 5-link chain with a free
base: M has 259 operations here, 459 from sympy.physics.mechanics and still 319 after trigsimp of
every entry, whose derivation took 26-32 s against 2 s here (3 links: 113 against 179 and 137).
Smaller expressions are smaller kernels, so this derivation is used.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import sympy as sp

from .expressions import parse_expression
from .friction import coefficient
from .system import Constraint, MechanicalSystem

GROUND = "ground"
JOINT_KINDS = {"revolute": 1, "prismatic": 1, "free": 3}


@dataclass
class Body:
    name: str
    mass: object
    inertia: object = 0
    com: tuple = (0, 0)
    radius: object = None
    field: str = ""  # where it was declared (error messages); set by the YAML reader
    outline: tuple | None = None   # corners in the body frame, for animations (vcirun.mechanics.drawing)


@dataclass
class Joint:
    kind: str
    body: str
    parent: str = GROUND
    at: tuple = (0, 0)
    coordinate: str | None = None
    coordinates: tuple | None = None
    axis: tuple = (1, 0)
    absolute: bool = False
    field: str = ""


@dataclass
class PointContact:
    name: str
    body: str
    point: tuple = (0, 0)
    radius: object = 0
    line_point: tuple = (0, 0)
    normal: tuple = (0, 1)
    restitution: object = 1
    friction: object = 0
    static_friction: object = None
    field: str = ""


@dataclass
class CircleContact:
    name: str
    bodies: tuple
    centers: tuple | None = None
    radii: tuple | None = None
    restitution: object = 1
    friction: object = 0
    static_friction: object = None
    field: str = ""


@dataclass
class Spring:
    a: str
    b: str
    k: object
    length: object = 0
    point_a: tuple = (0, 0)
    point_b: tuple = (0, 0)
    field: str = ""


@dataclass
class Damper:
    a: str
    b: str
    c: object
    point_a: tuple = (0, 0)
    point_b: tuple = (0, 0)
    field: str = ""


# --- phasor sums: sum_k (re_k + i im_k) exp(i ang_k), a point of the plane in the coordinates ---------

def _add(terms: dict, re, im, ang) -> None:
    r0, i0 = terms.get(ang, (sp.Integer(0), sp.Integer(0)))
    terms[ang] = (r0 + re, i0 + im)


def _shift(origin: dict, re, im, ang) -> dict:
    out = dict(origin)
    _add(out, sp.sympify(re), sp.sympify(im), ang)
    return out


def _xy(terms: dict) -> tuple:
    """(x, y) of a phasor sum."""
    x = sum((re * sp.cos(a) - im * sp.sin(a) for a, (re, im) in terms.items()), sp.Integer(0))
    y = sum((re * sp.sin(a) + im * sp.cos(a) for a, (re, im) in terms.items()), sp.Integer(0))
    return x, y


def _jacobian(terms: dict, q: list) -> list:
    """d/dq_j of a phasor sum, one phasor sum per coordinate (the same angles)."""
    out = []
    for s in q:
        col = {}
        for a, (re, im) in terms.items():
            da = sp.diff(a, s)
            dre, dim = sp.diff(re, s) - im * da, sp.diff(im, s) + re * da
            if dre != 0 or dim != 0:
                col[a] = (dre, dim)
        out.append(col)
    return out


def _inner(A: dict, B: dict, acc: dict) -> None:
    """Accumulate Re(A conj B) into acc = {angle difference d: [cos coefficient, sin coefficient]}."""
    for a, (ar, ai) in A.items():
        for b, (br, bi) in B.items():
            cre, cim = ar * br + ai * bi, ai * br - ar * bi  # c = a conj(b); Re(c e^{id}) = cre cos d - cim sin d
            d = sp.expand(a - b)
            if d == 0:
                acc.setdefault(sp.Integer(0), [sp.Integer(0), sp.Integer(0)])[0] += cre
                continue
            if d.could_extract_minus_sign():
                d, cim = -d, -cim
            ent = acc.setdefault(d, [sp.Integer(0), sp.Integer(0)])
            ent[0] += cre
            ent[1] -= cim


def _collect(acc: dict) -> sp.Expr:
    out = sp.Integer(0)
    for d, (c, s) in sorted(acc.items(), key=lambda kv: sp.default_sort_key(kv[0])):
        c, s = sp.factor(sp.expand(c)), sp.factor(sp.expand(s))
        out += c if d == 0 else c * sp.cos(d) + s * sp.sin(d)
    return out


# --- the builder -------------------------------------------------------------------------------------

class _Scope:
    """Parses the scalars of a declaration against the parameters and coordinates."""

    def __init__(self, symbols: dict, q: list, params: dict):
        self.symbols = symbols
        self.q = q
        self.param_values = {sp.Symbol(k): float(v) for k, v in params.items()}

    def scalar(self, value, fld: str) -> sp.Expr:
        if isinstance(value, sp.Basic):
            return value
        if isinstance(value, bool) or value is None:
            raise ValueError(f"{fld}: must be a number or an expression (got {value!r})")
        return parse_expression(value if isinstance(value, (str, int, float)) else str(value), self.symbols, fld)

    def vector(self, value, fld: str) -> tuple:
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            raise ValueError(f"{fld}: must be a pair [x, y] (got {value!r})")
        return self.scalar(value[0], f"{fld}[0]"), self.scalar(value[1], f"{fld}[1]")


def _fld(obj, default: str) -> str:
    return obj.field or default


def planar_system(name: str, bodies, joints, contacts, *, params=None, gravity=0, springs=(), dampers=(),
                  q0=None, qdot0=None, p0=None, description: str = "", field_prefix: str = "system",
                  ic_map=None) -> MechanicalSystem:
    """The MechanicalSystem of a planar mechanism (see the module docstring). q0/qdot0 (or p0) are
    the default start (lists in coordinate order, or mappings coordinate -> value, others 0); every
    contact's phi is checked to be >= 0 there (a contact starting inside names itself)."""
    params = dict(params or {})
    bodies, joints, contacts = list(bodies), list(joints), list(contacts)
    P = f"{field_prefix}."
    if not bodies:
        raise ValueError(f"{P}bodies: declare at least one body")
    if not contacts:
        raise ValueError(f"{P}contacts: declare at least one contact (a point against a line, or two circles)")
    byname = {}
    for i, b in enumerate(bodies):
        if not isinstance(b, Body):
            raise ValueError(f"{P}bodies[{i}]: must be a Body")
        if b.name == GROUND or b.name in byname:
            raise ValueError(f"{_fld(b, f'{P}bodies[{i}]')}.name: {b.name!r} is "
                             + ("reserved (the fixed frame)" if b.name == GROUND else "declared twice"))
        byname[b.name] = b
    # coordinates, in joint order, named by the joints
    coords, joint_of = [], {}
    for j, jt in enumerate(joints):
        f = _fld(jt, f"{P}joints[{j}]")
        if not isinstance(jt, Joint):
            raise ValueError(f"{P}joints[{j}]: must be a Joint")
        if jt.kind not in JOINT_KINDS:
            raise ValueError(f"{f}.type: {jt.kind!r} is not a joint type (choose {', '.join(JOINT_KINDS)})")
        if jt.body not in byname:
            import difflib

            near = difflib.get_close_matches(str(jt.body), list(byname), n=1)
            raise ValueError(f"{f}.body: {jt.body!r} is not a declared body"
                             + (f"; did you mean {near[0]!r}?" if near else f" ({', '.join(byname)})"))
        if jt.body in joint_of:
            raise ValueError(f"{f}.body: body {jt.body!r} already has a joint ({joint_of[jt.body].field or 'above'})")
        if jt.parent != GROUND and jt.parent not in byname:
            import difflib

            near = difflib.get_close_matches(str(jt.parent), list(byname) + [GROUND], n=1)
            raise ValueError(f"{f}.parent: {jt.parent!r} is neither {GROUND!r} nor a declared body"
                             + (f"; did you mean {near[0]!r}?" if near else f" ({', '.join(byname)})"))
        names = (list(jt.coordinates) if jt.coordinates is not None else
                 [jt.coordinate] if jt.coordinate is not None else [])
        if len(names) != JOINT_KINDS[jt.kind]:
            need = "coordinates: [x, y, theta]" if jt.kind == "free" else "coordinate: <name>"
            raise ValueError(f"{f}: a {jt.kind} joint names {JOINT_KINDS[jt.kind]} coordinate(s) ({need})")
        for c in names:
            if not isinstance(c, str) or not c.isidentifier():
                raise ValueError(f"{f}.coordinate: {c!r} is not a name")
            if c in coords or c in params:
                raise ValueError(f"{f}.coordinate: {c!r} is already a coordinate or parameter name")
        coords += names
        joint_of[jt.body] = jt
    missing = [b for b in byname if b not in joint_of]
    if missing:
        raise ValueError(f"{P}joints: body {missing[0]!r} has no joint (attach it to {GROUND!r} or a parent body)")
    q = [sp.Symbol(c) for c in coords]
    scope = _Scope({s.name: s for s in q} | {k: sp.Symbol(k) for k in params}, q, params)
    frames = _frames(byname, joint_of, scope, P)
    n = len(q)
    # M and V
    grav = _gravity(gravity, scope, P)
    acc = [[{} for _ in range(n)] for _ in range(n)]
    V = sp.Integer(0)
    for i, b in enumerate(bodies):
        f = _fld(b, f"{P}bodies[{i}]")
        origin, ang = frames[b.name]
        m = scope.scalar(b.mass, f"{f}.mass")
        inertia = scope.scalar(b.inertia, f"{f}.inertia")
        cx, cy = scope.vector(b.com, f"{f}.com")
        com = _shift(origin, cx, cy, ang)
        J = _jacobian(com, q)
        da = [sp.diff(ang, s) for s in q]
        for r in range(n):
            for c in range(r, n):
                _inner({a: (m * re, m * im) for a, (re, im) in J[r].items()}, J[c], acc[r][c])
                if inertia != 0 and da[r] != 0 and da[c] != 0:
                    acc[r][c].setdefault(sp.Integer(0), [sp.Integer(0), sp.Integer(0)])[0] += inertia * da[r] * da[c]
        if grav is not None:
            x, y = _xy(com)
            V -= m * (grav[0] * x + grav[1] * y)
    M = sp.zeros(n, n)
    for r in range(n):
        for c in range(r, n):
            M[r, c] = M[c, r] = _collect(acc[r][c])
    qd = [sp.Symbol(f"{c}_dot") for c in coords]
    forcing = None
    springs_V = sp.Integer(0)
    for i, s in enumerate(springs):
        f = _fld(s, f"{P}springs[{i}]")
        ell = _distance(frames, s.a, s.b, s.point_a, s.point_b, scope, f)
        springs_V += scope.scalar(s.k, f"{f}.k") * (ell - scope.scalar(s.length, f"{f}.length")) ** 2 / 2
    for i, dmp in enumerate(dampers):
        f = _fld(dmp, f"{P}dampers[{i}]")
        ell = _distance(frames, dmp.a, dmp.b, dmp.point_a, dmp.point_b, scope, f)
        grad = sp.Matrix([sp.diff(ell, s) for s in q])
        rate = sum((grad[k] * qd[k] for k in range(n)), sp.Integer(0))
        term = -scope.scalar(dmp.c, f"{f}.c") * rate * grad
        forcing = term if forcing is None else forcing + term
    # gravity's terms collected by the trigonometric functions; the springs' as declared (expanded,
    # k (l - length)^2 / 2 has a term per pair of length's terms, and collecting them with factor took
    # a minute for a 30-term length)
    V = sp.collect(sp.expand(V), [sp.cos(s) for s in q] + [sp.sin(s) for s in q] + q, func=sp.factor) + springs_V
    start = _start(q0, coords, f"{P}q0")
    cons = [_contact(c, k, frames, byname, scope, params, start, P) for k, c in enumerate(contacts)]
    system = MechanicalSystem(name=name, q=q, qd=qd, params=params, M=M, V=V, constraints=cons, forcing=forcing,
                              description=description, ic_map=ic_map)
    from .drawing import from_bodies   # the geometry, kept for animations

    system.drawing = from_bodies(q, lambda body, local, fld: _xy(_point(frames, body, local, scope, fld)), GROUND,
                                 bodies, joint_of, contacts, springs, dampers, scope, field_prefix)
    if start is not None:
        _check_start(system, cons, start, contacts, P)
        _check_masses(system, start, coords, joint_of, P)
        if p0 is not None:
            pv = _start(p0, coords, f"{P}p0")
        else:
            pv = system.mass_matrix(start) @ (_start(qdot0, coords, f"{P}qdot0") if qdot0 is not None else np.zeros(n))
        system.default_q0, system.default_p0 = start, pv
    return system


def _frames(byname: dict, joint_of: dict, scope: _Scope, P: str) -> dict:
    """{body: (origin phasor sum, absolute angle)}, parents first (a loop of parents is an error)."""
    frames = {GROUND: ({}, sp.Integer(0))}

    def frame(name, seen):
        if name in frames:
            return frames[name]
        if name in seen:
            raise ValueError(f"{P}joints: the parents of {name!r} form a loop ({' -> '.join(seen + [name])}); "
                             f"every chain must end at {GROUND!r}")
        jt = joint_of[name]
        f = jt.field or f"{P}joints"
        po, pa = frame(jt.parent, seen + [name])
        ax, ay = scope.vector(jt.at, f"{f}.at")
        cs = jt.coordinates if jt.coordinates is not None else [jt.coordinate]
        s = [scope.symbols[c] for c in cs]
        if jt.kind == "revolute":
            out = (_shift(po, ax, ay, pa), s[0] if jt.absolute else pa + s[0])
        elif jt.kind == "prismatic":
            ux, uy = scope.vector(jt.axis, f"{f}.axis")
            nrm = sp.sqrt(ux ** 2 + uy ** 2)
            if nrm == 0:
                raise ValueError(f"{f}.axis: must be a nonzero direction")
            out = (_shift(po, ax + s[0] * ux / nrm, ay + s[0] * uy / nrm, pa), pa)
        else:
            out = (_shift(po, ax + s[0], ay + s[1], pa), pa + s[2])
        frames[name] = out
        return out

    for name in byname:
        frame(name, [])
    return frames


def _gravity(g, scope: _Scope, P: str):
    if isinstance(g, (list, tuple)):
        return scope.vector(g, f"{P}gravity")
    gv = scope.scalar(g, f"{P}gravity")
    return None if gv == 0 else (sp.Integer(0), -gv)


def _point(frames: dict, body: str, point, scope: _Scope, fld: str) -> dict:
    if body not in frames:
        raise ValueError(f"{fld}: {body!r} is neither {GROUND!r} nor a declared body")
    origin, ang = frames[body]
    px, py = scope.vector(point, fld + ".point")
    return _shift(origin, px, py, ang)


def _distance(frames, a, b, pa, pb, scope, fld) -> sp.Expr:
    xa, ya = _xy(_point(frames, a, pa, scope, f"{fld}.a"))
    xb, yb = _xy(_point(frames, b, pb, scope, f"{fld}.b"))
    return sp.sqrt((xa - xb) ** 2 + (ya - yb) ** 2)


def _restitution(e, params: dict, fld: str) -> sp.Expr:
    if isinstance(e, sp.Symbol):
        e = e.name
    if isinstance(e, str):
        if e not in params:
            raise ValueError(f"{fld}.restitution: {e!r} is not a parameter (declared: {', '.join(params) or 'none'}); "
                             "give a number in [0, 1] or a parameter name")
        return sp.Symbol(e)
    if isinstance(e, bool) or not isinstance(e, (int, float, sp.Number)) or not 0.0 <= float(e) <= 1.0:
        raise ValueError(f"{fld}.restitution: must be a number in [0, 1] or a parameter name (got {e!r})")
    return sp.Integer(1) if float(e) == 1.0 else sp.Float(float(e))


def _contact(c, k: int, frames: dict, byname: dict, scope: _Scope, params: dict, start, P: str) -> Constraint:
    f = _fld(c, f"{P}contacts[{k}]")
    if not isinstance(c, (PointContact, CircleContact)):
        raise ValueError(f"{f}: must be a PointContact or a CircleContact")
    mu = coefficient(c.friction, params, f"{f}.friction")
    mus = None if c.static_friction is None else coefficient(c.static_friction, params, f"{f}.static_friction",
                                                             "static_friction")
    frictional = mu != 0 or (mus is not None and mus != 0)
    slip = None
    if isinstance(c, PointContact):
        pt = _point(frames, c.body, c.point, scope, f"{f}.body")
        x, y = _xy(pt)
        lx, ly = scope.vector(c.line_point, f"{f}.line.point")
        nx, ny = scope.vector(c.normal, f"{f}.line.normal")
        nrm = sp.sqrt(nx ** 2 + ny ** 2)
        if nrm == 0:
            raise ValueError(f"{f}.line.normal: must be a nonzero direction")
        radius = scope.scalar(c.radius, f"{f}.radius")
        phi = (nx * (x - lx) + ny * (y - ly)) / nrm - radius
        if frictional:
            # the rim's material point at the contact, C - r n: velocity v_C + omega x (-r n) =
            # v_C + r omega t with t = (n_y, -n_x)/|n|, so v_t = t . J_C qdot + r omega
            slip = tuple(sp.expand((ny * sp.diff(x, s) - nx * sp.diff(y, s)) / nrm)
                         + radius * sp.diff(frames[c.body][1], s) for s in scope.q)
    else:
        if not isinstance(c.bodies, (list, tuple)) or len(c.bodies) != 2 or c.bodies[0] == c.bodies[1]:
            raise ValueError(f"{f}.circles: name two different bodies (got {c.bodies!r})")
        pts, rs = [], []
        for s, bn in enumerate(c.bodies):
            if bn not in frames or bn == GROUND:
                raise ValueError(f"{f}.circles[{s}]: {bn!r} is not a declared body")
            center = c.centers[s] if c.centers is not None else None
            r = c.radii[s] if c.radii is not None else None
            bd = byname[bn]
            center = bd.com if center is None else center
            r = bd.radius if r is None else r
            if r is None:
                raise ValueError(f"{f}.radii: body {bn!r} declares no radius; give radii: [rA, rB] or the bodies' radius")
            pts.append(_xy(_point(frames, bn, center, scope, f"{f}.centers[{s}]")))
            rs.append(scope.scalar(r, f"{f}.radii[{s}]"))
        dx, dy = sp.expand(pts[0][0] - pts[1][0]), sp.expand(pts[0][1] - pts[1][1])
        d = _separation(dx, dy, scope, start, f)
        phi = d - rs[0] - rs[1]
        if frictional:
            # n = (C_A - C_B)/d from B to A, t = (n_y, -n_x); the material points at the contact,
            # C_A - r_A n and C_B + r_B n, slide relative to each other at
            # v_t = (v_A - v_B) . t + r_A omega_A + r_B omega_B
            slip = tuple(sp.expand(dy * sp.diff(dx, s) - dx * sp.diff(dy, s)) / d
                         + rs[0] * sp.diff(frames[c.bodies[0]][1], s) + rs[1] * sp.diff(frames[c.bodies[1]][1], s)
                         for s in scope.q)
    return Constraint(str(c.name), phi, _restitution(c.restitution, params, f), friction=mu, static_friction=mus,
                      slip=slip, field=f)


def _separation(dx, dy, scope: _Scope, start, fld: str) -> sp.Expr:
    """|(dx, dy)|; on a line (dy or dx identically 0) with a start state, s dx (or s dy) with s the sign
    at the start: the same distance while the circles do not pass through each other (the contact
    keeps them apart), and a smooth phi with the linear form of a hand declaration."""
    if start is not None and (dy == 0 or dx == 0):
        lin = dx if dy == 0 else dy
        v = _value(lin, scope, start)
        if v is not None and v != 0.0:
            return lin if v > 0 else -lin
    return sp.sqrt(dx ** 2 + dy ** 2)


def _value(expr, scope: _Scope, start):
    """expr at the start coordinates and default parameters (None if it is not a number there)."""
    sub = dict(zip(scope.q, (float(v) for v in start)))
    try:
        return float(expr.subs(sub | scope.param_values))
    except (TypeError, ValueError):
        return None


def _start(v, coords: list, fld: str):
    if v is None:
        return None
    n = len(coords)
    if isinstance(v, dict):
        bad = [k for k in v if k not in coords]
        if bad:
            raise ValueError(f"{fld}.{bad[0]}: not a coordinate ({', '.join(coords)})")
        v = [v.get(c, 0.0) for c in coords]
    try:
        a = np.asarray(v, dtype=float).ravel()
    except (TypeError, ValueError):
        raise ValueError(f"{fld}: must be a list of {n} numbers or a mapping coordinate -> number") from None
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{fld}: must be {n} finite numbers ({', '.join(coords)})")
    return a


def _check_masses(system: MechanicalSystem, q0, coords: list, joint_of: dict, P: str) -> None:
    """M(q0) positive definite, else the coordinates that carry no mass or inertia are named with their
    bodies (a body of zero mass on a free joint: its x, y; of zero inertia: its angle)."""
    try:
        system.check_hyperregular(q0)
    except ValueError:
        M = system.mass_matrix(q0)
        w, V = np.linalg.eigh(0.5 * (M + M.T))
        null = V[:, w <= max(w[0], 0.0) + 1e-12 * max(abs(w[-1]), 1.0)]   # every direction without inertia
        v = np.sqrt(np.sum(null * null, axis=1))
        weak = [coords[i] for i in np.flatnonzero(v >= 0.3 * v.max())]
        owner = {c: b for b, jt in joint_of.items()
                 for c in (jt.coordinates if jt.coordinates is not None else [jt.coordinate])}
        bodies = list(dict.fromkeys(owner[c] for c in weak))
        raise ValueError(f"{P}bodies: M(q) is not positive definite at q0 = {np.asarray(q0).tolist()} (smallest "
                         f"eigenvalue {w[0]:.3g}): the coordinate{'s' * (len(weak) > 1)} {', '.join(weak)} carr"
                         f"{'y' if len(weak) > 1 else 'ies'} no mass or inertia; give body "
                         f"{' or '.join(repr(b) for b in bodies)} a mass (and an inertia for its angle), or "
                         "attach it to a body that has them") from None


def _number(x) -> float:
    """A substituted expression as a float (nan where it did not reduce to a real number)."""
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan


def _check_start(system: MechanicalSystem, cons: list, q0, contacts, P: str) -> None:
    """The sign convention: every phi_i >= 0 at the start (to round-off), else the contact is named.
    phi and its gradient are evaluated by substituting floats (sympy evaluates each function of a
    float): a few expressions once, where lambdify's code generation took 0.3 s of a first call."""
    subs = dict(zip(system.q, map(sp.Float, q0)))
    subs |= dict(zip(system.param_symbols, map(sp.Float, system.param_values())))
    phis = np.array([_number(c.phi.xreplace(subs)) for c in system.constraints])
    G = np.array([[_number(g.xreplace(subs)) for g in row] for row in system.constraint_jacobian.tolist()])
    for i, c in enumerate(cons):
        tol = 1e-10 * (1.0 + float(np.max(np.abs(q0))) * float(np.max(np.abs(G[i]))))
        if not math.isfinite(phis[i]) or phis[i] < -tol:
            f = _fld(contacts[i], f"{P}contacts[{i}]")
            what = ("the point starts on the wrong side of its line (phi > 0 on the side the normal points "
                    "to: flip the normal or move the point)" if isinstance(contacts[i], PointContact) else
                    "the circles overlap at the start (move them apart or reduce the radii)")
            raise ValueError(f"{f}: contact {c.name!r} has phi = {phis[i]:.6g} < 0 at the start state q0 = "
                             f"{q0.tolist()}: {what}")
