"""The error estimate of a run: `tr.error_estimate()`.

Richardson (kind "richardson"). A companion run of the same method from the same start at h / 2
(the grid points of the run are every second grid point of the companion) differs from the run
by d = e(h) - e(h / 2) on the run's grid. Where the error is C(t) h^p (the method's verified
order p through impacts: `Method.impact_order`; 2 for every method while a contact is held), the
companion's error is 2^-p that of the run, so the run's error is d / (1 - 2^-p): its L2 norm
sqrt(h sum_k |e_k|^2) (the norm of `vcirun.l2_error`), the final-state errors |q_N - q(t_N)| and
|p_N - p(t_N)|. The stated bracket assumes only that the companion's error is at most 2^-(p-1)
of the run's (one order of margin below the asymptotic ratio): e in [d / (1 + 2^(1-p)),
d / (1 - 2^(1-p))]. A third run shows the observed order of the two differences: at 2h where N is
even (half the cost of a run at h / 4), else, or where the run at 2h does not finish or does not
resolve the motion (its impacts differ from the run's), at h / 4 (companions=2 asks for h / 4). An
observed order more than one short of p says the runs are not in the asymptotic regime, and the
estimate is then "unresolved", not a number (check_order=False skips the third run). A method whose
order is not verified on the scene (CVA6 and CVA8 under a generalized force) always takes the run at
h / 4 and uses the observed order.

Against the exact reference (kind "reference"): `vcirun.reference` from the run's start (or a
Reference passed in): the error itself, to the reference's accuracy.

Unresolved. Impacts make the error non-smooth in h: the estimate compares the impact and release
records of the runs, contact by contact, and is "unresolved" (no number, the first differing
event named) when the counts or contacts differ, when an impact time moves between the runs by
more than a quarter of the time to that contact's neighbouring impact (the events may reorder),
when an impact lies within four times the runs' disagreement on its time of the end (the exact
motion may have it after the end), when the impact times of the three runs do not converge at the
order, when the runs differ by more than LOST (1 %) of the motion's L2 norm (neither resolves it),
or when a contact comes to rest after its impacts (a Zeno accumulation, or a bounce the run takes
for resting at this h: the number of bounces before the hold depends on h, and two runs can agree
on a wrong one). A contact whose gap phi dips between two grid points without an impact being
recorded (a grazing contact the grid does not see: the parabola through phi at three grid points
reaches the surface, to within the run's estimated error) makes the estimate unresolved too, even
where both runs miss it alike, and so does a contact that approaches its surface in the run's last step and ends within that error of
it (the exact motion may have touched before the end).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import asdict, dataclass, field

import numpy as np

from .pilot import Run, Runner

OK, UNRESOLVED, FAILED = "ok", "unresolved", "failed"
_EPS = float(np.finfo(float).eps)
_add, _max, _min, _sqrt = np.add.reduce, np.maximum.reduce, np.minimum.reduce, math.sqrt
# differences below ROUNDOFF * eps * (1 + max|q|) * sqrt(T) are round-off (accumulated over the grid
# and the impact-time solves, event_tol 1e-13): no order can be read from them
ROUNDOFF = 2e4


@dataclass
class ErrorEstimate:
    """kind: "richardson" or "reference"; status: "ok", "unresolved" (no number: the runs disagree in
    their impact sequence, a contact grazes, or the differences do not shrink at the order) or
    "failed" (a companion run or the run itself did not finish: `message`).

    l2: the estimated L2 error of the run's q on its grid (the norm of `vcirun.l2_error`), with
    l2_bounds (low, high); final_q, final_p: the error of the final state |q_N - q(t_N)|,
    |p_N - p(t_N)|; order: the order used (observed_order: measured with the third run);
    companion_h: the steps of the companions; first_difference: where the impact sequences part
    ("" if they agree); note: what the number rests on."""

    kind: str
    status: str
    h: float
    l2: float | None = None
    l2_bounds: tuple | None = None
    final_q: float | None = None
    final_p: float | None = None
    order: float | None = None
    observed_order: float | None = None
    companion_h: tuple = ()
    first_difference: str = ""
    note: str = ""
    message: str = ""
    extras: dict = field(default_factory=dict, repr=False)

    @property
    def ok(self) -> bool:
        return self.status == OK

    def as_dict(self) -> dict:
        d = asdict(self)
        d.pop("extras")
        d["l2_bounds"] = list(self.l2_bounds) if self.l2_bounds is not None else None
        d["companion_h"] = list(self.companion_h)
        return d

    def __str__(self) -> str:
        if self.status != OK:
            return f"error estimate ({self.kind}): {self.status}: {self.message}"
        lo, hi = self.l2_bounds if self.l2_bounds else (math.nan, math.nan)
        order = f", order {self.order:g}" if self.order is not None else ""   # (none against a reference)
        return (f"error estimate ({self.kind}{order}): L2 {self.l2:.3e} (in [{lo:.3e}, {hi:.3e}]), "
                f"final |dq| {self.final_q:.3e}, |dp| {self.final_p:.3e}" + (f"; {self.note}" if self.note else ""))


# --- comparing two runs --------------------------------------------------------------------------------
@dataclass
class Difference:
    """coarse - fine on the coarse grid: L2 norm, final |dq| and |dp|, sup |dq|; the impact-time
    differences (per matched impact); first: where the event sequences part ('' if they agree)."""

    l2: float
    final_q: float
    final_p: float
    sup_q: float
    dt: np.ndarray
    first: str


def _events(run: Run):
    """{contact: sorted impact times}, {contact: sorted release times} (kept on the run: a run is compared
    with several others; callers only read them)."""
    hit = run.diffs.get("events")
    if hit is None:
        hit = run.diffs["events"] = (_by_contact(run.impacts, run.impact_contact),
                                     _by_contact(run.releases, run.release_contact))
    return hit


def _by_contact(times: np.ndarray, contacts: np.ndarray) -> dict:
    """{contact: np.sort of its times in record order} (one mask per contact, not a loop over events)."""
    k = min(len(times), len(contacts))   # (pairs, as zip makes them)
    if not k:
        return {}
    times, contacts = np.asarray(times, dtype=float)[:k], np.asarray(contacts)[:k]
    if k == 1 or (contacts == contacts[0]).all():
        return {int(contacts[0]): np.sort(times)}
    # (np.unique of integers is sorted(set()) of them, without its per-call cost)
    cs = sorted(set(contacts.tolist())) if contacts.dtype.kind in "iu" else np.unique(contacts)
    return {int(c): np.sort(times[contacts == c]) for c in cs}


_NO_TIMES = np.zeros(0)   # (a contact without events in one run: read, never written)
_NO_TIMES.flags.writeable = False


def _name(names, c) -> str:
    return f"contact {names[c]}" if names and 0 <= c < len(names) else f"contact {c}"


def sequence_difference(a: Run, b: Run, label_a: str, label_b: str, names=None) -> tuple[str, np.ndarray]:
    """('' or where the event records of runs a and b part, impact-time differences of matched impacts,
    contact by contact in the order of the contacts' indices and each contact's in time order).

    Per contact: the same number of impacts and of releases; then each impact time may move by at
    most a quarter of the time to that contact's neighbouring impact (in either run)."""
    dt = _matched(a, b)
    if dt is not None:   # the common case: one pass, no per-contact bookkeeping unless an impact moves far
        return "", dt
    ia, ra = _events(a)
    ib, rb = _events(b)
    firsts = []   # (time, text)
    dts = []
    for c in sorted(set(ia) | set(ib)):
        ta, tb = ia.get(c, _NO_TIMES), ib.get(c, _NO_TIMES)
        k = min(len(ta), len(tb))
        if len(ta) != len(tb):
            extra, who = (ta[k:], label_a) if len(ta) > len(tb) else (tb[k:], label_b)
            firsts.append((float(extra[0]) if k == 0 else min(float(extra[0]), float(ta[k - 1])),
                           f"{_name(names, c)}: {len(ta)} impacts at {label_a} against {len(tb)} at {label_b} "
                           f"(the first unmatched one at t = {extra[0]:.6g}, {who})"))
        if k:
            d = np.abs(ta[:k] - tb[:k])
            dts.append(d)
            gaps = np.full(k, np.inf)
            for t in (ta[:k], tb[:k]):
                if k > 1:
                    g = t[1:] - t[:-1]   # (np.diff)
                    gaps[:-1] = np.minimum(gaps[:-1], g)
                    gaps[1:] = np.minimum(gaps[1:], g)
            bad = np.flatnonzero(d > 0.25 * gaps)
            if bad.size:
                j = int(bad[0])
                firsts.append((float(min(ta[j], tb[j])),
                               f"{_name(names, c)}: impact {j + 1} at t = {ta[j]:.9g} ({label_a}) and {tb[j]:.9g} "
                               f"({label_b}) moves by more than a quarter of the time to its neighbouring impact "
                               f"({gaps[j]:.3g}): the impacts may reorder"))
    for c in sorted(set(ra) | set(rb)):
        ta, tb = ra.get(c, _NO_TIMES), rb.get(c, _NO_TIMES)
        if len(ta) != len(tb):
            k = min(len(ta), len(tb))
            extra = ta[k:] if len(ta) > len(tb) else tb[k:]
            firsts.append((float(extra[0]), f"{_name(names, c)}: {len(ta)} releases from rest at {label_a} against "
                                            f"{len(tb)} at {label_b} (the first unmatched one at t = {extra[0]:.6g})"))
    first = min(firsts)[1] if firsts else ""
    return first, (np.concatenate(dts) if dts else np.zeros(0))


def _equal(x: np.ndarray, y: np.ndarray) -> bool:
    """np.array_equal of two arrays (the same shape and values), without its per-call overhead."""
    return x.shape == y.shape and (not x.size or bool((x == y).all()))


def _matched(a: Run, b: Run, raw: bool = False):
    """The impact-time differences of runs a and b, contact by contact (each contact's in time order),
    where their records match one for one (the same contacts in the same order, as many releases) and
    no impact moves by more than a quarter of the shortest time between two impacts of one contact;
    None otherwise (`sequence_difference` then compares contact by contact). raw: also |t_a - t_b| in
    record order, as a pair."""
    if len(a.impacts) != len(b.impacts) or len(a.releases) != len(b.releases) \
            or not _equal(a.impact_contact, b.impact_contact) or not _equal(a.release_contact, b.release_contact):
        return None
    d = np.abs(a.impacts - b.impacts)
    if len(d) >= 2 and not _max(d) <= 0.25 * _min_gap(a, b):
        return None
    order = _contact_order(a)[0]   # contact by contact: the record stably sorted by contact
    dt = d if order is None else d[order]
    return (dt, d) if raw else dt


def _contact_order(r: Run) -> tuple:
    """(order, one): np.argsort(impact_contact, kind="stable") of run r, None where that is the identity
    (the record's contacts do not decrease), and whether every impact is of one contact (kept on the run)."""
    hit = r.diffs.get("contact_order")
    if hit is None:
        c = r.impact_contact
        if len(c) < 2:
            hit = (None, True)
        elif (c[1:] >= c[:-1]).all():
            hit = (None, bool(c[0] == c[-1]))
        else:
            hit = (np.argsort(c, kind="stable"), False)
        r.diffs["contact_order"] = hit
    return hit


def _min_gap(a: Run, b: Run) -> float:
    """The shortest time between two impacts of one contact, in either run (inf if none)."""
    return min(_own_min_gap(a), _own_min_gap(b))


def _own_min_gap(r: Run) -> float:
    """The shortest time between two impacts of one contact of run r (inf if none; kept on the run).
    (np.diff(x) is x[1:] - x[:-1] and np.min np.minimum.reduce, which gives NaN where any entry is NaN.)"""
    g = r.diffs.get("min_gap")
    if g is None:
        g = math.inf
        if len(r.impacts) > 1:
            c, t = r.impact_contact, r.impacts
            order, one = _contact_order(r)
            if one:
                g = float(_min(t[1:] - t[:-1]))
            else:
                # each contact's consecutive impacts in record order: a stable sort by contact keeps that
                # order, and the gaps between neighbours of one contact are the per-contact np.diff's
                ts, cs = (t, c) if order is None else (t[order], c[order])
                gaps = (ts[1:] - ts[:-1])[cs[1:] == cs[:-1]]
                low = float(_min(gaps)) if gaps.size else math.nan
                if low == low:
                    g = low
                elif gaps.size:   # (a NaN time: the per-contact minima, as min() skips a NaN one)
                    for k in np.unique(c):
                        tk = t[c == k]
                        if len(tk) > 1:
                            g = min(g, float(np.min(np.diff(tk))))
        r.diffs["min_gap"] = g
    return g


# runs that differ by more than this fraction of the motion's L2 norm do not resolve it: errors that large
# move impacts by amounts that are not small, and two runs can agree on a motion the reference does not have
LOST = 0.01


def difference(coarse: Run, fine: Run, names=None) -> Difference:
    """coarse - fine on the coarse grid (fine.N a multiple of coarse.N, same t0 and horizon). Runs that
    differ by more than LOST of the L2 norm of q have lost the motion between them: `first` says so."""
    r = fine.N // coarse.N
    if r * coarse.N != fine.N or r < 1:
        raise ValueError(f"companion: N = {fine.N} is not a multiple of N = {coarse.N}")
    qf, pf = fine.q[::r], fine.p[::r]
    dq = coarse.q - qf
    # only the last row of dp is read: that row alone, the same elementwise difference (runs of other
    # lengths take the whole array, as broadcasting or its error would)
    dp_end = (coarse.p[-1] - pf[-1]) if coarse.p.shape == pf.shape else (coarse.p - pf)[-1]
    # (np.sum, np.max and np.sqrt as the ufuncs' reductions and math.sqrt: the same correctly rounded
    # operations without numpy's per-call wrappers)
    l2 = _sqrt(coarse.h * float(_add(dq * dq, None)))
    hit = _matched(coarse, fine, raw=True)
    if hit is not None:
        first, (dt, d_raw) = "", hit
    else:
        first, dt = sequence_difference(coarse, fine, f"h = {coarse.h:.6g}", f"h = {fine.h:.6g}", names)
        d_raw = None
    holds = sorted(coarse.holds + fine.holds) if coarse.holds or fine.holds else ()
    if not first and holds:
        t, c = holds[0]
        first = (f"{_name(names, c)} comes to rest at t = {t:.6g} (held after its impacts): where impacts "
                 "accumulate the number of bounces before the hold depends on h")
    if not first:
        qn = _sqrt(coarse.h * float(_add(qf * qf, None)))
        if l2 > LOST * qn:
            first = (f"the runs at h = {coarse.h:.6g} and {fine.h:.6g} differ by {l2:.3g} in L2, more than "
                     f"{LOST:.0%} of the motion's {qn:.3g}: neither resolves it")
    if not first and len(coarse.impacts):
        first = _end_straddle(coarse, fine, names, d_raw)
    e = dq[-1]
    return Difference(l2=l2, final_q=_sqrt(float(_add(e * e, None))),
                      final_p=_sqrt(float(_add(dp_end * dp_end, None))),
                      sup_q=float(_max(np.abs(dq), None)) if dq.size else 0.0, dt=dt, first=first)


def _end_straddle(coarse: Run, fine: Run, names=None, d_raw=None) -> str:
    """'' or the impact that the runs (with matched impacts per contact) place within four times their
    disagreement on its time of the end t_N: the exact motion may have it after the end (the runs'
    error in an impact time is about their difference there, and 4x leaves the margin of a run
    whose order is not yet asymptotic). d_raw: |t_coarse - t_fine| in record order where `_matched`
    has it."""
    t_end = coarse.t0 + coarse.h * coarse.N
    if _equal(coarse.impact_contact, fine.impact_contact):   # impacts matched one for one, in order
        ta, tb = coarse.impacts, fine.impacts
        if d_raw is None or d_raw.shape != ta.shape:
            d_raw = np.abs(ta - tb)
        if not (t_end - np.maximum(ta, tb) < 4.0 * d_raw).any():
            return ""
    ia, _ = _events(coarse)
    ib, _ = _events(fine)
    for c in sorted(ia):
        ta, tb = ia[c], ib.get(c, np.zeros(0))
        if len(ta) != len(tb):
            continue
        close = np.flatnonzero(t_end - np.maximum(ta, tb) < 4.0 * np.abs(ta - tb))
        if close.size:
            j = int(close[0])
            return (f"{_name(names, c)}: impact {j + 1} at t = {ta[j]:.9g} (h = {coarse.h:.6g}) and {tb[j]:.9g} "
                    f"(h = {fine.h:.6g}) is within four times the runs' disagreement on its time of the end "
                    f"t = {t_end:.6g}: the exact motion may have it after the end")
    return ""


def roundoff_level(run: Run) -> float:
    """The L2 difference two runs of this size can show from round-off alone."""
    level = run.diffs.get("roundoff")   # (kept on the run: every estimate and assessment of it asks)
    if level is None:
        span = run.h * run.N
        level = run.diffs["roundoff"] = ROUNDOFF * _EPS * (1.0 + float(_max(np.abs(run.q), None))) \
            * math.sqrt(max(span, 1e-300))
    return level


def amplified_floor(run: Run, twins: list, N: int, names=None) -> tuple[float, str]:
    """(F, first): the round-off floor of an N-step run of the motion, measured on `run` and its
    twins (`Runner.run(perturb="h")` and `perturb="start"`: the same method, N and start to within a
    few ulps, so their truncation errors agree and they differ by what the motion makes of round-off).
    F is the largest L2 difference among the runs (on run's grid), times sqrt(N / run.N): the round-off
    of each step adds up like a random walk, so a finer run of the same motion has more of it. A
    Richardson estimate cannot show this floor (it divides its runs' difference by r^p - 1, round-off
    and all); the twins do: where each impact multiplies an error (the double pendulum between walls),
    round-off grows to 1e-8 and more, at every h alike. first: where a twin's impacts part from the
    run's ("" if none): then the motion's impact sequence is decided at round-off level and F is inf."""
    runs = [run] + [t for t in twins if t is not None]
    bad = [t for t in runs if not t.ok or t.q.shape != run.q.shape]
    if bad:
        return math.inf, f"a twin run perturbed at round-off level ended with status {bad[0].status}"
    worst = 0.0
    for i in range(len(runs)):
        for j in range(i + 1, len(runs)):
            a, b = runs[i], runs[j]
            first, _ = sequence_difference(a, b, "a run", "its twin perturbed at round-off level", names)
            if first:
                return math.inf, (f"a perturbation at round-off level changes the impacts (N = {run.N}): {first}")
            dq = a.q - b.q
            worst = max(worst, float(np.sqrt(run.h * np.sum(dq * dq))))
    return worst * math.sqrt(max(N, run.N) / run.N), ""


# --- grazing contacts ----------------------------------------------------------------------------------
def _phis(run: Run, mod, prm, ks=None) -> np.ndarray:
    """phi_i at the grid states ks (indices or a slice; default: all, kept on the run) of a run, (len(ks), m)."""
    if ks is None:
        hit = run.diffs.get("phis")
        if hit is not None and hit[0] is mod:
            return hit[1]
    m = int(mod.NCON)
    sys_phis = mod.sys_phis
    q = run.q if ks is None else run.q[ks]
    out = np.empty((q.shape[0], m))
    columns = _column_form(sys_phis) if q.shape[0] >= COLUMNS_FROM else None
    if columns is not None:
        with np.errstate(all="ignore"):   # (the compiled kernel's error_model="numpy": no warnings)
            columns(q.T, prm, out.T)
    else:
        for qk, row in zip(q, out):
            sys_phis(qk, prm, row)
    if ks is None:
        run.diffs["phis"] = (mod, out)
    return out


# phi on many grid states at once: a compiled sys_phis whose Python source (the function numba compiles)
# is arithmetic only (+, -, *, / and unary minus on entries of q and prm and number constants, each entry of
# out assigned once) computes, called with the columns of q and out (q.T[j] is coordinate j at every
# state), the same IEEE operations in the same order on every state: the same bits as one compiled call
# per state (numba contracts no multiply-add without fastmath; tests/unit/test_choice_fast_paths.py holds
# it on random states), without a Python-to-compiled call per state. A kernel with any other operation
# (math.sin, **, a branch) is called per state.
COLUMNS_FROM = 8   # states; fewer are cheaper one call each
_PLAIN_OPS = frozenset(("RESUME", "NOP", "LOAD_FAST", "LOAD_FAST_CHECK", "STORE_FAST", "BINARY_SUBSCR", "STORE_SUBSCR",
                        "UNARY_NEGATIVE", "RETURN_VALUE", "POP_TOP"))
_COLUMN_FORMS: dict = {}   # id(code) -> (code, the function or None)


def _column_form(kernel):
    """The Python function of compiled `kernel` where it may be called on columns (see above), else None."""
    fn = getattr(kernel, "py_func", None)
    code = getattr(fn, "__code__", None)
    if code is None:
        return None
    hit = _COLUMN_FORMS.get(id(code))
    if hit is None or hit[0] is not code:
        if len(_COLUMN_FORMS) > 256:
            _COLUMN_FORMS.clear()
        hit = _COLUMN_FORMS[id(code)] = (code, fn if _arithmetic_only(fn) else None)
    return hit[1]


def _arithmetic_only(fn) -> bool:
    """fn(q, prm, out) is straight-line code of the operations _column_form allows (no call, attribute,
    global, comparison, branch, loop, in-place or other operator; constants are numbers)."""
    import dis
    import inspect

    code = fn.__code__
    odd = (inspect.CO_VARARGS | inspect.CO_VARKEYWORDS | inspect.CO_GENERATOR | inspect.CO_COROUTINE
           | inspect.CO_ITERABLE_COROUTINE | inspect.CO_ASYNC_GENERATOR)
    if code.co_argcount != 3 or code.co_kwonlyargcount or code.co_freevars or code.co_cellvars or code.co_flags & odd:
        return False
    for ins in dis.get_instructions(code):
        op = ins.opname
        if op in _PLAIN_OPS:
            continue
        if op in ("LOAD_CONST", "RETURN_CONST") and (type(ins.argval) in (int, float) or ins.argval is None):
            continue
        if op == "BINARY_OP" and ins.argrepr in ("+", "-", "*", "/"):
            continue
        return False
    return True


def _near_event(run: Run, reach: int) -> np.ndarray:
    """Grid points within `reach` steps of a recorded impact or release (their minima are explained;
    kept on the run)."""
    key = ("near", reach)
    near = run.diffs.get(key)
    if near is not None:
        return near
    N = run.q.shape[0] - 1
    near = np.zeros(N + 1, bool)
    k_ev = _event_steps(run, N)
    if k_ev is not None:
        ks = (k_ev[:, None] + np.arange(-reach, reach + 2)[None, :]).ravel()
        near[np.minimum(np.maximum(ks, 0), N)] = True
    run.diffs[key] = near
    return near


def _event_steps(run: Run, N: int):
    """The grid step of each recorded impact and release, in [0, N] (None where there is none)."""
    events = np.concatenate([run.impacts, run.releases]) if len(run.releases) else run.impacts
    if not len(events):
        return None
    # (np.minimum(np.maximum(.)) is np.clip on integers, without its per-call overhead)
    return np.minimum(np.maximum(np.floor((events - run.t0) / run.h).astype(np.int64), 0), N)


def _near_end(run: Run, reach: int) -> bool:
    """_near_event(run, reach)[N], the last grid point: from the whole grid's where it is kept, else from
    the events alone (the point N is marked where an event's step k has k + reach + 1 >= N)."""
    near = run.diffs.get(("near", reach))
    if near is not None:
        return bool(near[-1])
    hit = run.diffs.get(("near_end", reach))
    if hit is None:
        N = run.q.shape[0] - 1
        k_ev = _event_steps(run, N)
        hit = run.diffs[("near_end", reach)] = k_ev is not None and bool(_max(k_ev) >= N - reach - 1)
    return hit


# the gap a guarded constraint reads while its guard is not armed (vcirun.mechanics.hybrid.GUARD_OFF; a test
# holds them equal): a jump to or from it is the guard arming, not a dip the grid would miss. The screen
# skips every parabola through that exact value (on an unguarded contact a gap of exactly 1.0 at a grid
# point is one point of a dip that the neighbouring parabolas still see)
GUARD_OFF = 1.0


def _parabola_minima(f: np.ndarray, skip: np.ndarray):
    """(grid points k, contacts i, the lowest value of the parabola through f[k-1, i], f[k, i], f[k+1, i]
    on [t_k-1, t_k+1], its curvature) of f (grid x contacts): every (k, i) whose parabola has its vertex
    on that span (so a dip in the last step is seen too) or is a grid minimum, f[k, i] > 0, not skipped
    (skip: per grid point, or per grid point and contact). Every contact at once: the same elementwise
    arithmetic as one contact's column alone. The vertex s = -slope / (2 curv) (inf where curv <= 0) is on
    the span where |slope / (2 curv)| <= 1 and curv > 0 (IEEE division rounds -x as it rounds x); the
    lowest value b - slope^2 / (4 curv) (b where curv <= 0) is computed at the points kept."""
    a, b, c = f[:-2], f[1:-1], f[2:]
    # (float constants: numpy converts an int operand to the same float, at a cost per operation)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):   # inf outside a screen's windows
        curv = (a - 2.0 * b + c) / 2.0
        slope = (c - a) / 2.0
        keep = (curv > 0.0) & (np.abs(slope / (2.0 * curv)) <= 1.0)
        keep |= (b <= a) & (b <= c)
        keep &= b > 0.0
        keep &= ~(skip[1:-1] if skip.ndim == 2 else skip[1:-1, None])
        if (f == GUARD_OFF).any():   # a parabola across a guard's arming
            keep &= ~((a == GUARD_OFF) | (b == GUARD_OFF) | (c == GUARD_OFF))
        ks, cs = np.nonzero(keep)
        cv, sl, bv = curv[ks, cs], slope[ks, cs], b[ks, cs]
        low = np.where(cv > 0.0, bv - sl * sl / (4.0 * cv), bv)
    return ks + 1, cs, low, np.abs(cv)


def _screen_minima(run: Run, mod, prm):
    """`_parabola_minima` of run's phi on its whole grid, its impacts and releases skipped (kept on the run:
    the grazing checks of two estimates screen with the same companion)."""
    hit = run.diffs.get("minima")
    if hit is None or hit[0] is not mod:
        hit = run.diffs["minima"] = (mod, _parabola_minima(_phis(run, mod, prm), _near_event(run, 1)))
    return hit[1]


def _end_approach(run: Run, mod, prm, margin: float) -> list:
    """[(t_N, contact, phi_N)] for each contact that approaches its surface in the run's last step and
    ends within `margin` of it (no event in the last steps): the exact motion, within the run's error
    of the run, may have touched before the end (a parabola through the last grid points has its
    vertex beyond the end, so `_parabola_minima` does not see it)."""
    N = run.q.shape[0] - 1
    if N < 2:
        return []
    if _near_end(run, 1):
        return []
    hit = run.diffs.get("phis")   # (the whole grid's where it was computed; else the last two states, kept)
    if hit is None or hit[0] is not mod:
        hit = run.diffs.get("end_phis")
        if hit is None or hit[0] is not mod:
            hit = run.diffs["end_phis"] = (mod, _phis(run, mod, prm, slice(N - 1, N + 1)))
    fa, fb = hit[1][-2:].tolist()
    out = []
    for i, (a, b) in enumerate(zip(fa, fb)):
        if 0 < b < a and b <= margin and a != GUARD_OFF:   # (not a guard arming in the last step)
            out.append((run.t0 + N * run.h, i, b))
    return out


def near_misses(run: Run, mod, prm, margin: float = 0.0, screen: Run | None = None) -> list[tuple[float, int, float]]:
    """Grid minima of each gap phi_i that no impact explains and whose parabola through three grid
    points reaches within `margin` of the surface: [(t, contact, lowest phi of the parabola)], and
    contacts that approach their surface in the last step and end within `margin` of it.
    Points next to a recorded impact or release are skipped; a held contact sits at phi = 0 and is
    skipped by the same rule (its hold starts at an impact).

    screen: a coarser nested run of the same motion (a companion): phi is evaluated on its grid, and
    on the run's own grid only around the screen's minima that come within margin plus one
    curvature step of the surface (the parabola of a grid r times coarser errs by less than that)."""
    N, m = run.q.shape[0] - 1, int(mod.NCON)
    if N < 2:
        return []
    out = _end_approach(run, mod, prm, margin)
    t0, h = run.t0, run.h
    if screen is None:
        ks, cs, low, _ = _screen_minima(run, mod, prm)
        hit = low <= margin
        out += [(t0 + k * h, i, v) for k, i, v in zip(ks[hit].tolist(), cs[hit].tolist(), low[hit].tolist())]
        return sorted(out)
    r = N // (screen.q.shape[0] - 1)
    if r < 1 or (screen.q.shape[0] - 1) * r != N or screen.q.shape[0] < 3:
        return near_misses(run, mod, prm, margin)
    ks, _, low, curv = _screen_minima(screen, mod, prm)
    sel = ks[low <= margin + 2.0 * curv]
    if not sel.size:
        return sorted(out)
    # the run's grid points within the windows [(k - 1) r - 1, (k + 1) r + 1] (clipped to [0, N]) around
    # the screen's minima k that come near the surface: their union, ascending
    edges = np.zeros(N + 2, np.int64)
    np.add.at(edges, np.maximum(0, (sel - 1) * r - 1), 1)
    np.add.at(edges, np.minimum(N, (sel + 1) * r + 1) + 1, -1)
    ks = np.flatnonzero(np.cumsum(edges[: N + 1]) > 0)
    f = np.full((N + 1, m), np.inf)
    f[ks] = _phis(run, mod, prm, ks)
    fin = np.isfinite(f)
    kk, cs, low, _ = _parabola_minima(np.where(fin, f, np.inf), _near_event(run, 1)[:, None] | ~fin)
    hit = np.isfinite(low) & (low <= margin)
    out += [(t0 + k * h, i, v) for k, i, v in zip(kk[hit].tolist(), cs[hit].tolist(), low[hit].tolist())]
    return sorted(out)


# --- the estimate --------------------------------------------------------------------------------------
def forced_order(meth) -> int | None:
    """The order of `meth` verified under a generalized force (its `forcing` property), None where it
    has not been measured (CVA6, CVA8)."""
    forcing = (meth.properties or {}).get("forcing")
    return int(str(forcing).split()[-1]) if forcing else None


def verified_order(meth, runner: Runner | None, held: bool) -> tuple[int | None, str]:
    """(order, why) the estimate may assume: the method's order through impacts; 2 while contacts are
    held (the constrained steps and releases are second order); None where it is not verified (CVA6
    and CVA8 under a generalized force: their forced order has not been measured)."""
    p = int(meth.impact_order)
    if runner is not None and meth.constrained is not False and runner.forced(meth):
        forcing = forced_order(meth)
        if forcing is None:
            return None, f"{meth.name}'s order under a generalized force is not verified"
        p = min(p, forcing)
    if held and p > 2:
        return 2, "contacts held: the constrained steps and releases are second order"
    return p, ""


def richardson(runs: list[Run], order: int | None, names=None, mod=None, prm=None, grazing=True,
               coarse: Run | None = None) -> ErrorEstimate:
    """The estimate of runs[0] from its companion runs[1] (N twice); the observed order from a third run,
    runs[2] (4N) or `coarse` (N/2), where there is one."""
    run = runs[0]
    h = run.h
    comp = tuple(r.h for r in runs[1:]) + ((coarse.h,) if coarse is not None else ())
    bad = [r for r in runs + ([coarse] if coarse is not None else []) if not r.ok]
    if bad:
        r = bad[0]
        who = "the run" if r is run else f"the companion at h = {r.h:.6g}"
        return ErrorEstimate("richardson", FAILED, h, order=order, companion_h=comp,
                             message=f"{who} ended with status {r.status}")
    chain = ([coarse] if coarse is not None else []) + list(runs)
    diffs = [difference(a, b, names) for a, b in zip(chain[:-1], chain[1:])]
    first = next((d.first for d in diffs if d.first), "")
    est = ErrorEstimate("richardson", OK, h, order=order, companion_h=comp, first_difference=first)
    if first:
        est.status = UNRESOLVED
        est.message = f"the runs do not resolve the impacts: {first}"
        return est
    # d0: the run against its companion (the estimate); (dc, df): a coarser and a finer pair for the order
    d0 = diffs[1] if coarse is not None else diffs[0]
    dc, df = (diffs[0], diffs[1]) if len(diffs) > 1 else (None, None)
    floor = roundoff_level(run)
    p_obs = None
    if dc is not None and dc.l2 > floor and df.l2 > 0:
        p_obs = math.log2(dc.l2 / df.l2)
        est.observed_order = p_obs
    if order is None:
        if p_obs is None:
            if d0.l2 <= floor:
                order = 1
                est.note = "differences at round-off level"
            else:
                est.status = UNRESOLVED
                est.message = "the method's order is not verified here and a third run is needed to observe it"
                return est
        else:
            order = max(p_obs, 0.0)
            est.note = f"observed order {p_obs:.2f} (the method's order is not verified on this scene)"
            if p_obs < 0.5:
                est.status = UNRESOLVED
                est.message = f"the differences do not shrink with h (observed order {p_obs:.2f})"
                return est
        est.order = order
    elif p_obs is not None and p_obs < order - 1.0 and d0.l2 > floor:
        est.status = UNRESOLVED
        est.message = (f"the differences shrink at order {p_obs:.2f}, not {order}: the runs are not in the "
                       "asymptotic regime")
        return est
    if p_obs is not None and len(dc.dt) and len(dc.dt) == len(df.dt):
        # impact times: the coarser pair's difference must not be smaller by more than round-off than the finer's
        tfloor = 1e3 * _EPS * max(1.0, abs(run.t0) + h * run.N)
        slow = np.flatnonzero((dc.dt > tfloor) & (dc.dt < df.dt * 2.0 ** (max(order, 1) - 1.5)))
        if slow.size:
            j = int(slow[0])
            est.status = UNRESOLVED
            est.message = (f"impact {j + 1}'s time does not converge at order {order:g} (differences "
                           f"{dc.dt[j]:.3g}, {df.dt[j]:.3g}): an ill-conditioned (grazing) impact")
            return est
    ratio = float(runs[1].N // run.N)
    rho = ratio ** (-(order - 1.0)) if order > 1 else 0.5
    factor = 1.0 / (1.0 - ratio ** -order)
    est.l2 = d0.l2 * factor
    est.l2_bounds = (d0.l2 / (1.0 + rho), max(d0.l2 / (1.0 - rho), floor))   # (round-off: not in d)
    est.final_q = d0.final_q * factor
    est.final_p = d0.final_p * factor
    if d0.l2 <= floor:
        est.note = (est.note + "; " if est.note else "") + f"differences at round-off level (<= {floor:.1e})"
    if grazing and mod is not None:
        margin = 2.0 * d0.sup_q * factor * slope_scale(run, mod, prm)
        miss = near_misses(run, mod, prm, margin)
        if miss:
            t, c, low = miss[0]
            est.status = UNRESOLVED
            est.first_difference = (f"{_name(names, c)} comes within the run's error of its surface near t = {t:.6g} "
                                    f"(phi down to {low:.3g}) without an impact: a grazing impact, or one just "
                                    "before the end, may be missed")
            est.message = "a contact the grid does not resolve: " + est.first_difference
            est.l2 = est.l2_bounds = est.final_q = est.final_p = None
    return est


_SLOPES: dict = {}


def slope_scale(run: Run, mod, prm) -> float:
    """|grad phi| at the start (the largest over the contacts): converts a q error into a gap error
    (kept per module, parameters and start)."""
    hit = run.diffs.get("slope")   # (kept on the run too: each estimate of the run asks)
    if hit is not None and hit[0] is mod and hit[1] is prm:
        return hit[2]
    key = (id(mod), prm.tobytes(), run.q[0].tobytes())
    s = _SLOPES.get(key)
    if s is None:
        m, n = int(mod.NCON), run.q.shape[1]
        G = np.empty((m, n))
        mod.sys_dphis(np.ascontiguousarray(run.q[0]), prm, G)
        s = float(np.max(np.sqrt(np.sum(G * G, axis=1)))) if m else 1.0
        s = s if math.isfinite(s) else 1.0
        if len(_SLOPES) > 256:
            _SLOPES.clear()
        _SLOPES[key] = s
    run.diffs["slope"] = (mod, prm, s)
    return s


def companion_runs(run: Run, order, run_at, *, companions: int = 1, check_order: bool = True,
                   names=None) -> tuple[list, Run | None]:
    """The runs the Richardson estimate of `run` takes (`richardson`'s arguments): ([run, the companion
    at 2N, and 4N where the order is seen there], the third run at N/2 or None). run_at(N): the Run
    of the same method from the same start at N steps. The third run is at N/2 where N is even (half
    the cost of one at 4N) and that run finishes, holds no contact and resolves the motion as the run
    does (its events agree with the run's); else at 4N. An order not verified (None) always takes 4N."""
    coarse = None
    if companions == 1 and (order is None or check_order):
        if run.N % 2 == 0 and run.N >= 4 and order is not None:
            coarse = run_at(run.N // 2)
            if not coarse.ok or coarse.held or difference(coarse, run, names).first:
                # the run at 2h does not resolve the motion (or holds a contact): it says nothing about
                # the run's order; the run at h / 4 does
                coarse, companions = None, 2
        else:
            companions = 2
    return [run] + [run_at(run.N * 2 ** (j + 1)) for j in range(companions)], coarse


def estimate(tr, *, kind: str = "richardson", companions: int = 1, reference=None, system=None,
             grazing: bool = True, check_order: bool = True) -> ErrorEstimate:
    """`Trajectory.error_estimate` (see there)."""
    if kind not in ("richardson", "reference"):
        raise ValueError(f"kind: 'richardson' or 'reference' (got {kind!r})")
    if isinstance(companions, bool) or not isinstance(companions, (int, np.integer)) or companions not in (1, 2):
        raise ValueError(f"companions: 1 or 2 (got {companions!r})")
    if check_order not in (True, False):
        raise ValueError(f"check_order: true or false (got {check_order!r})")
    if reference is not None:
        kind = "reference"
    if tr.status != OK:
        return ErrorEstimate(kind, FAILED, float(tr.h), message=f"the run ended with status {tr.status}: {tr.message}")
    args = getattr(tr, "run_args", None)
    if args is None:
        args = _args_from_record(tr, system)
    elif system is not None:   # (for this estimate: a system refused here must not stay on the trajectory)
        args = dataclasses.replace(args, system=system)
    if kind == "reference":
        return _against_reference(tr, args, reference)
    runner = args.runner(float(tr.T))
    meth = args.method
    run = Run.of_trajectory(tr, meth, runner.module(meth), runner.params_vector(meth))
    order, why = verified_order(meth, runner, run.held)
    names = _contact_names(tr, args)
    runs, coarse = companion_runs(run, order, lambda N: runner.run(meth, N), companions=companions,
                                  check_order=check_order, names=names)
    for r in runs[1:]:
        run.held = run.held or r.held
    order2, why2 = verified_order(meth, runner, run.held)
    order, why = (order2, why2) if order2 != order else (order, why)
    est = richardson(runs, order, names, runner.module(meth), runner.params_vector(meth), grazing=grazing,
                     coarse=coarse)
    if why and est.status == OK:
        est.note = (why + "; " + est.note) if est.note else why
    if est.status == OK and int(getattr(runner.module(meth), "NCON", 0)) > 0 and (
            getattr(meth, "reset", "") is None or (tr.options or {}).get("constrained") is False):
        # a run that ignores the scene's constraint converges to the smooth motion: its companions
        # measure its error against that motion, which can be far from the scene's
        ignored = ("the run ignores the scene's constraint: this is its error against the motion with the "
                   "constraint ignored, not against the scene's motion (kind='reference' compares with that)")
        est.note = (ignored + "; " + est.note) if est.note else ignored
    return est


def _contact_names(tr, args):
    """Contact names where the system object is at hand (a MechanicalSystem), else None ("contact i"):
    naming them must not build a symbolic system."""
    cons = getattr(args.system, "constraints", None)
    try:
        return [str(c.name) for c in cons] if cons else None
    except (AttributeError, TypeError):
        return None


def _args_from_record(tr, system):
    """RunArgs of a trajectory without them (read from a file, unpickled): a built-in scene by its name,
    else `system` must be given; the start is the run's first grid state."""
    from ..methods.table import resolve_method
    from ..scenes.registry import scene_info
    from .pilot import RunArgs

    if system is None and scene_info(tr.system) is None:
        raise ValueError(f"system: the trajectory of {tr.system!r} does not carry its system; pass "
                         "error_estimate(system=...) with its YAML path or MechanicalSystem")
    opts = dict(tr.options or {})
    params = opts.pop("params", None)
    constrained = opts.pop("constrained", None)
    meth = resolve_method(tr.method, **{k: v for k, v in opts.items() if k in ("ld", "mh_order", "flow_order")})
    tol = {k: v for k, v in (tr.tolerances or {}).items() if k in ("newton_tol", "event_tol", "max_iter",
                                                                     "max_impacts_step")}
    return RunArgs(system=tr.system if system is None else system, method=meth, t0=float(tr.t[0]),
                   q0=np.asarray(tr.q[0], float), p0=np.asarray(tr.p[0], float), params=params,
                   constrained=constrained, options=tol)


def _against_reference(tr, args, ref) -> ErrorEstimate:
    import vcirun

    from .pilot import Run

    h = float(tr.h)
    if ref is not None:
        _check_reference(tr, ref)
    if ref is None:
        if float(tr.t[0]) != 0.0:
            raise ValueError(f"reference: the exact reference starts at t = 0 and this run at t0 = {tr.t[0]:g}; "
                             "pass reference= one computed for it, or use kind='richardson'")
        ref = vcirun.reference(args.system, T=float(tr.t[-1]), q0=np.asarray(tr.q[0], float),
                               p0=np.asarray(tr.p[0], float), params=args.params,
                               resting_contact=args.resting_contact)
    l2 = float(vcirun.l2_error(tr, ref))
    t_end = float(tr.t[-1])
    fq = float(np.linalg.norm(tr.q[-1] - ref(t_end)))
    fp = float(np.linalg.norm(tr.p[-1] - ref.p(t_end)))
    acc = float(getattr(ref, "accuracy", math.nan))
    pad = acc * math.sqrt(max(t_end - float(tr.t[0]), 0.0)) if math.isfinite(acc) else 0.0
    ref_run = Run(method=None, N=0, h=h, t0=float(tr.t[0]), q=np.zeros((0, tr.q.shape[1])), p=np.zeros((0, 0)),
                  impacts=np.asarray(ref.impacts, float), impact_contact=np.asarray(ref.impact_contact),
                  releases=np.asarray(getattr(ref, "releases", np.zeros(0)), float),
                  release_contact=np.asarray(getattr(ref, "release_contact", np.zeros(0, np.int64))), held=False,
                  status=OK, wall=0.0, cpu=0.0)
    first, _ = sequence_difference(Run.of_trajectory(tr, None), ref_run, "the run", "the reference",
                                   _contact_names(tr, args))
    note = f"exact reference ({ref.kind}, accuracy {acc:.1e})"
    if first:
        note += "; the run's impact sequence differs from the reference's"
    return ErrorEstimate("reference", OK, h, l2=l2, l2_bounds=(max(0.0, l2 - pad), l2 + pad), final_q=fq, final_p=fp,
                         first_difference=first, note=note, extras={"reference": ref})


def _check_reference(tr, ref) -> None:
    """A reference handed in must be one (callable in t, with .p) of this run's motion: its state at the
    run's first grid time is the run's start (ValueError naming `reference` otherwise)."""
    if not callable(ref) or not callable(getattr(ref, "p", None)) or not all(
            hasattr(ref, a) for a in ("impacts", "impact_contact", "kind")):
        raise ValueError(f"reference: a vcirun.reference(...) of this run's motion (got {type(ref).__name__})")
    t0 = float(tr.t[0])
    q0, p0 = np.asarray(tr.q[0], float), np.asarray(tr.p[0], float)
    try:
        qr, pr = np.asarray(ref(t0), float), np.asarray(ref.p(t0), float)
    except (ValueError, TypeError) as e:
        raise ValueError(f"reference: cannot be evaluated at the run's t0 = {t0:g} ({e})") from None
    scale = 1e-8 * (1.0 + float(np.max(np.abs(np.concatenate([q0, p0])))))
    if qr.shape != q0.shape or pr.shape != p0.shape or float(np.max(np.abs(qr - q0))) > scale \
            or float(np.max(np.abs(pr - p0))) > scale:
        raise ValueError(f"reference: it is at q = {np.round(qr, 9).tolist()}, p = {np.round(pr, 9).tolist()} at "
                         f"t = {t0:g}, this run starts at q = {np.round(q0, 9).tolist()}, p = "
                         f"{np.round(p0, 9).tolist()}: pass a reference of this run's motion")


# --- what a sweep stores -------------------------------------------------------------------------------
def sweep_attrs(traj, h_requested: float, error_estimate: bool) -> dict:
    """The attributes a sweep stores for a run (scalars; vcirun.experiments.worker): for a run of
    `simulate(tol=...)` the choice (h stays the grid's h of the config, the largest step allowed; the
    step chosen is h_chosen, the method core_method) and its estimate; with error_estimate, the
    estimate of any ok run (`Trajectory.error_estimate()`: the companion and the third run).
    est_status: ok / unresolved / failed; est_l2 etc. NaN unless ok."""
    out = {}
    est = None
    choice = getattr(traj, "choice", None)
    if choice is not None:
        out.update(h=float(h_requested), h_chosen=float(traj.h), tol=float(choice.tol), tol_status=choice.status,
                   tol_reason=choice.reason[:500], n_pilots=len(choice.pilots),
                   tol_cpu=float(choice.seconds.get("total_cpu", float("nan"))))
        est = choice.estimate
    elif error_estimate and traj.status == OK:
        try:
            est = traj.error_estimate()
        except ValueError as e:   # e.g. a system the record cannot rebuild
            est = ErrorEstimate("richardson", FAILED, float(traj.h), message=str(e))
    if est is not None:
        nan = float("nan")
        out.update(est_kind=est.kind, est_status=est.status, est_message=(est.message or est.note)[:500],
                   est_l2=est.l2 if est.l2 is not None else nan,
                   est_l2_low=est.l2_bounds[0] if est.l2_bounds else nan,
                   est_l2_high=est.l2_bounds[1] if est.l2_bounds else nan,
                   est_final_q=est.final_q if est.final_q is not None else nan,
                   est_final_p=est.final_p if est.final_p is not None else nan,
                   est_order=float(est.order) if est.order is not None else nan)
    return out
