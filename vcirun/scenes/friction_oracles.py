"""Closed forms of the friction scenes (derivations: docs/derivations/friction.md, "Closed forms").

Plain numpy and math (scipy.integrate.quad for the rocking block's quarter swings): no sympy, no
compiled module, so the reference, the studies and the tests can use them at any layer. Conventions
as the declarations (vcirun.mechanics.friction): the tangent of a contact with normal n is
t = (n_y, -n_x), the slip velocity v_t = W_t(q) qdot is the velocity of the contact's material point
along t, and the friction force opposes it; mu is the kinetic, mu_s the static coefficient.

- `spinning_ball`: a ball (radius R, inertia I = 2/5 m R^2) dropped with spin on a floor, plastic
  normal impact with Coulomb friction (Capobianco, Harsch, Eugster, Leine 2021, section 10.1):
  first impact, stick or slide through it, slip decaying at 7/2 mu g, rolling from then on.
- `incline`: a block (a point mass) on an incline of angle theta: sticks iff tan theta <= mu_s,
  slides with a = g (sin theta - mu cos theta), launched uphill it stops and sticks or slides back.
- `coulomb_oscillator`: m x'' + k x = -mu m g sign(x'): half swings about the shifted centres
  -+ mu m g / k, each losing 2 mu m g / k of amplitude, stopping at the first turning point with
  k |x| <= mu_s m g.
- `pushed_block`: a block on a floor pushed by a growing force c t: it sticks until c t = mu_s m g,
  then slides with m x'' = c t - mu m g.
- `housner_ratio`, `housner_stick_mu`, `housner_rocking`: a rectangular block rocking on its corners
  without sliding, omega+ / omega- = 1 - 3/2 sin^2 alpha at each plastic corner impact.
- `painleve_B`: a uniform rod sliding on one end, its normal force N = m (g - l sin(phi) phidot^2) / B
  with B = 1 + 3 cos^2 phi + 3 mu s sin phi cos phi (s the sign of the slip velocity); B <= 0
  (possible for mu > 4/3) is Painleve's paradox.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

__all__ = ["SpinningBall", "spinning_ball", "InclineMotion", "incline", "CoulombOscillator", "coulomb_oscillator",
           "PushedBlock", "pushed_block",
           "housner_ratio", "housner_stick_mu", "HousnerRocking", "housner_rocking", "painleve_B",
           "painleve_normal_force", "painleve_min_mu", "compass_gait_heel_impulse"]


def _positive(name, v):
    v = float(v)
    if not (math.isfinite(v) and v > 0.0):
        raise ValueError(f"{name}: must be a finite number > 0 (got {v!r})")
    return v


def _nonneg(name, v):
    v = float(v)
    if not (math.isfinite(v) and v >= 0.0):
        raise ValueError(f"{name}: must be a finite number >= 0 (got {v!r})")
    return v


def _sign(v) -> float:
    return 1.0 if v > 0.0 else -1.0 if v < 0.0 else 0.0


# --- the spinning ball dropped on a floor -------------------------------------------------------

class SpinningBall(NamedTuple):
    """t1, vn: time and normal speed of the first (plastic) impact; sticks: the contact sticks at the
    impact; xdot_plus, phidot_plus, slip_plus: centre velocity, spin and slip velocity just after it;
    P_n, P_t: the normal and tangential impulses; t_roll: when rolling starts (t1 if it sticks at
    the impact); xdot_roll, phidot_roll: the rolling motion from then on (x_roll: the centre's
    position at t_roll)."""

    t1: float
    vn: float
    sticks: bool
    xdot_plus: float
    phidot_plus: float
    slip_plus: float
    P_n: float
    P_t: float
    t_roll: float
    x_roll: float
    xdot_roll: float
    phidot_roll: float
    params: dict

    def state(self, t):
        """(x, y, phi, xdot, ydot, phidot) at time t (scalar): free flight, the impact at t1 (the
        state after it at t1), slipping on the floor, rolling."""
        p = self.params
        t = float(t)
        x0, y0, v0, w0, g, mu, R = p["x0"], p["h"], p["v0"], p["w0"], p["g"], p["mu"], p["R"]
        if t < self.t1:
            return np.array([x0 + v0 * t, y0 - g * t * t / 2, w0 * t, v0, -g * t, w0])
        x1, phi1 = x0 + v0 * self.t1, w0 * self.t1
        s = _sign(self.slip_plus)
        tau = min(t, self.t_roll) - self.t1   # slipping time so far
        ax, aphi = -mu * g * s, -5.0 * mu * g * s / (2.0 * R)
        x = x1 + self.xdot_plus * tau + ax * tau * tau / 2
        phi = phi1 + self.phidot_plus * tau + aphi * tau * tau / 2
        xd, phid = self.xdot_plus + ax * tau, self.phidot_plus + aphi * tau
        if t > self.t_roll:
            r = t - self.t_roll
            x, phi = x + self.xdot_roll * r, phi + self.phidot_roll * r
            xd, phid = self.xdot_roll, self.phidot_roll
        return np.array([x, R, phi, xd, 0.0, phid])


def spinning_ball(w0, *, m=1.0, R=0.1, mu=0.2, g=9.81, h=1.0, v0=0.0, x0=0.0) -> SpinningBall:
    """A ball of mass m, radius R, inertia 2/5 m R^2 (coordinates: centre x, y and the body's angle
    phi, counterclockwise), released at centre height h > R with horizontal velocity v0 and spin
    phidot = w0 onto the floor y = 0, normal restitution 0, Coulomb friction mu at the impact and
    after it (Capobianco et al. 2021, section 10.1: m = 1, R = 0.1, mu = 0.2, g = 9.81, h = 1).

    The slip velocity is xdot + R phidot (t = (1, 0) for the floor's normal (0, 1)). At the impact
    (t1 = sqrt(2 (h - R) / g), normal speed vn = g t1) the normal impulse is P_n = m vn; the impulse
    that stops the slip s0 = v0 + R w0 is P_t = -(2/7) m s0 (the effective mass of the slip is
    1 / (1/m + R^2/I) = 2 m / 7), inside the cone iff (2/7) |s0| <= mu vn: the contact sticks.
    Otherwise P_t = -mu P_n sign(s0), and the ball slides on: xdot'' = -mu g s, phidot' = -5 mu g s /
    (2 R), so the slip decays at 7/2 mu g and rolling starts |s+| / (7/2 mu g) later, at the velocity
    (5 v0 - 2 R w0) / 7 (the angular momentum about the contact point is kept), independent of mu."""
    m, R, g, h = _positive("m", m), _positive("R", R), _positive("g", g), float(h)
    mu, w0, v0, x0 = _nonneg("mu", mu), float(w0), float(v0), float(x0)
    if not h > R:
        raise ValueError(f"h: the centre must start above the floor, h > R = {R} (got {h})")
    I = 0.4 * m * R * R
    t1 = math.sqrt(2.0 * (h - R) / g)
    vn = g * t1
    Pn = m * vn
    s0 = v0 + R * w0
    meff = 1.0 / (1.0 / m + R * R / I)             # = 2 m / 7
    Pt_stick = -meff * s0
    sticks = abs(Pt_stick) <= mu * Pn
    Pt = Pt_stick if sticks else -mu * Pn * _sign(s0)
    xd, wd = v0 + Pt / m, w0 + R * Pt / I
    slip = 0.0 if sticks else xd + R * wd
    t_roll = t1 if sticks or slip == 0.0 else t1 + abs(slip) / (3.5 * mu * g)
    xr = (5.0 * v0 - 2.0 * R * w0) / 7.0
    params = {"m": m, "R": R, "mu": mu, "g": g, "h": h, "v0": v0, "w0": w0, "x0": x0}
    sol = SpinningBall(t1, vn, bool(sticks), xd, wd, slip, Pn, Pt, t_roll, 0.0, xr, -xr / R, params)
    return sol._replace(x_roll=float(sol.state(t_roll)[0]))


# --- a block on an incline ---------------------------------------------------------------------------

class InclineMotion(NamedTuple):
    """Along-slope motion s(t) (s up the slope, along t = (cos theta, sin theta) for the line through
    the origin with normal (-sin theta, cos theta)) of a point mass started at s0 with velocity v0:
    pieces [(t_start, t_end, s_start, v_start, a)] (t_end inf for the last), the stop time t_stop
    (inf if it never stops; the start when it sticks from rest) and the mode after it ("stick" or
    "slide down")."""

    pieces: list
    t_stop: float
    after_stop: str

    def state(self, t):
        """(s, sdot) at time t."""
        t = float(t)
        for t0, t1, s0, v0, a in self.pieces:
            if t <= t1:
                tau = t - t0
                return s0 + v0 * tau + a * tau * tau / 2, v0 + a * tau
        raise ValueError("t: before the start")


def incline(theta, *, mu, mu_s=None, v0=0.0, s0=0.0, g=9.81) -> InclineMotion:
    """A point mass on an incline of angle theta in (-pi/2, pi/2) (normal force m g cos theta),
    Coulomb friction mu (kinetic) and mu_s >= mu (static; default mu), started at s0 with along-slope
    velocity v0 (positive uphill). From rest it sticks iff tan |theta| <= mu_s, else it slides down at
    a = g (sin theta - mu cos theta). Moving uphill it decelerates at g (sin theta + mu cos theta) and
    stops at v0 / (g (sin theta + mu cos theta)), then sticks or slides back; moving downhill it
    decelerates at g (mu cos theta - sin theta) if mu > tan theta and stops, else it keeps sliding."""
    theta, g = float(theta), _positive("g", g)
    mu = _nonneg("mu", mu)
    mu_s = mu if mu_s is None else _nonneg("mu_s", mu_s)
    if mu_s < mu:
        raise ValueError(f"mu_s: the static coefficient must be >= mu = {mu} (got {mu_s})")
    if not abs(theta) < math.pi / 2:
        raise ValueError(f"theta: the incline's angle must lie in (-pi/2, pi/2) (got {theta})")
    sn, cs = math.sin(theta), math.cos(theta)
    pieces, t, s, v = [], 0.0, float(s0), float(v0)

    def from_rest(t, s):
        if abs(sn) <= mu_s * cs:
            pieces.append((t, math.inf, s, 0.0, 0.0))
            return "stick"
        a = -g * (sn - mu * cs * _sign(sn))   # sliding down the slope (the sign of -sin theta)
        pieces.append((t, math.inf, s, 0.0, a))
        return "slide down"

    if v == 0.0:
        after = from_rest(t, s)
        return InclineMotion(pieces, 0.0 if after == "stick" else math.inf, after)
    a = -g * sn - mu * g * cs * _sign(v)       # gravity along the slope, friction against the motion
    if _sign(a) == -_sign(v):                  # decelerating: it stops
        ts = -v / a
        pieces.append((t, ts, s, v, a))
        s_stop = s + v * ts + a * ts * ts / 2
        after = from_rest(ts, s_stop)
        return InclineMotion(pieces, ts, after)
    pieces.append((t, math.inf, s, v, a))
    return InclineMotion(pieces, math.inf, "slide down")


# --- the Coulomb-damped oscillator -------------------------------------------------------------------

class CoulombOscillator(NamedTuple):
    """x(t) of m x'' + k x = -mu m g sign(x'): turns [(t, x)] at each stop (x' = 0), the last one the
    final rest (t_stop, x_stop); pieces [(t0, t1, centre, amplitude, phase)] with
    x = centre + amplitude cos(w (t - t0) + phase) on [t0, t1]."""

    turns: list
    t_stop: float
    x_stop: float
    pieces: list
    w: float

    def state(self, t):
        """(x, xdot) at time t."""
        t = float(t)
        for t0, t1, c, A, ph in self.pieces:
            if t <= t1:
                th = self.w * (t - t0) + ph
                return c + A * math.cos(th), -A * self.w * math.sin(th)
        return self.x_stop, 0.0


def coulomb_oscillator(x0, v0=0.0, *, m=1.0, k=1.0, mu=0.1, mu_s=None, g=9.81, max_turns=100_000) -> CoulombOscillator:
    """A block (mass m) on a floor, a spring k to x = 0, Coulomb friction mu (kinetic), mu_s >= mu
    (static; default mu), started at (x0, v0). Moving with direction d = sign(x') the friction force
    is -mu m g d, so x'' = -w^2 (x + d c), w = sqrt(k/m), c = mu m g / k: a half swing about the
    centre -d c, which ends at x' = 0 after the phase reaches pi (from rest: every half period
    pi / w, the amplitude about 0 shrinking by 2 c). At a turn x it sticks iff k |x| <= mu_s m g,
    else it moves off towards 0 (d = -sign x)."""
    m, k, g = _positive("m", m), _positive("k", k), _positive("g", g)
    mu = _nonneg("mu", mu)
    mu_s = mu if mu_s is None else _nonneg("mu_s", mu_s)
    if mu_s < mu:
        raise ValueError(f"mu_s: the static coefficient must be >= mu = {mu} (got {mu_s})")
    w, c = math.sqrt(k / m), mu * m * g / k
    t, x, v = 0.0, float(x0), float(v0)
    turns, pieces = [], []
    for _ in range(max_turns):
        if v == 0.0:
            if k * abs(x) <= mu_s * m * g:
                if not turns or turns[-1] != (t, x):
                    turns.append((t, x))   # (a start at rest that sticks)
                return CoulombOscillator(turns, t, x, pieces, w)
            d = -_sign(x)
        else:
            d = _sign(v)
        centre = -d * c
        # x - centre = A cos(th), x' = -A w sin(th), th' = w; moving with direction d the phase lies in
        # (-pi, 0) (d > 0, ending at th = 0: x = centre + A) or in (0, pi) (d < 0, ending at pi)
        A = math.hypot(x - centre, v / w)
        ph = math.atan2(-v / w, x - centre)
        if d > 0:
            ph, end = (ph - 2.0 * math.pi if ph > 0.0 else ph), 0.0
        else:
            ph, end = (ph + 2.0 * math.pi if ph < 0.0 else ph), math.pi
        dt = (end - ph) / w
        pieces.append((t, t + dt, centre, A, ph))
        t, x, v = t + dt, centre + A * math.cos(end), 0.0
        turns.append((t, x))
    raise ValueError(f"max_turns: more than {max_turns} half swings (mu = {mu} too small for this amplitude?)")


# --- a block pushed by a growing force ------------------------------------------------------------------

class PushedBlock(NamedTuple):
    """t_slip: when the block starts to slide; state(t) = (x, xdot)."""

    t_slip: float
    params: dict

    def state(self, t):
        p = self.params
        t, ts, c, m, g = float(t), self.t_slip, p["c"], p["m"], p["g"]
        if t <= ts:
            return 0.0, 0.0
        # in d = t - t_s (c t_s = mu_s m g): no difference of the large t^3 and t_s^3 when t_s is long
        d, a0 = t - ts, (p["mu_s"] - p["mu"]) * g
        return a0 * d * d / 2 + c * d ** 3 / (6 * m), a0 * d + c * d * d / (2 * m)


def pushed_block(*, c, mu, mu_s=None, m=1.0, g=9.81) -> PushedBlock:
    """A block of mass m at rest on a floor, pushed along it by the force c t (c > 0): the tangential
    force that holds it is c t, inside the static cone until t_slip = mu_s m g / c; from then on it
    slides, m x'' = c t - mu m g (x''(t_slip) = (mu_s - mu) g >= 0, so the slip never ends):
    x = (mu_s - mu) g (t - t_s)^2 / 2 + c (t - t_s)^3 / (6 m)."""
    c, m, g = _positive("c", c), _positive("m", m), _positive("g", g)
    mu = _nonneg("mu", mu)
    mu_s = mu if mu_s is None else _nonneg("mu_s", mu_s)
    if mu_s < mu:
        raise ValueError(f"mu_s: the static coefficient must be >= mu = {mu} (got {mu_s})")
    return PushedBlock(mu_s * m * g / c, {"c": c, "m": m, "g": g, "mu": mu, "mu_s": mu_s})


# --- Housner's rocking block -------------------------------------------------------------------------

def _alpha(a, b) -> float:
    return math.atan2(_positive("b", b), _positive("a", a))


def housner_ratio(a, b) -> float:
    """omega+ / omega- at a plastic corner impact of a rectangular block (height a, width b, uniform)
    rocking without sliding: 1 - 3/2 sin^2 alpha, alpha = atan(b / a) (the angular momentum about the
    impacting corner is kept). Housner's picture, in which the old corner lifts off, needs this ratio
    > 0: b / a < sqrt(2); a wider block would press its old corner in too."""
    return 1.0 - 1.5 * math.sin(_alpha(a, b)) ** 2


def housner_stick_mu(a, b) -> float:
    """The least friction coefficient for which the corner impact sticks: |P_t| / P_n =
    3 sin alpha cos alpha / (4 - 3 sin^2 alpha)."""
    al = _alpha(a, b)
    return 3.0 * math.sin(al) * math.cos(al) / (4.0 - 3.0 * math.sin(al) ** 2)


class HousnerRocking(NamedTuple):
    """Rocking from rest at the tilt theta0 (> 0: on the right corner): impact times, the angular
    velocities just before and after each impact, and the tilt amplitudes after each."""

    impact_times: list
    omega_minus: list
    omega_plus: list
    amplitudes: list


def housner_rocking(theta0, *, a, b, g=9.81, impacts=3) -> HousnerRocking:
    """The block rocking without sliding and without bouncing, from rest at tilt theta0 (0 < theta0 <
    alpha: it falls back), on its corners alternately. About a corner O, with R the half diagonal and
    I_O = 4/3 m R^2, the centre's height is R cos(alpha - th) at the tilt th, so energy gives
    omega^2 = k (cos(alpha - A) - cos(alpha - th)), k = 3 g / (2 R), from the amplitude A (at rest);
    a quarter swing from A to the flat position takes int_0^A dth / omega (by quadrature, with
    th = A - u^2 removing the end point's inverse square root). At each impact omega+ =
    housner_ratio(a, b) omega-, and the next amplitude A' solves k (cos(alpha - A') - cos alpha) =
    omega+^2."""
    from scipy.integrate import quad

    a, b, g = _positive("a", a), _positive("b", b), _positive("g", g)
    al = _alpha(a, b)
    R = 0.5 * math.hypot(a, b)
    theta0 = float(theta0)
    if not 0.0 < theta0 < al:
        raise ValueError(f"theta0: the tilt must lie in (0, alpha = {al:.6g}) to rock back (got {theta0})")
    r = housner_ratio(a, b)
    if not r > 0.0:
        raise ValueError(f"b: a block with b / a = {b / a:.6g} >= sqrt(2) does not rock on its corners (the old "
                         "corner would not lift off at an impact); give a slenderer block")
    k = 3.0 * g / (2.0 * R)

    def quarter(A):
        def f(u):
            if u == 0.0:
                return 2.0 / math.sqrt(k * math.sin(al - A))
            # cos(al - A) - cos(al - th) at th = A - u^2, without cancellation
            d = 2.0 * math.sin(al - A + u * u / 2) * math.sin(u * u / 2)
            return 2.0 * u / math.sqrt(k * d)

        val, _ = quad(f, 0.0, math.sqrt(A), epsabs=0.0, epsrel=2e-14, limit=200)
        return val

    times, wm, wp, amps = [], [], [], []
    t, A = quarter(theta0), theta0   # the first fall; then up to each amplitude and back: two quarters
    for _ in range(int(impacts)):
        w_minus = math.sqrt(k * 2.0 * math.sin(al - A / 2) * math.sin(A / 2))
        w_plus = r * w_minus
        times.append(t)
        wm.append(w_minus)
        wp.append(w_plus)
        A = al - math.acos(min(math.cos(al) + w_plus * w_plus / k, 1.0))
        amps.append(A)
        t += 2.0 * quarter(A)
    return HousnerRocking(times, wm, wp, amps)


# --- the compass gait's heel strike --------------------------------------------------------------------

def compass_gait_heel_impulse(q_minus, qd_minus, qd_plus, *, m, mH, a, b, gamma, **_):
    """(P_n, P_t) of the compass gait's heel strike (the built-in `compass_gait`: q = (theta_s,
    theta_ns) from the slope normal, point masses m at a from each foot, mH at the hip; the reset
    exchanges the legs): the impulse on the walker at the new stance foot, P = sum_i m_i (v_i+ - v_i-)
    (Goswami's model: the old stance foot leaves without impulse), along the slope's normal
    n = (-sin gamma, cos gamma) and tangent t = (cos gamma, sin gamma). A point at r along a leg of
    absolute angle phi = theta + gamma from the vertical moves at r phidot (-cos phi, -sin phi) about
    its foot; the swing leg's mass at b below the hip at the hip's velocity + b phidot (cos phi, sin phi).
    The stance foot sticks through the impact iff |P_t| <= mu P_n."""
    l = a + b
    ps, pn = q_minus[0] + gamma, q_minus[1] + gamma
    ws, wn = qd_minus
    # after: the old swing leg stands (angle pn, rate qd_plus[0]), the old stance leg swings (ps, qd_plus[1])
    ws2, wn2 = qd_plus

    def rot(phi):
        return np.array([-math.cos(phi), -math.sin(phi)])

    def swing(phi):
        return np.array([math.cos(phi), math.sin(phi)])

    hip_m, hip_p = l * ws * rot(ps), l * ws2 * rot(pn)
    old_stance_mass = (a * ws * rot(ps), hip_p + b * wn2 * swing(ps))   # (before, after: now the swing leg's)
    old_swing_mass = (hip_m + b * wn * swing(pn), a * ws2 * rot(pn))   # (before, after: now the stance leg's)
    P = m * (old_stance_mass[1] - old_stance_mass[0]) + mH * (hip_p - hip_m) + m * (old_swing_mass[1] - old_swing_mass[0])
    n = np.array([-math.sin(gamma), math.cos(gamma)])
    t = np.array([math.cos(gamma), math.sin(gamma)])
    return float(P @ n), float(P @ t)


# --- Painleve's rod ----------------------------------------------------------------------------------

def painleve_B(phi, mu, s):
    """B of a uniform rod (length 2 l, mass m, inertia m l^2 / 3 about its centre) at angle phi from
    the floor, sliding on its lower end with slip direction s = sign(v_t) in {+1, -1}: the held
    normal acceleration is N B / m + (l sin(phi) phidot^2 - g), B = 1 + 3 cos^2 phi + 3 mu s sin phi
    cos phi. (The rod's end A = C - l (cos phi, sin phi), slip velocity xdot + l sin(phi) phidot.)"""
    phi = np.asarray(phi, float)
    return 1.0 + 3.0 * np.cos(phi) ** 2 + 3.0 * float(mu) * float(s) * np.sin(phi) * np.cos(phi)


def painleve_normal_force(phi, phidot, *, mu, s, m=1.0, l=1.0, g=9.81):
    """N = m (g - l sin(phi) phidot^2) / B of the sliding rod (B > 0; NaN where B <= 0: no unique
    force, Painleve's paradox)."""
    B = painleve_B(phi, mu, s)
    N = m * (g - l * np.sin(phi) * np.asarray(phidot, float) ** 2) / np.where(B > 0, B, np.nan)
    return N


def painleve_min_mu() -> float:
    """B(phi) > 0 for every phi iff mu < 4/3: min over phi of B = 5/2 - 3/2 sqrt(1 + mu^2)."""
    return 4.0 / 3.0
