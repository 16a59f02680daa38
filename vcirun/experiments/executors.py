"""Where a sweep's runs are computed: the local process pool (default) or a Dask cluster.

`sweep.run_sweep` expands the grid, reads what the results file already holds, compiles the kernels
once (`_preflight`) and is the only writer of the file; an executor only turns the pending runs into
result dicts (`sweep._execute`'s: a reference and the runs of one initial condition) and yields them
as they arrive. Every result is written by the client as it arrives, so the file, resume and
kill-safety do not depend on the executor, and the runs are bit-for-bit the same on either.

Executor protocol (what `run_sweep` calls, in this order)::

    connect()             before the results file exists: reach the cluster, count its workers
    start(cfg, pending, stored_refs, needs_reference, ref_T, ref_h, reference_ics=())
                          (reference_ics: initial conditions that only need their reference)
    results()             iterator of result dicts, in completion order
    close()               always; stops whatever is still running
    describe(), session_info(), stats()   for the progress label and the file's history

`LocalExecutor`: the `ProcessPoolExecutor` of the runner as it was (fork, one task per initial
condition, parent-death signal), or in-process run by run for one worker; `task_size` caps the runs
per task. Pool workers send finished runs to the client through a queue within
`worker.STREAM_INTERVAL` (0.1 s) of their end (a task of many runs is not held back until its last
run: a hard kill of the client loses only uncommitted runs); a
reader thread moves the messages into the client, so the client never blocks on a worker that died
in the middle of a message, and it learns of a dead worker from the pool's futures.

`DaskExecutor` (`--scheduler tcp://HOST:PORT` or `executor: {kind: dask, address: ...}`): a
`distributed.Client`. A task is a list of `sweep.Task`s, whole initial conditions where they fit (so
a worker computes each reference once, next to the runs that use it) and `task_size` runs at most.
What is shipped per task is small and plain: the validated config (a pydantic model of numbers and
strings), the run specs and a few numbers; no sympy object. A worker builds the system and loads (or
compiles, once) the kernels itself, from its own kernel cache or from `cache_dir`, which the task sets
as the worker's VCIRUN_CACHE_DIR. It keeps that state per thread across tasks (`_run_unit`).

Task size (automatic unless given): the client keeps about two tasks per worker thread in flight and
sizes each new task from what it has measured: the per-task overhead o (median round trip of an
empty task, measured at connect) and the per-run cost c (the workers' compute time per run, warm
tasks only; the first tasks are single runs until one is measured). The size is the smallest that
keeps o under 5% of a task (o / (0.05 c)) and holds at least one whole initial condition, capped so
that at least 4 tasks per worker remain (load balance, and a dead worker loses little) and a task
stays under a minute.

Faults: a worker that dies mid-task has its task rerun elsewhere by the scheduler (up to Dask's
`distributed.scheduler.allowed-failures` deaths, then KilledWorker ends the sweep like a dead local
worker); a task that raises is retried (`retries`) before it ends the sweep; a run that fails inside a
task is a result like any other (its status is recorded). Losing the scheduler cancels every future:
the sweep stops with `SchedulerLost`, having written every result it received. The same command
then resumes, on the cluster or locally.
"""
from __future__ import annotations

import concurrent.futures as cf
import contextlib
import hashlib
import logging
import math
import multiprocessing as mp
import os
import socket
import statistics
import threading
import time
import uuid
from collections import OrderedDict, deque
from pathlib import Path

__all__ = ["ExecutorError", "WorkerDied", "SchedulerLost", "TaskFailed", "LocalExecutor", "DaskExecutor",
           "make_executor", "resolve_spec", "choose_task_size", "split_tasks", "source_fingerprint"]

# Automatic task size (see the module docstring).
MAX_OVERHEAD_FRACTION = 0.05
MIN_TASKS_PER_WORKER = 4
MAX_TASK_SECONDS = 60.0
IN_FLIGHT_PER_WORKER = 2


class ExecutorError(RuntimeError):
    """The executor cannot go on; `status` is recorded in the file's history."""
    status = "failed"


class WorkerDied(ExecutorError):
    status = "worker_died"


class SchedulerLost(ExecutorError):
    status = "scheduler_lost"


class TaskFailed(ExecutorError):
    status = "failed"


def _one_line(text, limit: int = 300) -> str:
    s = " ".join(str(text).split())
    return s if len(s) <= limit else s[: limit - 3] + "..."


# --- executor choice ---------------------------------------------------------------------------------
def resolve_spec(cfg_spec=None, *, scheduler: str | None = None, task_size: int | None = None,
                 cache_dir: str | None = None):
    """The ExecutorSpec a sweep uses: the config's `executor` section, overridden by the command line
    (`--scheduler ADDRESS`, or `--scheduler local` for the local pool; `--task-size`; `--worker-cache-dir`)."""
    from .config import ExecutorSpec, check_scheduler_address
    from .worker import SweepError

    spec = cfg_spec or ExecutorSpec()
    upd: dict = {}
    if scheduler is not None:
        if scheduler.strip().lower() == "local":
            upd.update(kind="local", address=None, cache_dir=None)
        else:
            try:
                upd.update(kind="dask", address=check_scheduler_address(scheduler))
            except ValueError as e:
                raise SweepError(f"--scheduler: {e}") from None
    if task_size is not None:
        upd["task_size"] = int(task_size)
    if cache_dir is not None:
        upd["cache_dir"] = str(cache_dir)
    kind = upd.get("kind", spec.kind)
    if kind == "local" and upd.get("cache_dir"):
        raise SweepError("--worker-cache-dir is for Dask workers (give --scheduler tcp://HOST:PORT)")
    data = {**spec.model_dump(), **upd}
    if kind == "local":
        data.update(address=None, cache_dir=None)
    spec = ExecutorSpec(**data)
    if spec.kind == "dask":
        _import_distributed()
        if not spec.address:
            import dask

            addr = dask.config.get("scheduler-address", None)  # e.g. DASK_SCHEDULER_ADDRESS
            if not addr:
                raise SweepError("a Dask executor needs the scheduler's address: --scheduler tcp://HOST:PORT "
                                 "(or executor.address in the config, or DASK_SCHEDULER_ADDRESS)")
            spec = spec.model_copy(update={"address": check_scheduler_address(addr)})
    return spec


def _import_distributed():
    from .worker import SweepError

    try:
        import distributed  # noqa: F401 - optional dependency, imported only for a Dask sweep
    except ImportError as e:
        raise SweepError("--scheduler (a Dask executor) needs Dask, which is not installed "
                         f"({_one_line(e)}): pip install 'vcirun[dask]'") from None
    return distributed


def make_executor(spec, *, workers: int, start_method: str | None = None):
    """LocalExecutor(workers) or DaskExecutor(address) for a resolved ExecutorSpec."""
    if spec.kind == "dask":
        return DaskExecutor(spec.address, task_size=spec.task_size, cache_dir=spec.cache_dir)
    return LocalExecutor(workers, start_method=start_method, task_size=spec.task_size)


def split_tasks(tasks: list, task_size: int) -> list:
    """Split tasks into tasks of at most `task_size` runs (the reference stays with the first part)."""
    from .worker import Task

    out = []
    for t in tasks:
        for j in range(0, len(t.runs), task_size):
            out.append(Task(t.ic, t.runs[j:j + task_size], t.want_reference and j == 0))
    return out


def choose_task_size(run_cost: float, overhead: float, remaining: int, workers: int, group: int = 1) -> int:
    """Runs per task: the fewest that keep the per-task overhead under 5% of the task, and at least one
    initial condition's `group` of runs (its reference is then computed once, by one worker, as in the
    local pool); capped so that at least 4 tasks per worker remain and a task takes at most a minute."""
    run_cost = max(float(run_cost), 1e-7)
    k_amortize = math.ceil(max(float(overhead), 0.0) / (MAX_OVERHEAD_FRACTION * run_cost))
    k_balance = max(1, int(remaining) // (MIN_TASKS_PER_WORKER * max(1, int(workers))))
    k_time = max(1, int(MAX_TASK_SECONDS / run_cost))
    return max(1, min(max(k_amortize, int(group)), k_balance, k_time))


def source_fingerprint(cached: bool = True) -> str:
    """sha256 (16 hex) of the vcirun package's Python sources and version: the client and every Dask
    worker must run the same code for the results to be the same. A worker computes it once (when it
    first imports vcirun: the code it runs); the client reads the files as they are now (the code the
    results file's provenance names)."""
    global _FINGERPRINT
    if _FINGERPRINT is None or not cached:
        import vcirun

        pkg = Path(vcirun.__file__).resolve().parent
        h = hashlib.sha256(str(getattr(vcirun, "__version__", "")).encode())
        for p in sorted(pkg.rglob("*.py")):
            if "__pycache__" in p.parts:
                continue
            h.update(p.relative_to(pkg).as_posix().encode())
            h.update(p.read_bytes())
        fp = h.hexdigest()[:16]
        if not cached:
            return fp
        _FINGERPRINT = fp
    return _FINGERPRINT


_FINGERPRINT: str | None = None


# --- local ---------------------------------------------------------------------------------------------
class LocalExecutor:
    """The local process pool (fork where available), or this process for one worker."""
    kind = "local"

    def __init__(self, workers: int, *, start_method: str | None = None, task_size: int | None = None):
        self.workers = max(1, int(workers))
        self.start_method = start_method
        self.task_size = task_size
        self._pool: cf.ProcessPoolExecutor | None = None
        self._iter = iter(())
        self._n_tasks = 0

    def connect(self) -> None:
        pass

    def describe(self) -> str:
        return f"{self.workers} worker{'s' * (self.workers > 1)}"

    def session_info(self) -> dict:
        return {"kind": "local", "task_size": self.task_size}

    def stats(self) -> dict:
        return {"tasks": self._n_tasks}

    def start(self, cfg, pending, stored_refs, needs_reference, ref_T, ref_h, reference_ics=()) -> None:
        from . import worker as sweep  # (the worker side of a sweep)

        tasks = sweep.make_tasks(pending, self.workers, set(stored_refs), needs_reference, reference_ics)
        if self.task_size:
            tasks = split_tasks(tasks, self.task_size)
        self._n_tasks = len(tasks)
        if self.workers == 1:
            sweep._init_worker(cfg, ref_T, ref_h, in_pool=False)
            self._iter = self._in_process(tasks)
            return
        method = self.start_method or sweep._default_start_method()
        ctx = mp.get_context(method)
        self._outbox = ctx.SimpleQueue()
        _widen_pipe(self._outbox)
        self._pool = cf.ProcessPoolExecutor(
            max_workers=min(self.workers, len(tasks)), mp_context=ctx, initializer=sweep._init_worker,
            initargs=(cfg, ref_T, ref_h, None if method == "forkserver" else os.getpid(), True, self._outbox))
        # With fork, every worker is created by the first submit: before the progress thread starts,
        # and after _preflight compiled the kernels, which the workers inherit.
        futures = [self._pool.submit(sweep._execute_streamed, t) for t in tasks]
        self._iter = self._pooled(futures)

    @staticmethod
    def _in_process(tasks):
        from vcirun.codegen.kernel_cache import default

        from . import worker as sweep  # (the worker side of a sweep)

        kc = default()
        switch, kc.switch_builds = kc.switch_builds, False   # (as a pool worker: one build per module)
        try:
            yield from LocalExecutor._in_process_runs(tasks, sweep)
        finally:
            kc.switch_builds = switch

    @staticmethod
    def _in_process_runs(tasks, sweep):
        for task in tasks:
            # run by run, so an interruption loses at most one run (the reference is cached)
            for j, spec in enumerate(task.runs):
                yield sweep._execute(sweep.Task(task.ic, [spec], task.want_reference and j == 0))
            if not task.runs:  # only the reference
                yield sweep._execute(task)

    def _pooled(self, futures):
        import queue

        inbox: queue.Queue = queue.Queue()
        stop = threading.Event()
        outbox = self._outbox

        def pump():  # blocking reads live here, never in the client's loop
            conn = outbox._reader
            while not stop.is_set():
                try:
                    if conn.poll(0.1):
                        inbox.put(outbox.get())
                except (EOFError, OSError):
                    return
                except Exception as e:  # noqa: BLE001 - a message that does not unpickle
                    inbox.put(e)
                    return

        reader = threading.Thread(target=pump, name="vcirun-results", daemon=True)
        reader.start()
        pending, expected, received = set(futures), 0, 0
        try:
            while pending or received < expected:
                try:
                    msg = inbox.get(timeout=0.01)  # (then the futures: the last ones end just after their last run)
                except queue.Empty:
                    msg = None
                if isinstance(msg, Exception):
                    raise WorkerDied(f"a result message could not be read ({_one_line(msg)})")
                if msg is not None:
                    received += 1
                    yield msg
                for fut in [f for f in pending if f.done()]:
                    pending.discard(fut)
                    expected += int(fut.result()["streamed"])  # raises the task's error, or a broken pool
        except cf.process.BrokenProcessPool as e:
            raise WorkerDied(_one_line(e)) from None
        finally:
            stop.set()
        self._pool.shutdown(wait=True)
        self._pool = None

    def results(self):
        return self._iter

    def close(self) -> None:
        if self._pool is not None:
            from . import worker as sweep  # (the worker side of a sweep)

            sweep._terminate_pool(self._pool)
            self._pool = None


def _widen_pipe(q, size: int = 1 << 20) -> None:
    """Give the result queue's pipe a buffer of `size` bytes where the OS allows (Linux: F_SETPIPE_SZ,
    up to /proc/sys/fs/pipe-max-size, 1 MiB by default): a message of a few runs' trajectories (a few
    hundred kB) is then written at once instead of in 64 kB turns with the client's reader (the fig4
    sweep's workers spent 9 % of their time sending with the default buffer, 6 % with this one)."""
    try:
        import fcntl

        fcntl.fcntl(q._writer.fileno(), getattr(fcntl, "F_SETPIPE_SZ", 1031), size)
    except (ImportError, AttributeError, OSError, ValueError):
        pass   # the default buffer: only slower


# --- Dask: worker side ------------------------------------------------------------------------------------
_LOCAL = threading.local()  # per worker thread: (state key, sweep._WorkerState)


def _worker_hello(cache_dir: str | None = None) -> dict:
    """Run once on every worker at connect: import vcirun (warms the worker) and report who it is."""
    if cache_dir:
        os.environ["VCIRUN_CACHE_DIR"] = cache_dir
    import vcirun  # noqa: F401

    return {"pid": os.getpid(), "host": socket.gethostname(), "fingerprint": source_fingerprint()}


def _run_unit(payload: dict, tasks: list) -> dict:
    """Dask task: every sweep.Task of `tasks` on this worker; returns their result dicts and timings."""
    t0 = time.perf_counter()
    cache_dir = payload.get("cache_dir")
    if cache_dir and os.environ.get("VCIRUN_CACHE_DIR") != cache_dir:
        os.environ["VCIRUN_CACHE_DIR"] = cache_dir  # read by vcirun.codegen.build.cache_dir() at each load
    from . import worker as sweep

    key, st = getattr(_LOCAL, "state", (None, None))
    cold = key != payload["key"]
    if cold:
        mine = source_fingerprint()
        if mine != payload["fingerprint"]:
            raise RuntimeError(f"this worker ({socket.gethostname()}) runs a different vcirun than the client "
                               f"(source fingerprint {mine} != {payload['fingerprint']}); install the same "
                               "version on the workers and restart them")
        st = sweep._WorkerState(payload["cfg"], payload["ref_T"], payload["ref_h"])
        _LOCAL.state = (payload["key"], st)
    t1 = time.perf_counter()
    n_warm = len(st.warm)
    out = [sweep._execute(task, st) for task in tasks]
    t2 = time.perf_counter()
    return {"results": out, "n_runs": sum(len(t.runs) for t in tasks), "init_s": t1 - t0, "compute_s": t2 - t1,
            "cold": cold or len(st.warm) != n_warm, "pid": os.getpid(), "host": socket.gethostname()}


def _noop(x=None):
    return x


def task_payload(cfg, ref_T: float, ref_h: float, *, cache_dir: str | None = None, fingerprint: str = "") -> dict:
    """What every Dask task carries besides its runs: plain data, a few kB pickled (no sympy object;
    the worker builds the system and loads the kernels itself)."""
    from .config import FileSystem

    ship = cfg
    if isinstance(cfg.system, FileSystem):  # workers resolve the file from their own working directory
        ship = cfg.model_copy(update={"system": FileSystem(file=str(Path(cfg.system.file).resolve()),
                                                           params=cfg.system.params)})
    key = hashlib.sha256(f"{ship.canonical_sha256()}|{ref_T!r}|{ref_h!r}|{ship.system!r}".encode()).hexdigest()
    return {"cfg": ship, "ref_T": ref_T, "ref_h": ref_h, "cache_dir": cache_dir, "key": key,
            "fingerprint": fingerprint}


# --- Dask: client side -----------------------------------------------------------------------------------
class _QuietDistributed(logging.Filter):
    """Drop distributed's and tornado's log records while a sweep's client runs: the sweep reports what
    matters in one line (a lost scheduler otherwise prints reconnection tracebacks)."""

    def filter(self, record):
        return not record.name.startswith(("distributed", "tornado"))


@contextlib.contextmanager
def _quiet_logs():
    f = _QuietDistributed()
    names = [n for n in list(logging.root.manager.loggerDict) if n.startswith(("distributed", "tornado"))]
    loggers = [logging.getLogger(n) for n in names] + [logging.getLogger()]
    handlers = {h for lg in loggers for h in getattr(lg, "handlers", ())}
    for h in handlers:
        h.addFilter(f)
    try:
        yield
    finally:
        for h in handlers:
            h.removeFilter(f)


class DaskExecutor:
    """Runs the sweep's tasks on a Dask cluster through `distributed.Client(address)`."""
    kind = "dask"

    def __init__(self, address: str, *, task_size: int | None = None, cache_dir: str | None = None,
                 retries: int = 2, connect_timeout: float | None = None, workers_timeout: float = 120.0,
                 overhead_probes: int = 7):
        self.address = address
        self.task_size = task_size
        self.cache_dir = str(Path(cache_dir).expanduser()) if cache_dir else None
        self.retries = int(retries)
        self.connect_timeout = connect_timeout  # None: Dask's distributed.comm.timeouts.connect (30 s)
        self.workers_timeout = workers_timeout
        self.overhead_probes = overhead_probes
        self.client = None
        self.workers = 0
        self.overhead = float("nan")       # s, median round trip of an empty task
        self._quiet = None
        self._closing = False
        self._queue: deque = deque()       # [ic_key, [RunSpec, ...]] groups still to submit
        self._ref_only: list = []          # initial conditions that only need their reference
        self._refs_to_store: set = set()
        self._inflight: dict = {}          # future -> number of runs
        self._seen: set = set()
        self._ac = None
        self._warm_runs = 0
        self._warm_seconds = 0.0
        self._cold_costs: list = []
        self._sizes: list = []
        self._hosts: set = set()
        self._pids: set = set()
        self._n_done = 0
        self._payload = None
        self._no_workers_since = None
        self._compute_total = 0.0          # s, summed over the workers' tasks
        self._fingerprint = ""
        self._token = uuid.uuid4().hex[:8]  # task keys are global on a cluster: unique per sweep session

    # -- connect
    def connect(self) -> None:
        from .worker import SweepError

        distributed = _import_distributed()
        self._quiet = _quiet_logs()
        self._quiet.__enter__()
        try:
            kw = {} if self.connect_timeout is None else {"timeout": self.connect_timeout}
            self.client = distributed.Client(self.address, set_as_default=False, **kw)
        except (OSError, TimeoutError) as e:
            self.close()
            raise SweepError(f"cannot connect to the Dask scheduler at {self.address} ({_one_line(e)}); start "
                             f"one with `dask scheduler` and workers with `dask worker {self.address}`") from None
        try:
            self.client.wait_for_workers(1, timeout=self.workers_timeout)
        except (OSError, TimeoutError):
            self.close()
            raise SweepError(f"the Dask scheduler at {self.address} has no workers after "
                             f"{self.workers_timeout:g} s; start some with `dask worker {self.address}`") from None
        try:
            self._set_up()
        except SweepError:
            raise
        except Exception as e:  # noqa: BLE001 - a worker without vcirun, a scheduler gone meanwhile, ...
            self.close()
            raise SweepError(f"setting up the Dask workers at {self.address} failed ({type(e).__name__}: "
                             f"{_one_line(e)}); the workers need the same vcirun as this client") from None

    def _set_up(self) -> None:
        from .worker import SweepError

        hello = self.client.run(_worker_hello, self.cache_dir)
        mine = self._fingerprint = source_fingerprint(cached=False)
        for addr, h in hello.items():
            if h["fingerprint"] != mine:
                self.close()
                raise SweepError(f"Dask worker {addr} ({h['host']}) runs a different vcirun than this client "
                                 f"(source fingerprint {h['fingerprint']} != {mine}); install the same version "
                                 "on the workers and restart them")
            self._hosts.add(h["host"])
        self.workers = self._count_threads()
        self.overhead = self.measure_overhead(self.overhead_probes)

    def _count_threads(self) -> int:
        try:
            return max(1, sum(self.client.nthreads().values()))
        except Exception:  # noqa: BLE001 - keep the last count; a lost scheduler is noticed elsewhere
            return max(1, self.workers)

    def _cached_threads(self) -> int | None:
        """Worker threads from the client's periodic scheduler-info update (no call to the scheduler,
        so a lost scheduler cannot block here)."""
        info = getattr(self.client, "_scheduler_identity", None) or {}
        n = info.get("total_threads") if hasattr(info, "get") else None
        return n if isinstance(n, int) else None

    def measure_overhead(self, n: int = 7) -> float:
        """Median round trip of an empty task (submit -> result in this process), seconds."""
        times = []
        for i in range(max(1, n)):
            t0 = time.perf_counter()
            self.client.submit(_noop, i, pure=False).result()
            times.append(time.perf_counter() - t0)
        return float(statistics.median(times))

    def describe(self) -> str:
        return f"{self.workers} Dask worker thread{'s' * (self.workers > 1)} at {self.address}"

    def session_info(self) -> dict:
        return {"kind": "dask", "address": self.address, "worker_threads": self.workers,
                "task_size": self.task_size, "cache_dir": self.cache_dir}

    def run_cost(self) -> float | None:
        """Measured compute seconds per run (warm tasks; cold ones until a warm one arrived)."""
        if self._warm_runs:
            return self._warm_seconds / self._warm_runs
        return max(self._cold_costs) if self._cold_costs else None

    def stats(self) -> dict:
        sizes = self._sizes
        mode = max(set(sizes), key=sizes.count) if sizes else None
        return {"tasks": len(sizes), "task_size_mode": mode, "task_size_max": max(sizes) if sizes else None,
                "task_size_fixed": self.task_size, "per_task_overhead_s": self.overhead,
                "per_run_cost_s": self.run_cost(), "worker_compute_s": self._compute_total,
                "worker_threads": self.workers,
                "worker_hosts": len(self._hosts), "worker_processes_used": len(self._pids)}

    # -- run
    def start(self, cfg, pending, stored_refs, needs_reference, ref_T, ref_h, reference_ics=()) -> None:
        from distributed import as_completed

        self._payload = task_payload(cfg, ref_T, ref_h, cache_dir=self.cache_dir, fingerprint=self._fingerprint)
        groups: OrderedDict[str, list] = OrderedDict()
        for s in pending:
            groups.setdefault(s.ic.key, []).append(s)
        self._ref_only = [ic for ic in reference_ics if ic.key not in groups] if needs_reference else []
        self._queue = deque([k, runs] for k, runs in groups.items())
        self._refs_to_store = set(groups) - set(stored_refs) if needs_reference else set()
        self._ac = as_completed(loop=self.client.loop, with_results=True, raise_errors=False)
        self._fill()

    def _remaining(self) -> int:
        return sum(len(g[1]) for g in self._queue)

    def _next_size(self) -> int:
        if self.task_size:
            return self.task_size
        c = self.run_cost()
        if c is None or not self._warm_runs:
            return 1  # measure first
        return choose_task_size(c, self.overhead, self._remaining() + sum(self._inflight.values()), self.workers,
                                group=len(self._queue[0][1]) if self._queue else 1)

    def _next_unit(self, k: int) -> list:
        """Up to k runs from the queue: whole initial conditions while they fit, else part of one."""
        from .worker import Task

        tasks, n = [], 0
        if self._ref_only:  # initial conditions whose runs are stored but whose reference is missing
            batch, self._ref_only = self._ref_only[:k], self._ref_only[k:]
            return [Task(ic, [], True) for ic in batch]
        while self._queue and n < k:
            key, runs = self._queue[0]
            if n and len(runs) > k - n:
                break  # keep an initial condition's runs together when it fits in the next task
            take = runs[: k - n]
            want = key in self._refs_to_store
            self._refs_to_store.discard(key)
            tasks.append(Task(take[0].ic, take, want))
            n += len(take)
            if len(take) == len(runs):
                self._queue.popleft()
            else:
                self._queue[0][1] = runs[len(take):]
        return tasks

    def _fill(self) -> None:
        n = self._cached_threads()  # workers may join or leave (adaptive clusters, batch jobs)
        if n:
            self.workers = n
        window = max(2, IN_FLIGHT_PER_WORKER * self.workers)
        while (self._queue or self._ref_only) and len(self._inflight) < window:
            k = self._next_size()
            unit = self._next_unit(k)
            n = sum(len(t.runs) for t in unit)
            first = unit[0].runs[0].run_id if unit[0].runs else "ref-" + hashlib.sha256(
                unit[0].ic.key.encode()).hexdigest()[:12]
            fut = self.client.submit(_run_unit, self._payload, unit, pure=False, retries=self.retries,
                                     key=f"vcirun-{first}-{self._token}-{len(self._sizes)}")
            self._inflight[fut] = n
            self._sizes.append(n)
            self._ac.add(fut)

    def _lost(self) -> bool:
        return self._closing or self.client is None or self.client.status in ("connecting", "closing", "closed")

    def _next_completed(self):
        """(future, result) of the next finished task; SchedulerLost if the client lost its scheduler."""
        ac = self._ac
        lost_since = None
        while not ac.has_ready():
            now = time.monotonic()
            if self._lost():
                lost_since = lost_since or now
                if now - lost_since > 2.0:  # cancelled futures arrive at once; don't hang
                    raise SchedulerLost(f"the client lost its connection (status {self.client.status})")
            if self._cached_threads() == 0:  # every worker gone: the tasks would wait forever
                self._no_workers_since = self._no_workers_since or now
                if now - self._no_workers_since > self.workers_timeout:
                    raise WorkerDied(f"the cluster has had no workers for {self.workers_timeout:g} s")
            else:
                self._no_workers_since = None
            with ac.thread_condition:
                ac.thread_condition.wait(timeout=0.1)
        return next(ac)

    def results(self):
        from distributed.client import FutureCancelledError

        while self._inflight or self._queue or self._ref_only:
            fut, res = self._next_completed()
            n = self._inflight.pop(fut, 0)
            # Classify by what as_completed gathered: the future's status may have changed since (a lost
            # scheduler marks every future of the client, finished ones included).
            status = fut.status
            if isinstance(res, dict) and "results" in res:
                self._record(res)
                self._fill()
                for r in res["results"]:
                    ids = [x["run_id"] for x in r["runs"]]
                    if any(i in self._seen for i in ids):  # never twice in the file (defensive)
                        r = {**r, "runs": [x for x in r["runs"] if x["run_id"] not in self._seen]}
                    self._seen.update(ids)
                    yield r
            elif isinstance(res, (FutureCancelledError, cf.CancelledError)) or (
                    status == "cancelled" and not isinstance(res, tuple)):
                # Only the client's reconnection cancels our futures (close() ends the iteration first).
                text = str(res) if isinstance(res, BaseException) else ""
                raise SchedulerLost("the client lost its connection" if "connection-lost" in text
                                    else f"task cancelled: {_one_line(text) or 'no reason given'}")
            else:
                exc = res[1] if isinstance(res, tuple) and len(res) >= 2 else res
                name = type(exc).__name__
                msg = f"{name}: {_one_line(exc)}"
                if self._lost():  # the task erred because the cluster went away
                    raise SchedulerLost(f"the client lost its connection; {msg}")
                if name == "KilledWorker":
                    raise WorkerDied(msg)
                raise TaskFailed(f"a task of {n} run{'s' * (n != 1)} failed after {self.retries} "
                                 f"retr{'ies' if self.retries != 1 else 'y'}: {msg}")
            del fut, res

    def _record(self, res: dict) -> None:
        n = max(1, int(res.get("n_runs") or 0))
        self._n_done += n
        self._pids.add((res.get("host"), res.get("pid")))
        self._hosts.add(res.get("host"))
        self._compute_total += float(res.get("init_s", 0.0)) + float(res["compute_s"])
        if res.get("cold"):
            self._cold_costs.append(res["compute_s"] / n)
        else:
            self._warm_runs += n
            self._warm_seconds += res["compute_s"]

    def close(self) -> None:
        self._closing = True
        self._inflight.clear()
        if self.client is not None:
            client, self.client = self.client, None
            with contextlib.suppress(Exception):
                client.close(timeout=5)
        if self._quiet is not None:
            q, self._quiet = self._quiet, None
            q.__exit__(None, None, None)
