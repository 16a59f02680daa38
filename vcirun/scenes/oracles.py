"""Closed-form solutions of built-in scenes: the exact oracles against which references and runs are checked.

Plain numpy and scipy (optimize for one root, integrate.quad and special.ellipj for the bead): no
sympy, no compiled method module, so the reference, the studies and the tests can use them at any layer.

- `oscillator_wall_exact`: m x'' = -k x with an elastic wall at x = -d (scene `oscillator_wall`).
- `ball_exact`, `ball_position`, `ball_exact_onset`: the bouncing ball y'' = -g - (c/m) y' with
  elastic impacts on y = 0 (scene `bouncing_ball`; with drag its impacts accumulate).

Several contacts and restitution (issues 17 and 18; derivations in docs/derivations/contacts.md):
- `ball_in_box_exact`: a point mass in a box under gravity, restitution e on four walls; the impact
  list (time, contact index, impulse), corner hits as two entries at the same time.
- `zeno_ball`: a ball bouncing on a floor with e < 1: the geometric impact times, the Zeno time
  t_inf = t1 + 2 e v1 / (g (1 - e)), rest on the floor afterwards.
- `bead_release`: a bead leaving the top of a circle (unilateral phi = |x| - R >= 0) where the
  normal force vanishes, cos theta_r = 2/3 + v0^2 / (3 g R); release time by quadrature.
- `newton_cradle_velocities`, `newton_cradle_impulses`: Moreau's simultaneous-impact (LCP) answer for
  N equal touching balls.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

__all__ = ["oscillator_wall_exact", "ball_exact", "ball_position", "ball_exact_onset", "ball_in_box_exact",
           "BoxSolution", "zeno_ball", "ZenoBall", "bead_release", "BeadRelease", "newton_cradle_velocities",
           "newton_cradle_impulses", "rimless_wheel_stride", "rimless_wheel_fixed_point", "RimlessGait"]


# --- the harmonic oscillator against a wall --------------------------------------------------------

def oscillator_wall_exact(t, x0, v0, m=1.0, k=1.0, d=0.5):
    """Closed form of m x'' = -k x with an elastic wall at x = -d (phi = x + d >= 0).

    Phase form x = A cos(th), v = -A w sin(th), th' = w; at an impact (x = -d, v < 0, th = th_i with
    cos th_i = -d/A) the reflection v -> -v maps th_i to 2 pi - th_i. Returns (x, v, impact_times)."""
    t = np.asarray(t, float)
    w = np.sqrt(k / m)
    A = np.hypot(x0, v0 / w)
    if A <= d:
        th0 = np.arctan2(-v0 / w, x0)
        th = th0 + w * t
        return A * np.cos(th), -A * w * np.sin(th), np.array([])
    thi = np.arccos(-d / A)                        # impact phase in (pi/2, pi)
    th0 = np.mod(np.arctan2(-v0 / w, x0), 2 * np.pi)  # x0 = A cos th0, v0 = -A w sin th0
    # admissible phases: [2pi - thi, 2pi + thi) (mod 2pi); unfold into a phase that advances by 2 thi
    # per period and wraps back
    th0 = th0 if th0 < thi else th0 - 2 * np.pi   # now in [-(2pi - ... ), thi)
    if th0 < -thi:
        th0 = -thi
    period = 2 * thi / w
    s = (th0 + thi) / w + t                       # time since the last reflection point
    frac = np.mod(s, period)
    th = -thi + w * frac
    n_imp = int(np.floor(((th0 + thi) / w + float(np.max(t, initial=0.0))) / period))
    t_imp = np.array([(j + 1) * period - (th0 + thi) / w for j in range(n_imp)])
    t_imp = t_imp[t_imp > 0]
    return A * np.cos(th), -A * w * np.sin(th), t_imp


# --- the bouncing ball with linear drag --------------------------------------------------------------

def _flight(v, g, k):
    """Time for y(0) = 0, y'(0) = v > 0 to return to y = 0 under y'' = -g - k y', and the return speed.
    Newton on f(T) = -(g/k) T - (v + g/k) expm1(-k T) / k from the series guess
    T ~ (2 v / g) / (1 + k v / (3 g)); f'(T) = -(return speed), so it is well conditioned."""
    if k == 0.0:
        return 2 * v / g, v
    T = (2 * v / g) / (1 + k * v / (3 * g))
    for _ in range(30):
        e = math.exp(-k * T)
        f = -(g / k) * T - (v + g / k) * math.expm1(-k * T) / k
        df = -(g / k) + (v + g / k) * e
        dT = f / df
        T -= dT
        if abs(dT) <= 1e-15 * T:
            break
    return T, g / k - (v + g / k) * math.exp(-k * T)


def ball_exact(y0, g, k, T, *, min_flight=1e-9, max_impacts=2_000_000):
    """Exact impact times and post-impact speeds of a ball dropped from rest at y0 onto y = 0 with
    y'' = -g - k y' (k = c/m) and elastic impacts, up to time T or until a flight is shorter than
    min_flight (then the ball lies on the floor to within g min_flight^2 / 8). Returns (times, speeds)."""
    if k == 0.0:
        t1 = math.sqrt(2 * y0 / g)
        v = g * t1
    else:
        from scipy.optimize import brentq

        t1 = brentq(lambda s: y0 - (g / k) * s - (g / k**2) * math.expm1(-k * s), 0.0,
                    10 * math.sqrt(2 * y0 / g) + 10.0, xtol=1e-15, rtol=1e-15)
        v = (g / k) * (-math.expm1(-k * t1))
    ts, vs = [t1], [v]
    t = t1
    while t < T and len(ts) < max_impacts:
        dt, v = _flight(v, g, k)
        t += dt
        ts.append(t)
        vs.append(v)
        if dt < min_flight:
            break
    return np.array(ts), np.array(vs)


def ball_position(t, y0, g, k, times, speeds):
    """y(t) of the exact ball (see ball_exact) on the times t; 0 after the last computed impact."""
    t = np.asarray(t, float)
    y = np.zeros_like(t)
    first = t < times[0]
    s = t[first]
    y[first] = y0 - g * s**2 / 2 if k == 0 else y0 - (g / k) * s - (g / k**2) * np.expm1(-k * s)
    j = np.searchsorted(times, t, side="right") - 1
    m = (j >= 0) & (j < len(times) - 1)
    s = t[m] - times[j[m]]
    v = speeds[j[m]]
    y[m] = v * s - g * s**2 / 2 if k == 0 else -(g / k) * s - (v + g / k) * np.expm1(-k * s) / k
    return y


def ball_exact_onset(times, h) -> float:
    """The exact accumulation onset on a grid of step h: the impact after which every flight is
    shorter than h (the flights of the damped ball decrease monotonically)."""
    d = np.diff(times)
    k = np.flatnonzero(d < h)
    return float(times[k[0]]) if k.size else float("nan")


# --- restitution: validation shared by the oracles below ---------------------------------------------

def _finite(name, value, fix):
    if not math.isfinite(value):
        raise ValueError(f"{name} = {value!r} is not finite: {fix}")


def _restitution(e) -> float:
    e = float(e)
    if not (0.0 <= e <= 1.0):
        raise ValueError(f"e = {e!r} is not a restitution coefficient: give 0 <= e <= 1")
    return e


# --- a ball leaving the floor: the geometric bounce phase --------------------------------------------

def _bounce_times(ta, w, g, e, j):
    """Time of the j-th floor impact (j >= 0, j = 0 is ta) of a ball leaving y = 0 at ta with speed w."""
    T0 = 2.0 * w / g
    if e == 1.0:
        return ta + T0 * j
    return ta + T0 * (-np.expm1(j * math.log(e))) / (1.0 - e) if e > 0.0 else ta + T0 * (j > 0)


def _bounce_rest(ta, w, g, e) -> float:
    """The Zeno time ta + 2 w / (g (1 - e)) of the bounces from (ta, w); inf for e = 1."""
    if w == 0.0:
        return ta
    return math.inf if e == 1.0 else ta + 2.0 * w / (g * (1.0 - e))


def _bounce_state(t, ta, w, g, e):
    """(y, v) at times t >= ta of a ball leaving the floor y = 0 at time ta with speed w >= 0 under
    gravity g > 0, restitution e on the floor and nothing above. Impact j >= 1 at
    t_j = ta + (2 w / g) (1 - e^j) / (1 - e) (ta + 2 w j / g for e = 1), speed w e^j after it
    (right-continuous at t_j); at rest (0, 0) from t_inf = ta + 2 w / (g (1 - e)) on."""
    t = np.asarray(t, float)
    t_inf = _bounce_rest(ta, w, g, e)
    rest = t >= t_inf
    if w == 0.0 or e == 0.0:
        j = np.zeros(t.shape)
    elif e == 1.0:
        j = np.floor((t - ta) / (2.0 * w / g))
    else:
        r = 1.0 - (t - ta) * (1.0 - e) * g / (2.0 * w)   # e^j >= r on impact j's flight
        with np.errstate(invalid="ignore", divide="ignore"):
            j = np.floor(np.log(np.where(rest, 1.0, np.maximum(r, 1e-300))) / math.log(e))
        j = np.maximum(j, 0.0)
        for _ in range(2):  # the logarithm's round-off: make t_j <= t < t_{j+1} exact
            j = np.where(_bounce_times(ta, w, g, e, j + 1) <= t, j + 1, j)
            j = np.where((_bounce_times(ta, w, g, e, j) > t) & (j > 0), j - 1, j)
    tj = _bounce_times(ta, w, g, e, j)
    wj = w * np.power(e, j) if e > 0.0 else np.full(t.shape, w)
    s = t - tj
    y = wj * s - 0.5 * g * s * s
    v = wj - g * s
    return np.where(rest, 0.0, y), np.where(rest, 0.0, v)


def _first_landing(y, v, g):
    """Time to reach y = 0 from height y >= 0 with upward speed v under gravity g > 0 (the positive
    root of y + v s - g s^2 / 2 = 0, in the form without cancellation) and the landing speed."""
    D = math.sqrt(v * v + 2.0 * g * y)
    s = (v + D) / g if v >= 0.0 else 2.0 * y / (D - v)
    return s, D


# --- the Zeno ball -------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class ZenoBall:
    """A ball on a floor y >= 0 under gravity g, restitution e (see `zeno_ball`).

    t1, v1: the first impact's time and speed; t_inf: the Zeno time (inf for e = 1), from which on
    the ball rests on the floor. impact_times(n), impact_speeds(n): the first n impacts (times, speeds
    before each impact); state(t): (y, v) at times t (right-continuous at impacts)."""

    y0: float
    v0: float
    g: float
    e: float
    t1: float
    v1: float
    t_inf: float

    def impact_times(self, n: int) -> np.ndarray:
        """t_k = t1 + (2 e v1 / g) (1 - e^(k-1)) / (1 - e), k = 1..n (t1 + 2 v1 (k - 1) / g for e = 1)."""
        k = np.arange(int(n), dtype=float)
        if self.v1 == 0.0:
            return np.full(min(int(n), 1), self.t1)  # at rest from t1: one "impact" of speed 0 at most
        return _bounce_times(self.t1, self.e * self.v1, self.g, self.e, k)

    def impact_speeds(self, n: int) -> np.ndarray:
        """The speed just before impact k: v1 e^(k-1), k = 1..n."""
        return self.v1 * np.power(self.e, np.arange(int(n), dtype=float))

    def state(self, t):
        t = np.asarray(t, float)
        y = self.y0 + self.v0 * t - 0.5 * self.g * t * t
        v = self.v0 - self.g * t
        after = t >= self.t1
        yb, vb = _bounce_state(np.where(after, t, self.t1), self.t1, self.e * self.v1, self.g, self.e)
        return np.where(after, yb, y), np.where(after, vb, v)


def zeno_ball(y0, v0, g, e) -> ZenoBall:
    """A ball at height y0 >= 0 with upward velocity v0 above a floor y >= 0, gravity g > 0,
    restitution e in [0, 1].

    First impact: t1 the positive root of y0 + v0 t - g t^2 / 2 = 0, at speed v1 = sqrt(v0^2 + 2 g y0).
    After impact k the speed is e^k v1 and the flight lasts 2 e^k v1 / g, so
    t_{k+1} = t1 + (2 e v1 / g)(1 + e + ... + e^(k-1)) = t1 + (2 e v1 / g)(1 - e^k) / (1 - e), and
    the impacts accumulate at the Zeno time t_inf = t1 + 2 e v1 / (g (1 - e)); after it the ball
    lies on the floor (y = 0, v = 0). e = 0: at rest from t1; e = 1: no accumulation (t_inf = inf)."""
    y0, v0, g, e = float(y0), float(v0), float(g), _restitution(e)
    for name, val in (("y0", y0), ("v0", v0), ("g", g)):
        _finite(name, val, "give a finite number")
    if not g > 0.0:
        raise ValueError(f"g = {g!r}: the Zeno ball needs gravity, give g > 0")
    if y0 < 0.0:
        raise ValueError(f"y0 = {y0!r} is below the floor: give y0 >= 0")
    t1, v1 = _first_landing(y0, v0, g)
    return ZenoBall(y0, v0, g, e, t1, v1, _bounce_rest(t1, e * v1, g, e))


# --- a point mass in a box ----------------------------------------------------------------------------

class BoxSolution(NamedTuple):
    """The exact ball in a box (see `ball_in_box_exact`). States at the requested times are
    right-continuous at impacts. Contacts in declaration order: 0 floor y >= 0, 1 ceiling
    height - y >= 0, 2 left x >= 0, 3 right width - x >= 0."""

    x: np.ndarray
    y: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    impact_times: np.ndarray     # (K,) ascending; a corner hit gives two entries at the same time
    impact_contact: np.ndarray   # (K,) int64 contact index
    impact_impulse: np.ndarray   # (K,) lambda = (1 + e) m |u-| (p+ = p- + lambda grad phi, |grad phi| = 1)
    t_rest: float                # the ball rests on the floor from t_rest on (inf: not before max(t))


BOX_CONTACTS = ("floor", "ceiling", "left", "right")


def _walls(T, x0, v0, L, e, m, lo, hi, max_impacts):
    """Constant-speed bounces between x = 0 (contact lo) and x = L (contact hi), speed times e at each
    hit, up to time T: segment starts [(t, x, v)] and impacts [(t, contact, impulse)]."""
    segs, imps = [(0.0, x0, v0)], []
    t, x, v = 0.0, x0, v0
    while v != 0.0:
        s, c, wall = ((L - x) / v, hi, L) if v > 0.0 else (x / -v, lo, 0.0)
        if t + s > T:
            break
        t += s
        imps.append((t, c, (1.0 + e) * m * abs(v)))
        x, v = wall, -e * v
        segs.append((t, x, v))
        if len(imps) > max_impacts:
            raise ValueError(f"more than max_impacts = {max_impacts} wall impacts before t = {T}: "
                             "shorten the time span or raise max_impacts")
    return segs, imps


def _eval_linear(t, segs):
    ts, xs, vs = (np.array(c) for c in zip(*segs))
    i = np.searchsorted(ts, t, side="right") - 1
    return xs[i] + vs[i] * (t - ts[i]), vs[i]


def ball_in_box_exact(t, x0, y0, vx0, vy0, *, width, height, g, e, m=1.0, min_flight=1e-9,
                      simultaneous_tol=1e-12, max_impacts=1_000_000) -> BoxSolution:
    """A point mass m in the box 0 <= x <= width, 0 <= y <= height, gravity -g in y, restitution e on
    the four walls (contacts in this order: floor y >= 0, ceiling height - y >= 0, left x >= 0,
    right width - x >= 0), from (x0, y0, vx0, vy0) at time 0, on the times t >= 0.

    M = m I and the wall normals are the coordinate axes, so W = G M^-1 G^T is diagonal for any set of
    touching walls: the LCP of a corner hit decouples into Newton's law per wall (docs/derivations/contacts.md),
    and the motion is decoupled: x bounces between the side walls at constant speed, multiplied by
    e at each hit; y is a bouncing ball with a ceiling. Once the ball leaves the floor with a speed
    w with w^2 <= 2 g height it never reaches the ceiling again and the floor impacts are geometric
    (`zeno_ball`): for e < 1 they accumulate at t_rest = t_k + 2 w / (g (1 - e)), after which the ball
    slides on the floor (vy = 0). Infinitely many impacts precede t_rest: the list stops at the first
    flight shorter than min_flight (the states stay exact up to t_rest). A grazing touch (zero normal
    velocity, e.g. the apex exactly at the ceiling) is not an impact. x and y impact times within
    simultaneous_tol (relative, min 1 s) are one corner hit: reported at the same time, floor/ceiling
    first (contact order). Returns a BoxSolution."""
    x0, y0, vx0, vy0, width, height, g, m = (float(a) for a in (x0, y0, vx0, vy0, width, height, g, m))
    e = _restitution(e)
    for name, val in (("x0", x0), ("y0", y0), ("vx0", vx0), ("vy0", vy0), ("width", width), ("height", height),
                      ("g", g), ("m", m)):
        _finite(name, val, "give a finite number")
    for name, val in (("width", width), ("height", height), ("m", m)):
        if not val > 0.0:
            raise ValueError(f"{name} = {val!r} must be positive")
    if g < 0.0:
        raise ValueError(f"g = {g!r}: gravity points in -y, give g >= 0")
    if not (0.0 <= x0 <= width and 0.0 <= y0 <= height):
        raise ValueError(f"(x0, y0) = ({x0}, {y0}) is outside the box [0, {width}] x [0, {height}]: start inside")
    t = np.asarray(t, float)
    if t.size and not (np.all(np.isfinite(t)) and np.min(t) >= 0.0):
        raise ValueError("t must be finite times >= 0")
    T = float(np.max(t)) if t.size else 0.0

    xsegs, imps = _walls(T, x0, vx0, width, e, m, 2, 3, max_impacts)
    t_rest, geo = math.inf, None
    if g == 0.0:
        ysegs, yimps = _walls(T, y0, vy0, height, e, m, 0, 1, max_impacts)
    else:
        ysegs, yimps = [(0.0, y0, vy0)], []
        tc, y, v = 0.0, y0, vy0
        while True:
            if y == 0.0 and v >= 0.0 and v * v <= 2.0 * g * height:
                geo = (tc, v)   # leaves the floor below the ceiling's reach: geometric from here
                t_rest = _bounce_rest(tc, v, g, e)
                w, j = v, 1
                while w > 0.0:
                    tj = float(_bounce_times(tc, v, g, e, j))
                    if tj > T or 2.0 * w / g < min_flight:
                        break
                    yimps.append((tj, 0, (1.0 + e) * m * w))
                    w *= e
                    j += 1
                    if len(yimps) > max_impacts:
                        raise ValueError(f"more than max_impacts = {max_impacts} floor impacts before t = {T}: "
                                         "raise min_flight or max_impacts")
                break
            s, D = _first_landing(y, v, g)
            c, vpre = 0, -D
            disc = v * v - 2.0 * g * (height - y)
            if v > 0.0 and disc > 0.0:       # reaches the ceiling (before coming back down)
                s, c, vpre = 2.0 * (height - y) / (v + math.sqrt(disc)), 1, math.sqrt(disc)
            if tc + s > T:
                break
            tc += s
            yimps.append((tc, c, (1.0 + e) * m * abs(vpre)))
            y, v = (0.0 if c == 0 else height), -e * vpre
            ysegs.append((tc, y, v))
            if len(yimps) > max_impacts:
                raise ValueError(f"more than max_impacts = {max_impacts} impacts before t = {T}: "
                                 "shorten the time span or raise max_impacts")

    x, vx = _eval_linear(t, xsegs)
    if g == 0.0:
        y, vy = _eval_linear(t, ysegs)
    else:
        ts, ys, vs = (np.array(c) for c in zip(*ysegs))
        i = np.searchsorted(ts, t, side="right") - 1
        s = t - ts[i]
        y, vy = ys[i] + vs[i] * s - 0.5 * g * s * s, vs[i] - g * s
        if geo is not None:
            late = t >= geo[0]
            yb, vb = _bounce_state(np.where(late, t, geo[0]), geo[0], geo[1], g, e)
            y, vy = np.where(late, yb, y), np.where(late, vb, vy)

    # merge; a corner: an x and a y impact at the same instant up to round-off
    ev = sorted(imps + yimps)
    times = [a[0] for a in ev]
    for i in range(1, len(ev)):
        if (ev[i][1] < 2) != (ev[i - 1][1] < 2) and \
                abs(times[i] - times[i - 1]) <= simultaneous_tol * max(1.0, abs(times[i])):
            times[i] = times[i - 1]
    order = sorted(range(len(ev)), key=lambda i: (times[i], ev[i][1]))
    return BoxSolution(x, y, vx, vy, np.array([times[i] for i in order], float),
                       np.array([ev[i][1] for i in order], np.int64), np.array([ev[i][2] for i in order], float),
                       t_rest)


# --- a bead leaving a circle ---------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class BeadRelease:
    """The bead of `bead_release`. On the circle (t <= t_r): q = R (sin theta, cos theta),
    theta(t) in closed form; released at t_r (theta_r, q_r, v_r); free flight afterwards.
    state(t) -> (q (..., 2), v (..., 2)); normal_force(t): the contact multiplier lambda (the force
    lambda grad phi, grad phi = q / |q|), m (3 g cos theta - 2 g - v0^2 / R) on the circle, 0 after."""

    R: float
    g: float
    v0: float
    m: float
    cos_r: float
    theta_r: float
    t_r: float
    q_r: np.ndarray
    v_r: np.ndarray

    def theta(self, t):
        """theta(t) of the motion on the circle (followed until t_r), from the energy equation
        R theta' = sqrt(v0^2 + 4 g R sin^2(theta / 2)) by the Jacobi elliptic functions: with
        u = theta / 2 and k^2 = 4 g R / v0^2, t = (2 R / v0) F(u | -k^2), and by the imaginary-modulus
        transformation F(u | -k^2) = F(beta | m) / sqrt(1 + k^2), m = k^2 / (1 + k^2),
        tan u = tan beta / sqrt(1 + k^2), beta = am(sqrt(1 + k^2) v0 t / (2 R) | m)."""
        from scipy.special import ellipj

        t = np.asarray(t, float)
        k2 = 4.0 * self.g * self.R / self.v0 ** 2
        sn, cn, _, _ = ellipj(math.sqrt(1.0 + k2) * self.v0 * t / (2.0 * self.R), k2 / (1.0 + k2))
        return 2.0 * np.arctan2(sn, cn * math.sqrt(1.0 + k2))

    def _theta_dot(self, th):
        return np.sqrt(self.v0 ** 2 + 4.0 * self.g * self.R * np.sin(0.5 * th) ** 2) / self.R

    def state(self, t):
        t = np.asarray(t, float)
        on = t < self.t_r
        th = self.theta(np.where(on, t, 0.0))
        w = self._theta_dot(th)
        s = np.where(on, 0.0, t - self.t_r)
        qf = self.q_r + s[..., None] * self.v_r + np.stack([np.zeros_like(s), -0.5 * self.g * s * s], -1)
        vf = self.v_r + np.stack([np.zeros_like(s), -self.g * s], -1)
        qc = self.R * np.stack([np.sin(th), np.cos(th)], -1)
        vc = (self.R * w)[..., None] * np.stack([np.cos(th), -np.sin(th)], -1)
        return np.where(on[..., None], qc, qf), np.where(on[..., None], vc, vf)

    def normal_force(self, t):
        t = np.asarray(t, float)
        on = t < self.t_r
        th = self.theta(np.where(on, t, 0.0))
        return np.where(on, self.m * (3.0 * self.g * np.cos(th) - 2.0 * self.g - self.v0 ** 2 / self.R), 0.0)


def bead_release(R, g, v0, m=1.0) -> BeadRelease:
    """A bead of mass m starting at the top q = (0, R) of a circle of radius R centred at the origin,
    outside it (unilateral phi = |q| - R >= 0), gravity -g in y, tangential speed v0 (in +x).

    On the circle q = R (sin theta, cos theta). Energy: R^2 theta'^2 / 2 + g R cos theta =
    v0^2 / 2 + g R, so the speed is v^2 = R^2 theta'^2 = v0^2 + 2 g R (1 - cos theta). Radial balance
    (the circle's normal is outward, the contact force N >= 0 pushes out): m v^2 / R =
    m g cos theta - N, so N = m (g cos theta - v^2 / R) = m (3 g cos theta - 2 g - v0^2 / R), which
    vanishes at cos theta_r = 2/3 + v0^2 / (3 g R): the release. Release time by quadrature of the
    energy equation, t_r = int_0^theta_r R dtheta / sqrt(v0^2 + 4 g R sin^2(theta / 2)) (scipy quad).
    After release the bead flies free: |q|^2 has zero first and second derivatives at t_r
    (q.v = 0, v^2 = g y there) and a positive third (-6 g v_y, v_y < 0), and (|q|^2)'' = 2 (v^2 - g y)
    grows on (v^2 grows, y falls), so the bead never returns to the circle.
    The top is an unstable equilibrium: v0 > 0 is required; v0^2 >= g R leaves at once (N < 0 at the
    top) and is refused."""
    from scipy.integrate import quad

    R, g, v0, m = float(R), float(g), float(v0), float(m)
    for name, val in (("R", R), ("g", g), ("v0", v0), ("m", m)):
        _finite(name, val, "give a finite number")
        if not val > 0.0:
            raise ValueError(f"{name} = {val!r} must be positive" + (
                " (the top of the circle is an unstable equilibrium: give the bead a tangential speed)"
                if name == "v0" else ""))
    if v0 * v0 >= g * R:
        raise ValueError(f"v0 = {v0!r}: with v0^2 >= g R = {g * R} the bead leaves the circle at once; "
                         "give v0 < sqrt(g R)")
    cos_r = 2.0 / 3.0 + v0 * v0 / (3.0 * g * R)
    th_r = math.acos(cos_r)
    t_r, _ = quad(lambda th: R / math.sqrt(v0 * v0 + 4.0 * g * R * math.sin(0.5 * th) ** 2), 0.0, th_r,
                  epsabs=0.0, epsrel=1e-13, limit=200)
    sin_r = math.sin(th_r)
    v_r = math.sqrt(v0 * v0 + 2.0 * g * R * (1.0 - cos_r))
    return BeadRelease(R, g, v0, m, cos_r, th_r, t_r, np.array([R * sin_r, R * cos_r]),
                       np.array([v_r * cos_r, -v_r * sin_r]))


# --- Newton's cradle -----------------------------------------------------------------------------

def _cradle_check(N, e, v0):
    N = int(N)
    if N < 2:
        raise ValueError(f"N = {N}: a cradle needs N >= 2 balls")
    e = _restitution(e)
    v0 = float(v0)
    _finite("v0", v0, "give a finite number")
    return N, e, v0


def newton_cradle_velocities(N, e, v0) -> np.ndarray:
    """Velocities after the impact of N equal balls in a row, all touching, the first approaching the
    others (at rest) at v0 > 0, restitution e on every contact: Moreau's simultaneous-impact law (the
    LCP of docs/derivations/contacts.md), not the sequential-impact textbook answer (for N = 3, e = 1:
    (-1/3, 2/3, 2/3) v0, where sequential pairwise impacts give (0, 0, v0)).

    Contacts phi_i = x_{i+1} - x_i - d, G rows (-1, +1) at (i, i+1), W = G G^T / m = T / m with
    T = tridiag(-1, 2, -1) of size N - 1, u- = (-v0, 0, ..., 0). With every contact active, W lam =
    -(1 + e) u- = (1 + e) v0 e_1, and (T^-1)_{i1} = (N - i) / N gives lam_i = (1 + e) m v0 (N - i) / N
    > 0, w = 0: the LCP solution (unique, W is positive definite). Then u+ = -e u-: v2 - v1 = e v0,
    v2 = ... = vN, and momentum v1 + (N - 1) v2 = v0: v1 = v0 (1 - (N - 1) e) / N,
    v2 = ... = vN = v0 (1 + e) / N. v0 <= 0 (no approach): no impact, velocities unchanged."""
    N, e, v0 = _cradle_check(N, e, v0)
    v = np.zeros(N)
    if v0 <= 0.0:
        v[0] = v0
        return v
    v[0] = v0 * (1.0 - (N - 1) * e) / N
    v[1:] = v0 * (1.0 + e) / N
    return v


def newton_cradle_impulses(N, e, v0, m=1.0) -> np.ndarray:
    """The contact impulses of `newton_cradle_velocities` (N - 1,): lam_i = (1 + e) m v0 (N - i) / N,
    i = 1..N-1 (zero for v0 <= 0)."""
    N, e, v0 = _cradle_check(N, e, v0)
    if v0 <= 0.0:
        return np.zeros(N - 1)
    i = np.arange(1, N, dtype=float)
    return (1.0 + e) * float(m) * v0 * (N - i) / N


# --- the rimless wheel (scene `rimless_wheel`) ------------------------------------------------------

class RimlessGait(NamedTuple):
    omega: float        # the angular velocity just after each impact
    eigenvalue: float   # d omega_{k+1} / d omega_k at the fixed point
    period: float       # the stride time


def rimless_wheel_stride(omega, *, alpha, gamma, g, l, **_):
    """The closed-form stride map of the rimless wheel: from theta = -alpha with angular velocity omega,
    energy to theta = alpha gives omega_-^2 = omega^2 + (4 g / l) sin(alpha) sin(gamma), and the
    plastic impact keeps the angular momentum about the new foot: omega_+ = cos(2 alpha) omega_-."""
    return math.cos(2 * alpha) * math.sqrt(omega**2 + 4 * g / l * math.sin(alpha) * math.sin(gamma))


def rimless_wheel_fixed_point(*, alpha, gamma, g, l, **_) -> RimlessGait:
    """The rimless wheel's period-one gait: omega*^2 = c^2 (4 g / l) sin(alpha) sin(gamma) / (1 - c^2),
    c = cos(2 alpha); its multiplier c^2 (omega* / omega_-(omega*) times c); its stride time by
    quadrature of dt = dtheta / omega(theta) on [-alpha, alpha] (omega(theta)^2 = omega*^2 +
    (2 g / l) (cos(gamma - alpha) - cos(theta + gamma)))."""
    from scipy.integrate import quad

    c2 = math.cos(2 * alpha) ** 2
    w2 = c2 * 4 * g / l * math.sin(alpha) * math.sin(gamma) / (1 - c2)
    if w2 + 2 * g / l * (math.cos(gamma - alpha) - 1.0) <= 0.0:
        raise ValueError(f"rimless wheel: no gait for alpha={alpha}, gamma={gamma}: the wheel does not pass "
                         "the vertical at the fixed point's speed (increase gamma or decrease alpha: the speed at the "
                         "vertical grows with the slope and falls with the spoke angle)")
    rate = lambda th: math.sqrt(w2 + 2 * g / l * (math.cos(gamma - alpha) - math.cos(th + gamma)))
    T, _ = quad(lambda th: 1.0 / rate(th), -alpha, alpha, epsabs=1e-14, epsrel=1e-13, limit=200)
    return RimlessGait(math.sqrt(w2), c2, T)
