"""The exact reference against every closed form of the project, over random states (hypothesis):
the oscillator against a wall, the ball in a box (e = 1; one e < 1; a restitution per wall, the floor's
impacts accumulating into rest while the ball still crosses the box; any size, gravity (0 included), mass and
restitution (plastic included), from inside or from a wall), Newton's cradle, the Zeno ball
and the bead leaving the circle. Zero wrong event sequences: the same contacts in the same order as the
closed form, impact times to 1e-11 and positions on a dense grid to 1e-10 or better, and a finite
self-reported accuracy that bounds the error.

About 200 random states in the default suite (derandomized: the same states every run) and ten times
as many, new ones each run, under `-m slow`.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import vcirun
from vcirun.mechanics.loader import load_system_yaml
from vcirun.scenes.oracles import (ball_in_box_exact, bead_release, newton_cradle_impulses, newton_cradle_velocities,
                                   oscillator_wall_exact, zeno_ball)


def _settings(n, slow):
    return settings(max_examples=10 * n if slow else n, deadline=None, derandomize=not slow, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])


def _both(n, *strategies):
    """The default-suite test of `check` over `strategies` and its slow twin (ten times the states,
    fresh ones each run)."""
    def deco(check):
        names = [f"a{i}" for i in range(len(strategies))]

        def make(slow):
            ns = {"check": check}
            exec(f"def run({', '.join(names)}):\n    check({', '.join(names)})\n", ns)   # hypothesis wants named args
            run = ns["run"]
            run.__name__ = run.__qualname__ = "test_" + check.__name__.strip("_") + ("_slow" if slow else "")
            return _settings(n, slow)(given(**dict(zip(names, strategies)))(run))
        return make(False), pytest.mark.slow(make(True))
    return deco


def _num(lo, hi):
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False, allow_subnormal=False)


def _checked(ref, err):
    """The reference's own accuracy is finite and not below the error measured here."""
    assert np.isfinite(ref.accuracy)
    assert err <= max(ref.accuracy, 1e-15) * 10.0, (err, ref.accuracy)


# --- the oscillator against a wall -----------------------------------------------------------------

def _oscillator(x0, v0, m, k, d):
    A = math.hypot(x0, v0 / math.sqrt(k / m))
    assume(abs(A - d) > 1e-6 * d)            # not grazing: the closed form's impact phase arccos(-d / A)
    T = 12.0
    ref = vcirun.reference("oscillator_wall", T=T, q0=[x0], p0=[m * v0], params={"m": m, "k": k, "d": d})
    tt = np.linspace(0.0, T, 2001)
    x, _, ti = oscillator_wall_exact(tt, x0, v0, m, k, d)
    ti = ti[ti <= T]
    assert len(ref.impacts) == len(ti)
    if len(ti):
        assert np.max(np.abs(ref.impacts - ti)) <= 1e-11 / min(1.0, math.sqrt(abs(A / d - 1.0)))
    err = float(np.max(np.abs(ref(tt)[:, 0] - x)))
    assert err <= 1e-11 / min(1.0, math.sqrt(abs(A / d - 1.0)))
    assert np.isfinite(ref.accuracy)


def _oscillator_wall(x0, v0, m, k, d):
    _oscillator(max(x0, -d), v0, m, k, d)


test_oscillator_wall, test_oscillator_wall_slow = _both(
    30, _num(-0.2, 3.0), _num(-3.0, 3.0), _num(0.5, 2.0), _num(0.5, 4.0), _num(0.2, 1.0))(_oscillator_wall)


# --- the ball in a box -------------------------------------------------------------------------------

def _zeno_tail(ref, it, ic):
    """The closed form's floor impacts after the reference's last resolved one (the Zeno tail the
    reference holds instead of resolving) are left out."""
    floor = ref.impacts[ref.impact_contact == 0]
    if not any(0 in iv[2] for iv in ref.held_intervals) or not len(floor):
        return it, ic
    keep = ~((ic == 0) & (it > floor[-1] + 1e-12))
    return it[keep], ic[keep]


def _box(x0, y0, vx, vy, e, T=5.0, width=1.0, height=1.0, g=9.81, m=1.0):
    params = {"e": e, "width": width, "height": height, "g": g, "m": m}
    ref = vcirun.reference("ball_in_box", T=T, q0=[x0, y0], p0=[m * vx, m * vy], params=params)
    # on a wall or within round-off of it (1e-12), a normal velocity within the rest tolerance (1e-12
    # relative) is zero to the reference (vcirun.reference_solution.held: at rest on it), not an impact of
    # impulse 1e-278 as the closed form would have it (y0 = 2e-241 with vy = -3e-204 hits it at t = 7e-38):
    # the closed form starts on the wall at rest there
    if min(x0, width - x0) <= 1e-12 and abs(vx) <= 1e-12:
        x0, vx = (0.0 if x0 <= width / 2 else width), 0.0
    if min(y0, height - y0) <= 1e-12 and abs(vy) <= 1e-12:
        y0, vy = (0.0 if y0 <= height / 2 else height), 0.0
    tt = np.linspace(0.0, T, 2001)
    ex = ball_in_box_exact(tt, x0, y0, vx, vy, width=width, height=height, g=g, e=e, m=m)
    it, ic = _zeno_tail(ref, ex.impact_times, ex.impact_contact)
    assert list(ref.impact_contact) == list(ic)
    if len(it):
        assert np.max(np.abs(ref.impacts - it)) <= 1e-11
    err = float(np.max(np.abs(ref(tt) - np.column_stack([ex.x, ex.y]))))
    assert err <= 1e-10
    _checked(ref, err)
    return ref


_BOX = (_num(0.001, 0.999), _num(0.001, 0.999), _num(-5.0, 5.0), _num(-5.0, 5.0))

def _box_elastic(x0, y0, vx, vy):
    _box(x0, y0, vx, vy, 1.0)


def _box_restitution(x0, y0, vx, vy, e):
    _box(x0, y0, vx, vy, e)


test_box_elastic, test_box_elastic_slow = _both(40, *_BOX)(_box_elastic)
test_box_restitution, test_box_restitution_slow = _both(40, *_BOX, _num(0.2, 0.98))(_box_restitution)


def _box_any_size(width, height, g, m, e, xf, yf, vx, vy, T, start):
    """Any box, gravity (0 included), mass and restitution (plastic included), from inside or from a wall."""
    x0, y0 = xf * width, yf * height
    if start == "floor":
        y0 = 0.0
    elif start == "floor at rest":
        y0, vy = 0.0, 0.0
    elif start == "left wall":
        x0 = 0.0
    elif start == "right wall":
        x0 = width
    _box(x0, y0, vx, vy, e, T=T, width=width, height=height, g=g, m=m)


test_box_any_size, test_box_any_size_slow = _both(
    20, _num(0.3, 3.0), _num(0.3, 3.0), st.one_of(st.just(0.0), _num(0.5, 20.0)), _num(0.5, 2.0),
    st.one_of(st.sampled_from([0.0, 1.0]), _num(0.0, 1.0)), _num(0.0, 1.0), _num(0.0, 1.0), _num(-8.0, 8.0),
    _num(-8.0, 8.0), _num(1.0, 8.0), st.sampled_from(["inside", "floor", "floor at rest", "left wall", "right wall"]))(
    _box_any_size)


def test_box_plastic_impact_on_the_floor_beside_the_side_wall_it_rests_on():
    """e = 0: the right wall stops vx, the floor then stops vy with the ball touching the right wall (no
    velocity into it): one impact entry for the floor, none for the wall (its LCP impulse is round-off)."""
    ref = _box(0.35757012864373, 0.3012369723640788, 5.005737644784066,
               4.146307720491883, 0.0, T=8.263411722337514, width=0.406935060839306, height=1.5226130362523007,
               m=1.3898425897784683)
    assert list(ref.impact_contact) == [3, 0]


def test_box_state_with_a_ceiling_impact_a_long_step_would_span():
    """A ceiling impact inside a free flight that one long DOP853 step spans (its error estimate vanishes on
    the parabola; a sign test sees 13 impacts of 15): all 15, times to 1e-11."""
    ref = _box(0.2214, 0.406, -0.1352, 3.5858, 1.0)
    assert len(ref.impacts) == 15 and ref.kind == "taylor"


# --- a restitution per wall (a closed form written here: the x and y motions decouple) ----------------

BOX4 = {"name": "box_per_wall", "coordinates": ["x", "y"],
        "parameters": {"m": 1.0, "g": 9.81, "width": 1.0, "height": 1.0, "ef": 0.5, "ec": 0.9, "el": 0.8,
                       "er": 1.0},
        "mass_matrix": [["m", "0"], ["0", "m"]], "potential": "m*g*y",
        "constraints": [{"name": "floor", "phi": "y", "restitution": "ef"},
                        {"name": "ceiling", "phi": "height - y", "restitution": "ec"},
                        {"name": "left", "phi": "x", "restitution": "el"},
                        {"name": "right", "phi": "width - x", "restitution": "er"}]}


def _walls_x(T, x0, v0, W, el, er):
    segs, imps = [(0.0, x0, v0)], []
    t, x, v = 0.0, x0, v0
    while v != 0.0:
        s, c, wall, e = ((W - x) / v, 3, W, er) if v > 0.0 else (x / -v, 2, 0.0, el)
        if t + s > T:
            break
        t += s
        imps.append((t, c))
        x, v = wall, -e * v
        segs.append((t, x, v))
    return segs, imps


def _walls_y(T, y0, v0, H, g, ef, ec, cut=1e-9):
    """Floor (ef) and ceiling (ec) under gravity: flights to a wall, then, once the ball leaves the
    floor with w^2 <= 2 g H, the geometric bounces t_j = ta + (2 w / g)(1 - ef^j) / (1 - ef) and rest
    from ta + 2 w / (g (1 - ef)). Returns (parabola segments, impacts, (ta, w) or None)."""
    segs, imps = [(0.0, y0, v0)], []
    t, y, v = 0.0, y0, v0
    while True:
        if y == 0.0 and v >= 0.0 and v * v <= 2.0 * g * H:
            w, j = v, 1
            while w > 0.0 and ef > 0.0:
                tj = t + (2.0 * v / g) * (1.0 - ef ** j) / (1.0 - ef)
                if tj > T or 2.0 * w / g < cut:
                    break
                imps.append((tj, 0))
                w *= ef
                j += 1
            return segs, imps, (t, v)
        D = math.sqrt(v * v + 2.0 * g * y)
        s, c, vin = ((v + D) / g if v >= 0.0 else 2.0 * y / (D - v)), 0, D
        disc = v * v - 2.0 * g * (H - y)
        if v > 0.0 and disc > 0.0:
            s, c, vin = 2.0 * (H - y) / (v + math.sqrt(disc)), 1, math.sqrt(disc)
        if t + s > T:
            return segs, imps, None
        t += s
        imps.append((t, c))
        y, v = (0.0, ef * vin) if c == 0 else (H, -ec * vin)
        segs.append((t, y, v))


def _y_at(tt, segs, geo, g, ef):
    ts = np.array([s[0] for s in segs])
    i = np.searchsorted(ts, tt, side="right") - 1
    s = tt - ts[i]
    y = np.array([segs[k][1] for k in i]) + np.array([segs[k][2] for k in i]) * s - 0.5 * g * s * s
    if geo is not None:
        ta, w = geo
        rest = ta + (2.0 * w / (g * (1.0 - ef)) if ef < 1.0 else math.inf)
        for k, t in enumerate(tt):
            if t >= ta:
                if t >= rest:
                    y[k] = 0.0
                    continue
                tj, wj = ta, w
                while True:
                    d = 2.0 * wj / g
                    if t < tj + d or d == 0.0:
                        break
                    tj, wj = tj + d, wj * ef
                y[k] = wj * (t - tj) - 0.5 * g * (t - tj) ** 2
    return y


_SYSTEMS = {}


def _system(spec):
    """A YAML-declared system, built once per process."""
    if spec["name"] not in _SYSTEMS:
        _SYSTEMS[spec["name"]] = load_system_yaml(spec)
    return _SYSTEMS[spec["name"]]


def _box4(box4, x0, y0, vx, vy, ef, ec, el, er, T=6.0):
    prm = {"ef": ef, "ec": ec, "el": el, "er": er}
    ref = vcirun.reference(box4, T=T, q0=[x0, y0], p0=[vx, vy], params=prm)
    xs, xi = _walls_x(T, x0, vx, 1.0, el, er)
    ys, yi, geo = _walls_y(T, y0, vy, 1.0, 9.81, ef, ec)
    ev = sorted(xi + yi)
    it, ic = _zeno_tail(ref, np.array([a for a, _ in ev]), np.array([c for _, c in ev], np.int64))
    assert list(ref.impact_contact) == list(ic)
    if len(it):
        assert np.max(np.abs(ref.impacts - it)) <= 1e-11
    tt = np.linspace(0.0, T, 1201)
    tx = np.array([s[0] for s in xs])
    j = np.searchsorted(tx, tt, side="right") - 1
    x = np.array([xs[k][1] + xs[k][2] * (t - xs[k][0]) for k, t in zip(j, tt)])
    y = _y_at(tt, ys, geo, 9.81, ef)
    err = float(np.max(np.abs(ref(tt) - np.column_stack([x, y]))))
    assert err <= 1e-10
    _checked(ref, err)
    if geo is not None and ef < 1.0 and geo[0] + 2.0 * geo[1] / (9.81 * (1.0 - ef)) < T - 1e-6:
        assert ref.held_intervals and ref.held_intervals[-1][2] == (0,) and ref.held_intervals[-1][1] == T


_E = _num(0.2, 1.0)
def _box_per_wall(x0, y0, vx, vy, ef, ec, el, er):
    _box4(_system(BOX4), x0, y0, vx, vy, ef, ec, el, er)


test_box_per_wall, test_box_per_wall_slow = _both(30, *_BOX, _num(0.2, 0.95), _E, _E, _E)(_box_per_wall)


# --- Newton's cradle -----------------------------------------------------------------------------------

def _cradle(N, gap, v0, e, m, d):
    params = {"e": e, "m": m, "d": d}
    q0 = np.array([-gap] + [d * k for k in range(1, N)])
    p0 = np.zeros(N)
    p0[0] = m * v0
    t_hit = gap / v0   # the first contact x2 - x1 - d closes from gap at the speed v0
    T = t_hit + 1.0
    ref = vcirun.reference(f"newton_cradle_{N}", T=T, q0=q0, p0=p0, params=params)
    assert list(ref.impact_contact) == list(range(N - 1))        # one simultaneous impact, every contact
    assert np.max(np.abs(ref.impacts - t_hit)) <= 1e-13 * (1.0 + t_hit)
    np.testing.assert_allclose(ref.impact_impulse, newton_cradle_impulses(N, e, v0, m), rtol=1e-12, atol=1e-14)
    v = ref.p(T) / m
    np.testing.assert_allclose(v, newton_cradle_velocities(N, e, v0), rtol=0, atol=1e-13 * v0)
    x_T = q0 + v0 * np.eye(N)[0] * t_hit + v * (T - t_hit)
    assert np.max(np.abs(ref(T) - x_T)) <= 1e-12
    assert np.isfinite(ref.accuracy)


test_cradle, test_cradle_slow = _both(
    20, st.integers(2, 5), _num(0.01, 0.5), _num(0.1, 3.0), _num(0.0, 1.0), _num(0.5, 2.0), _num(0.05, 0.3))(_cradle)


# --- the Zeno ball ----------------------------------------------------------------------------------------

ZENO = {"name": "zeno_ball", "coordinates": ["y"], "parameters": {"g": 9.81, "m": 1.0, "e": 0.8},
        "mass_matrix": [["m"]], "potential": "m*g*y",
        "constraints": [{"name": "floor", "phi": "y", "restitution": "e"}]}


def _zeno(system, y0, v0, g, e):
    assume(y0 == 0.0 or y0 > 1e-9)   # within the rest tolerance of the floor (1e-12) is on it ...
    assume(y0 > 0.0 or v0 == 0.0 or abs(v0) > 1e-9)   # ... and so is a speed within it
    z = zeno_ball(y0, v0, g, e)
    T = z.t_inf + 0.5 if np.isfinite(z.t_inf) else z.t1 + 2.0
    ref = vcirun.reference(system, T=T, q0=[y0], p0=[v0], params={"g": g, "e": e})
    n = len(ref.impacts)
    if y0 == 0.0 and v0 == 0.0:     # at rest on the floor: held from the start
        assert n == 0 and ref.held_intervals == [(0.0, T, (0,))]
    elif e > 0.0:
        assert n >= 1
        assert np.max(np.abs(ref.impacts - z.impact_times(n))) <= 1e-11 * (1.0 + z.t_inf)
    if e < 1.0:   # held from the Zeno time (exact for constant gravity) to T
        t0, t1, held = ref.held_intervals[-1]
        assert held == (0,) and t1 == T and abs(t0 - z.t_inf) <= 1e-11 * (1.0 + z.t_inf)
    tt = np.linspace(0.0, T, 2001)
    err = float(np.max(np.abs(ref(tt)[:, 0] - z.state(tt)[0])))
    assert err <= 1e-11 * (1.0 + y0 + v0 * v0 / g)
    assert np.isfinite(ref.accuracy)


def _zeno_ball(y0, v0, g, e):
    _zeno(_system(ZENO), y0, v0, g, e)


test_zeno_ball, test_zeno_ball_slow = _both(20, _num(0.0, 2.0), _num(-3.0, 3.0), _num(2.0, 20.0), _num(0.0, 0.9))(
    _zeno_ball)


# --- the bead leaving the circle -------------------------------------------------------------------------

BEAD = {"name": "bead_on_circle", "coordinates": ["x", "y"], "parameters": {"g": 9.81, "R": 1.0, "m": 1.0},
        "mass_matrix": [["m", "0"], ["0", "m"]], "potential": "m*g*y",
        "constraints": [{"name": "surface", "phi": "sqrt(x**2 + y**2) - R", "restitution": 0.0}]}


def _bead(R, g, frac, m, after):
    v0 = frac * math.sqrt(g * R)
    b = bead_release(R, g, v0, m)
    T = b.t_r + after
    ref = vcirun.reference(_system(BEAD), T=T, q0=[0.0, R], p0=[m * v0, 0.0], params={"R": R, "g": g, "m": m})
    assert list(ref.release_contact) == [0] and len(ref.impacts) == 0
    assert abs(ref.releases[0] - b.t_r) <= 1e-10 * (1.0 + b.t_r)
    tt = np.linspace(0.0, T, 1201)
    err = float(np.max(np.abs(ref(tt) - b.state(tt)[0])))
    assert err <= 1e-10 * R
    assert np.isfinite(ref.accuracy)


test_bead, test_bead_slow = _both(20, _num(0.5, 2.0), _num(2.0, 20.0), _num(0.05, 0.95), _num(0.5, 2.0),
                                  _num(0.05, 1.0))(_bead)
