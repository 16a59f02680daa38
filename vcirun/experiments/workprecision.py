"""The work-precision study: what accuracy a method buys for what time, beside solve_ivp.

A study config (`study: work_precision` or `study: long_horizon`; `configs/work_precision.yaml`,
`configs/work_precision_double.yaml`, `configs/long_horizon.yaml`) is validated by
`vcirun.experiments.studies.schema.WorkPrecisionStudy`; its grid holds methods that are not vcirun
methods (scipy's solve_ivp at a tolerance, see `vcirun.experiments.baselines`):

    study: work_precision            # or long_horizon
    name: work_precision
    system: cart_pendulum            # built-in name (params: {...} optional)
    beta: {start: 3.2, stop: 5.2, num: 5}    # or a list
    T: 5                             # long_horizon: a list of horizons, e.g. [1000, 10000]
    methods: [CVA, VCI, MCVAA, MCVAC]        # as in a sweep config (MCVA with ld/mh_order/flow_order)
    h: [1.0e-1, 3.2e-2, 1.0e-2, 3.2e-3, 1.0e-3, 3.2e-4, 1.0e-4]
    baselines: {DOP853: [1.0e-3, ..., 1.0e-12], Radau: [1.0e-3, ..., 1.0e-10]}   # "DOP853/numpy": numpy rhs
    baseline_h: null                 # output grid of solve_ivp; null: every h of the methods (matched grids)
    baseline_max_T: {Radau: 1000}    # skip a solver on longer horizons
    repeats: 7                       # timing repeats per run (vcirun); medians are reported
    baseline_repeats: 5
    reference_rtol: 1.0e-13          # exact reference (work_precision only)
    max_steps: 2000000               # skip (method, h, T) with more grid steps
    baseline_time_limit: 60          # seconds; a solve_ivp run past it is stopped (status time_limit)
    output: results/work_precision.json

Protocol. Everything runs in ONE process, serially (one core; the other may be busy: the machine
is shared). Kernels are compiled and every (method, h) is warmed up before any timing. Timing
repeats are interleaved: pass r times every run once, so a slow spell of the machine spreads over
all runs instead of hitting one method. Reported per run: the median over repeats of the compiled
loop time (`traj.wall_time`; for solve_ivp the solve loop) and of the whole call (`simulate()` /
`solve_ivp_run()`) and the CPU time of the whole call (`time.thread_time`: on a loaded machine a long
run is preempted and its wall time inflated, a sub-millisecond one rarely is; CPU time is immune to
that bias, so ratios are reported on all three), the L2 error against the exact reference (work_precision) or max |H - H0| and,
for the MCVA family, max |Hmod - Hmod0| (long_horizon). Per (method, h) or (solver, rtol, grid) the
study takes the median over initial conditions of errors and times. In work_precision neither side
evaluates H inside the timed call (`simulate(energies=False)`; solve_ivp_run(energies=False)); in
long_horizon vcirun evaluates H along the grid inside its timed call and solve_ivp's H is computed
after it (the comparison favours solve_ivp).

Lost motion. An error above 10 % of the median ||q_ref||_L2 (work_precision) or of |H0| (long_horizon)
means the run has lost the motion (e.g. solve_ivp at a loose tolerance misses an impact and the cart
falls through the floor). Such solver runs are not candidates for the matching below, and such vcirun
points are marked rather than rated.

Speed ratio at matched accuracy. For each vcirun point (error e, time t) and each solver, the
solver's Pareto front on the same output grid (its runs sorted by time, keeping each that is more
accurate than every cheaper one) is interpolated linearly in (log error, log time) at e:
ratio = t_solver(e) / t. Outside the front the ratio is a bound, and says so: e above the front's
largest error means the solver's cheapest run is already more accurate (ratio <= t_cheapest / t);
e below its smallest error means the solver did not reach e at any tolerance tried (ratio >=
t_tightest / t). A point is *competitive* ("yes") where the interpolated ratio against the best solver is > 1 (or no
solver run reached its accuracy); "faster, less accurate" where it is cheaper than every solver run
but less accurate than the cheapest one (the ratio is then only bounded above); "no" otherwise. Computed
on the medians over initial conditions and, separately, per initial condition.

`vcirun study CONFIG [--quick] [--plot]` runs a study and prints its tables (the runner:
`vcirun.experiments.studies.runner`); `vcirun.experiments.wp_figures.plot_study(JSON)` draws it.
"""
from __future__ import annotations

import math
import os
import platform
import statistics
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.grid import grid_count, grid_end
from .baselines import hamiltonian_on_grid, solve_ivp_run
from .studies.jsonio import load_json, save_json
from .studies.schema import WorkPrecisionStudy

__all__ = ["run_study", "analyze", "summarize", "matched_ratios", "vcirun_front", "print_tables", "save", "load"]


# --- running ----------------------------------------------------------------------------------------
@dataclass
class _Run:
    kind: str            # "vcirun" | "baseline"
    label: str
    method: str
    kwargs: dict         # method options (vcirun) or {"rtol": ...} (baseline)
    h: float             # grid step (baseline: output grid)
    T: float
    beta: float
    record: dict


def _machine() -> dict:
    try:
        load = os.getloadavg()
    except OSError:
        load = (math.nan,) * 3
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:
        cpus = os.cpu_count()
    import numba
    import scipy

    return {"cpus": cpus, "loadavg_start": list(load), "python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "numba": numba.__version__, "platform": platform.platform(),
            "processor": platform.processor()}


def _energy(traj) -> tuple[float, float]:
    H = np.asarray(traj.H, float)
    dH = float(np.nanmax(np.abs(H - H[0]))) if H.size and np.isfinite(H[0]) else math.nan
    dHm = math.nan
    if traj.Hmod is not None and len(traj.Hmod) and np.isfinite(traj.Hmod[0]):
        dHm = float(np.nanmax(np.abs(np.asarray(traj.Hmod, float) - traj.Hmod[0])))
    return dH, dHm


def _call(run: _Run, system, params, time_limit):
    import vcirun

    t0 = time.perf_counter()
    c0 = time.thread_time()
    if run.kind == "vcirun":
        # energies along the grid only where the study measures them (long_horizon): solve_ivp's
        # timed call does not evaluate H either
        traj = vcirun.simulate(system, run.method, h=run.h, T=run.T, beta=run.beta, params=params,
                               energies=bool(run.record.get("need_energy", True)), **run.kwargs)
    else:
        traj = solve_ivp_run(system, run.method, h=run.h, T=run.T, beta=run.beta, params=params,
                             time_limit=time_limit, energies=False, **run.kwargs)
    return traj, time.perf_counter() - t0, time.thread_time() - c0


def run_study(cfg: WorkPrecisionStudy, *, quick: bool = False, log=print, extra_methods: dict | None = None) -> dict:
    """Run every run of the study (see the module docstring) and return the JSON-able result.
    extra_methods: {label: vcirun.methods.table.Method} run beside the config's methods (prototypes that
    have no name in the method registry, e.g. from bench/)."""
    import vcirun

    t_study = time.perf_counter()
    system = cfg.system
    params = dict(cfg.params) or None
    betas = cfg.betas()
    horizons = cfg.horizons()
    specs = cfg.method_specs()
    repeats, brepeats = cfg.repeats, cfg.baseline_repeats
    if quick:   # a smoke run: one initial condition, the shortest horizon, fewer repeats and tolerances
        betas = betas[:1]
        horizons = horizons[:1]
        repeats, brepeats = min(repeats, 3), min(brepeats, 2)
        cfg = cfg.model_copy(update={"baselines": {k: v[::3] for k, v in cfg.baselines.items()},
                                     "baseline_time_limit": min(cfg.baseline_time_limit, 10.0)})
    lh = cfg.study == "long_horizon"
    out = {"study": cfg.study, "name": cfg.name + ("_quick" if quick else ""), "description": cfg.description, "config": cfg.model_dump(mode="json", by_alias=True),
           "quick": quick, "machine": _machine(), "started": time.strftime("%Y-%m-%d %H:%M:%S"),
           "protocol": {"repeats": repeats, "baseline_repeats": brepeats, "statistic": "median over repeats, "
                        "then median over initial conditions", "interleaved": True, "process": "one, serial"}}
    # references (work_precision): exact, on the longest grid end of every run
    refs, ref_info = {}, []
    if not lh:
        for T in horizons:
            T_ref = max([T] + [grid_end(h, T) for h in cfg.h + cfg.baseline_grids()])
            for b in betas:
                t0 = time.perf_counter()
                ref = vcirun.reference(system, T=T_ref, beta=b, params=params, rtol=cfg.reference_rtol)
                refs[(T, b)] = ref
                tt = np.linspace(0.0, T, 20001)
                qn = float(np.sqrt((tt[1] - tt[0]) * np.sum(np.asarray(ref(tt)) ** 2)))   # ||q_ref||_L2
                ref_info.append({"T": T, "beta": b, "impacts": len(ref.impacts), "accuracy": float(ref.accuracy),
                                 "q_norm": qn,
                                 "seconds": time.perf_counter() - t0})
        out["references"] = ref_info
        log(f"references: {len(ref_info)} (impacts {min(r['impacts'] for r in ref_info)}.."
            f"{max(r['impacts'] for r in ref_info)}, self-reported accuracy <= "
            f"{max(r['accuracy'] for r in ref_info):.2g})")
    runs: list[_Run] = []
    for T in horizons:
        for spec in specs:
            kw = spec.simulate_kwargs()
            for h in cfg.h:
                if grid_count(h, T) > cfg.max_steps:
                    continue
                for b in betas:
                    runs.append(_Run("vcirun", spec.display, spec.name, kw, float(h), T, b, {"need_energy": lh}))
        for label, meth in (extra_methods or {}).items():
            for h in cfg.h:
                if grid_count(h, T) > cfg.max_steps:
                    continue
                for b in betas:
                    runs.append(_Run("vcirun", label, meth, {}, float(h), T, b, {"need_energy": lh}))
        for solver, rtols in cfg.baselines.items():
            if T > cfg.baseline_max_T.get(solver, math.inf):
                continue
            for hg in cfg.baseline_grids():
                if grid_count(hg, T) > cfg.max_steps:
                    continue
                for rtol in rtols:
                    for b in betas:
                        # "DOP853/numpy": the same solver on a lambdified numpy model (what a user writes)
                        base, _, rhs = solver.partition("/")
                        kw = {"rtol": float(rtol)} | ({"kernels": rhs} if rhs else {})
                        runs.append(_Run("baseline", solver, base, kw, hg, T, b, {"need_energy": lh}))
    # warm up: compile every kernel set and touch every (method, h) once, untimed
    warm = set()
    for r in runs:
        if r.kind == "vcirun" and (r.label, r.h) not in warm:
            warm.add((r.label, r.h))
            vcirun.simulate(system, r.method, h=r.h, T=min(r.T, 20 * r.h), beta=r.beta, params=params, **r.kwargs)
        elif r.kind == "baseline" and r.label not in warm:
            warm.add(r.label)
            solve_ivp_run(system, r.method, h=r.h, T=min(r.T, 1.0), beta=r.beta, params=params, rtol=1e-6,
                          **{k: v for k, v in r.kwargs.items() if k == "kernels"})
    log(f"{len(runs)} runs x repeats ({repeats} vcirun, {brepeats} solve_ivp), interleaved")
    stopped = set()  # (solver, rtol, T): a run hit the time limit; the remaining ones are skipped
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for rep in range(max(repeats, brepeats)):
            for r in runs:
                nrep = repeats if r.kind == "vcirun" else brepeats
                if rep >= nrep:
                    continue
                key = (r.label, r.kwargs.get("rtol"), r.T, r.h)
                if r.kind == "baseline" and key in stopped:
                    continue
                if rep > 0 and r.record.get("status") not in ("ok",):
                    continue  # failures are not worth timing again
                traj, call, cpu = _call(r, system, params, cfg.baseline_time_limit)
                rec = r.record
                rec.setdefault("walls", []).append(float(traj.wall_time))
                rec.setdefault("calls", []).append(float(call))
                rec.setdefault("cpus", []).append(float(cpu))
                if rep == 0:
                    rec.update(status=traj.status, message=traj.message[:300], n_steps=int(traj.n_steps),
                               n_impacts=int(len(traj.impacts)))
                    if traj.status == "time_limit":
                        stopped.add(key)
                    if r.kind == "baseline":
                        rec["nfev"] = int(traj.options.get("nfev", 0))
                    if r.kind == "baseline" and lh:   # H on the grid, outside the timed call
                        traj.H = hamiltonian_on_grid(system, traj.q, traj.p, params)
                    if lh:
                        rec["dH"], rec["dHmod"] = _energy(traj)
                        if r.kind == "baseline" and traj.status != "ok":
                            rec["dH"] = math.nan
                    else:
                        ref = refs[(r.T, r.beta)]
                        rec["l2"] = float(vcirun.l2_error(traj, ref)) if traj.status == "ok" else math.nan
                        rec["dH"], rec["dHmod"] = _energy(traj)
                    del traj
            log(f"  pass {rep + 1}/{max(repeats, brepeats)} done ({time.perf_counter() - t_study:.0f} s)")
    recs = []
    for r in runs:
        rec = dict(r.record)
        rec.pop("need_energy", None)
        rec.update(kind=r.kind, label=r.label, method=r.method if isinstance(r.method, str) else repr(r.method),
                   options={k: v for k, v in r.kwargs.items()},
                   rtol=r.kwargs.get("rtol"), h=r.h, T=r.T, beta=r.beta,
                   wall=statistics.median(rec["walls"]) if rec.get("walls") else math.nan,
                   call=statistics.median(rec["calls"]) if rec.get("calls") else math.nan,
                   cpu=statistics.median(rec["cpus"]) if rec.get("cpus") else math.nan)
        recs.append(rec)
    out["runs"] = recs
    ics = []
    from ..run.resolve import resolve_system

    sysm = resolve_system(system)
    for b in betas:
        q0, p0 = sysm.initial_state(beta=b, params=sysm.param_values(params))
        ics.append({"beta": b, "H0": float(hamiltonian_on_grid(system, q0[None, :], p0[None, :], params)[0])})
    out["initial_conditions"] = ics
    analyze(out)
    out["machine"]["loadavg_end"] = list(os.getloadavg())
    out["seconds"] = time.perf_counter() - t_study
    return out


# --- analysis ---------------------------------------------------------------------------------------
def lost_threshold(res: dict) -> float:
    """The error beyond which a run has lost the motion: 10 % of the median ||q_ref||_L2 (work_precision)
    or of the median |H0| (long_horizon); inf if unknown. Solver runs beyond it are left out of the
    matched-accuracy comparison (a solve_ivp run that missed an impact is not a cheap, inaccurate
    answer but a wrong one), and vcirun points beyond it are marked, not rated."""
    if res["study"] == "work_precision":
        v = [x["q_norm"] for x in res.get("references", []) if x.get("q_norm")]
    else:
        v = [abs(x["H0"]) for x in res.get("initial_conditions", []) if x.get("H0")]
    return 0.1 * statistics.median(v) if v else math.inf


def analyze(res: dict) -> dict:
    """(Re)compute the summary and the matched-accuracy ratios of a study from its runs."""
    metric = "dH" if res["study"] == "long_horizon" else "l2"
    res["lost_threshold"] = lost_threshold(res)
    res["summary"] = summarize(res["runs"], metric=metric)
    res["ratios"] = matched_ratios(res["runs"], res["summary"], metric=metric, lost=res["lost_threshold"])
    res["front"] = vcirun_front(res["ratios"], lost=res["lost_threshold"], floor=_reference_floor(res))
    return res


def _median(xs):
    xs = [x for x in xs if x is not None and np.isfinite(x)]
    return statistics.median(xs) if xs else math.nan


def summarize(recs: list[dict], metric: str = "l2") -> list[dict]:
    """One point per (T, kind, label, h, rtol): medians over initial conditions (NaN if any run failed:
    a point must hold for every initial condition)."""
    groups: dict = {}
    for r in recs:
        groups.setdefault((r["T"], r["kind"], r["label"], r["h"], r["rtol"]), []).append(r)
    pts = []
    for (T, kind, label, h, rtol), rs in groups.items():
        ok = all(r.get("status") == "ok" for r in rs)
        err = [r.get(metric, math.nan) for r in rs]
        p = {"T": T, "kind": kind, "label": label, "h": h, "rtol": rtol, "n": len(rs), "all_ok": ok,
             "statuses": sorted({r.get("status", "?") for r in rs}),
             "err": _median(err) if ok else math.nan, "err_max": max(err) if ok else math.nan,
             "wall": _median([r["wall"] for r in rs]), "call": _median([r["call"] for r in rs]),
             "cpu": _median([r["cpu"] for r in rs]),
             "impacts": _median([r.get("n_impacts", math.nan) for r in rs])}
        if metric == "dH":
            p["dHmod"] = _median([r.get("dHmod", math.nan) for r in rs]) if ok else math.nan
        pts.append(p)
    return pts


def _front(points):
    """Pareto front [(time, err)] sorted by time: each point more accurate than every cheaper one."""
    pts = sorted((t, e) for t, e in points if np.isfinite(t) and np.isfinite(e) and e > 0 and t > 0)
    front = []
    for t, e in pts:
        if not front or e < front[-1][1]:
            front.append((t, e))
    return front


def time_at_error(front, e) -> tuple[float, str]:
    """(solver time to reach error e, how): 'interpolated', 'cheapest_more_accurate' (upper bound),
    'not_reached' (lower bound: the tightest tolerance's time), or 'none'."""
    if not front or not (e > 0 and np.isfinite(e)):
        return math.nan, "none"
    if e >= front[0][1]:
        return front[0][0], "cheapest_more_accurate"
    if e < front[-1][1]:
        return front[-1][0], "not_reached"
    for (t0, e0), (t1, e1) in zip(front[:-1], front[1:]):
        if e1 <= e <= e0:
            if e0 == e1:
                return t0, "interpolated"
            w = (math.log(e) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(t0) + w * (math.log(t1) - math.log(t0))), "interpolated"
    return math.nan, "none"


def matched_ratios(recs: list[dict], summary: list[dict], metric: str = "l2", lost: float = math.inf) -> list[dict]:
    """Speed ratio solver time / vcirun time at the vcirun point's error, per (T, method, h), for the
    compiled-loop time ('wall'), the whole call ('call') and its CPU time ('cpu'); on the medians and
    per initial condition. Solver runs with an error above `lost` are not candidates."""
    out = []
    if not (lost > 0):
        lost = math.inf
    solvers = sorted({p["label"] for p in summary if p["kind"] == "baseline"})
    for p in summary:
        if p["kind"] != "vcirun" or not np.isfinite(p["err"]):
            continue
        row = {"T": p["T"], "label": p["label"], "h": p["h"], "err": p["err"], "wall": p["wall"], "call": p["call"],
               "cpu": p["cpu"]}
        for timing in ("wall", "call", "cpu"):
            best = (math.inf, "none", None)
            for s in solvers:
                grid = [q for q in summary if q["kind"] == "baseline" and q["label"] == s and q["T"] == p["T"]]
                hs = sorted({q["h"] for q in grid}, key=lambda x: abs(math.log(x / p["h"])))
                if not hs:
                    continue
                same = [q for q in grid if q["h"] == hs[0]]   # the same output grid (or the nearest)
                t, how = time_at_error(_front([(q[timing], q["err"]) for q in same if q["err"] <= lost]), p["err"])
                ratio = t / p[timing] if np.isfinite(t) else math.nan
                row[f"{s}_{timing}_ratio"] = ratio
                row[f"{s}_{timing}_how"] = how
                row[f"{s}_grid_h"] = hs[0]
                if np.isfinite(ratio) and ratio < best[0]:
                    best = (ratio, how, s)
            row[f"best_{timing}_ratio"] = best[0] if np.isfinite(best[0]) else math.nan
            row[f"best_{timing}_how"] = best[1]
            row[f"best_{timing}_solver"] = best[2]
        # per initial condition (wall time), against the best solver
        per = []
        for b in sorted({r["beta"] for r in recs}):
            mine = [r for r in recs if r["kind"] == "vcirun" and r["label"] == p["label"] and r["h"] == p["h"]
                    and r["T"] == p["T"] and r["beta"] == b]
            if not mine or mine[0].get("status") != "ok":
                continue
            e, w = mine[0].get(metric, math.nan), mine[0]["wall"]
            best_b = math.inf
            for s in solvers:
                theirs = [r for r in recs if r["kind"] == "baseline" and r["label"] == s and r["T"] == p["T"]
                          and r["beta"] == b and r.get("status") == "ok"]
                if not theirs:
                    continue
                hg = min({r["h"] for r in theirs}, key=lambda x: abs(math.log(x / p["h"])))
                t, how = time_at_error(_front([(r["wall"], r.get(metric, math.nan)) for r in theirs
                                               if r["h"] == hg and r.get(metric, math.nan) <= lost]), e)
                if np.isfinite(t) and how == "interpolated":
                    best_b = min(best_b, t / w)
            if np.isfinite(best_b):
                per.append(best_b)
        row["per_ic_wall_ratio_median"] = statistics.median(per) if per else math.nan
        row["per_ic_wall_ratio_min"] = min(per) if per else math.nan
        row["per_ic_n"] = len(per)
        r_, how_ = row["best_wall_ratio"], row["best_wall_how"]
        if p["err"] > lost:
            row["competitive"] = "lost the motion"
        elif not np.isfinite(r_):
            row["competitive"] = "no solver data"
        elif how_ == "interpolated":
            row["competitive"] = "yes" if r_ > 1.0 else "no"
        elif how_ == "not_reached":
            row["competitive"] = "yes"          # no solve_ivp run reached this accuracy
        else:                                   # solve_ivp's cheapest run is more accurate
            row["competitive"] = "faster, less accurate" if r_ > 1.0 else "no"
        out.append(row)
    return out


# --- printing ---------------------------------------------------------------------------------------
def _g(x, fmt=".3g"):
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else format(x, fmt)


_HOW = {"interpolated": "", "cheapest_more_accurate": "<=", "not_reached": ">=", "none": "?"}


def vcirun_front(ratios: list[dict], timing: str = "call", lost: float | None = math.inf,
                 floor: float = 0.0) -> list[dict]:
    """vcirun's work-precision front: over every method and h (median rows of `ratios`, motion not
    lost), sorted by `timing` ('call': the whole simulate() call, what a user waits for), each point
    more accurate than every cheaper one. This is the curve a user choosing the best vcirun method
    for an accuracy gets; the performance target "at every accuracy level ... at least 10 times faster"
    is read on it. Each entry keeps the point's ratios against every solver (same output grid). Errors at or
    below `floor` (the exact reference's own accuracy, times 3) are not resolved: only the cheapest
    such point is kept."""
    lost = lost if lost is not None and np.isfinite(lost) else math.inf
    out = []
    for T in sorted({r["T"] for r in ratios}):
        pts = sorted((r for r in ratios if r["T"] == T and r["err"] is not None and np.isfinite(r["err"])
                      and r["err"] <= lost), key=lambda r: r[timing])
        best = math.inf
        for r in pts:
            if r["err"] < best and best > floor:
                best = r["err"]
                out.append(r | {"front_timing": timing, "at_reference_floor": bool(r["err"] <= floor)})
    return out


def _reference_floor(res: dict) -> float:
    acc = [r.get("accuracy") for r in res.get("references") or [] if r.get("accuracy") is not None]
    return 3.0 * max(acc) if acc else 0.0


def print_tables(res: dict, file=sys.stdout) -> None:
    lh = res["study"] == "long_horizon"
    metric = "max|H-H0|" if lh else "L2 error"
    pr = lambda s="": print(s, file=file)  # noqa: E731
    pr(f"== {res['name']}: {res['description']}")
    pr(f"   machine: {res['machine']['cpus']} cpus, load {res['machine']['loadavg_start'][0]:.2f} at start; "
       f"protocol: {res['protocol']['statistic']}, {res['protocol']['repeats']} / "
       f"{res['protocol']['baseline_repeats']} repeats, interleaved")
    for T in sorted({p["T"] for p in res["summary"]}):
        pr(f"-- T = {T:g}: median over {len({r['beta'] for r in res['runs']})} initial conditions")
        hdr = f"{'method':22s} {'h / rtol':>9s} {'grid h':>8s} {metric:>11s} "
        if lh:
            hdr += f"{'max|Hm-Hm0|':>11s} "
        hdr += f"{'loop ms':>10s} {'call ms':>10s} {'call CPU ms':>11s} {'impacts':>7s}  status"
        pr(hdr)
        for p in sorted([q for q in res["summary"] if q["T"] == T],
                        key=lambda q: (q["kind"] != "vcirun", q["label"], -(q["rtol"] or 0), -q["h"])):
            par = _g(p["rtol"], ".0e") if p["kind"] == "baseline" else _g(p["h"], ".2g")
            line = (f"{p['label']:22s} {par:>9s} {_g(p['h'], '.2g'):>8s} {_g(p['err'], '.3e'):>11s} ")
            if lh:
                line += f"{_g(p.get('dHmod'), '.3e'):>11s} "
            line += (f"{_g(p['wall'] * 1e3, '.4g'):>10s} {_g(p['call'] * 1e3, '.4g'):>10s} "
                     f"{_g(p.get('cpu', math.nan) * 1e3, '.4g'):>11s} "
                     f"{_g(p['impacts'], '.0f'):>7s}  {','.join(p['statuses'])}")
            pr(line)
        lost = res.get("lost_threshold", math.inf)
        lost = lost if lost is not None and np.isfinite(lost) else math.inf
        if np.isfinite(lost):
            what = "||q_ref||_L2" if not lh else "|H0|"
            pr(f"   lost the motion: an error above 10 % of the median {what} ({lost:.2g}); such solve_ivp runs are "
               "left out of the matching, such vcirun points are marked *")
        rows = [r for r in res.get("ratios", []) if r["T"] == T]
        if rows:
            solvers = sorted({k.split("_")[0] for r in rows for k in r if k.endswith("_wall_ratio")} - {"best"})
            pr(f"-- speed ratio solve_ivp / vcirun at matched {metric} (same output grid; <= : solve_ivp's cheapest "
               "run is already more accurate, >= : not reached by solve_ivp)")
            pr(f"{'method':22s} {'h':>8s} {metric:>11s} " + " ".join(f"{s + ' loop':>12s} {s + ' call':>12s} "
                                                                      f"{s + ' CPU':>12s}" for s in solvers)
               + f" {'best loop':>10s} {'per-IC med/min':>15s} competitive")
            for r in rows:
                cells = []
                for s in solvers:
                    for tm in ("wall", "call", "cpu"):
                        cells.append(f"{_HOW[r.get(f'{s}_{tm}_how', 'none')] + _g(r.get(f'{s}_{tm}_ratio'), '.3g'):>12s}")
                best = _HOW[r["best_wall_how"]] + _g(r["best_wall_ratio"], ".3g")
                per = f"{_g(r['per_ic_wall_ratio_median'], '.3g')}/{_g(r['per_ic_wall_ratio_min'], '.3g')}"
                star = "*" if r["err"] > lost else " "
                pr(f"{r['label']:22s} {_g(r['h'], '.2g'):>8s} {_g(r['err'], '.3e'):>10s}{star} " + " ".join(cells)
                   + f" {best:>10s} {per:>15s} {r['competitive']}")
        front = [r for r in res.get("front") or vcirun_front(res.get("ratios", []), lost=lost,
                                                             floor=_reference_floor(res)) if r["T"] == T]
        if front and not lh:
            solvers = sorted({k.split("_")[0] for r in front for k in r if k.endswith("_call_ratio")} - {"best"})
            pr("-- vcirun's front (best method at each accuracy, whole-call time) against solve_ivp, ratio of "
               "whole-call times (loop times in brackets)")
            pr(f"{'method':22s} {'h':>8s} {metric:>11s} {'call ms':>9s} " + " ".join(f"{s:>22s}" for s in solvers))
            for r in front:
                cells = [f"{_HOW[r.get(f'{s}_call_how', 'none')] + _g(r.get(f'{s}_call_ratio'), '.3g')} "
                         f"({_g(r.get(f'{s}_wall_ratio'), '.3g')})" for s in solvers]
                pr(f"{r['label']:22s} {_g(r['h'], '.2g'):>8s} {_g(r['err'], '.3e'):>11s} {r['call'] * 1e3:9.3f} "
                   + " ".join(f"{c:>22s}" for c in cells))
    pr(f"   study wall time {res['seconds']:.0f} s")


def save(res: dict, path) -> Path:
    return save_json(res, path)


def load(path) -> dict:
    """A saved study (None -> NaN in the runs' numeric fields), re-analysed."""
    res = load_json(path)
    for r in res.get("runs", []):
        for k, v in list(r.items()):
            if v is None and k not in ("rtol", "message") and not k.endswith(("_how", "_solver")):
                r[k] = math.nan
    return analyze(res)   # summary and ratios from the stored runs (the analysis may be newer than the file)
