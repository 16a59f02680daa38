# numba source unit: the impact law of k simultaneous contacts (docs/derivations/contacts.md, section 1):
# Moreau's generalized Newton law as a linear complementarity problem, solved exactly for any k: by
# enumeration of supports for k <= LCP_MAX_CONTACTS (every case below), by Lemke's complementary
# pivoting with the lexicographic ratio test above that (docs/derivations/contacts.md, section 1.7).
# It reads no name of the generated part (every size from its arguments, its own constants only) and
# calls only maps/linalg.py, so it compiles on its own (vcirun.codegen.units.standalone_source).
#
#   impact_law(W, um, e, lam) -> case code
#     W   (k, k) the Delassus matrix G M^-1 G^T of the k contacts at the impact (symmetric PSD)
#     um  (k,)   their normal velocities before the impact, u- = G M^-1 p-
#     e   (k,)   their restitution coefficients in [0, 1]
#     lam (k,)   out: the impulses, p+ = p- + G^T lam
#   LCP: w = (1 + e) * u- + W lam >= 0, lam >= 0, lam . w = 0, i.e. with u+ = u- + W lam:
#   u+_i + e_i u-_i >= 0, lam_i >= 0, lam_i (u+_i + e_i u-_i) = 0.
#
# Case codes (the return value):
#   LCP_UNIQUE (0)          W positive definite (a P-matrix): the unique solution.
#   LCP_SINGULAR_UNIQUE (1) W singular (dependent constraint gradients), but W_PP is nonsingular on the
#                           set P = {i : w_i = 0}: lam is still unique.
#   LCP_MIN_NORM (2)        W singular and W_PP singular: u+ is unique, lam is not (in general); lam is
#                           the least Euclidean norm solution (a convex QP, solved exactly by
#                           enumeration of supports; order-independent, so duplicated contacts share
#                           the impulse equally).
#   LCP_INFEASIBLE (-1)     no lam >= 0 makes w >= 0: no solution. Impossible for positive definite W;
#                           possible for singular W with different restitutions (e.g. a ball pressed in
#                           a gap of zero width between walls of different e). lam is set to 0.
#   LCP_BAD_INPUT (-2)      k < 1, shapes disagree, a non-finite entry, e outside [0, 1], W not symmetric
#                           (to LCP_SYM_TOL), or W_ii <= 0. lam is set to 0.
#   LCP_DEGENERATE (-3)     k > LCP_MAX_CONTACTS and lam is not unique (W_PP singular on the contacts P
#                           that end with w_i = 0: dependent contact gradients, e.g. a closed loop of
#                           contacts), or Lemke's method met a pivot it cannot decide within round-off.
#                           lam is set to 0; the caller names the contacts.
# Above LCP_MAX_CONTACTS contacts a solution found by Lemke is returned as LCP_UNIQUE (W positive
# definite) or LCP_SINGULAR_UNIQUE (W singular, W_PP nonsingular); LCP_INFEASIBLE on a secondary ray.
# One contact (k = 1, W > 0): lam = -(1 + e) u- / W if u- < 0 else 0, written as
# -(1.0 + e[0]) * um[0] / W[0, 0] so that e = 1 gives -2 u-/W bit for bit (cva_lambda's value).
import math

import numpy as np
from numba import njit

from vcirun.maps.linalg import solve_small

LCP_MAX_CONTACTS = 8    # up to here 2^k supports are enumerated (256 small solves at most); Lemke above
LCP_UNIQUE = 0
LCP_SINGULAR_UNIQUE = 1
LCP_MIN_NORM = 2
LCP_INFEASIBLE = -1
LCP_BAD_INPUT = -2
LCP_DEGENERATE = -3
LCP_RANK_TOL = 1e-11    # a pivot/eigenvalue below this times max W_ii counts as zero (rank decisions)
LCP_FEAS_TOL = 1e-10    # accepted violation of the LCP conditions, relative to max |(1 + e_i) u-_i|
LCP_SYM_TOL = 1e-8      # accepted |W_ij - W_ji| relative to max W_ii (G M^-1 G^T's round-off grows with cond M)


@njit(cache=True, nogil=True, error_model="numpy")
def impact_law(W, um, e, lam):
    """Moreau's generalized Newton law for k contacts as an LCP; returns a case code (see the unit's
    header): lam >= 0 with u+ = um + W lam, u+_i + e_i um_i >= 0, complementary."""
    k = um.shape[0]
    for i in range(lam.shape[0]):
        lam[i] = 0.0
    if k < 1 or W.shape[0] != k or W.shape[1] != k or e.shape[0] != k or lam.shape[0] != k:
        return LCP_BAD_INPUT
    for i in range(k):
        if not (math.isfinite(um[i]) and math.isfinite(e[i]) and e[i] >= 0.0 and e[i] <= 1.0):
            return LCP_BAD_INPUT
        if not (math.isfinite(W[i, i]) and W[i, i] > 0.0):
            return LCP_BAD_INPUT
    if k == 1:
        if um[0] < 0.0:
            lam[0] = -(1.0 + e[0]) * um[0] / W[0, 0]
        return LCP_UNIQUE
    wmax = 0.0
    for i in range(k):
        wmax = max(wmax, W[i, i])
    A = np.empty((k, k))  # W symmetrised (it is symmetric up to the round-off of G M^-1 G^T)
    for i in range(k):
        for j in range(k):
            if not math.isfinite(W[i, j]) or abs(W[i, j] - W[j, i]) > LCP_SYM_TOL * wmax:
                return LCP_BAD_INPUT
            A[i, j] = 0.5 * (W[i, j] + W[j, i])
    q = np.empty(k)
    qs = 0.0
    for i in range(k):
        q[i] = (1.0 + e[i]) * um[i]
        qs = max(qs, abs(q[i]))
    if k > LCP_MAX_CONTACTS:
        return _lcp_large(A, q, qs, k, wmax, lam)
    full = (1 << k) - 1
    pd = _lcp_rank_full(A, full, k, wmax)
    if qs == 0.0:
        return LCP_UNIQUE if pd else LCP_MIN_NORM  # lam = 0: w = 0, P = all, W_PP = W singular, 0 least norm
    tol_w = LCP_FEAS_TOL * qs
    # 1. a basic solution: the support S with the smallest violation among the 2^k candidates
    #    lam_S = -A_SS^-1 q_S (A_SS nonsingular). For PSD A a solvable LCP has a vertex solution, whose
    #    support has A_SS nonsingular (docs/derivations/contacts.md, 1.3), so this finds a solution if one exists.
    x = np.empty(k)
    best = np.zeros(k)
    best_v = np.inf
    for mask in range(full + 1):
        if _lcp_solve_support(A, q, mask, k, wmax, x):
            v = _lcp_violation(A, q, x, mask, k, wmax)
            if v < best_v:
                best_v = v
                for i in range(k):
                    best[i] = x[i]
    if not best_v <= tol_w:
        return LCP_INFEASIBLE
    if pd:
        _lcp_clip_into(best, lam, k)
        return LCP_UNIQUE
    # 2. W singular: w (hence u+) is unique; every solution is supported in P = {i : w_i = 0} and
    #    solves A_PP lam_P = -q_P. If A_PP is nonsingular that solution is unique.
    P = 0
    for i in range(k):
        wi = q[i]
        for j in range(k):
            wi += A[i, j] * best[j]
        if wi <= tol_w:
            P |= 1 << i
    if _lcp_rank_full(A, P, k, wmax):
        _lcp_clip_into(best, lam, k)
        return LCP_SINGULAR_UNIQUE
    # 3. the least-norm solution: on its support F it is the least-norm solution pinv(A_FF) (-q_F) of
    #    A_FF x_F = -q_F, so the feasible candidate of least norm over all F within P is it.
    best_n = np.inf
    bestm = np.zeros(k)
    for F in range(P + 1):
        if F & ~P:
            continue
        _lcp_pinv_support(A, q, F, k, wmax, x)
        if _lcp_violation(A, q, x, F, k, wmax) <= tol_w:
            nrm = 0.0
            for i in range(k):
                nrm += x[i] * x[i]
            if nrm < best_n:
                best_n = nrm
                for i in range(k):
                    bestm[i] = x[i]
    if best_n == np.inf:  # cannot happen: the basic solution's support is a candidate
        _lcp_clip_into(best, lam, k)
        return LCP_SINGULAR_UNIQUE
    _lcp_clip_into(bestm, lam, k)
    return LCP_MIN_NORM


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _lcp_clip_into(x, lam, k):
    """lam = max(x, 0): removes the round-off negatives (within the accepted violation)."""
    for i in range(k):
        lam[i] = x[i] if x[i] > 0.0 else 0.0


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _lcp_violation(A, q, x, mask, k, wmax):
    """Largest violation of the LCP conditions by x (supported on mask), in velocity units:
    -x_i wmax and |w_i| on the support (w_S = 0 there), -w_i off it."""
    v = 0.0
    for i in range(k):
        wi = q[i]
        for j in range(k):
            wi += A[i, j] * x[j]
        if (mask >> i) & 1:
            v = max(v, -x[i] * wmax, abs(wi))
        else:
            v = max(v, -wi)
    return v if v == v else np.inf


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _lcp_solve_support(A, q, mask, k, wmax, x):
    """x_S = -A_SS^-1 q_S, x = 0 off S = mask, by Gaussian elimination with partial pivoting
    (maps/linalg.py); False if A_SS is singular (a pivot not above LCP_RANK_TOL wmax)."""
    idx = np.empty(k, np.int64)
    m = 0
    for i in range(k):
        x[i] = 0.0
        if (mask >> i) & 1:
            idx[m] = i
            m += 1
    if m == 0:
        return True
    B = np.empty((m, m))
    b = np.empty(m)
    for r in range(m):
        b[r] = -q[idx[r]]
        for c in range(m):
            B[r, c] = A[idx[r], idx[c]]
    if not solve_small(B, b, m, LCP_RANK_TOL * wmax):
        return False
    for r in range(m):
        x[idx[r]] = b[r]
    return True


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _lcp_rank_full(A, mask, k, wmax):
    """True if the principal submatrix A_SS (S = mask; symmetric PSD) is positive definite: Cholesky
    with every pivot above LCP_RANK_TOL wmax. The empty matrix counts as nonsingular."""
    sel = np.zeros(k, np.int64)
    for i in range(k):
        if (mask >> i) & 1:
            sel[i] = 1
    return _cholesky_pd(A, sel, k, wmax)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _lcp_pinv_support(A, q, mask, k, wmax, x):
    """x_S = pinv(A_SS) (-q_S) (the least-norm least-squares solution; eigenvalues below LCP_RANK_TOL
    wmax count as zero), x = 0 off S, by the cyclic Jacobi eigendecomposition of the symmetric A_SS."""
    idx = np.empty(k, np.int64)
    m = 0
    for i in range(k):
        x[i] = 0.0
        if (mask >> i) & 1:
            idx[m] = i
            m += 1
    if m == 0:
        return
    B = np.empty((m, m))
    V = np.zeros((m, m))
    for r in range(m):
        V[r, r] = 1.0
        for c in range(m):
            B[r, c] = A[idx[r], idx[c]]
    for _ in range(100):
        off = 0.0
        for r in range(m):
            for c in range(r + 1, m):
                off += B[r, c] * B[r, c]
        if off <= (1e-17 * wmax) ** 2:
            break
        for a in range(m - 1):
            for c in range(a + 1, m):
                if B[a, c] == 0.0:
                    continue
                # rotation in the (a, c) plane that zeroes B[a, c]
                theta = (B[c, c] - B[a, a]) / (2.0 * B[a, c])
                t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
                cs = 1.0 / math.sqrt(t * t + 1.0)
                sn = t * cs
                for r in range(m):
                    bra = B[r, a]
                    brc = B[r, c]
                    B[r, a] = cs * bra - sn * brc
                    B[r, c] = sn * bra + cs * brc
                for r in range(m):
                    bar = B[a, r]
                    bcr = B[c, r]
                    B[a, r] = cs * bar - sn * bcr
                    B[c, r] = sn * bar + cs * bcr
                for r in range(m):
                    var = V[r, a]
                    vcr = V[r, c]
                    V[r, a] = cs * var - sn * vcr
                    V[r, c] = sn * var + cs * vcr
    # x_S = V diag(1/d) V^T (-q_S) over the eigenvalues d above the rank tolerance
    for j in range(m):
        d = B[j, j]
        if d > LCP_RANK_TOL * wmax:
            s = 0.0
            for r in range(m):
                s -= V[r, j] * q[idx[r]]
            s /= d
            for r in range(m):
                x[idx[r]] += V[r, j] * s


# --- more than LCP_MAX_CONTACTS contacts: Lemke's method ---------------------------------------------

LEMKE_PIVOT_TOL = 1e-12  # a tableau entry below this times its column's largest counts as zero
LEMKE_MAX_PIVOTS = 50    # times k (Lemke needs about k pivots; cycling is excluded by the lexicographic rule)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _lcp_large(A, q, qs, k, wmax, lam):
    """The LCP of k > LCP_MAX_CONTACTS contacts: Lemke, then the uniqueness checks of the case codes."""
    x = np.zeros(k)
    code = lemke(A, q, x)
    if code != 0:
        return LCP_INFEASIBLE if code == 1 else LCP_DEGENERATE
    if not _lcp_violation_dense(A, q, x, k, wmax) <= LCP_FEAS_TOL * qs:
        return LCP_DEGENERATE
    sel = np.ones(k, np.int64)
    if _cholesky_pd(A, sel, k, wmax):
        _lcp_clip_into(x, lam, k)
        return LCP_UNIQUE
    for i in range(k):  # P = {i : w_i = 0}
        wi = q[i]
        for j in range(k):
            wi += A[i, j] * x[j]
        sel[i] = 1 if wi <= LCP_FEAS_TOL * qs else 0
    if _cholesky_pd(A, sel, k, wmax):
        _lcp_clip_into(x, lam, k)
        return LCP_SINGULAR_UNIQUE
    return LCP_DEGENERATE


@njit(cache=True, nogil=True, error_model="numpy")
def lemke(A, q, x):
    """Lemke's complementary pivoting for w = q + A x >= 0, x >= 0, x . w = 0 (covering vector 1),
    with the lexicographic minimum ratio test (the tableau's w columns hold B^-1), so a degenerate q
    (many u-_i = 0, as in a cradle at rest) cannot cycle. Returns 0 with x the solution, 1 on a
    secondary ray (for positive semidefinite A: no solution), 2 if the pivots did not end (round-off
    on a degenerate problem). Dense tableau k x (2k + 2): O(k^2) per pivot."""
    k = q.shape[0]
    for i in range(k):
        x[i] = 0.0
    r = 0
    for i in range(1, k):
        if q[i] < q[r]:
            r = i
    if q[r] >= 0.0:
        return 0
    nc = 2 * k + 2                     # columns: w (0..k-1), x (k..2k-1), z0 (2k), rhs (2k+1)
    T = np.zeros((k, nc))
    for i in range(k):
        T[i, i] = 1.0
        for j in range(k):
            T[i, k + j] = -A[i, j]
        T[i, 2 * k] = -1.0
        T[i, 2 * k + 1] = q[i]
    basis = np.empty(k, np.int64)
    for i in range(k):
        basis[i] = i
    # z0 enters at the most negative q: every rhs becomes >= 0
    _pivot(T, basis, r, 2 * k, k)
    entering = r + k                   # the complement of w_r, which left
    for _ in range(LEMKE_MAX_PIVOTS * k):
        cmax = 0.0
        for i in range(k):
            cmax = max(cmax, abs(T[i, entering]))
        tol = LEMKE_PIVOT_TOL * cmax
        row = -1
        for i in range(k):
            if T[i, entering] > tol:
                if row < 0 or _lex_less(T, i, row, entering, k):
                    row = i
        if row < 0:
            return 1
        leaving = basis[row]
        _pivot(T, basis, row, entering, k)
        if leaving == 2 * k:           # z0 left: a complementary solution
            for i in range(k):
                if basis[i] >= k and basis[i] < 2 * k:
                    x[basis[i] - k] = T[i, 2 * k + 1]
            return 0
        entering = leaving + k if leaving < k else leaving - k
    return 2


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _lex_less(T, a, b, c, k):
    """Row a before row b in the lexicographic ratio test on column c: (rhs, B^-1 row) / T[., c]."""
    ra = T[a, 2 * k + 1] / T[a, c]
    rb = T[b, 2 * k + 1] / T[b, c]
    if ra != rb:
        return ra < rb
    for j in range(k):
        ra = T[a, j] / T[a, c]
        rb = T[b, j] / T[b, c]
        if ra != rb:
            return ra < rb
    return a < b


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _pivot(T, basis, r, c, k):
    """Gauss-Jordan pivot on T[r, c]: column c's variable replaces basis[r]."""
    nc = T.shape[1]
    piv = T[r, c]
    for j in range(nc):
        T[r, j] /= piv
    for i in range(k):
        if i != r:
            f = T[i, c]
            if f != 0.0:
                for j in range(nc):
                    T[i, j] -= f * T[r, j]
                T[i, c] = 0.0
    T[r, c] = 1.0
    basis[r] = c


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _lcp_violation_dense(A, q, x, k, wmax):
    """Largest violation of x >= 0, w = q + A x >= 0 and of complementarity, in velocity units."""
    v = 0.0
    for i in range(k):
        wi = q[i]
        for j in range(k):
            wi += A[i, j] * x[j]
        v = max(v, -x[i] * wmax, -wi, min(abs(wi), abs(x[i]) * wmax))
    return v if v == v else np.inf


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _cholesky_pd(A, sel, k, wmax):
    """True if A restricted to {i : sel[i] = 1} is positive definite (pivots above LCP_RANK_TOL wmax)."""
    idx = np.empty(k, np.int64)
    m = 0
    for i in range(k):
        if sel[i] != 0:
            idx[m] = i
            m += 1
    L = np.zeros((m, m))
    for j in range(m):
        d = A[idx[j], idx[j]]
        for c in range(j):
            d -= L[j, c] * L[j, c]
        if not d > LCP_RANK_TOL * wmax:
            return False
        L[j, j] = math.sqrt(d)
        for r in range(j + 1, m):
            s = A[idx[r], idx[j]]
            for c in range(j):
                s -= L[r, c] * L[j, c]
            L[r, j] = s / L[j, j]
    return True
