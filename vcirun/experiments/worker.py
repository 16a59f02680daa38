"""The worker side of a sweep: run specs and tasks, and what a worker does with them (apart
from `sweep` so that `executors` imports this module and not `sweep`, which imports `executors`).

A task is the pending runs of one initial condition (`make_tasks`). A worker process (the local
pool, fork context, or a Dask worker thread) builds the system once (`_WorkerState`), keeps compiled
kernels and reference solutions across its tasks, and returns (or, in the local pool, streams run by
run: `_execute_streamed`) result dicts: the reference of the initial condition when the task stores
it, and each run's attributes and arrays. A run that fails numerically, or raises, is a result like
any other (its status and message recorded).
"""
from __future__ import annotations

import concurrent.futures as cf
import contextlib
import math
import multiprocessing as mp
import os
import signal
import sys
import time
import traceback
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ..core.sizes import limit_memory
from ..io.batches import attrs_text
from ..run.trajectory_files import trajectory_payload
from .config import InitialCondition, MethodReference, MethodSpec, NoReference, SweepConfig, build_system

__all__ = ["SweepError", "RunSpec", "Task", "make_tasks"]


class SweepError(RuntimeError):
    """A sweep that cannot start or cannot go on; one-line message."""


@dataclass(frozen=True)
class RunSpec:
    run_id: str
    method_index: int
    method: MethodSpec
    h: float
    ic_index: int
    ic: InitialCondition

    @property
    def label(self) -> str:
        return self.method.display


@dataclass
class Task:
    ic: InitialCondition
    runs: list
    want_reference: bool


def make_tasks(pending: list[RunSpec], workers: int, stored_refs: set, needs_reference: bool,
               reference_ics=()) -> list[Task]:
    """One task per initial condition; split when there are fewer than 2 per worker. `reference_ics`:
    initial conditions whose runs are all stored but whose reference is missing (a task of no runs)."""
    by_ic: OrderedDict[str, list[RunSpec]] = OrderedDict()
    for s in pending:
        by_ic.setdefault(s.ic.key, []).append(s)
    extra = [Task(ic, [], True) for ic in reference_ics if ic.key not in by_ic] if needs_reference else []
    parts = 1
    if workers > 1 and len(by_ic) < 2 * workers:
        parts = math.ceil(2 * workers / max(1, len(by_ic)))
    tasks = []
    for key, runs in by_ic.items():
        k = max(1, min(parts, len(runs)))
        size = math.ceil(len(runs) / k)
        for j in range(0, len(runs), size):
            want = needs_reference and key not in stored_refs and j == 0
            tasks.append(Task(runs[0].ic, runs[j:j + size], want))
    return tasks + extra


# --- worker side ----------------------------------------------------------------------------------
class _WorkerState:
    def __init__(self, cfg: SweepConfig, ref_T: float, ref_h: float):
        import warnings

        import vcirun  # noqa: F401 - once per process; kernels and scenes are cached inside
        from vcirun.core.grid import GridWarning

        warnings.simplefilter("ignore", GridWarning)  # the client says it once for the sweep

        self.cfg = cfg
        self.ref_T = ref_T
        self.ref_h = ref_h
        self.system, self.params, _ = build_system(cfg)
        self.tolerances = cfg.tolerances.model_dump(exclude_none=True)
        self.refs: OrderedDict[str, object] = OrderedDict()
        self.ref_errors: dict[str, str] = {}
        self.ref_grids: OrderedDict[tuple, _OnGrid] = OrderedDict()   # q_ref on a run's grid (_l2_error)
        self.warm: set[str] = set()


_STATE: _WorkerState | None = None


def _set_parent_death_signal() -> None:
    """Linux: die with the parent (a SIGKILLed sweep must not leave workers computing)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


_OUTBOX = None  # pool workers: the queue each finished run is sent to (see executors.LocalExecutor)


def _init_worker(cfg: SweepConfig, ref_T: float, ref_h: float, parent_pid: int | None = None,
                 in_pool: bool = True, outbox=None) -> None:
    global _STATE, _OUTBOX
    _OUTBOX = outbox
    if in_pool:
        # The parent handles Ctrl-C and SIGTERM for everyone (a terminal sends Ctrl-C to the whole
        # process group); a worker is stopped by the parent's terminate(), i.e. SIGTERM's default action.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if parent_pid is not None:
        _set_parent_death_signal()
        if os.getppid() != parent_pid:  # the parent died before prctl took effect
            os._exit(1)
    if in_pool:   # a module keeps its build in a sweep (one build per method's times; vcirun.codegen.specialize)
        from vcirun.codegen.kernel_cache import default

        default().switch_builds = False
    if _STATE is None or _STATE.cfg != cfg or (_STATE.ref_T, _STATE.ref_h) != (ref_T, ref_h):
        _STATE = _WorkerState(cfg, ref_T, ref_h)


def _one_line(text: str, limit: int = 500) -> str:
    s = " ".join(str(text).split())
    return s if len(s) <= limit else s[: limit - 3] + "..."


def _reference(st: _WorkerState, ic: InitialCondition):
    """The reference for one initial condition (cached in this process), or None with a reason."""
    import vcirun

    ref_spec = st.cfg.reference
    if isinstance(ref_spec, NoReference):
        return None
    if ic.key in st.refs:
        st.refs.move_to_end(ic.key)
        return st.refs[ic.key]
    if ic.key in st.ref_errors:
        return None
    kw = dict(T=st.ref_T, params=st.params, **ic.simulate_kwargs())
    if isinstance(ref_spec, MethodReference):
        kw.update(method=ref_spec.method, h=ref_spec.h)
    else:
        kw.update(rtol=ref_spec.rtol)
    try:
        ref = vcirun.reference(st.system, **kw)
    except Exception as e:  # noqa: BLE001 - recorded; runs keep their trajectories, l2 becomes NaN
        st.ref_errors[ic.key] = _one_line(f"{type(e).__name__}: {e}")
        return None
    if getattr(ref, "status", "ok") != "ok":
        # an exact reference that stopped before T (Painleve's case) has no values past its end: the
        # runs and the reference's record say so, as for a reference that raised
        st.ref_errors[ic.key] = _one_line(f"the exact reference stopped at t = {ref.T:.6g}: {ref.message}")
        return None
    if ref.kind in ("taylor", "dop853") and not math.isfinite(ref.accuracy):
        # an exact reference whose accuracy is unknown is not a reference (runs get NaN, not a number)
        st.ref_errors[ic.key] = f"the exact reference's self-reported accuracy is {ref.accuracy}"
        return None
    st.refs[ic.key] = ref
    while len(st.refs) > 8:
        st.refs.popitem(last=False)
    return ref


def _reference_payload(st: _WorkerState, ic: InitialCondition, ref) -> tuple[dict, dict]:
    spec = st.cfg.reference
    attrs = {"ic_key": ic.key, "beta": ic.beta, "kind": spec.kind, "T": st.ref_T,
             "rtol": getattr(spec, "rtol", None), "method": getattr(spec, "method", ""),
             "ref_h": getattr(spec, "h", None)}
    if ref is None:
        attrs.update(status="failed", message=st.ref_errors.get(ic.key, ""), accuracy=None, path="",
                     path_reason="")
        return attrs, {}
    n = max(1, math.ceil(st.ref_T / st.ref_h - 1e-9))
    t = np.linspace(0.0, st.ref_T, n + 1)
    arrays = {"t": t, "q": np.asarray(ref(t)), "impacts": np.asarray(ref.impacts, float)}
    with contextlib.suppress(Exception):
        arrays["p"] = np.asarray(ref.p(t))
    attrs.update(status="ok", message="", accuracy=float(getattr(ref, "accuracy", float("nan"))),
                 H0=float(getattr(ref, "H0", float("nan"))), n_impacts=int(len(ref.impacts)),
                 ref_description=str(getattr(ref, "kind", spec.kind)),
                 # the exact reference's integration path (taylor or dop853) and why DOP853, if it is
                 path=str(ref.kind) if ref.kind in ("taylor", "dop853") else "",
                 path_reason=str(getattr(ref, "kind_reason", "")))
    return attrs, arrays


def _resolved_method(spec: MethodSpec) -> dict:
    """What a method spec resolves to (name, ld, partial, reset, mh_order, flow_order): provenance.
    The config layer has already resolved every method, so a failure here is a bug and raises."""
    from vcirun.methods.table import resolve_method

    if spec.tol is not None and spec.name == "auto":   # simulate(tol=...) chooses; core_method records it
        return {"name": "auto", "tol": spec.tol}
    m = resolve_method(spec.name, **{k: v for k, v in spec.simulate_kwargs().items()
                                     if k in ("ld", "mh_order", "flow_order")})
    return {k: getattr(m, k, None) for k in ("name", "ld", "partial", "reset", "mh_order", "flow_order")}


def _simulate_kwargs(st: _WorkerState, spec: RunSpec, T: float) -> dict:
    kw = dict(h=spec.h, T=T, **spec.method.simulate_kwargs(), **spec.ic.simulate_kwargs(), **st.tolerances)
    if st.params:
        kw["params"] = st.params
    return kw


class _OnGrid:
    """A reference evaluated once on one grid: called with that grid's times it returns the stored
    q_ref(t_k); with other times it evaluates the reference."""

    def __init__(self, ref, t):
        self.ref, self.t, self.q = ref, t.copy(), np.asarray(ref(t))

    def __call__(self, t):
        return self.q if np.array_equal(t, self.t) else self.ref(t)


def _l2_error(st: _WorkerState, ic: InitialCondition, traj, ref) -> float:
    """vcirun.l2_error(traj, ref) with the reference evaluated once per (reference, grid): the runs of
    every method at one h share their grid times, so they share q_ref(t_k) (the values l2_error would
    compute, hence the same error to the bit)."""
    import vcirun

    key = (ic.key, id(ref), traj.t.shape[0])
    on_grid = st.ref_grids.get(key)
    if on_grid is None or on_grid.ref is not ref or not np.array_equal(on_grid.t, traj.t):
        on_grid = st.ref_grids[key] = _OnGrid(ref, traj.t)
        while len(st.ref_grids) > 64:
            st.ref_grids.popitem(last=False)
    return float(vcirun.l2_error(traj, on_grid))


def _execute_run(st: _WorkerState, spec: RunSpec, ref) -> dict:
    import vcirun

    base = {"run_id": spec.run_id, "method": spec.method.name, "label": spec.label,
            "method_index": spec.method_index, "method_spec": spec.method.identity(),
            "resolved_method": _resolved_method(spec.method), "ic_key": spec.ic.key, "ic_index": spec.ic_index,
            "beta": spec.ic.beta, "T_requested": st.cfg.T, "worker_pid": os.getpid()}
    if spec.method.display not in st.warm:
        st.warm.add(spec.method.display)
        with contextlib.suppress(Exception):  # the timed call below reports any error
            vcirun.simulate(st.system, spec.method.name, **_simulate_kwargs(st, spec, spec.h))
    walls, calls = [], []
    for _ in range(st.cfg.timing_repeats):
        t0 = time.perf_counter()
        try:
            traj = vcirun.simulate(st.system, spec.method.name, **_simulate_kwargs(st, spec, st.cfg.T))
        except Exception as e:  # noqa: BLE001 - a run that raises is recorded, the sweep goes on
            attrs = {**base, "status": "error", "message": _one_line(f"{type(e).__name__}: {e}"),
                     "traceback": traceback.format_exc(limit=20), "h": spec.h, "T": st.cfg.T,
                     "n_steps": 0, "n_impacts": 0, "wall_time": None, "wall_time_call": time.perf_counter() - t0,
                     "l2_error": None, "l2_note": "run raised", "has_trajectory": False, "has_Hmod": False}
            return {"run_id": spec.run_id, "attrs": attrs, "arrays": {}}
        calls.append(time.perf_counter() - t0)
        walls.append(float(traj.wall_time))
        if traj.status != "ok" or getattr(traj, "tier", None) == "interpreted":
            break  # a failure is not worth timing again; an interpreted run is not timed (below)
    traj.wall_time = min(walls)  # identical runs: the spread is timing noise, the minimum the cost
    call = min(calls)
    attrs, arrays = trajectory_payload(traj, store_arrays=st.cfg.store_every)
    attrs["wall_time_repeats"] = walls
    attrs["tier"] = traj.tier or "compiled"
    if attrs["tier"] == "interpreted":
        # the run's numbers are the compiled tier's (vcirun.codegen.tiers); its time is not: kept apart,
        # so that no table or figure of wall_time mixes the tiers (Table II's means skip a None)
        attrs["wall_time_interpreted"], attrs["wall_time"], attrs["wall_time_repeats"] = walls[0], None, []
    l2, note = None, ""
    if isinstance(st.cfg.reference, NoReference):
        note = "no reference configured"
    elif spec.method.options.constrained is False:
        note = "unconstrained run: the reference solves the constrained system"
    elif traj.status != "ok":
        note = "run failed; error over a partial grid would mislead"
    elif ref is None:
        note = "reference failed: " + st.ref_errors.get(spec.ic.key, "")
    else:
        l2 = _l2_error(st, spec.ic, traj, ref)
    attrs.update(base)
    if spec.method.tol is not None or st.cfg.error_estimate:   # the choice of tol= and the error estimate
        from ..run.estimate import sweep_attrs

        attrs.update(sweep_attrs(traj, spec.h, st.cfg.error_estimate))
    attrs.update(l2_error=l2, l2_note=note, wall_time_call=call,
                 q0=np.asarray(traj.q[0], float) if len(traj.q) else None,
                 p0=np.asarray(traj.p[0], float) if len(traj.p) else None)
    # encoded here, in parallel, as the results file stores it (the client only splices the texts)
    return {"run_id": spec.run_id, "attrs": attrs, "arrays": arrays, "text": attrs_text(attrs)}


def _execute(task: Task, st: _WorkerState | None = None, emit=None) -> dict:
    """Worker entry point: the reference (if this task stores it) and every run of the task
    (state: this process's, or `st` given by the Dask executor). With `emit`, the runs are sent on
    as they are computed (result dicts of the runs finished within STREAM_INTERVAL, the reference
    with the first) and the return value only counts the messages (`streamed`). simulate's memory
    check uses the sweep's max_memory inside."""
    st = st or _STATE
    if st is None:  # pragma: no cover - initializer always runs first
        raise RuntimeError("worker not initialised")
    with limit_memory(st.cfg.max_memory):
        return _execute_task(task, st, emit)


def _execute_task(task: Task, st: _WorkerState, emit) -> dict:
    ref = None
    needs_ref = not isinstance(st.cfg.reference, NoReference) and (
        task.want_reference or any(r.method.options.constrained is not False for r in task.runs))
    if needs_ref:
        ref = _reference(st, task.ic)
    out = {"ic_key": task.ic.key, "runs": [], "reference": None}
    if task.want_reference:
        out["reference"] = _reference_payload(st, task.ic, ref)
    if emit is None:
        for spec in task.runs:
            out["runs"].append(_execute_run(st, spec, ref))
        return out
    sent, runs, since = 0, [], time.monotonic()
    for spec in task.runs:
        runs.append(_execute_run(st, spec, ref))
        if time.monotonic() - since >= STREAM_INTERVAL or spec is task.runs[-1]:
            emit({**out, "runs": runs})
            out["reference"], runs, since = None, [], time.monotonic()
            sent += 1
    if not task.runs:
        emit(out)
        sent += 1
    return {"streamed": sent}


# A pool worker sends a task's finished runs together once STREAM_INTERVAL seconds have passed (and
# at the task's end): a finished run waits at most that long before the client has it (the loss bound
# of a hard kill grows by it), and runs of a few milliseconds do not cost a message each (~0.35 ms of
# pickling and queueing per message, measured on the fig4 sweep).
STREAM_INTERVAL = 0.1


def _execute_streamed(task: Task) -> dict:
    """Pool entry point: `_execute` sending the runs to the client's queue as they finish (within
    STREAM_INTERVAL: a hard kill of the client then loses only what it had not committed, not whole
    tasks)."""
    return _execute(task, emit=_OUTBOX.put)


def _default_start_method() -> str:
    """fork where available: workers inherit the imported package and the kernels _preflight
    compiled, so a pool is ready at once (spawn costs every worker a fresh import and kernel load,
    seconds per sweep). The pool is created before any thread of ours starts, and workers use
    neither h5py nor rich, so nothing they need can be left locked by the fork."""
    return "fork" if "fork" in mp.get_all_start_methods() else "spawn"


def _terminate_pool(executor: cf.ProcessPoolExecutor) -> None:
    procs = list(getattr(executor, "_processes", {}) .values())
    executor.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        with contextlib.suppress(Exception):
            p.terminate()
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(timeout=5)
