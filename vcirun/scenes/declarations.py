"""Built-in scenes: the paper's vertical cart-pendulum, a double pendulum against a wall (Figure 1),
a harmonic oscillator against a wall (closed-form oracle), an n-link pendulum (scaling), a
linearly damped oscillator (forced DEL check), a bouncing ball with drag (impact accumulation), a
ball in a box, a line of balls and the double pendulum between walls; the mechanisms declared by
bodies and joints (rocking block, link chain, hanging cradle) are vcirun.scenes.mechanisms'; the
scenes with Coulomb friction (rocking_block_friction, spinning_ball, incline, coulomb_oscillator,
painleve_rod, link_chain_friction_K) are vcirun.scenes.friction's constructors.

The numeric parts of each scene (parameter defaults, initial-condition map, default state,
description) live in the sympy-free `vcirun.scenes.data`; this module adds the symbolic M, V, phi
and forcing."""
from __future__ import annotations

import functools

import sympy as sp

from . import data as sd
from . import friction, mechanisms
from ..mechanics.system import Constraint, MechanicalSystem


def _system(d: sd.SystemData, q, M, V, phi, draw=None, **kw) -> MechanicalSystem:
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


def _slope(u, v, gam):
    """World (x, y) of the point u along a slope descending to the right at angle gam, v along its normal."""
    return u * sp.cos(gam) + v * sp.sin(gam), -u * sp.sin(gam) + v * sp.cos(gam)


def _chain(angles, lengths, origin=(0, 0)):
    """Points of a chain of links at absolute angles from the downward vertical: [(x, y)] after each."""
    pts, (x, y) = [], origin
    for th, ell in zip(angles, lengths):
        x, y = x + ell * sp.sin(th), y - ell * sp.cos(th)
        pts.append((x, y))
    return pts


def cart_pendulum(**overrides) -> MechanicalSystem:
    """Section 5.1: cart of mass m1 on a vertical track, pendulum point mass m2 on a rod of length L.
    q = (y, theta); phi = y >= 0. Initial-condition family Xi(beta) = FL([beta, 0], [0, 3.5 - 0.18 beta])."""
    d = sd.cart_pendulum(**overrides)
    y, th = sp.symbols("y theta")
    m1, m2, L, g = sp.symbols("m1 m2 L g")
    M = sp.Matrix([[m1 + m2, m2 * L * sp.sin(th)], [m2 * L * sp.sin(th), m2 * L**2]])
    V = (m1 + m2) * g * y - m2 * g * L * sp.cos(th)
    w = L / 10
    draw = dict(points={"cart": (0, y), "bob": (L * sp.sin(th), y - L * sp.cos(th)), "c1": (-w, y), "c2": (w, y),
                        "c3": (w, y + 2 * w), "c4": (-w, y + 2 * w)},
                polygons=[("c1", "c2", "c3", "c4")], segments=[("cart", "bob")], dots=["bob"],
                lines=[((0, 0), (0, 1))], contacts=["cart"])
    return _system(d, [y, th], M, V, y, draw=draw)


def double_pendulum(**overrides) -> MechanicalSystem:
    """Planar double pendulum, absolute angles from the downward vertical, point masses at the link
    tips; the second tip cannot pass the vertical wall x = w: phi = w - (l1 sin th1 + l2 sin th2).
    The paper gives neither parameters nor the initial state of its Figure 1; these are our choice:
    unit masses and lengths, g = 9.81, wall at w = 1.2, released from rest at th = (-pi/2, -pi/2)
    (both links horizontal, pointing away from the wall). beta scales the initial angles."""
    d = sd.double_pendulum(**overrides)
    t1, t2 = sp.symbols("theta1 theta2")
    m1, m2, l1, l2, g, w = sp.symbols("m1 m2 l1 l2 g w")
    c = sp.cos(t1 - t2)
    M = sp.Matrix([[(m1 + m2) * l1**2, m2 * l1 * l2 * c], [m2 * l1 * l2 * c, m2 * l2**2]])
    V = -(m1 + m2) * g * l1 * sp.cos(t1) - m2 * g * l2 * sp.cos(t2)
    phi = w - (l1 * sp.sin(t1) + l2 * sp.sin(t2))
    p1, p2 = _chain([t1, t2], [l1, l2])
    draw = dict(points={"pivot": (0, 0), "tip1": p1, "tip2": p2}, segments=[("pivot", "tip1"), ("tip1", "tip2")],
                dots=["tip1", "tip2"], pivots=["pivot"], lines=[((w, 0), (-1, 0))], contacts=["tip2"])
    return _system(d, [t1, t2], M, V, phi, draw=draw)


def oscillator_wall(**overrides) -> MechanicalSystem:
    """1-DOF harmonic oscillator m xdd = -k x against a wall at x = -d: phi = x + d.
    Closed-form solution with elastic impacts (see vcirun.scenes.oracles.oscillator_wall_exact)."""
    d = sd.oscillator_wall(**overrides)
    x = sp.Symbol("x")
    m, k, dd = sp.symbols("m k d")
    draw = dict(points={"mass": (x, 0), "anchor": (2 * dd + 1, 0), "low": (-dd, -0.2), "high": (-dd, 0.2)},
                springs=[("anchor", "mass")], dots=["mass"], pivots=["anchor"], lines=[((-dd, 0), (1, 0))],
                contacts=["mass"])
    return _system(d, [x], sp.Matrix([[m]]), k * x**2 / 2, x + dd, draw=draw)


def damped_oscillator(**overrides) -> MechanicalSystem:
    """Linearly damped oscillator m xdd = -k x - c xd (forcing f = -c xd through the discrete
    Lagrange-d'Alembert principle); the wall x = -d is far away unless d is overridden."""
    d = sd.damped_oscillator(**overrides)
    x, xd = sp.Symbol("x"), sp.Symbol("x_dot")
    m, k, c, dd = sp.symbols("m k c d")
    draw = dict(points={"mass": (x, 0), "anchor": (2, 0), "low": (-1.5, -0.2)}, springs=[("anchor", "mass")],
                dots=["mass"], pivots=["anchor"], lines=[((-dd, 0), (1, 0))], contacts=["mass"])
    return _system(d, [x], sp.Matrix([[m]]), k * x**2 / 2, x + dd, qd=[xd], forcing=sp.Matrix([-c * xd]), draw=draw)


def bouncing_ball(**overrides) -> MechanicalSystem:
    """A ball of mass m above the floor y = 0 under gravity with linear air drag f = -c ydot (forced
    DEL) and elastic impacts: phi = y. With c > 0 the bounces shrink until impacts are denser than
    any grid (the accumulation case of the extremes study, vcirun.experiments.studies.contact); with
    c = 0 it bounces forever to the same height (closed form, vcirun.scenes.oracles.ball_exact).
    beta = drop height."""
    d = sd.bouncing_ball(**overrides)
    y, yd = sp.Symbol("y"), sp.Symbol("y_dot")
    m, g, c = sp.symbols("m g c")
    draw = dict(points={"ball": (0, y), "low": (-0.5, 0), "high": (0.5, 0)}, dots=["ball"],
                lines=[((0, 0), (0, 1))], contacts=["ball"])
    return _system(d, [y], sp.Matrix([[m]]), m * g * y, y, qd=[yd], forcing=sp.Matrix([-c * yd]), draw=draw)


def n_pendulum(n: int = 2, **overrides) -> MechanicalSystem:
    """n-link planar pendulum (absolute angles, unit point masses at the joints) whose tip cannot
    pass the wall x = w. Used to measure how symbolic and numeric cost grow with the dimension."""
    n = int(n)
    d = sd.n_pendulum(n, **overrides)
    th = sp.symbols(f"theta1:{n + 1}")
    ms = sp.symbols(f"m1:{n + 1}")
    ls = sp.symbols(f"l1:{n + 1}")
    g, w = sp.symbols("g w")
    tail = [sum(ms[k] for k in range(i, n)) for i in range(n)]  # mass outboard of joint i
    M = sp.Matrix(n, n, lambda i, j: tail[max(i, j)] * ls[i] * ls[j] * sp.cos(th[i] - th[j]))
    V = -g * sum(tail[i] * ls[i] * sp.cos(th[i]) for i in range(n))
    phi = w - sum(ls[i] * sp.sin(th[i]) for i in range(n))
    pts = _chain(th, ls)
    names = ["pivot"] + [f"joint{i + 1}" for i in range(n)]
    draw = dict(points={"pivot": (0, 0), **{names[i + 1]: pts[i] for i in range(n)}},
                segments=list(zip(names[:-1], names[1:])), dots=names[1:], pivots=["pivot"],
                lines=[((w, 0), (-1, 0))], contacts=[names[-1]])
    return _system(d, list(th), M, V, phi, draw=draw)


def ball_in_box(**overrides) -> MechanicalSystem:
    """A point mass m in the box 0 <= x <= width, 0 <= y <= height under gravity g, four
    walls in this order: floor y >= 0, ceiling height - y >= 0, left x >= 0, right width - x >= 0,
    each with restitution e (a parameter). Decoupled motion: closed form in vcirun.scenes.oracles."""
    d = sd.ball_in_box(**overrides)
    x, y = sp.symbols("x y")
    m, g, W, Hh, e = sp.symbols("m g width height e")
    cons = [Constraint("floor", y, e), Constraint("ceiling", Hh - y, e), Constraint("left", x, e),
            Constraint("right", W - x, e)]
    draw = dict(points={"ball": (x, y), "corner0": (0, 0), "corner1": (W, Hh)}, dots=["ball"],
                lines=[((0, 0), (0, 1)), ((0, Hh), (0, -1)), ((0, 0), (1, 0)), ((W, 0), (-1, 0))],
                contacts=["ball"] * 4)
    return _system(d, [x, y], sp.diag(m, m), m * g * y, None, constraints=cons, draw=draw)


def newton_cradle(n: int = 3, **overrides) -> MechanicalSystem:
    """n equal balls (mass m, diameter d) on a line, no gravity along it; contact i between
    balls i and i + 1: x_{i+1} - x_i - d >= 0, restitution e."""
    n = int(n)
    d = sd.newton_cradle(n, **overrides)
    xs = sp.symbols(f"x1:{n + 1}")
    m, dd, e = sp.symbols("m d e")
    cons = [Constraint(f"c{i + 1}{i + 2}", xs[i + 1] - xs[i] - dd, e) for i in range(n - 1)]
    pts = {f"ball{i + 1}": (xs[i], 0) for i in range(n)}
    pts.update({f"touch{i + 1}": ((xs[i] + xs[i + 1]) / 2, 0) for i in range(n - 1)})
    draw = dict(points=pts, circles=[(f"ball{i + 1}", dd / 2) for i in range(n)],
                contacts=[f"touch{i + 1}" for i in range(n - 1)])
    return _system(d, list(xs), m * sp.eye(n), sp.Integer(0), None, constraints=cons, draw=draw)


def double_pendulum_walls(**overrides) -> MechanicalSystem:
    """The double pendulum of Figure 1 whose second tip x = l1 sin th1 + l2 sin th2 stays
    between two walls: right w - x >= 0, left x + w >= 0, restitution e."""
    d = sd.double_pendulum_walls(**overrides)
    t1, t2 = sp.symbols("theta1 theta2")
    m1, m2, l1, l2, g, w, e = sp.symbols("m1 m2 l1 l2 g w e")
    c = sp.cos(t1 - t2)
    M = sp.Matrix([[(m1 + m2) * l1**2, m2 * l1 * l2 * c], [m2 * l1 * l2 * c, m2 * l2**2]])
    V = -(m1 + m2) * g * l1 * sp.cos(t1) - m2 * g * l2 * sp.cos(t2)
    xt = l1 * sp.sin(t1) + l2 * sp.sin(t2)
    p1, p2 = _chain([t1, t2], [l1, l2])
    draw = dict(points={"pivot": (0, 0), "tip1": p1, "tip2": p2}, segments=[("pivot", "tip1"), ("tip1", "tip2")],
                dots=["tip1", "tip2"], pivots=["pivot"], lines=[((w, 0), (-1, 0)), ((-w, 0), (1, 0))],
                contacts=["tip2", "tip2"])
    return _system(d, [t1, t2], M, V, None, constraints=[Constraint("right", w - xt, e), Constraint("left", xt + w, e)],
                   draw=draw)


def rimless_wheel(**overrides) -> MechanicalSystem:
    """The rimless wheel: q = theta, the stance spoke from the slope normal; L = m l^2 thetadot^2 / 2 -
    m g l cos(theta + gamma). The next spoke lands at theta = alpha (phi = alpha - theta: the angle
    left to its touchdown); the impact is plastic at the new foot, which keeps the angular momentum
    about it: theta+ = theta - 2 alpha, thetadot+ = cos(2 alpha) thetadot- (the declared reset)."""
    d = sd.rimless_wheel(**overrides)
    th, thd = sp.symbols("theta theta_dot")
    m, l, a, gam, g = sp.symbols("m l alpha gamma g")
    c = Constraint("spoke", a - th, reset_q=(th - 2 * a,), reset_qd=(sp.cos(2 * a) * thd,))
    # the drawing: the hub over the stance foot (the origin), every spoke, the slope; at each impact
    # the landing spoke's foot becomes the origin (advance)
    spokes = max(3, round(float(sp.pi) / float(d.params["alpha"])))
    hub = (l * sp.sin(th), l * sp.cos(th))
    pts = {"hub": _slope(*hub, gam)}
    for k in range(spokes):
        pts[f"foot{k}"] = _slope(hub[0] - l * sp.sin(th + 2 * a * k), hub[1] - l * sp.cos(th + 2 * a * k), gam)
    landing = _slope(hub[0] - l * sp.sin(th - 2 * a), hub[1] - l * sp.cos(th - 2 * a), gam)
    draw = dict(points=pts, segments=[("hub", f"foot{k}") for k in range(spokes)], dots=["hub"],
                lines=[((0, 0), (sp.sin(gam), sp.cos(gam)))], contacts=["foot0"], advance=landing)
    return _system(d, [th], sp.Matrix([[m * l**2]]), m * g * l * sp.cos(th + gam), None, qd=[thd], constraints=[c],
                   draw=draw)


def compass_gait_heel_strike(q, qd, m, mH, a, b):
    """(q+, qdot+) of the compass gait's heel strike at (q, qdot) = ((theta_s, theta_ns), their rates):
    the swing foot's plastic impact keeps the whole walker's angular momentum about it and the old
    stance leg's about the hip, A qdot+ = B qdot- (Goswami et al. 1998: Q+ and Q-), and the legs
    exchange roles. Only the inter-leg angle enters (c = cos(theta_ns - theta_s))."""
    ts, tn = q
    c = sp.cos(tn - ts)
    A = sp.Matrix([[-(2 * a**2 * m + a**2 * mH + 2 * a * b * m + 2 * a * b * mH + b**2 * m + b**2 * mH)
                    + (a * b * m + b**2 * m) * c, b * m * ((a + b) * c - b)],
                   [b * m * (a + b) * c, -b**2 * m]])
    B = sp.Matrix([[a * b * m - (2 * a**2 * m + a**2 * mH + 2 * a * b * m + 2 * a * b * mH + b**2 * mH) * c, a * b * m],
                   [a * b * m, 0]])
    det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    Ainv = sp.Matrix([[A[1, 1], -A[0, 1]], [-A[1, 0], A[0, 0]]]) / det
    v = Ainv * B * sp.Matrix(qd)
    return (tn, ts), (v[0], v[1])


def compass_gait(**overrides) -> MechanicalSystem:
    """The compass gait (Goswami et al.): q = (theta_s, theta_ns) from the slope normal; stance mass m at
    a from its foot, hip mass mH, swing mass m at b below the hip. The swing foot's height above the
    slope, l (cos theta_s - cos theta_ns), is the guard, armed once the stance leg has passed the
    normal (theta_s > 0: the swing foot crosses the slope at mid-stride without an impact); heel
    strike is the declared reset compass_gait_heel_strike."""
    d = sd.compass_gait(**overrides)
    ts, tn = sp.symbols("theta_s theta_ns")
    tsd, tnd = sp.symbols("theta_s_dot theta_ns_dot")
    m, mH, a, b, gam, g = sp.symbols("m mH a b gamma g")
    l = a + b
    c = -m * l * b * sp.cos(ts - tn)
    M = sp.Matrix([[(mH + m) * l**2 + m * a**2, c], [c, m * b**2]])
    V = g * ((m * a + mH * l + m * l) * sp.cos(ts + gam) - m * b * sp.cos(tn + gam))
    q_plus, qd_plus = compass_gait_heel_strike((ts, tn), (tsd, tnd), m, mH, a, b)
    heel = Constraint("heel_strike", l * (sp.cos(ts) - sp.cos(tn)), when=ts, reset_q=q_plus, reset_qd=qd_plus)
    # the drawing: stance foot at the origin, hip, swing foot, the three masses, the slope; at each heel
    # strike the swing foot becomes the stance foot (advance)
    hip = (l * sp.sin(ts), l * sp.cos(ts))
    swing = (hip[0] - l * sp.sin(tn), hip[1] - l * sp.cos(tn))
    pts = {"stance": (0, 0), "hip": _slope(*hip, gam), "swing": _slope(*swing, gam),
           "m_stance": _slope(a * sp.sin(ts), a * sp.cos(ts), gam),
           "m_swing": _slope(hip[0] - b * sp.sin(tn), hip[1] - b * sp.cos(tn), gam)}
    draw = dict(points=pts, segments=[("stance", "hip"), ("hip", "swing")], dots=["hip", "m_stance", "m_swing"],
                lines=[((0, 0), (sp.sin(gam), sp.cos(gam)))], contacts=["swing"], advance=pts["swing"])
    return _system(d, [ts, tn], M, V, None, qd=[tsd, tnd], constraints=[heel], draw=draw)


# --- the scenes with Coulomb friction: the constructors of vcirun.scenes.friction at the scene data's
# parameters, with its start (initial-condition map, default beta or state) and description

def _with_start(d: sd.SystemData, s: MechanicalSystem) -> MechanicalSystem:
    s.ic_map, s.default_beta, s.default_q0, s.default_p0 = d.ic_map, d.default_beta, d.default_q0, d.default_p0
    s.ic_map_params = d.ic_map_params
    s.description = d.description
    return s


def rocking_block_friction(**overrides) -> MechanicalSystem:
    d = sd.rocking_block_friction(**overrides)
    return _with_start(d, friction.rocking_block_friction(**d.params))


def spinning_ball(**overrides) -> MechanicalSystem:
    d = sd.spinning_ball(**overrides)
    return _with_start(d, friction.spinning_ball(**d.params))


def incline(**overrides) -> MechanicalSystem:
    d = sd.incline(**overrides)
    return _with_start(d, friction.incline(**d.params))


def coulomb_oscillator(**overrides) -> MechanicalSystem:
    d = sd.coulomb_oscillator(**overrides)
    return _with_start(d, friction.coulomb_oscillator(**d.params))


def painleve_rod(**overrides) -> MechanicalSystem:
    d = sd.painleve_rod(**overrides)
    return _with_start(d, friction.painleve_rod(**d.params))


def link_chain_friction(n: int = 5, **overrides) -> MechanicalSystem:
    n = int(n)
    d = sd.link_chain_friction(n, **overrides)
    return _with_start(d, friction.link_chain_friction(n, **d.params))


# One registry of built-in scenes: the names (and numeric parts) are vcirun.scenes.data's; each has its
# symbolic part here under the same name.
BUILTIN_SCENES = {name: getattr(mechanisms, name) if hasattr(mechanisms, name) else globals()[name]
                  for name in sd.BUILTIN_SCENE_DATA}


def get_scene(name: str, **params) -> MechanicalSystem:
    """Built-in scene by name; `n_pendulum_K` selects the K-link pendulum. Scenes without parameter
    overrides are built once per process (parameter values are runtime inputs anyway)."""
    if not params:
        return _scene_cached(name)
    return _build_scene(name, **params)


@functools.lru_cache(maxsize=None)
def _scene_cached(name: str) -> MechanicalSystem:
    return _build_scene(name)


def _build_scene(name: str, **params) -> MechanicalSystem:
    args = sd.scene_args(name)
    if args is None:
        raise sd.unknown_scene_error(name)
    return BUILTIN_SCENES[args[0]](*args[1], **params)
