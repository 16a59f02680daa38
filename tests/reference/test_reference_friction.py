"""The exact reference with Coulomb friction (vcirun/reference_solution/coulomb.py and the event loop) against
the closed forms of vcirun/scenes/friction_oracles.py, over random parameters (hypothesis; derandomized
in the default suite, ten times as many fresh ones under -m slow):

  * the spinning ball (Capobianco et al. 2021, section 10.1): the mode at the impact, xdot+ and
    phidot+, the rolling start and velocity, both published spins and random ones, to 1e-12;
  * the block on an incline: the stop time and position, then stick or slide back, to 1e-12;
  * the Coulomb-damped oscillator: every turn (time, position) and the final rest, to 1e-12;
  * Housner's rocking block: impact times and angular velocities after each corner impact;
  * Painleve's rod: a sliding start with B <= 0 ends at once with the status "painleve" and a message
    naming the contact, the time and B (= the closed form's B); B > 0 runs on;
  * frictionless limits: mu = mu_s = 0 given as parameters is the frictionless reference;
  * the DOP853 path on the same closed forms (its rtol's accuracy).
A frictional impact needs the frictional impact law (vcirun/collision/friction_law.py, called through
vcirun/reference_solution/friction_law.py).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from vcirun.reference_solution.exact import solve_exact
from vcirun.scenes import friction as F
from vcirun.scenes import friction_oracles as fo

PKG = Path(__file__).resolve().parents[2] / "vcirun"
needs_law = pytest.mark.skipif(
    not ((PKG / "collision" / "friction_law.py").is_file() and (PKG / "reference" / "friction.py").is_file()),
    reason="the frictional impact law (collision/friction_law.py, reference/friction.py) is not installed")
TOL = 1e-12


def _settings(n, slow):
    return settings(max_examples=10 * n if slow else n, deadline=None, derandomize=not slow, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])


def _both(n, marks=(), **strategies):
    """The default-suite test of `check` over `strategies` and its slow twin (ten times the states)."""
    def deco(check):
        names = list(strategies)

        def make(slow):
            ns = {"check": check}
            exec(f"def run({', '.join(names)}):\n    check({', '.join(f'{a}={a}' for a in names)})\n", ns)
            run = ns["run"]   # (hypothesis wants named arguments)
            run.__name__ = run.__qualname__ = "test_" + check.__name__.strip("_") + ("_slow" if slow else "")
            out = _settings(n, slow)(given(**strategies)(run))
            for mk in marks:
                out = mk(out)
            return out
        return make(False), pytest.mark.slow(make(True))
    return deco


def _num(lo, hi):
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False, allow_subnormal=False)


def _ref(s, T, params=None, **kw):
    prm = s.param_values(params)
    q0, p0 = s.default_q0, s.default_p0
    return solve_exact(s, q0, p0, prm, T, **kw)


# --- the spinning ball ---------------------------------------------------------------------------------

def _ball_checks(ref, cf, R, m=1.0):
    I = 0.4 * m * R * R
    assert ref.status == "ok"
    assert len(ref.impacts) == 1 and abs(ref.impacts[0] - cf.t1) <= TOL * (1 + cf.t1)
    assert abs(ref.impact_impulse[0] - cf.P_n) <= TOL * (1 + cf.P_n)
    assert abs(ref.impact_tangential[0] - cf.P_t) <= TOL * (1 + abs(cf.P_n))
    p1 = ref.p(ref.impacts[0])
    assert abs(p1[0] / m - cf.xdot_plus) <= TOL * (1 + abs(cf.xdot_plus))
    assert abs(p1[2] / I - cf.phidot_plus) <= TOL * (1 + abs(cf.phidot_plus)) * 10
    # the modes: held from the impact on, sliding (with the sign of the slip) until it sticks
    first = ref.mode_intervals[0]
    assert first[2] == (0,) and abs(first[0] - cf.t1) <= TOL * (1 + cf.t1)
    if cf.sticks:
        assert first[3] == (0,) and not ref.transitions
    else:
        assert first[3] == ((1,) if cf.slip_plus > 0 else (-1,))
        assert len(ref.transitions) == 1 and ref.transitions[0][1:] == (0, 0)
        assert abs(ref.transitions[0][0] - cf.t_roll) <= TOL * (1 + cf.t_roll)
    for t in np.linspace(0.0, ref.T, 41):
        y, ex = ref.state(t), cf.state(t)
        qd = y[3:] / np.array([m, m, I])
        assert np.max(np.abs(y[:3] - ex[:3])) <= TOL * (1 + np.max(np.abs(ex[:3]))), t
        assert np.max(np.abs(qd - ex[3:])) <= 10 * TOL * (1 + np.max(np.abs(ex[3:]))), t


@needs_law
@pytest.mark.parametrize("w0", [10.0, 50.0])
def test_spinning_ball_published(w0):
    s = F.spinning_ball(w0)
    ref = _ref(s, 1.2)
    cf = fo.spinning_ball(w0)
    assert cf.sticks == (w0 == 10.0)
    _ball_checks(ref, cf, 0.1)
    assert ref.accuracy <= TOL
    assert abs(ref.state(1.2)[3] - (-2 / 7 * 0.1 * w0)) <= TOL    # rolls at -(2/7) R w0


@_both(12, marks=(needs_law,), w0=_num(-150, 150), mu=_num(0.05, 1.5), v0=_num(-2, 2), h=_num(0.2, 1.5), R=_num(0.05, 0.3))
def _spinning_ball_random(w0, mu, v0, h, R):
    cf = fo.spinning_ball(w0, mu=mu, v0=v0, h=h, R=R)
    s0 = v0 + R * w0
    assume(abs(abs(2 / 7 * s0) - mu * cf.vn) > 1e-6 * (1 + abs(s0)))   # (not on the cone's edge)
    assume(abs(cf.slip_plus) > 1e-6 or cf.sticks)
    s = F.spinning_ball(w0, mu=mu, v0=v0, h=h, R=R)
    ref = _ref(s, cf.t_roll + 0.3, check_accuracy=False)
    _ball_checks(ref, cf, R)


test_spinning_ball_random, test_spinning_ball_random_slow = _spinning_ball_random


# --- the incline -----------------------------------------------------------------------------------------

def _incline_checks(ref, cf, theta, T, modes=True):
    t_dir = np.array([math.cos(theta), math.sin(theta)])
    assert ref.status == "ok" and not len(ref.impacts)
    if modes and math.isfinite(cf.t_stop) and 0 < cf.t_stop <= T:   # (a stop past T is not in the run)
        assert len(ref.transitions) == 1
        t, i, mode = ref.transitions[0]
        assert abs(t - cf.t_stop) <= TOL * (1 + cf.t_stop)
        assert mode == (0 if cf.after_stop == "stick" else (1 if cf.pieces[-1][4] > 0 else -1))
    for t in np.linspace(0.0, T, 31):
        s = ref(t) @ t_dir
        ex = cf.state(t)[0]
        assert abs(s - ex) <= TOL * (1 + abs(ex)), (t, s, ex)
        assert abs(ref(t) @ np.array([-math.sin(theta), math.cos(theta)])) <= TOL   # on the slope


def test_incline_published():
    for theta, mu, mu_s, v0, after in ((0.3, 0.2, 0.4, 1.0, "stick"), (0.4, 0.3, 0.35, 2.0, "slide down")):
        s = F.incline(theta, mu=mu, mu_s=mu_s, v0=v0)
        ref = _ref(s, 1.0)
        cf = fo.incline(theta, mu=mu, mu_s=mu_s, v0=v0)
        assert cf.after_stop == after
        _incline_checks(ref, cf, theta, 1.0)
        assert ref.accuracy <= TOL


@_both(15, theta=_num(-1.2, 1.2), mu=_num(0.0, 1.5), dmu=_num(0.0, 0.5), v0=_num(-4, 4))
def _incline_random(theta, mu, dmu, v0):
    mu_s = mu + dmu
    assume(abs(abs(math.tan(theta)) - mu_s) > 1e-6 and abs(abs(math.tan(theta)) - mu) > 1e-6)
    assume(abs(v0) > 1e-3)
    cf = fo.incline(theta, mu=mu, mu_s=mu_s, v0=v0)
    T = min(cf.t_stop, 5.0) + 0.5 if math.isfinite(cf.t_stop) else 1.0
    s = F.incline(theta, mu=mu, mu_s=mu_s, v0=v0)
    _incline_checks(_ref(s, T, check_accuracy=False), cf, theta, T)


test_incline_random, test_incline_random_slow = _incline_random


def test_incline_held_at_a_static_margin_does_not_creep():
    # tan theta = mu_s / 1.05: held with 5 % margin for 10 s; still to the round-off of the held forces
    # (their balance leaves an acceleration of ~1e-16: 5e-15 m after 10 s; the target is 1e-14)
    mu_s = 0.4
    theta = math.atan(mu_s / 1.05)
    s = F.incline(theta, mu=0.3, mu_s=mu_s)
    ref = _ref(s, 10.0)
    assert ref.status == "ok" and not ref.transitions and ref.mode_intervals == [(0.0, 10.0, (0,), (0,))]
    assert float(np.max(np.abs(ref(np.linspace(0, 10, 101))))) <= 1e-14


def test_frictionless_parameters_are_the_frictionless_reference():
    s = F.incline(0.3, mu=0.2, mu_s=0.4, v0=1.0)
    ref = _ref(s, 1.0, params={"mu": 0.0, "mu_s": 0.0})
    assert not ref.transitions and not ref.mode_intervals
    cf = fo.incline(0.3, mu=0.0, v0=1.0)
    _incline_checks(ref, cf, 0.3, 1.0, modes=False)   # (no friction: its turn is no event)


# --- the Coulomb oscillator --------------------------------------------------------------------------------

def _oscillator_checks(ref, cf, T):
    assert ref.status == "ok"
    turns = [(t, x) for t, x in cf.turns if 0.0 < t <= T]
    assert len(ref.transitions) == len(turns)
    for (t, i, mode), (tc, xc) in zip(ref.transitions, turns):
        assert abs(t - tc) <= TOL * (1 + tc)
        assert abs(ref(t)[0] - xc) <= TOL * (1 + abs(xc))
    if turns and turns[-1][0] == cf.t_stop:
        assert ref.transitions[-1][2] == 0
        assert abs(ref(T)[0] - cf.x_stop) <= TOL * (1 + abs(cf.x_stop))


def test_coulomb_oscillator_published():
    s = F.coulomb_oscillator(1.0, m=1.0, k=10.0, mu=0.1)
    cf = fo.coulomb_oscillator(1.0, m=1.0, k=10.0, mu=0.1)
    ref = _ref(s, 6.0)
    assert len(cf.turns) == 5 and ref.accuracy <= 1e-12
    _oscillator_checks(ref, cf, 6.0)
    c = 0.1 * 9.81 / 10.0
    assert abs(ref(cf.turns[0][0])[0] - (-(1.0 - 2 * c))) <= TOL   # 2 mu m g / k lost per half period


@_both(12, x0=_num(-2, 2), v0=_num(-2, 2), k=_num(1, 20), mu=_num(0.05, 0.5), dmu=_num(0, 0.3))
def _coulomb_random(x0, v0, k, mu, dmu):
    mu_s = mu + dmu
    cf = fo.coulomb_oscillator(x0, v0, m=1.0, k=k, mu=mu, mu_s=mu_s)
    assume(len(cf.turns) <= 12)
    assume(all(abs(k * abs(x) - mu_s * 9.81) > 1e-6 for _, x in cf.turns) and abs(v0) > 1e-3)
    T = cf.t_stop + 0.5
    s = F.coulomb_oscillator(x0, v0=v0, m=1.0, k=k, mu=mu, mu_s=mu_s)
    _oscillator_checks(_ref(s, T, check_accuracy=False), cf, T)


test_coulomb_random, test_coulomb_random_slow = _coulomb_random


# --- Housner's rocking block -----------------------------------------------------------------------------

def _housner_checks(ref, cf, a, b, m=1.0):
    I = m * (a * a + b * b) / 12
    assert ref.status == "ok"
    k = len(cf.impact_times)
    assert list(ref.impact_contact[:k]) == [1 if j % 2 == 0 else 0 for j in range(k)]
    for j in range(k):
        t = ref.impacts[j]
        assert abs(t - cf.impact_times[j]) <= TOL * (1 + t)
        assert abs(abs(ref.p(t)[2]) / I - cf.omega_plus[j]) <= 10 * TOL * (1 + cf.omega_plus[j])
    # rocking without sliding: the pivot sticks throughout, one corner held at a time
    assert all(iv[3] == (0,) and len(iv[2]) == 1 for iv in ref.mode_intervals)


@needs_law
def test_housner_published():
    s = F.rocking_block_friction(0.1, mu=0.8)
    cf = fo.housner_rocking(0.1, a=1.0, b=0.4, impacts=3)
    ref = _ref(s, cf.impact_times[-1] + 0.05)
    _housner_checks(ref, cf, 1.0, 0.4)
    assert abs(abs(ref.p(ref.impacts[0])[2] / ref.p(ref.impacts[0] - 1e-12)[2]) - fo.housner_ratio(1.0, 0.4)) <= 1e-9


@_both(6, marks=(needs_law,), a=_num(0.5, 2.0), ratio=_num(0.1, 0.6), frac=_num(0.2, 0.8))
def _housner_random(a, ratio, frac):
    b = ratio * a
    al = math.atan(b / a)
    theta0 = frac * al
    cf = fo.housner_rocking(theta0, a=a, b=b, impacts=2)
    s = F.rocking_block_friction(theta0, a=a, b=b, mu=2.0)
    _housner_checks(_ref(s, cf.impact_times[-1] + 0.01, check_accuracy=False), cf, a, b)


test_housner_random, test_housner_random_slow = _housner_random


# --- Painleve's rod -----------------------------------------------------------------------------------------

def test_painleve_start_ends_with_the_status():
    s = F.painleve_rod(0.9, xdot0=-1.0, mu=1.5)
    ref = _ref(s, 1.0)
    B = float(fo.painleve_B(0.9, 1.5, -1))
    assert B < 0
    assert ref.status == "painleve" and ref.T == 0.0
    assert "contact end" in ref.message and "t=0" in ref.message and f"B = {B:.6g}" in ref.message


@_both(15, theta=_num(0.05, 1.5), mu=_num(0.0, 3.0), xd=_num(-4, 4))
def _painleve_random(theta, mu, xd):
    assume(abs(xd) > 1e-3)
    s_dir = 1 if xd > 0 else -1
    B = float(fo.painleve_B(theta, mu, s_dir))
    assume(abs(B) > 1e-6)
    ref = _ref(F.painleve_rod(theta, xdot0=xd, mu=mu), 0.05, check_accuracy=False)
    if B < 0:
        assert ref.status == "painleve" and ref.T == 0.0 and f"B = {B:.6g}" in ref.message
    else:
        assert ref.status == "ok" and ref.T == 0.05
        if mu > 0.0:
            assert ref.mode_intervals[0][:4] == (0.0, ref.mode_intervals[0][1], (0,), (s_dir,))
        else:   # no friction at these parameters: the frictionless reference, which has no modes
            assert ref.mode_intervals == []


test_painleve_random, test_painleve_random_slow = _painleve_random


# --- the DOP853 path -------------------------------------------------------------------------------------

def test_dop853_path_on_the_closed_forms():
    s = F.coulomb_oscillator(1.0, m=1.0, k=10.0, mu=0.1)
    cf = fo.coulomb_oscillator(1.0, m=1.0, k=10.0, mu=0.1)
    ref = solve_exact(s, s.default_q0, s.default_p0, s.param_values(), 6.0, path="dop853", check_accuracy=False)
    assert ref.kind == "dop853" and len(ref.transitions) == len(cf.turns)
    for (t, _, _), (tc, xc) in zip(ref.transitions, cf.turns):
        assert abs(t - tc) <= 1e-10 and abs(ref(t)[0] - xc) <= 1e-10
    s = F.incline(0.4, mu=0.3, mu_s=0.35, v0=2.0)
    cf = fo.incline(0.4, mu=0.3, mu_s=0.35, v0=2.0)
    ref = solve_exact(s, s.default_q0, s.default_p0, s.param_values(), 1.0, path="dop853", check_accuracy=False)
    assert [m for _, _, m in ref.transitions] == [-1] and abs(ref.transitions[0][0] - cf.t_stop) <= 1e-10
    t_dir = np.array([math.cos(0.4), math.sin(0.4)])
    assert abs(ref(1.0) @ t_dir - cf.state(1.0)[0]) <= 1e-10
    # stick, then slip at the static cone with mu_s = mu (a slip that starts with zero acceleration)
    s = F.pushed_block(c=2.0, mu=0.3, mu_s=0.3)
    cf = fo.pushed_block(c=2.0, mu=0.3, mu_s=0.3)
    ref = solve_exact(s, s.default_q0, s.default_p0, s.param_values(), cf.t_slip + 1.0, path="dop853",
                      check_accuracy=False)
    assert [m for _, _, m in ref.transitions] == [1] and abs(ref.transitions[0][0] - cf.t_slip) <= 1e-10
    assert abs(ref(cf.t_slip + 1.0)[0] - cf.state(cf.t_slip + 1.0)[0]) <= 1e-10


# --- the pushed block: stick, then slip where the tangential force reaches the static cone -------------------

def _pushed_checks(ref, cf, T):
    assert ref.status == "ok"
    assert len(ref.transitions) == 1 and ref.transitions[0][1:] == (0, 1)
    assert abs(ref.transitions[0][0] - cf.t_slip) <= TOL * (1 + cf.t_slip)
    m = cf.params["m"]
    for t in np.linspace(0.0, T, 41):
        x, v = cf.state(t)
        y = ref.state(t)
        assert abs(y[0] - x) <= TOL * (1 + abs(x)) and abs(y[2] / m - v) <= TOL * (1 + abs(v)), t


def test_pushed_block_published():
    s = F.pushed_block(c=2.0, mu=0.3, mu_s=0.5)
    cf = fo.pushed_block(c=2.0, mu=0.3, mu_s=0.5)
    ref = _ref(s, cf.t_slip + 1.0)
    _pushed_checks(ref, cf, cf.t_slip + 1.0)
    assert ref.accuracy <= TOL


@_both(10, c=_num(0.5, 10), mu=_num(0.0, 1.0), dmu=_num(0.0, 0.5), m=_num(0.2, 5))
def _pushed_random(c, mu, dmu, m):
    cf = fo.pushed_block(c=c, mu=mu, mu_s=mu + dmu, m=m)
    assume(cf.t_slip < 20 and mu + dmu > 1e-3)   # (mu = mu_s = 0: frictionless, no transition)
    s = F.pushed_block(c=c, mu=mu, mu_s=mu + dmu, m=m)
    _pushed_checks(_ref(s, cf.t_slip + 0.5, check_accuracy=False), cf, cf.t_slip + 0.5)


test_pushed_random, test_pushed_random_slow = _pushed_random


# --- a chain of links with friction at its ends -------------------------------------------------------------

@needs_law
@pytest.mark.slow
def test_link_chain_with_friction_comes_to_rest_without_gaining_energy():
    """Three links dropped in a zigzag (DOP853: M is 5x5 and depends on q): every frictional impact loses
    kinetic energy, the chain ends flat on its four ends, sticking (their slip rows depend on each
    other: one kept, the tangential force shared), at rest -- where the frictionless floor lets it
    skate on."""
    s = F.link_chain_friction(3)
    ref = _ref(s, 0.7, check_accuracy=False)
    assert ref.status == "ok" and ref.kind == "dop853" and len(ref.impacts) > 10
    from vcirun.codegen.build import load_module
    from vcirun.codegen.kernel_set import SYSTEM_KERNELS

    mod, prm = load_module(s, SYSTEM_KERNELS), s.param_values()
    n = s.n
    for t in sorted(set(ref.impacts)):
        before, after = ref.state(t - 1e-13 * max(1.0, t)), ref.state(t)
        Mq = np.empty((n, n))
        mod.sys_M(np.ascontiguousarray(after[:n]), prm, Mq)
        T_b = 0.5 * before[n:] @ np.linalg.solve(Mq, before[n:])
        T_a = 0.5 * after[n:] @ np.linalg.solve(Mq, after[n:])
        assert T_a <= T_b * (1 + 1e-9) + 1e-14, (t, T_b, T_a)
    last = ref.mode_intervals[-1]
    assert last[1] == 0.7 and last[2] == (0, 1, 2, 3) and last[3] == (0, 0, 0, 0)
    assert float(np.max(np.abs(ref.p(0.7)))) <= 1e-12
    assert float(np.max(np.abs(s.phi_values(ref(0.7))))) <= 1e-12


# --- the compass gait with a frictional stance foot ---------------------------------------------------------

def _pinned_gait():
    import vcirun
    from vcirun.scenes.registry import scene_data
    from vcirun.scenes.walkers import compass_gait_M

    D = scene_data("compass_gait")
    pin = vcirun.reference("compass_gait", T=1.0)
    return D, pin, pin.impacts[0], (lambda q, p: np.linalg.solve(np.array(compass_gait_M(q, D.params)), p))


def _stance_forces(s, ref, tt):
    from vcirun.codegen.build import load_module
    from vcirun.codegen.kernel_set import SYSTEM_KERNELS
    from vcirun.reference_solution import held as rh

    mod, prm, n = load_module(s, SYSTEM_KERNELS), s.param_values(), s.n
    out = []
    for t in tt:
        y = ref.state(t)
        f = rh._Geometry(mod, t, y[:n], y[n:], prm).forces((0,), (0,))
        out.append((f.lam_n[0], f.lam_t[0]))
    return np.array(out)


@pytest.mark.slow
def test_compass_gait_stance_foot_sticks_along_the_gait():
    """The built-in gait's stance phase (from heel strike to heel strike), with the stance foot a
    frictional contact of a floating base: (1) where it sticks it is the pinned gait (q to 1e-10, on
    DOP853: M is 4x4); (2) its held forces are the ground reaction sum_i m_i (a_i - g) of the pinned
    motion (accelerations by central differences of the pinned reference's velocities); (3) the stick
    test along the gait needs mu_s >= max |lam_t| / lam_n (0.274 at heel strike): with mu_s 1 % above
    the foot sticks all stride long, 1 % below it slides from the start; (4) the heel strike's impulse
    ratio |P_t| / P_n (Goswami's reset: angular momentum about the new foot and the old leg's about
    the hip kept, checked here with the same kinematics) is below it."""
    D, pin, ths, qdot = _pinned_gait()
    gam = D.params["gamma"]
    q0, p0 = pin.state(0.0)[:2], pin.state(0.0)[2:]
    v0 = qdot(q0, p0)
    s = F.compass_gait_stance(*q0, *v0, mu=1.0)
    ref = _ref(s, ths, check_accuracy=False)
    assert ref.status == "ok" and ref.mode_intervals == [(0.0, ths, (0,), (0,))]
    tt = np.linspace(0.0, ths, 201)
    before = tt[:-1]   # (the pinned reference is right-continuous: at ths it holds the relabelled legs)
    assert float(np.max(np.abs(ref(before)[:, 2:] - gam - pin(before)))) <= 1e-10
    assert float(np.max(np.abs(ref(tt)[:, :2]))) <= 1e-10                      # the foot stays put
    lam = _stance_forces(s, ref, tt)
    # Newton: the ground reaction of the pinned motion, masses m (stance, at a), mH (hip), m (swing, b below)
    m, mH, a, b, g = (D.params[k] for k in ("m", "mH", "a", "b", "g"))
    l = a + b

    def masses(q):
        ps, pn = q[0] + gam, q[1] + gam
        leg, hip = np.array([-math.sin(ps), math.cos(ps)]), l * np.array([-math.sin(ps), math.cos(ps)])
        return [(m, a * leg), (mH, hip), (m, hip + b * np.array([math.sin(pn), -math.cos(pn)]))]

    n_dir, t_dir = np.array([-math.sin(gam), math.cos(gam)]), np.array([math.cos(gam), math.sin(gam)])
    dt = 1e-4
    for k in range(5, 196, 19):
        t = tt[k]
        pos = [masses(pin(t + j * dt)) for j in (-1, 0, 1)]
        R = sum(mi * ((pos[2][i][1] - 2 * pos[1][i][1] + pos[0][i][1]) / dt ** 2 - np.array([0.0, -g]))
                for i, (mi, _) in enumerate(pos[1]))
        assert abs(R @ n_dir - lam[k, 0]) <= 1e-5 * lam[k, 0] and abs(R @ t_dir - lam[k, 1]) <= 1e-5 * lam[k, 0]
    need = float(np.max(np.abs(lam[:, 1]) / lam[:, 0]))
    assert np.all(lam[:, 0] > 0) and 0.2 < need < 0.3
    sticks = _ref(F.compass_gait_stance(*q0, *v0, mu=0.9 * need, mu_s=1.01 * need), ths, check_accuracy=False)
    assert sticks.status == "ok" and not sticks.transitions and sticks.mode_intervals[0][3] == (0,)
    slides = _ref(F.compass_gait_stance(*q0, *v0, mu=0.9 * need, mu_s=0.99 * need), 0.05, check_accuracy=False)
    assert slides.mode_intervals[0][3] in ((1,), (-1,))
    # the heel strike: Goswami's reset keeps the angular momenta; the impulse it takes at the new foot
    ym, yp = pin.state(ths - 1e-13), pin.state(ths)
    qm, qdm, qdp = ym[:2], qdot(ym[:2], ym[2:]), qdot(yp[:2], yp[2:])
    Pn, Pt = fo.compass_gait_heel_impulse(qm, qdm, qdp, **D.params)
    assert Pn > 0 and abs(Pt) / Pn < need
    ps, pn = qm[0] + gam, qm[1] + gam
    foot_new = l * np.array([-math.sin(ps), math.cos(ps)]) + l * np.array([math.sin(pn), -math.cos(pn)])
    hip = l * np.array([-math.sin(ps), math.cos(ps)])

    def momenta(qd_s, qd_n, before):
        # (angular momentum about the new foot, the old stance leg's about the hip), by the same kinematics
        # as fo.compass_gait_heel_impulse: before, the old foot is the pivot; after, the new one
        if before:
            vh = l * qd_s * np.array([-math.cos(ps), -math.sin(ps)])
            pts = [(m, a / l * hip, a * qd_s * np.array([-math.cos(ps), -math.sin(ps)])), (mH, hip, vh),
                   (m, hip + b * np.array([math.sin(pn), -math.cos(pn)]), vh + b * qd_n * np.array([math.cos(pn), math.sin(pn)]))]
            old_leg = pts[0]
        else:
            vh = l * qd_s * np.array([-math.cos(pn), -math.sin(pn)])
            pts = [(m, foot_new + a / l * (hip - foot_new), a * qd_s * np.array([-math.cos(pn), -math.sin(pn)])),
                   (mH, hip, vh),
                   (m, hip + b * np.array([math.sin(ps), -math.cos(ps)]), vh + b * qd_n * np.array([math.cos(ps), math.sin(ps)]))]
            old_leg = pts[2]

        def L(mi, r, v, o):
            d = r - o
            return mi * (d[0] * v[1] - d[1] * v[0])
        return sum(L(*p_, foot_new) for p_ in pts), L(*old_leg, hip)

    Hm, hm = momenta(*qdm, True)
    Hp, hp = momenta(*qdp, False)
    assert abs(Hp - Hm) <= 1e-9 * abs(Hm) and abs(hp - hm) <= 1e-9 * max(abs(hm), 1.0)
