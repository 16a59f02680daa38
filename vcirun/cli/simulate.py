"""`vcirun simulate`: one run through `vcirun.simulate` and a summary of it."""
from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import numpy as np
import typer

from ..run.accounts import FORCING, LAW
from ..run.energy import energy_drift
from .app import CliError, _announce_compiles, _console, _fail, app, check_output


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


# the Python API's words for what this command spells as flags (messages come from vcirun.simulate)
_API_WORDS = (("drop constrained=False", "drop --unconstrained"), ("pass constrained=False", "pass --unconstrained"),
              ("constrained: ", "--unconstrained: "), ("max_time: only with tol=", "--max-time: only with --tol"),
              ("max_time = ", "--max-time "), ("tol= ", "--tol "), ("tol=:", "--tol:"),
              ("needs q0 and p0 (or beta)", "needs --q0 and --p0 (or --beta)"),
              ("give both q0 and p0 (or beta)", "give both --q0 and --p0 (or --beta)"))


def _cli_words(msg: str) -> str:
    for api, flag in _API_WORDS:
        msg = msg.replace(api, flag)
    return msg


def simulate_once(system: str, method: str | None, *, h: float | None, T: float, beta: float | None = None, ld=None,
                  mh_order=None, flow_order=None, params: dict | None = None, constrained: bool | None = None,
                  newton_tol=None, event_tol=None, q0=None, p0=None, qdot0=None, tier=None, tol=None,
                  max_time=None):
    """One run through `vcirun.simulate`; bad input becomes CliError. Returns (trajectory, seconds);
    `traj.built` is the kernel cache's report of the call (vcirun.codegen.kernel_cache.BuildReport)."""
    import time
    import warnings

    import vcirun
    from vcirun.core.grid import GridWarning
    from vcirun.codegen.kernel_cache import default

    kw = {k: v for k, v in dict(ld=ld, mh_order=mh_order, flow_order=flow_order, params=params or None,
                                constrained=constrained, newton_tol=newton_tol, event_tol=event_tol, tol=tol,
                                max_time=max_time).items()
          if v is not None}
    if tol is None:   # without --tol: the command's defaults
        method = "CVA" if method is None else method
        h = 1e-2 if h is None else h
    if p0 is not None and qdot0 is not None:
        raise CliError("initial state: give --p0 or --qdot0, not both")
    if qdot0 is not None:
        if q0 is None:
            raise CliError("initial state: --qdot0 needs --q0")
        p0 = _momenta(system, q0, qdot0, params)
    if (q0 is None) != (p0 is None):
        raise CliError("initial state: give both --q0 and --p0 (or --qdot0, or --beta)")
    if q0 is not None:
        if beta is not None:
            raise CliError("initial state: give either --beta or --q0/--p0, not both")
        kw.update(q0=q0, p0=p0)
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings(record=True) as notes, default().report() as built:
            warnings.simplefilter("always", GridWarning)
            traj = vcirun.simulate(system, method, h=h, T=T, beta=beta, tier=tier, **kw)
    except ValueError as e:
        raise CliError(_cli_words(str(e))) from None
    for w in notes:
        typer.echo(f"note: {w.message}", err=True)
    from vcirun.scenes.registry import scene_args

    args = scene_args(system) if isinstance(system, str) else None
    if args is not None and args[1] == () and traj.system != system:
        typer.echo(f"note: {system} is {traj.system} (its default size; {args[0]}_K for K of your choice)", err=True)
    traj.built = built
    return traj, time.perf_counter() - t0


def energy_rows(traj) -> list[tuple[str, str]]:
    """The energy account of a run as summary rows: the impact law's loss and the forcing work (where
    the run has them) and the rest, the integration error, as the energy error."""
    try:
        acc = traj.energy_account()
    except ValueError:   # no dynamics: the drift of H alone
        drift = energy_drift(traj)
        return [] if drift.dH is None else [("max |H - H0|", f"{drift.dH:.3e}")]
    if not np.isfinite(acc.error):
        return []
    rows = []
    short = {LAW: f"restitution and plastic losses of {len(acc.events)} impacts", FORCING: "work of the force f"}
    terms = [x for x in acc.terms if x.total != 0.0 or x.name != LAW]
    label = "max |H - H0|" if not terms else "max |H - H0 - terms|"
    if terms:
        rows.append(("energy change", f"{acc.change:.4e}  (H0 = {acc.H0:.6g}, H(T) = {acc.H0 + acc.change:.6g})"))
        rows += [(x.name, f"{x.total:.4e}  ({short.get(x.name, x.doc)})") for x in terms]
    rel = (f" (relative {acc.relative_error:.2e} to the energy scale {acc.scale:.4g} = max(|H0|, max kinetic "
           "energy))" if np.isfinite(acc.relative_error) else "")
    rows.append(("energy error", f"{label} {acc.error:.3e}{rel}"))
    drift = energy_drift(traj)
    if drift.dHmod is not None and not terms:
        rows.append(("max |Hmod - Hmod0|", f"{drift.dHmod:.3e}"))
    return rows


def _momenta(system, q0, qdot0, params):
    """p0 = M(q0) qdot0 from the system's compiled mass matrix (the same M the run uses)."""
    from vcirun.codegen.kernel_set import SYSTEM_KERNELS
    from vcirun.run.resolve import resolve_numeric

    try:
        sysd, load, _ = resolve_numeric(system, SYSTEM_KERNELS)
        prm = np.ascontiguousarray(sysd.param_values(params or None), float)
    except ValueError as e:
        raise CliError(str(e)) from None
    for name, v in (("--q0", q0), ("--qdot0", qdot0)):
        if len(v) != sysd.n:
            raise CliError(f"{name}: {sysd.n} numbers for system {sysd.name} (got {len(v)})")
    A = np.empty((sysd.n, sysd.n))
    load().sys_M(np.ascontiguousarray(q0, float), prm, A)
    return (A @ np.asarray(qdot0, float)).tolist()


def summary_lines(traj, total_seconds: float, tier=None) -> list[tuple[str, str]]:
    """The facts `vcirun simulate` prints about a run."""
    rows = [("run", f"{traj.system}  {traj.method}  h = {traj.h:g}  T = {traj.T:g}"
             + (f"  beta = {traj.beta:g}" if traj.beta is not None else ""))]
    rows.append(("steps", f"{traj.n_steps}"))
    imp = ", ".join(f"{t:.4g}" for t in traj.impacts[:8]) + (" ..." if len(traj.impacts) > 8 else "")
    rows.append(("impacts", f"{len(traj.impacts)}" + (f" at t = {imp}" if len(traj.impacts) else "")))
    if len(traj.mode_changes):   # friction: stick/slip transitions of held contacts (located events)
        kinds = np.bincount(np.asarray(traj.mode_change_kind, int), minlength=4)
        mc = ", ".join(f"{t:.4g}" for t in traj.mode_changes[:8]) + (" ..." if len(traj.mode_changes) > 8 else "")
        rows.append(("mode changes", (f"{len(traj.mode_changes)} at t = {mc} ({kinds[1]} slip -> stick, "
                                      f"{kinds[2]} stick -> slip, {kinds[3]} slip reversed)")))
    rows.append(("status", traj.status + (f" ({traj.message})" if traj.message else "")))
    rows += energy_rows(traj)
    setup = max(0.0, total_seconds - traj.wall_time)
    rows.append(("wall time", f"{traj.wall_time:.4g} s integrating{_on_tier(traj)}; {total_seconds:.3g} s in "
                              f"total, of which {setup:.3g} s {_setup_words(traj, tier)}"))
    return rows


def _on_tier(traj) -> str:
    return " on the interpreted tier" if getattr(traj, "tier", None) == "interpreted" else ""


def _setup_words(traj, tier=None) -> str:
    """What the time before the integration went to, from the call's build report (tier: the tier the
    call asked for, None for $VCIRUN_TIER or auto)."""
    built = getattr(traj, "built", None)
    if built is not None and built.unsaved:
        return (f"compiling kernels (not cached: {built.unsaved[0][1][:120]}; the next run compiles them "
                "again)")
    if built is not None and built.compiled:
        return "compiling kernels (cached for the next runs)"
    if getattr(traj, "tier", None) == "interpreted":
        from vcirun.codegen.tiers import requested

        if requested(tier) == "interpreted":   # asked for: no compiled tier is being built
            return "deriving kernels and setting up (the interpreted tier, as asked)"
        return "deriving kernels and setting up (the compiled tier is built in the background)"
    return "loading kernels and setting up"


@app.command(epilog="Examples:\n\n"
             "  vcirun simulate\n\n"
             "  vcirun simulate --system cart_pendulum --method MCVAA --h 0.01 --T 5 --beta 3.2\n\n"
             "  vcirun simulate --method MCVA --ld SVC --mh-order 3 --flow-order 4\n\n"
             "  vcirun simulate --system double_pendulum --method CVA --unconstrained\n\n"
             "  vcirun simulate --system double_pendulum --q0 -1.2,-1.0 --p0 0,0 --output run.h5\n\n"
             "  vcirun simulate --system cart_pendulum --beta 4.2 --tol 1e-6\n\n"
             "  vcirun simulate incline --T 2               (the system as an argument, as --system)")
def simulate(
    scene: Optional[str] = typer.Argument(None, help="The system, as --system (give one of the two).",
                                          show_default=False),
    system: Optional[str] = typer.Option(None, "--system", "-s",
                                         help="Built-in scene (cart_pendulum, double_pendulum, oscillator_wall, "
                                              "...) or a YAML system file (default cart_pendulum)."),
    method: Optional[str] = typer.Option(None, "--method", "-m",
                                         help="CVA (default), VCI, MCVAA, MCVAC, MCVA (with --ld, --mh-order), "
                                              "or a discrete Lagrangian (SE1 SE2 SVA SVB SVC midpoint) ignoring "
                                              "the constraint; with --tol: the only candidate."),
    h: Optional[float] = typer.Option(None, "--h", help="Step size (default 1e-2); with --tol: the largest "
                                                        "step allowed."),
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
    tol: Optional[float] = typer.Option(None, "--tol",
                                        help="An L2 trajectory error to reach: method (unless --method) and h "
                                             "chosen by pilot runs (docs/tolerance.md); prints the candidates "
                                             "and the run's error estimate."),
    max_time: Optional[float] = typer.Option(None, "--max-time", help="With --tol: a budget in seconds for the "
                                                                       "final run."),
    qdot0: Optional[str] = typer.Option(None, "--qdot0", metavar="V1,V2,...",
                                        help="Initial velocities (with --q0, instead of --p0)."),
    output: Optional[Path] = typer.Option(None, "--output", "-o",
                                          help="Save the trajectory: .h5 (read with "
                                               "vcirun.run.trajectory.read_trajectory), .nc, .csv or .npz."),
    tier: Optional[str] = typer.Option(None, "--tier",
                                       help="auto (default; VCIRUN_TIER): compiled kernels when cached, else "
                                            "interpreted at once while they compile in the background; "
                                            "compiled: wait for the compiler; interpreted: never compile."),
):
    """Simulate one run and print a summary (steps, impacts, status, energy error, wall time)."""
    _announce_compiles()
    try:
        if scene is not None and system is not None and scene != system:
            raise CliError(f"SYSTEM {scene!r} and --system {system!r} name two systems: give one")
        for flag, v in (("SYSTEM", scene), ("--system", system)):
            if v is not None and not v.strip():
                raise CliError(f"{flag}: empty; name a built-in scene (vcirun systems) or a YAML file")
        system = scene or system or "cart_pendulum"
        check_output(output, "--output", (".h5", ".hdf5", ".nc", ".csv", ".npz"), example="run.h5")
        traj, total = simulate_once(system, method, h=h, T=T, beta=beta, ld=ld, mh_order=mh_order,
                                    flow_order=flow_order, params=_parse_params(param),
                                    constrained=False if unconstrained else None, newton_tol=newton_tol,
                                    event_tol=event_tol, q0=_parse_vector(q0, "--q0"), p0=_parse_vector(p0, "--p0"),
                                    qdot0=_parse_vector(qdot0, "--qdot0"), tier=tier, tol=tol, max_time=max_time)
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
    for k, v in summary_lines(traj, total, tier):
        t.add_row(k, v)
    _console().print(t)
    if traj.choice is not None:   # --tol: the candidates, the pick and the run's error estimate
        typer.echo(traj.choice.table())
        typer.echo(str(traj.choice.estimate))
    if output is not None:
        typer.echo(f"saved {output}")
    if traj.status != "ok":
        _fail(f"run ended with status {traj.status}: {traj.message}")
    if traj.choice is not None and traj.choice.status != "ok":
        # (the reason's first clause: the table above gives the rest, each candidate's status included)
        _fail(f"--tol {tol:g} not reached ({traj.choice.status}): {traj.choice.reason.split('; ')[0]}")
