"""The `bodies:` form of a system file: a planar mechanism by bodies, joints and contact geometry
(vcirun.mechanics.bodies builds it; docs/bodies.md describes every key).

    name: cart_pendulum_bodies
    parameters: {m1: 1.0, m2: 0.2, L: 2.0, g: 10.0}
    gravity: g                                   # along -y; or [gx, gy]
    bodies:
      - {name: cart, mass: m1}                   # inertia (default 0), com (default [0, 0]), radius, outline
      - {name: bob, mass: m2, com: [0, -L]}
    joints:                                      # one per body; coordinates named here, in this order
      - {type: prismatic, body: cart, coordinate: y, axis: [0, 1]}
      - {type: revolute, body: bob, parent: cart, coordinate: theta}   # at: [x, y] in the parent frame
    contacts:
      - {name: floor, body: cart, line: {point: [0, 0], normal: [0, 1]}}   # point, radius, restitution,
                                                                            # friction, static_friction
      - {name: "c{i}", repeat: [1, 9], circles: ["ball{i}", "ball{i+1}"], restitution: e}
    springs: [{a: ground, b: bob, k: k, length: l0, point_b: [0, 0]}]       # dampers: c instead of k
    q0: {y: 1.0}                                 # a list in coordinate order, or a mapping (others 0)
    qdot0: {theta: 0.5}                          # or p0

`repeat: [first, last]` on any item of bodies, joints, contacts, springs and dampers declares it once
per integer i in first..last, with {i}, {i+K} and {i-K} in its texts replaced by the integers.

The caps of vcirun.core.limits hold for the totals after every `repeat` is expanded, as for a
hand-written system: coordinates (what the joints declare; each body has a joint, so bodies and
joints are at most that many too), contacts, parameters, springs and dampers together. A section is
counted while it is expanded, so a file that asks for millions of items is refused before they exist.
"""
from __future__ import annotations

import re

from ..core.limits import CAPS, check_count, refuse
from ..core.names import check_description, check_identifier, check_system_name
from ..core.values import describe
from .bodies import (
    GROUND,
    JOINT_KINDS,
    Body,
    CircleContact,
    Damper,
    Joint,
    PointContact,
    Spring,
    planar_system,
)

KEYS = {"name", "description", "parameters", "gravity", "bodies", "joints", "contacts", "springs", "dampers",
        "q0", "qdot0", "p0"}
_ITEM_KEYS = {
    "bodies": {"name", "mass", "inertia", "com", "radius", "outline", "repeat"},
    "joints": {"type", "body", "parent", "at", "coordinate", "coordinates", "axis", "absolute", "repeat"},
    "contacts": {"name", "body", "point", "radius", "line", "circles", "centers", "radii", "restitution", "friction",
                 "static_friction", "repeat"},
    "springs": {"a", "b", "k", "length", "point_a", "point_b", "repeat"},
    "dampers": {"a", "b", "c", "point_a", "point_b", "repeat"},
}
MAX_REPEAT = CAPS["repeat"].limit  # items one `repeat` may declare
# the cap each section's total is held to while it is expanded (springs and dampers share one)
_SECTION_CAP = {"bodies": "coordinates", "joints": "coordinates", "contacts": "contacts",
                "springs": "force_elements", "dampers": "force_elements"}
_SECTION_WHAT = {"bodies": "bodies (each has a joint of at least one coordinate)",
                 "joints": "joints (each declares at least one coordinate)", "contacts": None,
                 "springs": "springs", "dampers": "dampers"}
_INDEX = re.compile(r"\{i(?:\s*([+-])\s*(\d+))?\}")


def load_bodies(data: dict, field_prefix: str = "system"):
    """The MechanicalSystem of a `bodies:` mapping; errors name the field."""
    P = field_prefix
    extra = set(data) - KEYS
    if extra:
        raise ValueError(f"{P}.{sorted(map(str, extra))[0]}: unknown key in a bodies declaration "
                         f"(allowed: {', '.join(sorted(KEYS))})")
    for k in ("bodies", "joints", "contacts"):
        if k not in data:
            raise ValueError(f"{P}.{k}: required (a list) in a bodies declaration")
    params = data.get("parameters") or {}
    if not isinstance(params, dict):
        raise ValueError(f"{P}.parameters: must be a mapping name -> value")
    check_count("parameters", f"{P}.parameters", len(params))
    for k, v in params.items():
        check_identifier(str(k), f"{P}.parameters.{k}")
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"{P}.parameters.{k}: must be a finite number (got {describe(v)})")
    items = {sec: _expand(data.get(sec) or [], sec, P) for sec in _ITEM_KEYS}
    _check_totals(items, P)
    bodies = [Body(it["name"], it.get("mass"), it.get("inertia", 0), it.get("com", (0, 0)), it.get("radius"), field=f,
                   outline=_outline(it.get("outline"), f))
              for f, it in _required(items["bodies"], ("name", "mass"))]
    joints = [Joint(it["type"], it["body"], it.get("parent", GROUND), it.get("at", (0, 0)), it.get("coordinate"),
                    it.get("coordinates"), it.get("axis", (1, 0)), _flag(it.get("absolute", False), f"{f}.absolute"),
                    field=f) for f, it in _required(items["joints"], ("type", "body"))]
    contacts = [_contact(f, it, k) for k, (f, it) in enumerate(items["contacts"])]
    springs = [Spring(it["a"], it["b"], it["k"], it.get("length", 0), it.get("point_a", (0, 0)),
                      it.get("point_b", (0, 0)), field=f) for f, it in _required(items["springs"], ("a", "b", "k"))]
    dampers = [Damper(it["a"], it["b"], it["c"], it.get("point_a", (0, 0)), it.get("point_b", (0, 0)), field=f)
               for f, it in _required(items["dampers"], ("a", "b", "c"))]
    return planar_system(check_system_name(data.get("name", "user_system"), P), bodies, joints, contacts,
                         params=params, gravity=data.get("gravity", 0), springs=springs, dampers=dampers,
                         q0=data.get("q0"), qdot0=data.get("qdot0"), p0=data.get("p0"),
                         description=check_description(data.get("description", ""), P), field_prefix=P)


def _contact(f: str, it: dict, k: int):
    name = str(it.get("name", f"c{k}"))
    e = it.get("restitution", 1)
    if "circles" in it:
        if "body" in it or "line" in it:
            raise ValueError(f"{f}: give either circles: [A, B] or body and line, not both")
        return CircleContact(name, tuple(it["circles"]) if isinstance(it["circles"], list) else it["circles"],
                             it.get("centers"), it.get("radii"), e, it.get("friction", 0), it.get("static_friction"),
                             field=f)
    if "body" not in it:
        raise ValueError(f"{f}: a contact names a body (point against a line) or circles: [A, B]")
    line = it.get("line", {})
    if not isinstance(line, dict) or set(line) - {"point", "normal"}:
        raise ValueError(f"{f}.line: must be a mapping {{point: [x, y], normal: [nx, ny]}} (the admissible side "
                         "is where the normal points)")
    return PointContact(name, it["body"], it.get("point", (0, 0)), it.get("radius", 0), line.get("point", (0, 0)),
                        line.get("normal", (0, 1)), e, it.get("friction", 0), it.get("static_friction"), field=f)


def _outline(v, fld):
    """A body's outline: None or a list of at least 3 corners [x, y] in its frame (drawn by animations)."""
    if v is None:
        return None
    if not isinstance(v, list) or len(v) < 3 or not all(isinstance(p, list) and len(p) == 2 for p in v):
        raise ValueError(f"{fld}.outline: must be a list of at least 3 corners [x, y] in the body frame")
    return tuple(tuple(p) for p in v)


def _flag(v, fld):
    if not isinstance(v, bool):
        raise ValueError(f"{fld}: must be true or false (got {describe(v)})")
    return v


def _required(items, keys):
    for f, it in items:
        for k in keys:
            if k not in it:
                raise ValueError(f"{f}.{k}: required")
        yield f, it


def _check_totals(items: dict, P: str) -> None:
    """The caps on the expanded declaration: coordinates (what the joints name), contacts, springs and
    dampers together."""
    n = 0
    for _, it in items["joints"]:
        names = it.get("coordinates")
        n += len(names) if isinstance(names, list) else JOINT_KINDS.get(it.get("type"), 1)
    check_count("coordinates", f"{P}.joints", n, "declare fewer joints (coordinates), counted after every repeat")
    check_count("contacts", f"{P}.contacts", len(items["contacts"]),
                "declare fewer contacts, counted after every repeat")
    check_count("force_elements", f"{P}.springs", len(items["springs"]) + len(items["dampers"]),
                "declare fewer springs and dampers, counted after every repeat")


def _expand(items, sec: str, P: str) -> list:
    """[(field, item)] with every `repeat: [first, last]` item declared once per i; the section's
    total is held to its cap (_SECTION_CAP) while it grows."""
    if not isinstance(items, list):
        raise ValueError(f"{P}.{sec}: must be a list of mappings")
    limit = CAPS[_SECTION_CAP[sec]].limit
    out = []
    for j, it in enumerate(items):
        f = f"{P}.{sec}[{j}]"
        if not isinstance(it, dict):
            raise ValueError(f"{f}: must be a mapping (keys: {', '.join(sorted(_ITEM_KEYS[sec]))})")
        bad = set(it) - _ITEM_KEYS[sec]
        if bad:
            raise ValueError(f"{f}.{sorted(map(str, bad))[0]}: unknown key (allowed: {', '.join(sorted(_ITEM_KEYS[sec]))})")
        if "repeat" not in it:
            out.append((f, it))
            continue
        rep = it["repeat"]
        if (not isinstance(rep, list) or len(rep) != 2 or not all(isinstance(x, int) and not isinstance(x, bool)
                                                                   for x in rep) or rep[1] < rep[0]):
            raise ValueError(f"{f}.repeat: must be [first, last], two integers with first <= last (got {rep!r})")
        check_count("repeat", f"{f}.repeat", rep[1] - rep[0] + 1)
        if len(out) + rep[1] - rep[0] + 1 > limit:
            raise refuse(_SECTION_CAP[sec], f"{P}.{sec}", len(out) + rep[1] - rep[0] + 1,
                         f"declare fewer {sec}, counted after every repeat", _SECTION_WHAT[sec])
        body = {k: v for k, v in it.items() if k != "repeat"}
        for i in range(rep[0], rep[1] + 1):
            out.append((f"{f} (i={i})", _substitute(body, i)))
    if len(out) > limit:
        raise refuse(_SECTION_CAP[sec], f"{P}.{sec}", len(out), f"declare fewer {sec}, counted after every repeat",
                     _SECTION_WHAT[sec])
    return out


def _substitute(v, i: int):
    if isinstance(v, str):
        return _INDEX.sub(lambda mt: str(i + (int(mt.group(2)) if mt.group(1) == "+" else -int(mt.group(2)))
                                          if mt.group(1) else i), v)
    if isinstance(v, list):
        return [_substitute(x, i) for x in v]
    if isinstance(v, dict):
        return {k: _substitute(x, i) for k, x in v.items()}
    return v
