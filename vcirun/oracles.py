"""Closed-form solutions of built-in scenes: the exact oracles against which references and runs are checked.

Plain numpy (scipy.optimize for one root): no sympy, no compiled method module, so the reference,
the studies and the tests can use them at any layer.

- `oscillator_wall_exact`: m x'' = -k x with an elastic wall at x = -d (scene `oscillator_wall`).
- `ball_exact`, `ball_position`, `ball_exact_onset`: the bouncing ball y'' = -g - (c/m) y' with
  elastic impacts on y = 0 (scene `bouncing_ball`; with drag its impacts accumulate).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["oscillator_wall_exact", "ball_exact", "ball_position", "ball_exact_onset"]


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
