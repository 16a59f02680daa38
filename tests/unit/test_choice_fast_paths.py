"""The shortcuts that keep a later `simulate(tol=...)` call's Python small compute what the plain code
computed, bit for bit: the scene model's median, the per-contact event records and gaps, the one-pass
match of two event records, the grazing screen of every contact at once, phi on many grid states in one
call, the last grid point's event mark, the hold onsets, the observed order's bisection, a pilot's fresh
buffers, and a final run whose Trajectory is built only when returned."""
from __future__ import annotations

import dataclasses
import math
import random

import numpy as np
import pytest

from vcirun.run import estimate as es
from vcirun.run.pilot import Run, Runner, hold_onsets
from vcirun.run.scene_model import _median


def _bits(a, b) -> bool:
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_bits(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_bits(x, y) for x, y in zip(a, b))
    if isinstance(a, float):
        return (a == b and math.copysign(1, a) == math.copysign(1, b)) or (a != a and b != b)
    return a == b


def _run(impacts, contacts, N=10, h=0.5, q=None):
    q = np.zeros((N + 1, 2)) if q is None else q
    return Run(method=None, N=N, h=h, t0=0.0, q=q, p=np.zeros_like(q), impacts=np.asarray(impacts, float),
               impact_contact=np.asarray(contacts, np.int64), releases=np.zeros(0),
               release_contact=np.zeros(0, np.int64), held=False, status="ok", wall=0.0, cpu=0.0)


# --- the plain versions ------------------------------------------------------------------------------
def _plain_events(run):
    imp: dict = {}
    for t, c in zip(run.impacts, run.impact_contact):
        imp.setdefault(int(c), []).append(float(t))
    return {c: np.sort(v) for c, v in imp.items()}


def _plain_min_gap(run):
    g = math.inf
    for k in np.unique(run.impact_contact):
        t = run.impacts[run.impact_contact == k]
        if len(t) > 1:
            g = min(g, float(np.min(np.diff(t))))
    return g


def _plain_near_misses(run, mod, prm, margin):
    """One contact at a time over the whole grid (no screen)."""
    out = es._end_approach(run, mod, prm, margin)
    phis = np.array([_phi(mod, run.q[k], prm) for k in range(run.q.shape[0])])
    near = es._near_event(run, 1)
    for i in range(phis.shape[1]):
        f = phis[:, i]
        a, b, c = f[:-2], f[1:-1], f[2:]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            curv = (a - 2 * b + c) / 2.0
            slope = (c - a) / 2.0
            s = np.where(curv > 0, -slope / (2 * curv), np.inf)
            low = np.where(curv > 0, b - slope * slope / (4 * curv), b)
        for k in np.flatnonzero(((np.abs(s) <= 1.0) | ((b <= a) & (b <= c))) & (b > 0) & ~near[1:-1]):
            if low[k] <= margin:
                out.append((run.t0 + int(k + 1) * run.h, i, float(low[k])))
    return sorted(out)


def _phi(mod, q, prm):
    out = np.empty(int(mod.NCON))
    mod.sys_phis(np.ascontiguousarray(q), prm, out)
    return out


# --- the checks --------------------------------------------------------------------------------------
def test_median_is_numpys():
    rng = random.Random(5)
    for _ in range(2000):
        n = rng.randint(1, 40)
        floats = [rng.lognormvariate(0, 20) for _ in range(n)]
        ints = [rng.choice([16, 24, 96, 1000]) * rng.randint(1, 9) for _ in range(n)]
        values = rng.choice([floats, ints])
        assert _bits(float(_median(values)), float(np.median(values))), values
        assert int(_median(values)) == int(np.median(values)) or not isinstance(values[0], int)
    assert math.isnan(_median([1.0, math.nan, 2.0]))


def test_event_records_and_gaps_per_contact():
    rng = random.Random(7)
    for _ in range(2000):
        k, m = rng.randint(0, 30), rng.randint(1, 4)
        times = np.sort([round(rng.uniform(0, 5), rng.choice([1, 9])) for _ in range(k)])
        run = _run(times, [rng.randrange(m) for _ in range(k)])
        assert _bits(es._events(run)[0], _plain_events(run))
        assert _bits(es._own_min_gap(_run(run.impacts, run.impact_contact)), _plain_min_gap(run))


def test_hold_onsets_times():
    rng = random.Random(11)
    for _ in range(500):
        active = np.array([[rng.random() < 0.3 for _ in range(3)] for _ in range(rng.randint(2, 40))])
        t0, h = rng.uniform(-1, 1), rng.uniform(1e-4, 1)
        on = active[1:] & ~active[:-1]
        want = tuple((t0 + (int(k) + 1) * h, int(c)) for k, c in zip(*np.nonzero(on)))
        assert _bits(hold_onsets(active, t0, h), want)


@pytest.mark.parametrize("system,q0,p0", [("ball_in_box", [0.2, 0.7], [2.5, -1.7]),
                                          ("double_pendulum_walls", [0.3, -0.2], [6.0, 1.5])])
def test_grazing_screen_of_every_contact_at_once(system, q0, p0):
    """near_misses over all contacts at once is the per-contact scan (margins from none to everything),
    and the screened scan on a companion's grid sees what the full scan sees where the screen applies."""
    runner = Runner(system, T=5.0, q0=q0, p0=p0)
    mod, prm = runner.module("CVA"), runner.params_vector("CVA")
    for N in (32, 96, 256):
        run, comp = runner.run("CVA", N), runner.run("CVA", N // 2)
        for margin in (0.0, 1e-4, 1e-2, 0.3, 10.0):
            plain = _plain_near_misses(run, mod, prm, margin)
            assert _bits(es.near_misses(run, mod, prm, margin), plain), (N, margin)
            screened = es.near_misses(run, mod, prm, margin, screen=comp)
            assert set(screened) <= set(plain), (N, margin)
    assert plain, "a margin of 10 finds every grid minimum"


def test_a_deferred_trajectory_is_the_one_built_at_once():
    from vcirun.run.api import trajectory_of

    runner = Runner("double_pendulum_walls", T=5.0, q0=[0.3, -0.2], p0=[6.0, 1.5], build=trajectory_of)
    now, later = runner.run("CVA4", 300, trajectory=True), runner.run("CVA4", 300, trajectory="later")
    assert later.trajectory is None and later.pending is not None and later.status == now.status
    tr = later.built()
    assert tr is later.built() and later.pending is None
    for name in ("q", "p", "H", "Ed", "impacts", "impact_contact", "contact_active"):
        assert _bits(getattr(tr, name), getattr(now.trajectory, name)), name
    assert tr.status == now.trajectory.status and tr.run_args.method == now.trajectory.run_args.method


@pytest.mark.parametrize("system,q0,p0", [("ball_in_box", [0.2, 0.7], [2.5, -1.7]),
                                          ("cart_pendulum", [1.0, 0.3], [0.5, 0.2]),
                                          ("double_pendulum_walls", [0.3, -0.2], [6.0, 1.5])])
def test_phi_on_many_states_is_one_compiled_call_per_state(system, q0, p0):
    """phi on a run's grid (and on chosen grid states) equals sys_phis called state by state, bit for bit:
    on the run's states and on random states of many magnitudes (the column form where the kernel is
    arithmetic only, the per-state calls where it is not)."""
    runner = Runner(system, T=5.0, q0=q0, p0=p0)
    mod, prm = runner.module("CVA"), runner.params_vector("CVA")
    rng = np.random.default_rng(3)
    run = runner.run("CVA", 200)
    n = run.q.shape[1]
    states = [run.q] + [rng.normal(size=(k, n)) * 10.0 ** rng.uniform(-8, 8, size=(k, n)) for k in (8, 9, 300)]
    for q in states:
        r = Run(method=None, N=q.shape[0] - 1, h=0.1, t0=0.0, q=np.ascontiguousarray(q), p=np.zeros_like(q),
                impacts=np.zeros(0), impact_contact=np.zeros(0, np.int64), releases=np.zeros(0),
                release_contact=np.zeros(0, np.int64), held=False, status="ok", wall=0.0, cpu=0.0)
        want = np.array([_phi(mod, x, prm) for x in r.q])
        assert _bits(es._phis(r, mod, prm), want)
        ks = np.sort(rng.choice(q.shape[0], size=min(12, q.shape[0]), replace=False))
        assert _bits(es._phis(r, mod, prm, ks), want[ks])
        assert _bits(es._phis(r, mod, prm, [q.shape[0] - 2, q.shape[0] - 1]), want[-2:])
    columns = es._column_form(mod.sys_phis)
    if system == "double_pendulum_walls":
        assert columns is None   # (its gaps take math.sin: called per state)
    else:
        assert columns is not None


def test_column_form_only_for_arithmetic_kernels():
    """The column form is refused for a kernel with a call, a power, a branch or an in-place operator."""
    from numba import njit

    def plain(q, prm, out):
        s_x = q[0]
        out[0] = -0.1 * s_x + q[1] / prm[0]
        out[1] = 1 - s_x
        return 0

    def sine(q, prm, out):
        out[0] = math.sin(q[0])
        return 0

    def power(q, prm, out):
        out[0] = q[0] ** 3
        return 0

    def branch(q, prm, out):
        out[0] = q[0] if q[0] > 0 else -q[0]
        return 0

    def inplace(q, prm, out):
        s = q[0]
        s += 1.0
        out[0] = s
        return 0

    assert es._column_form(njit(plain)) is not None
    for fn in (sine, power, branch, inplace):
        assert es._column_form(njit(fn)) is None, fn.__name__
    assert es._column_form(plain) is None   # (not compiled: no py_func; called per state)


def test_fresh_buffers_are_record_allocates():
    """A pilot's output buffers (shapes, dtypes, layout, fills) are record.allocate's, for any N, sizes and
    impact capacity (their trailing shapes are kept per (n, m), the rows follow N)."""
    from vcirun.core import record
    from vcirun.run.pilot import _FRESH

    for N, n, m in ((1, 1, 0), (5, 1, 1), (137, 2, 1), (64, 3, 4), (1000, 6, 2), (64, 3, 4)):
        for cap in (record.impact_capacity(N), 4 * record.impact_capacity(N) + 3):
            want, got = record.allocate(N, n, m=m, cap_impacts=cap), _FRESH.get(N, n, m, cap)
            assert len(want) == len(got)
            for a, b, f in zip(want, got, record.FIELDS):
                assert a.shape == b.shape and a.dtype == b.dtype and b.flags.c_contiguous, f.name
                if f.fill is not None:
                    assert a.tobytes() == b.tobytes(), f.name


def _plain_observed_order(Na, Nb, Nc, dab, dbc):
    if not (dab > 0 and dbc > 0):
        return None
    target = math.log(dab / dbc)

    def f(p):
        return p * math.log(Nb / Na) + math.log1p(-(Na / Nb) ** p) - math.log1p(-(Nb / Nc) ** p) - target

    lo, hi = 0.05, 30.0
    flo, fhi = f(lo), f(hi)
    if flo > 0:
        return 0.0
    if fhi < 0:
        return hi
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if f(mid) > 0:
            hi = mid
        else:
            lo = mid
    return 0.5 * (lo + hi)


def test_observed_order_bisection():
    from vcirun.run.ladder import _observed_order

    rng = random.Random(13)
    for _ in range(3000):
        Na = rng.choice([4, 8, 16, 24, 100])
        Nb = Na * rng.choice([2, 3, 4])
        Nc = Nb * rng.choice([2, 4])
        dab, dbc = 10 ** rng.uniform(-14, 0), 10 ** rng.uniform(-14, 0)
        want = _plain_observed_order(Na, Nb, Nc, dab, dbc)
        assert _bits(_observed_order(Na, Nb, Nc, dab, dbc), want)
    assert _observed_order(8, 16, 32, 0.0, 1.0) is None


def test_matched_records_and_gaps_with_nan_and_sorted_contacts():
    """The one-pass match of two records gives the per-contact impact-time differences (contacts in index
    order, each in time order); the shortest gap per contact is the plain one with NaN times and with
    records already in contact order."""
    rng = random.Random(17)
    for _ in range(2000):
        k, m = rng.randint(0, 25), rng.randint(1, 4)
        times = np.sort([rng.uniform(0, 5) for _ in range(k)])
        contacts = [rng.randrange(m) for _ in range(k)]
        if rng.random() < 0.3:
            contacts.sort()
        if k and rng.random() < 0.1:
            times[rng.randrange(k)] = math.nan
        a = _run(times, contacts)
        one = k > 1 and len(set(contacts)) == 1   # (one contact: np.min of its gaps, NaN with a NaN time)
        assert _bits(es._own_min_gap(a), float(np.min(np.diff(times))) if one else _plain_min_gap(a))
        b = _run(times + np.array([rng.uniform(-1e-9, 1e-9) for _ in range(k)]), contacts)
        dt = es._matched(a, b)
        if dt is not None:
            ca = np.asarray(contacts, np.int64)
            want = [np.abs(a.impacts[ca == c] - b.impacts[ca == c]) for c in sorted(set(contacts))]
            assert _bits(dt, np.concatenate(want) if want else np.zeros(0))


def test_near_end_is_the_last_point_of_near_event():
    rng = random.Random(19)
    for _ in range(3000):
        N, h, t0 = rng.randint(0, 40), rng.uniform(0.01, 1.0), rng.uniform(-1, 1)
        imp = np.sort([t0 + rng.uniform(-0.5, N + 1.5) * h for _ in range(rng.randint(0, 4))])
        rel = np.sort([t0 + rng.uniform(0, N) * h for _ in range(rng.choice([0, 0, 1, 2]))])
        run = Run(method=None, N=N, h=h, t0=t0, q=np.zeros((N + 1, 1)), p=np.zeros((N + 1, 1)), impacts=imp,
                  impact_contact=np.zeros(len(imp), np.int64), releases=rel,
                  release_contact=np.zeros(len(rel), np.int64), held=False, status="ok", wall=0.0, cpu=0.0)
        for reach in (0, 1, 2):
            fresh = dataclasses.replace(run, diffs={})
            assert es._near_end(fresh, reach) == bool(es._near_event(run, reach)[-1]), (N, imp, rel, reach)


def test_model_median_as_its_lists_grow():
    """The scene model's medians, kept as its lists grow one value at a time (signed zeros, equal values,
    the NaN rule), are those of the whole list sorted each time."""
    from vcirun.run.scene_model import MethodModel

    rng = random.Random(23)
    for _ in range(200):
        mm = MethodModel(order=4)
        for _ in range(rng.randint(1, 60)):
            nan_or_two = math.nan if rng.random() < 0.02 else 2.0
            mm.C.append(rng.choice([rng.lognormvariate(0, 20), 0.0, -0.0, 1.5, nan_or_two]))
            mm.N_asymptotic.append(rng.choice([16, 24, 32, 96]) * rng.randint(1, 4))
            if rng.random() < 0.5:
                mm.N_resolved.append(rng.choice([16, 32, 64]))
            C, n_asym, n_res = mm.medians()
            assert _bits(C, float(_median(mm.C)))
            assert n_asym == int(_median(mm.N_asymptotic))
            assert n_res == (int(_median(mm.N_resolved)) if mm.N_resolved else None)
