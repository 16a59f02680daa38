"""Built-in scenes declared by bodies, joints and contact geometry (vcirun.mechanics.bodies): the
rocking block, a chain of N links falling on a floor and a cradle of N hanging balls (touching, or
hung with small gaps). Their numeric
parts (defaults, initial states, descriptions) are vcirun.scenes.data's, under the same names."""
from __future__ import annotations

from ..mechanics.bodies import Body, CircleContact, Joint, PointContact, planar_system
from ..mechanics.system import MechanicalSystem
from . import data as sd


def _build(d, bodies, joints, contacts, gravity="g") -> MechanicalSystem:
    s = planar_system(d.name, bodies, joints, contacts, params=d.params, gravity=gravity, q0=d.default_q0,
                      description=d.description, ic_map=d.ic_map)
    s.default_q0, s.default_p0 = d.default_q0, d.default_p0
    return s


def rocking_block(**overrides) -> MechanicalSystem:
    """A rectangular block (width b, height a, mass m, inertia m (a^2 + b^2)/12) on a free planar
    joint (x, y, theta of its centre), dropped tilted on the floor y = 0; its two lower corners are
    the contacts, restitution e. beta = the drop height of the centre."""
    d = sd.rocking_block(**overrides)
    corners = (("-b/2", "-a/2"), ("b/2", "-a/2"), ("b/2", "a/2"), ("-b/2", "a/2"))
    return _build(d, [Body("block", "m", "m*(a**2 + b**2)/12", outline=corners)],
                  [Joint("free", "block", coordinates=("x", "y", "theta"))],
                  [PointContact("left", "block", ("-b/2", "-a/2"), restitution="e"),
                   PointContact("right", "block", ("b/2", "-a/2"), restitution="e")])


def link_chain(n: int = 5, **overrides) -> MechanicalSystem:
    """N uniform links (mass m, length l, inertia m l^2/12) joined end to end by revolute joints;
    link 1 on a free joint (x, y: its first end; theta1), the others by their absolute angles
    theta2..thetaN; the N + 1 link ends are point contacts with the floor y = 0, restitution e."""
    n = int(n)
    d = sd.link_chain(n, **overrides)
    bodies = [Body(f"link{i}", "m", "m*l**2/12", ("l/2", 0)) for i in range(1, n + 1)]
    joints = [Joint("free", "link1", coordinates=("x", "y", "theta1"))]
    joints += [Joint("revolute", f"link{i}", f"link{i - 1}", ("l", 0), f"theta{i}", absolute=True)
               for i in range(2, n + 1)]
    contacts = [PointContact("end0", "link1", restitution="e")]
    contacts += [PointContact(f"end{i}", f"link{i}", ("l", 0), restitution="e") for i in range(1, n + 1)]
    return _build(d, bodies, joints, contacts)


def cradle(n: int = 5, **overrides) -> MechanicalSystem:
    """Newton's cradle: N balls (mass m, radius r) hanging on massless strings of length L from
    pivots 2r apart (revolute joints to the ground, angles theta_i from the downward vertical);
    neighbours are circle contacts, restitution e. Ball 1 released from theta1 = -beta, the others
    hanging at rest, touching: Moreau's law treats the touching row as one simultaneous impact
    (docs/derivations/contacts.md 1.6); `cradle_gap` hangs them apart."""
    n = int(n)
    return _cradle(sd.cradle(n, **overrides), n, "2*r*{i}")


def cradle_gap(n: int = 5, **overrides) -> MechanicalSystem:
    """Newton's cradle with the balls hung `gap` apart (pivots 2r + gap apart): each impact is one pair,
    in sequence down the row, and the last ball swings out (the cradle of the desk toy)."""
    n = int(n)
    return _cradle(sd.cradle_gap(n, **overrides), n, "(2*r + gap)*{i}")


def _cradle(d, n, pivot) -> MechanicalSystem:
    bodies = [Body(f"ball{i}", "m", 0, (0, "-L"), radius="r") for i in range(1, n + 1)]
    joints = [Joint("revolute", f"ball{i}", at=(pivot.format(i=i), 0), coordinate=f"theta{i}")
              for i in range(1, n + 1)]
    contacts = [CircleContact(f"c{i}", (f"ball{i}", f"ball{i + 1}"), restitution="e") for i in range(1, n)]
    return _build(d, bodies, joints, contacts)
