"""The `vcirun` application and what every command shares: the expected-failure rule (one line
`error: ...` on stderr, exit status 1; unexpected exceptions keep their traceback), the console, and
the compile announcement. Commands register on `app` in their own modules (vcirun.cli.main imports
them in the order `vcirun --help` lists them)."""
from __future__ import annotations

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

    cache.listen(_say_compile)


def _say_compile(message: str) -> bool:
    typer.echo(message, err=True)
    return True   # shown (vcirun.codegen.cache.listen)


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


def _control_flow() -> tuple:
    """The exceptions typer and click end a command with (re-raised as they are): typer's own, and
    click's where it is installed (typer >= 0.29 carries its own copy of click and needs none)."""
    import importlib

    out = [typer.Exit, typer.Abort]
    for module, names in (("click.exceptions", ("Exit", "Abort", "ClickException")),
                          ("typer._click.exceptions", ("ClickException",)), ("typer.exceptions", ("TyperException",))):
        try:
            m = importlib.import_module(module)
        except ImportError:
            continue
        out += [getattr(m, n) for n in names if isinstance(getattr(m, n, None), type)]
    return tuple(out)


def _reads_results(fn):
    """`info` and `plot`: a results file that cannot be read (damaged blocks, wrong types where the
    readers expect numbers, permissions) ends in one line naming the file, never in a traceback."""
    import functools

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except _control_flow():
            raise
        except (OSError, KeyError, ValueError, TypeError, IndexError, AttributeError, RuntimeError,
                MemoryError) as e:
            text = " ".join(str(e).split())
            _fail(f"{kwargs.get('results') or 'results'}: cannot read the results file ({type(e).__name__}: "
                  f"{text[:200]}); it may be damaged: rerun the sweep that wrote it, or move it away")
    return wrapper
