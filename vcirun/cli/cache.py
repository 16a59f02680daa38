"""`vcirun cache info` and `vcirun cache clear`: the kernel cache."""
from __future__ import annotations

import typer

from .app import app


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
