"""The closed-form oracles of several contacts (vcirun.scenes.oracles; docs/derivations/contacts.md, section 4), each
against an independent numerical solve written here from the equations of motion:

  * ball_in_box_exact, zeno_ball: scipy solve_ivp (DOP853) on the unconstrained equations with one
    terminal event per wall (phi_i(q) = 0, decreasing), and at each event the impact law of the walls
    that are closed (|phi_i| <= 1e-10) as an LCP solved by NNLS (W = G M^-1 G^T), so a corner is two
    simultaneous contacts here too;
  * bead_release: the motion on the circle as the 1-DOF ODE R theta'' = g sin theta with a release
    event on the normal force N / m = g cos theta - R theta'^2, then the free flight in Cartesian
    coordinates;
  * newton_cradle_velocities / _impulses: the LCP of N touching balls solved by NNLS.
Tolerances 1e-9 (relative to the scale of each quantity) or tighter.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import nnls

from vcirun.scenes.oracles import (ball_in_box_exact, bead_release, newton_cradle_impulses, newton_cradle_velocities, zeno_ball)

RTOL, ATOL = 1e-13, 1e-15


def _lcp(W, q):
    """lam >= 0, q + W lam >= 0, complementary, for SPD W (the QP min 1/2 lam W lam + q lam)."""
    L = np.linalg.cholesky(W)
    return nnls(L.T, -np.linalg.solve(L, q))[0]


# --- an event-driven solve of a point mass among walls ------------------------------------------------

def _walls_solve(T, z0, walls, g, e, m=1.0, max_events=400):
    """Point mass m in the plane, z = (x, y, vx, vy), gravity -g in y, walls phi_i = a_i . (x, y) + b_i
    >= 0 with restitution e_i. Returns (impacts [(t, i, lam)], segments [(t_start, t_end, dense sol)])."""
    A = np.array([w[0] for w in walls], float)
    b = np.array([w[1] for w in walls], float)
    e = np.broadcast_to(np.asarray(e, float), (len(walls),))

    def rhs(t, z):
        return [z[2], z[3], 0.0, -g]

    def event(i):
        f = lambda t, z: A[i] @ z[:2] + b[i]
        f.terminal, f.direction = True, -1
        return f

    events = [event(i) for i in range(len(walls))]
    t, z, imps, segs = 0.0, np.asarray(z0, float), [], []
    while t < T and len(imps) < max_events:
        # max_step: an event function that dips below zero and back within one step would be missed
        sol = solve_ivp(rhs, (t, T), z, method="DOP853", rtol=RTOL, atol=ATOL, events=events, dense_output=True,
                        max_step=0.01)
        segs.append((t, sol.t[-1], sol.sol))
        if sol.status != 1:
            break
        t, z = sol.t[-1], sol.y[:, -1].copy()
        phi, u = A @ z[:2] + b, A @ z[2:] / 1.0
        closed = np.flatnonzero(np.abs(phi) <= 1e-10)
        G = A[closed]
        W = G @ G.T / m
        lam = _lcp(W, (1 + e[closed]) * (G @ z[2:]))
        z[2:] += G.T @ lam / m
        for i, li in zip(closed, lam):
            if li > 0.0:
                imps.append((t, int(i), li))
    return imps, segs


def _dense(segs, t):
    out = np.empty((len(t), 4))
    for k, tk in enumerate(t):
        for a, bnd, s in segs:
            if a <= tk <= bnd:
                out[k] = s(tk)
    return out


BOX = dict(width=1.0, height=1.2)
BOX_WALLS = [((0.0, 1.0), 0.0), ((0.0, -1.0), 1.2), ((1.0, 0.0), 0.0), ((-1.0, 0.0), 1.0)]


@pytest.mark.parametrize("e", [1.0, 0.9, 0.6])
@pytest.mark.parametrize("start", [(0.3, 0.5, 0.7, 4.0), (0.9, 1.1, -2.3, 1.5), (0.5, 0.2, 0.0, -1.0)])
def test_ball_in_box_against_event_driven_solve(e, start):
    """Impact sequence (times, contacts, impulses) and states against the event-driven solve, up to
    T = 2.5 or 0.01 before the floor impacts accumulate; the first start reaches the ceiling."""
    g, m = 9.81, 1.7
    T = min(2.5, ball_in_box_exact([100.0], *start, **BOX, g=g, e=e).t_rest - 0.01)
    imps, segs = _walls_solve(T, start, BOX_WALLS, g, e, m=m)
    t = np.linspace(0.0, T, 401)
    ex = ball_in_box_exact(t, *start, **BOX, g=g, e=e, m=m)
    ref_t = np.array([a for a, _, _ in imps])
    assert ex.impact_contact.tolist() == [i for _, i, _ in imps]
    assert np.max(np.abs(ex.impact_times - ref_t)) <= 1e-9 * T
    assert np.max(np.abs(ex.impact_impulse - [lam for _, _, lam in imps])) <= 1e-9 * max(1.0, ex.impact_impulse.max())
    z = _dense(segs, t)
    # away from impact times (a state is right-continuous there, the dense output two-sided)
    far = np.min(np.abs(t[:, None] - ref_t[None, :]), axis=1) > 1e-6 if ref_t.size else np.ones(t.size, bool)
    for k, arr in enumerate((ex.x, ex.y, ex.vx, ex.vy)):
        assert np.max(np.abs(arr[far] - z[far, k])) <= 1e-9 * max(1.0, np.max(np.abs(z[:, k])))
    if e == 1.0 and start[3] == 4.0:
        assert 1 in ex.impact_contact  # the ceiling is reached


def test_ball_in_box_corner_hit_gives_two_entries_at_the_same_time():
    """x0 = 0.5, vx0 = -0.5 / t_y reaches x = 0 when the drop from y0 = 0.3 reaches the floor,
    t_y = sqrt(2 y0 / g): a corner hit (floor and left wall), two entries at one time, floor first;
    the event-driven solve sees the two closed walls at once and its LCP gives the same impulses."""
    g, y0 = 9.81, 0.3
    ty = np.sqrt(2 * y0 / g)
    start = (0.5, y0, -0.5 / ty, 0.0)
    for e in (1.0, 0.8):
        ex = ball_in_box_exact([0.0, 1.0], *start, **BOX, g=g, e=e)
        imps, _ = _walls_solve(1.0, start, BOX_WALLS, g, e)
        assert ex.impact_contact[:2].tolist() == [0, 2]
        assert ex.impact_times[0] == ex.impact_times[1]
        assert abs(ex.impact_times[0] - ty) <= 1e-14
        assert [i for _, i, _ in imps[:2]] == [0, 2] and abs(imps[0][0] - imps[1][0]) <= 1e-12
        assert np.max(np.abs(ex.impact_times - [a for a, _, _ in imps])) <= 1e-9
        assert np.max(np.abs(ex.impact_impulse - [lam for _, _, lam in imps])) <= 1e-9


def test_ball_in_box_without_gravity_and_at_rest():
    """g = 0: both axes bounce at constant speed (times against the event-driven solve); a ball
    starting on the floor at rest rests there (t_rest = 0) while it slides in x."""
    start = (0.2, 0.4, 0.9, -0.7)
    imps, _ = _walls_solve(6.0, start, BOX_WALLS, 0.0, 0.7)
    ex = ball_in_box_exact([6.0], *start, **BOX, g=0.0, e=0.7)
    assert ex.impact_contact.tolist() == [i for _, i, _ in imps]
    assert np.max(np.abs(ex.impact_times - [a for a, _, _ in imps])) <= 1e-12
    rest = ball_in_box_exact([0.0, 0.5, 2.0], 0.5, 0.0, 0.3, 0.0, **BOX, g=9.81, e=0.5)
    assert rest.t_rest == 0.0 and np.all(rest.y == 0.0) and np.all(rest.vy == 0.0)
    assert rest.impact_contact.tolist() == [3] and np.allclose(rest.vx, [0.3, 0.3, -0.5 * 0.3], rtol=1e-15)


def test_ball_in_box_settles_like_the_zeno_ball():
    """Vertical drop below the ceiling: the box's floor impacts and rest time are the Zeno ball's."""
    ex = ball_in_box_exact(np.linspace(0, 6, 61), 0.5, 1.0, 0.0, 0.0, **BOX, g=9.81, e=0.8)
    zb = zeno_ball(1.0, 0.0, 9.81, 0.8)
    n = ex.impact_times.size
    assert n > 50 and ex.t_rest == zb.t_inf
    assert np.max(np.abs(ex.impact_times - zb.impact_times(n))) <= 1e-13
    assert np.array_equal(ex.y, zb.state(np.linspace(0, 6, 61))[0])


def test_ball_in_box_bad_input_names_the_field():
    with pytest.raises(ValueError, match="outside the box"):
        ball_in_box_exact([1.0], 1.5, 0.5, 0.0, 0.0, **BOX, g=9.81, e=1.0)
    with pytest.raises(ValueError, match="e = 1.5"):
        ball_in_box_exact([1.0], 0.5, 0.5, 0.0, 0.0, **BOX, g=9.81, e=1.5)
    with pytest.raises(ValueError, match="width"):
        ball_in_box_exact([1.0], 0.5, 0.5, 0.0, 0.0, width=0.0, height=1.0, g=9.81, e=1.0)


# --- the Zeno ball ------------------------------------------------------------------------------------

@pytest.mark.parametrize("y0,v0,e", [(1.0, 0.0, 0.8), (0.3, 2.0, 0.5), (2.0, -1.0, 0.9)])
def test_zeno_ball_against_event_driven_solve(y0, v0, e):
    g = 9.81
    zb = zeno_ball(y0, v0, g, e)
    n = int(np.log(1e-6) / np.log(e))  # the last flights ~ 1e-6 of the first: well resolved by the solve
    imps, segs = _walls_solve(zb.t_inf, (0.0, y0, 0.0, v0), [((0.0, 1.0), 0.0)], g, e, max_events=n)
    ts = np.array([a for a, _, _ in imps])
    assert ts.size == n
    assert np.max(np.abs(zb.impact_times(n) - ts)) <= 1e-9 * zb.t_inf
    lam = np.array([li for _, _, li in imps])                      # m = 1: lam = (1 + e) * speed
    assert np.max(np.abs((1 + e) * zb.impact_speeds(n) - lam)) <= 1e-9 * lam[0]
    # states between impacts
    t = np.linspace(0.0, ts[-1], 777)
    far = np.min(np.abs(t[:, None] - ts[None, :]), axis=1) > 1e-9
    y, v = zb.state(t)
    z = _dense(segs, t)
    assert np.max(np.abs(y[far] - z[far, 1])) <= 1e-9 * max(y0, 1.0)
    assert np.max(np.abs(v[far] - z[far, 3])) <= 1e-9 * zb.v1
    # the Zeno time: Aitken's extrapolation of the solve's impact times (exact for a geometric tail)
    d1, d2 = ts[-1] - ts[-2], ts[-2] - ts[-3]
    aitken = ts[-1] - d1 * d1 / (d1 - d2)
    assert abs(aitken - zb.t_inf) <= 1e-9 * zb.t_inf
    assert abs(zb.t_inf - (zb.t1 + 2 * e * zb.v1 / (g * (1 - e)))) <= 1e-15 * zb.t_inf
    # at rest afterwards, exactly
    y, v = zb.state(zb.t_inf + np.array([0.0, 1e-9, 1.0, 100.0]))
    assert np.all(y == 0.0) and np.all(v == 0.0)


def test_zeno_ball_limits():
    """e = 0: at rest from the first impact; e = 1: periodic, no Zeno time."""
    zb = zeno_ball(1.0, 0.0, 9.81, 0.0)
    assert zb.t_inf == zb.t1 and np.all(zb.state([zb.t1, 5.0])[0] == 0.0)
    zb = zeno_ball(1.0, 0.0, 9.81, 1.0)
    assert np.isinf(zb.t_inf)
    ts = zb.impact_times(4)
    assert np.allclose(np.diff(ts), 2 * zb.v1 / 9.81, rtol=1e-14)
    y, v = zb.state(ts[2] + 0.5 * (ts[3] - ts[2]))
    assert abs(y - 1.0) <= 1e-12 and abs(v) <= 1e-12   # back to the drop height at the apex
    with pytest.raises(ValueError, match="y0"):
        zeno_ball(-1.0, 0.0, 9.81, 0.5)


# --- the bead leaving a circle ------------------------------------------------------------------------

def _bead_solve(R, g, v0):
    """theta'' = (g / R) sin theta on the circle until N / m = g cos theta - R theta'^2 = 0."""
    def rhs(t, s):
        return [s[1], g / R * np.sin(s[0])]

    def normal(t, s):
        return g * np.cos(s[0]) - R * s[1] ** 2
    normal.terminal, normal.direction = True, -1
    sol = solve_ivp(rhs, (0.0, 100.0), [0.0, v0 / R], method="DOP853", rtol=RTOL, atol=ATOL, events=normal,
                    dense_output=True)
    assert sol.status == 1
    return sol.t_events[0][0], sol.y_events[0][0], sol.sol


@pytest.mark.parametrize("R,g,v0", [(1.0, 9.81, 0.5), (0.7, 9.81, 0.05), (2.0, 1.0, 1.3)])
def test_bead_release_against_the_constrained_ode(R, g, v0):
    b = bead_release(R, g, v0)
    tr, (thr, wr), dense = _bead_solve(R, g, v0)
    assert abs(b.t_r - tr) <= 1e-9 * tr
    assert abs(b.theta_r - thr) <= 1e-9
    assert abs(b.cos_r - (2 / 3 + v0 ** 2 / (3 * g * R))) <= 1e-15
    q_ode = R * np.array([np.sin(thr), np.cos(thr)])
    v_ode = R * wr * np.array([np.cos(thr), -np.sin(thr)])
    assert np.max(np.abs(b.q_r - q_ode)) <= 1e-9 * R
    assert np.max(np.abs(b.v_r - v_ode)) <= 1e-9 * np.sqrt(g * R)
    # on the circle: theta(t) (elliptic closed form), the state and the normal force
    t = np.linspace(0.0, b.t_r, 101)[:-1]
    th_ode, w_ode = dense(t)
    assert np.max(np.abs(b.theta(t) - th_ode)) <= 1e-9
    q, v = b.state(t)
    assert np.max(np.abs(q - R * np.stack([np.sin(th_ode), np.cos(th_ode)], -1))) <= 1e-9 * R
    assert np.max(np.abs(v - (R * w_ode)[:, None] * np.stack([np.cos(th_ode), -np.sin(th_ode)], -1))) <= 1e-9 * np.sqrt(g * R)
    assert np.max(np.abs(b.normal_force(t) - (g * np.cos(th_ode) - R * w_ode ** 2))) <= 1e-9 * g
    assert np.all(b.normal_force(t) > 0.0) and abs(b.normal_force(b.t_r * (1 - 1e-12))) <= 1e-9 * g
    # free flight from the solve's release state
    t2 = b.t_r + np.linspace(0.0, 1.5, 31)
    fly = solve_ivp(lambda t, z: [z[2], z[3], 0.0, -g], (tr, t2[-1] + 1e-9), [*q_ode, *v_ode], method="DOP853",
                    rtol=RTOL, atol=ATOL, dense_output=True).sol(t2 + (tr - b.t_r))
    q2, v2 = b.state(t2)
    assert np.max(np.abs(q2 - fly[:2].T)) <= 1e-9 * max(R, g)
    assert np.max(np.abs(v2 - fly[2:].T)) <= 1e-9 * max(np.sqrt(g * R), g)
    assert np.all(np.linalg.norm(q2[1:], axis=1) > R) and np.all(b.normal_force(t2[1:]) == 0.0)


def test_bead_release_refuses_the_equilibrium_and_an_immediate_release():
    with pytest.raises(ValueError, match="v0 = 0.0 must be positive"):
        bead_release(1.0, 9.81, 0.0)
    with pytest.raises(ValueError, match="leaves the circle at once"):
        bead_release(1.0, 9.81, 3.2)


# --- Newton's cradle ----------------------------------------------------------------------------------

@pytest.mark.parametrize("N", [2, 3, 4, 7])
@pytest.mark.parametrize("e", [1.0, 0.7, 0.0])
def test_newton_cradle_against_the_lcp(N, e):
    m, v0 = 1.3, 2.0
    G = np.zeros((N - 1, N))
    for i in range(N - 1):
        G[i, i], G[i, i + 1] = -1.0, 1.0
    v = np.zeros(N)
    v[0] = v0
    lam = _lcp(G @ G.T / m, (1 + e) * (G @ v))
    vp = v + G.T @ lam / m
    assert np.max(np.abs(newton_cradle_velocities(N, e, v0) - vp)) <= 1e-12 * v0
    assert np.max(np.abs(newton_cradle_impulses(N, e, v0, m=m) - lam)) <= 1e-12 * m * v0
    if N == 3 and e == 1.0:
        assert np.max(np.abs(newton_cradle_velocities(3, 1.0, 1.0) - [-1 / 3, 2 / 3, 2 / 3])) <= 1e-15
    assert abs(newton_cradle_velocities(N, e, v0).sum() - v0) <= 1e-14 * N


def test_newton_cradle_no_approach_and_bad_input():
    assert np.array_equal(newton_cradle_velocities(3, 1.0, -1.0), [-1.0, 0.0, 0.0])
    assert np.array_equal(newton_cradle_impulses(3, 1.0, -1.0), [0.0, 0.0])
    with pytest.raises(ValueError, match="N = 1"):
        newton_cradle_velocities(1, 1.0, 1.0)
