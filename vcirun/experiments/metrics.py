"""Metrics of runs: L2 trajectory error, energy variation, timing statistics.

Pure numpy/scipy (no sympy): used by the sweep workers and by the figure and table builders.
"""
from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass

import numpy as np


__all__ = ["l2_error", "mean_ci", "TimingStat", "timing_stats",
           "l2_series"]


def l2_error(traj, ref) -> float:
    """sqrt(h * sum_k |q_k - q_ref(t_k)|^2) over the run's grid: `vcirun.l2_error`, the one definition."""
    import vcirun

    return float(vcirun.l2_error(traj, ref))


def mean_ci(values, level: float = 0.95) -> tuple[float, float, int]:
    """(mean, half-width of the Student-t confidence interval at `level`, n). Half-width is NaN for n < 2."""
    from scipy.special import stdtrit   # the Student-t quantile (scipy.stats.t.ppf's own; scipy.stats costs 1 s to import)

    x = np.asarray([v for v in values if v is not None and np.isfinite(v)], float)
    n = int(x.size)
    if n == 0:
        return math.nan, math.nan, 0
    mean = float(x.mean())
    if n < 2:
        return mean, math.nan, n
    half = float(stdtrit(n - 1, 0.5 + level / 2) * x.std(ddof=1) / math.sqrt(n))
    return mean, half, n


@dataclass
class TimingStat:
    label: str
    method_index: int
    h: float
    n: int
    mean: float
    halfwidth: float
    std: float
    n_failed: int


def timing_stats(runs, level: float = 0.95) -> list[TimingStat]:
    """Computation time per (method, h) over the initial conditions: mean and t-interval of
    `wall_time` (the core's integration time) over runs that finished with status ok on the compiled
    tier (a run on the interpreted tier has no wall_time: vcirun.experiments.worker)."""
    groups: dict[tuple, list] = defaultdict(list)
    failed: dict[tuple, int] = defaultdict(int)
    index: dict[str, int] = {}
    for r in runs:
        key = (r.attrs["label"], float(r.attrs["h"]))
        index[key[0]] = int(r.attrs.get("method_index", 0))
        wt = r.attrs.get("wall_time")
        if r.attrs.get("status") == "ok" and wt is not None and math.isfinite(float(wt)):
            groups[key].append(float(wt))
        elif r.attrs.get("status") == "ok":   # run on the interpreted tier: its time is not the method's
            groups.setdefault(key, [])
        else:
            failed[key] += 1
            groups.setdefault(key, [])
    out = []
    for (label, h), xs in groups.items():
        mean, half, n = mean_ci(xs, level)
        std = float(np.std(xs, ddof=1)) if len(xs) > 1 else math.nan
        out.append(TimingStat(label, index[label], h, n, mean, half, std, failed[(label, h)]))
    out.sort(key=lambda s: (s.method_index, -s.h))
    return out


def l2_series(runs) -> dict[tuple, tuple[np.ndarray, np.ndarray]]:
    """{(label, h): (betas, l2 errors)} sorted by beta, over runs with a finite beta. Runs without an
    L2 error (failed, or no reference) appear as NaN so gaps stay visible."""
    acc: dict[tuple, list] = defaultdict(list)
    for r in runs:
        beta = r.attrs.get("beta")
        if beta is None or not np.isfinite(beta):
            continue
        l2 = r.attrs.get("l2_error")
        acc[(r.attrs["label"], float(r.attrs["h"]))].append((float(beta), math.nan if l2 is None else float(l2)))
    out = {}
    for key, pts in acc.items():
        pts.sort()
        out[key] = (np.array([p[0] for p in pts]), np.array([p[1] for p in pts]))
    return out
