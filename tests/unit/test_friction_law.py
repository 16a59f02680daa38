"""The frictional impact law (vcirun/collision/friction_law.py; docs/derivations/friction.md,
"Frictional impacts"), run as plain Python and compiled (its standalone source, as test_impact_law).

Checked against
  * the energy theorem (F.3): hypothesis over planar rigid bodies (masses, inertias, contact points,
    normal angles, velocities, e and mu drawn), one to six contacts, duplicated and collinear contact
    rows included: no impact increases the kinetic energy, and the result meets the law's conditions
    (written again here from the equations);
  * an independent enumeration of stage 2's pieces for one and two contacts: the law's impulse is one
    of the enumerated solutions, and the only one where the code says LCP_UNIQUE;
  * closed forms derived in the note: Capobianco et al.'s rotating ball (stick at w0 = 10, slip at
    w0 = 50), Housner's plastic corner impact of a rocking block, a rod hitting a floor while sliding
    (friction lifting and pushing in), Kane's example (Newton's law with Coulomb on the final slip
    gains 34 % here, this law loses 97 %), the ladder on which the weighted Newton law (b) with mixed
    restitution gains 3/8 of the energy;
  * mu = 0: impact_law's impulses bit for bit, up to 12 contacts (Lemke's range of impact_law);
    mu -> infinity: every contact with an impulse ends stuck; bad input; 1000 contacts.
"""
from __future__ import annotations

import itertools
import types

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from vcirun.codegen import units

UNIT = "collision/friction_law.py"


def _njit(*args, **kwargs):
    if args and callable(args[0]):
        return args[0]
    return lambda f: f


def _python_unit():
    text = units.standalone_source([UNIT]).replace("from numba import njit", "")
    mod = types.ModuleType("friction_law_python")
    mod.__dict__["njit"] = _njit
    exec(compile(text, UNIT, "exec"), mod.__dict__)
    return mod


def _compiled_unit():
    """The compiled unit, as the exact reference loads it (vcirun.reference_solution.friction_law)."""
    from vcirun.reference_solution.friction_law import friction_law_module

    return friction_law_module()


@pytest.fixture(scope="module", params=["python", "numba"])
def law(request):
    return _python_unit() if request.param == "python" else _compiled_unit()


def _solve(law, W, u, e, mu):
    W = np.ascontiguousarray(W, float)
    u = np.asarray(u, float).copy()
    e = np.asarray(e, float).copy()
    mu = np.asarray(mu, float).copy()
    lam = np.full(u.shape[0], np.nan)
    code = law.friction_impact_law(W, u, e, mu, lam)
    return int(code), lam


def _stage1(law, W, u, e):
    k = len(e)
    lam1 = np.empty(k)
    law.impact_law(np.ascontiguousarray(W[:k, :k]), u[:k].copy(), np.asarray(e, float).copy(), lam1)
    r = np.maximum(u[:k] + W[:k, :k] @ lam1, 0.0)
    return lam1, r


def _check_law(law, W, u, e, mu, lam, tol=1e-9):
    """The law's conditions (docs/derivations/friction.md F.2): u+_n >= 0, (P_i, u+_n,i) on the rebound
    graph of stage 1's lam1 and r, |lam_t| <= mu P, friction opposing a slip; to `tol` times the velocity
    scale max(|u-|, max W_ii |lam|) times max(1, mu)."""
    k = len(e)
    lam1, r = _stage1(law, W, u, e)
    up = u + W @ lam
    P, lt = lam[:k], lam[k:]
    wm = np.max(np.diag(W))
    s = max(np.max(np.abs(u)), wm * np.max(np.abs(lam)), 1e-300) * max(1.0, np.max(mu))
    t = tol * s
    for i in range(k):
        vn, vt = up[i], up[k + i]
        assert P[i] >= 0.0 and vn >= -t, (i, P[i], vn)
        pieces = [abs(vn) <= t and P[i] * wm >= lam1[i] * wm - t,
                  abs(P[i] - lam1[i]) * wm <= t and vn <= r[i] + t,
                  abs(vn - r[i]) <= t and P[i] * wm <= lam1[i] * wm + t,
                  P[i] * wm <= t and vn >= r[i] - t]
        if r[i] <= t:
            pieces[0] = abs(vn) <= t
        assert any(pieces), (i, P[i], lam1[i], vn, r[i])
        assert abs(lt[i]) <= mu[i] * P[i] * (1 + 1e-12), (i, lt[i], mu[i], P[i])
        if mu[i] > 0 and abs(vt) > t and W[k + i, k + i] > 1e-11 * wm:
            assert abs(lt[i] + np.sign(vt) * mu[i] * P[i]) * wm <= t, (i, lt[i], vt, mu[i] * P[i])


def _energy_change(W, u, lam):
    """(F.1): Delta T = lam . u- + 1/2 lam W lam."""
    return float(lam @ u + 0.5 * lam @ W @ lam)


# --- planar rigid bodies ------------------------------------------------------------------------------

def _rows(n_ang, r, body, nb):
    """Normal and tangent rows (3 nb generalized velocities) of a point at offset r of `body` against a
    fixed line with normal angle n_ang: the velocity of the point, v + w x r, along n and t."""
    n = np.array([np.cos(n_ang), np.sin(n_ang)])
    tg = np.array([-n[1], n[0]])
    gn, gt = np.zeros(3 * nb), np.zeros(3 * nb)
    for g, d in ((gn, n), (gt, tg)):
        g[3 * body: 3 * body + 2] = d
        g[3 * body + 2] = r[0] * d[1] - r[1] * d[0]
    return gn, gt


def _system(masses, inertias, contacts, qdot):
    """(W, u, T-) of bodies with diagonal mass matrices and point contacts (body, r, normal angle)."""
    nb = len(masses)
    Mdiag = np.concatenate([[m, m, m * j] for m, j in zip(masses, inertias)])
    G_n, G_t = [], []
    for body, r, ang in contacts:
        gn, gt = _rows(ang, r, body, nb)
        G_n.append(gn)
        G_t.append(gt)
    G = np.array(G_n + G_t)
    W = G @ np.diag(1.0 / Mdiag) @ G.T
    W = 0.5 * (W + W.T)
    return W, G @ qdot, 0.5 * float(qdot @ (Mdiag * qdot))


@st.composite
def _impacts(draw):
    nb = draw(st.integers(1, 2))
    masses = [draw(st.floats(0.05, 20.0)) for _ in range(nb)]
    inertias = [draw(st.floats(0.01, 3.0)) for _ in range(nb)]
    k = draw(st.integers(1, 6))
    floor = draw(st.booleans())                      # every normal vertical: collinear, dependent rows
    contacts = []
    for _ in range(k):
        body = draw(st.integers(0, nb - 1))
        r = (draw(st.floats(-1.0, 1.0)), draw(st.floats(-1.0, 1.0)))
        ang = np.pi / 2 if floor else draw(st.floats(0.0, 2 * np.pi))
        contacts.append((body, r, ang))
    if draw(st.booleans()):                          # a contact declared twice
        contacts.append(contacts[draw(st.integers(0, len(contacts) - 1))])
    qdot = np.array([draw(st.floats(-3.0, 3.0)) for _ in range(3 * nb)])
    W, u, T = _system(masses, inertias, contacts, qdot)
    k = len(contacts)
    keep = [i for i in range(k) if u[i] <= 0.0]      # the contacts of an impact approach or rest
    assume(keep and np.min(u[:k]) < -1e-3 and T > 1e-6)
    rows = keep + [k + i for i in keep]
    W, u = W[np.ix_(rows, rows)], u[rows]
    kk = len(keep)
    same = draw(st.booleans())
    e = np.full(kk, draw(st.floats(0.0, 1.0))) if same else np.array([draw(st.floats(0.0, 1.0)) for _ in keep])
    mu = np.array([draw(st.sampled_from([0.0, 0.1, 0.5, 1.0, 2.0, 3.0, 1e3])) if draw(st.booleans())
                   else draw(st.floats(0.0, 3.0)) for _ in keep])
    return W, u, e, mu, T


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.filter_too_much, HealthCheck.too_slow])
@given(case=_impacts())
def test_no_frictional_impact_increases_the_energy(case):
    """(F.3) on random bodies: Delta T <= 0 up to round-off, and the result meets the law's conditions."""
    law = _compiled_unit()
    W, u, e, mu, T = case
    code, lam = _solve(law, W, u, e, mu)
    assert code >= 0, code
    assert _energy_change(W, u, lam) <= 1e-12 * T
    _check_law(law, W, u, e, mu, lam)


def test_energy_over_random_bodies_python_and_numba(law):
    """The same property, seeded, on both builds: rigid bodies with 1 to 5 contacts, half of them on a
    floor (dependent rows), mixed restitution."""
    rng = np.random.default_rng(11)
    count = 60 if law.__name__ == "friction_law_python" else 1500
    done = 0
    while done < count:
        k = int(rng.integers(1, 6))
        floor = rng.random() < 0.5
        contacts = [(0, tuple(rng.uniform(-1, 1, 2)), np.pi / 2 if floor else rng.uniform(0, 2 * np.pi))
                    for _ in range(k)]
        W, u, T = _system([1.0], [rng.uniform(0.05, 1.0)], contacts, rng.normal(size=3))
        if np.any(u[:k] > 0):
            continue
        e = np.full(k, rng.uniform(0, 1)) if rng.random() < 0.5 else rng.uniform(0, 1, k)
        mu = rng.uniform(0, 2, k)
        code, lam = _solve(law, W, u, e, mu)
        assert code >= 0, (code, k, floor)
        assert _energy_change(W, u, lam) <= 1e-12 * T
        _check_law(law, W, u, e, mu, lam)
        done += 1


# --- an independent enumeration of stage 2 (one and two contacts) -------------------------------------

def _enumerate_stage2(W, u, mu, lam1, r, tol=1e-9):
    """Every (P, lam_t) meeting stage 2's conditions, by its pieces: per contact a normal piece (the four
    of the rebound graph) and a tangential one (stick, slide +, slide -), each a linear system."""
    k = len(mu)
    s = max(np.max(np.abs(u)), 1.0)
    fr = [mu[i] > 0 and W[k + i, k + i] > 1e-11 * np.max(np.diag(W)) for i in range(k)]
    sols = []
    for nm in itertools.product(range(4), repeat=k):
        for tm in itertools.product(range(3), repeat=k):
            A, b = [], []
            for i in range(k):
                eP = np.zeros(2 * k)
                eP[i] = 1.0
                eT = np.zeros(2 * k)
                eT[k + i] = 1.0
                [lambda: (A.append(W[i]), b.append(-u[i])),
                 lambda: (A.append(eP), b.append(lam1[i])),
                 lambda: (A.append(W[i]), b.append(r[i] - u[i])),
                 lambda: (A.append(eP), b.append(0.0))][nm[i]]()
                if not fr[i]:
                    A.append(eT)
                    b.append(0.0)
                elif tm[i] == 0:
                    A.append(W[k + i])
                    b.append(-u[k + i])
                else:
                    sg = 1.0 if tm[i] == 1 else -1.0
                    A.append(eT + sg * mu[i] * eP)
                    b.append(0.0)
            A, b = np.array(A), np.array(b)
            if np.linalg.matrix_rank(A, tol=1e-10) < 2 * k:
                continue
            lam = np.linalg.solve(A, b)
            up = u + W @ lam
            ok = True
            for i in range(k):
                P, vn, vt, lt = lam[i], up[i], up[k + i], lam[k + i]
                ok &= P >= -tol * s and vn >= -tol * s
                ok &= [P >= lam1[i] - tol * s, vn <= r[i] + tol * s, P <= lam1[i] + tol * s,
                       vn >= r[i] - tol * s][nm[i]]
                if fr[i]:
                    ok &= [abs(lt) <= mu[i] * P + tol * s, vt >= -tol * s, vt <= tol * s][tm[i]]
            if ok and not any(np.allclose(W @ lam, W @ x, atol=1e-8 * s) for x in sols):
                sols.append(lam)
    return sols


@pytest.mark.parametrize("k", [1, 2])
def test_matches_an_enumeration_of_the_pieces(law, k):
    rng = np.random.default_rng(100 + k)
    count = (30 // k if law.__name__ == "friction_law_python" else 150)
    unique_seen = several_seen = 0
    done = 0
    while done < count:
        nd = int(rng.integers(2, 2 * k + 2))
        B = rng.normal(size=(nd, 2 * k)) * rng.uniform(0.2, 2.0, size=(nd, 1))
        W = B.T @ B
        u = B.T @ rng.normal(size=nd)
        if np.any(u[:k] > 0) or np.min(np.linalg.eigvalsh(W)) < 1e-3 * np.max(np.diag(W)):
            continue
        e = rng.choice([0.0, 0.3, 1.0], size=k) if rng.random() < 0.5 else rng.uniform(0, 1, k)
        mu = rng.uniform(0, 2, k) if done % 2 else rng.uniform(0, 0.01, k)   # the latter often certified
        code, lam = _solve(law, W, u, e, mu)
        assert code >= 0
        lam1, r = _stage1(law, W, u, e)
        sols = _enumerate_stage2(W, u, mu, lam1, r)
        s = np.max(np.abs(u))
        assert any(np.max(np.abs(W @ (lam - x))) <= 1e-8 * s for x in sols), (lam, sols)
        if code == law.LCP_UNIQUE:
            assert len(sols) == 1, sols
            unique_seen += 1
        else:
            assert code == law.FRIC_SOLVED
            several_seen += len(sols) > 1
        done += 1
    assert unique_seen > 0


# --- closed forms ---------------------------------------------------------------------------------------

CAPO_M, CAPO_R, CAPO_MU, CAPO_G = 1.0, 0.1, 0.2, 9.81


def _capobianco(law, w0):
    m, R = CAPO_M, CAPO_R
    Iz = 0.4 * m * R * R
    vn = np.sqrt(2 * CAPO_G * (1 - R))
    G = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, R]])
    Minv = np.diag([1 / m, 1 / m, 1 / Iz])
    qdot = np.array([0.0, -vn, w0])
    W, u = G @ Minv @ G.T, G @ qdot
    code, lam = _solve(law, W, u, [0.0], [CAPO_MU])
    return code, qdot + Minv @ G.T @ lam, vn


def test_capobianco_rotating_ball_sticks_at_w0_10(law):
    """(2/7) R w0 = 0.285714 <= mu v_n = 0.840428: sticks, xdot+ = -(2/7) R w0, phidot+ = (2/7) w0."""
    code, qp, vn = _capobianco(law, 10.0)
    assert abs(vn - 4.202142) < 1e-6
    assert code == law.LCP_UNIQUE
    assert abs(qp[0] - (-2 / 7 * CAPO_R * 10.0)) <= 1e-12
    assert abs(qp[0] - (-0.285714)) < 1e-6
    assert abs(qp[1]) <= 1e-12
    assert abs(qp[2] - 2 / 7 * 10.0) <= 1e-12
    assert abs(qp[0] + CAPO_R * qp[2]) <= 1e-12        # rolling


def test_capobianco_rotating_ball_slides_at_w0_50(law):
    """1.428571 > 0.840428: slides, xdot+ = -mu v_n, phidot+ = w0 - mu m v_n R / I."""
    code, qp, vn = _capobianco(law, 50.0)
    assert code == law.LCP_UNIQUE
    assert abs(qp[0] - (-CAPO_MU * vn)) <= 1e-12
    assert abs(qp[2] - (50.0 - CAPO_MU * vn * CAPO_R / (0.4 * CAPO_R ** 2))) <= 1e-11
    assert abs(qp[0] - (-0.840428)) < 1e-6 and abs(qp[2] - 28.989288) < 1e-6


@pytest.mark.parametrize("b,h", [(0.3, 1.0), (0.5, 1.5), (1.0, 2.0), (0.2, 0.5)])
def test_housner_plastic_corner_impact(law, b, h):
    """Rocking about the left corner, the right one lands (e = 0, friction enough to stick):
    w+/w- = 1 - 3/2 sin^2 alpha, alpha = atan(b/h); the left corner lifts; the cone needs
    mu >= 3 sin a cos a / (4 - 3 sin^2 a). Below that bound the landing corner slides."""
    m = 2.0
    Iz = m * (b * b + h * h) / 3
    Minv = np.diag([1 / m, 1 / m, 1 / Iz])
    rows = lambda cx, cy: (np.array([0.0, 1.0, cx]), np.array([1.0, 0.0, -cy]))   # noqa: E731
    (nR, tR), (nL, tL) = rows(b, -h), rows(-b, -h)
    G = np.array([nR, nL, tR, tL])
    w = -1.3
    qdot = w * np.array([-h, b, 1.0])
    W, u = G @ Minv @ G.T, G @ qdot
    alpha = np.arctan(b / h)
    need = 3 * np.sin(alpha) * np.cos(alpha) / (4 - 3 * np.sin(alpha) ** 2)
    code, lam = _solve(law, W, u, [0.0, 0.0], [need * 1.5, need * 1.5])
    assert code >= 0
    qp = qdot + Minv @ G.T @ lam
    assert abs(qp[2] / w - (1 - 1.5 * np.sin(alpha) ** 2)) <= 1e-12
    up = u + W @ lam
    assert abs(up[0]) <= 1e-12 and abs(up[2]) <= 1e-12        # the landing corner sticks
    assert up[1] > 0 and abs(lam[1]) <= 1e-14                          # the old pivot lifts
    assert abs(abs(lam[2]) / lam[0] - need) <= 1e-12
    code, lam = _solve(law, W, u, [0.0, 0.0], [need * 0.5, need * 0.5])
    up = u + W @ lam
    assert code >= 0 and abs(up[2]) > 1e-3 and abs(abs(lam[2]) - 0.5 * need * lam[0]) <= 1e-12


def _rod(law, phi, qdot, e, mu, m=2.0, l=0.5):
    S, C = np.sin(phi), np.cos(phi)
    G = np.array([[0.0, 1.0, -l * C], [1.0, 0.0, l * S]])
    Minv = np.diag([1 / m, 1 / m, 3 / (m * l * l)])
    W, u = G @ Minv @ G.T, G @ np.asarray(qdot, float)
    code, lam = _solve(law, W, u, [e], [mu])
    return code, u, lam, u + W @ lam


@pytest.mark.parametrize("phi_deg,qdot,e,mu", [
    (30, (4.0, -2.0, 0.0), 0.5, 0.3),     # slip +: friction lifts -> Routh's u+_n = e |u-_n|
    (50, (5.0, -1.0, 1.0), 0.8, 0.4),
    (30, (4.0, -2.0, 0.0), 0.0, 0.3),
    (30, (-1.0, -2.0, 0.0), 0.5, 0.3),    # slip -: friction pushes in, rebound slowed
    (30, (-0.3, -2.0, 0.0), 0.2, 0.3),
    (30, (-1.0, -2.0, 0.0), 0.0, 0.3),    # ... to zero
    (20, (-3.0, -1.0, 2.0), 0.9, 0.6),
])
def test_rod_hitting_a_floor_while_sliding(law, phi_deg, qdot, e, mu):
    """The closed forms of F.5 (the slip keeps its sign through the impact in each case)."""
    m, l = 2.0, 0.5
    phi = np.radians(phi_deg)
    S, C = np.sin(phi), np.cos(phi)
    code, u, lam, up = _rod(law, phi, qdot, e, mu, m, l)
    assert code == law.LCP_UNIQUE
    s = np.sign(u[1])
    un = abs(u[0])
    Wnn = (1 + 3 * C * C) / m
    kappa = (1 + 3 * C * C + 3 * s * mu * S * C) / m
    assert kappa > 0
    if s > 0:
        P, upn = (1 + e) * un / kappa, e * un
    else:
        upn = un * ((1 + e) * kappa / Wnn - 1)
        P = (1 + e) * un / Wnn
        if upn < 0:
            P, upn = un / kappa, 0.0
    upt = u[1] - (3 * S * C + s * mu * (1 + 3 * S * S)) * P / m
    assert s * upt > 0                                          # slides throughout
    assert abs(lam[0] - P) <= 1e-12 * P
    assert abs(lam[1] + s * mu * P) <= 1e-12 * P
    assert abs(up[0] - upn) <= 1e-12 * un and abs(up[1] - upt) <= 1e-12 * un


def _double_pendulum(th1, th2):
    """Two uniform rods of mass 1, length 1, hinged at a fixed point; angles from the downward vertical.
    (M, normal row, tangent row) of the tip: its height and abscissa differentiated."""
    M = np.array([[4 / 3, 0.5 * np.cos(th1 - th2)], [0.5 * np.cos(th1 - th2), 1 / 3]])
    return M, np.array([np.sin(th1), np.sin(th2)]), np.array([np.cos(th1), np.cos(th2)])


def test_kane_example(law):
    """Newton's law with Coulomb on the final slip (tangential restitution 0) gains 34 % of the energy
    on Kane's kind of double pendulum (F.1); this law loses 97 % there (F.5)."""
    M, gn, gt = _double_pendulum(np.radians(60), np.radians(40))
    G = np.array([gn, gt])
    W = G @ np.linalg.inv(M) @ G.T
    qdot = np.array([0.0, -1.0])
    u, T = G @ qdot, 0.5 * qdot @ M @ qdot
    e, mu = 0.5, 0.5
    # Kane's law, written out: stick if the impulse to u+ = (e |u-_n|, 0) lies in the cone
    lam_n = np.linalg.solve(W, np.array([-e * u[0], 0.0]) - u)
    assert lam_n[0] > 0 and abs(lam_n[1]) <= mu * lam_n[0]
    gain = _energy_change(W, u, lam_n)
    assert abs(gain - 0.056668) < 1e-6 and gain / T > 0.33
    code, lam = _solve(law, W, u, [e], [mu])
    assert code == law.LCP_UNIQUE
    dT = _energy_change(W, u, lam)
    assert abs(dT - (-0.161503)) < 1e-6
    up = u + W @ lam
    lam1, r = _stage1(law, W, u, [e])
    assert abs(lam[0] - lam1[0]) <= 1e-15 * lam1[0] and 0 < up[0] < r[0] and abs(up[1]) <= 1e-14


def test_weighted_newton_law_gains_energy_with_mixed_restitution(law):
    """The ladder of F.1: smooth elastic wall (e = 1, mu = 0), rough plastic floor (e = 0, mu = 1),
    phi = 30 deg, qdot- = (-1, -1/2, -1/2). Law (b) gives qdot+ = (5/8, 5 sqrt 3/8, 5/4) with admissible
    impulses and T+ = 25/24 > T- = 2/3; this law loses energy."""
    s3 = np.sqrt(3.0)
    G = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, -s3 / 2], [0.0, 1.0, s3 / 2], [1.0, 0.0, -0.5]])
    Mdiag = np.array([1.0, 1.0, 1 / 3])
    qdot = np.array([-1.0, -0.5, -0.5])
    W, u = G @ np.diag(1 / Mdiag) @ G.T, G @ qdot
    T = 0.5 * qdot @ (Mdiag * qdot)
    assert abs(T - 2 / 3) < 1e-15
    # law (b): u+_A,n = -u-_A,n (e = 1); the floor sticks, u+_B = 0 (e = 0)
    qp = np.linalg.solve(G[[0, 1, 3]], np.array([-u[0], 0.0, 0.0]))
    assert np.allclose(qp, [5 / 8, 5 * s3 / 8, 5 / 4], atol=1e-14)
    lam_b = np.zeros(4)                                               # no tangential impulse at the wall
    lam_b[[0, 1, 3]] = np.linalg.solve(G[[0, 1, 3]].T, Mdiag * (qp - qdot))
    assert lam_b[0] > 0 and lam_b[1] > 0 and abs(lam_b[2]) < 1e-12 and abs(lam_b[3]) <= 1.0 * lam_b[1]
    assert abs(0.5 * qp @ (Mdiag * qp) - 25 / 24) < 1e-14            # a gain of 3/8
    code, lam = _solve(law, W, u, [1.0, 0.0], [0.0, 1.0])
    assert code >= 0
    assert _energy_change(W, u, lam) < -0.3 * T
    _check_law(law, W, u, np.array([1.0, 0.0]), np.array([0.0, 1.0]), lam)


def test_uncoupled_contact_bounces_by_newton_and_sticks_without_tangential_restitution(law):
    """A ball (W_nt = 0), e = 0.8, enough friction: u+_n = -e u-_n, u+_t = 0 (law (b) would give -e u-_t)."""
    m, R = 0.3, 0.05
    G = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, R]])
    Minv = np.diag([1 / m, 1 / m, 1 / (0.4 * m * R * R)])
    W, u = G @ Minv @ G.T, G @ np.array([0.4, -2.0, 3.0])
    code, lam = _solve(law, W, u, [0.8], [1.0])
    up = u + W @ lam
    assert code == law.LCP_UNIQUE
    assert abs(up[0] - 0.8 * 2.0) <= 1e-14 and abs(up[1]) <= 1e-14
    assert abs(lam[0] - 1.8 * 2.0 * m) <= 1e-14


# --- limits: mu = 0, mu -> infinity ------------------------------------------------------------------------

@pytest.mark.parametrize("k", [1, 2, 3, 5, 8, 9, 12])
def test_mu_zero_is_impact_law_bit_for_bit(law, k):
    rng = np.random.default_rng(7 * k)
    for trial in range(5):
        n = k + 2
        Gn = rng.normal(size=(k, n))
        Gt = rng.normal(size=(k, n)) if trial % 2 else np.zeros((k, n))   # zero tangent rows too
        G = np.vstack([Gn, Gt])
        B = rng.normal(size=(n, n))
        Minv = np.linalg.inv(B @ B.T + n * np.eye(n))
        W = G @ Minv @ G.T
        W = 0.5 * (W + W.T)
        u = G @ rng.normal(size=n)
        u[0] = -abs(u[0]) - 0.1
        e = rng.uniform(0, 1, k)
        lam1 = np.empty(k)
        c1 = law.impact_law(np.ascontiguousarray(W[:k, :k]), u[:k].copy(), e.copy(), lam1)
        code, lam = _solve(law, W, u, e, np.zeros(k))
        assert code == c1
        assert np.array_equal(lam[:k], lam1) and np.all(lam[k:] == 0.0)
        if trial % 2 == 0:       # zero tangent rows drop friction whatever mu
            code, lam = _solve(law, W, u, e, np.full(k, 0.7))
            assert code == c1 and np.array_equal(lam[:k], lam1) and np.all(lam[k:] == 0.0)


def test_large_mu(law):
    """mu -> infinity (F.2): contacts whose friction does not couple into the normal direction (balls on a
    floor, W_nt = 0) all end stuck at mu = 1e6. On bodies (one to three contacts, dependent rows from two
    on) at mu = 1e3 a contact can still slide, but only with |lam_t| = mu P, i.e. a normal impulse of
    order 1/mu (friction lifts it, as in Routh's analysis): every contact with P above 10 max |lam| / mu
    ends stuck, and the energy does not grow."""
    rng = np.random.default_rng(3)
    k, R, m = 5, 0.1, 0.5
    Iz = 0.4 * m * R * R
    W = np.diag(np.concatenate([np.full(k, 1 / m), np.full(k, 1 / m + R * R / Iz)]))
    u = np.concatenate([-rng.uniform(0.5, 3, k), rng.uniform(-5, 5, k)])
    code, lam = _solve(law, W, u, rng.uniform(0, 1, k), np.full(k, 1e6))
    up = u + W @ lam
    assert code == law.LCP_UNIQUE and np.max(np.abs(up[k:])) <= 1e-14 * np.max(np.abs(u))
    done = 0
    while done < (20 if law.__name__ == "friction_law_python" else 300):
        k = int(rng.integers(1, 4))
        contacts = [(0, tuple(rng.uniform(-1, 1, 2)), rng.uniform(0, 2 * np.pi)) for _ in range(k)]
        W, u, T = _system([1.0], [0.3], contacts, rng.normal(size=3))
        if np.any(u[:k] > 0):
            continue
        mu = 1e3
        code, lam = _solve(law, W, u, rng.uniform(0, 1, k), np.full(k, mu))
        assert code >= 0
        up = u + W @ lam
        # the law's own accuracy (its check): impulses that cancel (G^T lam = 0) can be of order mu
        s = 1e-10 * mu * max(np.max(np.abs(u)), np.max(np.diag(W)) * np.max(np.abs(lam)))
        for i in range(k):
            if lam[i] > 10 * np.max(np.abs(lam)) / mu:     # a sliding contact has P = |lam_t| / mu
                assert abs(up[k + i]) <= s, (i, up, lam)
        assert _energy_change(W, u, lam) <= 1e-12 * T
        done += 1


# --- input, sizes -------------------------------------------------------------------------------------------

def test_bad_input(law):
    W = np.array([[2.0, 0.1, 0.3, 0.0], [0.1, 2.0, 0.0, 0.2], [0.3, 0.0, 1.0, 0.0], [0.0, 0.2, 0.0, 1.0]])
    u = np.array([-1.0, -0.5, 0.2, 0.1])
    ok = (np.array([0.5, 0.5]), np.array([0.3, 0.3]))
    assert _solve(law, W, u, *ok)[0] >= 0
    bad = [(W, u, [0.5, 1.5], ok[1]), (W, u, ok[0], [0.3, -0.1]), (W, u, ok[0], [np.nan, 0.3]),
           (W, np.array([-1.0, np.nan, 0.2, 0.1]), *ok), (W[:3, :3], u[:3], *ok), (W, u, [0.5], [0.3]),
           (W + np.triu(np.full((4, 4), 1e-3), 1), u, *ok)]
    Wn = W.copy()
    Wn[1, 1] = 0.0
    Wt = W.copy()
    Wt[3, 3] = -1.0
    bad += [(Wn, u, *ok), (Wt, u, *ok)]
    for W_, u_, e_, mu_ in bad:
        lam = np.full(len(u_), np.nan)
        code = law.friction_impact_law(np.ascontiguousarray(W_, float), np.asarray(u_, float),
                                       np.asarray(e_, float), np.asarray(mu_, float), lam)
        assert code == law.LCP_BAD_INPUT
        assert np.all(lam == 0.0)


def test_case_codes(law):
    assert law.FRIC_SOLVED not in (law.LCP_UNIQUE, law.LCP_SINGULAR_UNIQUE, law.LCP_MIN_NORM)
    assert law.FRIC_SOLVED > 0


def test_thousand_contacts():
    """k = 1000: a thousand balls landing on a floor with spin (one group each), and one coupled group of
    up to 59 contacts (a row of 30 discs, each on the floor and touching its neighbour)."""
    law = _compiled_unit()
    rng = np.random.default_rng(5)
    k = 1000
    R, m = 0.05, 0.2
    Iz = 0.4 * m * R * R
    W = np.zeros((2 * k, 2 * k))
    for i in range(k):
        W[i, i] = 1 / m
        W[k + i, k + i] = 1 / m + R * R / Iz
    u = np.concatenate([-rng.uniform(0.5, 2.0, k), rng.uniform(-2, 2, k)])
    code, lam = _solve(law, W, u, np.full(k, 0.3), np.full(k, 0.4))
    assert code == law.LCP_UNIQUE
    assert _energy_change(W, u, lam) < 0
    # a chain of discs on a floor: disc j touches the floor (contact j) and disc j + 1 (contact nd + j)
    nd = 30
    contacts = []
    G_n, G_t = [], []
    for j in range(nd):
        gn, gt = np.zeros(3 * nd), np.zeros(3 * nd)
        gn[3 * j + 1] = 1.0
        gt[3 * j], gt[3 * j + 2] = 1.0, R
        G_n.append(gn)
        G_t.append(gt)
    for j in range(nd - 1):
        gn, gt = np.zeros(3 * nd), np.zeros(3 * nd)
        gn[3 * (j + 1)], gn[3 * j] = 1.0, -1.0
        gt[3 * (j + 1) + 1], gt[3 * j + 1] = 1.0, -1.0
        gt[3 * (j + 1) + 2], gt[3 * j + 2] = -R, -R     # (v_j+1 - R w_j+1) - (v_j + R w_j), along y
        G_n.append(gn)
        G_t.append(gt)
    G = np.array(G_n + G_t)
    Mdiag = np.tile([m, m, Iz], nd)
    qdot = rng.normal(size=3 * nd)
    qdot[1::3] = -np.abs(qdot[1::3]) - 0.5
    W2, u2 = G @ np.diag(1 / Mdiag) @ G.T, G @ qdot
    kk = len(G_n)
    keep = [i for i in range(kk) if u2[i] <= 0]
    rows = keep + [kk + i for i in keep]
    W2, u2 = W2[np.ix_(rows, rows)], u2[rows]
    contacts = len(keep)
    code, lam = _solve(law, W2, u2, np.full(contacts, 0.5), np.full(contacts, 0.6))
    assert code >= 0
    assert _energy_change(W2, u2, lam) <= 1e-12 * 0.5 * qdot @ (Mdiag * qdot)
    _check_law(law, W2, u2, np.full(contacts, 0.5), np.full(contacts, 0.6), lam)


def test_unit_needs_no_generated_name():
    u = units.Unit(UNIT)
    units.check_unit(u)
    assert set(u.imports) == {"vcirun.collision.impact_law"}
    assert "friction_impact_law" in u.provides and "FRIC_SOLVED" in u.provides


def test_reference_wrapper():
    """vcirun.reference_solution.friction_law: the same compiled unit, compiled once per process, Python-callable."""
    from vcirun.reference_solution import friction_law as friction

    mod = friction.friction_law_module()
    assert friction.friction_law_module() is mod
    m, R = 1.0, 0.1
    W = np.diag([1 / m, 1 / m + R * R / (0.4 * m * R * R)])
    u = [-4.202142, 5.0]
    code, lam = friction.friction_impact(W, u, [0.0], [0.2])
    assert friction.code_name(code) == "LCP_UNIQUE"
    ref_code, ref = _solve(_compiled_unit(), W, u, [0.0], [0.2])
    assert code == ref_code and np.array_equal(lam, ref)
    code, lam = friction.friction_impact(W, u, [0.0], [-1.0])
    assert friction.code_name(code) == "LCP_BAD_INPUT" and np.all(lam == 0.0)
    assert {n for n in friction.CODES} <= set(dir(mod))


@pytest.mark.parametrize("k", [20, 50])
def test_coupled_groups_of_many_contacts(k):
    """A random mechanism of 2k + 3 degrees of freedom with k contacts, every row coupled (one Lemke
    problem of up to 6k unknowns), mixed restitution: a solution of the law that loses energy."""
    law = _compiled_unit()
    rng = np.random.default_rng(k)
    n = 2 * k + 3
    G = rng.normal(size=(2 * k, n))
    B = rng.normal(size=(n, n))
    Minv = np.linalg.inv(B @ B.T + n * np.eye(n))
    W = G @ Minv @ G.T
    W = 0.5 * (W + W.T)
    qdot = rng.normal(size=n)
    u = G @ qdot
    keep = [i for i in range(k) if u[i] <= 0]
    rows = keep + [k + i for i in keep]
    W, u = W[np.ix_(rows, rows)], u[rows]
    kk = len(keep)
    e, mu = rng.uniform(0, 1, kk), rng.uniform(0, 1.5, kk)
    code, lam = _solve(law, W, u, e, mu)
    assert code >= 0
    assert _energy_change(W, u, lam) < 0
    _check_law(law, W, u, e, mu, lam)
