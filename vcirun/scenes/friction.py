"""Scenes with Coulomb friction (vcirun.mechanics.friction), each with its closed form in
vcirun.scenes.friction_oracles (derivations: docs/derivations/friction.md, "Closed forms").

The built-in ones, each declared once (vcirun.scenes.scene.Scene):
- `spinning_ball`: a ball dropped with spin on a floor (Capobianco et al. 2021, section 10.1);
- `incline`: a block (a point mass) on an incline, launched uphill or released at rest;
- `coulomb_oscillator`: a block on a floor attached to a spring, Coulomb-damped;
- `rocking_block_friction`: a block rocking on its corners without sliding (Housner), released at
  rest on one corner;
- `painleve_rod`: a uniform rod sliding on one end (Painleve's paradox for mu > 4/3);
- `link_chain_friction`: a chain of links falling on a floor with friction at every link end.

Their constructors (`spinning_ball(w0, ...)`, `incline(theta, ...)`, ...) build the same systems from
other start arguments, at the scenes' parameter defaults unless overridden; `mu_s` follows `mu` unless
given. Two more constructors are no built-in scene: `pushed_block` (a block pushed by a growing force
c t) and `compass_gait_stance` (the compass gait's stance phase with the stance foot a frictional
contact, a floating base, instead of a pin: where it sticks it is the gait of the built-in `compass_gait`).

Each returns a MechanicalSystem whose parameters are symbols (mu, mu_s, ... overridable at run time
through params=); the start state is built from the arguments (exactly on the contact surface where
the scene starts held). No sympy at import: the builders import it when they run."""
from __future__ import annotations

import math

import numpy as np

from .contacts import LINK_CHAIN_PARAMS, BLOCK_COORDINATES, link_chain_coordinates, link_chain_parts, link_chain_start
from .scene import EVERY_CONTACT_E, Param, Scene
from .walkers import COMPASS_GAIT

__all__ = [
    "block_corner",
    "compass_gait_stance",
    "coulomb_oscillator",
    "incline",
    "link_chain_friction",
    "painleve_rod",
    "pushed_block",
    "rocking_block_friction",
    "spinning_ball",
]

_G = Param(9.81, "m/s^2", "gravitational acceleration")


def _mu(value):
    return Param(value, "", "Coulomb (kinetic) friction coefficient")


def _mu_s(value):
    return Param(value, "", "static friction coefficient (>= mu)")


def _with_mu_s(params: dict) -> dict:
    """A constructor's parameters: mu_s follows mu unless given."""
    if params.get("mu_s") is None:
        params.pop("mu_s", None)
        if "mu" in params:
            params["mu_s"] = params["mu"]
    return params


# --- the start states (sympy-free: the scenes' initial-condition maps and the constructors) ----------

def block_corner(theta, a, b, side):
    """The corner (side b/2, -a/2) of a block at angle theta, relative to its centre."""
    cx, cy = side * b / 2.0, -a / 2.0
    return cx * math.cos(theta) - cy * math.sin(theta), cx * math.sin(theta) + cy * math.cos(theta)


def spinning_ball_start(w0, h=1.0, v0=0.0):
    """(q0, qdot0) of the spinning ball: centre at height h, horizontal velocity v0, spin w0."""
    return np.array([0.0, float(h), 0.0]), np.array([float(v0), 0.0, float(w0)])


def incline_start(theta, v0=0.0):
    """(q0, qdot0) of the block on the incline: at the origin (on the slope), velocity v0 up the slope."""
    return np.zeros(2), float(v0) * np.array([math.cos(theta), math.sin(theta)])


def coulomb_oscillator_start(x0=1.0, v0=0.0):
    """(q0, qdot0) of the Coulomb oscillator: on the floor at x0 with velocity v0."""
    return np.array([float(x0), 0.0]), np.array([float(v0), 0.0])


def rocking_block_friction_start(theta0, a, b):
    """(q0, qdot0) of the block at rest on one corner at the tilt theta0 (the left corner for theta0 >
    0), that corner exactly on the floor y = 0."""
    rx, ry = block_corner(theta0, a, b, -1 if theta0 > 0 else 1)
    return np.array([-rx, -ry, float(theta0)]), np.zeros(3)


def painleve_rod_start(theta0, xdot0, thetadot0, l):
    """(q0, qdot0) of the rod with its end A on the floor at the tilt theta0: centre velocity (xdot0,
    l cos(theta0) thetadot0) (A's normal velocity zero), angular velocity thetadot0."""
    return (np.array([0.0, l * math.sin(theta0), float(theta0)]),
            np.array([float(xdot0), l * math.cos(theta0) * thetadot0, float(thetadot0)]))


# --- the spinning ball --------------------------------------------------------------------------------

def _spinning_ball_symbolic(x):
    """A ball (mass m, radius R, inertia 2/5 m R^2) on a free planar joint (x, y: its centre, phi: its
    angle) above the floor y = 0: restitution 0, friction mu (the rim's material point slides at xdot +
    R phidot)."""
    from ..mechanics.bodies import Body, Joint, PointContact
    from .symbolic import mechanism

    return mechanism(x.d, [Body("ball", "m", "2*m*R**2/5", radius="R")],
                     [Joint("free", "ball", coordinates=tuple(map(str, x.q)))],
                     [PointContact("floor", "ball", radius="R", restitution=0, friction="mu")], **x.start)


SPINNING_BALL = Scene(
    "spinning_ball",
    description="ball (radius R, inertia 2/5 m R^2) dropped from centre height 1 with spin beta onto the "
                "floor y = 0: plastic impact with Coulomb friction mu (Capobianco et al. 2021, 10.1); the "
                "contact sticks at impact iff (2/7) R beta <= mu v_n, else it slides, then rolls "
                "(declared by bodies)",
    coordinates=(("x", "m", "horizontal position of the centre"), ("y", "m", "height of the centre"),
                 ("phi", "rad", "angle of the ball")),
    params={"m": Param(1.0, "kg", "mass"), "R": Param(0.1, "m", "radius"), "mu": _mu(0.2), "g": _G},
    constraint="1 contact: the rim above the floor, y - R >= 0, plastic, with friction (the slip velocity xdot + "
               "R phidot includes the spin)",
    ic_text="dropped from centre height 1, at rest but for the spin phidot = beta",
    default_text="beta = 50 (slides through the impact; beta = 10 sticks)",
    symbolic=_spinning_ball_symbolic,
    start=lambda p: dict(ic_map=lambda beta: spinning_ball_start(beta), default_beta=50.0),
    example=("--h 0.001 --T 1", "slides through the impact at t = 0.4284, rolls from t = 0.7281 "
                                "(slip -> stick); --beta 10 sticks at the impact"))


def spinning_ball(w0=50.0, *, h=1.0, v0=0.0, **params):
    """The spinning ball released at centre height h with horizontal velocity v0 and spin phidot = w0
    (defaults: Capobianco et al. 2021, section 10.1)."""
    q0, qdot0 = spinning_ball_start(w0, h, v0)
    return SPINNING_BALL.constructed(start=dict(q0=q0.tolist(), qdot0=qdot0.tolist()), **params)


# --- the block on an incline and the Coulomb oscillator (point masses) -------------------------------

def _incline_symbolic(x):
    """A point mass (x, y) on the line through the origin with normal (-sin theta, cos theta): phi =
    -sin(theta) x + cos(theta) y, restitution 0, friction mu, static friction mu_s, the slip row (cos
    theta, sin theta) (up the slope)."""
    import sympy as sp

    from ..mechanics.drawing import Drawing
    from .symbolic import Constraint, MechanicalSystem

    (qx, qy), p = x.q, x.p
    th = p.theta
    c = Constraint("slope", -sp.sin(th) * qx + sp.cos(th) * qy, sp.Integer(0), friction=p.mu,
                   static_friction=p.mu_s, slip=(sp.cos(th), sp.sin(th)))
    s = MechanicalSystem(name=x.d.name, q=[qx, qy], params=x.d.params, M=sp.eye(2) * p.m, V=p.m * p.g * qy,
                         constraints=[c], description=x.d.description)
    # the drawing: the mass on the slope, the line through the origin with normal (-sin theta, cos theta)
    s.drawing = Drawing(q=[qx, qy], points={"mass": (qx, qy)}, dots=["mass"],
                        lines=[((0, 0), (-sp.sin(th), sp.cos(th)))], contacts=["mass"]).check(
        f"scene {x.d.name} drawing")
    return s


INCLINE = Scene(
    "incline",
    description="block (a point mass) on an incline of angle theta, launched uphill at beta m/s with "
                "Coulomb friction mu: it stops, then sticks if tan theta <= mu_s, else slides back",
    coordinates=(("x", "m", "horizontal position"), ("y", "m", "height")),
    params={"m": Param(1.0, "kg", "mass"), "g": _G, "theta": Param(0.3, "rad", "slope angle"), "mu": _mu(0.2),
            "mu_s": _mu_s(0.2)},
    constraint="1 contact: -sin(theta) x + cos(theta) y >= 0 (the slope through the origin), plastic, with friction "
               "along (cos theta, sin theta)",
    ic_text="at the origin, launched up the slope at beta m/s",
    default_text="beta = 2 (stops at t = 0.419 s, then slides back: tan theta > mu_s)",
    symbolic=_incline_symbolic,
    start=lambda p: dict(ic_map=lambda beta, p: incline_start(p["theta"], beta), ic_map_params=True,
                         default_beta=2.0),
    example=("--h 0.01 --T 1", "stops at t = 0.419 s, slides back (slip reversed); --param mu_s=0.4 sticks"))


def incline(theta=None, *, v0=0.0, **params):
    """The block on the incline of angle theta, starting at the origin with velocity v0 up the slope
    (held from the start)."""
    if theta is not None:
        params["theta"] = theta
    s = INCLINE.constructed(**_with_mu_s(params))
    s.default_q0, qdot0 = incline_start(s.params["theta"], v0)
    s.default_p0 = s.params["m"] * qdot0
    return s


def _coulomb_oscillator_symbolic(x):
    """A block (x, y) on the floor y = 0 attached to a spring k at x = 0: V = k x^2/2 + m g y,
    restitution 0, friction mu, static friction mu_s, slip row (1, 0)."""
    import sympy as sp

    from ..mechanics.drawing import Drawing
    from .symbolic import Constraint, MechanicalSystem

    (qx, qy), p = x.q, x.p
    c = Constraint("floor", qy, sp.Integer(0), friction=p.mu, static_friction=p.mu_s,
                   slip=(sp.Integer(1), sp.Integer(0)))
    s = MechanicalSystem(name=x.d.name, q=[qx, qy], params=x.d.params, M=sp.eye(2) * p.m,
                         V=p.k * qx ** 2 / 2 + p.m * p.g * qy, constraints=[c], description=x.d.description)
    # the drawing: the block on the floor, the spring from its rest point x = 0 (its length the extension)
    pts = {"rest": (sp.Integer(0), sp.Rational(1, 10)), "block": (qx, qy + sp.Rational(1, 10)), "foot": (qx, qy)}
    s.drawing = Drawing(q=[qx, qy], points=pts, segments=[("rest", "block")], dots=["block"],
                        lines=[((0, 0), (0, 1))], contacts=["foot"]).check(f"scene {x.d.name} drawing")
    return s


COULOMB_OSCILLATOR = Scene(
    "coulomb_oscillator",
    description="block on the floor y = 0 on a spring k to x = 0, released at x = beta: Coulomb friction "
                "mu takes 2 mu m g / k of amplitude each half period pi sqrt(m/k); it sticks at the first "
                "turning point with |x| <= mu_s m g / k",
    coordinates=(("x", "m", "position along the floor (the spring's rest point x = 0)"),
                 ("y", "m", "height above the floor")),
    params={"m": Param(1.0, "kg", "mass"), "k": Param(10.0, "N/m", "spring stiffness"), "g": _G, "mu": _mu(0.1),
            "mu_s": _mu_s(0.1)},
    constraint="1 contact: the floor y >= 0, plastic, with friction along x",
    ic_text="on the floor at x = beta, at rest", default_text="beta = 1 (five half swings, then it sticks)",
    symbolic=_coulomb_oscillator_symbolic,
    start=lambda p: dict(ic_map=lambda beta: coulomb_oscillator_start(beta), default_beta=1.0),
    example=("--h 0.01 --T 6", "four slip reversals, sticks at t = 4.97 s"))


def coulomb_oscillator(x0=1.0, *, v0=0.0, **params):
    """The Coulomb oscillator starting on the floor at (x0, 0) with velocity v0 (held from the start)."""
    s = COULOMB_OSCILLATOR.constructed(**_with_mu_s(params))
    s.default_q0, qdot0 = coulomb_oscillator_start(x0, v0)
    s.default_p0 = s.params["m"] * qdot0
    return s


def pushed_block(*, c=2.0, mu=0.3, mu_s=0.5, m=1.0, g=9.81):
    """A block (x, y) at rest on the floor y = 0, pushed along it by the generalized force (c t, 0):
    restitution 0, friction mu, static friction mu_s; the slip row (1, 0)."""
    import sympy as sp

    from .symbolic import Constraint, MechanicalSystem

    x, y, t = sp.symbols("x y t")
    M_, g_, c_ = sp.symbols("m g c")
    cons = Constraint("floor", y, sp.Integer(0), friction=sp.Symbol("mu"), static_friction=sp.Symbol("mu_s"),
                      slip=(sp.Integer(1), sp.Integer(0)))
    s = MechanicalSystem(name="pushed_block", q=[x, y], params={"m": m, "g": g, "c": c, "mu": mu, "mu_s": mu_s},
                         M=sp.eye(2) * M_, V=M_ * g_ * y, constraints=[cons], forcing=sp.Matrix([c_ * t, 0]), t=t,
                         description="a block on a floor pushed by a growing force c t, Coulomb friction mu, mu_s")
    s.default_q0, s.default_p0 = np.zeros(2), np.zeros(2)
    return s


# --- the rocking block with friction ------------------------------------------------------------------

def _rocking_block_friction_symbolic(x):
    """A rectangular block (height a, width b, mass m, inertia m (a^2 + b^2)/12) on a free planar joint
    (x, y, theta of its centre), its two lower corners point contacts with the floor y = 0: plastic
    (restitution 0), friction mu, static friction mu_s. Released at rest on one corner: Housner's
    rocking (vcirun.scenes.friction_oracles.housner_rocking) while the corners stick."""
    from ..mechanics.bodies import Body, Joint, PointContact
    from .symbolic import mechanism

    corners = (("-b/2", "-a/2"), ("b/2", "-a/2"), ("b/2", "a/2"), ("-b/2", "a/2"))   # drawn as the rectangle
    return mechanism(x.d, [Body("block", "m", "m*(a**2 + b**2)/12", outline=corners)],
                     [Joint("free", "block", coordinates=tuple(map(str, x.q)))],
                     [PointContact("left", "block", ("-b/2", "-a/2"), restitution=0, friction="mu",
                                   static_friction="mu_s"),
                      PointContact("right", "block", ("b/2", "-a/2"), restitution=0, friction="mu",
                                   static_friction="mu_s")], **x.start)


ROCKING_BLOCK_FRICTION = Scene(
    "rocking_block_friction",
    description="Housner's rocking block (width b, height a) released at rest on a corner at the tilt "
                "beta: it rocks on its corners without sliding (friction mu, mu_s), plastic corner impacts, "
                "the angular velocity times 1 - 3/2 sin^2 alpha (alpha = atan(b/a)) at each (declared by "
                "bodies)",
    coordinates=BLOCK_COORDINATES,
    params={"m": Param(1.0, "kg", "mass"), "a": Param(1.0, "m", "block height"), "b": Param(0.4, "m", "block width"),
            "g": _G, "mu": _mu(0.8), "mu_s": _mu_s(0.8)},
    constraint="2 contacts: the lower corners (-b/2, -a/2) and (b/2, -a/2) above the floor y = 0, plastic, with "
               "friction (declared by bodies)",
    ic_text="at rest on a corner at the tilt theta = beta (the left corner for beta > 0), that corner on the floor",
    default_text="beta = 0.1",
    symbolic=_rocking_block_friction_symbolic,
    start=lambda p: dict(ic_map=lambda beta, p: rocking_block_friction_start(beta, p["a"], p["b"]),
                         ic_map_params=True, default_beta=0.1),
    example=("--h 0.001 --T 1", "Housner's rocking: corner impacts at t = 0.2238, 0.551, 0.7995, 0.9919 s, "
                                "the corners sticking"))


def rocking_block_friction(theta0=0.1, **params):
    """The rocking block at rest on one corner at the tilt theta0 (the left corner for theta0 > 0),
    which lies exactly on the floor."""
    d = ROCKING_BLOCK_FRICTION.data(**_with_mu_s(params))
    q0 = rocking_block_friction_start(theta0, d.params["a"], d.params["b"])[0]
    return ROCKING_BLOCK_FRICTION.constructed(start=dict(q0=q0.tolist()), **params)


# --- Painleve's rod -----------------------------------------------------------------------------------

def _painleve_rod_symbolic(x):
    """A uniform rod (length 2 l, mass m, inertia m l^2 / 3) on a free planar joint (x, y, theta of its
    centre), its end A = C - l (cos theta, sin theta) on the floor y = 0: restitution 0, friction mu,
    static friction mu_s. Painleve's B (friction_oracles.painleve_B) decides the held problem."""
    from ..mechanics.bodies import Body, Joint, PointContact
    from .symbolic import mechanism

    return mechanism(x.d, [Body("rod", "m", "m*l**2/3")], [Joint("free", "rod", coordinates=tuple(map(str, x.q)))],
                     [PointContact("end", "rod", ("-l", 0), restitution=0, friction="mu", static_friction="mu_s")],
                     **x.start)


PAINLEVE_ROD = Scene(
    "painleve_rod",
    description="uniform rod (length 2 l) sliding on one end at 1 m/s from the tilt beta, friction mu: "
                "where B = 1 + 3 cos^2 theta - 3 mu sin theta cos theta <= 0 (mu > 4/3) the held contact "
                "has no unique force (Painleve's paradox) and the run ends with status painleve "
                "(declared by bodies)",
    coordinates=(("x", "m", "horizontal position of the rod's centre"), ("y", "m", "height of the rod's centre"),
                 ("theta", "rad", "angle of the rod from the floor")),
    params={"m": Param(1.0, "kg", "mass"), "l": Param(1.0, "m", "half length"), "g": _G, "mu": _mu(1.5),
            "mu_s": _mu_s(1.5)},
    constraint="1 contact: the lower end C - l (cos theta, sin theta) above the floor y = 0, plastic, with friction "
               "(declared by bodies)",
    ic_text="its end on the floor at the tilt theta = beta, the centre moving at xdot = -1 m/s, not turning",
    default_text="beta = 0.9 (B < 0 there for mu = 1.5: status painleve)",
    symbolic=_painleve_rod_symbolic,
    start=lambda p: dict(ic_map=lambda beta, p: painleve_rod_start(beta, -1.0, 0.0, p["l"]), ic_map_params=True,
                         default_beta=0.9),
    example=("--h 0.001 --T 0.5", "B < 0 at the start: the run ends with status painleve (exit code 1)"))


def painleve_rod(theta0=0.5, *, xdot0=-1.0, thetadot0=0.0, **params):
    """The rod with its end A on the floor (held) at the tilt theta0, centre velocity (xdot0, l
    cos(theta0) thetadot0) (the end's normal velocity zero) and angular velocity thetadot0: the end
    slides at xdot0 + l sin(theta0) thetadot0."""
    d = PAINLEVE_ROD.data(**_with_mu_s(params))
    q0, qdot0 = painleve_rod_start(theta0, xdot0, thetadot0, d.params["l"])
    return PAINLEVE_ROD.constructed(start=dict(q0=q0.tolist(), qdot0=qdot0.tolist()), **params)


# --- the link chain with friction ---------------------------------------------------------------------

def _link_chain_friction_symbolic(x):
    """The link chain of vcirun.scenes.contacts.LINK_CHAIN with friction mu at every link end: falling on
    the floor y = 0, it no longer skates sideways."""
    from .symbolic import mechanism

    return mechanism(x.d, *link_chain_parts(x.k, friction="mu"), **x.start)


LINK_CHAIN_FRICTION = Scene(
    "link_chain_friction", size=5,
    description=lambda n: (f"the chain of {n} links of link_chain_{n} with Coulomb friction mu at the link ends: "
                           "it lands, its ends stick and slip, it does not skate (declared by bodies)"),
    coordinates=link_chain_coordinates, params=LINK_CHAIN_PARAMS | {"mu": _mu(0.5)},
    constraint=lambda n: (f"{n + 1} contacts end0..end{n}: the link ends above the floor y = 0, with friction mu "
                          "(declared by bodies)"),
    ic_text="height of the first end y = beta, tilted zigzag, at rest",
    default_text="y = 0.5, theta_k = 0.3 (-1)^k + 0.05, at rest",
    restitution=EVERY_CONTACT_E, symbolic=_link_chain_friction_symbolic,
    start=lambda p, n: dict(default_q0=link_chain_start(n, 0.5)[0], default_p0=link_chain_start(n, 0.5)[1],
                            ic_map=lambda beta: link_chain_start(n, beta)),
    example=("--h 0.001 --T 1", "the link ends hit the floor, stick and slip"))


def link_chain_friction(n=5, *, height=0.5, **params):
    """The chain of n links with friction, its first end at the height `height`."""
    return LINK_CHAIN_FRICTION.constructed(n, start=dict(q0=link_chain_start(n, height)[0].tolist()), **params)


# --- the compass gait's stance phase on a frictional foot ---------------------------------------------

def compass_gait_stance(theta_s, theta_ns, thetadot_s=0.0, thetadot_ns=0.0, *, mu=1.0, mu_s=None, **walker):
    """The compass gait of vcirun.scenes.walkers (Goswami et al.: point masses m at a from each foot, mH at
    the hip, legs a + b, a slope gamma; `walker` overrides its parameters) with its stance foot a point
    contact on the slope (restitution 0, friction mu, static friction mu_s, default mu) instead of a pin:
    the stance leg on a free joint (x, y of its foot, its absolute angle theta_s + gamma from the
    vertical; the stance and hip masses are one body), the swing leg on a revolute joint at the hip (its
    absolute angle theta_ns + gamma). The swing foot is no contact (the stance phase only). Starts with
    the foot at the origin, at rest on the slope, the legs at (theta_s, theta_ns) with rates
    (thetadot_s, thetadot_ns): while the foot sticks this is the pinned gait's stance phase, and the held
    forces at the foot are its ground reaction."""
    from ..mechanics.bodies import Body, Joint, PointContact, planar_system

    w = COMPASS_GAIT.data(**walker).params
    m, mH, a, b, gamma, g = (w[k] for k in ("m", "mH", "a", "b", "gamma", "g"))
    mu_s = mu if mu_s is None else mu_s
    l = a + b
    c = (m * a + mH * l) / (m + mH)                       # the stance body's centre of mass on the leg
    inertia = m * (a - c) ** 2 + mH * (l - c) ** 2
    params = {"m": m, "mH": mH, "a": a, "b": b, "g": g, "gamma": gamma, "mu": mu, "mu_s": mu_s}
    return planar_system(
        "compass_gait_stance",
        [Body("stance", m + mH, inertia, (0.0, c)), Body("swing", "m", 0, (0, "-b"))],
        [Joint("free", "stance", coordinates=("x", "y", "phi_s")),
         Joint("revolute", "swing", "stance", (0, "a + b"), "phi_ns", absolute=True)],
        [PointContact("foot", "stance", normal=("-sin(gamma)", "cos(gamma)"), restitution=0, friction="mu",
                      static_friction="mu_s")],
        params=params, gravity="g", q0=[0.0, 0.0, theta_s + gamma, theta_ns + gamma],
        qdot0=[0.0, 0.0, thetadot_s, thetadot_ns],
        description="the compass gait's stance phase with a frictional stance foot (a floating base)")


SCENES = (ROCKING_BLOCK_FRICTION, SPINNING_BALL, INCLINE, COULOMB_OSCILLATOR, PAINLEVE_ROD, LINK_CHAIN_FRICTION)
