"""`vcirun recommend SYSTEM --tol TOL`: the candidate methods for an L2 error tol on a scene, their
predicted h, error and cost, and the pick; from stored measurements where they exist (a
work-precision study's JSON, a sweep's results file: vcirun.experiments.studies.wp_model), else from
pilot runs on the scene's start (`vcirun.simulate(tol=...)`, whose run and error estimate are shown)."""
from __future__ import annotations

import math
from pathlib import Path
from typing import List, Optional

import typer

from .app import CliError, _announce_compiles, _fail, app
from .simulate import _parse_params, _parse_vector


def _g(x, f=".3g") -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, f)


def _stored_models(system: str, sources: list[Path]) -> list[dict]:
    """The models of the stored measurements of `system` among `sources` (files, or folders searched for
    *.json studies and *.h5 sweeps)."""
    from vcirun.experiments.studies import wp_model
    from vcirun.io.errors import StorageError

    files = []
    for s in sources:
        if s.is_dir():
            files += sorted(s.glob("*.json")) + sorted(s.glob("*.h5"))
        elif s.exists():
            files.append(s)
        else:
            raise CliError(f"--results: {s} does not exist")
    want = Path(system).stem if system.endswith((".yaml", ".yml")) else system
    out = []
    for f in files:
        try:
            if f.suffix == ".json":
                from vcirun.experiments.studies.jsonio import load_json

                res = load_json(f)
                if not isinstance(res, dict) or res.get("study") != "work_precision":
                    continue
                model = res.get("model") or wp_model.from_study(res)
            elif f.suffix in (".h5", ".hdf5"):
                model = wp_model.from_results(f)
            else:
                continue
            _check_model(model)
        except (OSError, ValueError, KeyError, TypeError, AttributeError, ZeroDivisionError, StorageError) as e:
            typer.echo(f"note: {f}: not read ({type(e).__name__}: {str(e)[:120]})", err=True)
            continue
        name = str(model.get("system") or "")
        if name == system or Path(name).stem == want or name == want:
            out.append(model)
    return out


def _check_model(model) -> None:
    """A stored model recommend can print: every horizon predicts, with finite positive constants and
    costs (ValueError naming what is not; an edited or damaged study would print nan or negative
    errors and costs)."""
    from vcirun.experiments.studies import wp_model

    if not isinstance(model, dict) or not isinstance(model.get("horizons"), dict) or not model["horizons"]:
        raise ValueError("its model has no horizons")
    for k, hz in model["horizons"].items():
        T = float(hz["T"])
        if not (T > 0 and math.isfinite(T)):
            raise ValueError(f"horizon {k}: T = {hz['T']!r}")
        for r in wp_model.predict(hz, 1e-6, T):
            for name in ("C_h", "b", "predicted_error", "predicted_cost"):
                v = r.get(name)
                if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                    raise ValueError(f"horizon {k}, method {r.get('method')}: {name} = {v!r}")


def _print_model(model: dict, tol: float, T: float | None) -> bool:
    """Print the model's table at tol (each stored horizon, or T); True where a pick was printed."""
    from vcirun.experiments.studies import wp_model

    horizons = model["horizons"]
    keys = list(horizons)
    if T is not None:
        keys = [k for k in keys if abs(horizons[k]["T"] - T) <= 1e-9 * max(1.0, T)]
        if not keys:
            typer.echo(f"{model['source']}: no measurements at T = {T:g} (it has T = {', '.join(horizons)})")
            return False
    picked = False
    for k in keys:
        hz = horizons[k]
        rows = wp_model.predict(hz, tol, hz["T"])
        typer.echo(f"{model['source']}: system {model.get('system')}, T = {hz['T']:g}; cost: {model['cost']}")
        typer.echo(f"{'method':22s} {'order':>5s} {'C_h (e = C_h h^p)':>18s} {'us/step':>8s} {'h':>10s} {'steps':>8s} "
                   f"{'pred. error':>11s} {'pred. ms':>9s}  note")
        pick = next((r for r in rows if r["predicted_cost"] is not None), None)
        for r in rows:
            mark = "*" if r is pick else " "
            typer.echo(f"{mark}{r['method']:21s} {_g(r['order'], 'd'):>5s} {_g(r['C_h'], '.3e'):>18s} "
                       f"{_g(None if r['b'] is None else r['b'] * 1e6):>8s} {_g(r['h'], '.4g'):>10s} "
                       f"{_g(r['N'], 'd'):>8s} {_g(r['predicted_error'], '.2e'):>11s} "
                       f"{_g(None if r['predicted_cost'] is None else r['predicted_cost'] * 1e3):>9s}  {r['note']}")
        if pick is not None:
            picked = True
            typer.echo(f"pick: {pick['method']} at h = {pick['h']:.6g} ({pick['N']} steps), predicted error "
                       f"{pick['predicted_error']:.2e}, {pick['predicted_cost'] * 1e3:.3g} ms")
        else:
            typer.echo("pick: none (no method of these measurements can be predicted: they hold no "
                       "timings or no error above the reference's floor)")
    return picked


@app.command(epilog="Examples:\n\n"
             "  vcirun recommend cart_pendulum --tol 1e-6\n\n"
             "  vcirun recommend cart_pendulum --tol 1e-8 --results results/work_precision.json\n\n"
             "  vcirun recommend docs/examples/spring_pendulum.yaml --tol 1e-5 --T 3 --q0 1.2,-1.0 --p0 0,0 --pilots")
def recommend(
    system: str = typer.Argument(..., help="Built-in scene or YAML system file."),
    tol: float = typer.Option(..., "--tol", help="The L2 trajectory error to reach (absolute, in q's units)."),
    T: Optional[float] = typer.Option(None, "--T", "-T", help="Horizon (default: every stored horizon; 5 for "
                                                             "pilot runs)."),
    results: List[Path] = typer.Option([], "--results", "-r",
                                       help="Stored measurements: a study JSON, a sweep .h5, or a folder "
                                            "(repeatable; default: results/)."),
    pilots: bool = typer.Option(False, "--pilots", help="Pilot runs on the start even where measurements are "
                                                         "stored."),
    beta: Optional[float] = typer.Option(None, "--beta", "-b", help="Start of the pilot runs (the scene's map)."),
    q0: Optional[str] = typer.Option(None, "--q0", metavar="Q1,Q2,...", help="Start of the pilot runs (with --p0)."),
    p0: Optional[str] = typer.Option(None, "--p0", metavar="P1,P2,...", help="Initial momenta p = M(q) qdot."),
    param: List[str] = typer.Option([], "--param", "-p", help="Parameter override NAME=VALUE (repeatable)."),
):
    """The candidate methods for an L2 error TOL on a scene, with their predicted step, error and cost, and
    the pick: from stored work-precision measurements (a study's or a sweep's results) where they exist,
    else from pilot runs on the scene's start."""
    if not (tol > 0 and math.isfinite(tol)):
        _fail(f"--tol: must be a positive number (got {tol:g})")
    try:
        start_given = [n for n, v in (("--beta", beta), ("--q0", q0), ("--p0", p0), ("--param", param))
                       if v is not None and v != []]   # (--beta 0 is a start)
        if start_given and not pilots:   # stored measurements are of their own starts and parameters
            typer.echo(f"{', '.join(start_given)}: the start and parameters of pilot runs; stored measurements "
                       "are not used")
            pilots = True
        picked, models = False, []
        if not pilots:
            sources = list(results) or ([Path("results")] if Path("results").is_dir() else [])
            models = _stored_models(system, sources)
            for model in models:
                picked = _print_model(model, tol, T) or picked
        if picked:
            return
        if models:
            typer.echo(f"no stored measurement of {system} predicts a pick: pilot runs")
        elif results and not pilots:
            typer.echo(f"no stored measurements of {system} in {', '.join(map(str, results))}: pilot runs")
        _announce_compiles()
        import vcirun

        qv, pv = _parse_vector(q0, "--q0"), _parse_vector(p0, "--p0")
        if (qv is None) != (pv is None):
            raise CliError("initial state: give both --q0 and --p0 (or --beta)")
        try:
            tr = vcirun.simulate(system, T=5.0 if T is None else T, tol=tol, beta=beta, q0=qv, p0=pv,
                                 params=_parse_params(param) or None)
        except ValueError as e:
            raise CliError(str(e)) from None
        c = tr.choice
        typer.echo(f"pilot runs on the start of {system}, T = {tr.T:g} (CPU {c.seconds['total_cpu']:.3g} s)")
        typer.echo(c.table())
        typer.echo(f"run: {c.method} h = {c.h:.6g} ({c.N} steps), status {c.status}; {c.estimate}")
    except CliError as e:
        _fail(str(e))
    if c.status != "ok":   # (as `vcirun simulate --tol`: tol not reached is not a recommendation)
        _fail(f"--tol {tol:g} not reached ({c.status}): {c.reason.split('; ')[0]}")   # (the table gives the rest)
