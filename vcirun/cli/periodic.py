"""`vcirun periodic`: a periodic orbit of a hybrid system (a walker's gait) and its multipliers, or
with --sweep the continuation along a parameter with period doubling and the bifurcation diagram."""
from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import numpy as np
import typer

from .app import CliError, _announce_compiles, _fail, app, check_output

EPILOG = ("Examples:\n\n"
          "  vcirun periodic --system rimless_wheel --method CVA4 --h 0.002\n\n"
          "  vcirun periodic --system compass_gait --method CVA4 --h 0.005 --param gamma=0.0524\n\n"
          "  vcirun periodic --system compass_gait --h 0.005 --sweep gamma=0.0524:0.09:40 --output bif.png")


@app.command("periodic", epilog=EPILOG)
def periodic(
    system: str = typer.Option("rimless_wheel", "--system", "-s", help="Built-in walker or a YAML system file."),
    method: str = typer.Option("CVA4", "--method", "-m", help="A collision integrator (CVA, CVA4, VCI, MCVAC, ...)."),
    h: float = typer.Option(5e-3, "--h", help="Step size."),
    param: List[str] = typer.Option([], "--param", "-p", help="Parameter override NAME=VALUE (repeatable)."),
    q0: Optional[str] = typer.Option(None, "--q0", metavar="Q1,...", help="Guess: coordinates (default: the "
                                     "scene's default state)."),
    p0: Optional[str] = typer.Option(None, "--p0", metavar="P1,...", help="Guess: momenta."),
    k: int = typer.Option(1, "--k", help="Impacts per period (2: a period-two orbit)."),
    sweep: Optional[str] = typer.Option(None, "--sweep", metavar="NAME=START:STOP:COUNT",
                                        help="Continuation along a parameter, period doubling followed."),
    output: Optional[Path] = typer.Option(None, "--output", "-o",
                                          help="With --sweep: the bifurcation diagram (.png) and its data (.json)."),
    solver: str = typer.Option("newton", "--solver", help="newton, or iterate: the stable gait as simulated "
                                                          "(VCI, whose stride map jumps by O(h^2))."),
    jacobian: Optional[str] = typer.Option(None, "--jacobian", help="envelope (the default with --solver iterate): "
                                           "the derivative of the map's smooth envelope, fitted with a model of VCI's "
                                           "sawtooth in the impact phase (VCI's multipliers at order 2); or fd "
                                           "(finite differences; the default with --solver newton)."),
):
    """Find a periodic orbit (Newton on the method's return map) and print its fixed point, period and
    multipliers; with --sweep, continue it along a parameter."""
    _announce_compiles()
    try:
        if k < 1:
            raise ValueError(f"--k: must be a positive integer, the impacts per period (got {k})")
        if not (np.isfinite(h) and h > 0):
            raise ValueError(f"--h: must be a positive finite step (got {h:g})")
        if output is not None and sweep is None:
            raise ValueError("--output: writes the bifurcation diagram of --sweep; add --sweep or drop --output")
        if output is not None:
            check_output(output.with_suffix(".png"), "--output", also=(output.with_suffix(".json"),),
                         example="bifurcation.png")
        if sweep is not None:
            name, values = _sweep(sweep)   # before anything is computed
        params = _parse_params(param)
        guess = _guess(system, params, _vector(q0, "--q0"), _vector(p0, "--p0"))
        if sweep is None:
            from vcirun.experiments.periodic import periodic_orbit

            o = periodic_orbit(system, method, h=h, guess=guess, params=params or None, k=k, solver=solver,
                               jacobian=jacobian)
            q, p = o.fixed_point
            typer.echo(f"fixed point q = {np.array2string(q, precision=12)}, p = {np.array2string(p, precision=12)}")
            typer.echo(f"period {o.period:.12g} s ({o.k} impact{'s' if o.k > 1 else ''}), residual {o.residual:.2e}, "
                       f"{o.iterations} {'Newton steps' if solver == 'newton' else 'returns'}")
            typer.echo("multipliers " + ", ".join(f"{z.real:.10g}{z.imag:+.3g}j" if abs(z.imag) > 0 else f"{z.real:.10g}"
                                                  for z in o.eigenvalues) + ("  (stable)" if o.stable else "  (unstable)")
                       + f"  [jacobian {o.jacobian_kind}]")
            return
        from vcirun.experiments.bifurcation import bifurcation_figure, continuation

        if jacobian not in (None, "fd"):
            raise ValueError("--jacobian: continuation (--sweep) uses the finite-difference Jacobian; drop --jacobian")
        if solver != "newton":
            raise ValueError("--solver: continuation (--sweep) uses Newton; drop --solver iterate or --sweep")
        br = continuation(system, method, h=h, param=name, values=values, guess=guess, params=params or None)
        for v, o in zip(br.values, br.orbits):
            typer.echo(f"{name} = {v:.6g}: period-{o.k}, q = {np.array2string(o.fixed_point[0], precision=6)}, "
                       f"max |multiplier| {np.max(np.abs(o.eigenvalues)):.4f}")
        typer.echo(f"period doubling at {name} = {br.doubling:.9g}" if br.doubling is not None
                   else "no period doubling in the range")
        if output is not None:
            try:
                output.parent.mkdir(parents=True, exist_ok=True)
                bifurcation_figure(br, output.with_suffix(".png"))
                br.save(output.with_suffix(".json"))
            except OSError as e:
                raise CliError(f"--output {e.filename or output}: cannot write ({e.strerror or e})") from None
            typer.echo(f"saved {output.with_suffix('.png')} and {output.with_suffix('.json')}")
    except (ValueError, RuntimeError, CliError) as e:
        _fail(str(e))


def _parse_params(items) -> dict:
    out = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        try:
            if not sep or not name.strip():
                raise ValueError
            out[name.strip()] = float(value)
        except ValueError:
            raise ValueError(f"--param: expected NAME=VALUE with a number (got {item!r})") from None
    return out


def _vector(text, name):
    if text is None:
        return None
    try:
        return [float(x) for x in str(text).replace(" ", "").split(",") if x != ""]
    except ValueError:
        raise ValueError(f"{name}: expected comma-separated numbers such as 1.2,-1.0 (got {text!r})") from None


def _guess(system, params, q0, p0):
    if (q0 is None) != (p0 is None):
        raise ValueError("--q0/--p0: give both or neither")
    if q0 is not None:
        return (np.array(q0), np.array(p0))
    from vcirun.experiments.periodic import default_guess

    try:
        return default_guess(system, params)
    except ValueError as e:
        if not str(e).startswith("guess:"):
            raise   # (a parameter's error names its field)
        raise ValueError(f"--q0/--p0: {str(e).partition(': ')[2]}") from None


def _sweep(text: str):
    name, sep, rng = text.partition("=")
    parts = rng.split(":")
    try:
        if not sep or len(parts) != 3:
            raise ValueError
        a, b, n = float(parts[0]), float(parts[1]), int(parts[2])
    except ValueError:
        raise ValueError(f"--sweep: expected NAME=START:STOP:COUNT (got {text!r})") from None
    if not (np.isfinite(a) and np.isfinite(b)):
        raise ValueError(f"--sweep: START and STOP must be finite numbers (got {text!r})")
    if not 2 <= n <= MAX_SWEEP_VALUES:
        raise ValueError(f"--sweep: COUNT must be from 2 to {MAX_SWEEP_VALUES:,} (got {n}); each value is a Newton "
                         "solve of the return map")
    return name.strip(), np.linspace(a, b, n)


MAX_SWEEP_VALUES = 10_000
