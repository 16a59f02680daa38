"""The compass gait (Goswami, Thuilot and Espiau 1998: m = 5, mH = 10, a = b = 0.5) on its 3-degree
slope: the period-one gait's fixed point, stride period and multipliers converge in h at each method's
order (against CVA8 at h = 0.005); the gait is Goswami et al.'s; the period doubling along the slope
is detected and the period-two orbit followed; `vcirun periodic` prints the rimless wheel's gait."""
from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from vcirun.cli.main import app
from vcirun.experiments.bifurcation import continuation
from vcirun.experiments.periodic import periodic_orbit
from vcirun.scenes.registry import scene_data
from vcirun.scenes.walkers import compass_gait_M

D = scene_data("compass_gait")


def _gait(method, h, **kw):
    o = periodic_orbit("compass_gait", method, h=h, guess=(D.default_q0, D.default_p0), **kw)
    q, p = o.fixed_point
    ev = o.eigenvalues[:3]                       # (the fourth is the section's ~0)
    return o, np.concatenate([q, np.linalg.solve(np.array(compass_gait_M(q, D.params)), p), [o.period],
                              ev.real, np.abs(ev.imag)])


@pytest.fixture(scope="module")
def reference():
    o, x = _gait("CVA8", 0.005)
    assert abs(o.eigenvalues[3]) < 1e-9
    return x


def test_the_gait_is_goswamis(reference):
    """Goswami et al.'s 3-degree gait (their angles from the vertical, 0.3234 and -0.2187, are
    +-0.2710 from the slope normal; rates 1.0918 and 0.3772 rad/s, rounded), stable, complex pair."""
    np.testing.assert_allclose(reference[:2], [-0.2710, 0.2710], atol=1e-4)
    np.testing.assert_allclose(reference[2:4], [1.0918, 0.3772], atol=1e-3)
    assert np.hypot(reference[5], reference[8]) < 1.0 and reference[8] > 0.5   # |-0.1997 +- 0.5445 i| = 0.58


@pytest.mark.parametrize("method, order, hs", [("CVA", 2, (0.02, 0.01, 0.005)), ("CVA4", 4, (0.02, 0.01, 0.005)),
                                               ("MCVAA", 2, (0.02, 0.01, 0.005)), ("MCVAC", 2, (0.02, 0.01, 0.005))])
def test_compass_gait_converges_at_the_method_order(reference, method, order, hs):
    """Fixed point (q, qdot) and period at the method's order; the multipliers' error decreases at
    least at half of it (not monotone in h: the discrete map's derivative changes where the impact
    crosses a grid point; measured rates CVA 1.8, 1.6, CVA4 3.2, 3.9, MCVAA 2.0, 2.0, MCVAC 2.2, 2.1)."""
    err = np.array([np.abs(_gait(method, h)[1] - reference) for h in hs])
    for name, cols, need in (("state", slice(0, 4), order - 0.3), ("period", slice(4, 5), order - 0.3),
                             ("multipliers", slice(5, 11), order / 2)):
        e = err[:, cols].max(axis=1)
        rates = np.log2(e[:-1] / e[1:])
        print(method, name, "errors:", e.tolist(), "rates:", rates.tolist())
        assert np.all(rates > need), (name, rates)


# The exact gait's multipliers (the reference's stride map, Taylor, fd_step 5e-5; accurate to 4e-11:
# tests/reference/test_reference_declared_resets.py)
EXACT_MULTIPLIERS = (-0.19972612682583946, 0.5444760621134417, 0.13157262406967357)   # Re, |Im| of the pair; real


def _vci_envelope_errors(h):
    """|Re|, ||Im||, |real| errors of VCI's envelope multipliers (solver "iterate") against the exact ones."""
    o = periodic_orbit("compass_gait", "VCI", h=h, guess=(D.default_q0, D.default_p0), solver="iterate",
                       jacobian="envelope")
    ev = o.eigenvalues
    pair, real = ev[np.abs(ev.imag) > 1e-9], ev[(np.abs(ev.imag) <= 1e-9) & (np.abs(ev) > 1e-3)]
    assert len(pair) == 2 and len(real) == 1 and abs(ev[3]) < 1e-8, ev
    return np.abs(np.array([pair[0].real, abs(pair[0].imag), real[0].real]) - EXACT_MULTIPLIERS)


def test_vci_envelope_multipliers_converge_at_order_two():
    """VCI's stride map jumps by O(h^2) where the impact time crosses a grid point (its pointwise
    multipliers converge at order 1); the envelope Jacobian's multipliers (docs/walkers.md) converge at
    order 2: largest error over Re, |Im| of the pair and the real one 2.60, 2.24, 2.23, 2.22 h^2 at
    h = 0.02, 0.01, 0.005, 0.0025 (orders 2.21, 2.00, 2.01)."""
    hs = np.array([0.02, 0.01, 0.005, 0.0025])
    err = np.array([_vci_envelope_errors(h) for h in hs]).max(axis=1)
    orders = np.log2(err[:-1] / err[1:])
    print("VCI envelope multipliers, error / h^2:", (err / hs ** 2).tolist(), "orders:", orders.tolist())
    assert np.all((err / hs ** 2 > 2.1) & (err / hs ** 2 < 2.7)), err / hs ** 2
    assert 1.9 < orders[0] < 2.4 and np.all(np.abs(orders[1:] - 2.0) < 0.05), orders


def test_period_doubling_is_detected_and_followed():
    br = continuation("compass_gait", "CVA4", h=0.01, param="gamma", values=np.deg2rad([4.3, 4.35, 4.4, 4.5]),
                      guess=(D.default_q0, D.default_p0))
    assert br.doubling is not None and abs(np.rad2deg(br.doubling) - 4.3909) < 1e-3
    assert [o.k for o in br.orbits] == [1, 1, 2, 2]
    last = br.points[-1]
    assert abs(last[0, 0] - last[1, 0]) > 1e-2                  # two different strides
    assert np.max(np.abs(br.orbits[-1].eigenvalues)) < 1.0      # the period-two gait is stable


def test_cli_periodic_prints_the_rimless_wheel_gait():
    r = CliRunner().invoke(app, ["periodic", "--system", "rimless_wheel", "--method", "CVA4", "--h", "0.005"])
    assert r.exit_code == 0, r.output
    assert "fixed point" in r.output and "multipliers 0.49999" in r.output and "(stable)" in r.output
    assert "[jacobian fd]" in r.output
    env = CliRunner().invoke(app, ["periodic", "--system", "rimless_wheel", "--method", "VCI", "--h", "0.01",
                                   "--solver", "iterate"])             # the envelope Jacobian by default
    assert env.exit_code == 0 and "multipliers 0.4999" in env.output and "[jacobian envelope]" in env.output, env.output
    fd = CliRunner().invoke(app, ["periodic", "--system", "rimless_wheel", "--method", "VCI", "--h", "0.01",
                                  "--solver", "iterate", "--jacobian", "fd"])
    assert fd.exit_code == 0 and "[jacobian fd]" in fd.output, fd.output
    bad = CliRunner().invoke(app, ["periodic", "--system", "rimless_wheel", "--sweep", "gamma=1:2"])
    assert bad.exit_code == 1 and "NAME=START:STOP:COUNT" in bad.output
