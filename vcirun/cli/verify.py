"""`vcirun verify`: the method checks of `vcirun.verify` on a system, and their report."""
from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from .app import CliError, _console, _fail, app, check_output
from .simulate import _cli_words
from .simulate import _parse_params, _parse_vector


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
        raise CliError(_cli_words(str(e))) from None
    try:
        written = res.save(output) if output is not None else []
    except OSError as e:
        raise CliError(f"--output {e.filename or output}: cannot write the report ({e.strerror or e})") from None
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
    and energy across impacts (with friction also stick/slip mode-change times and the energy account);
    one verdict per check (pass / warn / fail, the number, the threshold)."""
    try:
        check_output(output, "--output", also=() if output is None else (output.with_suffix(".png"),),
                     example="report.md")
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
    for n in res.notes:   # what the verification did (e.g. the window of a motion that comes to rest)
        console.print(f"note  {n}", soft_wrap=True, markup=False)
    for p in written:
        typer.echo(f"wrote {p}")
    if not res.ok:
        raise typer.Exit(1)
