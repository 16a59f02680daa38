"""Holds after a plastic impact are resolved; holds where bounces accumulate are not: the estimate
(vcirun.run.estimate.difference) reads the hold onsets `pilot.accumulated_holds` leaves, and a plastic
contact (restitution 0) held from the step of its own impact is not among them. Checked against the
exact reference on the friction scenes, whose impacts are plastic."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

import vcirun
from vcirun.run.pilot import accumulated_holds


def test_which_onsets_are_kept():
    h = 0.1
    onsets = ((0.5, 0), (0.5, 1), (0.9, 0))
    impacts, contacts = np.array([0.43, 0.47, 0.61]), np.array([0, 1, 0])
    # contact 0 plastic: its onset at 0.5 follows its impact at 0.43 in that step; the one at 0.9 follows none
    # contact 1 (e = 0.5): kept, whatever precedes it
    assert accumulated_holds(onsets, impacts, contacts, h, np.array([0.0, 0.5])) == ((0.5, 1), (0.9, 0))
    assert accumulated_holds(onsets, impacts, contacts, h, None) == onsets
    assert accumulated_holds((), impacts, contacts, h, np.array([0.0, 0.0])) == ()


@pytest.mark.parametrize("system, T, tol", [("spinning_ball", 1.0, 1e-6), ("rocking_block_friction", 1.0, 1e-5)])
def test_tol_is_reached_on_plastic_friction_scenes(system, T, tol):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tr = vcirun.simulate(system, T=T, tol=tol)
        assert tr.choice.status == "ok", tr.choice.reason
        assert vcirun.l2_error(tr, vcirun.reference(system, T=T)) <= tol


def test_holds_after_accumulating_bounces_are_kept():
    """The rocking block (e = 0.5): its corners come to rest after bounces that accumulate; those onsets
    stay for the estimate, which reads them as unresolved."""
    from vcirun.run.pilot import Run, Runner

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tr = vcirun.simulate("rocking_block", "CVA", T=1.5, h=1e-3)
        runner = Runner("rocking_block", T=1.5)
        run = Run.of_trajectory(tr, "CVA", runner.module("CVA"), runner.params_vector("CVA"))
    assert np.asarray(tr.contact_active).any() and len(run.holds) > 0, run.holds
    assert tr.error_estimate().status == "unresolved"
