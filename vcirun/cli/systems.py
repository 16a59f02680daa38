"""`vcirun systems`: the built-in scenes, their coordinates, parameters, constraints and starts."""
from __future__ import annotations

from typing import Optional

import typer

from .app import _console, _fail, app


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
