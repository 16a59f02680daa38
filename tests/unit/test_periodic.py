"""vcirun.periodic_orbit on the rimless wheel against its closed-form stride map
(vcirun.scenes.oracles.rimless_wheel_fixed_point): the fixed-point speed and the multiplier to 1e-10
with CVA4 at a fine step, and each method's error converging at its order."""
from __future__ import annotations

import numpy as np
import pytest

from vcirun.experiments.periodic import periodic_orbit
from vcirun.scenes.registry import scene_data
from vcirun.scenes.oracles import rimless_wheel_fixed_point

PRM = scene_data("rimless_wheel").params
GAIT = rimless_wheel_fixed_point(**PRM)
ML2 = PRM["m"] * PRM["l"] ** 2


def _errors(method, h):
    orb = periodic_orbit("rimless_wheel", method, h=h, guess=([-PRM["alpha"]], [1.1 * ML2 * GAIT.omega]))
    (q, p), lam = orb.fixed_point, orb.eigenvalues
    assert q[0] == pytest.approx(-PRM["alpha"], abs=1e-13)          # on the section
    assert abs(lam[1]) < 1e-6                                        # the section's trivial multiplier
    return abs(p[0] / ML2 - GAIT.omega), abs(lam[0].real - GAIT.eigenvalue), abs(orb.period - GAIT.period)


def test_rimless_wheel_fixed_point_to_1e10():
    e_w, e_lam, e_T = _errors("CVA4", 2e-3)
    print(f"CVA4 h=2e-3: |omega - omega*| = {e_w:.2e}, |lambda - cos^2(2 alpha)| = {e_lam:.2e}, |T - T*| = {e_T:.2e}")
    assert e_w <= 1e-10 and e_lam <= 1e-10 and e_T <= 1e-10


@pytest.mark.parametrize("method, order, hs", [("CVA", 2, (0.04, 0.02, 0.01)), ("CVA4", 4, (0.04, 0.02, 0.01)),
                                               ("MCVAA", 2, (0.02, 0.01, 0.005)), ("MCVAC", 2, (0.02, 0.01, 0.005))])
def test_rimless_wheel_converges_at_the_method_order(method, order, hs):
    errs = np.array([_errors(method, h) for h in hs])
    rates = np.log2(errs[:-1] / errs[1:])
    print(method, "errors (omega, lambda, T):", errs.tolist(), "rates:", rates.tolist())
    # speed and period at the method's order; the multiplier's error is not monotone in h (the
    # derivative of the discrete map changes where the impact crosses a grid point): it decreases
    # at least at half the order (CVA, CVA4, MCVAA: at the order or faster; MCVAC: ~1.6)
    assert np.all(rates[:, [0, 2]] > order - 0.4), (method, rates)
    assert np.all(rates[:, 1] > order / 2), (method, rates)


def test_vci_stride_map_jumps_where_the_impact_crosses_a_grid_point():
    """R^VCI's energy target is the discrete energy of the partial step that reached the impact: a
    full step's -D3 Ld just before the impact crosses a grid point, H (a step of length 0) just after,
    an O(h^2) difference. The VCI stride map therefore jumps by O(h^2) where the impact time crosses a
    grid point (finite differences across it are meaningless: periodic_orbit does not converge for
    VCI). Measured on the wheel: the jump found by bisection on the start angle, at h and h/2."""
    from vcirun.experiments.periodic import ReturnMap

    jumps = []
    for h in (0.02, 0.01):
        P = ReturnMap("rimless_wheel", "VCI", h=h)
        x = np.array([-PRM["alpha"], ML2 * GAIT.omega])
        t0 = P(x)[1]
        k = np.ceil(t0 / h)                       # the grid point the impact approaches as q0 grows
        lo, hi = 0.0, 0.05
        assert P(x + [hi, 0])[1] < (k - 1) * h + 1e-12 or P(x + [hi, 0])[1] < k * h
        for _ in range(50):                        # q0 shift where the impact time crosses k h ... (k-1) h
            mid = 0.5 * (lo + hi)
            if P(x + [mid, 0])[1] > (k - 1) * h:
                lo = mid
            else:
                hi = mid
        jumps.append(abs(P(x + [hi, 0])[0][1] - P(x + [lo, 0])[0][1]))
    print("VCI stride-map jumps at h = 0.02, 0.01:", jumps)
    assert jumps[0] > 1e-4 and 2.5 < jumps[0] / jumps[1] < 6.0     # O(h^2)


def test_vci_gait_by_iteration_converges_at_order_two_in_its_envelope():
    """VCI's stride map jumps by O(h^2) (the test above), so Newton's fixed point need not exist; the
    gait as simulated (solver "iterate": x <- P(x) until it stops moving, or settles on a cycle across
    a jump) is within 11 h^2 and 14 h^2 of the closed form's speed and period at every h (the constant
    depends on where the impact falls between grid points: 0.44-10.8 for the speed over 21 steps
    h = 0.02 .. 6.25e-4, docs/walkers.md). Its multiplier with jacobian="fd" is the derivative of the
    smooth piece of the map it settles on, which carries the O(h^2) energy target's O(h) slope in the
    impact phase: it converges at order 1 only."""
    ev_err = {}
    for h in (0.02, 0.01, 0.005, 0.0025):
        orb = periodic_orbit("rimless_wheel", "VCI", h=h, guess=([-PRM["alpha"]], [1.1 * ML2 * GAIT.omega]),
                             solver="iterate", jacobian="fd")
        w = orb.fixed_point[1][0] / ML2
        assert abs(w - GAIT.omega) / GAIT.omega <= 11 * h ** 2
        assert abs(orb.period - GAIT.period) <= 14 * h ** 2
        assert orb.stable and orb.residual <= 2e-3
        ev_err[h] = abs(orb.eigenvalues[0] - GAIT.eigenvalue)
    assert ev_err[0.0025] < 0.5 * ev_err[0.01] and ev_err[0.0025] < 0.05


def test_iterate_solver_agrees_with_newton_on_a_smooth_map():
    """CVA's stride map is smooth: the simulated gait is Newton's fixed point, with its multipliers."""
    g = ([-PRM["alpha"]], [1.1 * ML2 * GAIT.omega])
    a = periodic_orbit("rimless_wheel", "CVA", h=0.01, guess=g)
    b = periodic_orbit("rimless_wheel", "CVA", h=0.01, guess=g, solver="iterate", jacobian="fd")
    np.testing.assert_allclose(b.fixed_point[1], a.fixed_point[1], rtol=1e-10)
    assert abs(b.period - a.period) < 1e-10 and abs(b.eigenvalues[0] - a.eigenvalues[0]) < 1e-6
    with pytest.raises(ValueError, match="solver"):
        periodic_orbit("rimless_wheel", "CVA", h=0.01, guess=g, solver="bisect")


def test_iterate_solver_decides_stability_across_a_jump():
    """At h = 0.02 * 2^(-14/4) = 1.77e-3 VCI's wheel gait settles 1.2e-4 h before a grid point, so the
    central finite-difference stencil (fd_step 1e-6) crosses the map's jump there: its multiplier is
    -16, and solver "iterate" used to refuse the gait. Its default Jacobian is now the envelope's
    (multiplier -0.72 h^2 from the closed form), and jacobian="fd" keeps its stencil on the gait's
    smooth piece (one-sided there)."""
    g = ([-PRM["alpha"]], [1.1 * ML2 * GAIT.omega])
    h = 0.02 * 2.0 ** (-14 / 4)
    orb = periodic_orbit("rimless_wheel", "VCI", h=h, guess=g, solver="iterate")
    assert orb.jacobian_kind == "envelope" and orb.stable
    assert abs((orb.eigenvalues[0].real - GAIT.eigenvalue) / h ** 2 + 0.72) < 0.01
    piece = periodic_orbit("rimless_wheel", "VCI", h=h, guess=g, solver="iterate", jacobian="fd")
    assert piece.jacobian_kind == "fd" and piece.stable and abs(piece.eigenvalues[0] - GAIT.eigenvalue) < 0.03
    from vcirun.experiments.periodic import ReturnMap

    central = np.linalg.eigvals(ReturnMap("rimless_wheel", "VCI", h=h).jacobian(np.concatenate(orb.fixed_point), 1e-6))
    assert np.max(np.abs(central)) > 10                      # the stencil that crosses the jump


def _vci_envelope_multiplier_errors(js):
    """(h, lambda - c^2) of VCI's envelope multiplier on the wheel at h = 0.02 * 2^(-j/4)."""
    g = ([-PRM["alpha"]], [1.1 * ML2 * GAIT.omega])
    hs = 0.02 * 2.0 ** (-np.asarray(js) / 4)
    errs = []
    for h in hs:
        orb = periodic_orbit("rimless_wheel", "VCI", h=h, guess=g, solver="iterate", jacobian="envelope")
        assert orb.jacobian_kind == "envelope" and abs(orb.eigenvalues[1]) < 1e-10
        errs.append(orb.eigenvalues[0].real - GAIT.eigenvalue)
    return hs, np.array(errs)


def test_vci_envelope_multiplier_converges_at_order_two():
    """jacobian="envelope" (the map's envelope, its sawtooth in the impact phase fitted out, at the
    envelope's fixed point): VCI's wheel multiplier is -0.72 h^2 from the closed form at every step
    h = 0.02 * 2^(-j/4) (measured -0.7224 .. -0.7203 for j = 0 .. 20, docs/walkers.md), so it converges
    at order 2.00 between any h and h/2, whatever the impact's grid phase (the pointwise multiplier:
    order 1; the gait's speed: within 13 h^2, erratic). Here j = 0 .. 12 (h = 0.02 .. 0.0025)."""
    hs, err = _vci_envelope_multiplier_errors(range(13))
    c = err / hs ** 2
    orders = np.log2(err[:-4] / err[4:])
    print("VCI envelope multiplier error / h^2:", np.round(c, 4).tolist(), "orders h -> h/2:", np.round(orders, 3).tolist())
    assert np.all((c > -0.73) & (c < -0.715)), c
    assert np.all(np.abs(orders - 2.0) < 0.01), orders
    g = ([-PRM["alpha"]], [1.1 * ML2 * GAIT.omega])
    with pytest.raises(ValueError, match="jacobian"):
        periodic_orbit("rimless_wheel", "VCI", h=0.01, guess=g, solver="iterate", jacobian="spline")
    with pytest.raises(ValueError, match="jacobian"):
        periodic_orbit("rimless_wheel", "CVA", h=0.01, guess=g, jacobian="envelope")   # needs "iterate"


@pytest.mark.slow
def test_vci_envelope_multiplier_order_two_over_21_steps():
    """The test above over all 21 steps h = 0.02 .. 6.25e-4 (docs/walkers.md): error / h^2 within
    -0.7224 .. -0.7203, the largest error per octave (4 steps) falling at order 2.00."""
    hs, err = _vci_envelope_multiplier_errors(range(21))
    c = err / hs ** 2
    peak = np.abs(err[:20]).reshape(5, 4).max(axis=1)
    orders = np.log2(peak[:-1] / peak[1:])
    print("error / h^2:", np.round(c, 4).tolist(), "per-octave maxima:", peak.tolist(), "orders:", orders.tolist())
    assert np.all((c > -0.725) & (c < -0.718)), c
    assert np.all(np.abs(np.log2(err[:-4] / err[4:]) - 2.0) < 0.01)
    assert np.all(np.abs(orders - 2.0) < 0.01), orders
