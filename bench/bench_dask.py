"""Benchmark: the Figure 4 sweep (configs/fig4.yaml, 408 runs) on the local process pool and on a
2-worker Dask LocalCluster, the per-task overhead of Dask, the task size the runner chose, and the
client's serial cost per run; then the projection to N workers that docs/scaling_out.md explains.
Printed and saved to results/bench_dask.json; nothing is asserted.

    python bench/bench_dask.py [--repeats 2] [--config configs/fig4.yaml]

Kernels come from VCIRUN_CACHE_DIR (the client's preflight compiles them once; the cluster's workers
inherit the variable and load them). Every sweep is timed end to end (`SweepSummary.wall_time`:
reading the file state, preflight, connecting, computing, writing), after one untimed warm-up sweep
per executor, and the best of `--repeats` is kept.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def timed_sweep(cfg, out: Path, **kw) -> dict:
    from vcirun.experiments.sweep import run_sweep

    cpu0 = time.process_time()
    s = run_sweep(cfg, output=out, force=True, progress=False, argv=["bench_dask"], **kw)
    cpu = time.process_time() - cpu0
    assert s.ok and s.computed == s.total, s
    return {"runs": s.computed, "wall_s": s.wall_time, "runs_per_s": s.computed / s.wall_time,
            "client_write_s": s.write_time, "client_write_s_per_run": s.write_time / s.computed,
            "client_cpu_s": cpu, "client_cpu_s_per_run": cpu / s.computed, "workers": s.workers,
            "executor": s.executor, "executor_stats": s.executor_stats,
            "status_counts": s.status_counts}


def best(rows: list[dict]) -> dict:
    out = dict(min(rows, key=lambda r: r["wall_s"]))
    out["wall_s_all"] = [r["wall_s"] for r in rows]
    return out


def empty_task_overhead(client, n_seq: int = 50, n_batch: int = 2000) -> dict:
    """Round trip of one empty task (submit -> result, one at a time) and the amortized cost per empty
    task when n_batch are submitted at once (the scheduler's and workers' throughput)."""
    from vcirun.experiments.executors import _noop

    seq = []
    for i in range(n_seq):
        t0 = time.perf_counter()
        client.submit(_noop, i, pure=False).result()
        seq.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    futs = client.map(_noop, range(n_batch), pure=False)
    client.gather(futs)
    batch = time.perf_counter() - t0
    del futs
    return {"round_trip_median_s": statistics.median(seq), "round_trip_min_s": min(seq),
            "batch_tasks": n_batch, "batch_s_per_task": batch / n_batch}


WORKERS = (1, 2, 4, 8, 16, 32, 64, 128, 256, 512)


def projection(c: float, o_rt: float, o_task: float, s_client: float, runs: int, startup: float,
               group: int = 1, workers=WORKERS) -> list[dict]:
    """Time of a `runs`-run sweep on N worker threads (docs/scaling_out.md):
      k    = choose_task_size(c, o_rt, runs, N, group)   the runner's rule (o_rt: empty-task round trip,
                                                         group: runs per initial condition)
      rate = min(N / (c + o_task / k),                   workers: a run, plus its share of a task's overhead
                 k / o_task,                             scheduler: one task per o_task, serially
                 1 / s_client)                           client: receives and writes every run, serially
      time = startup + max(runs / rate, c k + o_rt)      (at least one task's latency)"""
    from vcirun.experiments.executors import choose_task_size

    rows = []
    for n in workers:
        k = choose_task_size(c, o_rt, runs, n, group)
        bounds = {"workers": n / (c + o_task / k), "scheduler": k / o_task, "client": 1.0 / s_client}
        bound = min(bounds, key=bounds.get)
        rate = bounds[bound]
        t = startup + max(runs / rate, c * k + o_rt)
        rows.append({"workers": n, "task_size": k, "runs_per_s": runs / (t - startup), "sweep_s": t,
                     "bound": bound})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(ROOT / "configs" / "fig4.yaml"))
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_dask.json"))
    args = ap.parse_args()

    import distributed

    from vcirun.experiments.config import load_config
    from vcirun.experiments.sweep import default_workers

    cfg = load_config(args.config)
    tmp = Path(tempfile.mkdtemp(prefix="bench_dask_"))
    report: dict = {"config": str(Path(args.config).resolve().relative_to(ROOT)) if str(args.config).startswith(
        str(ROOT)) else args.config, "cores": default_workers(), "python": platform.python_version(),
        "dask": distributed.__version__, "loadavg_start": list(os.getloadavg())}
    try:
        # --- local pool (every core), after one warm-up sweep
        timed_sweep(cfg, tmp / "warm.h5")
        local = best([timed_sweep(cfg, tmp / "local.h5") for _ in range(args.repeats)])
        report["local_pool"] = local
        print(f"local pool, {local['workers']} workers: {local['runs']} runs in {local['wall_s']:.2f} s = "
              f"{local['runs_per_s']:.1f} runs/s (client writes {1e3 * local['client_write_s_per_run']:.2f} ms/run)")

        # --- 2-worker LocalCluster
        t0 = time.perf_counter()
        cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                           dashboard_address=":0", worker_dashboard_address=":0")
        client = distributed.Client(cluster, set_as_default=False)
        report["cluster_start_s"] = time.perf_counter() - t0
        try:
            addr = cluster.scheduler_address
            t0 = time.perf_counter()
            timed_sweep(cfg, tmp / "warm.h5", scheduler=addr)  # workers import vcirun, load kernels
            report["dask_first_sweep_s"] = time.perf_counter() - t0
            dask_rows = [timed_sweep(cfg, tmp / "dask.h5", scheduler=addr) for _ in range(args.repeats)]
            dk = best(dask_rows)
            report["dask_localcluster_2"] = dk
            report["empty_tasks"] = empty_task_overhead(client)
            # fixed cost of a sweep (read file state, preflight, connect, one wave of tasks): all methods
            # at one h from one initial condition
            few = cfg.model_copy(update={"beta": cfg.beta.model_copy(update={"num": 1, "stop": cfg.beta.start}),
                                         "h": cfg.h[:1]})
            report["dask_startup_s"] = min(timed_sweep(few, tmp / "few.h5", scheduler=addr)["wall_s"]
                                           for _ in range(args.repeats))
            fixed = {}
            for k in (1, 8, 32):
                fixed[k] = timed_sweep(cfg, tmp / f"dask_k{k}.h5", scheduler=addr, task_size=k)
            report["dask_fixed_task_size"] = {str(k): {"wall_s": v["wall_s"], "runs_per_s": v["runs_per_s"]}
                                              for k, v in fixed.items()}
        finally:
            client.close()
            cluster.close()
        st = dk["executor_stats"]
        et = report["empty_tasks"]
        print(f"dask LocalCluster, 2 workers x 1 thread: {dk['runs']} runs in {dk['wall_s']:.2f} s = "
              f"{dk['runs_per_s']:.1f} runs/s (cluster start {report['cluster_start_s']:.1f} s; first sweep, "
              f"cold workers, {report['dask_first_sweep_s']:.1f} s)")
        print(f"  task size chosen: {st['task_size_mode']} runs (max {st['task_size_max']}, {st['tasks']} tasks); "
              f"measured per-run cost {1e3 * st['per_run_cost_s']:.2f} ms, per-task overhead "
              f"{1e3 * st['per_task_overhead_s']:.2f} ms (empty-task round trip at connect)")
        print(f"  empty tasks: round trip {1e3 * et['round_trip_median_s']:.2f} ms (median of 50), "
              f"{1e3 * et['batch_s_per_task']:.2f} ms each when {et['batch_tasks']} are submitted at once")
        print("  fixed task sizes: " + ", ".join(f"k={k}: {v['runs_per_s']:.1f} runs/s"
                                                 for k, v in report["dask_fixed_task_size"].items()))
        print(f"  client: writes {1e3 * dk['client_write_s_per_run']:.2f} ms/run, CPU {1e3 * dk['client_cpu_s_per_run']:.2f} "
              f"ms/run (receive + write + preflight)")
        busy = st["worker_compute_s"] / (dk["workers"] * dk["wall_s"])
        report["dask_worker_busy_fraction"] = busy
        print(f"  workers computing {100 * busy:.0f}% of the sweep's wall time (the client and the scheduler share "
              f"the {report['cores']} cores with them here)")

        # --- projection (docs/scaling_out.md)
        c = st["per_run_cost_s"]
        o_rt = et["round_trip_median_s"]
        o_task = et["batch_s_per_task"]  # amortized cost of a task when many are queued
        s_client = dk["client_cpu_s_per_run"]
        startup = report["dask_startup_s"]
        runs = dk["runs"]
        scenarios = {"fig4": (c, runs), "fig4_x100_runs": (c, 100 * runs), "fig4_x100_longer_runs": (100 * c, runs)}
        group = len(cfg.methods) * len(cfg.h)
        proj = {name: projection(cc, o_rt, o_task, s_client, rr, startup, group)
                for name, (cc, rr) in scenarios.items()}
        report["model"] = {"per_run_cost_s": c, "task_round_trip_s": o_rt, "per_task_overhead_s": o_task,
                           "client_s_per_run": s_client, "startup_s": startup, "projection": proj}
        print(f"projection (c = {1e3 * c:.2f} ms/run, round trip {1e3 * o_rt:.2f} ms, o = {1e3 * o_task:.2f} ms/task, "
              f"client {1e3 * s_client:.2f} ms/run, startup {startup:.2f} s); sweep seconds (task size, bound):")
        print(f"  {'N':>4} | {'fig4, 408 runs':>24} | {'100x the runs':>24} | {'runs 100x longer':>24}")
        for i, n in enumerate(WORKERS):
            cells = [f"{p[i]['sweep_s']:9.2f} s ({p[i]['task_size']:3d}, {p[i]['bound'][:6]:>6})" for p in proj.values()]
            print(f"  {n:4d} | " + " | ".join(f"{x:>24}" for x in cells))
        report["loadavg_end"] = list(os.getloadavg())
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=1, default=str))
    print(f"saved {out}")


if __name__ == "__main__":
    sys.exit(main())
