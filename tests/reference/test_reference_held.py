"""The held-contact machinery of the exact reference (vcirun.reference_solution.held; docs/derivations/contacts.md,
"Held contacts in the reference"), against closed forms (vcirun.scenes.oracles) and independent solves
written here from the equations of motion (never vcirun kernels):

  * a bead on a circle (e = 0), held from the start at the top (case (c)) or by a plastic impact
    there (case (b)): the release angle cos theta = 2/3 + v0^2 / (3 g R), time and state against
    oracles.bead_release, the multiplier against the closed-form normal force;
  * the cart-pendulum held on its floor y = 0: the multiplier against the hand-derived normal force
    (m1 + m2) g - m2 g sin^2 theta + m2 L theta'^2 cos theta (the coupled mass matrix: the Mdot v
    term), theta(t) against the simple pendulum solved here, the lift-off against that solve's
    event N = 0;
  * the Zeno ball (e = 0.8): the bounces solved here up to a flight below ZENO_FLIGHT, the
    extrapolated t_inf against oracles.zeno_ball's, rest afterwards; the extrapolation on a
    non-geometric sequence (drag) computed here, error O(flight^2);
  * settling by accumulation then release (the cart-pendulum, the bead): the event-driven bounces
    solved here, cut at a flight d, then held from the extrapolated Zeno time as the reference's loop
    holds it: the release time O(d^3);
  * a ball sliding on the floor of ball_in_box (frictionless, held) between the side walls: the wall
    impacts and states against oracles.ball_in_box_exact, mu = m g;
  * projection and the held-set decision.
Every held phase runs on both integration paths (Taylor and DOP853) against the same closed forms.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from vcirun.codegen.build import load_module
from vcirun.codegen.kernel_set import SYSTEM_KERNELS
from vcirun.reference_solution import held as rh
from vcirun.reference_solution.dop853 import Dop853Backend
from vcirun.reference_solution.loop import _geometry, _immediate
from vcirun.reference_solution.taylor import TaylorBackend, taylor_model
from vcirun.scenes.registry import get_scene
from vcirun.mechanics.loader import load_system_yaml
from vcirun.scenes.oracles import ball_in_box_exact, bead_release, zeno_ball

BEAD = {"name": "bead_circle_drag", "coordinates": ["x", "y"],
        "parameters": {"m": 1.0, "g": 9.81, "R": 1.0, "e": 0.0, "c": 0.0},
        "mass_matrix": [["m", "0"], ["0", "m"]], "potential": "m*g*y", "forcing": ["-c*x_dot", "-c*y_dot"],
        "constraints": [{"name": "surface", "phi": "sqrt(x**2 + y**2) - R", "restitution": "e"}]}
ZENO = {"name": "zeno_ball", "coordinates": ["y"], "parameters": {"m": 1.0, "g": 9.81, "e": 0.8},
        "mass_matrix": [["m"]], "potential": "m*g*y",
        "constraints": [{"name": "floor", "phi": "y", "restitution": "e"}]}


def _module(system):
    return system, load_module(system, SYSTEM_KERNELS)


PATHS = ["taylor", "dop853"]
# the held phases' accuracy: Taylor at machine precision, DOP853 at rtol 1e-13
TOL = {"taylor": 1e-11, "dop853": 1e-8}


class _Held:
    """A held phase [t0, t1] on one path: the segments from (t0, y0) projected onto A until an event
    or T (DOP853's projections after a drift joined), like the reference's loop runs them."""

    def __init__(self, system, mod, prm, t0, y0, T, A, path, R=()):
        self.mod, self.prm, self.A = mod, prm, tuple(A)
        y = np.asarray(y0, float)
        if mod.FORCED and len(y) == 2 * int(mod.NDOF):
            y = np.append(y, 0.0)   # a forced solve carries the work W as its last component
        y = rh._project_y(mod, y, prm, A)
        if path == "taylor":
            backend = TaylorBackend(taylor_model(system), mod, prm)
        else:
            backend = Dop853Backend(mod, prm, 1e-13, 1e-13 * max(1.0, float(np.max(np.abs(y)))))
        self.flights = []
        t = float(t0)
        while True:
            fl = backend.segment(t, y, T, self.A, R)
            self.flights.append(fl)
            if fl.reason != "drift":
                break
            t, y = fl.t1, rh._project_y(mod, fl.y1, prm, A)
        self.t0, self.t1, self.reason, self.contact = float(t0), fl.t1, fl.reason, fl.contact
        self.y1 = rh._project_y(mod, fl.y1, prm, A) if fl.reason in ("end", "release") else np.array(fl.y1)
        self.held = self.A

    def sol(self, t):
        ts = np.atleast_1d(np.asarray(t, float))
        out = np.empty((len(self.y1), ts.size))
        starts = np.array([f.t0 for f in self.flights])
        idx = np.clip(np.searchsorted(starts, ts, side="right") - 1, 0, len(self.flights) - 1)
        for j in np.unique(idx):
            sel = idx == j
            out[:, sel] = self.flights[j].piece(ts[sel])
        return out[:, 0] if np.ndim(t) == 0 else out

    def mu(self, t):
        ts = np.atleast_1d(np.asarray(t, float))
        y = self.sol(ts)
        n = int(self.mod.NDOF)
        out = np.column_stack([rh.held_multipliers(self.mod, s, y[:n, k], y[n:2 * n, k], self.prm, self.A)
                               for k, s in enumerate(ts)])
        return out[:, 0] if np.ndim(t) == 0 else out

    def drift(self, samples=101):
        """max |phi_A| along the phase."""
        n, phis, worst = int(self.mod.NDOF), np.empty(int(self.mod.NCON)), 0.0
        for y in self.sol(np.linspace(self.t0, self.t1, samples)).T:
            self.mod.sys_phis(np.ascontiguousarray(y[:n]), self.prm, phis)
            worst = max(worst, float(np.max(np.abs(phis[list(self.A)]))))
        return worst


def _after_release(mod, prm, seg):
    """(held set, resting contacts) after a release, as the loop decides them."""
    n = int(mod.NDOF)
    q, p = seg.y1[:n], seg.y1[n:2 * n]
    return (rh.held_set(mod, seg.t1, q, p, prm, [i for i in seg.held if i != seg.contact]),
            rh.at_rest(mod, seg.t1, q, p, prm))


def _impact(mod, prm, t, y, A):
    """The loop's impact step at (t, y) with held set A: (impacts [(t, contact, lam)], y+, new held set)."""
    n, m = int(mod.NDOF), int(mod.NCON)
    d, lam, active = np.empty(n), np.empty(m), np.empty(m, dtype=np.int64)
    k, s0, _ = mod.impact_direction(y[:n].copy(), y[n:2 * n].copy(), 1.0, 2.5e-11, prm, d, lam, active)
    assert k > 0
    y = np.array(y, float)
    y[n:2 * n] += s0 * d
    imps = [(t, int(i), float(s0 if m == 1 else lam[i])) for i in np.flatnonzero(active)
            if (m == 1 or lam[i] > 0.0) and int(i) not in A]
    held = rh.held_set(mod, t, y[:n], y[n:2 * n], prm, None)
    return imps, (rh._project_y(mod, y, prm, held) if held else y), held


@pytest.fixture(scope="module")
def bead():
    return _module(load_system_yaml(BEAD))


@pytest.fixture(scope="module")
def box():
    return _module(get_scene("ball_in_box"))


@pytest.fixture(scope="module")
def cart():
    return _module(get_scene("cart_pendulum"))


# --- the bead on a circle ------------------------------------------------------------------------

BEADS = [(1.0, 9.81, 0.5, 1.0), (0.7, 9.81, 0.05, 2.0), (2.0, 1.0, 1.3, 0.3)]


def _check_release(seg, b, m, tol):
    assert seg.reason == "release" and seg.contact == 0 and seg.held == (0,)
    assert abs(seg.t1 - b.t_r) <= tol * max(1.0, b.t_r)
    q, v = seg.y1[:2], seg.y1[2:4] / m
    assert abs(q[1] / np.hypot(*q) - b.cos_r) <= tol
    np.testing.assert_allclose(q, b.q_r, rtol=0, atol=tol * b.R)
    np.testing.assert_allclose(v, b.v_r, rtol=0, atol=tol * max(1.0, np.linalg.norm(b.v_r)))
    # the segment's dense output and multiplier along the circle
    tt = np.linspace(0.0, seg.t1, 41)
    qs, vs = b.state(tt)
    y = seg.sol(tt)
    assert np.max(np.abs(y[:2].T - qs)) <= 10 * tol * b.R
    assert np.max(np.abs(y[2:4].T / m - vs)) <= 10 * tol * max(1.0, b.v0)
    assert np.max(np.abs(seg.mu(tt)[0] - b.normal_force(tt))) <= 10 * tol * m * b.g
    assert abs(seg.mu(seg.t1)[0]) <= 10 * tol * m * b.g
    assert seg.drift() <= 1e-11


@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("R,g,v0,m", BEADS)
def test_bead_held_from_the_start_releases_where_the_normal_force_vanishes(bead, R, g, v0, m, path):
    system, mod = bead
    prm = system.param_values({"R": R, "g": g, "m": m})
    q0, p0 = np.array([0.0, R]), m * np.array([v0, 0.0])
    A = rh.initially_held(mod, q0, p0, prm)                      # case (c)
    assert A == (0,)
    mu0 = rh.held_multipliers(mod, 0.0, q0, p0, prm, A)
    assert abs(mu0[0] - m * (g - v0 * v0 / R)) <= 1e-12 * m * g  # N = m (g - v0^2 / R) at the top
    b = bead_release(R, g, v0, m)
    assert abs(b.cos_r - (2.0 / 3.0 + v0 * v0 / (3.0 * g * R))) <= 1e-15
    seg = _Held(system, mod, prm, 0.0, np.r_[q0, p0], 10.0 * b.t_r + 1.0, A, path)
    _check_release(seg, b, m, TOL[path])
    assert _after_release(mod, prm, seg) == ((), (0,))
    # after the release the free motion leaves the circle: |q| grows like t^3 (oracle's flight)
    s = 1e-2
    q1, _ = bead_release(R, g, v0, m).state(seg.t1 + s)
    assert np.hypot(*q1) > R


@pytest.mark.parametrize("path", PATHS)
def test_bead_plastic_impact_at_the_top_then_held(bead, path):
    """Case (b): arriving at the top with a normal velocity -w, the plastic impact (e = 0) leaves the
    tangential v0 and zero normal velocity; the bead is then held and releases as from rest on it."""
    system, mod = bead
    R, g, v0, w, m = 1.0, 9.81, 0.5, 0.7, 1.0
    prm = system.param_values({"R": R, "g": g, "m": m})
    q0, pm = np.array([0.0, R]), m * np.array([v0, -w])
    assert rh.initially_held(mod, q0, pm, prm) == ()  # approaching: not at rest
    d, lam, active = np.empty(2), np.empty(1), np.empty(1, dtype=np.int64)
    k, s0, dE = mod.impact_direction(q0.copy(), pm.copy(), 1.0, 2.5e-11, prm, d, lam, active)
    assert k == 1 and abs(dE - 0.5 * m * w * w) <= 1e-14
    pp = pm + s0 * d
    A = rh.plastic_entry(mod, 0.0, q0, pp, prm, [0])
    assert A == (0,)
    seg = _Held(system, mod, prm, 0.0, np.r_[q0, pp], 5.0, A, path)
    _check_release(seg, bead_release(R, g, v0, m), m, TOL[path])


def test_bead_fast_at_the_top_is_not_held(bead):
    """v0^2 > g R: the free normal acceleration v0^2 / R - g is positive, no force is needed."""
    system, mod = bead
    prm = system.param_values({"R": 1.0, "g": 9.81, "m": 1.0})
    q0, p0 = np.array([0.0, 1.0]), np.array([3.5, 0.0])
    assert rh.initially_held(mod, q0, p0, prm) == ()
    acc = rh.free_normal_accelerations(mod, 0.0, q0, p0, prm)
    assert abs(acc[0] - (3.5 ** 2 - 9.81)) <= 1e-12


@pytest.mark.parametrize("path", PATHS)
def test_bead_with_drag_carries_the_work_and_releases_later(bead, path):
    """A forced held phase: linear drag f = -c v (tangential on the circle, so the normal force is
    still m (g cos theta - R theta'^2)) and the work W = int f . v as a last state component (as the
    reference's forced solves carry it): the release against the 1-DOF ODE
    R theta'' = g sin theta - (c/m) R theta' with the event N = 0, and H(t) - H(0) = W(t)."""
    system, mod = bead
    R, g, v0, m, c = 1.0, 9.81, 0.5, 1.0, 0.8
    prm = system.param_values({"R": R, "g": g, "m": m, "c": c})
    assert bool(mod.FORCED)
    q0, p0 = np.array([0.0, R]), m * np.array([v0, 0.0])
    assert rh.initially_held(mod, q0, p0, prm) == (0,)
    seg = _Held(system, mod, prm, 0.0, np.r_[q0, p0, 0.0], 10.0, (0,), path)

    def N(t, z):
        return g * math.cos(z[0]) - R * z[1] ** 2
    N.terminal, N.direction = True, -1.0
    sol = solve_ivp(lambda t, z: [z[1], (g / R) * math.sin(z[0]) - (c / m) * z[1]], (0.0, 10.0), [0.0, v0 / R],
                    method="DOP853", rtol=1e-13, atol=1e-15, events=N, dense_output=True)
    t_r = float(sol.t_events[0][0])
    assert seg.reason == "release" and abs(seg.t1 - t_r) <= 1e-10
    assert t_r > bead_release(R, g, v0, m).t_r                       # drag: later than without
    tt = np.linspace(0.0, seg.t1, 41)
    y = seg.sol(tt)
    th = sol.sol(tt)[0]
    assert np.max(np.abs(y[0] - R * np.sin(th))) <= 1e-9 and np.max(np.abs(y[1] - R * np.cos(th))) <= 1e-9
    H = 0.5 * (y[2] ** 2 + y[3] ** 2) / m + m * g * y[1]
    assert np.max(np.abs(H - H[0] - y[4])) <= 1e-11 and y[4, -1] < -1e-3    # energy balance, W < 0


# --- the cart-pendulum on its floor: a coupled mass matrix ---------------------------------------

def _pendulum(th0, w0, g, L, m1, m2, T):
    """The cart held at y = 0 leaves theta'' = -(g/L) sin theta; the floor's force
    N = (m1 + m2) g + m2 d^2/dt^2 (-L cos theta) = (m1 + m2) g - m2 g sin^2 th + m2 L th'^2 cos th."""
    def N(t, z):
        return (m1 + m2) * g - m2 * g * math.sin(z[0]) ** 2 + m2 * L * z[1] ** 2 * math.cos(z[0])

    N.terminal, N.direction = True, -1.0
    sol = solve_ivp(lambda t, z: [z[1], -(g / L) * math.sin(z[0])], (0.0, T), [th0, w0], method="DOP853",
                    rtol=1e-13, atol=1e-15, events=N, dense_output=True)
    return sol, N


@pytest.mark.parametrize("path", PATHS)
def test_cart_pendulum_held_force_motion_and_lift_off(cart, path):
    system, mod = cart
    prm = system.param_values()
    m1, m2, L, g = (system.params[k] for k in ("m1", "m2", "L", "g"))
    th0, w0 = 0.3, 8.0  # swings over the top: the centrifugal pull lifts the cart off
    M0 = np.array([[m1 + m2, m2 * L * math.sin(th0)], [m2 * L * math.sin(th0), m2 * L * L]])
    q0, p0 = np.array([0.0, th0]), M0 @ np.array([0.0, w0])
    assert rh.initially_held(mod, q0, p0, prm) == (0,)
    sol, N = _pendulum(th0, w0, g, L, m1, m2, 5.0)
    assert sol.status == 1
    t_off = float(sol.t_events[0][0])
    seg = _Held(system, mod, prm, 0.0, np.r_[q0, p0], 5.0, (0,), path)
    assert seg.reason == "release" and seg.contact == 0
    assert abs(seg.t1 - t_off) <= 1e-10
    tt = np.linspace(0.0, seg.t1, 37)
    y = seg.sol(tt)
    z = sol.sol(tt)
    # the cart stays on the floor: 1e-13 at DOP853's steps, ~1e-11 between them (its dense output)
    assert np.max(np.abs(y[0])) <= 2e-11
    assert np.max(np.abs(y[1] - z[0])) <= 1e-9
    # p = M(q) qdot with ydot = 0: p_theta = m2 L^2 theta', p_y = m2 L sin(theta) theta'
    assert np.max(np.abs(y[3] - m2 * L * L * z[1])) <= 1e-9 * m2 * L * L * w0
    assert np.max(np.abs(y[2] - m2 * L * np.sin(z[0]) * z[1])) <= 1e-9 * m2 * L * w0
    Nref = np.array([N(0.0, z[:, k]) for k in range(tt.size)])
    assert np.max(np.abs(seg.mu(tt)[0] - Nref)) <= 1e-9 * (m1 + m2) * g
    assert _after_release(mod, prm, seg) == ((), (0,))


def test_project_onto_the_held_manifold(cart, bead):
    rng = np.random.default_rng(18)
    system, mod = bead
    prm = system.param_values()
    for _ in range(20):
        ang = rng.uniform(-1.0, 1.0)
        q = (1.0 + rng.uniform(-1e-3, 1e-3)) * np.array([math.sin(ang), math.cos(ang)])
        p = rng.normal(size=2)
        qp, pp = rh.project(mod, q, p, prm, (0,))
        assert abs(np.hypot(*qp) - 1.0) <= 4e-16
        assert abs(qp @ pp) <= 1e-15 * (1.0 + np.linalg.norm(p))          # u = grad phi . M^-1 p = 0
        # the tangential momentum is kept: p changes along grad phi only
        n = qp / np.hypot(*qp)
        assert abs((p - pp) @ np.array([-n[1], n[0]])) <= 1e-15 * (1.0 + np.linalg.norm(p))
    system, mod = cart
    prm = system.param_values()
    m1, m2, L = (system.params[k] for k in ("m1", "m2", "L"))
    q, p = np.array([1e-4, 0.7]), np.array([0.3, -1.1])
    qp, pp = rh.project(mod, q, p, prm, (0,))
    assert qp[0] == 0.0
    M = np.array([[m1 + m2, m2 * L * math.sin(qp[1])], [m2 * L * math.sin(qp[1]), m2 * L * L]])
    v = np.linalg.solve(M, pp)
    assert abs(v[0]) <= 1e-15
    # along M^-1 grad phi: the theta coordinate moves by -(M^-1)_{21} / (M^-1)_{11} times the y shift
    Mi = np.linalg.inv(np.array([[m1 + m2, m2 * L * math.sin(0.7)], [m2 * L * math.sin(0.7), m2 * L * L]]))
    assert abs((qp[1] - 0.7) - (-1e-4) * Mi[1, 0] / Mi[0, 0]) <= 1e-9


# --- the Zeno ball -------------------------------------------------------------------------------

@pytest.mark.parametrize("path", PATHS)
def test_zeno_ball_extrapolated_and_at_rest_after(path):
    system, mod = _module(load_system_yaml(ZENO))
    prm = system.param_values()
    y0, g, e, m = 1.0, 9.81, 0.8, 1.0
    z = zeno_ball(y0, 0.0, g, e)

    def newton(zz):
        u = zz[1]
        zz[0], zz[1] = 0.0, -e * u
        return u

    # the bounces solved here, up to the first flight below ZENO_FLIGHT (as the reference's loop will)
    ts, zk = _bounce_until(lambda t, zz: [zz[1], -g], lambda zz: zz[0], newton, [y0, 0.0], rh.ZENO_FLIGHT, g)
    k = len(ts) - 1
    assert rh.accumulating(ts, e=e) and not rh.accumulating(ts[:-1], e=e)
    assert ts[k] - ts[k - 1] < rh.ZENO_FLIGHT <= ts[k - 1] - ts[k - 2]
    np.testing.assert_allclose(ts, z.impact_times(k + 1), rtol=0, atol=1e-12)
    t_inf = rh.zeno_extrapolation(ts)
    seg = _Held(system, mod, prm, ts[k], np.array([zk[0], m * zk[1]]), t_inf, (0,), path)
    assert abs(t_inf - z.t_inf) <= 1e-8
    assert seg.reason == "end" and seg.t1 == t_inf and seg.held == (0,)
    assert abs(seg.y1[0]) <= 1e-15 and abs(seg.y1[1]) <= 1e-15
    rest = _Held(system, mod, prm, t_inf, seg.y1, t_inf + 3.0, (0,), path)
    assert rest.reason == "end" and rest.t1 == t_inf + 3.0
    tt = np.linspace(t_inf, t_inf + 3.0, 31)
    y = rest.sol(tt)
    assert np.max(np.abs(y)) <= 1e-15                         # y = 0, p = 0 to round-off
    assert np.max(np.abs(rest.mu(tt) - m * g)) <= 1e-12 * m * g
    assert np.max(np.abs(z.state(tt)[0])) <= 1e-15            # the oracle rests there too


def _drag_bounces(v1, g, k, e, d_min):
    """Impact times of a ball leaving the floor at t = 0 with speed v1 under y'' = -g - k y' and
    restitution e, solved here: each flight's time T is the root of y(T) = 0 with
    y(s) = -(g/k) s + (v + g/k)(1 - exp(-k s)) / k, the return speed g/k - (v + g/k) exp(-k T)."""
    ts, t, v = [0.0], 0.0, v1
    while True:
        y = lambda s: -(g / k) * s + (v + g / k) * (-math.expm1(-k * s)) / k  # noqa: E731
        T0 = 2.0 * v / g
        T = brentq(y, 0.5 * T0, 1.01 * T0, xtol=1e-300, rtol=1e-15)
        t += T
        ts.append(t)
        v = e * (g / k - (v + g / k) * math.exp(-k * T))
        if T < d_min:
            return np.array(ts)


def test_zeno_extrapolation_exact_for_geometric_and_second_order_in_the_flight():
    z = zeno_ball(1.0, 0.0, 9.81, 0.8)
    for n in (3, 10, 40):
        assert abs(rh.zeno_extrapolation(z.impact_times(n)) - z.t_inf) <= 1e-14 * z.t_inf
    # drag: the flight ratio drifts by O(flight); the accumulation time of the full sequence (flights
    # summed down to 1e-13 s, their tail below 1e-12 s) against the extrapolation from a cut
    g, k, e = 9.81, 0.7, 0.8
    ts = _drag_bounces(2.0, g, k, e, 1e-13)
    t_inf = ts[-1] + (ts[-1] - ts[-2]) * e / (1 - e)
    # second order, with the constant of docs/derivations/contacts.md: the flight ratio r_j = e (1 - k (1 + e) d_j / 6)
    # gives t_inf(extrapolated) - t_inf = -k d^2 / (6 (1 - e)^2) + O(d^3)
    c = k / (6.0 * (1.0 - e) ** 2)
    for d in (1e-2, 1e-3, 1e-4):
        j = next(i for i in range(2, len(ts)) if ts[i] - ts[i - 1] < d)
        d2 = ts[j] - ts[j - 1]
        assert abs((rh.zeno_extrapolation(ts[:j + 1]) - t_inf) / d2 ** 2 + c) <= 0.02 * c
    j = next(i for i in range(2, len(ts)) if ts[i] - ts[i - 1] < rh.ZENO_FLIGHT)
    d2 = ts[j] - ts[j - 1]
    # + the round-off of the summed times
    assert abs(rh.zeno_extrapolation(ts[:j + 1]) - t_inf) <= 1.02 * c * d2 ** 2 + 1e-13
    assert rh.accumulating(ts[:j + 1]) and not rh.accumulating(ts[:j])
    assert rh.accumulating(ts[:j + 1], e=e) and not rh.accumulating(ts[:j + 1], e=0.7)
    # shrinking flights that do not accumulate (e = 1 with drag: d_j ~ 1 / j, ratio -> 1)
    harmonic = np.cumsum(1e-6 * 1000.0 / (1000.0 + np.arange(50)))
    assert rh.accumulating(harmonic)  # the flights alone do not tell ...
    assert not rh.accumulating(harmonic, e=1.0) and not rh.accumulating(harmonic, e=0.8)  # ... the ratio does
    with pytest.raises(ValueError, match="times"):
        rh.zeno_extrapolation([0.0, 1.0])
    with pytest.raises(ValueError, match="do not shrink"):
        rh.zeno_extrapolation([0.0, 1.0, 2.0])
    with pytest.raises(ValueError, match="increase"):
        rh.zeno_extrapolation([0.0, 1.0, 1.0])


@pytest.mark.parametrize("path", PATHS)
def test_zeno_entry_carries_the_tangential_motion(box, path):
    """The ball in the box bounces on the floor with e = 0.8 while moving sideways: the held state at
    t_inf from the last resolved impact (oracle times and state) against the oracle's t_rest."""
    system, mod = box
    params = {"e": 0.8, "width": 50.0, "height": 5.0}
    prm = system.param_values(params)
    x0, y0, vx0 = 0.5, 1.0, 0.9
    ex = ball_in_box_exact(np.array([10.0]), x0, y0, vx0, 0.0, width=50.0, height=5.0, g=9.81, e=0.8)
    floor = ex.impact_times[ex.impact_contact == 0]
    k = next(j for j in range(len(floor)) if rh.accumulating(floor[:j + 1], 1e-6))
    tk = floor[k]
    s = ball_in_box_exact(np.array([tk, ex.t_rest, ex.t_rest + 1.0]), x0, y0, vx0, 0.0, width=50.0, height=5.0,
                          g=9.81, e=0.8)
    yk = np.array([s.x[0], s.y[0], s.vx[0], s.vy[0]])
    t_inf = rh.zeno_extrapolation(floor[:k + 1])
    seg = _Held(system, mod, prm, tk, yk, t_inf, (0,), path)
    assert abs(t_inf - ex.t_rest) <= 1e-12
    np.testing.assert_allclose(seg.y1, [s.x[1], 0.0, s.vx[1], 0.0], rtol=0, atol=1e-12)
    after = _Held(system, mod, prm, t_inf, seg.y1, t_inf + 1.0, (0,), path)
    np.testing.assert_allclose(after.y1, [s.x[2], 0.0, s.vx[2], 0.0], rtol=0, atol=1e-12)


# --- settling by accumulation, then release: the state at t_inf to O(d^3) ------------------------

CART_E = {"name": "cart_pendulum_e", "coordinates": ["y", "theta"],
          "parameters": {"m1": 1.0, "m2": 0.2, "L": 2.0, "g": 10.0, "e": 0.5},
          "mass_matrix": [["m1 + m2", "m2*L*sin(theta)"], ["m2*L*sin(theta)", "m2*L**2"]],
          "potential": "(m1 + m2)*g*y - m2*g*L*cos(theta)",
          "constraints": [{"name": "floor", "phi": "y", "restitution": "e"}]}


def _cart_free(m1, m2, L, g):
    """The cart-pendulum's free motion on z = (y, theta, ydot, thetadot), from its Lagrangian
    T = ((m1 + m2) ydot^2 + 2 m2 L sin(th) ydot thd + m2 L^2 thd^2) / 2, V = (m1 + m2) g y - m2 g L cos th."""
    def M(th):
        return np.array([[m1 + m2, m2 * L * math.sin(th)], [m2 * L * math.sin(th), m2 * L * L]])

    def rhs(t, z):
        a = np.linalg.solve(M(z[1]), [-(m1 + m2) * g - m2 * L * math.cos(z[1]) * z[3] ** 2,
                                      -m2 * g * L * math.sin(z[1])])
        return [z[2], z[3], a[0], a[1]]
    return M, rhs


def _bounce_until(rhs, phi, impact, z0, d_cut, g_scale, T=5.0):
    """Event-driven solve (DOP853, rtol 1e-13) with Newton's law `impact` at phi = 0, up to the first
    flight shorter than d_cut: (impact times, post-impact state at the last one). The first step after
    an impact is a fiftieth of the flight's scale (a flight inside one step would be missed)."""
    def ev(t, z):
        return phi(z)
    ev.terminal, ev.direction = True, -1.0
    t, z, times, fs = 0.0, np.array(z0, float), [], None
    while True:
        sol = solve_ivp(rhs, (t, T), z, method="DOP853", rtol=1e-13, atol=1e-16, events=ev, first_step=fs)
        assert sol.status == 1
        t, z = float(sol.t[-1]), sol.y[:, -1].copy()
        u = impact(z)
        times.append(t)
        fs = 0.02 * abs(u) / g_scale
        if len(times) >= 3 and times[-1] - times[-2] < d_cut:
            return np.array(times), z


def _settle_and_release(system, mod, prm, times, zk, to_y, path):
    """The loop's accumulation: held from the last impact to the extrapolated Zeno time, then on."""
    t_inf = rh.zeno_extrapolation(times)
    seg = _Held(system, mod, prm, times[-1], to_y(zk), t_inf, (0,), path)
    held = _Held(system, mod, prm, t_inf, seg.y1, 5.0, (0,), path)
    assert held.reason == "release" and held.contact == 0
    return t_inf, held


def _check_cubic(results):
    """The release time from the cut at flight d against the finest cut: |error| <= 2 d^3 and the
    error falls faster than d^2.5 (third order: the O(d^2) terms of the state at t_inf cancel)."""
    d_ref, t_ref = results[-1]
    errs = [(d, abs(t - t_ref)) for d, t in results[:-1]]
    for d, err in errs:
        assert err <= 2.0 * d ** 3 + 1e-14
    (da, ea), (db, eb) = errs[0], errs[1]
    assert ea / eb >= (da / db) ** 2.5


@pytest.mark.parametrize("path", PATHS)
def test_cart_pendulum_settles_by_accumulation_then_lifts_off(path):
    system, mod = _module(load_system_yaml(CART_E))
    prm = system.param_values()
    m1, m2, L, g, e = 1.0, 0.2, 2.0, 10.0, 0.5
    M, rhs = _cart_free(m1, m2, L, g)

    def newton(z):  # ydot+ = -e ydot-: the impulse lam on p_y, qdot += M^-1 (lam, 0)
        Mi = np.linalg.inv(M(z[1]))
        u = z[2]
        z[2:] += Mi[:, 0] * (-(1.0 + e) * u / Mi[0, 0])
        z[0] = 0.0
        return z[2]

    def to_y(z):
        return np.r_[z[:2], M(z[1]) @ z[2:]]

    z0 = [0.01, 0.3, 0.0, 7.5]
    results = []
    for d_cut in (1e-2, 1e-3, 1e-6):
        times, zk = _bounce_until(rhs, lambda z: z[0], newton, z0, d_cut, g)
        t_inf, held = _settle_and_release(system, mod, prm, times, zk, to_y, path)
        assert held.t0 == t_inf and 0.05 < t_inf < held.t1
        results.append((times[-1] - times[-2], held.t1))
    _check_cubic(results)
    # the release from the finest cut against this test's own held solve: the plastic projection
    # (ydot = 0, p_theta kept: thd = p_theta / (m2 L^2)) and theta'' = -(g/L) sin theta with N = 0
    pth = (M(zk[1]) @ zk[2:])[1]
    sol, _ = _pendulum(zk[1], pth / (m2 * L * L), g, L, m1, m2, 5.0)
    assert abs((times[-1] + float(sol.t_events[0][0])) - held.t1) <= 1e-10


@pytest.mark.parametrize("path", PATHS)
def test_bead_settles_on_the_circle_by_accumulation_then_releases(bead, path):
    system, mod = bead
    g, R, e = 9.81, 1.0, 0.5
    prm = system.param_values({"e": e})

    def rhs(t, z):
        return [z[2], z[3], 0.0, -g]

    def newton(z):  # the normal n = q / |q|: u+ = -e u-
        n = z[:2] / math.hypot(z[0], z[1])
        u = n @ z[2:]
        z[2:] -= (1.0 + e) * u * n
        return u

    results = []
    for d_cut in (1e-2, 1e-3, 1e-6):
        times, zk = _bounce_until(rhs, lambda z: math.hypot(z[0], z[1]) - R, newton, [0.0, R + 0.01, 0.5, 0.0],
                                  d_cut, g)
        t_inf, held = _settle_and_release(system, mod, prm, times, zk, lambda z: z.copy(), path)
        results.append((times[-1] - times[-2], held.t1))
    _check_cubic(results)
    # this test's own held solve from the finest cut: the plastic projection onto the tangent, then
    # R theta'' = g sin theta until the normal force g cos theta - R theta'^2 vanishes
    q, v = zk[:2], zk[2:]
    th0 = math.atan2(q[0], q[1])
    w0 = (v @ np.array([math.cos(th0), -math.sin(th0)])) / R

    def N(t, z):
        return g * math.cos(z[0]) - R * z[1] ** 2
    N.terminal, N.direction = True, -1.0
    sol = solve_ivp(lambda t, z: [z[1], (g / R) * math.sin(z[0])], (0.0, 5.0), [th0, w0], method="DOP853",
                    rtol=1e-13, atol=1e-15, events=N)
    assert abs((times[-1] + float(sol.t_events[0][0])) - held.t1) <= 1e-10


# --- sliding on the floor of the box between the walls -------------------------------------------

@pytest.mark.parametrize("path", PATHS)
def test_ball_slides_on_the_floor_and_meets_the_walls(box, path):
    """Held on the floor from the start (case (c)), sliding into the right wall, then the left: the floor
    stays held through both wall impacts; impacts, impulses, states and mu = m g against the closed form."""
    from vcirun.reference_solution.exact import solve_exact

    system, mod = box
    m, e, W = 1.7, 0.5, 2.0
    params = {"e": e, "m": m, "width": W}
    prm = system.param_values(params)
    x0, vx0, T = 0.5, 0.9, 14.0
    y = np.array([x0, 0.0, m * vx0, 0.0])
    assert rh.initially_held(mod, y[:2], y[2:], prm) == (0,)
    ref = solve_exact(system, y[:2], y[2:], prm, T, path=path)
    assert ref.kind == path
    iv = ref.held_intervals   # one held interval between impacts, the floor in each
    assert all(h == (0,) for _, _, h in iv) and iv[0][0] == 0.0 and iv[-1][1] == T
    assert all(a[1] == b[0] for a, b in zip(iv[:-1], iv[1:]))
    ex = ball_in_box_exact(np.linspace(0.0, T, 57), x0, 0.0, vx0, 0.0, width=W, height=1.0, g=9.81, e=e, m=m)
    assert list(ref.impact_contact) == list(ex.impact_contact) == [3, 2]
    np.testing.assert_allclose(ref.impacts, ex.impact_times, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ref.impact_impulse, ex.impact_impulse, rtol=1e-12)
    tt = np.linspace(0.0, T, 57)
    yy = ref.state(tt)
    np.testing.assert_allclose(yy[:, 0], ex.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(yy[:, 2] / m, ex.vx, rtol=0, atol=1e-12)
    assert np.max(np.abs(yy[:, 1])) == 0.0 and np.max(np.abs(yy[:, 3])) == 0.0
    mu = [rh.held_multipliers(mod, t, yy[k, :2], yy[k, 2:], prm, (0,))[0] for k, t in enumerate(tt)]
    assert np.max(np.abs(np.array(mu) - m * 9.81)) <= 1e-12 * m * 9.81


OBSTACLES = {"name": "floor_and_obstacles", "coordinates": ["x", "y", "z"],
             "parameters": {"m": 1.0, "g": 9.81, "a": 2.0, "b": 1.0, "c": 2.0, "d": 1.0, "r": 1.0, "rho": 100.0},
             "mass_matrix": [["m", "0", "0"], ["0", "m", "0"], ["0", "0", "m"]], "potential": "m*g*y",
             "constraints": [{"name": "floor", "phi": "y", "restitution": 0},
                             {"name": "bump", "phi": "(x - a)**2 + (y - b)**2 - r**2", "restitution": 1},
                             {"name": "post", "phi": "(x - c)**2 + (z - d)**2 - r**2", "restitution": 1},
                             {"name": "ring", "phi": "rho**2 - x**2 - z**2", "restitution": 1}]}


@pytest.fixture(scope="module")
def obstacles():
    return _module(load_system_yaml(OBSTACLES))


@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("depth", [1e-3, 1e-9])
def test_sliding_past_a_post_is_found_however_shallow_the_contact(obstacles, depth, path):
    """Held on the floor, sliding at constant speed along x (a linear motion, on which DOP853's error
    estimate vanishes) past a vertical post (a cylinder about the y axis) that reaches `depth` into the
    path: the contact is an impact even when the dip below phi = 0 is far shorter than a step (Taylor:
    the roots of the step's polynomial; DOP853: a minimum below 0 between two samples, in steps bounded
    by the approach time); the bump is out of the way."""
    system, mod = obstacles
    prm = system.param_values({"b": 5.0, "d": 1.0 - depth})
    seg = _Held(system, mod, prm, 0.0, np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0]), 10.0, (0,), path)
    # first contact: (x - 2)^2 + d^2 = 1 at z = 0
    t_hit = 2.0 - math.sqrt(depth * (2.0 - depth))
    assert seg.reason == "impact" and seg.contact == 2
    # a grazing root: the gap's round-off over its slope 2 sqrt(2 depth) (measured 8.6e-13 at 1e-9)
    assert abs(seg.t1 - t_hit) <= 1e-12 + 1e-16 / math.sqrt(depth)
    imps, y, held = _impact(mod, prm, seg.t1, seg.y1, seg.held)
    assert [c for _, c, _ in imps] == [2] and held == (0,)
    # elastic reflection off the post: the normal velocity reversed, the speed kept
    n = np.array([y[0] - 2.0, y[2] - (1.0 - depth)])
    n /= np.linalg.norm(n)
    assert abs(np.hypot(y[3], y[5]) - 1.0) <= 1e-12
    assert abs(n @ y[[3, 5]] + n @ np.array([1.0, 0.0])) <= 1e-12


@pytest.mark.parametrize("path", PATHS)
def test_an_impact_that_presses_into_the_held_floor(obstacles, path):
    """Sliding into the bump (a cylinder about z whose lowest point is 1e-3 below the floor line):
    its normal at the contact points down and back, so Moreau's law gives the held floor an impulse
    too; the floor stays held and no impact entry is recorded for it (a held contact has no impacts)."""
    system, mod = obstacles
    depth = 1e-3
    b = 1.0 - depth
    prm = system.param_values({"b": b, "d": 5.0})
    seg = _Held(system, mod, prm, 0.0, np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0]), 10.0, (0,), path)
    assert seg.reason == "impact" and seg.contact == 1
    assert abs(seg.t1 - (2.0 - math.sqrt((1.0 - b) * (1.0 + b)))) <= 1e-12
    imps, y, held = _impact(mod, prm, seg.t1, seg.y1, seg.held)
    assert [c for _, c, _ in imps] == [1]
    assert held == (0,) and y[1] == 0.0 and abs(y[4]) <= 1e-15
    # the LCP of the bump (e = 1, normal n) and the floor (u- = 0): both active, vy+ = 0 and
    # n . v+ = -n . v- = -n_x, so vx+ = -1: the ball is sent back at its speed
    assert abs(y[3] - (-1.0)) <= 1e-12


@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("start", ["held", "pressed"])
def test_two_held_contacts_ball_running_round_inside_a_ring(obstacles, start, path):
    """A ball on the floor running round the inside of a vertical ring wall x^2 + z^2 = rho^2 at
    speed v: two held contacts, the floor with m g and the ring with m v^2 / rho (the multiplier of
    grad phi = -2 (x, 0, z), |grad phi| = 2 rho: mu = m v^2 / (2 rho^2)), uniform circular motion.
    Held from the start by (c), or started held on the floor only with the ring resting (touching,
    not approaching): then the loop sees it pressed at once and the held set takes both."""
    system, mod = obstacles
    rho, v, m, g = 1.5, 2.0, 1.0, 9.81
    prm = system.param_values({"rho": rho, "b": 50.0, "d": 50.0})
    y0 = np.array([rho, 0.0, 0.0, 0.0, 0.0, m * v])
    if start == "held":
        A = rh.initially_held(mod, y0[:3], y0[3:], prm)
        assert A == (0, 3)
    else:
        geo = _geometry(mod, 0.0, y0, prm)
        R = tuple(i for i in rh.at_rest(mod, 0.0, None, None, prm, geo=geo) if i != 0)
        assert R == (3,)
        fl = _immediate(geo, 0.0, y0, (0,), R)
        assert fl.reason == "pressed" and fl.contact == 3 and fl.t1 == 0.0
        A = rh.held_set(mod, 0.0, y0[:3], y0[3:], prm, [0, 3])
        assert A == (0, 3)
    T = 2.0 * math.pi * rho / v          # one turn
    seg = _Held(system, mod, prm, 0.0, y0, T, A, path)
    assert seg.reason == "end" and seg.held == (0, 3)
    tt = np.linspace(0.0, T, 73)
    y = seg.sol(tt)
    w = v / rho
    assert np.max(np.abs(y[0] - rho * np.cos(w * tt))) <= 1e-9 and np.max(np.abs(y[2] - rho * np.sin(w * tt))) <= 1e-9
    assert np.max(np.abs(y[1])) <= 1e-14 and seg.drift() <= 1e-10
    mu = seg.mu(tt)
    assert np.max(np.abs(mu[0] - m * g)) <= 1e-12 * m * g
    assert np.max(np.abs(mu[1] - m * v * v / (2.0 * rho * rho))) <= 1e-9 * m * v * v / rho
    assert abs(np.hypot(seg.y1[3], seg.y1[5]) - m * v) <= 1e-9           # the speed is kept


def test_held_set_needs_a_compressive_force(box):
    system, mod = box
    prm = system.param_values({"width": 2.0})
    # in the corner at rest: the floor carries m g, the wall nothing (gravity is vertical): floor only
    assert rh.initially_held(mod, np.array([0.0, 0.0]), np.zeros(2), prm) == (0,)
    assert rh.at_rest(mod, 0.0, np.array([0.0, 0.0]), np.zeros(2), prm) == (0, 2)
    # at rest against the ceiling: pulled away by gravity, not held
    assert rh.initially_held(mod, np.array([1.0, 1.0]), np.zeros(2), prm) == ()
    # on the floor but lifting off (normal velocity), or slightly above it: not held
    assert rh.initially_held(mod, np.array([1.0, 0.0]), np.array([0.0, 1e-3]), prm) == ()
    assert rh.initially_held(mod, np.array([1.0, 1e-6]), np.zeros(2), prm) == ()
