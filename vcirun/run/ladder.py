"""The runs of one method from one start, read as a ladder: nested runs (each N a multiple of the
coarser ones) give the error constant C of e(N) = C N^-p (`assess`), the observed order of three runs
(`_observed_order`), and the Richardson estimate of one run from its companion and a third run
(`estimate_of`, which also runs the grazing check and reads an order short of p near round-off as
round-off amplified by the motion). Used by vcirun.run.choose."""
from __future__ import annotations

import math
from dataclasses import dataclass

from .estimate import ErrorEstimate, difference, near_misses, roundoff_level, sequence_difference, slope_scale
from .pilot import Run

def _observed_order(Na, Nb, Nc, dab, dbc) -> float | None:
    """p with dab / dbc = (Nb/Na)^p (1 - (Na/Nb)^p) / (1 - (Nb/Nc)^p) (nested runs a < b < c), by bisection."""
    if not (dab > 0 and dbc > 0):
        return None
    target = math.log(dab / dbc)
    log_ba, ab, bc = math.log(Nb / Na), Na / Nb, Nb / Nc   # (constant over the bisection: the same floats)
    log1p = math.log1p
    # f(p) = p log_ba + log1p(-ab^p) - log1p(-bc^p) - target, written out in the loop (the same operations)
    lo, hi = 0.05, 30.0
    if lo * log_ba + log1p(-ab ** lo) - log1p(-bc ** lo) - target > 0:
        return 0.0
    if hi * log_ba + log1p(-ab ** hi) - log1p(-bc ** hi) - target < 0:
        return hi
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if mid * log_ba + log1p(-ab ** mid) - log1p(-bc ** mid) - target > 0:
            hi = mid
        else:
            lo = mid
    return 0.5 * (lo + hi)


@dataclass
class Assessment:
    """What the runs of one method say: status "resolved" (C, the coarsest resolved N, the observed
    order where three nested runs exist), "saturated" (differences at round-off: any resolved N
    reaches tol down to `floor`), "unresolved" (the last two runs differ in their impacts or the
    order is not seen) or "failed" (no two ok runs)."""

    status: str
    C: float | None = None
    N_resolved: int | None = None
    observed: float | None = None
    floor: float = 0.0
    note: str = ""
    N_asymptotic: int | None = None   # the coarsest N of the three runs that showed the order


def _difference(coarse: Run, fine: Run):
    """difference(coarse, fine), kept on the fine run (a ladder compares the same pairs again)."""
    d = fine.diffs.get(coarse.N)
    if d is None:
        d = fine.diffs[coarse.N] = difference(coarse, fine)
    return d


MAX_RATIO = 8     # a Richardson companion is at least 1/MAX_RATIO as fine as its run
NOISE = 10.0      # an order short of p is read as amplified round-off where order p puts the run this near it


def _companion(runs: dict, N: int, max_ratio: int = MAX_RATIO) -> Run | None:
    """The largest ok run whose N divides N at most max_ratio times (the Richardson companion of run N)."""
    best = None
    for M, r in runs.items():
        if M < N and N % M == 0 and N <= max_ratio * M and r.ok and (best is None or M > best.N):
            best = r
    return best


def _finest(runs: dict, N: int) -> Run | None:
    """The finest ok run of the ladder finer than N (None if there is none)."""
    M = max((M for M, r in runs.items() if M > N and r.ok), default=None)
    return None if M is None else runs[M]


def estimate_of(runs: dict, N: int, p: float, mod=None, prm=None, grazing=True,
                order_from: int | None = None) -> ErrorEstimate:
    """The Richardson estimate of run N from its companion among `runs` (ratio r = N / N_companion),
    with the observed order from a third nested run where there is one; "unresolved" where the
    companion's impacts, or the finest run's of the ladder, differ from run N's. order_from: the scene model's
    word that the order showed at or above this N (vcirun.run.choose, later calls): without a third
    run, a companion at or above it makes the estimate checked on that word (extras["order_from_model"],
    the bracket one order wide, as for check_order=False), not on this start's runs."""
    run = runs[N]
    comp = _companion(runs, N)
    if not run.ok:
        return ErrorEstimate("richardson", "failed", run.h, order=p, message=f"the run ended with status {run.status}")
    if comp is None:
        return ErrorEstimate("richardson", "failed", run.h, order=p, message="no companion run")
    r = N // comp.N
    d = _difference(comp, run)
    est = ErrorEstimate("richardson", "ok", run.h, order=p, companion_h=(comp.h,), first_difference=d.first)
    if d.first:
        est.status, est.message = "unresolved", f"the runs do not resolve the impacts: {d.first}"
        return est
    # the finest run of the ladder sees impacts that run N and its companion may both miss (a block at
    # rest after two impacts at N = 32 and 64, rocking on at N = 128 and above): Richardson on a pair
    # that agrees with itself is no bound then
    fine = _finest(runs, N)
    if fine is not None:
        first, _ = sequence_difference(run, fine, f"h = {run.h:.6g}", f"h = {fine.h:.6g}")
        if first:
            est.status, est.first_difference = "unresolved", first
            est.message = f"a finer run of the same method (N = {fine.N}) has other impacts: {first}"
            return est
    floor = roundoff_level(run)
    third = _companion(runs, comp.N, 4)
    # checked: a third run showed the order (or the pair agrees to round-off); without it the bracket
    # allows the pair to be two orders short of p (one for p <= 2), and _pursue does not accept it
    margin = min(2.0, max(p - 1.0, 0.5))
    est.extras["checked"] = d.l2 <= floor
    if third is None and d.l2 > floor and order_from is not None and comp.N >= order_from:
        # no observed order: the order the model saw on other starts of the scene at this N (the
        # choice accepts such an estimate only far below tol: vcirun.run.choose, THIRD_FREE)
        margin = 1.0
        est.extras["checked"] = est.extras["order_from_model"] = True
    if third is not None and d.l2 > floor:
        d0 = _difference(third, comp)
        if not d0.first and d0.l2 > floor:
            margin = 1.0
            est.extras["checked"] = True
            est.extras["third"] = third.N
            p_obs = _observed_order(third.N, comp.N, N, d0.l2, d.l2)
            est.observed_order = p_obs
            if p_obs is not None and p_obs < 1.0:
                est.status = "unresolved"
                est.message = f"the differences do not shrink with h (observed order {p_obs:.2f})"
                est.extras["noise"] = max(d0.l2, d.l2)   # (the choice may measure round-off against them)
                return est
            if p_obs is not None and p_obs < p - 1.0 and d.l2 / (r ** p - 1.0) < NOISE * floor:
                est.extras["noise"] = max(d0.l2, d.l2)
                # an order more than one short where the verified order would put the run near round-off:
                # the differences are round-off amplified by the motion (each impact multiplies it), not
                # the step's error, and the finer run need not be the more accurate one
                est.status = "unresolved"
                est.message = (f"the differences shrink at order {p_obs:.2f}, not {p:g}, within {NOISE:g} times "
                               f"the round-off level ({floor:.1e}) at order {p:g}: round-off amplified by the "
                               "motion, not the step, sets them")
                return est
            if p_obs is not None and p_obs < p - 0.5:
                # the coarser runs are not yet asymptotic: the order they show, the smaller (safer) one
                est.note = f"observed order {p_obs:.2f} used (verified order {p:g})"
                p = p_obs
            margin = 0.5 if p_obs is not None and abs(p_obs - p) <= 0.5 else 1.0
    R = r ** p
    est.l2 = d.l2 / (R - 1.0)
    lo_R, hi_R = r ** (p + margin), r ** max(p - margin, 0.0)
    est.l2_bounds = (d.l2 / (lo_R + 1.0), d.l2 / (hi_R - 1.0) if hi_R > 1.0 else math.inf)
    est.final_q = d.final_q / (R - 1.0)
    est.final_p = d.final_p / (R - 1.0)
    # round-off: the run's own share of it is not in d; the bracket's upper end is at least its level
    est.l2_bounds = (est.l2_bounds[0], max(est.l2_bounds[1], floor))
    est.extras["floor"] = floor
    if d.l2 <= floor or est.l2 < floor:
        est.note = f"at the round-off level of these runs (<= {floor:.1e})"
    if grazing and mod is not None:
        margin_phi = 2.0 * d.sup_q / (R - 1.0) * slope_scale(run, mod, prm)
        miss = near_misses(run, mod, prm, margin_phi, screen=comp)
        if miss:
            t, c, low = miss[0]
            est.status = "unresolved"
            est.first_difference = (f"contact {c} comes within the run's error of its surface near t = {t:.6g} "
                                    f"(phi down to {low:.3g}) without an impact: a grazing impact, or one just "
                                    "before the end, may be missed")
            est.message = "a contact the grid does not resolve: " + est.first_difference
            est.l2 = est.l2_bounds = est.final_q = est.final_p = None
    return est


def assess(runs: dict, p: float, need_order: bool = False) -> Assessment:
    """Read C (e = C N^-p) from the finest resolved pair of nested runs; need_order: only once a third
    nested run shows the order (at least p - 1)."""
    ok = sorted(N for N, r in runs.items() if r.ok)
    if len(ok) < 2:
        return Assessment("failed", note="fewer than two runs finished")
    pairs = []
    for N in ok:
        c = _companion(runs, N)
        if c is not None:
            pairs.append((c.N, N, _difference(c, runs[N])))
    if not pairs:
        return Assessment("failed", note="no nested pair of runs")
    # the coarsest N from which every finer pair agrees in its impacts
    N_res = None
    for a, b, d in reversed(pairs):
        if d.first:
            break
        N_res = a
    a, b, d = pairs[-1]
    if d.first:
        return Assessment("unresolved", note=d.first)
    floor = roundoff_level(runs[b])
    r = b // a
    if d.l2 <= floor:
        return Assessment("saturated", C=0.0, N_resolved=N_res, floor=floor, N_asymptotic=N_res,
                          note=f"differences at round-off level ({d.l2:.1e} <= {floor:.1e})")
    observed = a0 = None
    if len(pairs) >= 2:
        a0, b0, d0 = pairs[-2]
        if b0 == a and not d0.first and d0.l2 > floor:
            observed = _observed_order(a0, a, b, d0.l2, d.l2)
            if observed is not None and observed < p - 1.0:
                return Assessment("unresolved", observed=observed,
                                  note=f"differences shrink at order {observed:.2f}, not {p:g}")
    if need_order and observed is None:
        return Assessment("unresolved", note="the order is not yet seen (two runs)")
    e_b = d.l2 / (r ** p - 1.0)
    return Assessment("resolved", C=e_b * b ** p, N_resolved=N_res, observed=observed, floor=floor,
                      N_asymptotic=a0 if observed is not None else None)
