"""The `vcirun` command line: thin wrappers over plain functions in vcirun.experiments.

Expected failures (bad config, unusable results file, bad option values) print one line
`error: ...` on stderr and exit with status 1; an interrupted sweep exits 130 (SIGINT) or 143
(SIGTERM) after saving every finished run. Unexpected exceptions keep their traceback (bugs).
"""
from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

app = typer.Typer(
    name="vcirun",
    help="Event-driven variational collision integrators (Pekarek & Murphey 2014): single runs, "
         "parallel resumable sweeps stored in HDF5, and the paper's figures and tables.",
    no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False,
)

class CliError(Exception):
    """An expected failure: reported as one line on stderr, exit status 1."""


def _version_callback(value: bool):
    if value:
        import vcirun

        typer.echo(f"vcirun {vcirun.__version__}")
        raise typer.Exit()


@app.callback()
def _main(version: bool = typer.Option(False, "--version", callback=_version_callback, is_eager=True,
                                       help="Print the version and exit.")):
    """Event-driven variational collision integrators (Pekarek & Murphey 2014)."""


def _announce_compiles() -> None:
    """Print the build module's "compiling kernels for <scene>/<family> (first time, about N s)" line
    on stderr (once per process)."""
    from vcirun.codegen import cache

    if _say_compile not in cache.COMPILE_CALLBACKS:
        cache.COMPILE_CALLBACKS.append(_say_compile)


def _say_compile(message: str) -> None:
    typer.echo(message, err=True)


def _fail(message: str, code: int = 1):
    typer.echo(f"error: {' '.join(str(message).split())}", err=True)
    raise typer.Exit(code)


def _console(stderr: bool = False):
    from rich.console import Console

    return Console(stderr=stderr, highlight=False, soft_wrap=False)


def _expected_errors():
    """The exception types that are user errors, not bugs."""
    from vcirun.experiments.config import ConfigError
    from vcirun.io.errors import StorageError
    from vcirun.experiments.worker import SweepError

    return (ConfigError, StorageError, SweepError, CliError)


def _reads_results(fn):
    """`info` and `plot`: a results file that cannot be read (damaged blocks, wrong types where the
    readers expect numbers, permissions) ends in one line naming the file, never in a traceback."""
    import functools

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        import click

        try:
            return fn(*args, **kwargs)
        except (typer.Exit, typer.Abort, click.exceptions.Exit, click.exceptions.Abort,
                click.exceptions.ClickException):
            raise
        except (OSError, KeyError, ValueError, TypeError, IndexError, AttributeError, RuntimeError,
                MemoryError) as e:
            text = " ".join(str(e).split())
            _fail(f"{kwargs.get('results') or 'results'}: cannot read the results file ({type(e).__name__}: "
                  f"{text[:200]}); it may be damaged: rerun the sweep that wrote it, or move it away")
    return wrapper


# --- simulate ---------------------------------------------------------------------------------------
def _parse_params(items: list[str]) -> dict:
    out = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise CliError(f"--param: expected NAME=VALUE (got {item!r})")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise CliError(f"--param {name.strip()}: value must be a number (got {value!r})") from None
    return out


def _parse_vector(text: str | None, name: str):
    """'1.2,-1.0' -> [1.2, -1.0] (None stays None)."""
    if text is None:
        return None
    try:
        return [float(x) for x in str(text).replace(" ", "").split(",") if x != ""]
    except ValueError:
        raise CliError(f"{name}: expected comma-separated numbers such as 1.2,-1.0 (got {text!r})") from None


def simulate_once(system: str, method: str, *, h: float, T: float, beta: float | None = None, ld=None,
                  mh_order=None, flow_order=None, params: dict | None = None, constrained: bool | None = None,
                  newton_tol=None, event_tol=None, q0=None, p0=None):
    """One run through `vcirun.simulate`; bad input becomes CliError. Returns (trajectory, seconds);
    `traj.compiled_now` says whether kernels were generated during the call."""
    import time
    import warnings

    import vcirun
    from vcirun.core.grid import GridWarning
    from vcirun.codegen import build

    kw = {k: v for k, v in dict(ld=ld, mh_order=mh_order, flow_order=flow_order, params=params or None,
                                constrained=constrained, newton_tol=newton_tol, event_tol=event_tol).items()
          if v is not None}
    if (q0 is None) != (p0 is None):
        raise CliError("initial state: give both --q0 and --p0 (or --beta)")
    if q0 is not None:
        if beta is not None:
            raise CliError("initial state: give either --beta or --q0/--p0, not both")
        kw.update(q0=q0, p0=p0)
    n_log = len(build.BUILD_LOG)
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings(record=True) as notes:
            warnings.simplefilter("always", GridWarning)
            traj = vcirun.simulate(system, method, h=h, T=T, beta=beta, **kw)
    except ValueError as e:
        raise CliError(str(e)) from None
    for w in notes:
        typer.echo(f"note: {w.message}", err=True)
    traj.compiled_now = any(not e["cached"] for e in build.BUILD_LOG[n_log:])
    return traj, time.perf_counter() - t0


def _energy_scale(traj) -> float:
    """max(|H0|, the largest kinetic energy 1/2 p . qdot on (up to 2000 of) the grid states): what a
    relative energy error is relative to (|H0| alone depends on the zero of V and may be ~0)."""
    import numpy as np

    H0 = abs(float(traj.H[0]))
    if traj.dynamics is None or len(traj.t) == 0:
        return H0
    n = traj.q.shape[1]
    ke = 0.0
    for k in np.unique(np.linspace(0, len(traj.t) - 1, min(2000, len(traj.t))).astype(int)):
        y = np.concatenate([traj.q[k], traj.p[k]])
        qdot = traj.dynamics(traj.t[k], y)[:n]
        ke = max(ke, 0.5 * float(traj.p[k] @ qdot))
    return max(H0, ke)


def summary_lines(traj, total_seconds: float) -> list[tuple[str, str]]:
    """The facts `vcirun simulate` prints about a run."""
    import numpy as np

    rows = [("run", f"{traj.system}  {traj.method}  h = {traj.h:g}  T = {traj.T:g}"
             + (f"  beta = {traj.beta:g}" if traj.beta is not None else ""))]
    rows.append(("steps", f"{traj.n_steps}"))
    imp = ", ".join(f"{t:.4g}" for t in traj.impacts[:8]) + (" ..." if len(traj.impacts) > 8 else "")
    rows.append(("impacts", f"{len(traj.impacts)}" + (f" at t = {imp}" if len(traj.impacts) else "")))
    rows.append(("status", traj.status + (f" ({traj.message})" if traj.message else "")))
    H = np.asarray(traj.H, float)
    if H.size and np.isfinite(H[0]):
        dH = float(np.nanmax(np.abs(H - H[0])))
        scale = _energy_scale(traj)
        rel = (f" (relative {dH / scale:.2e} to the energy scale {scale:.4g} = max(|H0|, max kinetic energy))"
               if np.isfinite(scale) and scale > 0 else "")
        rows.append(("max |H - H0|", f"{dH:.3e}{rel}"))
    if traj.Hmod is not None and len(traj.Hmod) and np.isfinite(traj.Hmod[0]):
        rows.append(("max |Hmod - Hmod0|", f"{float(np.nanmax(np.abs(traj.Hmod - traj.Hmod[0]))):.3e}"))
    setup = max(0.0, total_seconds - traj.wall_time)
    what = ("compiling kernels (first time; cached for the next runs)" if getattr(traj, "compiled_now", False)
            else "loading kernels and setting up")
    rows.append(("wall time", f"{traj.wall_time:.4g} s integrating; {total_seconds:.3g} s in total, of which "
                              f"{setup:.3g} s {what}"))
    return rows


@app.command(epilog="Examples:\n\n"
             "  vcirun simulate\n\n"
             "  vcirun simulate --system cart_pendulum --method MCVAA --h 0.01 --T 5 --beta 3.2\n\n"
             "  vcirun simulate --method MCVA --ld SVC --mh-order 3 --flow-order 4\n\n"
             "  vcirun simulate --system double_pendulum --method CVA --unconstrained\n\n"
             "  vcirun simulate --system double_pendulum --q0 1.2,-1.0 --p0 0,0 --output run.h5")
def simulate(
    system: str = typer.Option("cart_pendulum", "--system", "-s",
                               help="Built-in scene (cart_pendulum, double_pendulum, oscillator_wall, ...) "
                                    "or a YAML system file."),
    method: str = typer.Option("CVA", "--method", "-m",
                               help="CVA, VCI, MCVAA, MCVAC, MCVA (with --ld, --mh-order), or a discrete "
                                    "Lagrangian (SE1 SE2 SVA SVB SVC midpoint) ignoring the constraint."),
    h: float = typer.Option(1e-2, "--h", help="Step size."),
    T: float = typer.Option(5.0, "--T", "-T", help="Final time."),
    beta: Optional[float] = typer.Option(None, "--beta", "-b",
                                         help="Initial-condition parameter of the scene's map "
                                              "(default: the scene's default state; 3.2 for cart_pendulum)."),
    ld: Optional[str] = typer.Option(None, "--ld", help="Discrete Lagrangian of the generalized MCVA."),
    mh_order: Optional[int] = typer.Option(None, "--mh-order", help="Modified-Hamiltonian truncation order."),
    flow_order: Optional[int] = typer.Option(None, "--flow-order", help="Gauss partial-flow order (4 or 6)."),
    param: List[str] = typer.Option([], "--param", "-p", help="Parameter override NAME=VALUE (repeatable)."),
    unconstrained: bool = typer.Option(False, "--unconstrained", help="Ignore the impact constraint."),
    newton_tol: Optional[float] = typer.Option(None, "--newton-tol", help="Newton tolerance."),
    event_tol: Optional[float] = typer.Option(None, "--event-tol", help="Collision-time tolerance."),
    q0: Optional[str] = typer.Option(None, "--q0", metavar="Q1,Q2,...",
                                     help="Initial coordinates, comma-separated (with --p0; `vcirun systems` "
                                          "lists each scene's coordinates)."),
    p0: Optional[str] = typer.Option(None, "--p0", metavar="P1,P2,...", help="Initial momenta p = M(q) qdot."),
    output: Optional[Path] = typer.Option(None, "--output", "-o",
                                          help="Save the trajectory: .h5 (read with "
                                               "vcirun.run.trajectory.read_trajectory), .nc, .csv or .npz."),
):
    """Simulate one run and print a summary (steps, impacts, status, energy error, wall time)."""
    _announce_compiles()
    try:
        traj, total = simulate_once(system, method, h=h, T=T, beta=beta, ld=ld, mh_order=mh_order,
                                    flow_order=flow_order, params=_parse_params(param),
                                    constrained=False if unconstrained else None, newton_tol=newton_tol,
                                    event_tol=event_tol, q0=_parse_vector(q0, "--q0"), p0=_parse_vector(p0, "--p0"))
        if output is not None:
            try:
                traj.save(output)
            except (ValueError, OSError, ImportError) as e:
                raise CliError(f"--output: {e}") from None
    except CliError as e:
        _fail(str(e))
    from rich.table import Table

    t = Table(show_header=False, box=None, pad_edge=False)
    t.add_column(style="bold")
    t.add_column()
    for k, v in summary_lines(traj, total):
        t.add_row(k, v)
    _console().print(t)
    if output is not None:
        typer.echo(f"saved {output}")
    if traj.status != "ok":
        _fail(f"run ended with status {traj.status}: {traj.message}")


# --- sweep ------------------------------------------------------------------------------------------
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
                                help="Exit with status 1 when any run in the file did not finish with status ok "
                                     "(for scripts and CI; the runs are stored either way)."),
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
            "time; cached now)" if summary.compiled else "loading kernels")
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
    if summary.computed and summary.failed:
        typer.echo(f"note: {summary.failed} run(s) did not finish with status ok; `vcirun info {summary.path}` "
                   "lists their messages")
    if summary.summary_error:
        typer.echo(f"note: {summary.summary_error}", err=True)
    not_ok = sum(n for st, n in summary.status_counts.items() if st != "ok")
    if strict and not_ok:
        _fail(f"--strict: {not_ok} of {sum(summary.status_counts.values())} stored runs did not finish with status "
              f"ok; `vcirun info {summary.path} --failed` lists them")
    typer.echo(f"next: vcirun plot {summary.path}")


# --- plot -------------------------------------------------------------------------------------------
@app.command(epilog="Examples:\n\n"
             "  vcirun plot                      (every results file under results/)\n\n"
             "  vcirun plot results/fig4.h5\n\n"
             "  vcirun plot results/fig4.h5 --out paper-figures/")
@_reads_results
def plot(
    results: Optional[Path] = typer.Argument(None, help="Results file or work-precision study JSON (default: every "
                                                        "*.h5 under results/, each into results/figures/<name>/).",
                                             show_default=False),
    out: Optional[Path] = typer.Option(None, "--out", help="Output folder (default: <results dir>/figures/<name>)."),
):
    """Write the figures (PNG and PDF) and tables (CSV and Markdown) a results file supports."""
    from vcirun.experiments.figures import plot_results
    from vcirun.io.errors import StorageError
    from vcirun.experiments.tables import print_table
    from vcirun.experiments.wp_figures import is_study_file, plot_study, print_study_tables

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
    typer.echo(f"  output    {cfg.output_path()}")


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
                                                      "tolerances (a smoke run)."),
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
@app.command(epilog="Examples:\n\n  vcirun info results/quick.h5\n\n  vcirun info results/fig4.h5 --failed")
@_reads_results
def info(
    results: Path = typer.Argument(..., help="Results file.", show_default=False),
    failed: bool = typer.Option(False, "--failed", help="Only runs whose status is not ok."),
):
    """Summarize a results file: provenance, then a table of runs (method, h, beta, status, impacts,
    L2 error, wall time) and the messages of failed runs."""
    from vcirun.io.reader import read_results
    from vcirun.experiments.tables import print_table, runs_table

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
    say(f"  created {a.get('created', '?')}, updated {a.get('updated', '?')}; vcirun "
                  f"{a.get('vcirun_version', '?')}, git {str(a.get('git_commit', ''))[:10] or 'n/a'}"
                  + (" (dirty)" if a.get("git_dirty") == "yes" else ""))
    hist = a.get("history") or []
    if hist:
        last = hist[-1]
        say(f"  sessions: {len(hist)}; last {last.get('status', '?')} at {last.get('updated', '?')} "
                      f"({last.get('computed', 0)} runs computed)")
    table = runs_table(res, only_failed=failed)
    print_table(table, console)
    bad = [r for r in res.runs if r.attrs.get("status") != "ok"]
    for r in bad[:50]:
        typer.echo(f"  {r.run_id} {r.attrs.get('label')} h={r.attrs.get('h'):g}: {r.attrs.get('status')}: "
                   f"{r.attrs.get('message', '')}")
    if len(bad) > 50:
        typer.echo(f"  ... and {len(bad) - 50} more failed runs")


# --- verify -------------------------------------------------------------------------------------------
def verify_system(system: str, *, methods: str = "CVA,MCVAC", q0=None, p0=None, beta=None, T: float = 5.0,
                  h=None, params: dict | None = None, output: Path | None = None, console=None):
    """`vcirun verify` as a plain function: runs vcirun.verify (progress on `console`), writes the report
    if `output` is given; bad input becomes CliError. Returns (VerifyResult, written paths)."""
    import time

    import vcirun

    t0 = time.perf_counter()

    def progress(msg):
        if console is not None:
            console.print(f"[dim]{time.perf_counter() - t0:6.1f} s[/dim]  {msg}")

    try:
        res = vcirun.verify(system, methods=methods, q0=q0, p0=p0, beta=beta, T=T, h=h, params=params or None,
                            progress=progress)
    except ValueError as e:
        raise CliError(str(e)) from None
    written = res.save(output) if output is not None else []
    return res, written


@app.command("verify", epilog="Examples:\n\n"
             "  vcirun verify cart_pendulum\n\n"
             "  vcirun verify my_system.yaml --methods CVA,MCVAC --q0 1.2,-1.0 --p0 0,0 --T 5 --output report.md\n\n"
             "  vcirun verify cart_pendulum --beta 3.2 --h 0.02,0.01,0.005,0.0025\n\n"
             "Exit status 0 when every check passes (warnings are printed, they do not fail), 1 when one fails.")
def verify_command(
    system: str = typer.Argument(..., help="Built-in scene (cart_pendulum, oscillator_wall, ...) or a YAML system file.",
                                 show_default=False),
    methods: str = typer.Option("CVA,MCVAC", "--methods", "-m", help="Comma-separated methods to verify."),
    q0: Optional[str] = typer.Option(None, "--q0", help="Start positions, comma separated (with --p0)."),
    p0: Optional[str] = typer.Option(None, "--p0", help="Start momenta, comma separated (with --q0)."),
    beta: Optional[float] = typer.Option(None, "--beta", "-b",
                                         help="Initial-condition parameter of the scene's map (default: the scene's "
                                              "default state; 3.2 for cart_pendulum)."),
    T: float = typer.Option(5.0, "--T", "-T", help="Final time of every run."),
    h: Optional[str] = typer.Option(None, "--h", help="Step ladder, comma separated (default 0.04 / 2^k, k = 0..6)."),
    param: List[str] = typer.Option([], "--param", "-p", help="Parameter override NAME=VALUE (repeatable)."),
    output: Optional[Path] = typer.Option(None, "--output", "-o",
                                          help="Markdown report to write (the figure goes next to it, .png)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress output."),
):
    """Run the test suite's numerical checks on SYSTEM: kernel derivatives, hyperregularity, observed
    orders (smooth and through impacts), symplecticity, modified-Hamiltonian conservation, impact times
    and energy across impacts; one verdict per check (pass / warn / fail, the number, the threshold)."""
    try:
        res, written = verify_system(system, methods=methods, q0=_parse_vector(q0, "--q0"),
                                     p0=_parse_vector(p0, "--p0"), beta=beta, T=T, h=_parse_vector(h, "--h"),
                                     params=_parse_params(param), output=output,
                                     console=None if quiet else _console(stderr=True))
    except CliError as e:
        _fail(str(e))
    from rich.table import Table

    style = {"pass": "green", "warn": "yellow", "fail": "bold red", "skip": "dim"}
    t = Table(title=f"vcirun verify {res.system} ({res.seconds:.1f} s)", box=None, pad_edge=False)
    for col in ("check", "method", "verdict", "value", "threshold"):
        t.add_column(col)
    from vcirun.verification.verdict import _value

    for c in res.checks:
        t.add_row(c.name, c.method or "-", f"[{style[c.verdict]}]{c.verdict}[/]", _value(c), c.threshold)
    console = _console()
    console.print(t)
    for c in res.checks:
        if c.verdict in ("warn", "fail", "skip"):
            console.print(f"[{style[c.verdict]}]{c.verdict}[/]  {c.name}" + (f" [{c.method}]" if c.method else "")
                          + f": {c.note}", soft_wrap=True)
    for p in written:
        typer.echo(f"wrote {p}")
    if not res.ok:
        raise typer.Exit(1)


# --- systems -----------------------------------------------------------------------------------------
@app.command(epilog="Examples:\n\n  vcirun systems\n\n  vcirun systems cart_pendulum")
def systems(name: Optional[str] = typer.Argument(None, help="One scene (default: all).", show_default=False)):
    """The built-in scenes: coordinates, parameters (default, unit, meaning), constraint and initial
    states. Any scene also runs with `n_pendulum_K` for K links; YAML files declare your own."""
    from vcirun.scenes.catalog import BUILTIN_INFO, momentum_unit, scene_info
    from vcirun.scenes.data import scene_data

    names = [name] if name else list(BUILTIN_INFO) + ["n_pendulum_3"]
    console = _console()

    def say(text):  # unit brackets such as [m] are text, not rich markup
        console.print(text, soft_wrap=True, markup=False)

    for nm in names:
        info = scene_info(nm)
        if info is None:
            _fail(f"system: unknown built-in system {nm!r} (choose one of {', '.join(BUILTIN_INFO)}, or n_pendulum_K)")
        d = scene_data(nm)
        console.print(f"[bold]{nm}[/bold]", end="")
        say(f"  {d.description}" + ("  (n_pendulum_K: any K)" if nm.startswith("n_pendulum_") else ""))
        coords = ", ".join(f"{c} [{u}] {m}" for c, u, m in info.coordinates)
        say(f"  coordinates  {coords}; momenta p = M(q) qdot in "
            + ", ".join(f"{momentum_unit(u)}" for _, u, _ in info.coordinates))
        say("  parameters   " + "; ".join(f"{k} = {v:g} {info.params.get(k, ('', ''))[0]} "
                                         f"({info.params.get(k, ('', ''))[1]})" for k, v in d.params.items()))
        say(f"  constraint   {info.constraint}")
        if info.ic_map:
            say(f"  --beta       {info.ic_map}")
        if info.default_state:
            say(f"  default      {info.default_state}")
        example = ",".join("0" for _ in info.coordinates)
        say(f"  example      vcirun simulate --system {nm} --q0 {example} --p0 {example}"
            if nm != "cart_pendulum" else "  example      vcirun simulate --system cart_pendulum --beta 3.2")
    typer.echo("Energies in J, times in s; options --param NAME=VALUE override parameters.")


# --- cache ---------------------------------------------------------------------------------------------
cache_app = typer.Typer(help="The kernel cache every vcirun command and `make` share ($VCIRUN_CACHE_DIR, "
                             "default ~/.cache/vcirun).", no_args_is_help=True)
app.add_typer(cache_app, name="cache")


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


@cache_app.command("info", epilog="Example:\n\n  vcirun cache info")
def cache_info():
    """Where the compiled kernels are and how much space they take."""
    from vcirun.codegen import cache

    i = cache.info()
    typer.echo(f"{i.path}: {i.modules} compiled modules, {i.cores} shared cores, {i.index_entries} warm-start entries, {i.files} files, "
               f"{_mb(i.bytes)}")
    typer.echo("It grows with every vcirun version and system; `vcirun cache clear` empties it (the next run of "
               "each system compiles again).")


@cache_app.command("clear", epilog="Example:\n\n  vcirun cache clear")
def cache_clear():
    """Delete every cached kernel."""
    from vcirun.codegen import cache

    i = cache.clear()
    typer.echo(f"removed {i.modules} compiled modules ({_mb(i.bytes)}) from {i.path}")


def main() -> None:  # pragma: no cover - console entry point alternative
    app()


if __name__ == "__main__":
    app()
