"""The scenes with several contacts, each declared once (vcirun.scenes.scene.Scene): a ball in a box,
a line of balls (Newton's cradle on a line), the double pendulum between walls, and the mechanisms
declared by bodies, joints and contact geometry (vcirun.mechanics.bodies): the rocking block, a chain
of N links falling on a floor and a cradle of N hanging balls (touching, or hung with small gaps).

No sympy at import: each symbolic builder imports it when it runs."""
from __future__ import annotations

import numpy as np

from .paper import DOUBLE_PENDULUM_COORDINATES, DOUBLE_PENDULUM_PARAMS, double_pendulum_M_V
from .scene import EVERY_CONTACT_E, Param, Scene

_G = Param(9.81, "m/s^2", "gravitational acceleration")
E = Param(1.0, "", "restitution coefficient of every contact")   # elastic by default


def _ball_in_box_symbolic(x):
    """A point mass m in the box 0 <= x <= width, 0 <= y <= height under gravity g, four
    walls in this order: floor y >= 0, ceiling height - y >= 0, left x >= 0, right width - x >= 0,
    each with restitution e (a parameter). Decoupled motion: closed form in vcirun.scenes.oracles."""
    import sympy as sp

    from .symbolic import Constraint, system

    (qx, qy), p = x.q, x.p
    m, g, W, Hh, e = p.m, p.g, p.width, p.height, p.e
    cons = [Constraint("floor", qy, e), Constraint("ceiling", Hh - qy, e), Constraint("left", qx, e),
            Constraint("right", W - qx, e)]
    draw = dict(points={"ball": (qx, qy), "corner0": (0, 0), "corner1": (W, Hh)}, dots=["ball"],
                lines=[((0, 0), (0, 1)), ((0, Hh), (0, -1)), ((0, 0), (1, 0)), ((W, 0), (-1, 0))],
                contacts=["ball"] * 4)
    return system(x.d, [qx, qy], sp.diag(m, m), m * g * qy, None, constraints=cons, draw=draw)


def _ball_in_box_start(p):
    return dict(default_q0=np.array([0.3, 0.6]), default_p0=p["m"] * np.array([0.7, 0.0]))


BALL_IN_BOX = Scene(
    "ball_in_box",
    description="point mass in the box 0 <= x <= width, 0 <= y <= height under gravity; four walls "
                "(floor, ceiling, left, right) with restitution e",
    coordinates=(("x", "m", "horizontal position of the ball"), ("y", "m", "height of the ball")),
    params={"m": Param(1.0, "kg", "mass"), "g": _G, "width": Param(1.0, "m", "box width"),
            "height": Param(1.0, "m", "box height"), "e": E},
    constraint="4 contacts: floor y >= 0, ceiling height - y >= 0, left x >= 0, right width - x >= 0",
    default_text="x = 0.3, y = 0.6, moving right at 0.7 m/s",
    restitution=EVERY_CONTACT_E, symbolic=_ball_in_box_symbolic, start=_ball_in_box_start,
    example=("", "bounces off floor, walls and ceiling"))


def _newton_cradle_symbolic(x):
    """n equal balls (mass m, diameter d) on a line, no gravity along it; contact i between
    balls i and i + 1: x_{i+1} - x_i - d >= 0, restitution e."""
    import sympy as sp

    from .symbolic import Constraint, system

    n, xs, p = x.k, x.q, x.p
    m, dd, e = p.m, p.d, p.e
    cons = [Constraint(f"c{i + 1}{i + 2}", xs[i + 1] - xs[i] - dd, e) for i in range(n - 1)]
    pts = {f"ball{i + 1}": (xs[i], 0) for i in range(n)}
    pts.update({f"touch{i + 1}": ((xs[i] + xs[i + 1]) / 2, 0) for i in range(n - 1)})
    draw = dict(points=pts, circles=[(f"ball{i + 1}", dd / 2) for i in range(n)],
                contacts=[f"touch{i + 1}" for i in range(n - 1)])
    return system(x.d, list(xs), m * sp.eye(n), sp.Integer(0), None, constraints=cons, draw=draw)


def _newton_cradle_start(p, n):
    q0 = np.array([-0.2] + [p["d"] * k for k in range(1, n)])  # balls 2..N touching, ball 1 away
    p0 = np.zeros(n)
    p0[0] = p["m"] * 1.0                                       # ... approaching at speed 1
    return dict(default_q0=q0, default_p0=p0)


NEWTON_CRADLE = Scene(
    "newton_cradle", size=3,
    description=lambda n: (f"{n} equal balls of diameter d on a line, contacts between neighbours with "
                           "restitution e; balls 2..N touching, ball 1 approaching at speed 1"),
    coordinates=lambda n: tuple((f"x{i}", "m", f"position of ball {i}") for i in range(1, n + 1)),
    params={"m": Param(1.0, "kg", "mass of each ball"), "d": Param(0.1, "m", "ball diameter"), "e": E},
    constraint=lambda n: f"{n - 1} contacts c{{i}}{{i+1}}: x_(i+1) - x_i - d >= 0",
    default_text="balls 2..N touching at rest, ball 1 0.2 m away approaching at 1 m/s",
    restitution=EVERY_CONTACT_E, symbolic=_newton_cradle_symbolic, start=_newton_cradle_start,
    example=("", "ball 1 hits the touching row"))


def _double_pendulum_walls_symbolic(x):
    """The double pendulum of Figure 1 whose second tip x = l1 sin th1 + l2 sin th2 stays
    between two walls: right w - x >= 0, left x + w >= 0, restitution e."""
    import sympy as sp

    from .symbolic import Constraint, chain, system

    (t1, t2), p = x.q, x.p
    l1, l2, w, e = p.l1, p.l2, p.w, p.e
    M, V = double_pendulum_M_V(x)
    xt = l1 * sp.sin(t1) + l2 * sp.sin(t2)
    p1, p2 = chain([t1, t2], [l1, l2])
    draw = dict(points={"pivot": (0, 0), "tip1": p1, "tip2": p2}, segments=[("pivot", "tip1"), ("tip1", "tip2")],
                dots=["tip1", "tip2"], pivots=["pivot"], lines=[((w, 0), (-1, 0)), ((-w, 0), (1, 0))],
                contacts=["tip2", "tip2"])
    return system(x.d, [t1, t2], M, V, None, constraints=[Constraint("right", w - xt, e), Constraint("left", xt + w, e)],
                  draw=draw)


# hanging straight down and kicked (the double pendulum's horizontal start would put the tip at
# x = -2, inside the left wall x = -w): Xi(beta) = (0, 0), beta (2, 1); the default beta = 3 gives
# three impacts in [0, 3], on the right, left and right walls
DOUBLE_PENDULUM_WALLS = Scene(
    "double_pendulum_walls",
    description="double pendulum whose second tip stays between the walls x = -w and x = w (restitution e)",
    coordinates=DOUBLE_PENDULUM_COORDINATES,
    params=DOUBLE_PENDULUM_PARAMS | {"w": Param(1.2, "m", "walls at x = -w and x = w"), "e": E},
    constraint="2 contacts: right w - x_tip >= 0, left x_tip + w >= 0 (x_tip = l1 sin theta1 + l2 sin theta2)",
    ic_text="hanging down, kicked: theta = (0, 0), thetadot = beta (2, 1)", default_text="hanging down, p = (6, 3)",
    restitution=EVERY_CONTACT_E, symbolic=_double_pendulum_walls_symbolic,
    start=lambda p: dict(ic_map=lambda beta: (np.zeros(2), beta * np.array([2.0, 1.0])),
                         default_q0=np.zeros(2), default_p0=np.array([6.0, 3.0])),
    example=("", "the tip bounces between the walls"))


# --- mechanisms declared by bodies ----------------------------------------------------------------

def _rocking_block_symbolic(x):
    """A rectangular block (width b, height a, mass m, inertia m (a^2 + b^2)/12) on a free planar
    joint (x, y, theta of its centre), dropped tilted on the floor y = 0; its two lower corners are
    the contacts, restitution e. beta = the drop height of the centre."""
    from ..mechanics.bodies import Body, Joint, PointContact
    from .symbolic import mechanism

    corners = (("-b/2", "-a/2"), ("b/2", "-a/2"), ("b/2", "a/2"), ("-b/2", "a/2"))
    return mechanism(x.d, [Body("block", "m", "m*(a**2 + b**2)/12", outline=corners)],
                     [Joint("free", "block", coordinates=tuple(map(str, x.q)))],
                     [PointContact("left", "block", ("-b/2", "-a/2"), restitution="e"),
                      PointContact("right", "block", ("b/2", "-a/2"), restitution="e")])


BLOCK_COORDINATES = (("x", "m", "horizontal position of the block's centre"),
                     ("y", "m", "height of the block's centre"), ("theta", "rad", "tilt of the block"))

ROCKING_BLOCK = Scene(
    "rocking_block",
    description="rectangular block (width b, height a) dropped tilted on the floor y = 0; its two lower "
                "corners are the contacts, restitution e, frictionless: it slides as it bounces and settles "
                "(the block rocking on its corners without sliding: rocking_block_friction) (declared by bodies)",
    coordinates=BLOCK_COORDINATES,
    params={"m": Param(1.0, "kg", "mass"), "a": Param(1.0, "m", "block height"), "b": Param(0.4, "m", "block width"),
            "g": _G, "e": Param(0.5, "", "restitution coefficient of every contact")},
    constraint="2 contacts: the lower corners (-b/2, -a/2) and (b/2, -a/2) above the floor y = 0 (declared by bodies)",
    ic_text="drop height of the centre y = beta, theta = 0.2, at rest", default_text="y = 0.7, theta = 0.2, at rest",
    restitution=EVERY_CONTACT_E, symbolic=_rocking_block_symbolic,
    start=lambda p: dict(default_q0=np.array([0.0, 0.7, 0.2]), default_p0=np.zeros(3),
                         ic_map=lambda beta: (np.array([0.0, beta, 0.2]), np.zeros(3))),
    example=("--h 0.001 --T 3", ("23 corner impacts, then at rest; frictionless, the corners slide: "
                                 "rocking_block_friction rocks")))


def link_chain_start(n: int, height: float):
    """(q0, qdot0) of a chain of n links: a tilted zigzag (theta_k = 0.3 (-1)^k + 0.05: the ends at
    different heights), its first end at (0, height), at rest (link_chain and link_chain_friction)."""
    angles = [0.3 * (-1) ** k + 0.05 for k in range(1, int(n) + 1)]
    return np.array([0.0, float(height)] + angles), np.zeros(int(n) + 2)


def link_chain_parts(n, friction=None):
    """Bodies, joints and contacts of N uniform links (mass m, length l, inertia m l^2/12) joined end
    to end by revolute joints; link 1 on a free joint (x, y: its first end; theta1), the others by
    their absolute angles theta2..thetaN; the N + 1 link ends are point contacts with the floor y = 0,
    restitution e, friction `friction` (a parameter name, or None)."""
    from ..mechanics.bodies import Body, Joint, PointContact

    fr = {} if friction is None else {"friction": friction}
    bodies = [Body(f"link{i}", "m", "m*l**2/12", ("l/2", 0)) for i in range(1, n + 1)]
    joints = [Joint("free", "link1", coordinates=("x", "y", "theta1"))]
    joints += [Joint("revolute", f"link{i}", f"link{i - 1}", ("l", 0), f"theta{i}", absolute=True)
               for i in range(2, n + 1)]
    contacts = [PointContact("end0", "link1", restitution="e", **fr)]
    contacts += [PointContact(f"end{i}", f"link{i}", ("l", 0), restitution="e", **fr) for i in range(1, n + 1)]
    return bodies, joints, contacts


def link_chain_coordinates(n):
    return ((("x", "m", "first end of link 1, horizontal"), ("y", "m", "first end of link 1, height"))
            + tuple((f"theta{i}", "rad", f"absolute angle of link {i} from the horizontal") for i in range(1, n + 1)))


def _link_chain_symbolic(x):
    from .symbolic import mechanism

    return mechanism(x.d, *link_chain_parts(x.k))


LINK_CHAIN_PARAMS = {"m": Param(0.2, "kg", "mass of each link"), "l": Param(0.3, "m", "length of each link"),
                     "g": _G, "e": Param(0.3, "", "restitution coefficient of every contact")}

LINK_CHAIN = Scene(
    "link_chain", size=5,
    description=lambda n: (f"chain of {n} links (revolute joints, the first on a free joint) falling on the floor "
                           "y = 0; the link ends are the contacts, restitution e (declared by bodies)"),
    coordinates=link_chain_coordinates, params=LINK_CHAIN_PARAMS,
    constraint=lambda n: f"{n + 1} contacts end0..end{n}: the link ends above the floor y = 0 (declared by bodies)",
    ic_text="height of the first end y = beta, tilted zigzag, at rest",
    default_text="y = 0.5, theta_k = 0.3 (-1)^k + 0.05, at rest",
    restitution=EVERY_CONTACT_E,
    symbolic=_link_chain_symbolic,
    start=lambda p, n: dict(default_q0=link_chain_start(n, 0.5)[0], default_p0=np.zeros(n + 2),
                            ic_map=lambda beta: link_chain_start(n, beta)),
    example=("--h 0.001 --T 2", "the link ends hit the floor, then rest"))


def _cradle_symbolic(pivot):
    """The builder of a cradle of N balls (mass m, radius r) hanging on massless strings of length L
    from pivots at `pivot` (revolute joints to the ground, angles theta_i from the downward vertical);
    neighbours are circle contacts, restitution e."""
    def build(x):
        from ..mechanics.bodies import Body, CircleContact, Joint
        from .symbolic import mechanism

        n = x.k
        bodies = [Body(f"ball{i}", "m", 0, (0, "-L"), radius="r") for i in range(1, n + 1)]
        joints = [Joint("revolute", f"ball{i}", at=(pivot.format(i=i), 0), coordinate=f"theta{i}")
                  for i in range(1, n + 1)]
        contacts = [CircleContact(f"c{i}", (f"ball{i}", f"ball{i + 1}"), restitution="e") for i in range(1, n)]
        return mechanism(x.d, bodies, joints, contacts)
    return build


def _cradle_start(p, n):
    q0 = np.zeros(n)
    q0[0] = -0.3
    return dict(default_q0=q0, default_p0=np.zeros(n),
                ic_map=lambda beta: (np.array([-beta] + [0.0] * (n - 1)), np.zeros(n)))


def _cradle_coordinates(n):
    return tuple((f"theta{i}", "rad", f"angle of string {i} from the downward vertical") for i in range(1, n + 1))


def _cradle_params(gap):
    return ({"m": Param(0.1, "kg", "mass of each ball"),
             "r": Param(0.05, "m", "ball radius" + (" (pivots 2r + gap apart)" if gap else " (pivots 2r apart)"))}
            | ({"gap": Param(0.001, "m", "distance between neighbouring balls at rest")} if gap else {})
            | {"L": Param(1.0, "m", "string length"), "g": _G, "e": E})


def _cradle_constraint(n):
    return f"{n - 1} circle contacts c1..c{n - 1}: |C_i - C_(i+1)| - 2 r >= 0 (declared by bodies)"


# Ball 1 released from theta1 = -beta, the others hanging at rest, touching: Moreau's law treats the
# touching row as one simultaneous impact (docs/derivations/contacts.md 1.6); `cradle_gap` hangs them apart.
CRADLE = Scene(
    "cradle", size=5,
    description=lambda n: (f"Newton's cradle of {n} touching balls (radius r, strings of length L, pivots 2r apart), "
                           "circle contacts between neighbours, restitution e; ball 1 released from theta1 = -0.3: "
                           "Moreau's simultaneous impact law on the touching row (balls 2..N move on together; the "
                           f"swing-out of a real cradle: cradle_gap_{n}) (declared by bodies)"),
    coordinates=_cradle_coordinates, params=_cradle_params(False), constraint=_cradle_constraint,
    ic_text="ball 1 released from theta1 = -beta, the others hanging at rest, touching",
    default_text="theta1 = -0.3, the others 0, at rest",
    restitution=EVERY_CONTACT_E, symbolic=_cradle_symbolic("2*r*{i}"), start=_cradle_start,
    example=("--h 0.001 --T 2", "ball 1 hits the touching row: Moreau's simultaneous law, balls 2..N move on together"))

# the balls hung `gap` apart (pivots 2r + gap apart): each impact is one pair, in sequence down the row,
# and the last ball swings out (the cradle of the desk toy)
CRADLE_GAP = Scene(
    "cradle_gap", size=5,
    description=lambda n: (f"Newton's cradle of {n} balls hung with small gaps (pivots 2r + gap apart), restitution e; "
                           "ball 1 released from theta1 = -0.3: the impacts run down the row one pair at a time and "
                           "the last ball swings out (declared by bodies)"),
    coordinates=_cradle_coordinates, params=_cradle_params(True), constraint=_cradle_constraint,
    ic_text="ball 1 released from theta1 = -beta, the others hanging at rest, gap apart",
    default_text="theta1 = -0.3, the others 0, at rest",
    restitution=EVERY_CONTACT_E, symbolic=_cradle_symbolic("(2*r + gap)*{i}"), start=_cradle_start,
    example=("--h 0.001 --T 2", "pairwise impacts down the row, the last ball swings out"))

SCENES = (BALL_IN_BOX, NEWTON_CRADLE, DOUBLE_PENDULUM_WALLS, ROCKING_BLOCK, LINK_CHAIN, CRADLE, CRADLE_GAP)
