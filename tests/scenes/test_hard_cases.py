"""Hard cases of Algorithm 1 (event search, resets, loop caps), each with a stated outcome.

Most cases use the oscillator against a wall (m = k = 1, wall at x = -d), where the SVC partial
step has a closed form: from (q0, p0), Phi_tau gives the parabola
    x(tau) = q0 + tau p0 / m - tau^2 k q0 / (2 m),
so the *discrete* collision time is the smallest positive root of x(tau) = -d. Impacts at a chosen
discrete time and momentum are constructed exactly with the self-adjointness of SVC:
Phi_tau(q1, -p1) = (q0, -p0), i.e. stepping back from the impact state lands (to round-off) on the
state from which Algorithm 1 hits the wall at exactly that tau with exactly that p-.

Every run goes through `_guarded`, which runs it in a daemon thread (the compiled loop releases the
GIL) and fails the test if it does not return within 60 s: nothing here may loop forever.
"""
from __future__ import annotations


import numpy as np
import pytest
import sympy as sp

import vcirun

NO_HELD = np.zeros(1, dtype=np.int64)  # collision_time's held contacts: none
from vcirun.run.resolve import resolve_system
from vcirun.codegen.build import load_module
from vcirun.mechanics.system import MechanicalSystem
from vcirun.methods.table import METHODS
from vcirun.scenes.oracles import oscillator_wall_exact
from guards import guarded

D = 0.5
NTOL, MAXIT, ETOL = 1e-12, 50, 1e-13
ZERO_STEP_BUG = (
    "BUG: a partial step of length 0 raises ZeroDivisionError out of simulate(). "
    "vcirun/collision/events.py:55 (collision_time, 'moving into the constraint from the surface: "
    "the impact is at tau = 0') calls partial(qh, ph, 0.0, ...); the generated step kernels divide "
    "by the step length (e.g. oscillator SVC_PmJ: r = -(1/2) hh (-k q - 2 m v / hh), the h/h from "
    "substituting q1 = q0 + h v in vcirun/discrete/lagrangians.py:step_expressions is never "
    "cancelled), and numba's default error model raises. Reached whenever a step starts on "
    "phi = 0 moving inwards: an initial state on the surface moving in, a trial step landing "
    "exactly on phi = 0.0 (the next step then starts there), resting contact. simulate() is "
    "documented never to raise on numerical failure.")


def _guarded(fn, timeout=60.0):
    return guarded(fn, timeout)


def _sim(method, h, T, x0, v0, **kw):
    return _guarded(lambda: vcirun.simulate("oscillator_wall", method, h=h, T=T, q0=np.array([float(x0)]),
                                            p0=np.array([float(v0)]), **kw))


def _osc(params=None):
    s = resolve_system("oscillator_wall")
    prm = s.param_values(params)
    return prm, load_module(s, METHODS["CVA"].kernel_set()), load_module(s, METHODS["VCI"].kernel_set())


def _backward(q_imp, p_imp, tau, h=None, k_full=0, params=None):
    """Initial state whose Algorithm-1 run reaches (q_imp, p_imp) after k_full full steps h and a
    partial step tau (SVC is self-adjoint)."""
    prm, mod, _ = _osc(params)
    q, p, v = np.empty(1), np.empty(1), np.empty(1)
    it, _ = mod.partial(np.array([q_imp]), np.array([-p_imp]), tau, tau, 0.0, prm, 1e-14, 50, q, p, v)
    assert it > 0
    for _ in range(k_full):
        qa, pa = q.copy(), p.copy()
        it, _ = mod.full(qa, pa, h, 0.0, prm, 1e-14, 50, q, p, v)
        assert it > 0
    return float(q[0]), float(-p[0])


def _err(tr, x0, v0, d=D):
    x, _, t_imp = oscillator_wall_exact(tr.t, x0, v0, 1.0, 1.0, d)
    return float(np.max(np.abs(tr.q[:, 0] - x))), t_imp


def _assert_failure_record(tr, status, step):
    """A failure is data: status, step, time, and the state it failed from (the last grid state)."""
    assert tr.status == status
    assert tr.fail_step == step and len(tr.t) == step + 1
    assert tr.fail_time == pytest.approx(step * tr.h)
    assert tr.message.startswith(f"{status} in step {step} (t = {tr.fail_time:.6g}) from q = [")
    assert f"q = {tr.q[-1].tolist()}" in tr.message and f"p = {tr.p[-1].tolist()}" in tr.message


# --- impacts at (or within 1e-12 h of) a step end ------------------------------------------------

H = 0.1
PM = -0.8
STEP_END_CASES = {
    # name: (full steps before, partial tau, exact discrete impact time)
    "1e-12h_before_step_end": (4, (1 - 1e-12) * H, 5 * H - 1e-12 * H),
    "1e-12h_after_step_start": (5, 1e-12 * H, 5 * H + 1e-12 * H),
    "1e-12h_after_t0": (0, 1e-12 * H, 1e-12 * H),
}


@pytest.mark.parametrize("method", ["CVA", "VCI"])
@pytest.mark.parametrize("case", list(STEP_END_CASES))
def test_impact_within_1e12_h_of_step_end(method, case):
    k, tau, t_star = STEP_END_CASES[case]
    x0, v0 = _backward(-D, PM, tau, H, k)
    tr = _sim(method, H, 3.0, x0, v0)
    assert tr.status == "ok", tr.message
    # located on the correct side of the grid point, far inside the 1e-12 h offset
    assert abs(tr.impacts[0] - t_star) <= 1e-14, tr.impacts[0] - t_star
    step = int(np.flatnonzero(tr.impact_step)[0])
    assert step == int(t_star // H)
    assert abs(tr.impact_p_minus[0, 0] - PM) <= 1e-12
    assert np.min(tr.partial_steps) <= 2e-12 * H   # the 1e-12 h sliver was actually stepped
    if method == "CVA":
        assert tr.impact_p_plus[0, 0] == pytest.approx(-PM, rel=1e-14)
    # the run stays second-order accurate: observed 1.4e-3..2.4e-3 (CVA), 0.9e-3..4.0e-3 (VCI)
    err, _ = _err(tr, x0, v0)
    assert err <= 1.0 * H**2, err


@pytest.mark.parametrize("method", ["CVA", "VCI"])
def test_map_across_the_step_end(method):
    """Impact 1e-12 h before vs after the grid point 5h. CVA is continuous (same final state to
    1e-9). VCI is not: at the end of a step R^VCI balances a full-length pre-impact step against a
    vanishing post-impact one and at the start of the next the reverse, so p+ jumps by O(h^2)
    (observed 0.80173 vs 0.79827 for p- = -0.8, h = 0.1). Bounded by 0.5 h^2."""
    runs = []
    for case in ("1e-12h_before_step_end", "1e-12h_after_step_start"):
        k, tau, _ = STEP_END_CASES[case]
        x0, v0 = _backward(-D, PM, tau, H, k)
        runs.append(_sim(method, H, 3.0, x0, v0))
    a, b = runs
    assert a.status == b.status == "ok"
    jump = abs(a.impact_p_plus[0, 0] - b.impact_p_plus[0, 0])
    if method == "CVA":
        assert jump <= 1e-12
        assert np.max(np.abs(a.q[-1] - b.q[-1])) <= 1e-9 and np.max(np.abs(a.p[-1] - b.p[-1])) <= 1e-9
    else:
        assert jump <= 0.5 * H**2, jump


def _exact_landing_state():
    """(x0, v0) whose first full step h = 0.1 ends *exactly* on phi = 0.0 (checked)."""
    prm, mod, _ = _osc()
    x0, v0 = _backward(-D, PM, H)
    q, p, v = np.empty(1), np.empty(1), np.empty(1)
    for _ in range(8):
        mod.full(np.array([x0]), np.array([v0]), H, 0.0, prm, NTOL, MAXIT, q, p, v)
        if q[0] + D == 0.0:
            return x0, v0
        x0 = np.nextafter(x0, -1.0 if q[0] + D > 0 else 1.0)
    raise AssertionError("could not construct an exact landing on phi = 0")


@pytest.mark.parametrize("method", ["CVA", "VCI"])
def test_impact_exactly_at_step_end(method):
    """The trial step lands exactly on phi = 0.0 at t = h: expected one impact at t = h (as in the
    1e-12 h cases next to it) and a normal run."""
    x0, v0 = _exact_landing_state()
    tr = _sim(method, H, 3.0, x0, v0)
    assert tr.status == "ok"
    assert abs(tr.impacts[0] - H) <= 1e-14
    assert _err(tr, x0, v0)[0] <= 1.0 * H**2


# --- grazing ------------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["CVA", "VCI"])
def test_grazing_exact_solution(method):
    """Amplitude A = d + 1 ulp: the exact motion touches the wall with normal speed
    sqrt(A^2 - d^2) = 1.05e-8 (3 impacts in [0, 20]). The discrete run may or may not see these
    contacts (their effect, a velocity change of 2e-8, is far below the O(h^2) error); it must
    complete and be exactly as accurate as the run with A = d that never touches."""
    x0 = float(np.nextafter(D, 1.0))
    vn = np.sqrt(x0**2 - D**2)
    assert 5e-9 < vn < 2e-8
    tr = _sim(method, H, 20.0, x0, 0.0)
    ref_run = _sim(method, H, 20.0, D, 0.0)
    assert tr.status == ref_run.status == "ok"
    err, t_imp = _err(tr, x0, 0.0)
    assert len(t_imp) == 3
    assert len(tr.impacts) <= len(t_imp)
    assert abs(err - _err(ref_run, D, 0.0)[0]) <= 1e-7 and err <= 1.0 * H**2


TAU_G = (1 - 1e-4) * H


def test_grazing_discrete_impact_cva():
    """Discrete grazing: the partial-step parabola crosses the wall at tau = (1 - 1e-4) h with
    p- = -1e-8; the impact is so late in the step that the trial step still ends inside, by
    1.2e-9. CVA finds it, reflects p -> +1e-8, and carries on at full accuracy."""
    x0, v0 = _backward(-D, -1e-8, TAU_G)
    tr = _sim("CVA", H, 10.0, x0, v0)
    assert tr.status == "ok", tr.message
    # a grazing root is ill-conditioned: delta tau ~ eps |x| / |v_n| ~ 1e-8 here, so ask 1e-10 h
    assert abs(tr.impacts[0] - TAU_G) <= 1e-10 * H
    assert abs(tr.impact_p_minus[0, 0] + 1e-8) <= 1e-12
    assert tr.impact_p_plus[0, 0] == pytest.approx(-tr.impact_p_minus[0, 0], rel=1e-12)
    assert _err(tr, x0, v0)[0] <= 1.0 * H**2


def test_grazing_discrete_impact_vci_has_no_reset():
    """Same impact for VCI: eq. (33) has no solution (the pre-impact step of length ~h carries
    discrete energy -D3 Ld below the minimum over w of the post-impact one; the difference, O(h^2)
    ~ 3e-4 here, cannot be absorbed by a normal kinetic energy of 5e-17). Outcome: status
    reset_failed at step 0 with time and state, not an exception, a loop, or p+ = p-."""
    x0, v0 = _backward(-D, -1e-8, TAU_G)
    prm, _, mv = _osc()
    m, k, d = prm
    q, p, v = np.empty(1), np.empty(1), np.empty(1)
    code, dtau, Epre, _ = mv.collision_time(np.array([x0]), np.array([v0]), H, H, 0.0, prm, NTOL, MAXIT, ETOL, q, p, v, NO_HELD)
    assert code == 1
    tau = H - dtau
    a, b, c = m / 2 + k * tau**2 / 4, k * tau * q[0] / 2, k * q[0] ** 2 / 2
    assert Epre < c - b * b / (4 * a)  # below min_w -D3 Ld(q, w, tau): no root
    tr = _sim("VCI", H, 10.0, x0, v0)
    _assert_failure_record(tr, "reset_failed", 0)


@pytest.mark.parametrize("method", ["CVA", "VCI"])
def test_start_on_surface_grazing_inwards(method):
    """On the wall moving in at 1e-8: the parabola dips 1e-16 deep (invisible to phi), the first
    trial step ends outside, no impact is recorded; the run matches the reflected exact motion."""
    tr = _sim(method, H, 10.0, -D, -1e-8)
    assert tr.status == "ok"
    assert _err(tr, -D, 1e-8)[0] <= 1.0 * H**2


# --- several impacts in one step ---------------------------------------------------------------

BOUNCE = dict(d=-0.5)            # wall at x = +0.5 on the spring's side: the mass bounces on it
A_B = 0.5 * (1 + 1e-4)           # bounce period 2 arccos(0.5 / A) = 0.0283 < h = 0.1


def test_several_impacts_in_one_step_cva():
    tr = _sim("CVA", H, 1.0, A_B, 0.0, params=BOUNCE)
    assert tr.status == "ok", tr.message
    err, t_imp = _err(tr, A_B, 0.0, d=-0.5)
    assert len(tr.impacts) == len(t_imp) == 35
    per_step = np.bincount(np.floor(tr.impacts / H).astype(int))
    assert per_step.max() >= 3   # observed 4
    assert np.max(np.abs(tr.impacts - t_imp)) < 5e-5   # observed 1.7e-5
    assert err < 1e-6                                  # observed 8.4e-8
    assert np.ptp(tr.H) < 1e-8                         # observed 1.3e-9
    # between two impacts of the same step the partial-step parabola from (q = 0.5, p+) returns
    # to the wall after exactly 2 p+ / (k q): the searches started on the surface are exact
    same_step = np.floor(tr.impacts[1:] / H) == np.floor(tr.impacts[:-1] / H)
    dt = np.diff(tr.impacts)[same_step]
    expected = 2 * tr.impact_p_plus[:-1, 0][same_step] / 0.5
    assert same_step.sum() >= 10
    np.testing.assert_allclose(dt, expected, rtol=1e-9)


def test_many_impacts_per_run_are_not_accumulation():
    """A full impact record is not an accumulation: the loop stops with ST_ACCUMULATION when the
    record is full and vcirun.run.api reruns with room. A fixed record of max(64, N // 4 + 16) would
    stop this run (1 impact per step, 106 exact impacts, N = 300) with 'accumulation in step 258'
    after 91 impacts, and cart_pendulum CVA h = 0.2, beta = 4.2 (a 59-impact chatter burst in one
    step) at 64 impacts."""
    tr = _sim("CVA", 0.01, 3.0, A_B, 0.0, params=BOUNCE)
    assert tr.status == "ok", tr.message
    err, t_imp = _err(tr, A_B, 0.0, d=-0.5)
    assert len(tr.impacts) == len(t_imp) == 106
    assert len(tr.partial_steps) == 2 * 106   # one partial step to and one from each impact
    tr = _guarded(lambda: vcirun.simulate("cart_pendulum", "CVA", h=0.2, T=10.0, beta=4.2))
    assert tr.status == "ok", tr.message
    assert np.bincount(np.floor(tr.impacts / 0.2).astype(int)).max() > 50


def test_several_impacts_in_one_step_vci_limitation():
    """VCI in the same regime: R^VCI balances the short pre-impact step against a post-impact step
    over the whole remaining time, which here contains further bounces. Eq. (33) then has one
    reflecting root, and its end point lies outside the wall: the first reset triples the normal
    momentum (0.00707 -> 0.0223), the next bounce is lost, and the run never records two impacts
    in a step (10 impacts in [0, 1] vs 35 exact). The run completes; the reset equations hold."""
    tr = _sim("VCI", H, 1.0, A_B, 0.0, params=BOUNCE)
    assert tr.status == "ok"
    _, t_imp = _err(tr, A_B, 0.0, d=-0.5)
    per_step = np.bincount(np.floor(tr.impacts / H).astype(int))
    assert per_step.max() == 1 and len(tr.impacts) < len(t_imp)
    assert abs(tr.impact_p_plus[0, 0]) > 2.5 * abs(tr.impact_p_minus[0, 0])
    # the first reset satisfies eq. (33): recompute it from the initial state
    prm, _, mv = _osc(BOUNCE)
    q, p, v = np.empty(1), np.empty(1), np.empty(1)
    code, dtau, Epre, _ = mv.collision_time(np.array([A_B]), np.array([0.0]), H, H, 0.0, prm, NTOL, MAXIT, ETOL, q, p, v, NO_HELD)
    assert code == 1
    pp = tr.impact_p_plus[0]
    w = (pp - (H - dtau) * prm[1] * q / 2) / prm[0]   # oscillator: Pm(q, w, tau) = m w + tau k q / 2
    assert abs(mv.SVC_Ed(q, w, H - dtau, prm) - Epre) <= 1e-12 * abs(Epre)


# --- event root search --------------------------------------------------------------------------

DEEP = [  # (q0, p0, h, k): trial steps ending far inside the wall
    (-0.45, -3.0, 0.5, 1.0),     # phi(trial) = -1.39 vs phi(q0) = 0.05
    (-0.45, -5.0, 0.15, 100.0),  # stiff (w h = 1.5), strongly curved parabola: -0.19 vs 0.05
    (0.0, -20.0, 0.15, 100.0),   # -2.5 vs 0.5
]


@pytest.mark.parametrize("method", ["CVA", "VCI"])
@pytest.mark.parametrize("q0, p0, h, k", DEEP)
def test_deep_trial_step_root_is_the_discrete_collision_time(method, q0, p0, h, k):
    prm, mod, _ = _osc(dict(k=k))
    q, p, v = np.empty(1), np.empty(1), np.empty(1)
    mod.full(np.array([q0]), np.array([p0]), h, 0.0, prm, NTOL, MAXIT, q, p, v)
    assert q[0] + D <= -3 * (q0 + D)   # deep inside
    tr = _sim(method, h, h, q0, p0, params=dict(k=k))
    assert tr.status == "ok"
    roots = np.roots([-k * q0 / 2, p0, q0 + D])
    roots = np.sort(roots[np.isreal(roots)].real)
    tau = roots[roots > 0][0]
    assert abs(tr.impacts[0] - tau) <= 1e-12 * h
    assert abs(tr.impact_q[0, 0] + D) <= 1e-13


@pytest.mark.parametrize("scene, kw", [("cart_pendulum", dict(beta=4.0)), ("double_pendulum", {})])
@pytest.mark.parametrize("method", ["CVA", "VCI"])
def test_large_step_events_are_first_roots_on_the_surface(scene, kw, method):
    """h = 0.1 (trial steps end well inside): every recorded impact lies on phi = 0 and no earlier
    sign change of phi along the partial-step path precedes it (scan of 400 points)."""
    s = resolve_system(scene)
    prm = s.param_values(None)
    mod = load_module(s, METHODS[method].kernel_set())
    h = 0.1
    tr = _guarded(lambda: vcirun.simulate(scene, method, h=h, T=10.0, **kw))
    assert tr.status == "ok" and len(tr.impacts) >= 2
    assert max(abs(s.phi_value(q, prm)) for q in tr.impact_q) <= 1e-12
    n = s.n
    qt, pt, vt = np.empty(n), np.empty(n), np.empty(n)
    for i in np.flatnonzero(tr.impact_step):
        code, tau, _, _ = mod.collision_time(tr.q[i], tr.p[i], h, h, tr.t[i], prm, NTOL, MAXIT, ETOL, qt, pt, vt, NO_HELD)
        assert code == 1
        for s_ in np.linspace(0.0, tau, 402)[1:-1]:
            mod.partial(tr.q[i], tr.p[i], s_, h, tr.t[i], prm, NTOL, MAXIT, qt, pt, vt)
            assert mod.sys_phi(qt, prm) > 0.0


def _free_particle_cubic_wall():
    x, m = sp.Symbol("x"), sp.Symbol("m")
    return MechanicalSystem(name="free_particle_cubic_phi", q=[x], params={"m": 1.0}, M=sp.Matrix([[m]]),
                            V=sp.Integer(0), phi=-(x - 1) * (x - 2) * (x - 3),
                            description="free particle; admissible x <= 1 or 2 <= x <= 3")


def test_first_root_when_the_trial_step_crosses_three_times():
    sysm = _free_particle_cubic_wall()
    tr = _guarded(lambda: vcirun.simulate(sysm, "CVA", h=3.5, T=3.5, q0=np.array([0.0]), p0=np.array([1.0])))
    assert tr.status == "ok"
    assert tr.impacts[0] == pytest.approx(1.0, abs=1e-12)
    assert tr.q[-1, 0] == pytest.approx(1.0 - 2.5, abs=1e-12)   # reflected at x = 1


# --- initial state on the constraint surface -----------------------------------------------------

@pytest.mark.parametrize("method", ["CVA", "VCI"])
def test_start_on_surface_moving_away(method):
    tr = _sim(method, H, 10.0, -D, 0.8)
    assert tr.status == "ok"
    err, t_imp = _err(tr, -D, 0.8)
    assert len(tr.impacts) == len(t_imp) >= 1 and tr.impacts[0] > 1.0   # no spurious impact at t = 0
    assert err <= 1.0 * H**2


def test_cart_pendulum_start_on_floor_moving_up():
    """y = 0, theta = 0.3 with (ydot, thetadot) = (1, 0.5): lifts off (no impact at t = 0) and
    25 bounces in [0, 5], all matched; L2 observed 3.9e-6 (CVA), 6.7e-3 (VCI)."""
    s = resolve_system("cart_pendulum")
    q0, p0 = s.legendre(np.array([0.0, 0.3]), np.array([1.0, 0.5]), s.param_values(None))
    ref = vcirun.reference("cart_pendulum", T=5.0, q0=q0, p0=p0)
    assert ref.accuracy < 1e-8
    for method in ("CVA", "VCI"):
        tr = _guarded(lambda: vcirun.simulate("cart_pendulum", method, h=1e-2, T=5.0, q0=q0, p0=p0))
        assert tr.status == "ok"
        assert len(tr.impacts) == len(ref.impacts) and tr.impacts[0] > 0.1
        assert vcirun.l2_error(tr, ref) < 0.05


@pytest.mark.parametrize("method", ["CVA", "VCI"])
def test_start_on_surface_moving_into_it_reflects_immediately(method):
    tr = _sim(method, H, 10.0, -D, -0.8)
    assert tr.status == "ok"
    assert tr.impacts[0] == 0.0 and tr.impact_p_plus[0, 0] > 0
    assert _err(tr, -D, 0.8)[0] <= 1.0 * H**2   # the exact motion is the reflected one


@pytest.mark.parametrize("method", ["CVA", "VCI"])
def test_resting_contact_is_a_reported_failure(method):
    """On the wall at rest, pushed into it by the spring (wall on the spring's side): zero normal
    velocity, so no elastic reset exists (R^CVA's lam = 0). Without held contacts: a failure status
    at step 0 with time and state. With them (the default): held on the wall for good, exactly."""
    tr = _sim(method, H, 1.0, 0.5, 0.0, params=BOUNCE, resting_contact=False)
    assert tr.status in ("reset_failed", "accumulation")
    _assert_failure_record(tr, tr.status, 0)
    tr = _sim(method, H, 1.0, 0.5, 0.0, params=BOUNCE)
    assert tr.status == "ok" and tr.contact_active.all() and np.all(tr.q[:, 0] == 0.5) and np.all(tr.p == 0.0)


# --- failures come back as data ------------------------------------------------------------------

@pytest.mark.parametrize("method", ["CVA", "VCI"])
def test_newton_failure_at_step_0(method):
    tr = _sim(method, H, 1.0, 1.0, 0.0, max_iter=1)
    _assert_failure_record(tr, "newton_failed", 0)
    assert tr.message == "newton_failed in step 0 (t = 0) from q = [1.0], p = [0.0]"


def test_newton_failure_mid_run():
    """Cart-pendulum at h = 0.3 (far too large for |theta'| ~ 8 rad/s): SVC's Newton fails in a
    later step; the record keeps every grid state reached."""
    tr = _guarded(lambda: vcirun.simulate("cart_pendulum", "CVA", h=0.3, T=10.0, beta=5.2))
    assert tr.fail_step > 0
    _assert_failure_record(tr, "newton_failed", tr.fail_step)
    assert np.all(np.isfinite(tr.q)) and np.all(np.isfinite(tr.p))


def test_accumulation_cap_per_step():
    """max_impacts_step = 1 with 4 bounces in the first step: status accumulation at step 0."""
    tr = _sim("CVA", H, 1.0, A_B, 0.0, params=BOUNCE, max_impacts_step=1)
    _assert_failure_record(tr, "accumulation", 0)
