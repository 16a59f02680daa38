"""`vcirun systems`: the built-in scenes, their coordinates, parameters, constraints and starts."""
from __future__ import annotations

from typing import Optional

import typer

from .app import _console, _fail, app


@app.command(epilog="Examples:\n\n  vcirun systems\n\n  vcirun systems cart_pendulum")
def systems(name: Optional[str] = typer.Argument(None, help="One scene (default: all).", show_default=False)):
    """The built-in scenes: coordinates, parameters (default, unit, meaning), constraints and initial
    states. The sized scenes (n_pendulum_K, newton_cradle_K, link_chain_K, cradle_K) run with K in
    their range (`vcirun systems cradle_3` says it); YAML files declare your own."""
    from vcirun.scenes.registry import describe, listed_scenes

    console = _console()
    for nm in [name] if name else listed_scenes():
        try:
            lines = describe(nm)
        except ValueError as e:
            _fail(str(e))
        console.print(f"[bold]{nm}[/bold]", end="")
        for text in [lines[0][len(nm):]] + lines[1:]:  # unit brackets such as [m] are text, not rich markup
            console.print(text, soft_wrap=True, markup=False)
    typer.echo("Energies in J, times in s; options --param NAME=VALUE override parameters.")
