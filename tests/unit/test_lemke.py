"""Moreau's impact law above LCP_MAX_CONTACTS contacts: Lemke's method (vcirun/collision/impact_law.py,
docs/derivations/contacts.md 1.7), run as plain Python and compiled (the fixture of test_impact_law), against
  * an independent brute-force enumeration of complementary index sets written from the equations
    (every support S: lam_S = -W_SS^-1 q_S, lam = 0 off S, accepted if lam >= 0 and w = q + W lam >= 0)
    on random Delassus matrices G M^-1 G^T of 9 to 12 contacts;
  * scipy's NNLS (the QP of a positive definite W) on the first hit of cradles of 10, 30 and 100 balls,
    a degenerate q (every contact but the first at rest), to 1e-12;
  * a degenerate problem (dependent contacts, impulses not unique): the LCP_DEGENERATE code.
"""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from tests.unit import test_impact_law as til
from tests.unit.test_impact_law import _check_lcp, _cradle, _nnls_lcp, _solve


@pytest.fixture(scope="module", params=["python", "numba"])
def law(request):
    return til._python_unit() if request.param == "python" else til._compiled_unit()


def _enumerate_lcp(W, q):
    """Every solution of w = q + W lam >= 0, lam >= 0, lam . w = 0 by enumeration of the supports."""
    k = len(q)
    sols = []
    for r in range(k + 1):
        for S in itertools.combinations(range(k), r):
            lam = np.zeros(k)
            if S:
                WS = W[np.ix_(S, S)]
                if abs(np.linalg.det(WS)) < 1e-14 * np.max(np.abs(W)) ** len(S):
                    continue
                lam[list(S)] = np.linalg.solve(WS, -q[list(S)])
            w = q + W @ lam
            s = np.max(np.abs(q))
            if np.all(lam >= -1e-12 * s) and np.all(w >= -1e-12 * s):
                sols.append(lam)
    return sols


@pytest.mark.parametrize("seed", range(6))
def test_lemke_matches_enumeration(law, seed):
    rng = np.random.default_rng(seed)
    k = 9 + seed % 4
    n = k + 3
    G = rng.normal(size=(k, n))
    B = rng.normal(size=(n, n))
    Minv = np.linalg.inv(B @ B.T + n * np.eye(n))
    W = G @ Minv @ G.T
    W = 0.5 * (W + W.T)
    um = rng.normal(size=k)
    um[0] = -abs(um[0]) - 0.1
    e = rng.uniform(0, 1, size=k)
    code, lam = _solve(law, W, um, e)
    assert code == law.LCP_UNIQUE, code
    _check_lcp(W, um, e, lam)
    sols = _enumerate_lcp(W, (1 + e) * um)
    assert len(sols) == 1  # positive definite W: a P-matrix, one solution
    assert np.max(np.abs(lam - sols[0])) <= 1e-12 * max(1.0, np.max(np.abs(sols[0])))


@pytest.mark.parametrize("N", [10, 30, 100])
def test_cradle_first_hit(law, N):
    """N touching unit balls, ball 1 arriving at speed 1 (u- = (-1, 0, ..., 0)), e = 1: Moreau's law
    against NNLS to 1e-12 (for N = 3 the velocities (-1/3, 2/3, 2/3))."""
    G = _cradle(N)
    W = G @ G.T
    um = np.zeros(N - 1)
    um[0] = -1.0
    e = np.ones(N - 1)
    code, lam = _solve(law, W, um, e)
    assert code == law.LCP_UNIQUE
    _check_lcp(W, um, e, lam)
    ref = _nnls_lcp(W, (1 + e) * um)
    assert np.max(np.abs(lam - ref)) <= 1e-12 * np.max(ref)
    v = np.zeros(N)
    v[0] = 1.0
    v += G.T @ lam
    assert abs(v.sum() - 1.0) <= 1e-12 and abs(v @ v - 1.0) <= 1e-12 * N  # momentum and energy (e = 1)


def test_degenerate_names_itself(law):
    """Ten contacts on two DOF with one repeated: W singular with the impulse split between copies
    not unique (W_PP singular): LCP_DEGENERATE, a negative code."""
    G = np.array([[0.0, 1.0]] * 2 + [[np.cos(a), np.sin(a)] for a in np.linspace(0.3, 1.2, 8)])
    W = G @ G.T
    um = G @ np.array([0.0, -1.0])
    code, lam = _solve(law, W, um, np.ones(10))
    assert code == law.LCP_DEGENERATE and code < 0 and np.all(lam == 0.0)


def test_lemke_secondary_ray_is_infeasible(law):
    """A point pressed into a zero-width gap (x >= 0 and -x >= 0, restitutions 1 and 0) among eight
    other contacts: lam1 - lam2 >= 2 and lam1 - lam2 <= 1 cannot both hold, Lemke ends on a secondary
    ray: LCP_INFEASIBLE."""
    G = np.array([[1.0, 0.0], [-1.0, 0.0]] + [[0.0, 1.0 + 0.1 * i] for i in range(8)])
    W = G @ G.T
    um = G @ np.array([-1.0, 0.0])
    e = np.array([1.0, 0.0] + [1.0] * 8)
    code, lam = _solve(law, W, um, e)
    assert code == law.LCP_INFEASIBLE and np.all(lam == 0.0)
