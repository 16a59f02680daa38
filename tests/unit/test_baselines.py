"""The solve_ivp baselines of the work-precision study (vcirun.experiments.baselines): correctness only.

They must solve the same nonsmooth problem as the exact reference (vcirun.reference: DOP853 at
rtol 1e-13, self-checked), report it on the same grid as a vcirun run, and converge to it as rtol
decreases. No timing is asserted (benchmarks live in bench/).

Observed on the cart-pendulum (beta = 3.2, T = 5, h = 1e-2, three impacts), L2 error against the
reference: DOP853 1.2e-5 (rtol 1e-8), 9.1e-8 (1e-10), 2.6e-10 (1e-12); Radau 1.1e-7 (1e-8).
The error over 5 s is a few hundred to a thousand times rtol: the impacts amplify the local errors.
"""
from __future__ import annotations

import numpy as np
import pytest

import vcirun
from vcirun.experiments.baselines import BASELINES, solve_ivp_run
from vcirun.reference import oscillator_wall_exact

T, BETA, H = 5.0, 3.2, 1e-2


@pytest.fixture(scope="module")
def ref():
    return vcirun.reference("cart_pendulum", T=T, beta=BETA)


@pytest.fixture(scope="module")
def dop():
    return {rtol: solve_ivp_run("cart_pendulum", "DOP853", h=H, T=T, beta=BETA, rtol=rtol)
            for rtol in (1e-8, 1e-10, 1e-12)}


def test_grid_and_record_match_a_vcirun_run(dop):
    b = dop[1e-10]
    tr = vcirun.simulate("cart_pendulum", "CVA", h=H, T=T, beta=BETA)
    assert b.status == "ok", b.message
    np.testing.assert_array_equal(b.t, tr.t)
    assert b.q.shape == tr.q.shape and b.p.shape == tr.p.shape and b.H.shape == tr.H.shape
    np.testing.assert_array_equal(b.q[0], tr.q[0])
    np.testing.assert_array_equal(b.p[0], tr.p[0])
    assert len(b.impacts) == len(tr.impacts) == 3
    # each impact is marked in the grid step that contains it
    assert b.impact_step.sum() == 3
    for ti in b.impacts:
        k = int(np.floor(ti / H))
        assert b.impact_step[k] and b.t[k] <= ti <= b.t[k + 1]
    assert b.wall_time > 0 and b.options["nfev"] > 0


def test_dop853_agrees_with_the_exact_reference_to_its_tolerance(dop, ref):
    errs = {rtol: vcirun.l2_error(b, ref) for rtol, b in dop.items()}
    # the reference is itself good to ~1e-10 (ref.accuracy): the tightest solve is limited by it
    assert ref.accuracy < 1e-9
    assert errs[1e-12] < 1e-8
    assert errs[1e-10] < 1e-6
    assert errs[1e-8] < 1e-4
    assert errs[1e-12] < errs[1e-10] < errs[1e-8]          # converges as rtol decreases
    for rtol, b in dop.items():
        assert np.max(np.abs(b.impacts - ref.impacts)) < 1e4 * rtol
        # the reset is exact, so H only drifts with the smooth integration error
        assert np.max(np.abs(b.H - b.H[0])) < 1e4 * rtol * abs(b.H[0])


def test_reset_is_the_exact_elastic_reflection(dop):
    from vcirun.api import resolve_system
    from vcirun.codegen.build import load_module
    from vcirun.methods import METHODS

    b = dop[1e-12]
    s = resolve_system("cart_pendulum")
    prm = s.param_values(None)
    mod = load_module(s, METHODS["CVA"].kernel_set())
    for q, pm, pp in zip(b.impact_q, b.impact_p_minus, b.impact_p_plus):
        assert abs(q[0]) < 1e-9                                         # on the surface y = 0
        g = np.empty(2)
        mod.sys_dphi(q, prm, g)
        M = np.empty((2, 2))
        mod.sys_M(q, prm, M)
        W = np.linalg.inv(M)
        assert g @ W @ pm < 0 < g @ W @ pp                              # in, then out
        np.testing.assert_allclose(g @ W @ pp, -(g @ W @ pm), rtol=1e-12)  # normal velocity reversed
        assert abs(mod.hamiltonian(q, pp, prm) - mod.hamiltonian(q, pm, prm)) < 1e-12


def test_radau_agrees_with_the_exact_reference(ref):
    b = solve_ivp_run("cart_pendulum", "Radau", h=H, T=T, beta=BETA, rtol=1e-8)
    assert b.status == "ok" and len(b.impacts) == 3
    assert vcirun.l2_error(b, ref) < 1e-5
    assert np.max(np.abs(b.impacts - ref.impacts)) < 1e-6


def test_numpy_kernels_give_the_same_solution(dop):
    b = solve_ivp_run("cart_pendulum", "DOP853", h=H, T=T, beta=BETA, rtol=1e-8, kernels="numpy")
    a = dop[1e-8]
    assert b.status == "ok"
    np.testing.assert_allclose(b.q, a.q, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.impacts, a.impacts, rtol=0, atol=1e-10)


def test_double_pendulum_agrees_with_its_reference():
    ref = vcirun.reference("double_pendulum", T=10.0)
    b = solve_ivp_run("double_pendulum", "DOP853", h=1e-2, T=10.0, rtol=1e-11)
    assert b.status == "ok" and len(b.impacts) == len(ref.impacts) == 3
    assert vcirun.l2_error(b, ref) < 1e-6


def test_oscillator_against_the_closed_form():
    b = solve_ivp_run("oscillator_wall", "DOP853", h=0.05, T=30.0, q0=np.array([1.0]), p0=np.array([0.0]),
                      rtol=1e-11)
    x, _, t_imp = oscillator_wall_exact(b.t, 1.0, 0.0)
    assert b.status == "ok" and len(b.impacts) == len(t_imp) == 7
    assert np.max(np.abs(b.q[:, 0] - x)) < 1e-8
    assert np.max(np.abs(b.impacts - t_imp)) < 1e-8


def test_bad_input_raises_naming_the_field():
    for kw, field in [({"method": "RK45"}, "method"), ({"h": 0.0}, "h"), ({"T": -1.0}, "T"), ({"rtol": 0.0}, "rtol")]:
        args = dict(method="DOP853", h=H, T=T, beta=BETA, rtol=1e-6) | kw
        method = args.pop("method")
        with pytest.raises(ValueError, match=f"^{field}:"):
            solve_ivp_run("cart_pendulum", method, **args)
    assert set(BASELINES) == {"DOP853", "Radau"}
