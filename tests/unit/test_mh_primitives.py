"""The modified Hamiltonian's building blocks (vcirun.modified.eta) at n > 2.

- Primitives from per-node tensors (d^A M_bc, d^A V at the quadrature nodes of each stage) equal the
  derivatives of ell(q, u) = Ld(q, q + h v(u), h) / h taken directly, for every Ld of MH_LDS.
- The gradient of H~ by reverse mode (plus the implicit-function closure) against central
  differences of H~ itself, on a 3-link pendulum (the cart-pendulum case is in
  tests/convergence/test_modified_series.py).
"""
from __future__ import annotations

from itertools import combinations_with_replacement

import numpy as np
import pytest
import sympy as sp

from vcirun.scenes.registry import get_scene
from vcirun.modified import MH_LDS
from vcirun.modified.eta import StationaryEta
from vcirun.codegen.evaluate import python_module


def _numeric(st, e, point):
    f = sp.lambdify(st.q + st.u + [st.h] + list(st.params), st.explicit(e), "math")
    return float(f(*point))


# (the cradle's diagonal M and the rocking block's zero entries: the per-node path skips the node tensors
# that are identically 0, and must still give every derivative)
@pytest.mark.parametrize("scene, lds", [("double_pendulum", MH_LDS), ("n_pendulum_3", ("SVA", "SVC", "midpoint")),
                                        ("newton_cradle_3", ("SVA", "SVC")), ("rocking_block", ("SVA",))])
def test_per_node_primitives_equal_derivatives_of_ell(scene, lds):
    system = get_scene(scene)
    rng = np.random.default_rng(11)
    for ld in lds:
        st = StationaryEta(system, ld)
        ref = StationaryEta(system, ld, per_node=False)
        assert st.tensor_def and not ref.tensor_def  # the two paths really differ
        dim = st.n + st.m
        point = list(rng.uniform(-1.5, 1.5, dim)) + [0.07] + list(system.param_values())
        checked = 0
        for order in range(4):
            for alpha in combinations_with_replacement(range(dim), order):
                a, b = st.prim(alpha), ref.prim(alpha)
                if a == 0 and b == 0:
                    continue
                va, vb = _numeric(st, a, point), _numeric(ref, b, point)
                assert va == pytest.approx(vb, rel=1e-12, abs=1e-12), (ld, alpha)
                checked += 1
        assert checked >= 5   # (the nonzero ones: 7 for the cradle's diagonal M)


def test_reverse_mode_gradient_against_differences_three_links():
    system = get_scene("n_pendulum_3")
    prm = system.param_values()
    mod = python_module(system, "SVA", 4, 4)
    h = 0.04
    rng = np.random.default_rng(5)
    q, p = rng.uniform(-0.8, 0.8, 3), rng.uniform(-1.5, 1.5, 3)
    z = np.r_[q, p]
    u, W = np.empty(mod.MH_M), np.empty((mod.MH_M, mod.MH_M))
    g, He = np.empty(6), np.empty((0, 0))
    mod.mh_guess(q, p, prm, u)
    it, val = mod.mh_gradient(q, p, h, prm, u, W, g, He)
    assert it >= 0 and val == pytest.approx(mod.mh_energy(q, p, h, prm), rel=1e-13)
    f = lambda y: mod.mh_energy(y[:3].copy(), y[3:].copy(), h, prm)  # noqa: E731
    d = 1e-4
    for j in range(6):
        e = np.zeros(6)
        e[j] = d
        fd = (-f(z + 2 * e) + 8 * f(z + e) - 8 * f(z - e) + f(z - 2 * e)) / (12 * d)
        assert g[j] == pytest.approx(fd, rel=1e-8, abs=1e-8)


@pytest.mark.parametrize("n", [2, 3])
def test_directional_series_equals_index_series(n):
    """The index-free series (contraction trees as directional derivatives along A = (0, K_q) and
    B = (K_p, 0)) equals the n-dimensional jet polynomial of series.modified_series on random jets."""
    from itertools import permutations

    from vcirun.modified.series import directional_series, evaluate, modified_series

    rng = np.random.default_rng(n)
    N = 2 * n
    T = {0: rng.normal(), 1: rng.normal(size=N)}
    for k in (2, 3):
        X = rng.normal(size=(N,) * k)
        T[k] = sum(np.transpose(X, pm) for pm in permutations(range(k))) / len(list(permutations(range(k))))
    D = {"A": np.r_[np.zeros(n), T[1][:n]], "B": np.r_[T[1][n:], np.zeros(n)]}

    def jet(dirs, free=None):
        t = T[len(dirs) + (free is not None)]
        for d in dirs:
            t = t @ D[d]
        return t if free is None else t[free]

    def value(desc):
        if desc[0] == "jet":
            return jet(desc[1]) if desc[1] else T[0]
        return sum(jet(desc[1], j) * jet(desc[2], n + j) for j in range(n))

    for Hi, Ti in zip(modified_series(n, 4), directional_series(4)):
        dense = evaluate(Hi, lambda al: T[len(al)][tuple(al)] if al else T[0])
        assert sum(float(c) * value(d) for c, d in Ti) == pytest.approx(dense, rel=1e-13, abs=1e-14)
