"""The failure record (vcirun.run.api): accumulation onset, named causes."""
from __future__ import annotations

import numpy as np
import pytest

import vcirun
from vcirun.run.diagnosis import accumulation_onset
from vcirun.run.resolve import resolve_system


def test_accumulation_onset_is_the_start_of_the_final_dense_run():
    h = 0.1
    assert np.isnan(accumulation_onset([], h))
    assert accumulation_onset([0.5], h) == 0.5
    # sparse, then a run of impacts less than h apart: the run's first impact
    assert accumulation_onset([0.5, 1.0, 1.5, 1.55, 1.58, 1.6], h) == 1.5
    # an earlier dense burst does not count, only the final run
    assert accumulation_onset([0.5, 0.52, 1.0, 2.0, 2.05], h) == 2.0
    # all sparse: the last impact
    assert accumulation_onset([0.5, 1.0, 2.0], h) == 2.0


def test_failure_message_keeps_its_prefix_and_appends_the_cause():
    """'<status> in step k (t = ..) from q = [..], p = [..]', then '; cause: ..' when a
    specific cause is found (here: the cart-pendulum with m2/m1 = 1e4 at h = 1e-2 blows up)."""
    tr = vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=5.0, beta=3.2, params={"m2": 1e4})
    assert tr.status == "newton_failed"
    head = (f"newton_failed in step {tr.fail_step} (t = {tr.fail_time:.6g}) from q = {tr.q[-1].tolist()}, "
            f"p = {tr.p[-1].tolist()}")
    assert tr.message.startswith(head + "; cause: ")
    assert "diverged" in tr.message or "mass matrix" in tr.message


def test_plain_newton_failure_has_no_invented_cause():
    """max_iter = 1 on a regular state: no specific cause, the message is the plain record."""
    tr = vcirun.simulate("oscillator_wall", "CVA", h=0.1, T=1.0, q0=np.array([1.0]), p0=np.array([0.0]), max_iter=1)
    assert tr.message == "newton_failed in step 0 (t = 0) from q = [1.0], p = [0.0]"


def test_resting_contact_cause():
    """With held contacts off, a start resting on the surface is the old failure with its cause; with
    them (the default) the cart is held from t0."""
    s = resolve_system("cart_pendulum")
    q0, p0 = s.legendre(np.array([0.0, 0.3]), np.zeros(2))
    tr = vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=1.0, q0=q0, p0=p0, resting_contact=False)
    assert tr.status == "reset_failed" and tr.fail_step == 0
    assert "; cause: zero normal velocity at the contact" in tr.message
    held = vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=1.0, q0=q0, p0=p0)
    assert held.status == "ok" and held.contact_active[0, 0]


@pytest.mark.parametrize("method", ["CVA", "VCI"])
def test_accumulation_message_names_the_onset(method):
    """max_impacts_step = 2 on a ball bouncing every 0.0089 s with h = 0.02 (up to 3 impacts per step)."""
    tr = vcirun.simulate("bouncing_ball", method, h=0.02, T=1.0, q0=np.array([1e-4]), p0=np.array([0.0]),
                         max_impacts_step=2, resting_contact=False)
    assert tr.status == "accumulation"
    onset = accumulation_onset(tr.impacts, tr.h)
    assert f"accumulation began at t = {onset:.9g}" in tr.message
