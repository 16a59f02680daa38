"""Acceptance: harmonic oscillator against a wall, against its closed form.

Scene: m x'' = -k x, wall at x = -d (phi = x + d >= 0); m = k = 1, d = 0.5, released from rest at
x0 = 1. The exact motion bounces every 2 arccos(-d/A) / w = 4.19 time units; T = 50 gives 12
impacts.

Observed order. CVA's error constant is smooth in h (max error / h^2 = 1.91 .. 2.02 over
h = 0.1 .. 0.0063). VCI's is not: the R^VCI reset equates the discrete energy of the pre-impact
partial step (length f h) with that of the post-impact one ((1 - f) h). -D3 Ld^SVC = E + O(tau^2),
so the two sides differ by c (f^2 - (1 - f)^2) h^2. That makes VCI's *local* impact error O(h^2)
(CVA's is O(h^3); see test_local_impact_error), with a sign and size that depend on where the
impact falls in its step. The global error is still O(h^2), but its constant jumps between
0.45 and 5.7 from one h to the next, so a 5-point log-log fit is noise-dominated (it gives 2.45 on
h = 0.1 .. 0.00625). The order is therefore fitted over 17 steps h = 0.1 * 2^(-j/4), j = 0..16
(same range, fit 2.00 for VCI and 1.98 for CVA), and the constant is checked to stay bounded.
"""
from __future__ import annotations

import numpy as np
import pytest

import vcirun
from vcirun.scenes.oracles import oscillator_wall_exact

X0, V0, T, D = 1.0, 0.0, 50.0, 0.5
H_DENSE = 0.1 * 2.0 ** (-np.arange(17) / 4.0)   # 0.1 .. 0.00625, 4 per octave
H_COARSE = np.array([0.1, 0.05, 0.025, 0.0125, 0.00625])


def _slope(h, e):
    return float(np.polyfit(np.log(h), np.log(e), 1)[0])


def _errors(method, hs):
    """(max grid error in x, max impact-time error) per h against the closed form."""
    ex, et = [], []
    for h in hs:
        tr = vcirun.simulate("oscillator_wall", method, h=h, T=T, q0=np.array([X0]), p0=np.array([V0]))
        assert tr.status == "ok", tr.message
        x, _, t_imp = oscillator_wall_exact(tr.t, X0, V0, 1.0, 1.0, D)
        assert len(tr.impacts) == len(t_imp), (h, tr.impacts, t_imp)
        ex.append(np.max(np.abs(tr.q[:, 0] - x)))
        et.append(np.max(np.abs(tr.impacts - t_imp)))
    return np.array(ex), np.array(et)


def test_closed_form_has_at_least_10_impacts_and_matches_dop853():
    """The closed form is only an oracle if it is right: check it against the DOP853 + event
    reference (independent code path) on the horizon used below."""
    _, _, t_imp = oscillator_wall_exact(np.array([T]), X0, V0, 1.0, 1.0, D)
    assert len(t_imp) >= 10
    ref = vcirun.reference("oscillator_wall", T=T, q0=np.array([X0]), p0=np.array([V0]))
    tt = np.linspace(0.0, T, 5001)
    x, _, _ = oscillator_wall_exact(tt, X0, V0, 1.0, 1.0, D)
    assert np.max(np.abs(ref(tt)[:, 0] - x)) < 1e-9
    assert len(ref.impacts) == len(t_imp)
    assert np.max(np.abs(ref.impacts - t_imp)) < 1e-9


def test_cva_order_2_coarse_grid():
    """The lead's grid: CVA is order 2 already on 5 halvings (errors 1.9e-2 .. 7.9e-5)."""
    ex, et = _errors("CVA", H_COARSE)
    assert abs(_slope(H_COARSE, ex) - 2.0) < 0.15, ex
    assert abs(_slope(H_COARSE, et) - 2.0) < 0.15, et


@pytest.mark.parametrize("method", ["CVA", "VCI"])
def test_order_2_max_error_and_impact_times(method):
    ex, et = _errors(method, H_DENSE)
    assert abs(_slope(H_DENSE, ex) - 2.0) < 0.15, (ex, ex / H_DENSE**2)
    assert abs(_slope(H_DENSE, et) - 2.0) < 0.15, (et, et / H_DENSE**2)
    # O(h^2) means a bounded constant, not only a slope: CVA 1.9-2.1, VCI 0.45-5.7 observed
    c = ex / H_DENSE**2
    assert np.all(c < 10.0) and np.all(c > 0.1), c
    ct = et / H_DENSE**2
    assert np.all(ct < 10.0), ct


@pytest.mark.parametrize("method", ["CVA", "VCI"])
def test_local_impact_error(method):
    """One step containing one impact, started on the exact solution, with the impact at fraction
    f of the step: the error after the step is O(h^3) for CVA and O(h^2) for VCI, except at
    f = 1/2, where the two partial steps are of equal length, R^VCI's discrete energies coincide
    with R^CVA's and VCI is O(h^3) too."""
    A = 1.0
    thi = np.arccos(-D / A)
    hs = np.array([0.1, 0.05, 0.025, 0.0125])
    for f in (0.1, 0.5, 0.9):
        errs = []
        for h in hs:
            th = thi - f * h
            x0, v0 = A * np.cos(th), -A * np.sin(th)
            tr = vcirun.simulate("oscillator_wall", method, h=h, T=h, q0=np.array([x0]), p0=np.array([v0]))
            assert tr.status == "ok" and len(tr.impacts) == 1
            x, v, _ = oscillator_wall_exact(tr.t, x0, v0, 1.0, 1.0, D)
            errs.append(max(abs(tr.q[-1, 0] - x[-1]), abs(tr.p[-1, 0] - v[-1])))
        s = _slope(hs, np.array(errs))
        expected = 3.0 if (method == "CVA" or f == 0.5) else 2.0
        assert abs(s - expected) < 0.15, (method, f, s, errs)
