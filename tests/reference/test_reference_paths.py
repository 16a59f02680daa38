"""The exact reference's two integration paths and its event loop (vcirun.reference_solution.taylor, dop853, loop):

- cross-validation: the Taylor path and the DOP853 path (at scipy's tightest rtol) see the same events
  and agree to 1e-11 on every built-in scene both express;
- several contacts accumulating together are held together: the rectangular block dropped flat (two
  bottom corners on the floor, e = 0.5) ends held on both corners with energy m g b and each contact
  force m g / 2, on both paths; tilted, it rocks onto its second corner and settles the same way;
  without resting contact it raises a clear error instead of looping;
- progress: an event loop that repeats its state, or spends more events than its bound, raises with
  the time and the contacts;
- which path produced a reference (ref.kind, ref.kind_reason), and the accuracy check: a check that
  sees another event sequence is refined, then an error; a returned reference has a finite accuracy.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import vcirun
from vcirun.codegen.build import load_module
from vcirun.codegen.kernel_set import SYSTEM_KERNELS
from vcirun.mechanics.loader import load_system_yaml
from vcirun.reference_solution import exact as rx
from vcirun.reference_solution import held as rh
from vcirun.reference_solution import loop
from vcirun.reference_solution.exact import RTOL_FLOOR, solve_exact
from vcirun.reference_solution.flight import Constant, Flight
from vcirun.reference_solution.taylor import NotExpressible, TaylorBackend
from vcirun.run.resolve import resolve_system
from vcirun.scenes.oracles import ball_in_box_exact

# (scene, start, params, T): T as long as DOP853 at its floor rtol stays below ~1e-12 itself
SCENES = [("cart_pendulum", {"beta": 4.2}, {}, 2.7), ("double_pendulum", {}, {}, 5.0),
          ("oscillator_wall", {}, {}, 10.0), ("damped_oscillator", {}, {"d": 0.5, "c": 0.3}, 10.0),
          ("bouncing_ball", {}, {"c": 0.5}, 3.0), ("n_pendulum_2", {}, {}, 4.0), ("n_pendulum_3", {}, {}, 3.0),
          ("ball_in_box", {}, {"e": 0.8}, 8.0), ("newton_cradle_3", {}, {}, 1.0),
          ("newton_cradle_5", {}, {"e": 0.7}, 1.0), ("double_pendulum_walls", {}, {"e": 0.9}, 3.0)]


@pytest.mark.parametrize("name,start,params,T", SCENES, ids=[c[0] for c in SCENES])
def test_taylor_and_dop853_agree_on_every_builtin_scene(name, start, params, T):
    s = resolve_system(name)
    prm = s.param_values(params)
    q0, p0 = s.initial_state(params=prm, **start)
    a = solve_exact(s, q0, p0, prm, T)
    b = solve_exact(s, q0, p0, prm, T, path="dop853", rtol=RTOL_FLOOR, check_accuracy=False)
    assert a.kind == "taylor" and b.kind == "dop853"
    assert list(a.impact_contact) == list(b.impact_contact) and len(a.impacts) >= 1
    assert list(a.release_contact) == list(b.release_contact)
    assert [iv[2] for iv in a.held_intervals] == [iv[2] for iv in b.held_intervals]
    assert np.max(np.abs(a.impacts - b.impacts)) <= 1e-11
    tt = np.linspace(0.0, T, 2001)
    assert np.max(np.abs(a(tt) - b(tt))) <= 1e-11
    assert 0.0 < a.accuracy <= 1e-11   # (at least the round-off of its events: 4 eps per event)


def test_a_system_beyond_the_taylor_path_says_why_and_is_exact_on_dop853():
    ref = vcirun.reference("n_pendulum_4", T=2.0)
    assert ref.kind == "dop853" and "4x4" in ref.kind_reason and "mass matrix" in ref.kind_reason
    assert np.isfinite(ref.accuracy) and ref.accuracy <= 1e-9 and len(ref.impacts) == 1
    assert repr(ref).startswith("Reference(kind='dop853'")
    ref = vcirun.reference("cart_pendulum", T=1.0, beta=3.2, check_accuracy=False)
    assert ref.kind == "taylor" and ref.kind_reason == "" and math.isnan(ref.accuracy)


CORNERS = {"name": "two_balls_in_corners", "coordinates": ["x1", "y1", "x2", "y2"],
           "parameters": {"m": 1.0, "g": 9.81, "gx": 2.0, "e": 0.5},
           "mass_matrix": [["m", "0", "0", "0"], ["0", "m", "0", "0"], ["0", "0", "m", "0"], ["0", "0", "0", "m"]],
           "potential": "m*g*(y1 + y2) + m*gx*(x1 + x2)",
           "constraints": [{"name": "floor1", "phi": "y1", "restitution": "e"},
                           {"name": "wall1", "phi": "x1", "restitution": "e"},
                           {"name": "floor2", "phi": "y2", "restitution": "e"},
                           {"name": "wall2", "phi": "x2", "restitution": "e"}]}


def test_more_contacts_held_together_than_the_taylor_path_takes_moves_to_dop853():
    """Gravity pulls both balls into their corners (down and to the left): the first rests there from
    the start, the second falls in and settles; then four contacts are held together, beyond the Taylor
    path's explicit inverse (MAX_HELD = 3): the whole solve is DOP853's, which says why."""
    s = load_system_yaml(CORNERS)
    mod = load_module(s, SYSTEM_KERNELS)
    prm = s.param_values()
    ref = solve_exact(s, [0.0, 0.0, 0.3, 0.2], [0.0, 0.0, 0.0, 0.0], prm, 3.0)
    assert ref.kind == "dop853" and "4 contacts held together" in ref.kind_reason
    assert ref.held_intervals[0][2] == (0, 1) and ref.held_intervals[-1][2] == (0, 1, 2, 3)
    assert ref.held_intervals[-1][1] == 3.0 and np.isfinite(ref.accuracy)
    y = ref.state(3.0)
    assert np.max(np.abs(y)) <= 1e-12
    np.testing.assert_allclose(rh.held_multipliers(mod, 3.0, y[:4], y[4:], prm, (0, 1, 2, 3)),
                               [9.81, 2.0, 9.81, 2.0], rtol=1e-10)
    with pytest.raises(NotExpressible, match="4 contacts held together"):
        solve_exact(s, [0.0, 0.0, 0.3, 0.2], [0.0, 0.0, 0.0, 0.0], prm, 3.0, path="taylor")


# --- the DOP853 path on random box states: no missed event either ---------------------------------------

@pytest.mark.parametrize("n,slow", [(8, False), pytest.param(80, True, marks=pytest.mark.slow)])
def test_dop853_path_on_random_box_states(n, slow):
    box = resolve_system("ball_in_box")

    @settings(max_examples=n, deadline=None, derandomize=not slow, database=None,
              suppress_health_check=[HealthCheck.too_slow])
    @given(st.floats(0.01, 0.99), st.floats(0.01, 0.99), st.floats(-5.0, 5.0), st.floats(-5.0, 5.0),
           st.sampled_from([1.0, 0.9, 0.6]))
    def check(x0, y0, vx, vy, e):
        T = 4.0
        ref = solve_exact(box, [x0, y0], [vx, vy], box.param_values({"e": e}), T, path="dop853")
        tt = np.linspace(0.0, T, 801)
        ex = ball_in_box_exact(tt, x0, y0, vx, vy, width=1.0, height=1.0, g=9.81, e=e)
        floor = ref.impacts[ref.impact_contact == 0]
        keep = ~((ex.impact_contact == 0) & (ex.impact_times > (floor[-1] if len(floor) else -1.0) + 1e-12)) \
            if ref.held_intervals else np.ones(len(ex.impact_times), bool)
        assert list(ref.impact_contact) == list(ex.impact_contact[keep])
        err = float(np.max(np.abs(ref(tt) - np.column_stack([ex.x, ex.y]))))
        assert err <= 1e-9 and err <= 10 * ref.accuracy + 1e-15

    check()


# --- the rocking block: contacts accumulating together -------------------------------------------------

BLOCK = {"name": "rocking_block", "coordinates": ["x", "y", "theta"],
         "parameters": {"m": 1.0, "g": 9.81, "a": 0.5, "b": 0.25, "e": 0.5},
         "mass_matrix": [["m", "0", "0"], ["0", "m", "0"], ["0", "0", "m*(a**2 + b**2)/3"]],
         "potential": "m*g*y",
         "constraints": [{"name": "left", "phi": "y - b*cos(theta) - a*sin(theta)", "restitution": "e"},
                         {"name": "right", "phi": "y - b*cos(theta) + a*sin(theta)", "restitution": "e"}]}


@pytest.fixture(scope="module")
def block():
    s = load_system_yaml(BLOCK)
    return s, load_module(s, SYSTEM_KERNELS), s.param_values()


def _drop(block, theta0, path):
    s, mod, prm = block
    y0 = 0.25 * math.cos(theta0) + 0.5 * abs(math.sin(theta0)) + 0.3
    return solve_exact(s, [0.0, y0, theta0], [0.0, 0.0, 0.0], prm, 3.0, path=path)


@pytest.mark.parametrize("path", ["taylor", "dop853"])
@pytest.mark.parametrize("theta0", [0.0, 0.1, -0.3])
def test_block_dropped_settles_on_both_corners(block, theta0, path):
    s, mod, prm = block
    m, g, b = 1.0, 9.81, 0.25
    ref = _drop(block, theta0, path)
    assert ref.kind == path
    t0, t1, held = ref.held_intervals[-1]
    assert held == (0, 1) and t1 == 3.0 and t0 < 1.0
    y = ref.state(3.0)
    H = mod.hamiltonian(y[:3].copy(), y[3:].copy(), prm)
    # Taylor: at rest on phi_A = 0 to the last digits. DOP853 integrates the index-reduced held
    # equations, whose phi_A and u_A drift with the solver's error between projections: within its
    # documented 1e-13 (docs/derivations/contacts.md 6.1; measured 4.5e-15 with scipy 1.17)
    tol = 1e-15 if path == "taylor" else 1e-13
    assert abs(H - m * g * b) <= (8 * np.finfo(float).eps * m * g * b if path == "taylor" else m * g * tol)
    assert np.max(np.abs(y[3:])) <= tol and abs(y[1] - b) <= tol and abs(y[2]) <= tol
    mu = rh.held_multipliers(mod, 3.0, y[:3], y[3:], prm, (0, 1))
    np.testing.assert_allclose(mu, [m * g / 2, m * g / 2], rtol=1e-13)
    if theta0 == 0.0:   # flat: every bounce hits both corners at once (Moreau's LCP), in pairs
        assert list(ref.impact_contact) == [0, 1] * (len(ref.impacts) // 2)
    assert np.isfinite(ref.accuracy) and ref.accuracy <= 1e-9


@pytest.mark.parametrize("path", ["taylor", "dop853"])
def test_block_landing_with_spin_chatters_and_settles(block, path):
    """Tilted and spinning (e = 0.83): both corners chatter, ever faster, in an order that no double
    precision solve fixes (the Taylor solve at eps and its check at 1e-14 part in it), while q differs
    by less than 1e-6 relative: a reference with that accuracy, held on both corners to the end."""
    s, mod, prm = block
    prm = s.param_values({"e": 0.8274723176088681})
    q0 = [0.0, 0.492801765037145, -0.09643511976626201]
    p0 = s.mass_matrix(q0, prm) @ np.array([0.4569149509632404, 0.4158245984780726, 2.496091581313797])
    ref = solve_exact(s, q0, p0, prm, 2.5, path=path)
    assert ref.held_intervals[-1][2] == (0, 1) and ref.held_intervals[-1][1] == 2.5 and len(ref.impacts) > 100
    assert np.isfinite(ref.accuracy) and ref.accuracy <= 1e-5
    y = ref.state(2.5)
    assert abs(mod.hamiltonian(y[:3].copy(), y[3:].copy(), prm) - 9.81 * 0.25 - 0.5 * y[3] ** 2) <= 1e-12


@pytest.mark.parametrize("path", ["taylor", "dop853"])
def test_block_without_resting_contact_raises_clearly(block, path):
    s, mod, prm = block
    with pytest.raises(RuntimeError, match=r"pushed into its constraint at t=0\.74.*resting_contact=True"):
        solve_exact(s, [0.0, 0.55, 0.0], [0.0, 0.0, 0.0], prm, 3.0, path=path, resting_contact=False)


# --- progress guard ------------------------------------------------------------------------------------

def test_an_event_loop_that_repeats_itself_is_an_error(monkeypatch):
    """A backend whose segment ends at its own start without changing anything (a lift-off that does
    not lift): the loop refuses the second repetition, naming the time and the contact."""
    def stuck(self, t0, y0, T, A, R, geo=None):
        return Flight(t0, t0, np.array(y0, float), "lift", 1, Constant(y0))

    monkeypatch.setattr(TaylorBackend, "segment", stuck)
    with pytest.raises(loop.NoProgressError, match=r"no progress at t=0: the lift of contact ceiling repeats"):
        vcirun.reference("ball_in_box", T=1.0)


def test_more_events_than_the_bound_is_an_error():
    s = resolve_system("bouncing_ball")
    mod = load_module(s, SYSTEM_KERNELS)
    prm = s.param_values()
    model = rx.taylor_model(s)
    with pytest.raises(loop.NoProgressError, match=r"more than 20 events by t=.* impact of contact phi"):
        loop.solve(TaylorBackend(model, mod, prm), mod, np.array([1.0]), np.array([0.0]), prm, 100.0,
                   names=["phi"], max_events=20)


def test_the_block_dropped_flat_ends_held_on_both_corners():
    """Both corners accumulating at once are held together: the solve ends (holding only the first one
    would repeat one held-phase solve at its own start time)."""
    s = load_system_yaml(BLOCK)
    ref = vcirun.reference(s, T=2.0, q0=[0.0, 0.55, 0.0], p0=[0.0, 0.0, 0.0])
    assert ref.held_intervals[-1][2] == (0, 1)


# --- the accuracy check ------------------------------------------------------------------------------------

class _Moved:
    """A dense piece whose positions are off by 1e-3 (the trajectory after a missed impact)."""

    def __init__(self, f, n):
        self.f, self.n = f, n

    def __call__(self, t):
        y = np.array(self.f(t), float)
        y[: self.n] += 1e-3
        return y


def _renumbered(sol, moved=True):
    """A Solution that misses its last impact (a check that sees another event sequence); moved: and
    whose trajectory differs by 1e-3 (else the same: a difference below the check's resolution)."""
    n = len(np.atleast_1d(sol.pieces[0][2](sol.pieces[0][0]))) // 2
    pieces = [(a, b, _Moved(f, n)) for a, b, f in sol.pieces] if moved else sol.pieces
    return loop.Solution(pieces, list(sol.impacts)[:-1], sol.releases, sol.intervals)


def test_a_taylor_check_that_sees_other_events_is_an_error(monkeypatch):
    real = rx._solve_taylor

    def fake(sysm, mod, model, q0, p0, prm, T, tol, resting_contact):
        sol = real(sysm, mod, model, q0, p0, prm, T, tol, resting_contact)
        return sol if tol == rx.TOL else _renumbered(sol)

    monkeypatch.setattr(rx, "_solve_taylor", fake)
    with pytest.raises(RuntimeError, match=r"event sequence of ball_in_box is ill-conditioned.*part at t=.*events "
                                           r"against"):
        vcirun.reference("ball_in_box", T=2.0)


def test_a_check_whose_other_events_do_not_show_in_q_is_accepted(monkeypatch):
    """A check that sees another event sequence with the same trajectory (the order of a settling
    chatter, a bounce more or less before a Zeno hold): accepted, its difference the accuracy."""
    real = rx._solve_taylor

    def fake(sysm, mod, model, q0, p0, prm, T, tol, resting_contact):
        sol = real(sysm, mod, model, q0, p0, prm, T, tol, resting_contact)
        return sol if tol == rx.TOL else _renumbered(sol, moved=False)

    monkeypatch.setattr(rx, "_solve_taylor", fake)
    ref = vcirun.reference("ball_in_box", T=2.0)
    assert ref.kind == "taylor" and np.isfinite(ref.accuracy) and ref.accuracy <= 1e-12


@pytest.mark.parametrize("disagree", [1, 2, 3])
def test_a_dop853_check_that_sees_other_events_is_refined_then_an_error(monkeypatch, disagree):
    """The check disagrees on the first `disagree` attempts: refined (tighter, denser, shorter steps)
    until it agrees; after three attempts, an error naming where the sequences part."""
    real = rx._solve_dop853
    calls = []

    def fake(sysm, mod, q0, p0, prm, T, rtol, resting_contact, samples=8, reach=2.0):
        calls.append((rtol, samples, reach))
        sol = real(sysm, mod, q0, p0, prm, T, rtol, resting_contact, samples, reach)
        return _renumbered(sol) if len(calls) % 2 == 0 and len(calls) <= 2 * disagree else sol

    monkeypatch.setattr(rx, "_solve_dop853", fake)
    if disagree < 3:
        ref = vcirun.reference("n_pendulum_4", T=1.5)
        assert ref.kind == "dop853" and np.isfinite(ref.accuracy) and len(calls) == 2 * (disagree + 1)
        assert calls[2][0] < calls[0][0] and calls[2][1] > calls[0][1] and calls[2][2] < calls[0][2]
    else:
        with pytest.raises(RuntimeError, match=r"different event sequences at t=.*1 events against 0, down to "
                                               r"rtol 2.3e-14"):
            vcirun.reference("n_pendulum_4", T=1.5)


# --- a resting contact that leaves and comes back -------------------------------------------------------

CART_E = {"name": "cart_pendulum_e", "coordinates": ["y", "theta"],
          "parameters": {"m1": 1.0, "m2": 0.2, "L": 2.0, "g": 10.0, "e": 0.3},
          "mass_matrix": [["m1 + m2", "m2*L*sin(theta)"], ["m2*L*sin(theta)", "m2*L**2"]],
          "potential": "(m1 + m2)*g*y - m2*g*L*cos(theta)",
          "constraints": [{"name": "floor", "phi": "y", "restitution": "e"}]}


def test_a_cart_resting_on_the_floor_lifted_by_its_pendulum_flies_bounces_settles_and_lifts_again():
    """On the floor at rest with the pendulum swinging over the top: the floor needs no force at first
    (the cart rests, not held), the pendulum lifts it, it comes back, bounces (e = 0.3), settles by
    accumulation, is released and lands again. Both paths: the same events, the same trajectory."""
    s = load_system_yaml(CART_E)
    prm = s.param_values()
    q0 = np.array([0.0, -1.9860761320374827])
    p0 = s.mass_matrix(q0, prm) @ np.array([0.0, 8.358438976097034])
    a = solve_exact(s, q0, p0, prm, 3.0)
    b = solve_exact(s, q0, p0, prm, 3.0, path="dop853", rtol=RTOL_FLOOR)
    assert a.held_intervals[0][0] > 0.01 and a.impacts[0] > 0.01     # not held from the start: it flew
    assert len(a.releases) == 1 and a.held_intervals[-1][1] == 3.0
    assert list(a.impact_contact) == list(b.impact_contact) and len(a.impacts) == len(b.impacts) >= 10
    np.testing.assert_allclose(a.releases, b.releases, rtol=0, atol=1e-10)
    tt = np.linspace(0.0, 3.0, 1201)
    assert np.max(np.abs(a(tt) - b(tt))) <= 1e-9
