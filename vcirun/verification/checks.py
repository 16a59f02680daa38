"""Verdicts: each check of `vcirun verify` as a `Check` (pass / warn / fail / skip, the number, the
threshold, what theory expects), built from measured data by the functions below.

A skip is a check that does not apply or could not be run (e.g. symplecticity of a forced map); it
never fails the verification but is reported with its reason.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .orders import EPS, OrderFitError, asymptotic_h, fit_order, local_slopes

PASS, WARN, FAIL, SKIP = "pass", "warn", "fail", "skip"
ORDER_TOL = 0.15          # the (and tests/convergence's) tolerance on an observed order
MH_TOL = 0.3              # the tolerance of tests/convergence/test_modified_conservation
SYMPLECTIC_THRESHOLDS = (1e-8, 1e-6)   # max |J^T Omega J - Omega| (tests/convergence/test_structure: 1e-8)
COND_WARN = 1e4           # cond(M) above this: nearly singular (vcirun.run.api's failure diagnosis uses 1e4)
LAMBDA_RATIO_WARN = 1e-4  # smallest eigenvalue of M fallen below this fraction of its value at q0
ASYMPTOTIC_REL = 1e-3     # an order miss with relative errors below this is a wrong method, not a coarse ladder
NEAR_ROUND_OFF = 1e5      # errors below this many eps (relative) are near the plateau: not used for the asymptotic h
ENVELOPE_TOL = 0.3        # an error that scatters in h: its upper envelope's slope within this of the theory warns
ENERGY_TOL = 0.3          # one-sided tolerance on the order of the energy change across impact steps
IMPACT_RATIO = 10.0       # ... or an impact step changes the energy at most this many times a smooth step


def envelope_slope(hs, errs, floor: float):
    """(slope, points) of the upper envelope of a ladder's errors above `floor`: at each h the largest
    error at that or any finer h, fitted in log-log. An error that is not monotone in h (VCI's through
    impacts depends on where each impact falls in its step) scatters about C h^p; its envelope falls at
    order p. (nan, k) with fewer than 3 points."""
    hs = np.asarray(hs, float)
    errs = np.asarray(errs, float)
    m = np.isfinite(errs) & (errs > floor)
    h, e = hs[m], errs[m]
    if h.size < 3:
        return float("nan"), int(h.size)
    o = np.argsort(h)   # fine to coarse: the running maximum is the envelope
    env = np.maximum.accumulate(e[o])
    if np.unique(h).size < 3:
        return float("nan"), int(h.size)
    return float(np.polyfit(np.log(h[o]), np.log(env), 1)[0]), int(h.size)


def _scatter_warning(name, method, hs, errs, theory, one_sided, scale, quantity, thr, expected, rows, data, local):
    """The warning for a ladder whose errors scatter in h -- some local slope below half the theory's
    order and some above it -- but whose upper envelope falls at the theory's order (within
    ENVELOPE_TOL), else None: such a method is not shown wrong by the ladder. A clean wrong order (every
    local slope near one value) is not scatter and still fails."""
    floor = NEAR_ROUND_OFF * EPS * scale
    m = np.isfinite(errs) & (errs > floor)
    sl = [x for _, x in local_slopes(hs[m], errs[m])]
    sl = [x for x in sl if np.isfinite(x)]
    if not sl or not (min(sl) < 0.5 * theory and max(sl) > theory):
        return None
    slope, k = envelope_slope(hs, errs, floor)
    if not np.isfinite(slope) or not (slope >= theory - ENVELOPE_TOL if one_sided
                                      else abs(slope - theory) <= ENVELOPE_TOL):
        return None
    data["envelope_slope"] = slope
    return Check(name, method, WARN, slope, thr, expected,
                 f"the {quantity} is not monotone in h (local slopes {local}), and the upper envelope of its "
                 f"{k} points above 100x round-off falls at order {slope:.3g}: consistent with order {theory:g} "
                 "for an error that depends on where each impact falls in its step (VCI); a longer ladder would "
                 "fit it", rows, data)


@dataclass
class Check:
    """One verdict. name: the check; method: the method or None (system-level); value: the number
    judged; threshold: what it was judged against (text); expected: what theory says; note: why;
    rows: the measured data (a list of dicts, shown as a table in the report)."""

    name: str
    method: str | None
    verdict: str
    value: float
    threshold: str
    expected: str
    note: str = ""
    rows: list = field(default_factory=list)
    data: dict = field(default_factory=dict)

    @property
    def failed(self) -> bool:
        return self.verdict == FAIL

    def line(self) -> str:
        who = f" [{self.method}]" if self.method else ""
        val = "-" if self.value is None or not np.isfinite(self.value) and self.verdict == SKIP else fmt(self.value)
        return f"{self.verdict.upper():4s}  {self.name}{who}: {val} (threshold {self.threshold}; expected {self.expected})" + (
            f" - {self.note}" if self.note else "")


def fmt(x) -> str:
    """A number for the report: 3 significant digits, exponent form outside [1e-2, 1e4)."""
    if x is None:
        return "-"
    x = float(x)
    if not np.isfinite(x):
        return str(x)
    return f"{x:.3g}" if 1e-2 <= abs(x) < 1e4 or x == 0 else f"{x:.2e}"


def by_threshold(value, thresholds) -> str:
    """pass if value <= thresholds[0], warn if <= thresholds[1], fail otherwise (nan fails)."""
    lo, hi = thresholds
    if value <= lo:
        return PASS
    if value <= hi:
        return WARN
    return FAIL


def skip(name, method, reason, expected="-") -> Check:
    return Check(name, method, SKIP, float("nan"), "-", expected, reason)


# --- derivatives ---------------------------------------------------------------------------------

def derivative_check(method, rows, n_probes) -> Check:
    """rows from vcirun.verification.fd.check_kernels; the verdict of the worst row."""
    order = {PASS: 0, WARN: 1, FAIL: 2}
    out, worst, worst_row = [], PASS, None
    for r in rows:
        v = by_threshold(r["worst"], r["thresholds"])
        out.append({"kernel": r["kernel"], "checked against": r["against"], "max rel. error": fmt(r["worst"]),
                    "pass / warn below": f"{r['thresholds'][0]:.0e} / {r['thresholds'][1]:.0e}", "verdict": v})
        ratio = r["worst"] / r["thresholds"][0]
        if worst_row is None or order[v] > order[worst] or (order[v] == order[worst] and ratio > worst_row[0]):
            worst, worst_row = max(worst, v, key=order.get), (ratio, r)
    if worst_row is None:
        return skip("derivatives", method, "the module defines none of the checked kernels")
    r = worst_row[1]
    return Check("derivatives", method, worst, r["worst"], f"{r['thresholds'][0]:.0e} relative ({r['kernel']})",
                 "agreement to FD truncation / round-off",
                 f"{len(rows)} kernel checks at {n_probes} states; worst relative to its threshold: {r['kernel']}", out)


# --- hyperregularity -------------------------------------------------------------------------------

def hyperregularity_check(samples, lam0) -> Check:
    """samples: list of (source, t, q, eigenvalues of M(q) ascending or None if M(q) is not finite,
    h) with h None for an exact solution (the nonsmooth reference, the smooth solution) and the step
    of a method's run otherwise; lam0: smallest eigenvalue of M(q0).

    Judged on the exact solutions (if there are none: on each method's finest run): fail at the
    earliest state where M(q) is not finite or not positive definite, warn at the earliest where it is
    nearly singular (cond(M) > COND_WARN or lambda_min < LAMBDA_RATIO_WARN lambda_min(M(q0))). Runs
    that leave the region the exact motion stays in (coarse steps going astray) warn."""
    if not samples:
        return skip("hyperregularity", None, "no states of the motion were available")
    thr = f"lambda_min > 0; cond(M) <= {COND_WARN:.0e}, lambda_min >= {LAMBDA_RATIO_WARN:.0e} x at q0"
    expected = "M(q) symmetric positive definite and well conditioned along the motion"
    exact = [x for x in samples if x[4] is None]
    if exact:
        primary, secondary = exact, [x for x in samples if x[4] is not None]
        basis = "the exact solutions"
    else:
        finest = {}
        for x in samples:
            finest[x[0].rsplit(" h = ", 1)[0]] = min(finest.get(x[0].rsplit(" h = ", 1)[0], np.inf), x[4])
        primary = [x for x in samples if x[4] == finest[x[0].rsplit(" h = ", 1)[0]]]
        secondary = [x for x in samples if x not in primary]
        basis = "the finest run of each method (no exact solution)"
    rows = []

    def stats(group):
        lam = np.array([ev[0] if ev is not None else np.nan for _, _, _, ev, _ in group])
        cond = np.array([ev[-1] / ev[0] if ev is not None and ev[0] > 0 else np.inf for _, _, _, ev, _ in group])
        return lam, cond, np.array([t for _, t, _, _, _ in group])

    def where(group, i):
        src, t, q, _, _ = group[i]
        return f"{src}, t = {t:.6g}, q = {fmt_vec(q)}"

    def earliest(ts, m):
        idx = np.flatnonzero(m)
        return int(idx[np.argmin(ts[idx])]) if idx.size else None

    lam, cond, ts = stats(primary)
    fin = np.isfinite(lam)
    for label, group in (("exact motion" if exact else "finest runs", primary), ("runs", secondary)):
        if not group:
            continue
        l_, c_, _ = stats(group)
        if np.isfinite(l_).any():
            i = int(np.nanargmin(l_))
            rows.append({"along": label, "quantity": "smallest eigenvalue of M", "value": fmt(l_[i]),
                         "relative to M(q0)'s": fmt(l_[i] / lam0), "where": where(group, i)})
            pos = np.flatnonzero(np.isfinite(l_) & (l_ > 0))
            if pos.size:
                j = int(pos[np.argmax(c_[pos])])
                rows.append({"along": label, "quantity": "condition number of M", "value": fmt(c_[j]),
                             "relative to M(q0)'s": "", "where": where(group, j)})
    n = len(primary)
    i = earliest(ts, ~fin)
    if i is not None:
        return Check("hyperregularity", None, FAIL, float("nan"), thr, expected,
                     f"M(q) is not finite at {where(primary, i)} (judged on {basis}, {n} states)", rows)
    i = earliest(ts, lam <= 0)
    if i is not None:
        before = np.flatnonzero((ts <= ts[i]) & (lam > 0))
        hint = ""
        if before.size:
            j = int(before[np.argmax(cond[before])])
            hint = f"; before that cond(M) reaches {cond[j]:.3g} (t = {ts[j]:.6g})"
        return Check("hyperregularity", None, FAIL, float(lam[i]), thr, expected,
                     f"M(q) loses positive definiteness along the motion: smallest eigenvalue {lam[i]:.3g} at "
                     f"{where(primary, i)}, the earliest such state{hint}; the Lagrangian is not hyperregular there "
                     f"(judged on {basis}, {n} states)", rows)
    near = (cond > COND_WARN) | (lam < LAMBDA_RATIO_WARN * lam0)
    i = earliest(ts, near)
    if i is not None:
        what = (f"cond(M) = {cond[i]:.3g}" if cond[i] > COND_WARN else
                f"smallest eigenvalue {lam[i]:.3g} = {lam[i] / lam0:.2e} x its value at q0")
        return Check("hyperregularity", None, WARN, float(cond[i] if cond[i] > COND_WARN else lam[i]), thr, expected,
                     f"M(q) nearly singular along the motion: {what} at {where(primary, i)}, the earliest such state "
                     f"(largest cond(M) {np.max(cond):.3g}; judged on {basis}, {n} states)", rows)
    j = int(np.argmax(cond))
    note = (f"smallest eigenvalue {np.min(lam):.3g}, largest condition number {cond[j]:.3g} (t = {ts[j]:.4g}) over "
            f"{n} states of {basis}")
    if secondary:
        l2, c2, t2 = stats(secondary)
        bad = ~np.isfinite(l2) | (l2 <= 0) | (c2 > COND_WARN) | (l2 < LAMBDA_RATIO_WARN * lam0)
        if bad.any():
            k = earliest(t2, bad)
            hs_bad = sorted({x[4] for x, b in zip(secondary, bad) if b}, reverse=True)
            return Check("hyperregularity", None, WARN, float(l2[k]), thr, expected,
                         note + f"; but runs at h = {', '.join(f'{h:g}' for h in hs_bad)} leave that region (smallest "
                         f"eigenvalue {l2[k]:.3g} at {where(secondary, k)}): those steps are too coarse for this "
                         "motion", rows)
    return Check("hyperregularity", None, PASS, float(cond[j]), thr, expected, note, rows)


def fmt_vec(q) -> str:
    """A state vector for the report: [x, y, ...] at 4 significant digits."""
    return "[" + ", ".join(f"{x:.4g}" for x in np.asarray(q, float).ravel()) + "]"


# --- orders ---------------------------------------------------------------------------------------

def order_check(name, method, hs, errs, theory, *, scale=1.0, tol=ORDER_TOL, one_sided=False,
                quantity="error", excluded=None) -> Check:
    """Observed order of errs against hs (fit_order: round-off plateau masked) against `theory`.

    The value is the least-squares slope over every point above the plateau (the test suite's number);
    h_asymptotic is the largest h from which on every finer local slope is within `tol` of the theory.
    pass: that fit is within `tol` (one_sided: slope >= theory - tol), or the asymptotic regime spans at
    least 3 points of the ladder (the order is observed where it is defined: as h -> 0).
    warn: the order is reached only between the two finest steps, or missed while the errors are
    still large (above ASYMPTOTIC_REL of `scale` at the finest point: the ladder is too coarse for the
    asymptotic regime), or fewer than 3 points lie above the round-off plateau (the ladder is too fine).
    fail otherwise: a clean but wrong order (errors small, local slopes off), or no usable point."""
    hs = np.asarray(hs, float)
    errs = np.asarray(errs, float)
    rows = []
    expected = f"order {theory:g}" + (" or more" if one_sided else "")
    thr = (f"slope >= {theory - tol:g}" if one_sided else f"|slope - {theory:g}| <= {tol:g}")
    ls = dict(local_slopes(hs, errs))
    # fit_order stops at the first point whose error does not decrease; at the coarse end that is a
    # pre-asymptotic step (e.g. a coarse run that went astray), not the plateau: drop such coarsest
    # points until a fit exists
    by_h = np.argsort(hs)[::-1]
    dropped = np.zeros(hs.size, bool)
    mask = np.zeros(hs.size, bool)
    slope = float("nan")
    for start in range(max(1, hs.size - 2)):
        keep = np.zeros(hs.size, bool)
        keep[by_h[start:]] = True
        try:
            s_, m_ = fit_order(hs[keep], errs[keep], scale=scale)
        except OrderFitError:
            continue
        slope = s_
        mask[np.flatnonzero(keep)[m_]] = True
        dropped[by_h[:start]] = True
        break
    for h, e, u, d in sorted(zip(hs, errs, mask, dropped), reverse=True):
        rows.append({"h": f"{h:.4g}", quantity: fmt(e), "local slope": fmt(ls[float(h)]) if float(h) in ls else "",
                     "used in fit": "yes" if u else ("no (pre-asymptotic: the error stalls)" if d else
                                                     "no (round-off plateau)" if e <= NEAR_ROUND_OFF * EPS * scale
                                                     else "no (finer than where the error stops falling)")})
    for h, why in (excluded or []):
        rows.append({"h": f"{h:.4g}", quantity: "-", "local slope": "", "used in fit": f"no ({why})"})
    data = {"h": hs.tolist(), "err": errs.tolist(), "mask": np.asarray(mask).tolist(), "theory": theory,
            "slope": slope, "h_asymptotic": None}
    if not np.isfinite(slope):
        listed = ", ".join(f"{e:.3g} (h = {h:.4g})" for h, e in sorted(zip(hs, errs), reverse=True)) or "none"
        big = [e for e in errs if np.isfinite(e) and e > ASYMPTOTIC_REL * scale]
        if excluded and not hs.size:
            return Check(name, method, FAIL, slope, thr, expected,
                         f"no usable run: {'; '.join(f'h = {h:.4g}: {why}' for h, why in excluded)}", rows, data)
        if excluded or big:
            why = [f"runs excluded at h = {', '.join(f'{h:.4g} ({w})' for h, w in excluded)}"] if excluded else []
            if big:
                why.append(f"the {quantity} is still {max(big) / scale:.2e} of the solution's size")
            return Check(name, method, WARN, slope, thr, expected,
                         f"the ladder is too coarse for the asymptotic regime: fewer than 3 usable points ({listed}); "
                         f"{'; '.join(why)}: use smaller h", rows, data)
        if hs.size >= 3 and np.all(np.isfinite(errs)) and np.sum(errs > NEAR_ROUND_OFF * 0.1 * EPS * scale) < 3:
            return Check(name, method, WARN, slope, thr, expected,
                         f"fewer than 3 points above the round-off plateau ({listed}): the truncation error is below "
                         "round-off at these h -- the method integrates this motion exactly (e.g. a variational "
                         "integrator on a free flight under constant gravity) or the ladder is too fine; larger h "
                         "would show the order if there is one", rows, data)
        scatter = _scatter_warning(name, method, hs, errs, theory, one_sided, scale, quantity, thr, expected,
                                   rows, data, ", ".join(fmt(s) for _, s in local_slopes(hs, errs)))
        if scatter is not None:
            return scatter
        return Check(name, method, FAIL, slope, thr, expected,
                     f"no order fit: fewer than 3 usable points ({listed})", rows, data)
    used_h = hs[mask]
    sl = [s for _, s in local_slopes(used_h, errs[mask])]          # coarse to fine
    # the asymptotic regime ignores points within 100x of the plateau level (round-off bends them)
    h_asym, n_asym = asymptotic_h(hs, errs, mask, theory, tol, one_sided, floor=NEAR_ROUND_OFF * EPS * scale)
    data["h_asymptotic"] = h_asym
    span = f"h = {used_h.max():.4g} .. {used_h.min():.4g}"
    where = (f"order within {tol:g} of {theory:g} for h <= {h_asym:.4g}" if h_asym is not None else
             f"no local slope within {tol:g} of {theory:g} on this ladder")
    local = ", ".join(fmt(s) for s in sl)
    fit_ok = slope >= theory - tol if one_sided else abs(slope - theory) <= tol
    if dropped.any():
        span += f" (coarser h = {', '.join(f'{h:.4g}' for h in np.sort(hs[dropped])[::-1])} pre-asymptotic: dropped)"
    if fit_ok or n_asym >= 3:
        return Check(name, method, PASS, slope, thr, expected,
                     f"fit over {span} ({int(mask.sum())} points); {where}", rows, data)
    finest = float(errs[mask][np.argmin(used_h)])
    near = NEAR_ROUND_OFF * EPS * scale
    above = mask & (errs > near)
    if above.sum() < mask.sum():
        # the finest points used lie within 100x of round-off, where the error bends off the order (the
        # Newton and event tolerances of the held steps sit there too): judged on the points above
        sl_above = [x for _, x in local_slopes(hs[above], errs[above])]
        ok = [np.isfinite(x) and (x >= theory - tol if one_sided else abs(x - theory) <= tol) for x in sl_above]
        if above.sum() >= 3 and all(ok):
            return Check(name, method, PASS, slope, thr, expected,
                         f"fit over {span} gives {slope:.3g}, bent by the errors within 100x of round-off (below "
                         f"{near:.2e}); above them the local slopes are {', '.join(fmt(x) for x in sl_above)}", rows,
                         data)
        if above.sum() < 3 and all(ok):
            return Check(name, method, WARN, slope, thr, expected,
                         f"fit over {span} gives {slope:.3g} (local slopes {local}), but only {int(above.sum())} of its "
                         f"points lie above 100x round-off ({near:.2e}), where the order is defined"
                         + (f" (local slope there {', '.join(fmt(x) for x in sl_above)})" if sl_above else "")
                         + ": the ladder is too fine for this method; larger h would show the order", rows, data)
    if n_asym == 2:
        return Check(name, method, WARN, slope, thr, expected,
                     f"the ladder is too coarse for the asymptotic regime: fit over {span} gives {slope:.3g} (local "
                     f"slopes {local}); {where} only: add smaller h", rows, data)
    if finest > ASYMPTOTIC_REL * scale:
        return Check(name, method, WARN, slope, thr, expected,
                     f"not in the asymptotic regime on this ladder: fit over {span} gives {slope:.3g} (local slopes "
                     f"{local}) and the finest {quantity} is still {finest / scale:.2e} of the solution's size: use "
                     "smaller h", rows, data)
    scatter = _scatter_warning(name, method, hs, errs, theory, one_sided, scale, quantity, thr, expected,
                               rows, data, ", ".join(fmt(s) for _, s in local_slopes(hs, errs)))
    if scatter is not None:
        return scatter
    return Check(name, method, FAIL, slope, thr, expected,
                 f"observed order {slope:.3g} over {span} (local slopes {local}) with errors down to "
                 f"{finest / scale:.2e} of the solution's size", rows, data)


def converges_elsewhere(c, hs, errs, diffs, scale) -> None:
    """Turn the warning `c` of an order check against an exact solution into a failure where the runs
    converge among themselves but not to it: the errors stay large (above ASYMPTOTIC_REL of `scale`)
    and do not fall (the finest at least half the coarsest) while the differences between successive
    runs (`diffs`, coarse to fine, one fewer than the runs) fall by at least 4x and end below a tenth
    of the finest error. A coarse ladder does not do that (its runs differ as much as they err): the
    method converges to another motion than the declared system's."""
    hs, errs, d = np.asarray(hs, float), np.asarray(errs, float), np.asarray(diffs, float)
    if errs.size < 3 or d.size != errs.size - 1 or not (np.all(np.isfinite(errs)) and np.all(np.isfinite(d))):
        return
    order = np.argsort(hs)[::-1]
    e = errs[order]
    if not (e[-1] > ASYMPTOTIC_REL * scale and e[-1] >= 0.5 * e[0] and d[-1] <= 0.25 * d[0] and d[-1] < 0.1 * e[-1]):
        return
    c.verdict = FAIL
    c.note = (f"the runs converge among themselves (successive differences {', '.join(fmt(x) for x in d)}) but not "
              f"to the exact solution (errors {', '.join(fmt(x) for x in e)}): the method integrates another motion "
              "than the declared system's (smaller h would not help)")


# --- symplecticity -----------------------------------------------------------------------------------

def symplecticity_check(method, rows, forced) -> Check:
    """rows: dicts {map, h, state, defect, floor}. floor (optional, 0 if none): the defect the FD
    stencil's round-off makes at that state where the defect lies at the bottom of a V in the stencil's
    step (vcirun.verification.suite._defect). A defect at or below its floor is the stencil's error and
    passes below the fail threshold, stated in the note; every other defect is judged by
    SYMPLECTIC_THRESHOLDS."""
    if not rows:
        return skip("symplecticity", method, "no map could be evaluated")

    def at_floor(r):
        return r["defect"] <= r.get("floor", 0.0)

    def verdict(r):
        if at_floor(r) and r["defect"] < SYMPLECTIC_THRESHOLDS[1]:
            return PASS
        return by_threshold(r["defect"], SYMPLECTIC_THRESHOLDS)

    rank = {PASS: 0, WARN: 1, FAIL: 2}
    # the worst verdict; among equals a defect of the map's own before one at a stencil's floor
    worst = max(rows, key=lambda r: (rank[verdict(r)], not at_floor(r),
                                     r["defect"] if np.isfinite(r["defect"]) else np.inf))
    shown = [{"map": r["map"], "h": f"{r['h']:.4g}", "state": r["state"],
              "max |J^T Omega J - Omega|": fmt(r["defect"]) + (f" (FD floor {fmt(r['floor'])})" if at_floor(r) else "")}
             for r in rows]
    thr = f"{SYMPLECTIC_THRESHOLDS[0]:.0e}"
    if forced:
        return Check("symplecticity", method, SKIP, worst["defect"], thr, "not symplectic (forced system)",
                     "a forced map contracts or expands phase volume: the defect is reported, not judged", shown)
    note = (f"worst: {worst['map']} at h = {worst['h']:.4g}, {worst['state']} (J by a 4th-order FD stencil; "
            f"{len(rows)} Jacobians)")
    floors = [r for r in rows if at_floor(r) and r["defect"] > SYMPLECTIC_THRESHOLDS[0]]
    if floors:
        big = max(floors, key=lambda r: r["defect"])
        note += (f"; {len(floors)} above {thr} at the stencil's round-off floor (the defect falls as d^4, then "
                 "rises as 1/d, and its bottom is within what NEWTON_TOL / d in J makes), which resolves no "
                 f"defect of the map's own below it: largest {fmt(big['defect'])}, floor {fmt(big['floor'])} "
                 f"({big['map']}, h = {big['h']:.4g}, {big['state']})")
    return Check("symplecticity", method, verdict(worst), worst["defect"], thr, "symplectic (defect at FD accuracy)",
                 note, shown)


# --- impacts -------------------------------------------------------------------------------------

def impact_events_check(method, rows, theory, T) -> Check:
    """rows: dicts {h, n_impacts, n_ref, time_error, status} (time_error: max |t_i - t_i,ref| when the
    counts agree). Every h must find the reference's impacts: a different count on the finer half of
    the ladder fails, on the coarser half warns (a grazing impact a coarse step misses); the impact
    times must converge at the method's order or faster (one-sided)."""
    if not rows:
        return skip("impact times", method, "no constrained run")
    n_ref = rows[0]["n_ref"]
    if n_ref == 0:
        return skip("impact times", method, "the exact reference has no impact on [0, T]: choose a state or T "
                    "with impacts")
    good = [r for r in rows if r["status"] == "ok" and r["n_impacts"] == n_ref]
    bad = [r for r in rows if r not in good]
    excluded = [(r["h"], f"{r['n_impacts']} impacts" if r["status"] == "ok" else f"status {r['status']}") for r in bad]
    c = order_check("impact times", method, [r["h"] for r in good], [r["time_error"] for r in good], theory,
                    scale=T, one_sided=True, quantity="max |t_i - t_i,ref|", excluded=excluded)
    c.note = f"the reference has {n_ref} impacts; " + c.note
    finer = sorted(r["h"] for r in rows)[: len(rows) // 2]
    wrong = [r for r in bad if r["h"] in finer]
    if wrong:
        r = wrong[0]
        c.verdict, c.value = FAIL, float(r["n_impacts"])
        c.threshold = f"{n_ref} impacts at every h"
        c.note = (f"at h = {r['h']:.4g} the run has {r['n_impacts']} impacts (status {r['status']}), the exact "
                  f"reference {n_ref}; " + c.note)
    elif bad and c.verdict == PASS:
        c.verdict = WARN
        c.note = (f"the impact count differs from the reference's at the coarse h = "
                  f"{', '.join(f'{r[0]:.4g}' for r in excluded)} (excluded: the ladder starts too coarse); " + c.note)
    return c


def impact_energy_check(method, rows, energy_name, theory, scale) -> Check:
    """rows: dicts {h, jump (max |dE| over the impact steps), smooth (max |dE| over the other steps)}.

    A finite number of impacts keeps the global order p only if each impact step changes the energy
    by O(h^p) or less (CVA and the MCVA family conserve H, resp. H~, in the reset: their impact steps
    change it like a smooth step, O(h^(p+1)); VCI conserves the discrete energy, so H changes by
    O(h^p)). Judged: the least-squares slope of log(jump) against log(h) over the points above the
    round-off plateau (no stall masking: the jump depends on where in the step the impact falls);
    pass if >= p - ENERGY_TOL, or if every jump is at round-off, or if every impact step changes the
    energy at most IMPACT_RATIO times as much as the largest smooth step; warn if >= p - 2 ENERGY_TOL,
    fail otherwise
    (O(h^(p-1)) per impact would cost the method one order). Forced systems: the change is
    dH - W, W the work of the forces over the step (the runner computes it)."""
    rows = [r for r in rows if np.isfinite(r["jump"])]
    if not rows:
        return skip("energy across impacts", method, "no run with impacts")
    rows = sorted(rows, key=lambda r: -r["h"])
    shown = [{"h": f"{r['h']:.4g}", f"max |d{energy_name}| impact steps": fmt(r["jump"]),
              f"max |d{energy_name}| other steps": fmt(r["smooth"]),
              "ratio": fmt(r["jump"] / r["smooth"]) if r["smooth"] > 0 else "-"} for r in rows]
    hs = np.array([r["h"] for r in rows])
    jumps = np.array([r["jump"] for r in rows])
    thr = f"slope >= {theory - ENERGY_TOL:g}"
    expected = f"O(h^{theory:g}) or smaller per impact step (keeps the global order {theory:g})"
    level = 1e3 * EPS * max(scale, 1e-300)
    above = jumps > level
    data = {"h": hs.tolist(), "err": jumps.tolist(), "mask": above.tolist(), "theory": theory}
    if above.sum() < 3:
        if np.all(jumps <= 1e2 * level):
            return Check("energy across impacts", method, PASS, float(jumps.max()), thr, expected,
                         f"{energy_name} conserved to round-off across every impact step (largest change "
                         f"{jumps.max():.2e}, {energy_name} ~ {scale:.3g})", shown, data)
        k = int(above.sum())
        prefix = k >= 1 and bool(np.all(above[:k])) and not above[k:].any()   # rows run from coarse to fine
        fast = k == 1 or float(np.polyfit(np.log(hs[:k]), np.log(jumps[:k]), 1)[0]) >= theory - ENERGY_TOL
        if prefix and fast:
            # above round-off only at the coarsest h, then at round-off: faster than any order the ladder
            # could resolve (the reset conserves the energy it targets; what is left is the smooth steps')
            return Check("energy across impacts", method, PASS, float(jumps[k - 1]), thr, expected,
                         f"the change of {energy_name} over an impact step is above round-off only at the coarsest "
                         f"h = {', '.join(f'{x:g}' for x in hs[:k])} ({', '.join(fmt(j) for j in jumps[:k])}) and "
                         f"at round-off below: it falls faster than h^{theory:g}", shown, data)
        return Check("energy across impacts", method, WARN, float("nan"), thr, expected,
                     f"fewer than 3 steps with a change above round-off: no order (changes "
                     f"{', '.join(fmt(j) for j in jumps)})", shown, data)
    slope = float(np.polyfit(np.log(hs[above]), np.log(jumps[above]), 1)[0])
    data["slope"] = slope
    smooth = np.array([r["smooth"] for r in rows])
    ratios = jumps[above] / np.maximum(smooth[above], 1e-300)
    k = int(np.argmin(hs))
    note = (f"largest change of {energy_name} over one impact step against h: slope {slope:.3g} over "
            f"{int(above.sum())} steps; at h = {hs[k]:.4g} it is {jumps[k]:.2e}"
            + (f" ({jumps[k] / smooth[k]:.3g} x the largest smooth step's)" if smooth[k] > 0 else ""))
    if slope >= theory - ENERGY_TOL:
        return Check("energy across impacts", method, PASS, slope, thr, expected, note, shown, data)
    if np.all(ratios <= IMPACT_RATIO):
        # the impact steps change the energy no more than the smooth steps do (the jumps depend on where
        # in the step the impact falls, which makes their slope noisy): they cannot cost an order
        return Check("energy across impacts", method, PASS, slope, thr + f" or impact / smooth step <= {IMPACT_RATIO:g}",
                     expected, note + f"; every impact step changes {energy_name} at most {ratios.max():.3g} x as much "
                     "as the largest smooth step", shown, data)
    v = WARN if slope >= theory - 2 * ENERGY_TOL else FAIL
    return Check("energy across impacts", method, v, slope, thr, expected, note, shown, data)


# --- friction -------------------------------------------------------------------------------------

MODE_KIND = {1: "slip -> stick", 2: "stick -> slip", 3: "slip reversed"}


def mode_events_check(method, rows, theory, T) -> Check:
    """rows: dicts {h, n_changes, n_ref, time_error, status, first_difference} (time_error: max |t_i -
    t_i,ref| when the run's mode changes are the reference's: the same count, contacts and kinds in
    the same order; first_difference: where they part, else ""). Stick/slip transitions are located
    events like impacts: judged as `impact_events_check` judges impact times (every h must find the
    reference's sequence: a different one on the finer half of the ladder fails, on the coarser half
    warns; the times converge at the method's order or faster, one-sided)."""
    name = "mode-change times"
    if not rows:
        return skip(name, method, "no constrained run")
    n_ref = rows[0]["n_ref"]
    start = [(r["h"], e) for r in rows for e in r.get("at_start", ())]
    if start:
        h0, (t0, i0, k0) = start[0]
        start = (f"not counted: {len(start)} mode changes within round-off of t = 0 (e.g. h = {h0:.4g}: contact "
                 f"{i0} {MODE_KIND.get(k0, k0)} at t = {t0:.3g}), the start's choice of a slip direction from a "
                 "round-off slip velocity, where the reference starts in the mode its held problem gives")
    if n_ref == 0 and all(r["n_changes"] == 0 for r in rows if r["status"] == "ok"):
        return skip(name, method, "neither the exact reference nor any run changes a friction mode on [0, T] "
                    "(no stick/slip transition to time)" + (f"; {start}" if start else ""))
    good = [r for r in rows if r["status"] == "ok" and not r["first_difference"]]
    bad = [r for r in rows if r not in good]
    excluded = [(r["h"], r["first_difference"] if r["status"] == "ok" else f"status {r['status']}") for r in bad]
    finer = sorted(r["h"] for r in rows)[: len(rows) // 2]
    wrong = [r for r in bad if r["h"] in finer]
    if n_ref == 0:
        c = Check(name, method, PASS, float("nan"), "0 mode changes at every h", "no mode change (the reference's)",
                  f"runs with mode changes: {'; '.join(f'h = {h:.4g}: {why}' for h, why in excluded)}",
                  [{"h": f"{r['h']:.4g}", "mode changes": r["n_changes"], "status": r["status"],
                    "differs": r["first_difference"] or "-"} for r in sorted(rows, key=lambda r: -r["h"])])
    else:
        c = order_check(name, method, [r["h"] for r in good], [r["time_error"] for r in good], theory,
                        scale=T, one_sided=True, quantity="max |t_i - t_i,ref|", excluded=excluded)
    c.note = f"the reference has {n_ref} mode changes; " + c.note
    if start:
        c.note += f"; {start}"
    if wrong:
        r = wrong[0]
        c.verdict, c.value = FAIL, float(r["n_changes"])
        c.threshold = f"the reference's {n_ref} mode changes at every h"
        c.note = (f"at h = {r['h']:.4g} the run's mode changes differ from the exact reference's "
                  f"({r['first_difference'] or 'status ' + r['status']}); " + c.note)
    elif bad and c.verdict == PASS:
        c.verdict = WARN
        c.note = (f"the mode changes differ from the reference's at the coarse h = "
                  f"{', '.join(f'{x[0]:.4g}' for x in excluded)} (excluded: the ladder starts too coarse); " + c.note)
    return c


def energy_account_check(method, rows, theory, scale) -> Check:
    """rows: dicts {h, rest (max |rest| over the run: H - H0 less the impact law's loss, the friction
    work and the forcing work of its energy account), law, friction (the totals of those terms)}.

    The friction work and the law's losses are the model's; what the account leaves is the method's
    integration error, which must vanish at the method's order p (one-sided: a faster fall passes).
    Passes also where every rest is at round-off (a motion the method integrates exactly); a friction
    work that is not what the step's forces did leaves an O(1) rest and fails."""
    name = "energy account"
    rows = sorted(rows, key=lambda r: -r["h"])
    if not rows:
        return skip(name, method, "no run finished")
    hs = [r["h"] for r in rows]
    rest = [r["rest"] for r in rows]
    level = NEAR_ROUND_OFF * EPS * max(scale, 1e-300)
    shown_note = (f"friction work {fmt(rows[-1]['friction'])}, impact law {fmt(rows[-1]['law'])} at h = "
                  f"{rows[-1]['h']:.4g} (the model's: not error)")
    if all(np.isfinite(x) and x <= level for x in rest):
        c = Check(name, method, PASS, float(max(rest)), f"slope >= {theory - ORDER_TOL:g} or round-off",
                  f"order {theory:g} or more", f"the rest is at round-off at every h (largest {max(rest):.2e}, "
                  f"energy ~ {scale:.3g}); {shown_note}")
    else:
        c = order_check(name, method, hs, rest, theory, scale=scale, one_sided=True,
                        quantity="max |rest|")
        c.note = f"{shown_note}; " + c.note
        if c.verdict == WARN and all(np.isfinite(x) for x in rest) and rest[-1] > ASYMPTOTIC_REL * scale \
                and rest[-1] >= 0.5 * rest[0]:
            # an O(1) rest that does not fall with h: the account does not balance (not a coarse ladder)
            c.verdict = FAIL
            c.note = (f"the rest does not fall with h ({fmt(rest[0])} at h = {hs[0]:.4g}, {fmt(rest[-1])} at "
                      f"h = {hs[-1]:.4g}): the recorded friction work or impact losses are not what the run's "
                      "forces did; " + c.note)
    c.rows = [{"h": f"{r['h']:.4g}", "max |rest|": fmt(r["rest"]), "friction work": fmt(r["friction"]),
               "impact law": fmt(r["law"])} for r in rows]
    c.data.setdefault("h", hs)
    c.data.setdefault("err", rest)
    c.data.setdefault("mask", [True] * len(hs))
    c.data.setdefault("theory", theory)
    return c
