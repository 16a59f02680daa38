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
measures integration, not kernel loading (the worker side lives in `worker`). The parent is the
only writer of the results file
(see `vcirun.io.writer.ResultsWriter`). A run that fails numerically, or raises, is recorded with its status
and message, and the sweep carries on. Ctrl-C and SIGTERM stop the workers, keep every finished
run and report the interruption. Storage (see `vcirun.io`): the client commits finished runs to a
journal beside the results file every `commit_interval` seconds (default 1 s, at a cost independent
of the file's size), folds the journal into the HDF5 file in the background and when the sweep
finishes; pool workers
send finished runs to the client within 0.1 s (worker.STREAM_INTERVAL). A SIGKILL therefore loses at
most the runs that finished in the last commit_interval plus 0.1 s (and one commit's duration) and the
runs being computed.
Before anything is created the sweep checks the memory of its runs in flight and the disk space its
results need.
"""
from __future__ import annotations

import contextlib
import gc
import hashlib
import json
import os
import shutil
import signal
import sys
import threading
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

from ..core.grid import grid_end, grid_note, grid_steps
from ..core.sizes import check_run_memory, format_bytes, stored_bytes
from ..core.tolerances import DEFAULT_TOLERANCES, split_options
from ..io.durable import run_isolated
from ..io.errors import StorageError
from ..io.provenance import environment_attrs
from ..io.writer import ResultsWriter
from .config import InitialCondition, MethodReference, MethodSpec, NoReference, SweepConfig, build_system
from .store_size import estimate_store
from .worker import RunSpec, SweepError, _one_line

__all__ = ["SweepSummary", "expand", "run_sweep", "sweep_file", "default_workers"]


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
    prepare_time: float = 0.0  # seconds of the preflight: loading or (cold cache) compiling the kernels
    compiled: int = 0          # kernel modules the preflight generated and compiled (cold cache)
    interpreted: int = 0       # computed runs that ran on the interpreted tier (untimed: wall_time None)
    summary_error: str = ""    # why the summary group could not be written ("" if it was)
    mixed_builds: dict = field(default_factory=dict)  # method label -> {build: runs} where its runs mix builds

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
    """A run ends at N h with N = floor(T / h) to a relative 1e-9 (vcirun.core.grid), which may exceed T
    by that much; the reference covers every run."""
    return max([cfg.T] + [grid_end(h, cfg.T) for h in cfg.h])


def missing_references(cfg: SweepConfig, writer: ResultsWriter) -> list[InitialCondition]:
    """Initial conditions whose reference the file lacks (e.g. a file that lost its references group)."""
    if isinstance(cfg.reference, NoReference):
        return []
    return [ic for ic in cfg.initial_conditions() if ic.key not in writer.references]


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
        self.stored_before = 0   # runs the file held when this run of the sweep started (a resumed sweep)

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
            # (saved: committed to the file so far; runs finished since are committed by the next batch,
            # the last ones when the sweep finishes)
            pending = self.done - (saved - self.stored_before)   # runs computed here, not yet committed
            self.console.print(f"[{self.done}/{self.total}] {note}; {saved} committed to the file"
                               + ((f", {pending} in the next batch" if self.done < self.total
                                   else f", the last {pending} as the sweep finishes") if pending > 0 else "")
                               + (f"; {self.failed} failed" if self.failed else ""), highlight=False, markup=False)

    def stop(self) -> None:
        if self._progress is not None:
            self._progress.stop()
            self._progress = None


def builds_for_sweep(kc, stored) -> None:
    """One build per method's times (vcirun.codegen.specialize): a sweep resumed over runs of the shared
    build (`stored`: the attributes of the runs in the file) stays on it (`kc.specialize` False until the
    sweep ends); otherwise it takes the specialized modules built so far, and keeps what it starts on."""
    from vcirun.codegen.specialize import take_built

    if "shared" in {a.get("build") for a in stored}:
        kc.specialize = False
    else:
        take_built(kc)


def _preflight(cfg: SweepConfig, pending: list[RunSpec]) -> tuple[int, int, bool, int]:
    """One step of every method in this process: loads the kernels the workers use (on the tier asked
    for, VCIRUN_TIER: compiled ones, cold ones compiled side by side, vcirun.experiments.precompile; in
    the auto tier the interpreted ones while the compiled ones are built in the background), and turns
    bad input the core rejects into an error before any file exists. Returns the numbers of coordinates and of contacts,
    whether the system has friction, and how many kernel sets were compiled in side-by-side processes,
    (n, m, friction, side)."""
    import vcirun

    from .precompile import compile_side_by_side
    from vcirun.codegen.tiers import requested

    system, params, sysm = build_system(cfg)
    tol = cfg.tolerances.model_dump(exclude_none=True)
    first = {}
    for spec in pending:
        if spec.method.display in first:
            continue
        kw = dict(h=spec.h, T=spec.h, **spec.method.simulate_kwargs(), **spec.ic.simulate_kwargs(), **tol)
        if params:
            kw["params"] = params
        first[spec.method.display] = (spec, kw)
    ref_kw = None
    if not isinstance(cfg.reference, NoReference):
        ref_kw = dict(T=min(cfg.h), params=params, **pending[0].ic.simulate_kwargs())
        if isinstance(cfg.reference, MethodReference):
            ref_kw.update(method=cfg.reference.method, h=min(cfg.reference.h, min(cfg.h) / 2))
        else:
            ref_kw.update(rtol=cfg.reference.rtol)
    # the compiled tier asked for: cold kernels of several method families compiled side by side, one
    # process per core; otherwise (auto) the first runs below start on the interpreted tier and each
    # kernel set's compiled tier is built in the background (vcirun.codegen.tiers)
    side = 0
    if requested() == "compiled":
        entries = []
        for s, kw in first.values():
            if s.method.tol is not None:   # a tol= run may use any of its candidates: compile each
                from ..run.choose import DEFAULT_CANDIDATES

                plain = {k: v for k, v in kw.items() if k != "tol"}
                entries += [(n, {}, plain) for n in ([s.method.name] if s.method.name != "auto" else DEFAULT_CANDIDATES)]
            else:
                entries.append((s.method.name, split_options(s.method.simulate_kwargs())[0], kw))
        side = compile_side_by_side(system, sysm, entries, default_workers(),
                                    reference=None if isinstance(cfg.reference, MethodReference) else ref_kw)
    for spec, kw in first.values():
        try:
            vcirun.simulate(system, spec.method.name, **kw)
        except ValueError as e:
            raise SweepError(f"methods[{spec.method_index}] ({spec.label}): {_one_line(e)}") from None
    if ref_kw is not None:
        try:
            vcirun.reference(system, **ref_kw)
        except ValueError as e:
            raise SweepError(f"reference: {_one_line(e)}") from None
        except Exception:  # noqa: BLE001 - numerical trouble is reported per initial condition later
            pass
    return sysm.n, sysm.m, bool(sysm.has_friction), side


def _check_resources(cfg: SweepConfig, pending: list[RunSpec], n: int, m: int, workers: int, path: Path,
                     writer: ResultsWriter, friction: bool = True) -> None:
    """Refuse, before the file is created, a sweep whose runs in flight exceed the memory limit or whose
    results cannot fit on the disk (their journal, then the file's final copy: about twice the data)."""
    if not pending:
        return
    steps = {h: grid_steps(h, cfg.T)[2] for h in {s.h for s in pending}}
    N = max(steps.values())
    stored = stored_bytes(N, n, m, every=cfg.store_every, friction=friction)
    try:  # each worker holds a run's buffers and its result message; the client the message and its record
        check_run_memory(N, n, m=m, copies=min(workers, len(pending)), extra=2 * stored, limit=cfg.max_memory,
                         field="h", hint=", or raise max_memory in the config (e.g. max_memory: 32GB) or "
                                         "the VCIRUN_MAX_MEMORY environment variable")
    except ValueError as e:
        raise SweepError(f"{_one_line(e)} (with {min(workers, len(pending))} worker(s); fewer --workers need less)") \
            from None
    per_h = {h: stored_bytes(N_h, n, m, every=cfg.store_every, friction=friction) for h, N_h in steps.items()}
    need = sum(per_h[s.h] for s in pending)
    size = path.stat().st_size if path.exists() and not writer.force else 0
    total = size + 2 * need
    where = next((d for d in [path.parent, *path.parent.parents] if d.exists()), Path("."))
    try:
        free = shutil.disk_usage(where).free
    except OSError:
        return
    if total > free:
        raise SweepError(f"{path}: the {len(pending)} pending runs need about {format_bytes(total)} on disk "
                         f"(their journal and the final copy of the file), {format_bytes(free)} free in "
                         f"{where}; free space, choose another --output"
                         + (" or set store: {every: k} or store: metrics" if cfg.store_every else ""))


def _final_hooks(writer: ResultsWriter) -> list:
    """The sweep finished (complete or not) and the file is final: callables f(h5py.File) that run
    inside the writer's last rewrite (on the copy that then atomically replaces the file): the summary
    group of every run, from the writer's record of what the file holds. This is the one place where
    'the file is final' happens."""
    from .summary import summary_hook

    return [summary_hook(writer.path, held=lambda: (writer.complete_runs, writer.references))]


def _root_attrs(cfg: SweepConfig, config_text: str, config_path, specs: list[RunSpec]) -> dict:
    tol = {**DEFAULT_TOLERANCES, **cfg.tolerances.model_dump(exclude_none=True)}
    attrs = {
        "name": cfg.name, "description": cfg.description or "", "config_yaml": config_text,
        "config_sha256": hashlib.sha256(config_text.encode()).hexdigest(),
        "config_canonical": cfg.canonical(), "config_path": str(config_path or ""),
        "system": cfg.system_label(), "system_spec": cfg.canonical()["system"], "T": cfg.T,
        "h_values": list(cfg.h), "methods": [{"label": m.display, **m.identity()} for m in cfg.methods],
        "ic_keys": [ic.key for ic in cfg.initial_conditions()], "n_runs_expected": len(specs),
        "reference_kind": cfg.reference.kind, "tolerances": tol, "store_trajectories": cfg.store_every > 0,
        "store_every": cfg.store_every,
        "timing_repeats": cfg.timing_repeats,
        # the unilateral constraints in declaration order (impact_contact indexes them)
        "constraints": [{"name": c.name, "phi": str(c.phi), "restitution": str(c.restitution)}
                        for c in build_system(cfg)[2].constraints],
    }
    attrs.update(environment_attrs())
    return attrs


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
    scheduler) and StorageError (a file that cannot be read or written).
    """
    from . import executors

    t_start = time.monotonic()
    path = Path(output) if output else cfg.output_path()
    workers = int(workers or cfg.workers or default_workers())
    most = max(8, 4 * default_workers())
    if workers > most and scheduler is None and (cfg.executor is None or cfg.executor.kind == "local"):
        raise SweepError(f"workers: {workers} local worker processes on {default_workers()} core(s) is too many "
                         f"(at most {most}); lower --workers, or use a Dask cluster (--scheduler)")
    ex_spec = executors.resolve_spec(cfg.executor, scheduler=scheduler, task_size=task_size,
                                     cache_dir=worker_cache_dir)
    specs = expand(cfg)
    if config_text is None:
        import yaml

        config_text = yaml.safe_dump(cfg.model_dump(mode="json", by_alias=True, exclude_none=True), sort_keys=False)
    summary = SweepSummary(path=path, total=len(specs), workers=workers, executor=ex_spec.kind)
    session = {"argv": list(argv if argv is not None else sys.argv), "workers": workers, "pid": os.getpid()}
    writer = ResultsWriter(path, root_attrs=_root_attrs(cfg, config_text, config_path, specs),
                           config_key=cfg.canonical_sha256(), force=force, session=session,
                           commit_interval=commit_interval)
    writer.final_hooks = _final_hooks(writer)
    writer.acquire()
    executor, frozen, specialize = None, False, None
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
            changed = writer.has_changes()
            if changed:
                writer.finish("complete")
            _finalize(writer, summary, if_missing=True)  # a no-op resume leaves the file untouched
            summary.status_counts = _status_counts(writer)
            summary.mixed_builds = _mixed_builds(writer)
            summary.wall_time = time.monotonic() - t_start
            return summary
        from vcirun.codegen.kernel_cache import default

        kc = default()
        specialize = kc.specialize
        builds_for_sweep(kc, writer.complete_runs.values())
        t_pre = time.monotonic()
        with kc.report() as built:
            n, m, friction, side = _preflight(cfg, pending or [specs[0]])
        summary.prepare_time = time.monotonic() - t_pre  # kernels loaded or compiled: not run time
        # What is loaded now (numba, LLVM, the kernels) stays for the sweep: frozen out of the garbage
        # collector, whose full passes would otherwise walk it in the client and, copy-on-write, copy it
        # into every forked worker and writer (unfrozen when the sweep ends).
        gc.freeze()
        frozen = True
        summary.compiled = side + built.generated
        _check_resources(cfg, pending, n, m, workers, writer.path, writer, friction)
        executor = executors.make_executor(ex_spec, workers=workers, start_method=start_method)
        executor.connect()  # a Dask cluster: reached (or a one-line error) before the file is created
        summary.workers = executor.workers
        writer.session.update(workers=executor.workers, executor=executor.session_info())
        writer.start()
        needs_ref = not isinstance(cfg.reference, NoReference)
        reporter = _Reporter(console, len(pending), f"{cfg.name}: {len(pending)} runs on {executor.describe()}",
                             progress)
        for h in cfg.h:
            if grid_note(h, cfg.T):
                reporter.log(f"note: {grid_note(h, cfg.T)}")
        size = estimate_store(cfg, n, m, pending, friction)
        reporter.log(f"note: the pending runs store {size.line()}"
                     + (f"\nwarning: {size.advice()}" if size.warn else ""))
        if summary.skipped or summary.deleted_incomplete:
            reporter.log(f"resuming {path}: {summary.skipped} of {len(specs)} runs already stored"
                         + (f", {summary.deleted_incomplete} incomplete or damaged groups discarded"
                            if summary.deleted_incomplete else "")
                         + (f", {len(ref_only)} missing reference(s) to recompute" if ref_only else ""))
        reporter.stored_before = len(writer.complete_runs)
        for note in writer.notes:   # damaged journal records skipped: their runs are among the pending
            reporter.log(f"note: {note}")
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
                writer.add_run(r["run_id"], r["attrs"], r["arrays"], r.get("text"))
                failed += r["attrs"].get("status") != "ok"
                if r["attrs"].get("tier") == "interpreted":
                    summary.interpreted += 1
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
                _finalize(writer, summary, if_missing=True)  # the summary group, if the last rewrite left none
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
        summary.mixed_builds = _mixed_builds(writer)
        summary.wall_time = time.monotonic() - t_start
        return summary
    finally:
        if executor is not None:
            executor.close()
        writer.close()
        if frozen:
            gc.unfreeze()
        if specialize is not None:
            kc.specialize = specialize


def _finalize(writer: ResultsWriter, summary: SweepSummary, if_missing: bool = False) -> None:
    """Write the file's summary group (vcirun.experiments.summary; with `if_missing` only where it has
    none); a failure there is reported in the summary, never allowed to cost the runs. Not after a
    failed write (a full disk), at the resolved path (an output that is a symlink stays one), and in a
    forked child like every HDF5 write of the sweep (run_isolated: an HDF5 crash there is an error here)."""
    if writer.failed:
        return
    from .summary import has_summary, write_summary

    if if_missing and has_summary(writer.path):   # (checked here: no forked writer for nothing)
        return
    try:
        run_isolated(lambda: write_summary(writer.path, if_missing=if_missing), writer.path,
                     isolate=writer.isolate)
    except (StorageError, RuntimeError, OSError) as e:
        summary.summary_error = _one_line(e)


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


def _status_counts(writer: ResultsWriter) -> dict:
    """Stored runs by status; a run of tol= that finished but did not reach its tolerance (its choice's
    status not_reached, below_floor, over_budget) is counted as "tol <status>", not as ok."""
    from .tables import run_status

    counts: dict[str, int] = defaultdict(int)
    for a in writer.complete_runs.values():
        counts[run_status(a) or "?"] += 1
    return dict(counts)


def _mixed_builds(writer: ResultsWriter) -> dict:
    """{method label: {build: stored runs}} of the methods whose stored runs ran on both builds
    (vcirun.codegen.specialize): their wall times are not comparable run to run (the sweep keeps one
    build per method; a file resumed across a change of VCIRUN_BUILD can hold both)."""
    per: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    for a in writer.complete_runs.values():
        if a.get("build"):
            per[str(a.get("label"))][a["build"]] += 1
    return {k: dict(v) for k, v in per.items() if len(v) > 1}


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
