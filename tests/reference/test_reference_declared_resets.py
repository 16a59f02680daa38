"""The exact reference through declared resets (vcirun.reference_solution.resets, vcirun.reference_solution.stride).

Measured (Taylor path; `vcirun.periodic_orbit("compass_gait", "reference", guess=..., fd_step=5e-5)`):
compass gait at 3 degrees, fixed point q = (-0.27102868, 0.27102868), p = (16.9430407, -1.86775612),
stride period 0.7343463911587195 s, multipliers -0.199726127 +- 0.54447606 i, 0.131572624 (and
~1e-11: the section). The multipliers' finite-difference error: 4e-11 (fd_step 1e-4, 2.5e-5, 1e-5
against 5e-5, periodic_orbit's default on the exact map), 1.5e-7 at fd_step 1e-3 (delta = 1e-3 |p| = 0.017 on p).
CVA4 against it (both at fd_step 1e-3), h = 0.01, 0.005, 0.0025, 0.00125: fixed point 3.8e-8, 2.4e-9,
1.5e-10, 9.6e-12; period 4.8e-9, 3.0e-10, 1.9e-11, 1.2e-12; multipliers 3.5e-8, 2.4e-9, 1.1e-10,
1.2e-11 (order 4). Period doubling (the real multiplier at -1, by the secant in gamma), the exact map:
gamma = 4.3908982497 degrees; CVA4 at h = 0.02, 0.01, 0.005, 0.0025: 1.67e-6, 1.39e-7, 6.8e-9,
7.2e-10 degrees from it (at fd_step 1e-3 CVA4's converge to 1.9e-7 degrees off). The DOP853 path (rtol 1e-13) agrees with the Taylor path to 1e-11 (fixed point,
period, multipliers)."""
from __future__ import annotations

import math

import numpy as np
import pytest
import sympy as sp

import vcirun
from vcirun.experiments.periodic import periodic_orbit
from vcirun.mechanics.system import Constraint, MechanicalSystem
from vcirun.reference_solution.exact import solve_exact
from vcirun.reference_solution.resets import declared_resets
from vcirun.reference_solution.stride import ReferenceReturnMap
from vcirun.run.resolve import resolve_system
from vcirun.scenes.oracles import rimless_wheel_fixed_point, rimless_wheel_stride

FD_STEP = 5e-5


def _stride_time(omega, *, alpha, gamma, g, l):
    """The closed-form time from theta = -alpha at rate omega to theta = alpha (energy quadrature)."""
    from scipy.integrate import quad

    rate = lambda th: math.sqrt(omega**2 + 2 * g / l * (math.cos(gamma - alpha) - math.cos(th + gamma)))
    return quad(lambda th: 1.0 / rate(th), -alpha, alpha, epsabs=1e-14, epsrel=1e-13, limit=200)[0]


def test_rimless_wheel_stride_equals_the_closed_form_at_random_speeds_and_slopes():
    """Seeded sample of (omega, gamma, alpha, l): the reference's speed after the impact and its stride
    time equal the closed form to 1e-10 (measured: <= 4.4e-16 and 1.7e-16)."""
    rng = np.random.default_rng(32)
    for _ in range(6):
        prm = {"alpha": float(rng.uniform(0.2, 0.5)), "gamma": float(rng.uniform(0.02, 0.15)),
               "l": float(rng.uniform(0.5, 1.5)), "g": 9.81}
        # above the speed that just carries the wheel over the vertical
        omega = math.sqrt(2 * prm["g"] / prm["l"] * (1 - math.cos(prm["gamma"] - prm["alpha"]))) + rng.uniform(0.3, 1.5)
        ml2 = prm["l"] ** 2   # m = 1
        P = ReferenceReturnMap("rimless_wheel", params=prm)
        assert P.kind == "taylor"
        x, t = P(np.array([-prm["alpha"], ml2 * omega]))
        assert abs(x[0] + prm["alpha"]) < 1e-14
        assert abs(x[1] / ml2 - rimless_wheel_stride(omega, **prm)) < 1e-10
        assert abs(t - _stride_time(omega, **prm)) < 1e-10


def test_rimless_wheel_reference_fixed_point_and_multiplier():
    """periodic_orbit on the exact map: the closed-form gait's speed, multiplier c^2 and stride time."""
    prm = {"alpha": math.pi / 8, "gamma": 0.1, "g": 9.81, "l": 1.0}
    gait = rimless_wheel_fixed_point(**prm)
    o = periodic_orbit("rimless_wheel", "reference", guess=([-prm["alpha"]], [1.0]), fd_step=FD_STEP)
    assert abs(o.fixed_point[1][0] - gait.omega) < 1e-10
    assert abs(o.period - gait.period) < 1e-10
    assert abs(o.eigenvalues[0] - gait.eigenvalue) < 1e-9
    assert math.isnan(o.h) and o.method == "reference"


def test_compass_gait_mid_stride_crossing_is_no_event():
    """Over two strides only the heel strikes are impacts (Taylor and DOP853 alike), although the
    swing foot's height (the unguarded surface) is below the slope at mid-stride, where theta_s < 0."""
    s = resolve_system("compass_gait")
    crossed = False
    for path in ("taylor", "dop853"):
        ref = solve_exact(s, s.default_q0, s.default_p0, s.param_values(), 1.6, path=path)
        assert ref.kind == path
        assert len(ref.impacts) == 2 and np.all(np.diff(ref.impacts) > 0.7)
        tt = np.linspace(0.01, ref.impacts[0] - 0.01, 400)
        q = ref(tt)
        height = np.cos(q[:, 0]) - np.cos(q[:, 1])
        crossed = crossed or bool(np.any((height < 0) & (q[:, 0] < 0)))
        # after each heel strike the legs have exchanged: q+ = (q-_ns, q-_s)
        for ti in ref.impacts:
            qm, qp = ref(ti - 1e-9), ref(ti)
            assert np.max(np.abs(qp - qm[::-1])) < 1e-7
    assert crossed


def test_compass_gait_reference_dop853_agrees_with_taylor():
    s = resolve_system("compass_gait")
    x = np.concatenate([s.default_q0, s.default_p0])
    a, ta = ReferenceReturnMap("compass_gait", path="taylor")(x)
    b, tb = ReferenceReturnMap("compass_gait", path="dop853")(x)
    assert np.max(np.abs(a - b)) < 1e-10 and abs(ta - tb) < 1e-10


@pytest.fixture(scope="module")
def exact_gait():
    s = resolve_system("compass_gait")
    return periodic_orbit("compass_gait", "reference", guess=(s.default_q0, s.default_p0), fd_step=FD_STEP)


def test_compass_gait_reference_gait(exact_gait):
    """The exact gait (module docstring): Goswami et al.'s, the multipliers' FD error below 1e-9."""
    o = exact_gait
    np.testing.assert_allclose(o.fixed_point[0], [-0.27102868, 0.27102868], atol=1e-8)
    assert abs(o.period - 0.73434639116) < 1e-10
    np.testing.assert_allclose(o.eigenvalues[:3], [-0.199726127 + 0.54447606j, -0.199726127 - 0.54447606j,
                                                   0.131572624], atol=1e-8)
    assert abs(o.eigenvalues[3]) < 1e-9
    s = resolve_system("compass_gait")
    o2 = periodic_orbit("compass_gait", "reference", guess=(s.default_q0, s.default_p0), fd_step=2 * FD_STEP)
    assert np.max(np.abs(o2.eigenvalues[:3] - o.eigenvalues[:3])) < 1e-9


def test_compass_gait_cva4_converges_to_the_reference_gait(exact_gait):
    """CVA4's fixed point, period and multipliers converge at order 4 to the reference's and agree to
    1e-9 at h = 0.00125 (module docstring: 9.6e-12, 1.2e-12, 1.2e-11; multipliers at the same fd_step
    1e-3 on both maps, whose FD error of 1.5e-7 is then common to both)."""
    s = resolve_system("compass_gait")
    guess = np.concatenate(exact_gait.fixed_point)
    ref = periodic_orbit("compass_gait", "reference", guess=guess, fd_step=1e-3)
    xr = np.concatenate(ref.fixed_point)
    errs = []
    for h in (0.005, 0.0025, 0.00125):
        o = periodic_orbit("compass_gait", "CVA4", h=h, guess=guess, fd_step=1e-3)
        errs.append((np.max(np.abs(np.concatenate(o.fixed_point) - xr)), abs(o.period - ref.period),
                     np.max(np.abs(o.eigenvalues[:3] - ref.eigenvalues[:3]))))
    errs = np.array(errs)
    orders = np.log2(errs[:-1] / errs[1:])
    assert np.all(orders[:, :2] > 3.7), orders
    assert np.all(errs[-1] < 1e-9), errs[-1]
    assert np.max(np.abs(np.concatenate(ref.fixed_point) - np.concatenate(exact_gait.fixed_point))) < 1e-12
    assert s.n == 2


def _real_multiplier(system, method, gamma, guess, h=None):
    """The real multiplier nearest -1 of the gait at slope gamma, and its fixed point."""
    o = periodic_orbit(system, method, h=h, guess=guess, params={"gamma": gamma}, fd_step=FD_STEP)
    ev = np.asarray(o.eigenvalues)
    return ev[np.abs(ev.imag) < 1e-9].real.min(), o.fixed_point


def _doubling(method, h=None, guess=None):
    """gamma where the compass gait's real multiplier crosses -1 (secant from 4.385, 4.395 degrees)."""
    g0, g1 = np.deg2rad(4.385), np.deg2rad(4.395)
    l0, x = _real_multiplier("compass_gait", method, g0, guess, h)
    l1, x = _real_multiplier("compass_gait", method, g1, x, h)
    for _ in range(8):
        g2 = g1 - (l1 + 1.0) * (g1 - g0) / (l1 - l0)
        l2, x = _real_multiplier("compass_gait", method, g2, x, h)
        g0, l0, g1, l1 = g1, l1, g2, l2
        if abs(l2 + 1.0) < 1e-10:
            break
    return g1


@pytest.mark.slow
def test_period_doubling_of_cva4_converges_to_the_exact_one(exact_gait):
    """The slope of the compass gait's period doubling on the exact map (module docstring:
    4.3908982497 degrees), and CVA4's at h = 0.01, 0.005, 0.0025 converging to it (at
    fd_step 5e-5 on both maps; 1.39e-7, 6.8e-9, 7.2e-10 degrees measured)."""
    guess = exact_gait.fixed_point
    ref = np.rad2deg(_doubling("reference", guess=guess))
    assert abs(ref - 4.3908982497) < 1e-8
    errs = [abs(np.rad2deg(_doubling("CVA4", h=h, guess=guess)) - ref) for h in (0.01, 0.005, 0.0025)]
    assert errs[0] < 5e-7 and errs[-1] < 5e-9, errs
    assert errs[0] / errs[-1] > 40, errs   # ~ order 4 over two halvings (3.2 .. 4.4 per halving)


def test_map_into_the_constraint_is_a_clear_error():
    """A state whose image under the map lies inside the constraint (the wheel past 3 alpha) is refused,
    naming the constraint."""
    s = resolve_system("rimless_wheel")
    from vcirun.codegen.build import load_module
    from vcirun.codegen.kernel_set import SYSTEM_KERNELS

    mod = load_module(s, SYSTEM_KERNELS)
    R = declared_resets(s, mod, s.param_values())
    a = float(s.params["alpha"])
    with pytest.raises(RuntimeError, match="inside constraint spoke"):
        R.apply(0.0, np.array([4 * a, 1.0]), np.zeros(1), 0.0, 0)


def _guard_inside():
    x = sp.Symbol("x")
    c = Constraint("wall", sp.Rational(1, 4) - x, when=x - sp.Rational(1, 2))
    return MechanicalSystem(name="guard_inside_r32", q=[x], params={}, M=sp.Matrix([[1]]), V=sp.Integer(0),
                            constraints=[c], default_q0=np.array([0.0]), default_p0=np.array([1.0]))


@pytest.mark.parametrize("path", ["taylor", "dop853"])
def test_guard_arming_inside_the_constraint_is_a_clear_error(path):
    s = _guard_inside()
    with pytest.raises(RuntimeError, match="guard of constraint wall .* arms at t=0.5"):
        solve_exact(s, np.array([0.0]), np.array([1.0]), s.param_values(), 3.0, path=path)


def test_reference_api_on_the_compass_gait_applies_the_map():
    """vcirun.reference: the impulse recorded for a map without an impact law is 0, H jumps at the
    heel strike (the map removes energy) and the accuracy check is at round-off."""
    ref = vcirun.reference("compass_gait", T=1.0)
    assert len(ref.impacts) == 1 and ref.impact_impulse[0] == 0.0
    assert ref.accuracy < 1e-12
