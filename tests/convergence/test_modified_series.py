"""Backward error analysis from the discrete Lagrangian (and the checks behind
items 1 of "What to build"): the symplectic-Euler series, eta for SE1, the exact derivatives of eta
and of the implicit qbar (Appendix A step 2 against finite differences), and the H4-for-SVA claim.

Everything here runs the generated code uncompiled (vcirun.codegen.evaluate.python_module): no numba
compile, the same source text.
"""
from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
import sympy as sp

from vcirun.discrete.lagrangians import LIBRARY, ld_expression
from vcirun.modified import MH_LDS
from vcirun.scenes.registry import get_scene
from vcirun.codegen.evaluate import python_module
from vcirun.modified.series import jet, modified_series, padd, pmul, pscale

SYSTEM = get_scene("cart_pendulum")
PRM = SYSTEM.param_values()
# generic states of the cart-pendulum (nonseparable: M depends on theta)
STATES = [(np.array([0.7, 0.4]), np.array([-1.3, 2.1])), (np.array([3.2, -1.1]), np.array([2.0, -0.7])),
          (np.array([-0.4, 2.5]), np.array([0.3, 1.6]))]


def _terms(mod, q, p, h):
    out = np.empty(4)
    mod.mh_terms(q, p, h, PRM, out)
    return out


def _grad(mod, q, p, h):
    n = len(q)
    u = np.empty(mod.MH_M)
    W = np.empty((mod.MH_M, mod.MH_M))
    g = np.empty(2 * n)
    He = np.empty((2 * n, 2 * n))
    mod.mh_guess(q, p, PRM, u)
    it, val = mod.mh_gradient(q, p, h, PRM, u, W, g, He)
    assert it >= 0
    return val, g, He, u


# ---- the series itself ----------------------------------------------------------------------------
def test_series_n1_is_hlw_symplectic_euler():
    """n = 1: H~ = K - h/2 K_p K_q + h^2/12 (K_pp K_q^2 + K_qq K_p^2 + 4 K_pq K_p K_q) + ... (HLW IX.3),
    and the h^3 term the paper prints (Appendix A, step 5) in one dimension."""
    q, p = 0, 1
    K = lambda *a: jet(a)  # noqa: E731
    H1, H2, H3, H4 = modified_series(1, 4)
    assert H1 == K()
    assert H2 == pscale(pmul(K(q), K(p)), Fraction(-1, 2))
    h3 = padd(padd(pmul(K(p, p), pmul(K(q), K(q))), pmul(K(q, q), pmul(K(p), K(p)))),
              pmul(K(q, p), pmul(K(p), K(q))), 4)
    assert H3 == pscale(h3, Fraction(1, 12))
    # paper: -1/12 (Kqqp Kq Kp^2 + Kqpp Kq^2 Kp + Kqq Kqp Kp^2 + Kqq Kpp Kq Kp + 3 Kqp^2 Kq Kp + Kpp Kqp Kq^2)
    mono = lambda *js: {tuple(sorted(tuple(sorted(j)) for j in js)): Fraction(1)}  # noqa: E731
    h4 = {}
    for m, c in [(mono((q, q, p), (q,), (p,), (p,)), 1), (mono((q, p, p), (q,), (q,), (p,)), 1),
                 (mono((q, q), (q, p), (p,), (p,)), 1), (mono((q, q), (p, p), (q,), (p,)), 1),
                 (mono((q, p), (q, p), (q,), (p,)), 3), (mono((p, p), (q, p), (q,), (q,)), 1)]:
        h4 = padd(h4, m, c)
    assert H4 == pscale(h4, Fraction(-1, 12))


def test_series_mixed_term_contracts_q_slot_with_Kp():
    """n = 2: the mixed term of H3 is 1/3 sum_ij K_{q_i p_j} K_{p_i} K_{q_j} (q-slot <- K_p), not the
    paper's D1D2 eta (D1 eta, D2 eta) read as q-slot <- K_q. (Both agree for n = 1.)"""
    H3 = modified_series(2, 3)[2]
    q0, q1, p0, p1 = 0, 1, 2, 3
    key = tuple(sorted([(q0,), (q1, p0), (p1,)]))  # K_{q0} K_{q1 p0} K_{p1}: i = 1, j = 0
    assert H3[key] == Fraction(1, 3)
    wrong = tuple(sorted([(q1,), (q1, p0), (p0,)]))  # K_{q1} K_{q1 p0} K_{p0}
    assert wrong not in H3


# ---- SE1: eta = H, and the closed-form series --------------------------------------------------------
def _hamiltonian_derivatives():
    Hs, ps = SYSTEM.hamiltonian_symbolic()
    z = list(SYSTEM.q) + list(ps)
    grad = [sp.diff(Hs, v) for v in z]
    hess = [[sp.diff(g, v) for v in z] for g in grad]
    args = (z, SYSTEM.param_symbols)
    return (sp.lambdify(args, Hs), sp.lambdify(args, grad), sp.lambdify(args, hess))


@pytest.mark.parametrize("h", [0.1, 0.01, 1e-4])
def test_se1_eta_is_H_and_series_is_closed_form(h):
    mod = python_module(SYSTEM, "SE1", 3, 4)
    fH, fg, fhess = _hamiltonian_derivatives()
    for q, p in STATES:
        z = list(q) + list(p)
        H = fH(z, PRM)
        g = np.array(fg(z, PRM), float)
        He = np.array(fhess(z, PRM), float)
        Hq, Hp = g[:2], g[2:]
        eta, H2, H3 = _terms(mod, q, p, h)[:3]
        assert abs(eta - H) <= 1e-12 * max(1.0, abs(H))
        assert abs(eta - mod.hamiltonian(q, p, PRM)) <= 1e-12 * max(1.0, abs(H))
        H2_ref = -0.5 * Hq @ Hp
        H3_ref = (Hp @ He[:2, :2] @ Hp + Hq @ He[2:, 2:] @ Hq + 4 * Hp @ He[:2, 2:] @ Hq) / 12
        assert H2 == pytest.approx(H2_ref, rel=1e-11, abs=1e-11)
        assert H3 == pytest.approx(H3_ref, rel=1e-11, abs=1e-11)
        # the n-dimensional slot assignment matters on this nonseparable system
        H3_paper = (Hp @ He[:2, :2] @ Hp + Hq @ He[2:, 2:] @ Hq + 4 * Hq @ He[:2, 2:] @ Hp) / 12
        assert abs(H3_paper - H3_ref) > 1e-3 * abs(H3_ref)


# ---- eta: generating function of the full step, exact derivatives -----------------------------------
@pytest.mark.parametrize("ld", MH_LDS)
def test_eta_generates_the_full_step(ld):
    """H_d^+ = p1 q0 + h eta(q0, p1) generates Phi_h (eqs. 19-24): p0 = p1 + h eta_q(q0, p1) and
    q1 = q0 + h eta_p(q0, p1), with Phi_h the core's full step (compositions for SVA/SVB)."""
    mod = python_module(SYSTEM, ld, 1, 4)
    h = 0.05
    for q0, p0 in STATES:
        q1, p1, v = np.empty(2), np.empty(2), np.empty(2)
        assert mod.ld_step(q0, p0, h, 0.0, PRM, 1e-14, 50, q1, p1, v)[0] >= 0
        _, g, _, _ = _grad(mod, q0, p1, h)
        np.testing.assert_allclose(p1 + h * g[:2], p0, rtol=0, atol=1e-12)
        np.testing.assert_allclose(q0 + h * g[2:], q1, rtol=0, atol=1e-12)


@pytest.mark.parametrize("ld", MH_LDS)
def test_gradient_and_eta_hessian_against_finite_differences(ld):
    """The implicit-function-theorem derivatives are exact: grad H~^{O(h^4)} and eta's Hessian match
    central differences of the values (to the differences' own truncation error)."""
    mod4 = python_module(SYSTEM, ld, 4, 4)
    mod1 = python_module(SYSTEM, ld, 1, 4)
    h = 0.05
    for q, p in STATES[:2]:
        z = np.r_[q, p]
        _, g, He, _ = _grad(mod4, q, p, h)
        f = lambda y: mod4.mh_energy(y[:2].copy(), y[2:].copy(), h, PRM)  # noqa: E731
        geta = lambda y: _grad(mod1, y[:2].copy(), y[2:].copy(), h)[1]  # noqa: E731
        d = 1e-4
        for j in range(4):
            e = np.zeros(4)
            e[j] = d
            fd = (-f(z + 2 * e) + 8 * f(z + e) - 8 * f(z - e) + f(z - 2 * e)) / (12 * d)
            assert g[j] == pytest.approx(fd, rel=1e-8, abs=1e-8)
            fdh = (-geta(z + 2 * e) + 8 * geta(z + e) - 8 * geta(z - e) + geta(z - 2 * e)) / (12 * d)
            np.testing.assert_allclose(He[:, j], fdh, rtol=1e-7, atol=1e-7)


def test_appendix_a_qbar_derivatives():
    """Appendix A step 2 for SVC: D_q qbar, D_p qbar as printed are right; the printed second
    derivatives D_pp qbar and D_qp qbar have the wrong sign (D_qq qbar is right once D_qp is).
    The implicit function theorem on D2 Ld(q, qbar) = p gives D_pp qbar (v1, v2) = -(D22)^-1 D222 ((D22)^-1 v1, (D22)^-1 v2) and
    D_qp qbar = -(D22)^-1 [D122 (., D_p qbar) + D222 (D_q qbar ., D_p qbar .)]; finite differences of
    qbar = q + h eta_p (our exact eta derivatives) decide."""
    h = 0.1
    mod = python_module(SYSTEM, "SVC", 1, 4)
    qa, qb = sp.symbols("qa0:2"), sp.symbols("qb0:2")
    Ld = ld_expression(SYSTEM, LIBRARY["SVC"], qa, qb, h)
    args = (list(qa) + list(qb), SYSTEM.param_symbols)
    D22 = sp.lambdify(args, [[sp.diff(Ld, a, b) for b in qb] for a in qb])
    D12 = sp.lambdify(args, [[sp.diff(Ld, b, a) for a in qa] for b in qb])           # [b, a]
    D222 = sp.lambdify(args, [[[sp.diff(Ld, a, b, c) for c in qb] for b in qb] for a in qb])
    D122 = sp.lambdify(args, [[[sp.diff(Ld, d, a, e) for e in qb] for a in qa] for d in qb])  # [d, a, e]
    D112 = sp.lambdify(args, [[[sp.diff(Ld, d, i, j) for j in qa] for i in qa] for d in qb])  # [d, i, j]

    def qbar(q, p):
        return q + h * _grad(mod, q, p, h)[1][2:]

    q, p = STATES[0]
    qbv = qbar(q, p)
    x = list(q) + list(qbv)
    A = np.array(D22(x, PRM), float)
    Ai = np.linalg.inv(A)
    Qq = -Ai @ np.array(D12(x, PRM), float)      # printed D1 qbar: correct
    Pq = Ai                                      # printed D2 qbar: correct
    T3 = np.array(D222(x, PRM), float)
    Y = np.array(D122(x, PRM), float)
    pp_true = -np.einsum("cd,def,ea,fb->cab", Ai, T3, Pq, Pq)
    qp_true = -np.einsum("cd,dae,eb->cab", Ai, Y, Pq) - np.einsum("cd,def,ea,fb->cab", Ai, T3, Qq, Pq)
    d = 1e-3
    # printed D1D1 qbar (v1, v2) = -D1D2 qbar (D1D2 Ld v1, v2) - (D22)^-1 D1D1D2 Ld (v1, v2)
    #                              - (D22)^-1 D2D1D2 Ld (v1, D1 qbar v2), with D1D2 qbar corrected
    X = np.array(D12(x, PRM), float)
    Z = np.array(D112(x, PRM), float)
    qq_printed = (-np.einsum("cjb,bi->cij", qp_true, X) - np.einsum("cd,dij->cij", Ai, Z)
                  - np.einsum("cd,die,ej->cij", Ai, Y, Qq))
    fd_p, fd_q, fd_pp, fd_qp = (np.empty((2, 2)), np.empty((2, 2)), np.empty((2, 2, 2)), np.empty((2, 2, 2)))
    fd_qq = np.empty((2, 2, 2))
    for a in range(2):
        ea = np.eye(2)[a] * d
        fd_p[:, a] = (qbar(q, p + ea) - qbar(q, p - ea)) / (2 * d)
        fd_q[:, a] = (qbar(q + ea, p) - qbar(q - ea, p)) / (2 * d)
        for b in range(2):
            eb = np.eye(2)[b] * d
            fd_pp[:, a, b] = (qbar(q, p + ea + eb) - qbar(q, p + ea - eb) - qbar(q, p - ea + eb)
                              + qbar(q, p - ea - eb)) / (4 * d * d)
            fd_qp[:, a, b] = (qbar(q + ea, p + eb) - qbar(q + ea, p - eb) - qbar(q - ea, p + eb)
                              + qbar(q - ea, p - eb)) / (4 * d * d)
            fd_qq[:, a, b] = (qbar(q + ea + eb, p) - qbar(q + ea - eb, p) - qbar(q - ea + eb, p)
                              + qbar(q - ea - eb, p)) / (4 * d * d)
    np.testing.assert_allclose(fd_p, Pq, atol=1e-6)   # O(d^2) differences
    np.testing.assert_allclose(fd_q, Qq, atol=1e-6)
    scale_pp, scale_qp = np.abs(pp_true).max(), np.abs(qp_true).max()
    assert scale_pp > 1e-4 and scale_qp > 1e-4
    assert np.abs(fd_pp - pp_true).max() < 1e-3 * scale_pp
    assert np.abs(fd_qp - qp_true).max() < 1e-3 * scale_qp
    scale_qq = np.abs(qq_printed).max()
    assert scale_qq > 1e-4 and np.abs(fd_qq - qq_printed).max() < 1e-3 * scale_qq
    # the printed formulas (same terms, + sign) are off by twice their size
    assert np.abs(fd_pp - (-pp_true)).max() > scale_pp
    assert np.abs(fd_qp - (-qp_true)).max() > scale_qp


def test_H4_of_SVA_does_not_vanish():
    """Section 5.2 claims H4 = 0 for SVA (symmetric method). In the eta-based series the h-dependence
    of eta itself carries part of every power of h: H4[eta_SVA] -> H4[H] (the symplectic-Euler h^3
    functional at H, = SE1's H4) != 0 as h -> 0. The symmetric method's *total* h^3 coefficient does
    vanish, but it is spread over eta, H2, H3 and H4 (test_modified_conservation: the SVA truncation
    without H4 conserves to order 3, with H4 to order 4)."""
    sva = python_module(SYSTEM, "SVA", 4, 4)
    se1 = python_module(SYSTEM, "SE1", 4, 4)
    q, p = STATES[0]
    H4_H = _terms(se1, q, p, 0.01)[3]
    assert abs(H4_H) > 1.0
    H4 = np.array([_terms(sva, q, p, h)[3] for h in (0.04, 0.02, 0.01, 0.005, 0.0025)])
    assert np.all(np.abs(H4) > 0.5 * abs(H4_H))
    assert abs(H4[-1] - H4_H) < 1e-3 * abs(H4_H)
