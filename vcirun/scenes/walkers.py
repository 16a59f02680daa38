"""The passive walkers, each declared once (vcirun.scenes.scene.Scene): the rimless wheel and the compass
gait of Goswami, Thuilot and Espiau (1998), their impacts declared resets.

No sympy at import: each symbolic builder imports it when it runs. The compass gait's mass matrix is
one function (`compass_gait_M`) used by both the numeric default start and the symbolic system."""
from __future__ import annotations

import numpy as np

from .scene import Param, Scene

_G = Param(9.81, "m/s^2", "gravitational acceleration")


# --- the rimless wheel ----------------------------------------------------------------------------

def _rimless_symbolic(x):
    """The rimless wheel: q = theta, the stance spoke from the slope normal; L = m l^2 thetadot^2 / 2 -
    m g l cos(theta + gamma). The next spoke lands at theta = alpha (phi = alpha - theta: the angle
    left to its touchdown); the impact is plastic at the new foot, which keeps the angular momentum
    about it: theta+ = theta - 2 alpha, thetadot+ = cos(2 alpha) thetadot- (the declared reset)."""
    import sympy as sp

    from .symbolic import Constraint, slope, system

    (th,), (thd,), p = x.q, x.qd, x.p
    m, l, a, gam, g = p.m, p.l, p.alpha, p.gamma, p.g
    c = Constraint("spoke", a - th, reset_q=(th - 2 * a,), reset_qd=(sp.cos(2 * a) * thd,))
    # the drawing: the hub over the stance foot (the origin), every spoke, the slope; at each impact
    # the landing spoke's foot becomes the origin (advance)
    spokes = max(3, round(float(sp.pi) / float(x.d.params["alpha"])))
    hub = (l * sp.sin(th), l * sp.cos(th))
    pts = {"hub": slope(*hub, gam)}
    for k in range(spokes):
        pts[f"foot{k}"] = slope(hub[0] - l * sp.sin(th + 2 * a * k), hub[1] - l * sp.cos(th + 2 * a * k), gam)
    landing = slope(hub[0] - l * sp.sin(th - 2 * a), hub[1] - l * sp.cos(th - 2 * a), gam)
    draw = dict(points=pts, segments=[("hub", f"foot{k}") for k in range(spokes)], dots=["hub"],
                lines=[((0, 0), (sp.sin(gam), sp.cos(gam)))], contacts=["foot0"], advance=landing)
    return system(x.d, [th], sp.Matrix([[m * l**2]]), m * g * l * sp.cos(th + gam), None, qd=[thd], constraints=[c],
                  draw=draw)


def _rimless_start(p):
    """Xi(beta): just after an impact (theta = -alpha) with angular velocity beta; the default state is
    the closed-form gait's (vcirun.scenes.oracles.rimless_wheel_fixed_point)."""
    m, l, a, gam, g = (p[k] for k in ("m", "l", "alpha", "gamma", "g"))
    c2 = np.cos(2 * a) ** 2
    w = np.sqrt(c2 * 4 * g / l * np.sin(a) * np.sin(gam) / (1 - c2))
    return dict(ic_map=lambda beta: (np.array([-a]), np.array([float(beta)])),
                default_q0=np.array([-a]), default_p0=np.array([m * l * l * w]))


# A point mass m on massless spokes of length l, 2 alpha apart, rolling down a slope gamma. q = theta,
# the stance spoke's angle from the slope normal (forward positive).
RIMLESS_WHEEL = Scene(
    "rimless_wheel",
    description="rimless wheel on a slope: plastic spoke impacts as a declared reset (closed-form stride map)",
    coordinates=(("theta", "rad", "stance spoke's angle from the slope normal, forward positive"),),
    params={"m": Param(1.0, "kg", "point mass at the hub"), "l": Param(1.0, "m", "spoke length"),
            "alpha": Param(float(np.pi / 8), "rad", "half the angle between two spokes"),
            "gamma": Param(0.1, "rad", "slope angle"), "g": _G},
    constraint="phi = alpha - theta >= 0 (the next spoke touches down at theta = alpha); declared plastic reset "
               "theta+ = theta - 2 alpha, thetadot+ = cos(2 alpha) thetadot",
    ic_text="just after a touchdown: theta = -alpha, thetadot = beta",
    default_text="the closed-form period-one gait just after a touchdown",
    symbolic=_rimless_symbolic, start=_rimless_start,
    example=("--h 0.001 --T 3", "a spoke impact every 0.4 s"))


# --- the compass gait -----------------------------------------------------------------------------

def compass_gait_M(q, prm, cos=np.cos):
    """The compass gait's mass matrix at q = (theta_s, theta_ns) as rows ((M11, M12), (M21, M22)) of
    `prm`'s entries m, mH, a, b: numbers with cos = np.cos (the numeric default start, the tests'
    velocities), symbols with cos = sympy.cos (the symbolic system)."""
    m, mh, a, b = prm["m"], prm["mH"], prm["a"], prm["b"]
    l = a + b
    c = -m * l * b * cos(q[0] - q[1])
    return ((mh + m) * l * l + m * a * a, c), (c, m * b * b)


def compass_gait_heel_strike(q, qd, m, mH, a, b):
    """(q+, qdot+) of the compass gait's heel strike at (q, qdot) = ((theta_s, theta_ns), their rates):
    the swing foot's plastic impact keeps the whole walker's angular momentum about it and the old
    stance leg's about the hip, A qdot+ = B qdot- (Goswami et al. 1998: Q+ and Q-), and the legs
    exchange roles. Only the inter-leg angle enters (c = cos(theta_ns - theta_s))."""
    import sympy as sp

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


def _compass_symbolic(x):
    """The compass gait (Goswami et al.): q = (theta_s, theta_ns) from the slope normal; stance mass m at
    a from its foot, hip mass mH, swing mass m at b below the hip. The swing foot's height above the
    slope, l (cos theta_s - cos theta_ns), is the guard, armed once the stance leg has passed the
    normal (theta_s > 0: the swing foot crosses the slope at mid-stride without an impact); heel
    strike is the declared reset compass_gait_heel_strike."""
    import sympy as sp

    from .symbolic import Constraint, slope, system

    (ts, tn), (tsd, tnd), p = x.q, x.qd, x.p
    m, mH, a, b, gam, g = p.m, p.mH, p.a, p.b, p.gamma, p.g
    l = a + b
    M = sp.Matrix(compass_gait_M((ts, tn), p, cos=sp.cos))
    V = g * ((m * a + mH * l + m * l) * sp.cos(ts + gam) - m * b * sp.cos(tn + gam))
    q_plus, qd_plus = compass_gait_heel_strike((ts, tn), (tsd, tnd), m, mH, a, b)
    heel = Constraint("heel_strike", l * (sp.cos(ts) - sp.cos(tn)), when=ts, reset_q=q_plus, reset_qd=qd_plus)
    # the drawing: stance foot at the origin, hip, swing foot, the three masses, the slope; at each heel
    # strike the swing foot becomes the stance foot (advance)
    hip = (l * sp.sin(ts), l * sp.cos(ts))
    swing = (hip[0] - l * sp.sin(tn), hip[1] - l * sp.cos(tn))
    pts = {"stance": (0, 0), "hip": slope(*hip, gam), "swing": slope(*swing, gam),
           "m_stance": slope(a * sp.sin(ts), a * sp.cos(ts), gam),
           "m_swing": slope(hip[0] - b * sp.sin(tn), hip[1] - b * sp.cos(tn), gam)}
    draw = dict(points=pts, segments=[("stance", "hip"), ("hip", "swing")], dots=["hip", "m_stance", "m_swing"],
                lines=[((0, 0), (sp.sin(gam), sp.cos(gam)))], contacts=["swing"], advance=pts["swing"])
    return system(x.d, [ts, tn], M, V, None, qd=[tsd, tnd], constraints=[heel], draw=draw)


# the period-one gait at the default slope (3 degrees), on the section just after heel strike
_COMPASS_Q0 = (-0.271016, 0.271016)
_COMPASS_QDOT0 = (1.092571, 0.377537)


def _compass_start(p):
    """Xi(beta): the default state with its velocities scaled by beta."""
    q0, v0 = np.array(_COMPASS_Q0), np.array(_COMPASS_QDOT0)
    return dict(ic_map=lambda beta: (q0.copy(), float(beta) * v0), default_q0=q0,
                default_p0=np.array(compass_gait_M(q0, p)) @ v0)


# Legs with point masses m at a from the foot (b from the hip), a hip mass mH, on a slope gamma. q =
# (theta_s, theta_ns), the stance and swing legs' angles from the slope normal (forward positive);
# heel strike (the swing foot reaches the slope ahead of the stance foot) is a plastic impact and the
# exchange of the legs, a declared reset.
COMPASS_GAIT = Scene(
    "compass_gait",
    description="compass-gait walker (Goswami et al.) on a slope gamma: heel strike as a declared reset",
    coordinates=(("theta_s", "rad", "stance leg's angle from the slope normal, forward positive"),
                 ("theta_ns", "rad", "swing leg's angle from the slope normal, forward positive")),
    params={"m": Param(5.0, "kg", "point mass on each leg"), "mH": Param(10.0, "kg", "hip mass"),
            "a": Param(0.5, "m", "leg mass to foot"), "b": Param(0.5, "m", "leg mass to hip"),
            "gamma": Param(float(np.deg2rad(3.0)), "rad", "slope angle"), "g": _G},
    constraint="phi = (a + b)(cos theta_s - cos theta_ns) >= 0 once theta_s > 0 (heel strike); declared reset: "
               "plastic impact of the swing foot and exchange of the legs (Goswami et al. 1998)",
    ic_text="the default state with its velocities scaled by beta",
    default_text="the period-one gait at gamma = 3 deg just after heel strike",
    symbolic=_compass_symbolic, start=_compass_start,
    example=("--h 0.001 --T 3", "a heel strike every 0.73 s"))

SCENES = (RIMLESS_WHEEL, COMPASS_GAIT)
