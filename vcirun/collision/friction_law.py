# numba source unit: the frictional impact law of k simultaneous planar contacts
# (docs/derivations/friction.md, section "Frictional impacts"). It reads no name of the generated
# part and calls only collision/impact_law.py (with the linear algebra it calls), so it compiles on
# its own (vcirun.codegen.units.standalone_source).
#
#   friction_impact_law(W, u, e, mu, lam) -> case code
#     rows ordered [normal_1 .. normal_k, tangent_1 .. tangent_k]
#     W   (2k, 2k) the Delassus matrix [Gn; Gt] M^-1 [Gn; Gt]^T (symmetric positive semidefinite)
#     u   (2k,)    the velocities before the impact: normal u-_n = Gn M^-1 p-, slip u-_t = Gt M^-1 p-
#     e   (k,)     restitution coefficients in [0, 1]
#     mu  (k,)     Coulomb's coefficients of friction >= 0 (the kinetic one: see the derivation)
#     lam (2k,)    out: the impulses, normal then tangential: p+ = p- + Gn^T lam_n + Gt^T lam_t
#
# The law ("restitution, then a plastic Coulomb stage"; the derivation proves that it never gains
# kinetic energy, for any k, any e_i and mu_i, dependent or duplicated contact rows included):
#   stage 1  Moreau's frictionless law (impact_law) on the normal rows: lam1 >= 0, u1 = u- + W[:, n] lam1,
#            u1_n + e o u-_n >= 0, complementary. r_i = max(u1_n,i, 0) is contact i's rebound velocity.
#   stage 2  a plastic impulse (P - lam1, lam_t) from u1, u+ = u- + W [P; lam_t], with per contact
#            - the rebound graph between the total normal impulse P_i >= 0 and u+_n,i >= 0:
#                u+_n = 0 and P >= lam1 | P = lam1 and 0 <= u+_n <= r | u+_n = r and 0 <= P <= lam1
#                | P = 0 and u+_n >= r
#              (the friction's impulse may add normal impulse only to stop penetration, and may take
#              stage 1's away only while the contact rebounds faster than r; r = 0 gives P >= 0 _|_ u+_n >= 0)
#            - Coulomb on the final slip: |lam_t,i| <= mu_i P_i, lam_t,i u+_t,i = -mu_i P_i |u+_t,i|.
#   mu = 0 everywhere: lam_n = impact_law's lam bit for bit, lam_t = 0. e = 0 everywhere: the standard
#   plastic Moreau-Coulomb impact (P >= 0 _|_ u+_n >= 0, Coulomb on u+_t).
# Stage 2 is a linear complementarity problem (LCP) of at most 6 unknowns per contact (3 for its
# normal law, 3 for the planar cone), one per group of contacts that W couples, solved by Lemke's
# method with the lexicographic ratio test (exact pivoting; its matrix is copositive and the
# derivation shows that Lemke cannot end on a secondary ray when u- = [Gn; Gt] M^-1 p-). Round-off on
# degenerate groups (dependent rows, exact ties) is met by up to FRIC_TRIES attempts, each result
# checked against the law's conditions. Memory: a dense tableau m x (2m + 2) on the heap, m <= 6 times
# the contacts of the largest coupled group, allocated once per call.
#
# Case codes (impact_law's, one more):
#   LCP_UNIQUE (0)          stage 1 unique (W_nn positive definite) and, in every group where friction acts,
#                           stage 2's solution certified unique: a contact alone in its group by enumerating
#                           the pieces of its law, a larger group by the bound lambda_min(W_g) > max mu_i
#                           ||tangent rows of W_g||_F (the derivation's uniqueness bound).
#   LCP_SINGULAR_UNIQUE (1) impact_law's codes, returned as impact_law returns them where friction does not
#   LCP_MIN_NORM (2)        act (every mu_i = 0, or no normal impulse in a group with friction).
#   FRIC_SOLVED (3)         a solution of the law, not certified unique: rigid-body Coulomb friction at an
#                           impact can have several (friction jams the impact when it couples strongly into
#                           the normal directions); the one Lemke's method reaches from lam = 0 is returned.
#   LCP_INFEASIBLE (-1)     stage 1 has no solution, or Lemke ended on a secondary ray (impossible when u-
#                           is a velocity of the system, i.e. in the range of W). lam = 0.
#   LCP_BAD_INPUT (-2)      shapes that disagree, a non-finite entry, e outside [0, 1], mu < 0, W not
#                           symmetric (to LCP_SYM_TOL), a normal W_ii <= 0 or a tangent W_ii < 0. lam = 0.
#   LCP_DEGENERATE (-3)     stage 1's (impact_law's), or Lemke's pivots did not end, or its result misses the
#                           law's conditions by more than LCP_FEAS_TOL (round-off on a degenerate problem).
#                           lam = 0.
# A contact whose tangent row is zero (W_tt,i <= LCP_RANK_TOL max W_ii: it cannot slip there) takes no
# tangential impulse, whatever its mu_i.
import math

import numpy as np
from numba import njit

from vcirun.collision.impact_law import (impact_law, LCP_UNIQUE, LCP_INFEASIBLE, LCP_BAD_INPUT, LCP_DEGENERATE,
                                         LCP_RANK_TOL, LCP_FEAS_TOL, LCP_SYM_TOL, LEMKE_PIVOT_TOL,
                                         LEMKE_MAX_PIVOTS)

FRIC_SOLVED = 3
FRIC_TRIES = 4          # Lemke's method is tried up to this many times on a group: round-off on a degenerate
                        # problem (dependent contact rows, exact ties) can end a path on a ray that exact
                        # arithmetic would not meet; try t = 1, 2, 3 uses another covering vector and adds to q
FRIC_SHIFT = 1e-13      # this times 10^(t - 1) times the velocity scale times a factor in [1, 2]: a slack of
                        # at most 2e-11 of the velocity scale, below the check's LCP_FEAS_TOL
FRIC_TIE_TOL = 1e-12    # ratios of Lemke's ratio test within this (relative) of the least tie
FRIC_RHS_TOL = 1e-14    # a tableau right-hand side below this times max |q| counts as 0 (a degenerate vertex)


@njit(cache=True, nogil=True, error_model="numpy")
def friction_impact_law(W, u, e, mu, lam):
    """The frictional impact law of k planar contacts; returns a case code (see the unit's header)."""
    for i in range(lam.shape[0]):
        lam[i] = 0.0
    k = e.shape[0]
    if (k < 1 or u.shape[0] != 2 * k or W.shape[0] != 2 * k or W.shape[1] != 2 * k or mu.shape[0] != k
            or lam.shape[0] != 2 * k):
        return LCP_BAD_INPUT
    n2 = 2 * k
    for i in range(k):
        if not (math.isfinite(mu[i]) and mu[i] >= 0.0 and math.isfinite(e[i]) and e[i] >= 0.0 and e[i] <= 1.0):
            return LCP_BAD_INPUT
        if not (math.isfinite(W[i, i]) and W[i, i] > 0.0):
            return LCP_BAD_INPUT
    wmax = 0.0
    for i in range(n2):
        if not math.isfinite(u[i]):
            return LCP_BAD_INPUT
        wmax = max(wmax, W[i, i])
    for i in range(n2):
        for j in range(n2):
            if not math.isfinite(W[i, j]) or abs(W[i, j] - W[j, i]) > LCP_SYM_TOL * wmax:
                return LCP_BAD_INPUT
    # the contacts with friction: mu_i > 0 and a tangent row that is not zero
    fric = np.zeros(k, np.int64)
    nfric = 0
    for i in range(k):
        wt = W[k + i, k + i]
        if wt < -LCP_RANK_TOL * wmax:
            return LCP_BAD_INPUT
        if mu[i] > 0.0 and wt > LCP_RANK_TOL * wmax:
            fric[i] = 1
            nfric += 1
    # stage 1: Moreau's frictionless law on the normal rows
    Wn = np.empty((k, k))
    un = np.empty(k)
    for i in range(k):
        un[i] = u[i]
        for j in range(k):
            Wn[i, j] = W[i, j]
    lam1 = np.empty(k)
    code1 = impact_law(Wn, un, e, lam1)
    if code1 < 0:
        return code1
    for i in range(k):
        lam[i] = lam1[i]
    if nfric == 0:
        return code1
    # stage 2 on the groups of contacts W couples that hold a contact with friction and an impulse
    A = np.empty((n2, n2))  # W symmetrised
    for i in range(n2):
        for j in range(n2):
            A[i, j] = 0.5 * (W[i, j] + W[j, i])
    qs = 0.0  # velocity scale of the tolerances
    for i in range(k):
        qs = max(qs, abs((1.0 + e[i]) * u[i]))
        if fric[i]:
            qs = max(qs, abs(u[k + i]))
    r = np.empty(k)
    box = np.zeros(k, np.int64)
    for i in range(k):
        s = u[i]
        for j in range(k):
            s += A[i, j] * lam1[j]
        r[i] = s if s > 0.0 else 0.0
        if lam1[i] > 0.0 and r[i] > LCP_FEAS_TOL * qs:
            box[i] = 1  # rebounds with r > 0: the three-piece normal law; else P >= 0 _|_ u+_n >= 0
    group = _fr_groups(A, fric, k)
    ngroups = 0
    for i in range(k):
        ngroups = max(ngroups, group[i] + 1)
    # a group takes part if it holds a contact with friction and a normal impulse can arise in it
    # (stage 1 gave one, or a contact of it approaches)
    takes_part = np.zeros(ngroups, np.int64)
    for i in range(k):
        if lam1[i] > 0.0 or u[i] < 0.0:
            takes_part[group[i]] |= 1
        if fric[i]:
            takes_part[group[i]] |= 2
    msize = 0
    for g in range(ngroups):
        if takes_part[g] == 3:
            m = 0
            for i in range(k):
                if group[i] == g:
                    m += 3 if box[i] else 1
                    m += 3 if fric[i] else 0
            msize = max(msize, m)
    if msize == 0:
        return code1
    T = np.empty((msize, 2 * msize + 2))
    basis = np.empty(msize, np.int64)
    x = np.empty(msize)
    ia = np.empty(k, np.int64)  # per contact: its unknowns' indices in the group's LCP (-1: none)
    ib = np.empty(k, np.int64)
    iz = np.empty(k, np.int64)
    ip = np.empty(k, np.int64)
    im = np.empty(k, np.int64)
    ig = np.empty(k, np.int64)
    ctc = np.empty(k, np.int64)  # the group's contacts
    P = np.empty(k)
    lt = np.zeros(k)
    for i in range(k):
        P[i] = lam1[i]
    acted = False
    certified = code1 == LCP_UNIQUE
    for g in range(ngroups):
        if takes_part[g] != 3:
            continue
        nc = 0
        m = 0
        for i in range(k):
            if group[i] != g:
                continue
            ctc[nc] = i
            nc += 1
            ia[i] = m
            m += 1
            if box[i]:
                ib[i] = m
                iz[i] = m + 1
                m += 2
            else:
                ib[i] = -1
                iz[i] = -1
            if fric[i]:
                ip[i] = m
                im[i] = m + 1
                ig[i] = m + 2
                m += 3
            else:
                ip[i] = -1
                im[i] = -1
                ig[i] = -1
        acted = True
        if nc == 1:     # one contact: its law's pieces enumerated; one solution is taken as it is
            i = ctc[0]
            if _fr_single(A, u, mu, lam1, r, i, box[i], fric[i], k, qs, wmax, P, lt) == 1:
                continue
            certified = False
        code = 1
        for attempt in range(FRIC_TRIES):
            _fr_tableau(A, u, mu, lam1, r, k, ctc, nc, ia, ib, iz, ip, im, ig, T, m, attempt, qs)
            code = _fr_lemke(T, basis, m, x)
            if code == 0:
                _fr_extract(x, ctc, nc, ia, ib, ip, im, mu, P, lt)
                if _fr_check(A, u, mu, lam1, r, P, lt, fric, k, ctc, nc, qs, wmax):
                    break
                code = 2
        if code != 0:
            for i in range(n2):
                lam[i] = 0.0
            return LCP_INFEASIBLE if code == 1 else LCP_DEGENERATE
        if certified and nc > 1:
            certified = _fr_certified(A, mu, fric, k, ctc, nc, wmax)
    for i in range(k):
        lam[i] = P[i]
        lam[k + i] = lt[i]
    if not acted:
        return code1
    return LCP_UNIQUE if certified else FRIC_SOLVED


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _fr_groups(A, fric, k):
    """The groups of contacts that W couples (a path of nonzero blocks between them; a tangent row
    without friction does not count): group[i] in 0 .. ngroups - 1."""
    group = np.empty(k, np.int64)
    for i in range(k):
        group[i] = -1
    stack = np.empty(k, np.int64)
    ng = 0
    for s in range(k):
        if group[s] >= 0:
            continue
        group[s] = ng
        stack[0] = s
        top = 1
        while top > 0:
            top -= 1
            i = stack[top]
            for j in range(k):
                if group[j] >= 0:
                    continue
                coupled = A[i, j] != 0.0
                if fric[j] and A[i, k + j] != 0.0:
                    coupled = True
                if fric[i] and A[k + i, j] != 0.0:
                    coupled = True
                if fric[i] and fric[j] and A[k + i, k + j] != 0.0:
                    coupled = True
                if coupled:
                    group[j] = ng
                    stack[top] = j
                    top += 1
        ng += 1
    return group


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _fr_tableau(A, u, mu, lam1, r, k, ctc, nc, ia, ib, iz, ip, im, ig, T, m, attempt, qs):
    """Lemke's tableau [I | -M | -d | q] (d the covering vector) of one group's stage-2 LCP
    w = q + M x >= 0, x >= 0, x . w = 0.

    Unknowns per contact i: a (ia; the normal impulse P if the contact has no rebound graph), b (ib;
    P = a + b, b <= lam1 the part of stage 1's impulse kept), z (iz; the slack of b <= lam1),
    beta+ (ip), beta- (im) (lam_t = beta+ - beta-), gamma (ig; the slip speed). Rows (u+ = u- + W [P; lam_t]):
      a: u+_n            b: u+_n - r + z        z: lam1 - b
      beta+: u+_t + gamma    beta-: -u+_t + gamma    gamma: mu (a + b) - beta+ - beta-.
    Attempt 0: covering vector 1 and q as is; attempt t = 1, 2, 3: _fr_cover's vector and
    q_i + FRIC_SHIFT 10^(t - 1) qs times a factor in [1, 2] (a deterministic perturbation that breaks
    exact ties)."""
    nco = 2 * m + 2
    for i in range(m):
        for j in range(nco):
            T[i, j] = 0.0
        T[i, i] = 1.0
        T[i, 2 * m] = -_fr_cover(i, m, attempt)
    for ci in range(nc):
        i = ctc[ci]
        rows_n = 1 if ib[i] < 0 else 2
        # the velocity rows: u+_n,i (rows a, b) and u+_t,i (rows beta+, beta-) from every unknown impulse
        for cj in range(nc):
            j = ctc[cj]
            wnn = A[i, j]
            wnt = A[i, k + j]
            wtn = A[k + i, j]
            wtt = A[k + i, k + j]
            for s in range(rows_n):
                row = ia[i] if s == 0 else ib[i]
                T[row, m + ia[j]] -= wnn
                if ib[j] >= 0:
                    T[row, m + ib[j]] -= wnn
                if ip[j] >= 0:
                    T[row, m + ip[j]] -= wnt
                    T[row, m + im[j]] += wnt
            if ip[i] >= 0:
                for s in range(2):
                    row = ip[i] if s == 0 else im[i]
                    sg = 1.0 if s == 0 else -1.0
                    T[row, m + ia[j]] -= sg * wtn
                    if ib[j] >= 0:
                        T[row, m + ib[j]] -= sg * wtn
                    if ip[j] >= 0:
                        T[row, m + ip[j]] -= sg * wtt
                        T[row, m + im[j]] += sg * wtt
        T[ia[i], 2 * m + 1] = u[i]
        if ib[i] >= 0:
            T[ib[i], 2 * m + 1] = u[i] - r[i]
            T[ib[i], m + iz[i]] -= 1.0
            T[iz[i], m + ib[i]] += 1.0
            T[iz[i], 2 * m + 1] = lam1[i]
        if ip[i] >= 0:
            T[ip[i], 2 * m + 1] = u[k + i]
            T[im[i], 2 * m + 1] = -u[k + i]
            T[ip[i], m + ig[i]] -= 1.0
            T[im[i], m + ig[i]] -= 1.0
            T[ig[i], m + ia[i]] -= mu[i]
            if ib[i] >= 0:
                T[ig[i], m + ib[i]] -= mu[i]
            T[ig[i], m + ip[i]] += 1.0
            T[ig[i], m + im[i]] += 1.0
            T[ig[i], 2 * m + 1] = 0.0
    if attempt > 0:
        shift = FRIC_SHIFT * qs * 10.0 ** (attempt - 1)
        for i in range(m):
            T[i, 2 * m + 1] += shift * (1.0 + ((7 * i + attempt) % 11) / 10.0)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _fr_cover(i, m, attempt):
    """Entry i of the covering vector of an attempt: 1 (Lemke's usual), then two ramps and a
    sawtooth, all in [1, 2]."""
    if attempt == 0:
        return 1.0
    if attempt == 1:
        return 1.0 + (i + 1.0) / m
    if attempt == 2:
        return 2.0 - i / m
    return 1.0 + ((7 * i) % 11) / 10.0


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _fr_lemke(T, basis, m, x):
    """Lemke's complementary pivoting on the tableau T[:m] = [I | -M | -d | q] (d the covering vector).
    Ratio test: the least ratio rhs / column entry (right-hand sides below FRIC_RHS_TOL max |q| count
    as 0), ties within FRIC_TIE_TOL; among ties z0 leaves if it can (the solution), else the
    lexicographic rule on the w columns (B^-1), which excludes cycling. An entering column without a
    positive entry while z0 is basic at level 0 is no ray: the point reached solves the LCP (a
    degenerate vertex). Returns 0 with x the solution, 1 on a secondary ray, 2 if the pivots did not
    end."""
    rhs = 2 * m + 1
    r = 0
    qs = 0.0
    for i in range(m):
        x[i] = 0.0
        basis[i] = i
        qs = max(qs, abs(T[i, rhs]))
        if T[i, rhs] < T[r, rhs]:
            r = i
    if T[r, rhs] >= 0.0:
        return 0
    rtol = FRIC_RHS_TOL * qs
    nz = np.empty(2 * m + 2, np.int64)
    _fr_pivot(T, basis, r, 2 * m, m, nz)
    entering = r + m
    for _ in range(LEMKE_MAX_PIVOTS * m):
        cmax = 0.0
        for i in range(m):
            cmax = max(cmax, abs(T[i, entering]))
        tol = LEMKE_PIVOT_TOL * cmax
        theta = np.inf
        for i in range(m):
            c = T[i, entering]
            if c > tol:
                b = T[i, rhs] if T[i, rhs] > rtol else 0.0
                theta = min(theta, b / c)
        if theta == np.inf:
            for i in range(m):
                if basis[i] == 2 * m and T[i, rhs] <= rtol:
                    _fr_basic_x(T, basis, m, x)
                    return 0
            return 1
        row = -1
        for i in range(m):
            c = T[i, entering]
            if c > tol:
                b = T[i, rhs] if T[i, rhs] > rtol else 0.0
                if b / c <= theta + FRIC_TIE_TOL * theta:
                    if basis[i] == 2 * m:
                        row = i
                        break
                    if row < 0 or _fr_lex_less(T, i, row, entering, m):
                        row = i
        leaving = basis[row]
        _fr_pivot(T, basis, row, entering, m, nz)
        if leaving == 2 * m:
            _fr_basic_x(T, basis, m, x)
            return 0
        entering = leaving + m if leaving < m else leaving - m
    return 2


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _fr_basic_x(T, basis, m, x):
    """x of the tableau's basic solution (the basic x variables at their right-hand sides, >= 0)."""
    for i in range(m):
        x[i] = 0.0
    for i in range(m):
        if basis[i] >= m and basis[i] < 2 * m:
            b = T[i, 2 * m + 1]
            x[basis[i] - m] = b if b > 0.0 else 0.0


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _fr_lex_less(T, a, b, c, m):
    """Row a before row b in the lexicographic rule on column c: the rows of B^-1 (the w columns)
    divided by their column-c entries, compared in order; entries within FRIC_TIE_TOL of the rows'
    largest ratio count as equal (exact ties that round-off split)."""
    big = 0.0
    for j in range(m):
        big = max(big, abs(T[a, j] / T[a, c]), abs(T[b, j] / T[b, c]))
    tol = FRIC_TIE_TOL * big
    for j in range(m):
        ra = T[a, j] / T[a, c]
        rb = T[b, j] / T[b, c]
        if abs(ra - rb) > tol:
            return ra < rb
    return a < b


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _fr_pivot(T, basis, r, c, m, nz):
    """Gauss-Jordan pivot on T[r, c]: column c's variable replaces basis[r]. The other rows are updated
    on the columns where the pivot row is nonzero only (nz: work array of 2m + 2 indices); for finite
    entries the skipped operations subtract zeros, so the result is the dense pivot's bit for bit."""
    nco = 2 * m + 2
    piv = T[r, c]
    nn = 0
    for j in range(nco):
        T[r, j] /= piv
        if T[r, j] != 0.0:
            nz[nn] = j
            nn += 1
    for i in range(m):
        if i != r:
            f = T[i, c]
            if f != 0.0:
                for jj in range(nn):
                    j = nz[jj]
                    T[i, j] -= f * T[r, j]
                T[i, c] = 0.0
    T[r, c] = 1.0
    basis[r] = c


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _fr_extract(x, ctc, nc, ia, ib, ip, im, mu, P, lt):
    """P_i = a + b (>= 0) and lt_i = beta+ - beta-, put into Coulomb's cone exactly (round-off), for
    the group's contacts."""
    for c in range(nc):
        i = ctc[c]
        p = x[ia[i]]
        if ib[i] >= 0:
            p += x[ib[i]]
        P[i] = p if p > 0.0 else 0.0
        t = 0.0
        if ip[i] >= 0:
            t = x[ip[i]] - x[im[i]]
            if abs(t) > mu[i] * P[i]:
                t = mu[i] * P[i] if t > 0.0 else -mu[i] * P[i]
        lt[i] = t


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _fr_check(A, u, mu, lam1, r, P, lt, fric, k, ctc, nc, qs, wmax):
    """The law's conditions on (P, lt) at the group's contacts, in velocity units (impulses times
    max W_ii): u+_n >= 0, the rebound graph between P_i and u+_n,i, and friction
    opposing a slip, lt_i = -mu_i P_i sign(u+_t,i) where |u+_t,i| is above the tolerance (the cone
    |lt_i| <= mu_i P_i holds exactly, _fr_extract). The tolerance is LCP_FEAS_TOL times the larger of qs
    and max W_ii times the largest impulse (the round-off of u+ = u- + W lam grows with lam: with
    dependent rows and a large mu, impulses that cancel, G^T lam = 0, can be large), times max(1, mu_i)
    (mu enters the tableau: Lemke's round-off grows with it)."""
    big = 0.0
    mmax = 1.0
    for c in range(nc):
        i = ctc[c]
        big = max(big, P[i], abs(lt[i]))
        mmax = max(mmax, mu[i])
    tol = LCP_FEAS_TOL * mmax * max(qs, big * wmax, 1e-300)
    for c in range(nc):
        i = ctc[c]
        vn = u[i]
        vt = u[k + i]
        for j in range(k):
            vn += A[i, j] * P[j]
            vt += A[k + i, j] * P[j]
            if fric[j]:
                vn += A[i, k + j] * lt[j]
                vt += A[k + i, k + j] * lt[j]
        if not (vn == vn and vt == vt):
            return False
        # distance of (P_i, u+_n,i) from the rebound graph, each branch in velocity units
        l1 = lam1[i]
        ri = r[i]
        pw = P[i] * wmax
        lw = l1 * wmax
        d_a = abs(vn) + max(0.0, lw - pw)                                     # u+ = 0, P >= lam1
        d_b = abs(pw - lw) + max(0.0, -vn) + max(0.0, vn - ri)               # P = lam1, 0 <= u+ <= r
        d_c = abs(vn - ri) + max(0.0, pw - lw)                               # u+ = r, P <= lam1
        d_d = pw + max(0.0, ri - vn)                                         # P = 0, u+ >= r
        if ri <= tol:                                                        # r = 0: P >= 0 _|_ u+ >= 0
            d_a = abs(vn)
        if min(min(d_a, d_b), min(d_c, d_d)) > tol:
            return False
        if fric[i] and abs(vt) > tol:
            want = -mu[i] * P[i] if vt > 0.0 else mu[i] * P[i]
            if abs(lt[i] - want) * wmax > tol:
                return False
    return True


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _fr_certified(A, mu, fric, k, ctc, nc, wmax):
    """The uniqueness bound of several contacts (docs/derivations/friction.md): W restricted to the
    group's rows (its normal rows, the tangent rows of its contacts with friction) minus c I positive
    definite, c = the group's max mu_i times the Frobenius norm of those tangent rows. Cholesky with
    pivots above LCP_RANK_TOL max W_ii."""
    idx = np.empty(2 * nc, np.int64)
    n = 0
    for a in range(nc):
        idx[n] = ctc[a]
        n += 1
    mmax = 0.0
    for a in range(nc):
        i = ctc[a]
        if fric[i]:
            idx[n] = k + i
            n += 1
            mmax = max(mmax, mu[i])
    fro = 0.0
    for a in range(nc, n):
        for b in range(n):
            fro += A[idx[a], idx[b]] ** 2
    c = mmax * math.sqrt(fro)
    L = np.zeros((n, n))
    for j in range(n):
        d = A[idx[j], idx[j]] - c
        for s in range(j):
            d -= L[j, s] * L[j, s]
        if not d > LCP_RANK_TOL * wmax:
            return False
        L[j, j] = math.sqrt(d)
        for rr in range(j + 1, n):
            s2 = A[idx[rr], idx[j]]
            for s in range(j):
                s2 -= L[rr, s] * L[j, s]
            L[rr, j] = s2 / L[j, j]
    return True


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)
def _fr_single(A, u, mu, lam1, r, i, box, fr, k, qs, wmax, P, lt):
    """One contact alone in its group: the number of stage 2's solutions, by enumeration of its pieces
    (normal: the rebound graph's four, or u+_n = 0 / P = 0 without rebound; tangential: stick, slide +,
    slide -, or none without friction), each a 2 x 2 linear system, candidates checked with the
    tolerances of _fr_check and counted once when they coincide. With one solution, P[i] and lt[i]
    are set to it (lt put into the cone exactly)."""
    wnn = A[i, i]
    wnt = A[i, k + i]
    wtt = A[k + i, k + i]
    tol = LCP_FEAS_TOL * max(qs, 1e-300)
    sols = np.empty((12, 2))
    ns = 0
    nn = 4 if box else 2
    nt = 3 if fr else 1
    for a in range(nn):
        for t in range(nt):
            # rows [c0 c1 | d]: c0 P + c1 lt = d
            if box:
                if a == 0:      # u+_n = 0
                    r0, r1, d0 = wnn, wnt, -u[i]
                elif a == 1:    # P = lam1
                    r0, r1, d0 = 1.0, 0.0, lam1[i]
                elif a == 2:    # u+_n = r
                    r0, r1, d0 = wnn, wnt, r[i] - u[i]
                else:           # P = 0
                    r0, r1, d0 = 1.0, 0.0, 0.0
            else:
                if a == 0:
                    r0, r1, d0 = wnn, wnt, -u[i]
                else:
                    r0, r1, d0 = 1.0, 0.0, 0.0
            if not fr:          # lt = 0
                s0, s1, d1 = 0.0, 1.0, 0.0
            elif t == 0:        # stick: u+_t = 0
                s0, s1, d1 = wnt, wtt, -u[k + i]
            else:               # slide: lt = -sigma mu P
                sg = 1.0 if t == 1 else -1.0
                s0, s1, d1 = sg * mu[i], 1.0, 0.0
            det = r0 * s1 - r1 * s0
            if abs(det) <= LCP_RANK_TOL * max(abs(r0 * s1), abs(r1 * s0), 1e-300):
                continue
            p_ = (d0 * s1 - r1 * d1) / det
            t_ = (r0 * d1 - d0 * s0) / det
            vn = u[i] + wnn * p_ + wnt * t_
            vt = u[k + i] + wnt * p_ + wtt * t_
            if p_ * wmax < -tol or vn < -tol:
                continue
            pw = p_ * wmax
            lw = lam1[i] * wmax
            if box:
                if a == 0 and lw - pw > tol:
                    continue
                if a == 1 and (vn > r[i] + tol):
                    continue
                if a == 2 and pw - lw > tol:
                    continue
                if a == 3 and vn < r[i] - tol:
                    continue
            if fr:
                if t == 0 and (abs(t_) - mu[i] * p_) * wmax > tol:
                    continue
                if t == 1 and vt < -tol:
                    continue
                if t == 2 and vt > tol:
                    continue
            new = True
            for q in range(ns):
                if (abs(sols[q, 0] - p_) + abs(sols[q, 1] - t_)) * wmax <= 10.0 * tol:
                    new = False
            if new:
                sols[ns, 0] = p_
                sols[ns, 1] = t_
                ns += 1
    if ns == 1:
        P[i] = max(sols[0, 0], 0.0)
        t_ = sols[0, 1]
        if abs(t_) > mu[i] * P[i]:
            t_ = mu[i] * P[i] if t_ > 0.0 else -mu[i] * P[i]
        lt[i] = t_ if fr else 0.0
    return ns
