"""Acceptance: the paper's vertical cart-pendulum (Section 5), Xi(beta), beta in [3.2, 5.2], T = 5.

L2 error (vcirun.l2_error): sqrt(h sum_k |q_k - q_ref(t_k)|^2) over the grid, against the exact
reference (DOP853 + event location + exact elastic reset).

Asserted band for the ratio L2(h = 3.2e-2) / L2(h = 1e-2): [5, 20]. A second-order method in its
asymptotic regime gives (3.2)^2 = 10.24 (the paper's footnote: "one order of magnitude"). At
h = 3.2e-2 the pendulum (|theta'| ~ 4-10 rad/s) is not yet asymptotic: the L2 errors there are
0.5-1.2 (rad over sqrt(s)) and the observed ratios over beta in {3.2, 3.7, 4.2, 4.7, 5.2} are
7.4-14.5 for both methods (11 betas: 6.8-14.5). Between h = 1e-2 and 1e-2/sqrt(10) the ratio is
8.5-10.4 (CVA 9.7-10.3), close to the asymptotic 10; that is asserted with the tighter band
[8, 12.5].
"""
from __future__ import annotations

import numpy as np
import pytest

import vcirun

T = 5.0
BETAS = [3.2, 3.7, 4.2, 4.7, 5.2]
_REFS: dict = {}


def _ref(beta):
    if beta not in _REFS:
        _REFS[beta] = vcirun.reference("cart_pendulum", T=T, beta=beta)
    return _REFS[beta]


def _l2(method, h, beta):
    tr = vcirun.simulate("cart_pendulum", method, h=h, T=T, beta=beta)
    assert tr.status == "ok", tr.message
    return vcirun.l2_error(tr, _ref(beta)), tr


@pytest.mark.parametrize("method", ["CVA", "VCI"])
@pytest.mark.parametrize("beta", BETAS)
def test_l2_error_drops_one_order_between_h_32e3_and_1e2(method, beta):
    e_coarse, tr_c = _l2(method, 3.2e-2, beta)
    e_fine, tr_f = _l2(method, 1e-2, beta)
    ratio = e_coarse / e_fine
    assert 5.0 <= ratio <= 20.0, (e_coarse, e_fine, ratio)
    # same impact count as the exact solution at both steps (3 over [0, 5] for every beta here)
    assert len(tr_c.impacts) == len(tr_f.impacts) == len(_ref(beta).impacts) == 3


@pytest.mark.parametrize("method", ["CVA", "VCI"])
@pytest.mark.parametrize("beta", [3.2, 4.2, 5.2])
def test_l2_error_asymptotic_second_order(method, beta):
    e1, _ = _l2(method, 1e-2, beta)
    e2, _ = _l2(method, 1e-2 / np.sqrt(10.0), beta)
    assert 8.0 <= e1 / e2 <= 12.5, (e1, e2, e1 / e2)


@pytest.mark.parametrize("method", ["CVA", "VCI"])
def test_three_impacts_at_beta_32(method):
    """Paper, Figure 3: Xi(3.2), h = 1e-2 gives three impacts."""
    _, tr = _l2(method, 1e-2, 3.2)
    assert len(tr.impacts) == 3
    ref = _ref(3.2)
    assert len(ref.impacts) == 3
    # impact times close to the exact ones (observed: CVA 8.7e-4, VCI 6.0e-4)
    assert np.max(np.abs(tr.impacts - ref.impacts)) < 2e-3


def test_reference_is_accurate_to_1e9_independent_check():
    """The default reference (rtol 1e-13) against one at scipy's tightest rtol (2.3e-14): they
    agree to < 1e-9 on a 2001-point grid and in the impact times (observed <= 4.2e-10)."""
    tt = np.linspace(0.0, T, 2001)
    for beta in BETAS:
        a = _ref(beta)
        b = vcirun.reference("cart_pendulum", T=T, beta=beta, rtol=2.3e-14, check_accuracy=False)
        assert np.max(np.abs(a(tt) - b(tt))) < 1e-9
        assert np.max(np.abs(a.impacts - b.impacts)) < 1e-9


def test_reference_self_reported_accuracy_below_1e9():
    worst = max(_ref(beta).accuracy for beta in BETAS)
    assert worst < 1e-9, worst


def test_fine_step_cva_reference_agrees_with_exact():
    """The paper's own benchmark (CVA at a small step, here h = 1e-3) is within its O(h^2) error of
    the exact reference (observed L2 4.7e-4 .. 1.2e-3 between them)."""
    for beta in (3.2, 5.2):
        fine = vcirun.reference("cart_pendulum", T=T, beta=beta, method="CVA", h=1e-3)
        tr = vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=T, beta=beta)
        e_exact = vcirun.l2_error(tr, _ref(beta))
        e_fine = vcirun.l2_error(tr, fine)
        assert abs(e_exact - e_fine) < 0.05 * e_exact
