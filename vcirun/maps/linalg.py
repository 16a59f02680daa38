# numba source unit: small dense linear algebra without allocation or LAPACK call overhead.
# (Source units are assembled into one generated module per scene and method; see vcirun.codegen.)
import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def solve_small(A, b, n):
    """Solve A x = b in place (x returned in b) by Gaussian elimination with partial pivoting.
    A (n, n) is destroyed. Returns False if A is singular to working precision."""
    for k in range(n):
        piv = k
        amax = abs(A[k, k])
        for i in range(k + 1, n):
            if abs(A[i, k]) > amax:
                amax = abs(A[i, k])
                piv = i
        if amax == 0.0 or not math.isfinite(amax):
            return False
        if piv != k:
            for j in range(n):
                tmp = A[k, j]
                A[k, j] = A[piv, j]
                A[piv, j] = tmp
            tmp = b[k]
            b[k] = b[piv]
            b[piv] = tmp
        inv = 1.0 / A[k, k]
        for i in range(k + 1, n):
            f = A[i, k] * inv
            if f != 0.0:
                for j in range(k + 1, n):
                    A[i, j] -= f * A[k, j]
                b[i] -= f * b[k]
    for k in range(n - 1, -1, -1):
        s = b[k]
        for j in range(k + 1, n):
            s -= A[k, j] * b[j]
        b[k] = s / A[k, k]
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def norm_inf(x):
    m = 0.0
    for i in range(x.shape[0]):
        a = abs(x[i])
        if a > m or a != a:  # NaN propagates as failure
            m = a if a == a else np.inf
    return m


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
