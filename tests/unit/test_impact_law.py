"""The impact law of several contacts (vcirun/collision/impact_law.py; docs/derivations/contacts.md, section 1).

The unit is a numba source unit; every test runs it twice: its text (with the linear algebra it
calls, vcirun.codegen.units.standalone_source) executed with `njit` replaced by the identity (plain
Python), and compiled by numba (the file imported from the kernel cache directory, so numba's
on-disk cache applies). The LCP

    w = (1 + e) u- + W lam >= 0,  lam >= 0,  lam . w = 0,      u+ = u- + W lam,

is checked against
  * hand-derived cases: Newton's cradle (e = 1 and e < 1), one contact (the closed formula, bit for
    bit), a duplicated constraint, a point hitting a corner of three walls (more contacts than DOF),
    an infeasible zero-width gap;
  * an independent solver for random positive definite W: the LCP of a symmetric positive definite W
    is the QP min 1/2 lam^T W lam + q^T lam over lam >= 0, i.e. with W = L L^T the nonnegative least
    squares problem min |L^T lam + L^-1 q| (scipy.optimize.nnls);
  * for random singular W (k contacts, n < k DOF): feasibility by a linear program (scipy linprog:
    for a positive semidefinite W the LCP is solvable iff {lam >= 0, q + W lam >= 0} is nonempty), and
    the least-norm solution by SLSQP on min |lam|^2 over the solution set.
"""
from __future__ import annotations

import hashlib
import importlib.util
import sys
import types

import numpy as np
import pytest
from scipy.optimize import linprog, minimize, nnls

from vcirun.codegen import units
from vcirun.codegen.build import cache_dir

UNIT = "collision/impact_law.py"
CODES = ("LCP_UNIQUE", "LCP_SINGULAR_UNIQUE", "LCP_MIN_NORM", "LCP_INFEASIBLE", "LCP_BAD_INPUT", "LCP_DEGENERATE")
PROVIDES = ("impact_law", "lemke", "LCP_MAX_CONTACTS", "LCP_RANK_TOL", "LCP_FEAS_TOL", "LCP_SYM_TOL", "LEMKE_PIVOT_TOL",
            "LEMKE_MAX_PIVOTS") + CODES


def _njit(*args, **kwargs):
    if args and callable(args[0]):
        return args[0]
    return lambda f: f


def _python_unit():
    text = units.standalone_source([UNIT]).replace("from numba import njit", "")
    mod = types.ModuleType("impact_law_python")
    mod.__dict__["njit"] = _njit
    exec(compile(text, UNIT, "exec"), mod.__dict__)
    return mod


def _compiled_unit():
    text = units.standalone_source([UNIT])
    key = hashlib.sha256(text.encode()).hexdigest()[:16]
    path = cache_dir() / f"unit_impact_law_{key}.py"
    if not path.exists():
        tmp = path.with_suffix(".tmp")
        tmp.write_text(text)
        tmp.replace(path)
    name = f"vcirun_unit_impact_law_{key}"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, path)
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod
        spec.loader.exec_module(mod)
    return sys.modules[name]


def _from_python(fn):
    """fn callable from Python: a unit's private function is compiled without numba's Python entry
    (vcirun.codegen.units.check_wrappers), so the compiled one is called from a jitted caller."""
    if not hasattr(fn, "py_func"):
        return fn
    from numba import njit

    @njit
    def call(*args):
        return fn(*args)
    return call


@pytest.fixture(scope="module", params=["python", "numba"])
def law(request):
    return _python_unit() if request.param == "python" else _compiled_unit()


def _solve(law, W, um, e):
    W = np.ascontiguousarray(W, float)
    um = np.asarray(um, float).copy()
    e = np.asarray(e, float).copy()
    lam = np.full(um.shape[0], np.nan)
    code = law.impact_law(W, um, e, lam)
    return int(code), lam


def _check_lcp(W, um, e, lam, tol=1e-12):
    """The LCP conditions, with u+ = u- + W lam, relative to the size of (1 + e) u-."""
    um, e = np.asarray(um, float), np.asarray(e, float)
    w = (1 + e) * um + W @ lam
    s = max(np.max(np.abs((1 + e) * um)), 1e-300)
    assert np.all(lam >= 0.0), lam
    assert np.all(w >= -tol * s), w
    assert np.max(np.abs(lam * w)) <= tol * s * max(np.max(lam), 1e-300), (lam, w)


def _cradle(N):
    """G (N-1, N) of N touching unit balls on a line: phi_i = x_{i+1} - x_i - d >= 0."""
    G = np.zeros((N - 1, N))
    for i in range(N - 1):
        G[i, i], G[i, i + 1] = -1.0, 1.0
    return G


def _nnls_lcp(W, q):
    """Independent solution of the LCP q + W lam >= 0, lam >= 0, complementary, for SPD W."""
    L = np.linalg.cholesky(W)
    lam, _ = nnls(L.T, -np.linalg.solve(L, q), maxiter=50 * W.shape[0])
    return lam


# --- the unit itself ------------------------------------------------------------------------------

def test_unit_needs_no_generated_name():
    """It defines the names the header declares and calls only the linear algebra unit."""
    u = units.UNIT[UNIT]
    units.check_unit(u)
    assert set(u.provides) == set(PROVIDES)
    assert u.imports == {"vcirun.maps.linalg": ("solve_small",)}


def test_case_codes_are_distinct(law):
    vals = [getattr(law, c) for c in CODES]
    assert len(set(vals)) == len(vals)
    assert law.LCP_UNIQUE == 0 and law.LCP_INFEASIBLE < 0 and law.LCP_BAD_INPUT < 0
    assert law.LCP_SINGULAR_UNIQUE > 0 and law.LCP_MIN_NORM > 0


# --- Newton's cradle ------------------------------------------------------------------------------

def test_newton_cradle_elastic(law):
    """Three equal unit balls, contacts between neighbours, the first approaching at speed 1, e = 1.

    phi_1 = x2 - x1 - d, phi_2 = x3 - x2 - d, so G = [[-1, 1, 0], [0, -1, 1]], M = I,
    W = G G^T = [[2, -1], [-1, 2]], v- = (1, 0, 0), u- = G v- = (-1, 0), q = (1 + e) u- = (-2, 0).
    Both contacts active: W lam = (2, 0) gives lam = (4/3, 2/3) > 0, and w = 0, so this is the LCP's
    (unique, W is positive definite) solution. v+ = v- + G^T lam = (1 - 4/3, 4/3 - 2/3, 2/3)
    = (-1/3, 2/3, 2/3): u+ = (1, 0) = -e u-; momentum sum(v) = 1 and energy 1/2 before and after.
    (Moreau's simultaneous law, not the sequential textbook answer (0, 0, 1).)"""
    G = _cradle(3)
    W = G @ G.T
    v = np.array([1.0, 0.0, 0.0])
    um = G @ v
    code, lam = _solve(law, W, um, [1.0, 1.0])
    assert code == law.LCP_UNIQUE
    assert np.max(np.abs(lam - [4 / 3, 2 / 3])) <= 1e-12
    vp = v + G.T @ lam
    assert np.max(np.abs(vp - [-1 / 3, 2 / 3, 2 / 3])) <= 1e-12
    assert abs(vp.sum() - v.sum()) <= 1e-14                       # momentum
    assert abs(0.5 * vp @ vp - 0.5 * v @ v) <= 1e-14               # energy, e = 1
    _check_lcp(W, um, [1.0, 1.0], lam)


@pytest.mark.parametrize("e", [0.0, 0.5, 0.9])
def test_newton_cradle_restitution(law, e):
    """Same cradle, e < 1 on both contacts. Both active: W lam = (1 + e)(1, 0) gives lam = (1 + e)(2/3,
    1/3) > 0, so u+ = -e u- = (e, 0): v2 - v1 = e, v3 = v2, and momentum v1 + 2 v2 = 1 give
    v+ = ((1 - 2e)/3, (1 + e)/3, (1 + e)/3). Energy loss = -1/2 sum lam_i (1 - e_i) u-_i
    (docs/derivations/contacts.md, 1.4) = (1 - e^2)/3."""
    G = _cradle(3)
    W = G @ G.T
    v = np.array([1.0, 0.0, 0.0])
    um = G @ v
    code, lam = _solve(law, W, um, [e, e])
    assert code == law.LCP_UNIQUE
    vp = v + G.T @ lam
    assert np.max(np.abs(vp - [(1 - 2 * e) / 3, (1 + e) / 3, (1 + e) / 3])) <= 1e-12
    assert abs(vp.sum() - 1.0) <= 1e-14
    loss = 0.5 * v @ v - 0.5 * vp @ vp
    assert abs(loss - (1 - e * e) / 3) <= 1e-14
    assert abs(loss + 0.5 * np.sum(lam * (1 - e) * um)) <= 1e-14
    _check_lcp(W, um, [e, e], lam)


def test_newton_cradle_mixed_restitution(law):
    """Different e on the two contacts (0.3, 0.8): against the independent NNLS solve."""
    G = _cradle(3)
    W = G @ G.T
    um = G @ np.array([1.0, 0.0, 0.0])
    e = np.array([0.3, 0.8])
    code, lam = _solve(law, W, um, e)
    assert code == law.LCP_UNIQUE
    assert np.max(np.abs(lam - _nnls_lcp(W, (1 + e) * um))) <= 1e-12
    _check_lcp(W, um, e, lam)


# --- one contact: the closed formula --------------------------------------------------------------

@pytest.mark.parametrize("e", [1.0, 0.9, 0.37, 0.0])
def test_one_contact_is_the_formula(law, e, rng):
    for _ in range(20):
        W = np.array([[10 ** rng.uniform(-3, 3)]])
        u = -10 ** rng.uniform(-4, 4)
        code, lam = _solve(law, W, [u], [e])
        assert code == law.LCP_UNIQUE
        assert lam[0] == -(1.0 + e) * u / W[0, 0]  # bit for bit
        if e == 1.0:
            assert lam[0] == -2.0 * u / W[0, 0]     # R^CVA's multiplier (cva_lambda), bit for bit
    for u in (0.0, 1e-300, 2.5):                   # at rest or separating: no impulse
        code, lam = _solve(law, np.array([[2.0]]), [u], [e])
        assert code == law.LCP_UNIQUE and lam[0] == 0.0


# --- random positive definite W against NNLS ------------------------------------------------------

def _random_spd(rng, k):
    B = rng.normal(size=(k, k + rng.integers(0, 3)))
    W = B @ B.T + 0.05 * np.eye(k)
    return W * 10 ** rng.uniform(-2, 2)


def test_random_positive_definite_against_nnls(law, rng):
    count = 40 if law.__name__ == "impact_law_python" else 400
    seen_active = set()
    for trial in range(count):
        k = int(rng.integers(2, 9 if trial % 4 == 0 else 6))
        W = _random_spd(rng, k)
        um = rng.normal(size=k) * 10 ** rng.uniform(-2, 2)
        e = rng.uniform(0, 1, size=k)
        if trial % 5 == 0:
            e[rng.integers(0, k)] = 1.0
            e[rng.integers(0, k)] = 0.0
        code, lam = _solve(law, W, um, e)
        assert code == law.LCP_UNIQUE
        ref = _nnls_lcp(W, (1 + e) * um)
        scale = max(np.max(np.abs(ref)), 1e-300)
        assert np.max(np.abs(lam - ref)) <= 1e-9 * scale * np.linalg.cond(W) ** 0.5, (W, um, e, lam, ref)
        _check_lcp(W, um, e, lam, tol=1e-10)
        seen_active.add(int(np.count_nonzero(lam)))
    assert len(seen_active) >= 3  # the cases cover several active-set sizes


def test_separating_contacts_get_no_impulse_unless_coupled(law):
    """Decoupled contacts (W diagonal): a separating one gets 0, an approaching one Newton's impulse.
    Coupled: contact 2 separates slowly but contact 1's impulse would drive it into approach, so
    the LCP gives it an impulse too."""
    code, lam = _solve(law, np.diag([2.0, 3.0]), [-1.0, 0.5], [0.5, 0.5])
    assert code == law.LCP_UNIQUE and lam[1] == 0.0 and abs(lam[0] - 0.75) <= 1e-15
    W = np.array([[1.0, -0.9], [-0.9, 1.0]])
    um, e = np.array([-1.0, 0.1]), np.array([1.0, 0.0])
    code, lam = _solve(law, W, um, e)
    assert code == law.LCP_UNIQUE and lam[1] > 0.0
    assert np.max(np.abs(lam - _nnls_lcp(W, (1 + e) * um))) <= 1e-13
    _check_lcp(W, um, e, lam)


# --- singular W -----------------------------------------------------------------------------------

def test_duplicated_constraint_shares_the_impulse(law):
    """A ball (m = 2) on a floor declared twice (phi_1 = phi_2 = y): G = [[1], [1]], W = [[1/2, 1/2],
    [1/2, 1/2]] (rank 1), u- = (-3, -3). Equal e: u+ = -e u- and lam_1 + lam_2 = (1 + e) 3 m; every split
    solves the LCP; the least-norm one is the equal split (code LCP_MIN_NORM).
    Different e (0.5, 0.9): the larger restitution wins, u+ = 0.9 * 3, lam = (0, 1.9 * 3 * 2), unique
    (P = {2}: LCP_SINGULAR_UNIQUE)."""
    W = np.full((2, 2), 0.5)
    code, lam = _solve(law, W, [-3.0, -3.0], [0.8, 0.8])
    assert code == law.LCP_MIN_NORM
    assert np.max(np.abs(lam - 1.8 * 3 * 2 / 2)) <= 1e-12
    code, lam = _solve(law, W, [-3.0, -3.0], [0.5, 0.9])
    assert code == law.LCP_SINGULAR_UNIQUE
    assert lam[0] == 0.0 and abs(lam[1] - 1.9 * 3 * 2) <= 1e-12
    _check_lcp(W, [-3.0, -3.0], [0.5, 0.9], lam)


def test_corner_of_three_walls(law):
    """A unit point mass hits, at the origin and with v- = (-1, -1), the floor y >= 0, the wall
    x >= 0 and the wall (x + y)/sqrt(2) >= 0: three contacts, two DOF, G = [[0, 1], [1, 0],
    [1, 1]/sqrt(2)], W = G G^T singular (rank 2), u- = (-1, -1, -sqrt(2)).
    e = 1: v+ = (1, 1) (u+ = -u-, w = 0) with G^T lam = (2, 2): lam = (2 - s, 2 - s, sqrt(2) s),
    s in [0, 2]; |lam|^2 = 2 (2 - s)^2 + 2 s^2 is least at s = 1: lam = (1, 1, sqrt(2))."""
    G = np.array([[0.0, 1.0], [1.0, 0.0], [1 / np.sqrt(2), 1 / np.sqrt(2)]])
    W = G @ G.T
    v = np.array([-1.0, -1.0])
    um = G @ v
    code, lam = _solve(law, W, um, np.ones(3))
    assert code == law.LCP_MIN_NORM
    assert np.max(np.abs(lam - [1.0, 1.0, np.sqrt(2)])) <= 1e-12
    assert np.max(np.abs(v + G.T @ lam - [1.0, 1.0])) <= 1e-12
    _check_lcp(W, um, np.ones(3), lam)


def test_a_zero_width_gap_with_different_restitutions_has_no_solution(law):
    """x between walls x >= 0 and -x >= 0 (G = [[1], [-1]], W = [[1, -1], [-1, 1]]), u- = (-1, 1),
    e = (1, 0): w_1 + w_2 = (1 + e_1) u-_1 + (1 + e_2) u-_2 = -1 < 0 for every lam (the rows of W sum
    to 0): infeasible, code LCP_INFEASIBLE and lam = 0. At rest (u- = 0) every lam = (s, s) solves it
    and 0 is the least-norm solution (LCP_MIN_NORM)."""
    W = np.array([[1.0, -1.0], [-1.0, 1.0]])
    code, lam = _solve(law, W, [-1.0, 1.0], [1.0, 0.0])
    assert code == law.LCP_INFEASIBLE and np.all(lam == 0.0)
    assert linprog(np.zeros(2), A_ub=-W, b_ub=np.array([-2.0, 1.0]), bounds=[(0, None)] * 2).status == 2
    code, lam = _solve(law, W, [0.0, 0.0], [1.0, 0.0])
    assert code == law.LCP_MIN_NORM and np.all(lam == 0.0)  # every (s, s) solves it; 0 is the least norm


def _least_norm_reference(W, q, lam0):
    """min |lam|^2 over the LCP's solution set {lam >= 0, lam_i = 0 where w_i > 0, W_PP lam_P = -q_P}
    (w unique for PSD W; P from the solution lam0), by SLSQP on independent equality constraints."""
    w = q + W @ lam0
    P = np.flatnonzero(w <= 1e-9 * np.max(np.abs(q)))
    d, V = np.linalg.eigh(W[np.ix_(P, P)])
    U = V[:, d > 1e-9 * d.max()]  # W_PP x = -q_P as independent equations: U^T W_PP x = -U^T q_P
    C, c = U.T @ W[np.ix_(P, P)], U.T @ q[P]
    cons = [{"type": "eq", "fun": lambda x: C @ x + c, "jac": lambda x: C}]
    r = minimize(lambda x: x @ x, lam0[P], jac=lambda x: 2 * x, method="SLSQP", constraints=cons,
                 bounds=[(0, None)] * P.size, options={"ftol": 1e-16, "maxiter": 500})
    out = np.zeros_like(lam0)
    out[P] = r.x
    return out


def test_random_singular_more_contacts_than_dof(law, rng):
    """k contacts on n < k DOF (random gradients G, random SPD M): u+ unique, lam the least-norm
    solution; feasibility against a linear program, lam against SLSQP on the solution set."""
    count = 12 if law.__name__ == "impact_law_python" else 60
    codes = []
    for trial in range(count):
        n = int(rng.integers(1, 4))
        k = int(rng.integers(n + 1, min(n + 4, 6) + 1))
        G = rng.normal(size=(k, n))
        if trial % 3 == 0:
            G[-1] = G[0] * rng.uniform(0.5, 2.0)       # a duplicated (rescaled) constraint
        B = rng.normal(size=(n, n))
        Minv = np.linalg.inv(B @ B.T + 0.5 * np.eye(n))
        W = G @ Minv @ G.T
        W = 0.5 * (W + W.T)
        um = G @ rng.normal(size=n)                    # u- in the range of G, as from a momentum
        e = np.full(k, rng.uniform(0, 1)) if trial % 2 == 0 else rng.uniform(0, 1, size=k)
        q = (1 + e) * um
        feasible = linprog(np.zeros(k), A_ub=-W, b_ub=q, bounds=[(0, None)] * k,
                           method="highs").status == 0
        code, lam = _solve(law, W, um, e)
        codes.append(code)
        if trial % 2 == 0:
            assert feasible  # equal restitution: always solvable (docs/derivations/contacts.md, 1.3)
        if not feasible:
            assert code == law.LCP_INFEASIBLE
            continue
        assert code in (law.LCP_SINGULAR_UNIQUE, law.LCP_MIN_NORM), code
        _check_lcp(W, um, e, lam, tol=1e-9)
        if code == law.LCP_MIN_NORM:
            ref = _least_norm_reference(W, q, lam)
            assert np.linalg.norm(lam) <= np.linalg.norm(ref) * (1 + 1e-9) + 1e-12
            assert np.max(np.abs(lam - ref)) <= 1e-6 * max(np.max(np.abs(lam)), 1e-300), (lam, ref)
    assert law.LCP_MIN_NORM in codes


def test_least_norm_kernel_is_the_pseudo_inverse(law, rng):
    """The Jacobi-based least-norm solve of step 3 against numpy's pinv, on random PSD matrices of
    rank r < m (and full rank), restricted to a random support."""
    pinv_support = _from_python(law._lcp_pinv_support)
    for _ in range(30):
        k = int(rng.integers(2, 8))
        r = int(rng.integers(1, k + 1))
        B = rng.normal(size=(r, k))
        A = B.T @ B
        q = rng.normal(size=k)
        mask = int(rng.integers(1, 2 ** k))
        S = [i for i in range(k) if (mask >> i) & 1]
        x = np.full(k, np.nan)
        pinv_support(A, q, mask, k, float(np.max(np.diag(A))), x)
        ref = np.zeros(k)
        ref[S] = np.linalg.pinv(A[np.ix_(S, S)], rcond=1e-11, hermitian=True) @ -q[S]
        assert np.max(np.abs(x - ref)) <= 1e-9 * max(1.0, np.max(np.abs(ref))), (A, q, S)


# --- bad input ------------------------------------------------------------------------------------

def test_bad_input_is_a_code(law):
    ok_W = np.eye(2)
    cases = [
        (np.eye(2), [-1.0, np.nan], [1.0, 1.0]),
        (np.eye(2), [-1.0, -1.0], [1.0, 1.5]),
        (np.eye(2), [-1.0, -1.0], [-0.1, 1.0]),
        (np.array([[1.0, 0.5], [0.0, 1.0]]), [-1.0, -1.0], [1.0, 1.0]),
        (np.array([[0.0, 0.0], [0.0, 1.0]]), [-1.0, -1.0], [1.0, 1.0]),
        (np.array([[-1.0]]), [-1.0], [1.0]),
    ]
    for W, um, e in cases:
        code, lam = _solve(law, W, um, e)
        assert code == law.LCP_BAD_INPUT and np.all(lam == 0.0), (W, um, e)
    lam = np.empty(3)
    assert law.impact_law(ok_W, np.array([-1.0, -1.0]), np.ones(2), lam) == law.LCP_BAD_INPUT
    code, lam = _solve(law, np.eye(9), -np.ones(9), np.ones(9))  # more than LCP_MAX_CONTACTS: Lemke
    assert code == law.LCP_UNIQUE and np.all(lam == 2.0)
