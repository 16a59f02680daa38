"""Energy accounts (vcirun.run.accounts): H(t) - H(t0) = the impact law's term + the forcing work + the
rest. The law's loss is evaluated from (q, p-) by the law itself, so for CVA (whose p+ is the law's) it
equals the jump of H in the record; the rest is the integration error (order of the method) for a
run and the solve's own error (round-off) for the exact reference; e = 1 gives a law term of 0.0."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import vcirun
from vcirun.run.accounts import FORCING, LAW

SCENES = Path(__file__).resolve().parents[1] / "scenes" / "dissipative"


def _slope(hs, errs):
    return float(np.polyfit(np.log(hs), np.log(errs), 1)[0])


@pytest.fixture(scope="module")
def block_runs():
    return {h: vcirun.simulate("rocking_block", "CVA", h=h, T=3) for h in (2e-3, 1e-3, 5e-4)}


def test_cva_law_loss_is_the_jump_of_H_and_the_rest_is_order_2(block_runs):
    rests = []
    for h, tr in block_runs.items():
        acc = tr.energy_account()
        assert tr.status == "ok" and len(acc.events) >= 15
        for ev in acc.events:   # CVA's p+ is the law's: the law's loss is the recorded jump of H
            assert ev.loss > 0 and abs(ev.jump - ev.loss) <= 1e-13 * acc.scale
        # the whole change: restitution (1.962 J here: the block ends at rest on the floor) plus a rest
        assert acc.change == pytest.approx(acc.total(LAW) + acc.rest, abs=1e-14 * acc.scale)
        assert acc.law_loss == pytest.approx(-acc.change, rel=1e-4)
        assert acc.term(FORCING) is None
        series = acc.term(LAW).series
        assert series[0] == 0.0 and np.all(np.diff(series) <= 0.0)   # losses only, at the impact steps
        rests.append(acc.error)
    assert 1.8 <= _slope(list(block_runs), rests) <= 2.2
    assert rests[-1] < 1e-6 * block_runs[5e-4].energy_account().scale


def test_elastic_law_term_is_exactly_zero_and_rest_is_the_drift():
    tr = vcirun.simulate("rocking_block", "VCI", h=1e-3, T=2, params={"e": 1.0})
    acc = tr.energy_account()
    assert len(acc.events) > 0 and acc.total(LAW) == 0.0 and all(ev.loss == 0.0 for ev in acc.events)
    np.testing.assert_array_equal(acc.rest_series, tr.H - tr.H[0])
    assert acc.error == np.max(np.abs(tr.H - tr.H[0]))
    assert "-0.000000e+00" not in str(acc) and "the law removed 0.000000e+00" in str(acc)   # (no negative zero)


def test_energy_reset_error_goes_to_the_rest():
    """VCI's reset conserves its discrete energy less the law's loss: the jump of H differs from the
    loss by O(h^2), and that difference is part of the rest (not of the law's term)."""
    diffs = []
    for h in (2e-3, 1e-3):
        acc = vcirun.simulate("rocking_block", "VCI", h=h, T=1).energy_account()
        diffs.append(max(abs(ev.jump - ev.loss) for ev in acc.events))
        assert acc.change == pytest.approx(acc.total(LAW) + acc.rest, abs=1e-13)
    assert diffs[1] < diffs[0] / 2.5


def test_reference_account_is_made_when_asked_and_travels_with_a_copy():
    """The exact reference's account is computed on first use (a sweep's references never read it),
    gives the same figures either way, and a pickled reference carries it (its maker holds the kernel
    module, which does not pickle)."""
    import pickle

    ref = vcirun.reference("rocking_block", T=1, params={"e": 0.5})
    assert ref._account is None
    copy = pickle.loads(pickle.dumps(ref))
    assert copy.energy_balance == ref.energy_balance == ref.energy_account().error
    assert copy.energy_account().total(LAW) == ref.energy_account().total(LAW) < 0.0


def test_reference_energy_balance_is_the_rest_with_and_without_restitution():
    for e in (1.0, 0.5):
        ref = vcirun.reference("rocking_block", T=2, params={"e": e})
        acc = ref.energy_account()
        assert ref.energy_balance == acc.error <= 1e-13 * acc.scale
        assert acc.change == pytest.approx(acc.total(LAW) + acc.rest, abs=1e-13 * acc.scale)
        if e == 1.0:
            assert abs(acc.total(LAW)) <= 1e-13 * acc.scale
        else:
            assert acc.law_loss > 1.0 and len(acc.events) == len(np.unique(ref.impacts))


def test_forced_two_link_arm_floor_and_wall():
    """A damped two-link arm whose tip hits a floor and a wall (e = 0.8): the reference's balance is
    round-off though restitution and damping each remove several J; the run's law loss and work agree
    with the reference's to the run's accuracy, and its rest converges at the method's order (CVA 2,
    CVA4 4: the work quadrature is not the limit)."""
    arm = str(SCENES / "two_link_arm.yaml")
    ref = vcirun.reference(arm, T=2.8)
    racc = ref.energy_account()
    assert len(ref.impacts) >= 4 and set(ref.impact_contact) == {0, 1}
    assert racc.law_loss > 5.0 and racc.total(FORCING) < -5.0
    assert ref.energy_balance <= 1e-12 * racc.scale
    for method, order, hs in (("CVA", 2, (2e-3, 1e-3, 5e-4)), ("CVA4", 4, (4e-3, 2e-3, 1e-3))):
        errs = []
        for h in hs:
            tr = vcirun.simulate(arm, method, h=h, T=2.8)
            acc = tr.energy_account()
            assert tr.status == "ok" and len(tr.impacts) == len(ref.impacts)
            errs.append(acc.error)
        assert abs(acc.law_loss - racc.law_loss) <= 1e-2 * racc.law_loss
        assert abs(acc.total(FORCING) - racc.total(FORCING)) <= 1e-2 * abs(racc.total(FORCING))
        assert order - 0.25 <= _slope(hs, errs) <= order + 0.5, (method, errs)


def test_declared_map_loss_and_dense_output_of_a_walker():
    """A declared reset (the compass gait's heel strike and leg exchange): the law's loss is the map's
    H(q-, p-) - H(q+, p+) (the relabelled potential included), the CVA jump equals it; the dense
    output jumps to the map's q+ at each impact."""
    tr = vcirun.simulate("compass_gait", "CVA", h=1e-3, T=2)
    acc = tr.energy_account()
    assert len(acc.events) >= 2
    for ev in acc.events:
        assert abs(ev.jump - ev.loss) <= 1e-12 * acc.scale
    # dense output after a heel strike starts from the map's q+ (the legs exchanged), not from q-
    for k, tau in enumerate(tr.impacts):
        np.testing.assert_allclose(tr(tau), tr.impact_q[k][::-1], atol=1e-12)
        np.testing.assert_allclose(tr(tau - 1e-9), tr.impact_q[k], atol=1e-6)
    tt = np.linspace(0, tr.t[-1], 4001)
    steps = np.max(np.abs(np.diff(tr(tt), axis=0)), axis=1)
    assert np.sum(steps > 0.05) == len(tr.impacts)   # jumps at the impacts only
    ref = vcirun.reference("compass_gait", T=2)
    assert ref.energy_balance <= 1e-12 * ref.energy_account().scale


def test_account_survives_a_file_and_pickling(tmp_path):
    import pickle

    tr = vcirun.simulate("rocking_block", "CVA", h=2e-3, T=1)
    path = tr.save(tmp_path / "run.h5")
    back = vcirun.run.trajectory.read_trajectory(path)
    a, b = tr.energy_account(), back.energy_account()
    assert a.error == b.error and a.total(LAW) == b.total(LAW)
    c = pickle.loads(pickle.dumps(tr)).energy_account()
    assert c.error == a.error
    assert "impact law" in str(a) and "rest" in a.table()
