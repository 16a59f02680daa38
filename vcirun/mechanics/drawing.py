"""What an animation draws of a scene: its geometry as expressions in the coordinates and parameters.

A `Drawing` is kept on the MechanicalSystem (`system.drawing`, None where nothing is declared):

- points: {name: (x, y)}, expressions in q and the parameters;
- segments [(a, b)] and polygons [(a, b, c, ...)] between named points (links, rigid outlines);
- circles [(point, radius)] (balls, rounded contacts) and dots [point] (point masses);
- pivots [point] (joints to the ground), springs [(a, b)], dampers [(a, b)];
- lines [((px, py), (nx, ny))]: fixed lines (floors, walls, slopes), drawn across the view;
- contacts: one point name (or None) per constraint, where an impact of that constraint is marked;
- advance: (x, y) or None: for a walker whose declared reset exchanges the stance foot, the new stance
  foot relative to the old one at an impact (evaluated at the pre-impact q); the drawing moves by it at
  each impact, so the walker walks instead of jumping back.

Three sources: planar mechanisms (`from_bodies`, called by vcirun.mechanics.bodies.planar_system: links
from each joint to the body's other points, circles for bodies with a radius, dots for point masses,
an `outline` polygon where a body declares one, the contact lines), the optional `draw:` section of a
hand-written system file (`from_yaml`), and the built-in hand-written scenes (their symbolic builders, vcirun.scenes.paper and the other scene modules).
`numeric(drawing, names, values)` compiles it at the parameter values (sympy.lambdify) to arrays for many
configurations at once; vcirun.run.animate draws them.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import sympy as sp

__all__ = ["Drawing", "NumericDrawing", "numeric", "from_yaml", "from_bodies", "DRAW_KEYS"]

DRAW_KEYS = {"points", "segments", "polygons", "circles", "dots", "pivots", "springs", "dampers", "lines", "contacts",
             "advance"}


@dataclass
class Drawing:
    q: list
    points: dict = field(default_factory=dict)
    segments: list = field(default_factory=list)
    polygons: list = field(default_factory=list)
    circles: list = field(default_factory=list)
    dots: list = field(default_factory=list)
    pivots: list = field(default_factory=list)
    springs: list = field(default_factory=list)
    dampers: list = field(default_factory=list)
    lines: list = field(default_factory=list)
    contacts: list = field(default_factory=list)
    advance: tuple | None = None

    def point(self, name: str, x, y) -> str:
        """Add (or keep) a named point; returns its name."""
        self.points.setdefault(name, (sp.sympify(x), sp.sympify(y)))
        return name

    def check(self, field_prefix: str = "draw") -> "Drawing":
        """Every referenced point exists (ValueError naming the item)."""
        P = field_prefix
        names = set(self.points)

        def need(name, fld):
            if name is not None and name not in names:
                raise ValueError(f"{fld}: {name!r} is not a point of {P}.points ({', '.join(sorted(names)) or 'none'})")

        for k, (a, b) in enumerate(self.segments):
            need(a, f"{P}.segments[{k}]"), need(b, f"{P}.segments[{k}]")
        for k, poly in enumerate(self.polygons):
            for a in poly:
                need(a, f"{P}.polygons[{k}]")
        for k, (a, _) in enumerate(self.circles):
            need(a, f"{P}.circles[{k}].at")
        for k, a in enumerate(self.dots):
            need(a, f"{P}.dots[{k}]")
        for k, a in enumerate(self.pivots):
            need(a, f"{P}.pivots[{k}]")
        for key in ("springs", "dampers"):
            for k, (a, b) in enumerate(getattr(self, key)):
                need(a, f"{P}.{key}[{k}]"), need(b, f"{P}.{key}[{k}]")
        for k, a in enumerate(self.contacts):
            need(a, f"{P}.contacts[{k}]")
        return self


@dataclass
class NumericDrawing:
    """A Drawing at fixed parameters: `positions(Q)` -> (len(Q), len(names), 2) for configurations Q
    (k, n); radii, lines and the advance likewise numeric."""

    source: Drawing
    names: list
    index: dict
    radii: list
    lines: list
    _xy: object = field(repr=False)
    _advance: object = field(default=None, repr=False)

    def positions(self, Q) -> np.ndarray:
        Q = np.atleast_2d(np.asarray(Q, float))
        if not self.names:
            return np.zeros((len(Q), 0, 2))
        cols = self._xy(*[Q[:, j] for j in range(Q.shape[1])])
        out = np.empty((len(Q), len(self.names), 2))
        for k, (x, y) in enumerate(cols):
            out[:, k, 0] = np.broadcast_to(np.asarray(x, float), (len(Q),))
            out[:, k, 1] = np.broadcast_to(np.asarray(y, float), (len(Q),))
        return out

    def advance(self, q) -> np.ndarray:
        """The drawing's shift at an impact from the pre-impact q (zero without an advance)."""
        if self._advance is None:
            return np.zeros(2)
        x, y = self._advance(*np.asarray(q, float))
        return np.array([float(x), float(y)])


def numeric(d: Drawing, param_symbols, param_values) -> NumericDrawing:
    """Compile `d` at the parameter values (sympy.lambdify over the coordinates)."""
    subs = {sp.Symbol(str(s)): float(v) for s, v in zip(param_symbols, param_values)}
    names = list(d.points)
    exprs = [(sp.sympify(x).subs(subs), sp.sympify(y).subs(subs)) for x, y in d.points.values()]
    q = list(d.q)
    xy = sp.lambdify(q, exprs, "numpy") if names else None
    radii = [(a, float(sp.sympify(r).subs(subs))) for a, r in d.circles]
    lines = [(np.array([float(sp.sympify(c).subs(subs)) for c in p]), np.array([float(sp.sympify(c).subs(subs))
                                                                               for c in n])) for p, n in d.lines]
    adv = None
    if d.advance is not None:
        adv = sp.lambdify(q, [sp.sympify(c).subs(subs) for c in d.advance], "numpy")
    return NumericDrawing(d, names, {nm: k for k, nm in enumerate(names)}, radii, lines, xy, adv)


# --- the `draw:` section of a hand-written system file ---------------------------------------------------

def from_yaml(data, symbols: dict, q: list, m: int, field_prefix: str = "system.draw") -> Drawing:
    """The Drawing of a `draw:` mapping (docs/guide.md):

        draw:
          points: {cart: [0, y], bob: ["L*sin(theta)", "y - L*cos(theta)"]}
          segments: [[cart, bob]]               # polygons: [[a, b, c]]; springs, dampers: [[a, b]]
          circles: [{at: bob, radius: 0.1}]     # dots: [cart]; pivots: [name]
          lines: [{point: [0, 0], normal: [0, 1]}]
          contacts: [cart]                      # one point (or null) per constraint: impact marks
          advance: [x, y]                       # optional, walkers: the drawing's shift at each impact

    Expressions through the whitelist parser (vcirun.mechanics.expressions); errors name the field."""
    from ..mechanics.expressions import parse_expression

    P = field_prefix
    if not isinstance(data, dict):
        raise ValueError(f"{P}: must be a mapping with keys {', '.join(sorted(DRAW_KEYS))}")
    extra = set(data) - DRAW_KEYS
    if extra:
        raise ValueError(f"{P}.{sorted(map(str, extra))[0]}: unknown key (allowed: {', '.join(sorted(DRAW_KEYS))})")

    def expr(v, fld):
        if isinstance(v, bool) or not isinstance(v, (str, int, float)):
            raise ValueError(f"{fld}: must be an expression or a number")
        return parse_expression(v, symbols, fld)

    def pair(v, fld):
        if not isinstance(v, (list, tuple)) or len(v) != 2:
            raise ValueError(f"{fld}: must be a pair [x, y]")
        return expr(v[0], f"{fld}[0]"), expr(v[1], f"{fld}[1]")

    def names_list(v, fld, size=None):
        if not isinstance(v, list) or not all(isinstance(x, str) for x in v) or (size and len(v) != size):
            what = f"a list of {size} point names" if size else "a list of point names"
            raise ValueError(f"{fld}: must be {what}")
        return v

    d = Drawing(q=list(q))
    pts = data.get("points") or {}
    if not isinstance(pts, dict) or not pts:
        raise ValueError(f"{P}.points: required, a mapping name -> [x, y] (expressions in the coordinates)")
    for k, v in pts.items():
        d.points[str(k)] = pair(v, f"{P}.points.{k}")
    for key in ("segments", "springs", "dampers"):
        for k, it in enumerate(_list(data, key, P)):
            getattr(d, key).append(tuple(names_list(it, f"{P}.{key}[{k}]", 2)))
    for k, it in enumerate(_list(data, "polygons", P)):
        d.polygons.append(tuple(names_list(it, f"{P}.polygons[{k}]")))
    for key in ("dots", "pivots"):
        getattr(d, key).extend(names_list(_list(data, key, P), f"{P}.{key}"))
    for k, it in enumerate(_list(data, "circles", P)):
        fld = f"{P}.circles[{k}]"
        if not isinstance(it, dict) or set(it) - {"at", "radius"} or "at" not in it or "radius" not in it:
            raise ValueError(f"{fld}: must be a mapping {{at: point, radius: expression}}")
        d.circles.append((str(it["at"]), expr(it["radius"], f"{fld}.radius")))
    for k, it in enumerate(_list(data, "lines", P)):
        fld = f"{P}.lines[{k}]"
        if not isinstance(it, dict) or set(it) - {"point", "normal"} or "normal" not in it:
            raise ValueError(f"{fld}: must be a mapping {{point: [x, y], normal: [nx, ny]}}")
        d.lines.append((pair(it.get("point", [0, 0]), f"{fld}.point"), pair(it["normal"], f"{fld}.normal")))
    con = data.get("contacts")
    if con is not None:
        if not isinstance(con, list) or len(con) != m or not all(c is None or isinstance(c, str) for c in con):
            raise ValueError(f"{P}.contacts: must list {m} point names (or null), one per constraint")
        d.contacts = list(con)
    if data.get("advance") is not None:
        d.advance = pair(data["advance"], f"{P}.advance")
    return d.check(P)


def _list(data, key, P):
    v = data.get(key) or []
    if not isinstance(v, list):
        raise ValueError(f"{P}.{key}: must be a list")
    return v


# --- planar mechanisms ---------------------------------------------------------------------------------

def from_bodies(q, locate, ground, bodies, joint_of, contacts, springs, dampers, scope, field_prefix="system") -> Drawing:
    """The Drawing of a planar mechanism (vcirun.mechanics.bodies; `frames` its body frames): each body
    as segments from its joint to its other points (child joints, contact points, spring ends; the
    centre of mass where there is no other), its `outline` polygon where it declares one, a circle
    where it has a radius and a dot for a point mass; pivots where a joint holds a body to the ground;
    every contact line; springs and dampers between their ends; impacts marked at the contact point
    (two circles: between their centres). locate(body, (x, y), field) -> (X, Y): a point of a body
    (or of the ground, named `ground`) in the plane, as expressions in q."""
    GROUND = ground
    P = field_prefix
    d = Drawing(q=list(q))

    def place(body, local, fld):
        lx, ly = scope.vector(local, fld)
        name = f"{body}@({sp.sstr(lx)}, {sp.sstr(ly)})"
        if name not in d.points:
            d.point(name, *((lx, ly) if body == GROUND else locate(body, (lx, ly), fld)))
        return name, (lx, ly)

    keys = {b.name: [] for b in bodies}
    origin = {}
    for b in bodies:
        origin[b.name] = place(b.name, (0, 0), f"{P}.bodies")[0]
        jt = joint_of[b.name]
        if jt.parent == GROUND and jt.kind != "free":
            d.pivots.append(place(GROUND, jt.at, f"{P}.joints")[0])
        elif jt.parent != GROUND:
            keys[jt.parent].append(place(jt.parent, jt.at, f"{P}.joints")[0])
    lines = []
    for k, c in enumerate(contacts):
        fld = c.field or f"{P}.contacts[{k}]"
        if hasattr(c, "line_point"):    # a point against a line
            name, _ = place(c.body, c.point, fld)
            keys[c.body].append(name)
            r = scope.scalar(c.radius, f"{fld}.radius")
            if r != 0 and (name, r) not in d.circles:
                d.circles.append((name, r))
            line = (scope.vector(c.line_point, f"{fld}.line.point"), scope.vector(c.normal, f"{fld}.line.normal"))
            if line not in lines:
                lines.append(line)
            d.contacts.append(name)
        elif hasattr(c, "bodies"):      # two circles
            ends = []
            for s, bn in enumerate(c.bodies):
                center = c.centers[s] if c.centers is not None else next(b.com for b in bodies if b.name == bn)
                ends.append(place(bn, center, fld)[0])
            (xa, ya), (xb, yb) = d.points[ends[0]], d.points[ends[1]]
            d.contacts.append(d.point(f"{c.name}@between", (xa + xb) / 2, (ya + yb) / 2))
        else:
            d.contacts.append(None)
    d.lines = lines
    for group, target in ((springs, d.springs), (dampers, d.dampers)):
        for k, s in enumerate(group):
            fld = s.field or P
            a = place(s.a, s.point_a, f"{fld}.point_a")[0]
            b = place(s.b, s.point_b, f"{fld}.point_b")[0]
            for body, nm in ((s.a, a), (s.b, b)):
                if body != GROUND:
                    keys[body].append(nm)
            target.append((a, b))
    for b in bodies:
        fld = b.field or f"{P}.bodies"
        com, local = place(b.name, b.com, f"{fld}.com")
        o = origin[b.name]
        outline = getattr(b, "outline", None)
        if outline:
            d.polygons.append(tuple(place(b.name, pt, f"{fld}.outline[{i}]")[0] for i, pt in enumerate(outline)))
        others = [nm for nm in dict.fromkeys(keys[b.name]) if nm != o]
        if not outline:
            for nm in others:
                d.segments.append((o, nm))
            if not others and com != o:
                d.segments.append((o, com))
        if b.radius is not None:
            d.circles.append((com, scope.scalar(b.radius, f"{fld}.radius")))
        elif scope.scalar(b.inertia, f"{fld}.inertia") == 0:
            d.dots.append(com)
    return d.check(P)
