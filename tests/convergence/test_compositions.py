"""Higher-order compositions of SVC (SVC4, SVC6, SVC8) and CVA on them (CVA4, CVA6, CVA8).

Beyond the paper (the fastest method at each accuracy). Checked here:
- the weights satisfy the necessary order conditions (sum = 1, odd power sums vanish);
- observed orders 4, 6, 8 of the smooth maps (cart-pendulum, against DOP853 at rtol 1e-13);
- the maps are symplectic and symmetric (the composition of symmetric SVC steps with palindromic
  weights is self-adjoint);
- the ORDER SURVIVES THE IMPACTS: CVA4/6/8 on the oscillator against a wall (closed form), and on
  the cart-pendulum against the exact reference (three impacts);
- `ld=` on CVA gives the same method as the named one; VCI and MCVA refuse the compositions.
"""
from __future__ import annotations

import numpy as np
import pytest

import vcirun
from convergence.helpers import exact_smooth, fit_order, map_jacobian, run_map, step, symplecticity_defect
from vcirun.discrete import lagrangians as L
from vcirun.scenes.oracles import oscillator_wall_exact

WEIGHTS = {"SVC4": (L.SVC4_WEIGHTS, 4), "SVC6": (L.SVC6_WEIGHTS, 6), "SVC8": (L.SVC8_WEIGHTS, 8)}
TOL = 0.35


@pytest.mark.parametrize("ld", list(WEIGHTS))
def test_weights_satisfy_the_necessary_order_conditions(ld):
    w, p = WEIGHTS[ld]
    w = np.asarray(w)
    assert L.LIBRARY[ld].order == p and L.LIBRARY[ld].symmetric
    assert abs(w.sum() - 1.0) < 1e-15
    np.testing.assert_allclose(w, w[::-1], rtol=0, atol=0)  # palindromic: symmetric method
    for k in range(3, p, 2):  # sum w^k = 0 for odd k < p (the h^k error terms of the symmetric stages)
        assert abs(np.sum(w**k)) < 1e-14, (ld, k, np.sum(w**k))
    assert abs(np.sum(w**(p + 1))) > 1e-4  # the next one does not vanish (Kahan-Li minimise, not cancel, it)


# cart-pendulum from Xi(1), constraint ignored (fully nonseparable swing); h = 2 / N
SMOOTH_N = {"SVC4": (20, 40, 80, 160), "SVC6": (20, 40, 80, 160), "SVC8": (10, 20, 40, 80)}


@pytest.mark.parametrize("ld", list(SMOOTH_N))
def test_observed_order_of_the_smooth_map(ld, compiled):
    T = 2.0
    system, mod, prm = compiled("cart_pendulum", ld)
    q0, p0 = system.initial_state(beta=1.0)
    NS = SMOOTH_N[ld]
    tc = np.linspace(0.0, T, 11)
    qref, _ = exact_smooth(mod, prm, q0, p0, tc)
    hs, errs = [], []
    for N in NS:
        Q, _ = run_map(mod, prm, q0, p0, T / N, N)
        hs.append(T / N)
        errs.append(float(np.max(np.abs(Q[:: N // 10] - qref))))
    slope, used = fit_order(hs, errs, scale=float(np.max(np.abs(qref))))
    p = L.LIBRARY[ld].order
    assert abs(slope - p) < TOL, f"{ld}: slope {slope:.2f} from {['%.2e' % e for e in errs]} (used {used})"


@pytest.mark.parametrize("ld", ["SVC6"])
def test_composition_is_symplectic_and_symmetric(ld, compiled, rng):
    system, mod, prm = compiled("cart_pendulum", ld)
    n = system.n
    worst_s = worst_adj = 0.0
    for _ in range(3):
        q, p = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
        f = lambda y: np.concatenate(step(mod, y[:n], y[n:], 0.1, 0.0, prm))  # noqa: E731
        worst_s = max(worst_s, symplecticity_defect(map_jacobian(f, np.r_[q, p], d=1e-3)))
        qa, pa = step(mod, q, p, 0.1, 0.0, prm)
        qb, pb = step(mod, qa, pa, -0.1, 0.0, prm)
        worst_adj = max(worst_adj, float(np.max(np.abs(np.r_[qb - q, pb - p]))))
    assert worst_s < 1e-8, worst_s
    assert worst_adj < 1e-12, worst_adj


IMPACT_H = {"CVA4": (0.2, 0.1, 0.05, 0.025), "CVA6": (0.4, 0.2, 0.1, 0.05), "CVA8": (0.5, 0.25, 0.125, 0.0625)}


# CVA6 and CVA8 each build their own module (~40 s cold): slow; CVA4 stays in the default suite
@pytest.mark.parametrize("method", ["CVA4", pytest.param("CVA6", marks=pytest.mark.slow),
                                    pytest.param("CVA8", marks=pytest.mark.slow)])
def test_order_survives_the_impacts_oscillator(method):
    """x'' = -x against a wall at x = -0.5 from x0 = 1 at rest: 3 impacts over T = 12 (the impact
    phase is where an event-driven method loses its order if the collision time or the reset is
    only first/second order)."""
    p = {"CVA4": 4, "CVA6": 6, "CVA8": 8}[method]
    hs, errs = [], []
    for h in IMPACT_H[method]:
        tr = vcirun.simulate("oscillator_wall", method, h=h, T=12.0, q0=[1.0], p0=[0.0])
        assert tr.status == "ok", tr.message
        x, _, ti = oscillator_wall_exact(tr.t, 1.0, 0.0)
        assert len(tr.impacts) == len(ti[ti <= 12.0]) >= 3
        hs.append(h)
        errs.append(float(np.max(np.abs(tr.q[:, 0] - x))))
    slope, used = fit_order(hs, errs)
    assert abs(slope - p) < TOL, f"{method}: slope {slope:.2f} from {['%.2e' % e for e in errs]} (used {used})"


def test_cva6_on_the_cart_pendulum_against_the_exact_reference():
    """Figure 4's setting (beta = 3.2, T = 5, three impacts): CVA6 at h = 1e-2 is ~6 orders of magnitude
    more accurate than CVA (measured L2 8.8e-10 against 4.8e-2), and its impact times agree to 1.6e-11."""
    ref = vcirun.reference("cart_pendulum", T=5.0, beta=3.2)
    out = {}
    for m in ("CVA", "CVA6"):
        tr = vcirun.simulate("cart_pendulum", m, h=1e-2, T=5.0, beta=3.2)
        assert tr.status == "ok" and len(tr.impacts) == 3
        out[m] = (vcirun.l2_error(tr, ref), np.max(np.abs(np.asarray(tr.impacts) - ref.impacts[:3])))
    assert out["CVA6"][0] < 1e-6 and out["CVA6"][0] < 1e-4 * out["CVA"][0], out
    assert out["CVA6"][1] < 1e-7, out


def test_ld_option_on_cva_is_the_named_method():
    a = vcirun.simulate("cart_pendulum", "CVA6", h=3.2e-2, T=2.0, beta=3.2)
    b = vcirun.simulate("cart_pendulum", "CVA", ld="SVC6", h=3.2e-2, T=2.0, beta=3.2)
    assert np.array_equal(a.q, b.q) and np.array_equal(a.p, b.p)
    assert b.method == "CVA[SVC6]"


@pytest.mark.parametrize("method, kwargs, match", [
    ("VCI", dict(ld="SVC6"), "^ld: VCI needs an explicit"),
    ("MCVA", dict(ld="SVC4", mh_order=3), "^ld: the modified Hamiltonian of SVC4"),
    ("CVA", dict(mh_order=3), "^mh_order: option not accepted by method CVA"),
    ("CVA6", dict(ld="SVC"), "^ld: option not accepted by method CVA6"),
    ("CVA", dict(ld="SVD"), "^ld: unknown discrete Lagrangian"),
])
def test_refused_combinations_name_the_field(method, kwargs, match):
    with pytest.raises(ValueError, match=match):
        vcirun.simulate("cart_pendulum", method, h=1e-2, T=0.1, beta=3.2, **kwargs)
