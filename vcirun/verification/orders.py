"""Observed orders: the ONE order estimator of the test suite and of `vcirun verify`.

fit_order      : least-squares slope of log(err) against log(h), round-off plateau masked
local_slopes   : slopes between consecutive points of a ladder (coarse to fine)
asymptotic_h   : the h from which on every finer local slope is within a tolerance of the theory
drift_slope    : least-squares slope (with 95% CI) of windowed max |H - H0| against time

No sympy, no scipy at import (scipy.stats is imported where drift_slope needs it).
"""
from __future__ import annotations

import numpy as np

EPS = np.finfo(float).eps


class OrderFitError(AssertionError):
    """Too few usable points for an order fit (an AssertionError: the test suite asserts with it)."""


def plateau_mask(hs, errs, scale=1.0, plateau=1e3, min_local_slope=0.5) -> np.ndarray:
    """The points an order fit may use (in the order given), coarse to fine until the round-off plateau.

    Going from coarse to fine h, the plateau starts at the first point whose error is not finite or is
    below `plateau` * eps * `scale` (round-off level relative to the solution's magnitude `scale`), or
    where the error stops decreasing (local slope against the previous point below `min_local_slope`);
    that point and every finer one are dropped."""
    hs = np.asarray(hs, float)
    errs = np.asarray(errs, float)
    keep = np.zeros(hs.size, bool)
    prev = None
    for i in np.argsort(hs)[::-1]:  # coarse to fine
        e = errs[i]
        if not np.isfinite(e) or e <= plateau * EPS * scale:
            break
        if prev is not None and np.log(errs[prev] / e) < min_local_slope * np.log(hs[prev] / hs[i]):
            break  # stalled: round-off (or Newton tolerance) dominated from here on
        keep[i] = True
        prev = i
    return keep


def fit_order(hs, errs, scale=1.0, plateau=1e3, min_local_slope=0.5):
    """Observed order: least-squares slope of log(err) against log(h) over `plateau_mask`'s points.

    Returns (slope, mask), mask marking the points used (in the order given). Raises OrderFitError
    (an AssertionError) if fewer than 3 remain."""
    hs = np.asarray(hs, float)
    errs = np.asarray(errs, float)
    keep = plateau_mask(hs, errs, scale, plateau, min_local_slope)
    if keep.sum() < 3:
        raise OrderFitError(f"fit_order: fewer than 3 usable points (h={hs.tolist()}, err={errs.tolist()})")
    slope = np.polyfit(np.log(hs[keep]), np.log(errs[keep]), 1)[0]
    return float(slope), keep


def local_slopes(hs, errs):
    """(h_fine, slope) for each consecutive pair of the ladder sorted coarse to fine: the slope of
    log err between the pair, attributed to its finer step. Pairs with a non-positive or non-finite
    error give nan."""
    hs = np.asarray(hs, float)
    errs = np.asarray(errs, float)
    o = np.argsort(hs)[::-1]
    out = []
    for a, b in zip(o[:-1], o[1:]):
        ea, eb = errs[a], errs[b]
        ok = np.isfinite(ea) and np.isfinite(eb) and ea > 0 and eb > 0
        out.append((float(hs[b]), float(np.log(ea / eb) / np.log(hs[a] / hs[b])) if ok else float("nan")))
    return out


def asymptotic_h(hs, errs, mask, order, tol=0.15, one_sided=False, floor=0.0):
    """(h, k): the asymptotic regime of a ladder. Among the points of `mask` whose error is above
    `floor` (points near the round-off plateau bend the finest slopes), the finest run of local
    slopes between consecutive points within `tol` of `order` (one_sided: at least order - tol) spans
    k points, the coarsest of which is h: the order is observed at and below h. (None, 0) if not even
    the finest pair is in range."""
    hs = np.asarray(hs, float)
    errs = np.asarray(errs, float)
    m = np.asarray(mask, bool) & (errs > floor)
    used = np.sort(hs[m])[::-1]
    sl = [s for _, s in local_slopes(hs[m], errs[m])]  # coarse to fine
    k = 0
    for s in reversed(sl):
        if not (np.isfinite(s) and (s >= order - tol if one_sided else abs(s - order) <= tol)):
            break
        k = k + 1 if k else 2
    return (float(used[used.size - k]), k) if k else (None, 0)


def drift_slope(t, dH, n_windows=100):
    """Split the run into n_windows equal windows, take max |H - H0| in each, and fit a line against
    the window centre time. Returns (slope, (ci_lo, ci_hi) 95%, window maxima)."""
    from scipy import stats

    t = np.asarray(t, float)
    dH = np.abs(np.asarray(dH, float))
    idx = np.array_split(np.arange(t.size), n_windows)
    tc = np.array([t[i].mean() for i in idx])
    wmax = np.array([dH[i].max() for i in idx])
    res = stats.linregress(tc, wmax)
    tq = stats.t.ppf(0.975, n_windows - 2)
    return float(res.slope), (res.slope - tq * res.stderr, res.slope + tq * res.stderr), wmax
