"""The error estimate on a scene with a guarded constraint (the compass gait's heel strike, armed once the
stance leg passes the slope normal): the gap reads GUARD_OFF until the guard arms, and that jump is not a
near miss of the surface the grid could have stepped over."""
from __future__ import annotations

import warnings

import pytest

import vcirun
from vcirun.run import estimate


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def test_the_screens_guard_value_is_the_generators():
    from vcirun.mechanics.hybrid import GUARD_OFF

    assert float(GUARD_OFF) == estimate.GUARD_OFF


@pytest.mark.parametrize("N", [18, 72])
def test_compass_gait_estimate_is_a_number_that_brackets_the_true_error(N):
    tr = vcirun.simulate("compass_gait", "CVA4", T=1, h=1 / N)
    est = tr.error_estimate()
    assert est.status == "ok", est.message
    true = vcirun.l2_error(tr, vcirun.reference("compass_gait", T=1))
    assert 0.5 * true <= est.l2 <= 2.0 * true, (est.l2, true)


def test_compass_gait_tol_is_met():
    tr = vcirun.simulate("compass_gait", T=1, tol=1e-6)
    assert tr.choice.status == "ok", tr.choice.reason
    assert vcirun.l2_error(tr, vcirun.reference("compass_gait", T=1)) <= 1e-6
