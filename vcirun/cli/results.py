"""The commands of sweeps and their results: `vcirun sweep`, `plot`, `validate`, `study`, `info`."""
from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from .app import _announce_compiles, _console, _expected_errors, _fail, _reads_results, app


@app.command(epilog="Examples:\n\n"
             "  vcirun sweep configs/quick.yaml\n\n"
             "  vcirun sweep configs/fig4.yaml --output results/fig4-rerun.h5 --workers 2\n\n"
             "  vcirun sweep configs/fig4.yaml --scheduler tcp://10.0.0.5:8786\n\n"
             "Interrupted? Run the same command again: only missing runs are computed "
             "(on any executor).")
def sweep(
    config: Path = typer.Argument(..., help="YAML sweep config.", show_default=False),
    output: Optional[Path] = typer.Option(None, "--output", "-o", help="Results file (overrides the config)."),
    force: bool = typer.Option(False, "--force", help="Recompute everything (replaces the results file)."),
    workers: Optional[int] = typer.Option(None, "--workers", "-j", min=1,
                                          help="Worker processes (default: the config's, else every core)."),
    retry_failed: bool = typer.Option(False, "--retry-failed", help="Also recompute stored runs that failed."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress output."),
    scheduler: Optional[str] = typer.Option(
        None, "--scheduler", metavar="tcp://HOST:PORT",
        help="Run on the Dask cluster of this scheduler (needs the optional dask extra; wins over the "
             "config's executor). "
             "'local' forces the local process pool."),
    task_size: Optional[int] = typer.Option(None, "--task-size", min=1,
                                            help="Runs per task (default: automatic on Dask, one initial "
                                                 "condition locally)."),
    worker_cache_dir: Optional[str] = typer.Option(
        None, "--worker-cache-dir", metavar="DIR",
        help="Kernel cache of the Dask workers (their VCIRUN_CACHE_DIR), e.g. one on a shared filesystem."),
    strict: bool = typer.Option(False, "--strict",
                                help="Exit with status 1 when any run in the file did not finish with status ok, or "
                                     "a run of tol: did not reach it (for scripts and CI; the runs are stored "
                                     "either way)."),
):
    """Run every method x h x initial condition of CONFIG in parallel into one HDF5 file; resumable.
    Locally by default; on a Dask cluster with --scheduler."""
    from vcirun.experiments.sweep import sweep_file

    _announce_compiles()

    try:
        summary = sweep_file(config, output=output, force=force, workers=workers, retry_failed=retry_failed,
                             console=_console(stderr=True), progress=not quiet, scheduler=scheduler,
                             task_size=task_size, worker_cache_dir=worker_cache_dir)
    except _expected_errors() as e:
        _fail(str(e))
    except OSError as e:  # e.g. the config or output vanished or became unreadable mid-way
        _fail(f"{e.filename or output or config}: {e.strerror or e}")
    except KeyboardInterrupt:  # before the first run started (e.g. while compiling kernels)
        _fail("interrupted before any run was computed", 130)
    done = summary.skipped + summary.computed
    if summary.interrupted:
        code = 130 if summary.interrupted == "SIGINT" else 143
        _fail(f"interrupted by {summary.interrupted}: {done} of {summary.total} runs are saved in "
              f"{summary.path}; run the same command again to resume", code)
    counts = ", ".join(f"{n} {s}" for s, n in sorted(summary.status_counts.items()))
    what = (f"compiling kernels for {summary.compiled} method famil{'ies' if summary.compiled > 1 else 'y'} (first "
            "time; cached now)" if summary.compiled and not summary.interpreted else
            "deriving kernels" if summary.interpreted else "loading kernels")
    prep = (f", of which {summary.prepare_time:.1f} s {what} before the first run"
            if summary.prepare_time >= 0.05 * max(summary.wall_time, 1e-9) and summary.prepare_time >= 1.0 else "")
    typer.echo(f"{summary.path}: {summary.total} runs ({summary.computed} computed, {summary.skipped} already "
               f"stored; {counts or 'none'}) in {summary.wall_time:.1f} s{prep}")
    st = summary.executor_stats
    if summary.executor == "dask" and summary.computed and st.get("tasks"):
        cost = st.get("per_run_cost_s")
        typer.echo(f"dask: {st['tasks']} tasks of up to {st.get('task_size_max')} runs on {summary.workers} worker "
                   f"threads" + (f"; measured {1e3 * cost:.3g} ms per run" if cost else "")
                   + f", {1e3 * st.get('per_task_overhead_s', float('nan')):.3g} ms per empty task")
    if summary.interpreted:
        typer.echo(f"note: {summary.interpreted} of the {summary.computed} runs ran on the interpreted tier while "
                   "the compiled one was built in the background: same numbers, no wall_time (kept apart as "
                   "wall_time_interpreted); `vcirun sweep --force` times them once `vcirun cache info` shows "
                   "the compiled tier ready")
    for label, builds in summary.mixed_builds.items():
        typer.echo(f"note: {label}'s runs ran on both builds ("
                   + ", ".join(f"{n} {b}" for b, n in sorted(builds.items()))
                   + "): their wall times differ by the build, not only by the run; `open_results(...)['build']` "
                   "says which (`vcirun sweep --force` with one VCIRUN_BUILD times them all on one)")
    if summary.computed and summary.failed:
        typer.echo(f"note: {summary.failed} run(s) did not finish with status ok; `vcirun info {summary.path}` "
                   "lists their messages")
    if summary.summary_error:
        typer.echo(f"note: {summary.summary_error}", err=True)
    not_ok = sum(n for st, n in summary.status_counts.items() if st != "ok")
    if strict and not_ok:
        _fail(f"--strict: {not_ok} of {sum(summary.status_counts.values())} stored runs did not finish with status "
              f"ok or did not reach their tol; `vcirun info {summary.path} --failed` lists them")
    typer.echo(f"next: vcirun plot {summary.path}")


# --- plot -------------------------------------------------------------------------------------------
@app.command(epilog="Examples:\n\n"
             "  vcirun plot                      (every results file under results/)\n\n"
             "  vcirun plot results/fig4.h5\n\n"
             "  vcirun plot results/fig4.h5 --out paper-figures/")
@_reads_results
def plot(
    results: Optional[Path] = typer.Argument(None, help="Results file, a file of one run (vcirun simulate --output), or "
                                                        "a work-precision study JSON (default: every *.h5 under "
                                                        "results/, each into results/figures/<name>/).",
                                             show_default=False),
    out: Optional[Path] = typer.Option(None, "--out", help="Output folder (default: <results dir>/figures/<name>)."),
):
    """Write the figures (PNG and PDF) and tables (CSV and Markdown) a results file supports."""
    from vcirun.experiments.figures import plot_results
    from vcirun.io.errors import StorageError
    from vcirun.experiments.tables import print_table
    from vcirun.experiments.wp_figures import is_study_file, plot_study, print_study_tables

    from vcirun.io.single import is_trajectory_file

    if results is not None and is_trajectory_file(results):
        from vcirun.experiments.figures import plot_single

        try:
            paths = plot_single(results, out)
        except _expected_errors() as e:
            _fail(str(e))
        typer.echo(f"figures for {results}:")
        for p in paths:
            typer.echo(f"  {p}")
        return
    if results is not None and is_study_file(results):
        # a work-precision or long-horizon study (results/work_precision*.json, long_horizon.json)
        print_study_tables(results)
        typer.echo(f"figures for {results}:")
        for p in plot_study(results, out):
            typer.echo(f"  {p}")
        return
    if results is None:
        d = Path("results")
        files = sorted(p for p in d.rglob("*.h5") if not p.name.startswith(".")) if d.is_dir() else []
        if not files:
            _fail(f"no results (*.h5) under {d}/; run `vcirun sweep CONFIG` first or name a file")
        if out is not None and len(files) > 1:
            _fail(f"--out: {len(files)} results files under {d}/ would overwrite each other; name one file")
    else:
        files = [results]
    created = _make_out_folder(out) if out is not None else None
    console = _console()
    for path in files:
        try:
            report = plot_results(path, outdir=out)
        except StorageError as e:
            if results is None and "no complete runs" in str(e):
                typer.echo(f"(skipped {path}: {e})")
                continue
            _remove_empty_folders(out, created)
            _fail(str(e))
        except _expected_errors() as e:
            _remove_empty_folders(out, created)
            _fail(str(e))
        for table in report.tables:
            print_table(table, console)
        typer.echo(f"figures and tables for {report.results_path}:")
        for p in report.paths:
            typer.echo(f"  {p}")
        for name, why in report.skipped.items():
            typer.echo(f"  (skipped {name}: {why})")


def _make_out_folder(out: Path) -> Path | None:
    """Create the --out folder before plotting, or fail in one line naming it: a parent that is a file
    (or a place where no folder can be made) was reported as a damaged results file. Returns the
    outermost folder created (None if it existed), for _remove_empty_folders after a failed plot."""
    import os

    if out.exists() and not out.is_dir():
        _fail(f"--out {out}: is a file, not a folder; choose another --out")
    first = None
    p = out
    while not p.exists() and not p.is_symlink() and p != p.parent:
        first, p = p, p.parent
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        where = e.filename or out
        _fail(f"--out {out}: cannot create the folder {where} ({e.strerror or type(e).__name__}); "
              "choose another --out")
    if not os.access(out, os.W_OK | os.X_OK):
        _remove_empty_folders(out, first)
        _fail(f"--out {out}: cannot write in it; choose a writable --out")
    return first


def _remove_empty_folders(out: Path, first: Path | None) -> None:
    """Remove the empty folders _make_out_folder created (out up to `first`), leaving nothing behind."""
    import os

    if first is None:
        return
    p = out
    while True:
        try:
            os.rmdir(p)
        except OSError:
            return
        if p == first:
            return
        p = p.parent


# --- validate -----------------------------------------------------------------------------------------
@app.command(epilog="Examples:\n\n  vcirun validate configs/fig4.yaml\n\n  vcirun validate configs/extremes.yaml")
def validate(config: Path = typer.Argument(..., help="YAML sweep or study config.", show_default=False)):
    """Check a sweep config (schema, system, methods, initial conditions) or a study config (top-level
    `study:`) without running it."""
    from vcirun.experiments.config import SweepConfig
    from vcirun.experiments.studies.schema import load_any
    from vcirun.experiments.sweep import expand

    try:
        cfg = load_any(config)
    except _expected_errors() as e:
        _fail(str(e))
    typer.echo(f"{config}: ok")
    if not isinstance(cfg, SweepConfig):
        typer.echo(f"  study     {cfg.study}")
        typer.echo(f"  name      {cfg.name}")
        for key, value in cfg.describe():
            typer.echo(f"  {key:<9s} {value}")
        typer.echo(f"run it with: vcirun study {config}")
        return
    ics = cfg.initial_conditions()
    typer.echo(f"  name      {cfg.name}")
    typer.echo(f"  system    {cfg.system_label()}")
    typer.echo(f"  methods   {', '.join(m.display for m in cfg.methods)}")
    typer.echo(f"  h         {', '.join(f'{h:g}' for h in cfg.h)}")
    if cfg.beta is not None:
        b = cfg.beta.values()
        typer.echo(f"  beta      {len(b)} value(s) in [{min(b):g}, {max(b):g}]")
    else:
        typer.echo(f"  initial   {len(ics)} state(s)")
    typer.echo(f"  T         {cfg.T:g}")
    from vcirun.core.grid import grid_note

    for h in cfg.h:
        if grid_note(h, cfg.T):
            typer.echo(f"  note      {grid_note(h, cfg.T)}")
    ref = cfg.reference
    typer.echo(f"  reference {ref.kind}" + (f" (rtol {ref.rtol:g})" if ref.kind == "exact" else
                                            f" ({ref.method} at h = {ref.h:g})" if ref.kind == "method" else ""))
    typer.echo(f"  runs      {len(expand(cfg))}")
    from vcirun.experiments.store_size import store_estimate_of

    try:
        size = store_estimate_of(cfg)
    except (ValueError, OSError) as e:   # (the semantic checks of load_any built this system already)
        _fail(str(e))
    typer.echo(f"  size      {size.line()}")
    typer.echo(f"  output    {cfg.output_path()}")
    if size.warn:
        typer.echo(f"warning: {cfg.output_path()} would hold {size.advice()}", err=True)


# --- study ----------------------------------------------------------------------------------------------
@app.command(epilog="Examples:\n\n"
             "  vcirun study configs/work_precision.yaml --quick\n\n"
             "  vcirun study configs/work_precision.yaml --plot\n\n"
             "  vcirun study configs/extremes.yaml\n\n"
             "  vcirun study configs/extremes.yaml --only step_limit,long_horizon")
def study(
    config: Path = typer.Argument(..., help="YAML study config (top-level key study: work_precision, "
                                            "long_horizon or extremes).", show_default=False),
    output: Optional[Path] = typer.Option(None, "--output", "-o", help="Results JSON (overrides the config's output)."),
    quick: bool = typer.Option(False, "--quick", help="Work precision: one initial condition, fewer repeats and "
                                                      "tolerances (a smoke run, written beside the config's output "
                                                      "as <output>_quick.json unless --output is given)."),
    plot: bool = typer.Option(False, "--plot", help="Work precision: also draw the figures."),
    only: List[str] = typer.Option([], "--only", help="Extremes: run only these sections (comma-separated or "
                                                      "repeated); the others are kept from the existing results."),
):
    """Run a study: work precision against solve_ivp, long horizons, or the extremes (hard cases). Writes the
    results JSON (and, for extremes, the Markdown report); prints the tables of a work-precision study."""
    from vcirun.experiments.studies.runner import run_file

    sections = [s.strip() for item in only for s in item.split(",") if s.strip()]
    try:
        out = run_file(config, output=output, quick=quick, plot=plot, only=sections or None,
                       log=lambda m: typer.echo(m, err=True))
    except _expected_errors() as e:
        _fail(str(e))
    typer.echo(f"{out.study} study {out.name}: results in {out.results}" + (f", report {out.report}" if out.report else "")
               + f" ({out.seconds:.0f} s)")
    for p in out.figures:
        typer.echo(f"  {p}")


# --- info ---------------------------------------------------------------------------------------------
@app.command(epilog="Examples:\n\n  vcirun info results/quick.h5\n\n  vcirun info results/fig4.h5 --runs\n\n"
             "  vcirun info results/fig4.h5 --failed\n\n  vcirun info run.h5          (a file of vcirun simulate --output)")
@_reads_results
def info(
    results: Path = typer.Argument(..., help="Results file of a sweep, or a file of one run.", show_default=False),
    failed: bool = typer.Option(False, "--failed", help="Only runs whose status is not ok (one row each)."),
    runs: bool = typer.Option(False, "--runs", help="One row per run instead of one per method and h."),
):
    """Summarize a results file: provenance, then one row per method and h (runs, ok, impacts, L2 error
    median and largest, wall time; --runs: one row per run) and the messages of failed runs. A file of
    one run: its summary and energy account."""
    from rich.markup import escape

    from vcirun.io.reader import read_results
    from vcirun.io.single import is_trajectory_file
    from vcirun.experiments.tables import print_table, runs_table, summary_table

    if is_trajectory_file(results):
        if failed or runs:
            _fail(f"{results} holds one run: --failed and --runs list the runs of a sweep's results file")
        return _info_single(results)
    try:
        res = read_results(results)
    except _expected_errors() as e:
        _fail(str(e))
    a = res.attrs
    console = _console()
    expected = a.get("n_runs_expected", "?")
    _print = console.print

    def say(text):  # long provenance lines are better unwrapped than broken mid-word
        _print(text, soft_wrap=True)

    say(f"[bold]{res.name}[/bold]  {results}")
    say(f"  system {a.get('system', '?')}, T = {a.get('T', '?')}, reference {a.get('reference_kind', '?')}")
    say(f"  {len(res.runs)} of {expected} runs stored"
                  + (f", {len(res.incomplete)} incomplete group(s) ignored" if res.incomplete else "")
                  + (f"; {res.in_journal} of them in the journal of a session that did not finish (the next "
                     "`vcirun sweep` of this config folds them into the file)" if getattr(res, "in_journal", 0)
                     else ""))
    if res.damaged:
        say(f"  [bold red]{len(res.damaged)} stored item(s) fail their checks and are not shown[/bold red] (`vcirun "
            "sweep` of the same config recomputes them):")
        for p, why in list(res.damaged.items())[:10]:
            say(escape(f"    {p}: {why}"))
        if len(res.damaged) > 10:
            say(f"    ... and {len(res.damaged) - 10} more")
    for note in getattr(res, "notes", ()):
        say(f"  [bold red]note[/bold red]: {escape(note)}")
    say(f"  created {a.get('created', '?')}, updated {a.get('updated', '?')}; vcirun "
                  f"{a.get('vcirun_version', '?')}, git {str(a.get('git_commit', ''))[:10] or 'n/a'}"
                  + (" (dirty)" if a.get("git_dirty") == "yes" else ""))
    hist = a.get("history") or []
    if hist:
        last = hist[-1]
        say(f"  sessions: {len(hist)}; last {last.get('status', '?')} at {last.get('updated', '?')} "
                      f"({last.get('computed', 0)} runs computed)")
    if runs or failed:
        print_table(runs_table(res, only_failed=failed), console, compact=True)
    elif res.runs:
        print_table(summary_table(res), console, compact=True)
    from vcirun.experiments.tables import run_status

    bad = [r for r in res.runs if run_status(r.attrs) != "ok"]
    for r in bad[:50]:
        a = r.attrs
        why = a.get("message", "") if a.get("status") != "ok" else a.get("tol_reason", "")
        typer.echo(f"  {r.run_id} {a.get('label')} h={a.get('h_chosen', a.get('h')):g}: {run_status(a)}: {why}")
    if len(bad) > 50:
        typer.echo(f"  ... and {len(bad) - 50} more failed runs")


def _info_single(path: Path) -> None:
    """`vcirun info run.h5`: the facts `vcirun simulate` printed about the run (its energy account too)."""
    from rich.table import Table

    from vcirun.io.single import read_single
    from .simulate import energy_rows

    try:
        traj = read_single(path)
    except _expected_errors() as e:
        _fail(str(e))
    imp = ", ".join(f"{t:.4g}" for t in traj.impacts[:8]) + (" ..." if len(traj.impacts) > 8 else "")
    rows = [("run", f"{traj.system}  {traj.method}  h = {traj.h:g}  T = {traj.T:g}"
             + (f"  beta = {traj.beta:g}" if traj.beta is not None else "")),
            ("steps", f"{traj.n_steps}"),
            ("impacts", f"{len(traj.impacts)}" + (f" at t = {imp}" if len(traj.impacts) else "")),
            ("status", traj.status + (f" ({traj.message})" if traj.message else ""))]
    try:
        rows += energy_rows(traj)
    except (ValueError, OSError, RuntimeError) as e:   # a YAML system the file does not carry
        rows.append(("energy", f"no account ({' '.join(str(e).split())[:120]})"))
    rows.append(("wall time", f"{traj.wall_time:.4g} s integrating"))
    t = Table(show_header=False, box=None, pad_edge=False, title=str(path), title_justify="left")
    t.add_column(style="bold")
    t.add_column()
    for k, v in rows:
        t.add_row(k, v)
    _console().print(t)
