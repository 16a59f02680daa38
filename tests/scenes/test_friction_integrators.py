"""Coulomb friction in the integrators (vcirun/maps/friction.py, the mode events and frictional impacts of
vcirun/collision/algorithm1.py; docs/derivations/friction.md) against the closed forms of
vcirun.scenes.friction_oracles, each derived there and checked against an independent solver in
tests/unit/test_friction_oracles.py.

The incline and the spinning ball move with constant accelerations between their events, which every
variational integrator here follows exactly: their checks are at round-off, and the event times at the
event tolerance. The Coulomb oscillator is harmonic between its turns: its turning times and stop
converge at the method's order. CVA and VCI share a core (the default suite); MCVAA and CVA4 on the
friction scenes are the `slow` twins."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import vcirun
from vcirun.scenes import friction as scenes
from vcirun.scenes import friction_oracles as oracles

FAST = ("CVA", "VCI")
SLOW = ("MCVAA", "CVA4")


def _incline_case(method, h, mu_s):
    th, mu, v0, g = 0.3, 0.2, 2.0, 9.81
    tr = vcirun.simulate(scenes.incline(th, mu=mu, mu_s=mu_s, v0=v0), method, h=h, T=1.0)
    ex = oracles.incline(th, mu=mu, mu_s=mu_s, v0=v0, g=g)
    return tr, ex


@pytest.mark.parametrize("method", FAST)
@pytest.mark.parametrize("mu_s", [0.25, 0.35])
def test_incline_stop_is_located_and_then_sticks_or_slides_back(method, mu_s):
    """Launched up a slope of 0.3 rad (tan = 0.309) with mu = 0.2: it stops at v0 / (g (sin + mu cos)); with
    mu_s = 0.35 it sticks there (mode change 1), with mu_s = 0.25 it slides back (3: slip reversed) with
    a = g (sin - mu cos). The stop is an event located to event_tol h, the positions exact to round-off."""
    for h in (1e-2, 2.5e-3):
        tr, ex = _incline_case(method, h, mu_s)
        assert tr.status == "ok", tr.message
        assert list(tr.mode_change_kind) == [1 if mu_s > math.tan(0.3) else 3]
        assert abs(tr.mode_changes[0] - ex.t_stop) <= 1e-10
        s = np.cos(0.3) * tr.q[:, 0] + np.sin(0.3) * tr.q[:, 1]   # distance up the slope
        want = np.array([ex.state(t)[0] for t in tr.t])
        assert np.max(np.abs(s - want)) <= 1e-12
        assert np.max(np.abs(-np.sin(0.3) * tr.q[:, 0] + np.cos(0.3) * tr.q[:, 1])) <= 1e-14   # on the slope
        assert set(np.unique(tr.contact_mode[:, 0])) <= {1, -1, 2}
        # the friction work is the energy the motion lost: H(T) - H(0) to round-off
        assert abs(tr.friction_work.sum() - (tr.H[-1] - tr.H[0])) <= 1e-12


@pytest.mark.parametrize("method", FAST)
def test_box_held_on_a_ramp_does_not_creep(method):
    """A block resting on a slope whose static friction is 1.05 times what holds it (mu_s = 1.05 tan theta):
    it sticks from the start and does not move in 10 s (MuJoCo's regularised friction creeps here)."""
    th = 0.3
    sysm = scenes.incline(th, mu=0.2, mu_s=1.05 * math.tan(th), v0=0.0)
    tr = vcirun.simulate(sysm, method, h=1e-3, T=10.0)
    assert tr.status == "ok", tr.message
    assert np.all(tr.contact_mode[:, 0] == 2)
    assert np.max(np.abs(tr.q - tr.q[0])) <= 1e-14
    assert len(tr.mode_changes) == 0 and np.all(tr.friction_work == 0.0)


@pytest.mark.parametrize("method", FAST)
@pytest.mark.parametrize("w0", [10.0, 50.0])
def test_spinning_ball_against_capobianco(method, w0):
    """Capobianco et al. 2021, 10.1: dropped from centre height 1 with spin w0 onto a floor with mu = 0.2,
    e = 0. w0 = 10 sticks at the impact (xdot+ = -(2/7) R w0) and rolls; w0 = 50 slides through the
    impact (xdot+ = -0.840428, phidot+ = 28.989288), and rolling starts 0.299767 s later at xdot =
    -(2/7) R w0: the impact time, the impulses, the mode at the impact and the rolling start against the
    closed form."""
    ex = oracles.spinning_ball(w0)
    tr = vcirun.simulate(scenes.spinning_ball(w0), method, h=1e-3, T=1.2)
    assert tr.status == "ok", tr.message
    assert len(tr.impacts) == 1 and abs(tr.impacts[0] - ex.t1) <= 1e-11
    xdot_plus = tr.impact_p_plus[0][0] / 1.0   # m = 1
    assert abs(xdot_plus - ex.xdot_plus) <= 1e-12
    assert abs(tr.impact_impulse[0] - ex.P_n) <= 1e-12 and abs(abs(tr.impact_impulse_t[0]) - abs(ex.P_t)) <= 1e-12
    k_imp = int(np.searchsorted(tr.t, ex.t1))
    if ex.sticks:
        assert len(tr.mode_changes) == 0 and np.all(tr.contact_mode[k_imp + 1:, 0] == 2)
    else:
        assert list(tr.mode_change_kind) == [1]                      # slip -> stick: rolling starts
        assert abs(tr.mode_changes[0] - ex.t_roll) <= 1e-10
        assert np.all(np.abs(tr.contact_mode[k_imp + 1: int(ex.t_roll / 1e-3) - 1, 0]) == 1)
    xdot_end = tr.p[-1, 0]
    assert abs(xdot_end - ex.xdot_roll) <= 1e-12
    # the energy went to the plastic impact and to friction, nothing to the integration
    acc = tr.energy_account()
    assert abs(acc.error) <= 1e-10 * abs(tr.H[0])


@pytest.mark.parametrize("method", FAST)
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(height=st.floats(0.3, 1.5), slip=st.floats(1e-4, 0.08), v_share=st.floats(0.0, 1.0),
       h=st.sampled_from([1e-2, 4e-3]))
def test_slip_that_stops_within_the_landing_step_is_located(method, height, slip, v_share, h):
    """The spinning ball landing with a slip velocity s+ so small that friction stops it within a step
    (s+ / (7/2 mu g) <= 1.2e-2 s): the stop falls in the rest of the landing step after the impact
    (an event step) or in the next steps. It is located to the event tolerance wherever it falls, and
    the motion is the closed form's to round-off (constant accelerations between the events); a stop
    found only at the next grid state would put it up to h late, with the ball off by O(mu g h^2)."""
    mu, g, R = 0.2, 9.81, 0.1
    vn = math.sqrt(2.0 * (height - R) * g)
    s0 = 3.5 * mu * vn + slip                     # the slip before the impact: s+ = slip after it
    v0 = v_share * s0
    w0 = (s0 - v0) / R
    ex = oracles.spinning_ball(w0, h=height, v0=v0, mu=mu, g=g, R=R)
    assert not ex.sticks and abs(ex.slip_plus - slip) <= 1e-12
    T = h * math.ceil((ex.t_roll + 0.05) / h)
    tr = vcirun.simulate(scenes.spinning_ball(w0, h=height, v0=v0), method, h=h, T=T)
    assert tr.status == "ok", tr.message
    assert len(tr.impacts) == 1 and abs(tr.impacts[0] - ex.t1) <= 1e-11
    assert list(tr.mode_change_kind) == [1]
    assert abs(tr.mode_changes[0] - ex.t_roll) <= 1e-10
    want = np.array([ex.state(t) for t in tr.t])
    assert np.max(np.abs(tr.q - want[:, :3])) <= 1e-11
    assert np.all(tr.friction_work <= 0.0)
    assert abs(tr.energy_account().error) <= 1e-10 * abs(tr.H[0])


def test_slip_stop_inside_the_landing_step_is_a_case_of_the_property():
    """The property above reaches the case it is written for: for one of its draws (height 1, the
    slip 0.01, h = 1e-2) the impact and the stop fall in the same grid step."""
    mu, g, R, h = 0.2, 9.81, 0.1, 1e-2
    vn = math.sqrt(2.0 * 0.9 * g)
    ex = oracles.spinning_ball((3.5 * mu * vn + 0.01) / R, h=1.0, mu=mu, g=g, R=R)
    assert math.floor(ex.t1 / h) == math.floor(ex.t_roll / h)


def _oscillator_turns(method, h):
    x0, m, k, mu = 1.0, 1.0, 10.0, 0.1
    tr = vcirun.simulate(scenes.coulomb_oscillator(x0, m=m, k=k, mu=mu), method, h=h, T=6.0)
    ex = oracles.coulomb_oscillator(x0, m=m, k=k, mu=mu)
    return tr, ex


@pytest.mark.parametrize("method", FAST)
def test_coulomb_oscillator_turns_and_stop_converge_at_order_two(method):
    """m x'' + k x = -mu m g sign x': each turn (slip stops, then reverses or sticks) is a located event;
    the turning times and the stop converge at order 2 (k = 10, mu = 0.1, x0 = 1: it stops at its 5th turn)."""
    errs = []
    for h in (4e-3, 2e-3, 1e-3):
        tr, ex = _oscillator_turns(method, h)
        assert tr.status == "ok", tr.message
        assert len(tr.mode_changes) == len(ex.turns)
        assert list(tr.mode_change_kind) == [3] * (len(ex.turns) - 1) + [1]
        errs.append(max(abs(a - b) for a, b in zip(tr.mode_changes, [t for t, _ in ex.turns])))
        assert abs(tr.q[-1, 0] - ex.x_stop) <= 5.0 * h * h
    orders = [math.log2(errs[i] / errs[i + 1]) for i in range(len(errs) - 1)]
    assert all(1.8 <= o <= 2.3 for o in orders), (errs, orders)


@pytest.mark.parametrize("method", FAST)
def test_painleve_rod_ends_with_the_status(method):
    """A uniform rod sliding on one end with mu = 1.5 > 4/3 at a tilt where B < 0: the run ends with status
    painleve at the start, its message names the contact and B; never a hang or NaN."""
    th0, mu = 1.0, 1.5
    assert oracles.painleve_B(th0, mu, -1.0) < 0.0
    tr = vcirun.simulate(scenes.painleve_rod(th0, xdot0=-1.0, mu=mu), method, h=1e-3, T=0.5)
    assert tr.status == "painleve", (tr.status, tr.message)
    assert "B = " in tr.message and "contact 0" in tr.message
    assert np.all(np.isfinite(tr.q))


@pytest.mark.slow
@pytest.mark.parametrize("method", SLOW)
def test_friction_scenes_every_method(method):
    """The incline (both outcomes), the box on the ramp and the spinning ball with the MCVA family and CVA4."""
    for mu_s in (0.25, 0.35):
        tr, ex = _incline_case(method, 1e-2, mu_s)
        assert tr.status == "ok" and abs(tr.mode_changes[0] - ex.t_stop) <= 1e-10
    th = 0.3
    tr = vcirun.simulate(scenes.incline(th, mu=0.2, mu_s=1.05 * math.tan(th)), method, h=1e-3, T=10.0)
    assert tr.status == "ok" and np.max(np.abs(tr.q - tr.q[0])) <= 1e-14
    for w0 in (10.0, 50.0):
        ex = oracles.spinning_ball(w0)
        tr = vcirun.simulate(scenes.spinning_ball(w0), method, h=1e-3, T=1.2)
        assert tr.status == "ok" and abs(tr.p[-1, 0] - ex.xdot_roll) <= 1e-10


@pytest.mark.parametrize("method", FAST)
def test_rocking_block_rocks_at_housners_ratio(method):
    """A block (a = 1, b = 0.4) released at rest on one corner at 0.1 rad, mu = 0.8 (above the 0.288 that
    a plastic corner impact needs to stick): it rocks on its corners alternately without sliding, each
    plastic corner impact multiplies the angular velocity by Housner's 1 - 3/2 sin^2 alpha (to round-off:
    the law's impact), and the impact times converge at order 2 to the closed form."""
    a, b, th0 = 1.0, 0.4, 0.1
    ex = oracles.housner_rocking(th0, a=a, b=b, impacts=3)
    ratio = oracles.housner_ratio(a, b)
    I = (a * a + b * b) / 12.0
    errs = []
    for h in (2e-3, 1e-3):
        tr = vcirun.simulate(scenes.rocking_block_friction(th0, a=a, b=b, mu=0.8), method, h=h, T=0.9)
        assert tr.status == "ok", tr.message
        assert list(tr.impact_contact[:3]) == [1, 0, 1]
        for k in range(3):
            w_minus, w_plus = tr.impact_p_minus[k][2] / I, tr.impact_p_plus[k][2] / I
            assert abs(w_plus / w_minus - ratio) <= 1e-13
        assert len(tr.mode_changes) == 0                          # stuck on each corner: no sliding
        held = tr.contact_mode[tr.contact_active]
        assert held.size > 0 and np.all(held == 2)
        errs.append(max(abs(tr.impacts[k] - ex.impact_times[k]) for k in range(3)))
    assert errs[1] < errs[0] / 3.0 and errs[0] < 1e-5, errs


# --- mechanisms against the exact reference ---------------------------------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("method", ["CVA", "MCVAA"])
def test_link_chain_with_friction_settles_as_the_reference(method):
    """Three links dropped in a zigzag on a floor with friction (e = 0.3, mu = 0.5) against the exact
    reference (DOP853): the first impacts at the reference's times to O(h^2), the chain at rest flat on
    its four ends with every end stuck (the reference's last mode interval), the end state converging at
    order 2. A body whose ends slide together stops on every end at once (maps/friction.py
    assign_modes), and a slip that reversed inside the rest of an event step is taken up at the next
    grid state (collision/algorithm1.py _modes_stale): without those the ends chatter or slide on."""
    s = scenes.link_chain_friction(3)
    T = 0.7
    ref = vcirun.reference(s, T=T, check_accuracy=False)
    assert ref.status == "ok" and ref.mode_intervals[-1][2] == (0, 1, 2, 3)
    q_end = ref(T)[:s.n]
    first = np.array(sorted(ref.impacts)[:6])
    errs, terrs = [], []
    for h in (1e-3, 5e-4):
        tr = vcirun.simulate(s, method, h=h, T=T)
        assert tr.status == "ok", tr.message
        assert np.all(tr.contact_mode[-1] == 2) and np.all(tr.contact_active[-1])
        assert float(np.max(np.abs(tr.p[-1]))) <= 1e-12
        errs.append(float(np.max(np.abs(tr.q[-1] - q_end))))
        terrs.append(float(np.max(np.abs(np.asarray(tr.impacts[:6]) - first))))
    assert errs[0] < 3e-5 and errs[1] < errs[0] / 2.5, errs
    assert terrs[0] < 5e-4 and terrs[1] < terrs[0] / 2.5, terrs


@pytest.mark.parametrize("method", FAST)
def test_link_chain_of_five_settles_through_a_stick_event_that_jumps(method):
    """The built-in 5-link chain with friction (`vcirun simulate --system link_chain_friction --h 0.001
    --T 1`). Lying almost flat on two stuck ends (t = 0.4532), their slip rows cross the dependence
    threshold of maps/friction.py (DEPENDENT_TOL) inside a partial held step, and the first end's stick
    event function mu_s lam - |lt| jumps there from +0.19 to -3e8: Illinois alone crept along the jump
    and the run ended `event_failed` in step 453 (VCI: 450) after the located mode event's 100
    iterations (collision/algorithm1.py _locate_mode_event, which now bisects where it stalls). The
    chain comes to rest flat on its six ends, every end held and stuck."""
    tr = vcirun.simulate("link_chain_friction", method, h=1e-3, T=1.0)
    assert tr.status == "ok", tr.message
    assert np.all(tr.contact_active[-1]) and np.all(tr.contact_mode[-1] == 2)
    assert float(np.max(np.abs(tr.q[-1][1:]))) <= 1e-12      # y and every angle: flat on the floor
    assert float(np.max(np.abs(tr.p[-1]))) <= 1e-12


@pytest.mark.slow
@pytest.mark.parametrize("method", ["CVA", "MCVAA"])
def test_compass_gait_stance_foot_sticks_in_the_methods(method):
    """The compass gait's stance phase with a frictional foot (mu = 1, above the 0.274 the gait needs):
    the methods keep the foot stuck all stride long (its position 0 to round-off, mode 2 at every grid
    state, no mode change), and the legs follow the built-in pinned gait's reference at order 2."""
    from vcirun.scenes.registry import scene_data
    from vcirun.scenes.walkers import compass_gait_M

    D = scene_data("compass_gait")
    gam = D.params["gamma"]
    pin = vcirun.reference("compass_gait", T=1.0)
    ths = float(pin.impacts[0])
    y0 = pin.state(0.0)
    q0, v0 = y0[:2], np.linalg.solve(np.array(compass_gait_M(y0[:2], D.params)), y0[2:])
    s = scenes.compass_gait_stance(*q0, *v0, mu=1.0)
    T = 0.66                       # (a multiple of both steps, before the heel strike at 0.734)
    assert T < ths
    errs = []
    for h in (2e-3, 1e-3):
        tr = vcirun.simulate(s, method, h=h, T=T)
        assert tr.status == "ok", tr.message
        assert np.all(tr.contact_mode[:, 0] == 2) and len(tr.mode_changes) == 0
        assert float(np.max(np.abs(tr.q[:, :2]))) <= 1e-12
        errs.append(float(np.max(np.abs(tr.q[:, 2:] - gam - pin(tr.t)))))
    assert errs[1] < errs[0] / 3.0 and errs[0] < 1e-3, errs


@pytest.mark.slow
@pytest.mark.parametrize("method", ["CVA", "MCVAA"])
def test_rocking_block_comes_to_rest_on_both_corners_as_the_reference(method):
    """Housner's block (mu = 0.8) rocks, loses energy at each plastic corner impact and comes to rest on
    both corners (the reference: at rest from t = 1.708, 61 impacts). The methods end at rest with
    both corners stuck and x at the reference's to O(h^2): a slip reversed inside the rest of an event
    step is tried stuck first at the next grid state (collision/algorithm1.py _reassign_modes); without
    that the block kept rocking and sliding."""
    s = scenes.rocking_block_friction(0.1, mu=0.8)
    T = 2.0
    ref = vcirun.reference(s, T=T, check_accuracy=False)
    assert ref.status == "ok"
    q_end = ref(T)[:s.n]
    errs = []
    for h in (1e-3, 5e-4):
        tr = vcirun.simulate(s, method, h=h, T=T)
        assert tr.status == "ok", tr.message
        assert np.all(tr.contact_mode[-1] == 2) and float(np.max(np.abs(tr.p[-1]))) <= 1e-12
        errs.append(float(np.max(np.abs(tr.q[-1] - q_end))))
    assert errs[0] < 1e-4 and errs[1] < errs[0] / 2.5, errs


def test_painleve_cause_takes_the_slip_direction_of_the_state():
    """Where the failing grid state records no slip mode, the cause takes the sign of the slip velocity
    W M^-1 p: a rod at th0 = 1.0 sliding to +x has B(+1) > 0 (no paradox), though B(-1) < 0."""
    from vcirun.run.diagnosis import failure_cause

    th0, mu = 1.0, 1.5
    assert oracles.painleve_B(th0, mu, 1.0) > 0.0 > oracles.painleve_B(th0, mu, -1.0)
    tr = vcirun.simulate(scenes.painleve_rod(th0, xdot0=-1.0, mu=mu), "CVA", h=1e-3, T=0.01)
    assert tr.status == "painleve"
    mod, prm = tr.dynamics.module, tr.dynamics.prm
    q = tr.q[:1]
    tol = dict(tr.tolerances)
    for sign, expect in ((-1.0, "direction -1"), (1.0, "")):
        p = np.array([sign, 0.0, 0.0])   # the rod's horizontal momentum (xdot0 = +-1, m = 1)
        cause = failure_cause(mod, "painleve", q, p, 0.0, 0, 1e-3, prm, tol, 0.0, np.zeros(0),
                              modes=np.zeros((1, 1), np.int8))
        assert (expect in cause) if expect else cause == "", (sign, cause)
