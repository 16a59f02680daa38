"""`vcirun animate`: the animation of one run (vcirun.run.animate), from a results file of a sweep, a
file of one run (`vcirun simulate --output run.h5`), or a run made here (--system, --method)."""
from __future__ import annotations

import os

from pathlib import Path
from typing import List, Optional

import typer

from .app import CliError, _announce_compiles, _expected_errors, _fail, app


def _pick_run(path: Path, run: str | None, method: str | None, h: float | None, beta: float | None):
    """The Trajectory of the run of a sweep's results file chosen by --run or by method, h and beta."""
    from vcirun.io.reader import load_trajectory, read_results

    res = read_results(path)
    if not res.runs:
        raise CliError(f"{path}: no complete runs stored")
    if run is not None:
        ids = {r.run_id for r in res.runs}
        if run not in ids:
            raise CliError(f"--run: {run!r} is not a run of {path} (e.g. {', '.join(sorted(ids)[:5])}); "
                           f"`vcirun info {path} --runs` lists them")
        chosen = run
    else:
        cand = res.runs
        if method is not None:
            cand = [r for r in cand if str(r.attrs.get("method", "")).lower() == method.lower()
                    or str(r.attrs.get("label", "")).lower() == method.lower()]
        if h is not None:
            cand = [r for r in cand if abs(float(r.attrs.get("h", float("nan"))) - h) <= 1e-12 * max(1.0, h)]
        if beta is not None:
            cand = [r for r in cand if r.beta_or_none is not None and abs(r.beta_or_none - beta) <= 1e-9 * max(1.0, abs(beta))]
        if not cand:
            raise CliError(f"{path}: no stored run has {_selection(method, h, beta)}; `vcirun info {path} --runs` "
                           "lists the runs")
        if len(cand) > 1:
            listed = "; ".join(f"{r.run_id} ({r.attrs.get('label', r.attrs.get('method'))}, h = {r.attrs.get('h'):g}"
                               + (f", beta = {r.beta_or_none:g}" if r.beta_or_none is not None else "") + ")"
                               for r in cand[:6])
            raise CliError(f"{path}: {len(cand)} runs match{' ' + _selection(method, h, beta) if (method or h or beta) else ''} "
                           f"({listed}{' ...' if len(cand) > 6 else ''}); choose one with --run, or narrow it with "
                           "--method, --h, --beta")
        chosen = cand[0].run_id
    tr = load_trajectory(path, chosen)
    if len(tr.t) < 2:
        raise CliError(f"{path}: run {chosen} stores no grid states (the sweep ran with store_trajectories: false); "
                       "rerun it with `vcirun animate --system ... --method ...`")
    return tr, chosen


def _selection(method, h, beta) -> str:
    parts = [f"method {method}" if method else "", f"h = {h:g}" if h is not None else "",
             f"beta = {beta:g}" if beta is not None else ""]
    return ", ".join(p for p in parts if p) or "any"


def _default_name(traj) -> str:
    """<system>_<method>_h<h>[_beta<beta>].gif: runs of one scene with other steps or betas do not
    overwrite each other's animation (runs that differ only in q0, p0, parameters or T do: --output)."""
    beta = f"_beta{traj.beta:g}" if isinstance(traj.beta, (int, float)) else ""
    return f"{traj.system}_{traj.method}_h{traj.h:g}{beta}.gif"


def _check_output(out: Path) -> None:
    """--output names a .gif or .mp4 file that can be written: its folder exists (or can be made) and is
    writable, and it is not a folder itself."""
    if out.suffix.lower() not in (".gif", ".mp4"):
        raise CliError(f"--output {out}: an animation is .gif or .mp4")
    if out.is_dir():
        raise CliError(f"--output {out}: is a folder; name the animation file in it")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise CliError(f"--output {out}: its folder cannot be made ({e.strerror or e})") from None
    if not os.access(out.parent, os.W_OK):
        raise CliError(f"--output {out}: its folder {out.parent} is not writable")


@app.command(epilog="Examples:\n\n"
             "  vcirun animate --system rocking_block --h 0.001 --T 3\n\n"
             "  vcirun animate --system docs/examples/cradle20.yaml --T 2 --output cradle.gif\n\n"
             "  vcirun animate run.h5                       (a file of vcirun simulate --output)\n\n"
             "  vcirun animate results/quick.h5 --method MCVAA --h 0.01 --beta 3.2")
def animate(
    results: Optional[Path] = typer.Argument(None, help="A file of one run (vcirun simulate --output run.h5) or a "
                                                        "sweep's results file; omit it to run --system here.",
                                             show_default=False),
    run: Optional[str] = typer.Option(None, "--run", help="Run id in a sweep's results file (vcirun info --runs)."),
    system: Optional[str] = typer.Option(None, "--system", "-s",
                                         help="Scene to run (built-in or YAML), or the YAML file that draws the run "
                                              "of a results file."),
    method: Optional[str] = typer.Option(None, "--method", "-m", help="Method to run (default CVA), or to choose in a "
                                                                     "results file."),
    h: Optional[float] = typer.Option(None, "--h", help="Step size (default 1e-3 for a run made here)."),
    T: Optional[float] = typer.Option(None, "--T", "-T", help="Final time of a run made here (default 5)."),
    beta: Optional[float] = typer.Option(None, "--beta", "-b", help="Initial-condition parameter."),
    q0: Optional[str] = typer.Option(None, "--q0", metavar="Q1,Q2,...", help="Initial coordinates (with --p0)."),
    p0: Optional[str] = typer.Option(None, "--p0", metavar="P1,P2,...", help="Initial momenta p = M(q) qdot."),
    param: List[str] = typer.Option([], "--param", "-p", help="Parameter override NAME=VALUE (repeatable)."),
    output: Optional[Path] = typer.Option(None, "--output", "-o",
                                          help="Animation file, .gif (Pillow) or .mp4 (needs ffmpeg) (default: "
                                               "results/animations/<system>_<method>_h<h>[_beta<beta>].gif)."),
    fps: float = typer.Option(30.0, "--fps", help="Frames per second of the animation."),
    speed: Optional[float] = typer.Option(None, "--speed",
                                          help="Motion seconds per animation second (default 1, raised to fit "
                                               "--max-frames)."),
    max_frames: int = typer.Option(600, "--max-frames", help="Most frames to write."),
    no_energy: bool = typer.Option(False, "--no-energy", help="Leave out the energy panel."),
    dpi: float = typer.Option(100.0, "--dpi", help="Pixels per inch (the figure is 8 x 4 inches)."),
):
    """Animate one run: the mechanism drawn from its scene's geometry (bodies-form scenes, built-in scenes, a
    YAML draw: section; else its configuration), impacts marked, the energy and a time bar beside it."""
    from .simulate import _parse_params, _parse_vector, simulate_once
    from vcirun.io.single import is_trajectory_file, not_read_back, read_single

    _announce_compiles()
    try:
        from vcirun.run.animate import check_args

        try:   # before any run is read or made
            check_args(fps, speed, max_frames, dpi)
        except ValueError as e:
            raise CliError(str(e)) from None
        if output is not None:
            _check_output(output)
        if results is not None:
            if any(v is not None for v in (T, q0, p0)) or param:
                raise CliError("--T, --q0, --p0, --param: options of a run made here; a results file's run is "
                               "animated as stored")
            if not results.exists():
                raise CliError(f"{results}: file not found")
            why = not_read_back(results)
            if why:
                raise CliError(why)
            if is_trajectory_file(results):
                if run is not None or method is not None or h is not None or beta is not None:
                    raise CliError(f"{results} holds one run: --run, --method, --h, --beta choose a run of a sweep's "
                                   "results file")
                traj, what = read_single(results), str(results)
            else:
                traj, rid = _pick_run(results, run, method, h, beta)
                what = f"{results} run {rid}"
        else:
            if run is not None:
                raise CliError("--run: chooses a run of a results file; name the file first")
            if system is not None and not system.strip():
                raise CliError("--system: empty; name a built-in scene (vcirun systems) or a YAML file")
            traj, _ = simulate_once(system or "cart_pendulum", method or "CVA", h=1e-3 if h is None else h,
                                    T=5.0 if T is None else T, beta=beta, params=_parse_params(param),
                                    q0=_parse_vector(q0, "--q0"), p0=_parse_vector(p0, "--p0"))
            what = f"{traj.system} {traj.method} h = {traj.h:g}"
        out = output or Path("results") / "animations" / _default_name(traj)
        if out.suffix.lower() not in (".gif", ".mp4"):
            raise CliError(f"--output {out}: an animation is .gif or .mp4")
        try:
            anim = traj.animate(system=system if results is not None else None, fps=fps, speed=speed,
                                max_frames=max_frames, energy=not no_energy, dpi=dpi)
            typer.echo(f"animating {what}: {anim.n_frames} frames at {fps:g} fps, {anim.speed:.3g}x speed"
                       + (f" ({anim.note})" if anim.note else ""), err=True)
            anim.save(out)
        except ValueError as e:
            raise CliError(str(e)) from None
        except OSError as e:
            raise CliError(f"--output {out}: cannot write it ({e.strerror or e})") from None
    except CliError as e:
        _fail(str(e))
    except _expected_errors() as e:
        _fail(str(e))
    typer.echo(f"saved {out}")
    if traj.status != "ok":
        typer.echo(f"note: the run ended with status {traj.status}: {traj.message}", err=True)
