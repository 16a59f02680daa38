# numba source unit: small dense linear algebra without allocation or LAPACK call overhead; it needs
# no generated name, so any module (and the impact law on its own) can hold it.
import math

from numba import njit

# An array whose size grows with the contacts squared (a Delassus matrix, the Newton matrix of many held
# contacts) is stack scratch up to this many doubles (32 KB) and on the heap beyond: a thread's stack
# (8 MB) would not hold 1000 contacts squared, and the heap's allocation is then small beside the work.
STACK_DOUBLES = 4096


@njit(cache=True, nogil=True, error_model="numpy")
def solve_band(A, b, n, bw, tiny=0.0):
    """Solve A x = b in place (x returned in b) by Gaussian elimination with partial pivoting, for a
    matrix whose entries (i, j) with |i - j| > bw are zero: the elimination restricted to the band
    (rows k..k + bw below a pivot; with row exchanges the upper band of the factor widens to 2 bw,
    as in LAPACK's gbtrf). The skipped operations only add zeros, so the result has the bits of the
    dense elimination (bw = n - 1, `solve_small`). O(n bw^2) instead of O(n^3) plus O(n^2) scans: a
    line of 100 free balls solves its diagonal step Jacobian in O(n). A (n, n) is destroyed.
    Returns False if a pivot is not above `tiny` (0: A is singular to working precision; the impact
    law passes its rank tolerance) or not finite. The units pass `tiny` always: numba compiles a call
    that omits it as a specialization of its own.

    n <= 2 (the paper's scenes: cart-pendulum, double pendulum, one-DOF oscillators) runs straight-line
    code with the loops' operations in their order (the same bits and the same A and b left behind,
    `_eliminate`): a Newton step solves one such system per iteration, and the loops' bounds and
    branches cost as much as the arithmetic there."""
    if n == 2:
        return _solve2(A, b, bw, tiny)
    if n == 1:
        amax = abs(A[0, 0])
        if not amax > tiny or not math.isfinite(amax):
            return False
        b[0] = b[0] / A[0, 0]
        return True
    return _eliminate(A, b, n, bw, tiny)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _solve2(A, b, bw, tiny):
    """`_eliminate` at n = 2 written out (the same operations in the same order)."""
    a00 = A[0, 0]
    a01 = A[0, 1]
    a10 = A[1, 0]
    a11 = A[1, 1]
    b0 = b[0]
    b1 = b[1]
    amax = abs(a00)
    if bw >= 1 and abs(a10) > amax:
        amax = abs(a10)
        a00, a01, a10, a11 = a10, a11, a00, a01
        b0, b1 = b1, b0
    if not amax > tiny or not math.isfinite(amax):
        return False
    if bw >= 1:
        f = a10 * (1.0 / a00)
        if f != 0.0:
            a11 -= f * a01
            b1 -= f * b0
        A[0, 0] = a00
        A[0, 1] = a01
        A[1, 0] = a10
        A[1, 1] = a11
    amax = abs(a11)
    if not amax > tiny or not math.isfinite(amax):
        b[0] = b0
        b[1] = b1
        return False
    b1 = b1 / a11
    if bw >= 1:
        b0 = (b0 - a01 * b1) / a00
    else:
        b0 = b0 / a00
    b[0] = b0
    b[1] = b1
    return True


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _eliminate(A, b, n, bw, tiny=0.0):
    """`solve_band`'s elimination and back substitution for any n (inline: no call more per solve
    than the loops had; the MCVA family's Gauss-Newton solves are 8 x 8 and larger)."""
    for k in range(n):
        rows = min(n, k + bw + 1)
        cols = min(n, k + 2 * bw + 1)
        piv = k
        amax = abs(A[k, k])
        for i in range(k + 1, rows):
            if abs(A[i, k]) > amax:
                amax = abs(A[i, k])
                piv = i
        if not amax > tiny or not math.isfinite(amax):
            return False
        if piv != k:
            for j in range(k, cols):
                tmp = A[k, j]
                A[k, j] = A[piv, j]
                A[piv, j] = tmp
            tmp = b[k]
            b[k] = b[piv]
            b[piv] = tmp
        inv = 1.0 / A[k, k]
        for i in range(k + 1, rows):
            f = A[i, k] * inv
            if f != 0.0:
                for j in range(k + 1, cols):
                    A[i, j] -= f * A[k, j]
                b[i] -= f * b[k]
    for k in range(n - 1, -1, -1):
        s = b[k]
        for j in range(k + 1, min(n, k + 2 * bw + 1)):
            s -= A[k, j] * b[j]
        b[k] = s / A[k, k]
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def solve_small(A, b, n, tiny=0.0):
    """`solve_band` of a dense matrix (bw = n - 1): its loops then run over whole rows and columns."""
    return solve_band(A, b, n, n - 1, tiny)


@njit(cache=True, nogil=True, error_model="numpy")
def positive_definite(A, n):
    """True if the symmetric part of A (n x n) is positive definite: its Cholesky factorisation exists
    with finite positive pivots. A's lower triangle is destroyed."""
    for j in range(n):
        for i in range(j, n):
            s = 0.5 * (A[i, j] + A[j, i])
            for k in range(j):
                s -= A[i, k] * A[j, k]
            if i == j:
                if not (s > 0.0 and math.isfinite(s)):
                    return False
                A[j, j] = math.sqrt(s)
            else:
                A[i, j] = s / A[j, j]
    return True


# Element loops instead of slice assignment: numba compiles `a[:] = b` through a generic path
# that pulls in string formatting and costs seconds of compile time per module.
@njit(cache=True, nogil=True, error_model="numpy")
def copy_into(dst, src):
    for i in range(src.shape[0]):
        dst[i] = src[i]


@njit(cache=True, nogil=True, error_model="numpy")
def set_row(M, k, src):
    for i in range(src.shape[0]):
        M[k, i] = src[i]
