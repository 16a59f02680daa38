"""The helpers of the scenes' symbolic builders (sympy; imported by a builder when it runs, never by
the sympy-free scene declarations at import): a MechanicalSystem from M, V, phi with the scene's
drawing, a mechanism from bodies and joints, points along a slope and along a chain of links."""
from __future__ import annotations

import sympy as sp

from ..core.system_data import SystemData
from ..mechanics.system import Constraint, MechanicalSystem

__all__ = ["Constraint", "MechanicalSystem", "chain", "mechanism", "slope", "system"]


def system(d: SystemData, q, M, V, phi, draw=None, **kw) -> MechanicalSystem:
    """The MechanicalSystem of scene data `d`; draw: the keyword arguments of its Drawing (what
    `vcirun animate` draws: vcirun.mechanics.drawing; points as (x, y) expressions in q and the parameters)."""
    s = MechanicalSystem(name=d.name, q=q, params=d.params, M=M, V=V, phi=phi, ic_map=d.ic_map,
                         default_q0=d.default_q0, default_p0=d.default_p0, default_beta=d.default_beta,
                         description=d.description, **kw)
    if draw is not None:
        from ..mechanics.drawing import Drawing

        pts = {k: (sp.sympify(x), sp.sympify(y)) for k, (x, y) in draw.pop("points").items()}
        s.drawing = Drawing(q=list(q), points=pts, **draw).check(f"scene {d.name} drawing")
    return s


def mechanism(d: SystemData, bodies, joints, contacts, gravity="g", **start) -> MechanicalSystem:
    """The MechanicalSystem of a scene declared by bodies, joints and contacts (vcirun.mechanics.bodies);
    start: planar_system's q0 / qdot0 (default: the scene data's default state)."""
    from ..mechanics.bodies import planar_system

    q0 = start.pop("q0", d.default_q0)
    return planar_system(d.name, bodies, joints, contacts, params=d.params, gravity=gravity, q0=q0,
                         description=d.description, ic_map=d.ic_map, **start)


def slope(u, v, gam):
    """World (x, y) of the point u along a slope descending to the right at angle gam, v along its normal."""
    return u * sp.cos(gam) + v * sp.sin(gam), -u * sp.sin(gam) + v * sp.cos(gam)


def chain(angles, lengths, origin=(0, 0)):
    """Points of a chain of links at absolute angles from the downward vertical: [(x, y)] after each."""
    pts, (x, y) = [], origin
    for th, ell in zip(angles, lengths):
        x, y = x + ell * sp.sin(th), y - ell * sp.cos(th)
        pts.append((x, y))
    return pts
