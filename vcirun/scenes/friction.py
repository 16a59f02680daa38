"""Scenes with Coulomb friction (vcirun.mechanics.friction), each with its closed form in
vcirun.scenes.friction_oracles (derivations: docs/derivations/friction.md, "Closed forms"):

- `spinning_ball`: a ball dropped with spin on a floor (Capobianco et al. 2021, section 10.1);
- `incline`: a block (a point mass) on an incline, launched uphill or released at rest;
- `coulomb_oscillator`: a block on a floor attached to a spring, Coulomb-damped;
- `pushed_block`: a block on a floor pushed by a growing force c t (sticks, then slides);
- `rocking_block_friction`: a block rocking on its corners without sliding (Housner), released at
  rest on one corner;
- `painleve_rod`: a uniform rod sliding on one end (Painleve's paradox for mu > 4/3);
- `link_chain_friction`: a chain of links falling on a floor with friction at every link end;
- `compass_gait_stance`: the compass gait's stance phase with the stance foot a frictional contact
  (a floating base) instead of a pin: where it sticks it is the gait of the built-in `compass_gait`.

Each returns a MechanicalSystem whose parameters are symbols (mu, mu_s, ... overridable at run time
through params=); the start state is built from the arguments (exactly on the contact surface where
the scene starts held)."""
from __future__ import annotations

import numpy as np
import sympy as sp

from ..mechanics.bodies import Body, Joint, PointContact, planar_system
from ..mechanics.system import Constraint, MechanicalSystem
from .data import (
    block_corner,
    coulomb_oscillator_start,
    incline_start,
    link_chain_start,
    painleve_rod_start,
    rocking_block_friction_start,
    spinning_ball_start,
)

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


def spinning_ball(w0=50.0, *, m=1.0, R=0.1, mu=0.2, g=9.81, h=1.0, v0=0.0) -> MechanicalSystem:
    """A ball (mass m, radius R, inertia 2/5 m R^2) on a free planar joint (x, y: its centre, phi: its
    angle), released at centre height h with horizontal velocity v0 and spin phidot = w0 onto the floor
    y = 0: restitution 0, friction mu (the rim's material point slides at xdot + R phidot). Defaults:
    Capobianco et al. 2021, section 10.1."""
    q0, qdot0 = spinning_ball_start(w0, h, v0)
    s = planar_system("spinning_ball", [Body("ball", "m", "2*m*R**2/5", radius="R")],
                      [Joint("free", "ball", coordinates=("x", "y", "phi"))],
                      [PointContact("floor", "ball", radius="R", restitution=0, friction="mu")],
                      params={"m": m, "R": R, "mu": mu, "g": g}, gravity="g", q0=q0.tolist(),
                      qdot0=qdot0.tolist(),
                      description="a ball dropped with spin on a floor, plastic impact with Coulomb friction "
                                  "(Capobianco et al. 2021, section 10.1)")
    return s


def incline(theta=0.3, *, mu=0.2, mu_s=None, v0=0.0, m=1.0, g=9.81) -> MechanicalSystem:
    """A point mass (x, y) on the line through the origin with normal (-sin theta, cos theta): phi =
    -sin(theta) x + cos(theta) y, restitution 0, friction mu, static friction mu_s (default mu), the
    slip row (cos theta, sin theta) (up the slope). Starts at the origin with velocity v0 up the slope
    (held from the start). Parameters m, g, theta, mu, mu_s."""
    mu_s = mu if mu_s is None else mu_s
    x, y = sp.symbols("x y")
    M_, g_, th = sp.symbols("m g theta")
    c = Constraint("slope", -sp.sin(th) * x + sp.cos(th) * y, sp.Integer(0), friction=sp.Symbol("mu"),
                   static_friction=sp.Symbol("mu_s"), slip=(sp.cos(th), sp.sin(th)))
    s = MechanicalSystem(name="incline", q=[x, y], params={"m": m, "g": g, "theta": theta, "mu": mu, "mu_s": mu_s},
                         M=sp.eye(2) * M_, V=M_ * g_ * y, constraints=[c],
                         description="a block on an incline of angle theta with Coulomb friction mu, mu_s")
    s.default_q0, qdot0 = incline_start(theta, v0)
    s.default_p0 = m * qdot0
    return s


def coulomb_oscillator(x0=1.0, *, v0=0.0, m=1.0, k=10.0, mu=0.1, mu_s=None, g=9.81) -> MechanicalSystem:
    """A block (x, y) on the floor y = 0 attached to a spring k at x = 0: V = k x^2/2 + m g y,
    restitution 0, friction mu, static friction mu_s (default mu), slip row (1, 0). Starts on the floor
    at (x0, 0) with velocity v0 (held from the start)."""
    mu_s = mu if mu_s is None else mu_s
    x, y = sp.symbols("x y")
    M_, g_, k_ = sp.symbols("m g k")
    c = Constraint("floor", y, sp.Integer(0), friction=sp.Symbol("mu"), static_friction=sp.Symbol("mu_s"),
                   slip=(sp.Integer(1), sp.Integer(0)))
    s = MechanicalSystem(name="coulomb_oscillator", q=[x, y],
                         params={"m": m, "k": k, "g": g, "mu": mu, "mu_s": mu_s},
                         M=sp.eye(2) * M_, V=k_ * x ** 2 / 2 + M_ * g_ * y, constraints=[c],
                         description="a block on a floor attached to a spring, Coulomb friction mu, mu_s")
    s.default_q0, qdot0 = coulomb_oscillator_start(x0, v0)
    s.default_p0 = m * qdot0
    return s


def pushed_block(*, c=2.0, mu=0.3, mu_s=0.5, m=1.0, g=9.81) -> MechanicalSystem:
    """A block (x, y) at rest on the floor y = 0, pushed along it by the generalized force (c t, 0):
    restitution 0, friction mu, static friction mu_s; the slip row (1, 0)."""
    x, y, t = sp.symbols("x y t")
    M_, g_, c_ = sp.symbols("m g c")
    cons = Constraint("floor", y, sp.Integer(0), friction=sp.Symbol("mu"), static_friction=sp.Symbol("mu_s"),
                      slip=(sp.Integer(1), sp.Integer(0)))
    s = MechanicalSystem(name="pushed_block", q=[x, y], params={"m": m, "g": g, "c": c, "mu": mu, "mu_s": mu_s},
                         M=sp.eye(2) * M_, V=M_ * g_ * y, constraints=[cons], forcing=sp.Matrix([c_ * t, 0]), t=t,
                         description="a block on a floor pushed by a growing force c t, Coulomb friction mu, mu_s")
    s.default_q0, s.default_p0 = np.zeros(2), np.zeros(2)
    return s


def rocking_block_friction(theta0=0.1, *, a=1.0, b=0.4, m=1.0, g=9.81, mu=0.8, mu_s=None) -> MechanicalSystem:
    """A rectangular block (height a, width b, mass m, inertia m (a^2 + b^2)/12) on a free planar joint
    (x, y, theta of its centre), its two lower corners point contacts with the floor y = 0: plastic
    (restitution 0), friction mu, static friction mu_s (default mu). Starts at rest on one corner at the
    tilt theta0 (the left corner for theta0 > 0), which lies exactly on the floor: Housner's rocking
    (vcirun.scenes.friction_oracles.housner_rocking) while the corners stick."""
    mu_s = mu if mu_s is None else mu_s
    q0 = rocking_block_friction_start(theta0, a, b)[0]
    s = planar_system("rocking_block_friction", [Body("block", "m", "m*(a**2 + b**2)/12")],
                      [Joint("free", "block", coordinates=("x", "y", "theta"))],
                      [PointContact("left", "block", ("-b/2", "-a/2"), restitution=0, friction="mu",
                                    static_friction="mu_s"),
                       PointContact("right", "block", ("b/2", "-a/2"), restitution=0, friction="mu",
                                    static_friction="mu_s")],
                      params={"m": m, "a": a, "b": b, "g": g, "mu": mu, "mu_s": mu_s}, gravity="g",
                      q0=q0.tolist(),
                      description="a block rocking on its corners without sliding (Housner), plastic corner "
                                  "impacts, Coulomb friction mu, mu_s")
    return s


def painleve_rod(theta0=0.5, *, xdot0=-1.0, thetadot0=0.0, mu=1.5, mu_s=None, m=1.0, l=1.0, g=9.81) -> MechanicalSystem:
    """A uniform rod (length 2 l, mass m, inertia m l^2 / 3) on a free planar joint (x, y, theta of its
    centre), its end A = C - l (cos theta, sin theta) on the floor y = 0: restitution 0, friction mu,
    static friction mu_s (default mu). Starts with A on the floor (held) at the tilt theta0, centre
    velocity (xdot0, l cos(theta0) thetadot0) (the end's normal velocity zero) and angular velocity
    thetadot0: the end slides at xdot0 + l sin(theta0) thetadot0. Painleve's B (friction_oracles.painleve_B)
    decides the held problem."""
    mu_s = mu if mu_s is None else mu_s
    q0, qdot0 = painleve_rod_start(theta0, xdot0, thetadot0, l)
    s = planar_system("painleve_rod", [Body("rod", "m", "m*l**2/3")],
                      [Joint("free", "rod", coordinates=("x", "y", "theta"))],
                      [PointContact("end", "rod", ("-l", 0), restitution=0, friction="mu", static_friction="mu_s")],
                      params={"m": m, "l": l, "g": g, "mu": mu, "mu_s": mu_s}, gravity="g", q0=q0.tolist(),
                      qdot0=qdot0.tolist(),
                      description="a uniform rod sliding on one end with Coulomb friction (Painleve's paradox "
                                  "for mu > 4/3)")
    return s


def link_chain_friction(n=5, *, m=0.2, l=0.3, g=9.81, e=0.3, mu=0.5, height=0.5) -> MechanicalSystem:
    """The link chain of vcirun.scenes.mechanisms.link_chain (N uniform links joined by revolute joints,
    the first on a free joint) with friction mu at every link end: falling on the floor y = 0, it no
    longer skates sideways."""
    n = int(n)
    bodies = [Body(f"link{i}", "m", "m*l**2/12", ("l/2", 0)) for i in range(1, n + 1)]
    joints = [Joint("free", "link1", coordinates=("x", "y", "theta1"))]
    joints += [Joint("revolute", f"link{i}", f"link{i - 1}", ("l", 0), f"theta{i}", absolute=True)
               for i in range(2, n + 1)]
    contacts = [PointContact("end0", "link1", restitution="e", friction="mu")]
    contacts += [PointContact(f"end{i}", f"link{i}", ("l", 0), restitution="e", friction="mu") for i in range(1, n + 1)]
    return planar_system(f"link_chain_friction_{n}", bodies, joints, contacts,
                         params={"m": m, "l": l, "g": g, "e": e, "mu": mu}, gravity="g",
                         q0=link_chain_start(n, height)[0].tolist(),
                         description=f"chain of {n} links falling on the floor y = 0 with friction mu at the link "
                                     "ends")


def compass_gait_stance(theta_s, theta_ns, thetadot_s=0.0, thetadot_ns=0.0, *, mu=1.0, mu_s=None, m=5.0, mH=10.0,
                        a=0.5, b=0.5, gamma=float(np.deg2rad(3.0)), g=9.81) -> MechanicalSystem:
    """The compass gait of vcirun.scenes (Goswami et al.: point masses m at a from each foot, mH at the
    hip, legs a + b, a slope gamma) with its stance foot a point contact on the slope (restitution 0,
    friction mu, static friction mu_s, default mu) instead of a pin: the stance leg on a free joint (x, y
    of its foot, its absolute angle theta_s + gamma from the vertical; the stance and hip masses are one
    body), the swing leg on a revolute joint at the hip (its absolute angle theta_ns + gamma). The swing
    foot is no contact (the stance phase only). Starts with the foot at the origin, at rest on the slope,
    the legs at (theta_s, theta_ns) with rates (thetadot_s, thetadot_ns): while the foot sticks this is
    the pinned gait's stance phase, and the held forces at the foot are its ground reaction."""
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
