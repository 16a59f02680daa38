"""Expand a sweep config into runs, compute them in parallel and store them as they arrive.

The grid is methods x h x initial conditions. Each run has a stable id: a short hash of everything
that determines its result (system, T, tolerances, method and options, h, initial condition), so
rerunning a sweep recomputes only the ids missing from the results file.

Execution: a `ProcessPoolExecutor` (fork context; `workers` processes, default every core), or a Dask
cluster (`executor` in the config, `--scheduler` on the command line; see `executors`). Each
worker imports vcirun once, builds the system once, and keeps compiled kernels and reference
solutions across its tasks. A task is the pending runs of one initial condition (split further
only when there are too few initial conditions to keep every worker busy), so the reference for
an initial condition is computed once, next to the runs that need it, and stored once. Before the
first timed run of each method a worker makes one untimed one-step run of it, so `wall_time`
measures integration, not kernel loading. The parent is the only writer of the results file
(see `storage.ResultsWriter`). A run that fails numerically, or raises, is recorded with its status
and message, and the sweep carries on. Ctrl-C and SIGTERM stop the workers, keep every finished
run and report the interruption. Storage (see `storage`): the client commits finished runs to a
journal beside the results file every `commit_interval` seconds (default 1 s, at a cost independent
of the file's size) and folds the journal into the HDF5 file when the sweep finishes; pool workers
send each run to the client as soon as it is computed. A SIGKILL therefore loses at most the runs
that finished in the last commit_interval (plus one commit's duration) and the runs being computed.
Before anything is created the sweep checks the memory of its runs in flight and the disk space its
results need.
"""
from __future__ import annotations

import concurrent.futures as cf
import contextlib
import hashlib
import json
import math
import multiprocessing as mp
import os
import shutil
import signal
import sys
import threading
import time
import traceback
from collections import OrderedDict, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import validation
from . import storage
from .config import InitialCondition, MethodReference, MethodSpec, NoReference, SweepConfig, build_system

__all__ = ["RunSpec", "Task", "SweepError", "SweepSummary", "expand", "run_sweep", "sweep_file", "default_workers"]


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


@dataclass
class SweepSummary:
    path: Path
    total: int = 0
    computed: int = 0
    skipped: int = 0
    failed: int = 0            # computed runs whose status is not ok
    deleted_incomplete: int = 0
    interrupted: str | None = None  # "SIGINT" | "SIGTERM"
    wall_time: float = 0.0
    status_counts: dict = field(default_factory=dict)
    workers: int = 1
    executor: str = "local"    # "local" | "dask"
    executor_stats: dict = field(default_factory=dict)  # task sizes, measured costs (executors.*.stats)
    write_time: float = 0.0    # seconds the client spent storing results, final commit included (serial)

    @property
    def ok(self) -> bool:
        return self.interrupted is None


def default_workers() -> int:
    """Every core this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


# --- grid ---------------------------------------------------------------------------------------
def run_identity(cfg: SweepConfig, method: MethodSpec, h: float, ic: InitialCondition) -> dict:
    """Everything that determines one run's result."""
    return {"system": cfg.canonical()["system"], "T": cfg.T,
            "tolerances": cfg.tolerances.model_dump(exclude_none=True), "method": method.identity(),
            "h": float(h), "ic": ic.identity()}


def run_id_for(identity: dict) -> str:
    return hashlib.sha256(json.dumps(identity, sort_keys=True).encode()).hexdigest()[:12]


def expand(cfg: SweepConfig) -> list[RunSpec]:
    """The run grid in a fixed order: method, then h, then initial condition."""
    ics = cfg.initial_conditions()
    specs = []
    for mi, m in enumerate(cfg.methods):
        for h in cfg.h:
            for ii, ic in enumerate(ics):
                specs.append(RunSpec(run_id_for(run_identity(cfg, m, h, ic)), mi, m, float(h), ii, ic))
    return specs


def reference_horizon(cfg: SweepConfig) -> float:
    """A run ends at N h with N = round(T / h), which may exceed T; the reference must cover it."""
    return max([cfg.T] + [round(cfg.T / h) * h for h in cfg.h])


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


def missing_references(cfg: SweepConfig, writer: storage.ResultsWriter) -> list[InitialCondition]:
    """Initial conditions whose reference the file lacks (e.g. a file that lost its references group)."""
    if isinstance(cfg.reference, NoReference):
        return []
    return [ic for ic in cfg.initial_conditions() if ic.key not in writer.references]


# --- worker side ----------------------------------------------------------------------------------
class _WorkerState:
    def __init__(self, cfg: SweepConfig, ref_T: float, ref_h: float):
        import vcirun  # noqa: F401 - once per process; kernels and scenes are cached inside

        self.cfg = cfg
        self.ref_T = ref_T
        self.ref_h = ref_h
        self.system, self.params, _ = build_system(cfg)
        self.tolerances = cfg.tolerances.model_dump(exclude_none=True)
        self.refs: OrderedDict[str, object] = OrderedDict()
        self.ref_errors: dict[str, str] = {}
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
        attrs.update(status="failed", message=st.ref_errors.get(ic.key, ""), accuracy=None)
        return attrs, {}
    n = max(1, math.ceil(st.ref_T / st.ref_h - 1e-9))
    t = np.linspace(0.0, st.ref_T, n + 1)
    arrays = {"t": t, "q": np.asarray(ref(t)), "impacts": np.asarray(ref.impacts, float)}
    with contextlib.suppress(Exception):
        arrays["p"] = np.asarray(ref.p(t))
    attrs.update(status="ok", message="", accuracy=float(getattr(ref, "accuracy", float("nan"))),
                 H0=float(getattr(ref, "H0", float("nan"))), n_impacts=int(len(ref.impacts)),
                 ref_description=str(getattr(ref, "kind", spec.kind)))
    return attrs, arrays


def _resolved_method(spec: MethodSpec) -> dict:
    try:
        from vcirun.methods import resolve_method

        m = resolve_method(spec.name, **{k: v for k, v in spec.simulate_kwargs().items()
                                         if k in ("ld", "mh_order", "flow_order")})
        return {k: getattr(m, k, None) for k in ("name", "ld", "partial", "reset", "mh_order", "flow_order")}
    except Exception:  # noqa: BLE001 - provenance only
        return {}


def _simulate_kwargs(st: _WorkerState, spec: RunSpec, T: float) -> dict:
    kw = dict(h=spec.h, T=T, **spec.method.simulate_kwargs(), **spec.ic.simulate_kwargs(), **st.tolerances)
    if st.params:
        kw["params"] = st.params
    return kw


def _execute_run(st: _WorkerState, spec: RunSpec, ref) -> dict:
    import vcirun

    base = {"run_id": spec.run_id, "method": spec.method.name, "label": spec.label,
            "method_index": spec.method_index, "method_spec": spec.method.identity(),
            "resolved_method": _resolved_method(spec), "ic_key": spec.ic.key, "ic_index": spec.ic_index,
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
        if traj.status != "ok":
            break  # a failure is not worth timing again
    traj.wall_time = min(walls)  # identical runs: the spread is timing noise, the minimum the cost
    call = min(calls)
    attrs, arrays = storage.trajectory_payload(traj, store_arrays=st.cfg.store_trajectories)
    attrs["wall_time_repeats"] = walls
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
        l2 = float(vcirun.l2_error(traj, ref))
    attrs.update(base)
    attrs.update(l2_error=l2, l2_note=note, wall_time_call=call,
                 q0=np.asarray(traj.q[0], float) if len(traj.q) else None,
                 p0=np.asarray(traj.p[0], float) if len(traj.p) else None)
    return {"run_id": spec.run_id, "attrs": attrs, "arrays": arrays}


def _execute(task: Task, st: _WorkerState | None = None, emit=None) -> dict:
    """Worker entry point: the reference (if this task stores it) and every run of the task
    (state: this process's, or `st` given by the Dask executor). With `emit`, each run is sent on
    as soon as it is computed (a result dict of one run, the reference with the first) and the
    return value only counts the messages (`streamed`). simulate's memory check uses the sweep's
    max_memory inside."""
    st = st or _STATE
    if st is None:  # pragma: no cover - initializer always runs first
        raise RuntimeError("worker not initialised")
    with validation.limit_memory(st.cfg.max_memory):
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
    sent = 0
    for spec in task.runs:
        emit({**out, "runs": [_execute_run(st, spec, ref)]})
        out["reference"] = None
        sent += 1
    if not task.runs:
        emit(out)
        sent += 1
    return {"streamed": sent}


def _execute_streamed(task: Task) -> dict:
    """Pool entry point: `_execute` sending every run to the client's queue as it finishes (a hard kill
    of the client then loses only what it had not committed, not whole tasks)."""
    return _execute(task, emit=_OUTBOX.put)


# --- client side -----------------------------------------------------------------------------------
class _Terminated(KeyboardInterrupt):
    """SIGTERM, delivered as an interruption so the same clean-up path runs."""


def _raise_terminated(signum, frame):
    raise _Terminated()


class _Reporter:
    """A rich progress bar with ETA on a terminal; one plain line per finished task otherwise."""

    def __init__(self, console, total: int, label: str, enabled: bool):
        self.console = console
        self.total = total
        self.done = 0
        self.failed = 0
        self.enabled = enabled and console is not None
        self.live = self.enabled and console.is_terminal
        self._progress = None
        self.label = label

    def start(self) -> None:
        """Start the live display (a thread; the fork-based pool must exist before it)."""
        if self.live and self._progress is None:
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn,
                                       TimeElapsedColumn, TimeRemainingColumn)

            self._progress = Progress(SpinnerColumn(), TextColumn("[bold]{task.description}"), BarColumn(),
                                      MofNCompleteColumn(), TextColumn("{task.fields[failed]}"),
                                      TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(),
                                      console=self.console, transient=False)
            self._task = self._progress.add_task(self.label, total=self.total, failed="")
            self._progress.start()

    def log(self, message: str) -> None:
        if self.enabled:
            self.console.print(message, highlight=False, markup=False)

    def advance(self, n: int, failed: int, saved: int, note: str) -> None:
        self.done += n
        self.failed += failed
        if self._progress is not None:
            self._progress.update(self._task, advance=n, failed=f"{self.failed} failed" if self.failed else "")
        elif self.enabled:
            self.console.print(f"[{self.done}/{self.total}] {note}; {saved} saved"
                               + (f"; {self.failed} failed" if self.failed else ""), highlight=False, markup=False)

    def stop(self) -> None:
        if self._progress is not None:
            self._progress.stop()
            self._progress = None


def _default_start_method() -> str:
    """fork where available: workers inherit the imported package and the kernels _preflight
    compiled, so a pool is ready at once (spawn costs every worker a fresh import and kernel load,
    seconds per sweep). The pool is created before any thread of ours starts, and workers use
    neither h5py nor rich, so nothing they need can be left locked by the fork."""
    return "fork" if "fork" in mp.get_all_start_methods() else "spawn"


def _preflight(cfg: SweepConfig, pending: list[RunSpec]) -> int:
    """One step of every method in this process: compiles (and caches on disk) the kernels the
    workers use, and turns bad input the core rejects into an error before any file exists.
    Returns the number of coordinates n."""
    import vcirun

    system, params, sysm = build_system(cfg)
    tol = cfg.tolerances.model_dump(exclude_none=True)
    seen = set()
    for spec in pending:
        if spec.method.display in seen:
            continue
        seen.add(spec.method.display)
        kw = dict(h=spec.h, T=spec.h, **spec.method.simulate_kwargs(), **spec.ic.simulate_kwargs(), **tol)
        if params:
            kw["params"] = params
        try:
            vcirun.simulate(system, spec.method.name, **kw)
        except ValueError as e:
            raise SweepError(f"methods[{spec.method_index}] ({spec.label}): {_one_line(e)}") from None
    if not isinstance(cfg.reference, NoReference):
        ic = pending[0].ic
        kw = dict(T=min(cfg.h), params=params, **ic.simulate_kwargs())
        if isinstance(cfg.reference, MethodReference):
            kw.update(method=cfg.reference.method, h=min(cfg.reference.h, min(cfg.h) / 2))
        else:
            kw.update(rtol=cfg.reference.rtol)
        try:
            vcirun.reference(system, **kw)
        except ValueError as e:
            raise SweepError(f"reference: {_one_line(e)}") from None
        except Exception:  # noqa: BLE001 - numerical trouble is reported per initial condition later
            pass
    return sysm.n


def _check_resources(cfg: SweepConfig, pending: list[RunSpec], n: int, workers: int, path: Path,
                     writer: storage.ResultsWriter) -> None:
    """Refuse, before the file is created, a sweep whose runs in flight exceed the memory limit or whose
    results cannot fit on the disk (their journal, then the file's final copy: about twice the data)."""
    if not pending:
        return
    steps = {h: validation.grid_size(h, cfg.T) for h in {s.h for s in pending}}
    N = max(steps.values())
    stored = validation.stored_bytes(N, n, store_trajectories=cfg.store_trajectories)
    try:  # each worker holds a run's buffers and its result message; the client the message and its record
        validation.check_run_memory(N, n, copies=min(workers, len(pending)), extra=2 * stored, limit=cfg.max_memory,
                                    field="h", hint=", or raise max_memory in the config (e.g. max_memory: 32GB) or "
                                                    "the VCIRUN_MAX_MEMORY environment variable")
    except ValueError as e:
        raise SweepError(f"{_one_line(e)} (with {min(workers, len(pending))} worker(s); fewer --workers need less)") \
            from None
    need = sum(validation.stored_bytes(steps[s.h], n, store_trajectories=cfg.store_trajectories) for s in pending)
    size = path.stat().st_size if path.exists() and not writer.force else 0
    total = size + 2 * need
    where = next((d for d in [path.parent, *path.parent.parents] if d.exists()), Path("."))
    try:
        free = shutil.disk_usage(where).free
    except OSError:
        return
    if total > free:
        raise SweepError(f"{path}: the {len(pending)} pending runs need about {validation.format_bytes(total)} on disk "
                         f"(their journal and the final copy of the file), {validation.format_bytes(free)} free in "
                         f"{where}; free space, choose another --output"
                         + (" or set store_trajectories: false" if cfg.store_trajectories else ""))


def _final_hooks(cfg: SweepConfig) -> list:
    """The sweep finished and the file is final: callables f(h5py.File) that run inside the last rewrite
    of a complete sweep (on the copy that then atomically replaces the file), e.g. a summary group of
    every run (issue 19). This is the one place where 'the file is final' happens."""
    return []


def _root_attrs(cfg: SweepConfig, config_text: str, config_path, specs: list[RunSpec]) -> dict:
    tol = cfg.tolerances.model_dump(exclude_none=True)
    try:
        from vcirun.api import DEFAULT_TOLERANCES

        tol = {**DEFAULT_TOLERANCES, **tol}
    except ImportError:  # pragma: no cover
        pass
    attrs = {
        "name": cfg.name, "description": cfg.description or "", "config_yaml": config_text,
        "config_sha256": hashlib.sha256(config_text.encode()).hexdigest(),
        "config_canonical": cfg.canonical(), "config_path": str(config_path or ""),
        "system": cfg.system_label(), "system_spec": cfg.canonical()["system"], "T": cfg.T,
        "h_values": list(cfg.h), "methods": [{"label": m.display, **m.identity()} for m in cfg.methods],
        "ic_keys": [ic.key for ic in cfg.initial_conditions()], "n_runs_expected": len(specs),
        "reference_kind": cfg.reference.kind, "tolerances": tol, "store_trajectories": cfg.store_trajectories,
        "timing_repeats": cfg.timing_repeats,
    }
    attrs.update(storage.environment_attrs())
    return attrs


def _terminate_pool(executor: cf.ProcessPoolExecutor) -> None:
    procs = list(getattr(executor, "_processes", {}) .values())
    executor.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        with contextlib.suppress(Exception):
            p.terminate()
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(timeout=5)


def run_sweep(cfg: SweepConfig, *, config_text: str | None = None, config_path=None, output=None,
              force: bool = False, workers: int | None = None, retry_failed: bool = False,
              console=None, progress: bool = True, argv: list | None = None,
              start_method: str | None = None, scheduler: str | None = None, task_size: int | None = None,
              worker_cache_dir: str | None = None, commit_interval: float | None = None) -> SweepSummary:
    """Compute every run of `cfg` missing from its results file; returns counts.

    output: results path (default cfg.output, else results/<name>.h5); force: start a new file;
    workers: local processes (default cfg.workers, else every core; 1 computes in this process);
    retry_failed: recompute stored runs whose status is not ok; start_method: multiprocessing start
    method of the pool (default fork where available, else spawn). scheduler: a Dask scheduler address
    (or "local"), winning over cfg.executor; task_size: runs per task (default automatic);
    worker_cache_dir: VCIRUN_CACHE_DIR of the Dask workers. commit_interval: seconds between journal
    commits (default 1, or VCIRUN_COMMIT_INTERVAL): the most a hard kill can lose. Raises SweepError
    (unusable file, a method the core rejects, not enough memory or disk, a worker that died, a lost
    scheduler) and storage.StorageError (a file that cannot be read or written).
    """
    from . import executors

    t_start = time.monotonic()
    path = Path(output) if output else cfg.output_path()
    workers = int(workers or cfg.workers or default_workers())
    ex_spec = executors.resolve_spec(cfg.executor, scheduler=scheduler, task_size=task_size,
                                     cache_dir=worker_cache_dir)
    specs = expand(cfg)
    if config_text is None:
        import yaml

        config_text = yaml.safe_dump(cfg.model_dump(mode="json", by_alias=True, exclude_none=True), sort_keys=False)
    summary = SweepSummary(path=path, total=len(specs), workers=workers, executor=ex_spec.kind)
    session = {"argv": list(argv if argv is not None else sys.argv), "workers": workers, "pid": os.getpid()}
    writer = storage.ResultsWriter(path, root_attrs=_root_attrs(cfg, config_text, config_path, specs),
                                   config_key=cfg.canonical_sha256(), force=force, session=session,
                                   commit_interval=commit_interval)
    writer.final_hooks = _final_hooks(cfg)
    writer.acquire()
    executor = None
    try:
        known = {s.run_id for s in specs}
        if retry_failed:
            writer.forget_runs([rid for rid, a in writer.complete_runs.items() if a.get("status") != "ok"])
        stale = [rid for rid in writer.complete_runs if rid not in known]
        if stale:  # cannot happen for an unchanged config key; guards against hash-scheme changes
            writer.forget_runs(stale)
        pending = [s for s in specs if s.run_id not in writer.complete_runs]
        summary.skipped = len(specs) - len(pending)
        summary.deleted_incomplete = len(writer.incomplete)
        pending_ics = {s.ic.key for s in pending}
        ref_only = [ic for ic in missing_references(cfg, writer) if ic.key not in pending_ics]
        if not pending and not ref_only:
            if writer.has_changes():
                writer.finish("complete")
            summary.status_counts = _status_counts(writer)
            summary.wall_time = time.monotonic() - t_start
            return summary
        n = _preflight(cfg, pending or [specs[0]])
        _check_resources(cfg, pending, n, workers, writer.path, writer)
        executor = executors.make_executor(ex_spec, workers=workers, start_method=start_method)
        executor.connect()  # a Dask cluster: reached (or a one-line error) before the file is created
        summary.workers = executor.workers
        writer.session.update(workers=executor.workers, executor=executor.session_info())
        writer.start()
        needs_ref = not isinstance(cfg.reference, NoReference)
        reporter = _Reporter(console, len(pending), f"{cfg.name}: {len(pending)} runs on {executor.describe()}",
                             progress)
        if summary.skipped or summary.deleted_incomplete:
            reporter.log(f"resuming {path}: {summary.skipped} of {len(specs)} runs already stored"
                         + (f", {summary.deleted_incomplete} incomplete or damaged groups discarded"
                            if summary.deleted_incomplete else "")
                         + (f", {len(ref_only)} missing reference(s) to recompute" if ref_only else ""))
        ref_T, ref_h = reference_horizon(cfg), min(cfg.h)
        status, broken = "complete", ""
        on_main = threading.current_thread() is threading.main_thread()
        old_term = signal.signal(signal.SIGTERM, _raise_terminated) if on_main else None

        def take(result: dict) -> None:
            t0 = time.perf_counter()
            if result.get("reference") is not None:
                writer.add_reference(result["ic_key"], *result["reference"])
            failed = 0
            for r in result["runs"]:
                writer.add_run(r["run_id"], r["attrs"], r["arrays"])
                failed += r["attrs"].get("status") != "ok"
            summary.computed += len(result["runs"])
            summary.failed += failed
            writer.maybe_commit()
            reporter.advance(len(result["runs"]), failed, len(writer.complete_runs),
                             f"{result['ic_key']}: {len(result['runs'])} run{'s' * (len(result['runs']) > 1)}")
            summary.write_time += time.perf_counter() - t0

        try:
            # The local pool forks its workers in start(): before the progress thread starts.
            executor.start(cfg, pending, set(writer.references), needs_ref, ref_T, ref_h, reference_ics=ref_only)
            writer.start_background_compaction()  # a forked child: before any thread of ours starts
            reporter.start()
            writer.start_autocommit()  # after the forks: commits while the client waits for results
            for result in executor.results():
                take(result)
        except KeyboardInterrupt as e:
            status = "interrupted"
            summary.interrupted = "SIGTERM" if isinstance(e, _Terminated) else "SIGINT"
        except executors.ExecutorError as e:  # a dead worker, a lost scheduler, a task that kept failing
            status = e.status
            broken = e
        except BaseException:
            status = "failed"  # a bug: recorded in the file's history, then re-raised with its traceback
            raise
        finally:
            with _signals_deferred(on_main):
                summary.executor_stats = executor.stats()
                executor.close()
                writer.session["executor"] = {**executor.session_info(), **summary.executor_stats}
                reporter.stop()
                t0 = time.perf_counter()
                writer.finish(status)  # every finished run is committed, whatever happened
                summary.write_time += time.perf_counter() - t0
            if on_main:
                signal.signal(signal.SIGTERM, old_term)
        if broken:
            saved = f"{len(writer.complete_runs)} of {len(specs)} runs are saved in {path}"
            if isinstance(broken, executors.SchedulerLost):
                raise SweepError(f"lost the Dask scheduler at {ex_spec.address} ({_one_line(broken)}); {saved}; "
                                 "rerun the same command to resume (--scheduler local finishes on this machine)")
            if isinstance(broken, executors.WorkerDied):
                raise SweepError(f"a worker process died unexpectedly ({_one_line(broken)}); {saved}; "
                                 "rerun the same command to resume")
            raise SweepError(f"{_one_line(broken)}; {saved}; rerun the same command to resume")
        summary.status_counts = _status_counts(writer)
        summary.wall_time = time.monotonic() - t_start
        return summary
    finally:
        if executor is not None:
            executor.close()
        writer.close()


@contextlib.contextmanager
def _signals_deferred(on_main: bool):
    """Ignore further SIGINT/SIGTERM while the workers are stopped and the last commit is written:
    the sweep is already stopping, and a second Ctrl-C must not cut the final commit short (the file
    would stay valid, but the finished runs since the previous commit would be lost)."""
    if not on_main:
        yield
        return
    old = {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def _status_counts(writer: storage.ResultsWriter) -> dict:
    counts: dict[str, int] = defaultdict(int)
    for a in writer.complete_runs.values():
        counts[a.get("status", "?")] += 1
    return dict(counts)


def sweep_file(config_path, *, output=None, force: bool = False, workers: int | None = None,
               retry_failed: bool = False, console=None, progress: bool = True,
               argv: list | None = None, scheduler: str | None = None, task_size: int | None = None,
               worker_cache_dir: str | None = None) -> SweepSummary:
    """`vcirun sweep CONFIG`: load and validate the config file, then `run_sweep` it."""
    from .config import config_text, load_config

    cfg = load_config(config_path)
    return run_sweep(cfg, config_text=config_text(config_path), config_path=config_path, output=output,
                     force=force, workers=workers, retry_failed=retry_failed, console=console,
                     progress=progress, argv=argv, scheduler=scheduler, task_size=task_size,
                     worker_cache_dir=worker_cache_dir)
