"""The `vcirun` application and what every command shares: the expected-failure rule (one line
`error: ...` on stderr, exit status 1; unexpected exceptions keep their traceback), the console, and
the compile announcement. Commands register on `app` in their own modules (vcirun.cli.main imports
them in the order `vcirun --help` lists them)."""
from __future__ import annotations

import errno

import typer


class _App(typer.Typer):
    """The Typer app whose every failure ends in one `error:` line: a bad option value or an unknown
    option (click's usage errors, otherwise a framed block), and standard output that cannot be
    written (`vcirun info x.h5 > /dev/full`, a closed pipe), which comes from the console's writes
    wherever they are."""

    def __call__(self, *args, **kwargs):
        import sys

        kwargs.setdefault("standalone_mode", False)
        try:
            code = super().__call__(*args, **kwargs)
        except OSError as e:
            if getattr(e, "filename", None) is not None or e.errno not in _STREAM_ERRNOS:
                raise
            _stdout_failed(e)
        except _click_errors() as e:
            where = getattr(getattr(e, "ctx", None), "command_path", None) or "vcirun"
            if type(e).__name__ == "Abort":
                _fail("aborted", 1)
            text = e.format_message() if hasattr(e, "format_message") else str(e)
            if not text.strip():   # `vcirun` alone: the help was printed (no_args_is_help)
                sys.exit(getattr(e, "exit_code", 2))
            hint = f" (`{where} --help` lists the options)" if getattr(e, "exit_code", 1) == 2 else ""
            typer.echo(f"error: {' '.join(text.split())}{hint}", err=True)
            sys.exit(getattr(e, "exit_code", 1))
        sys.exit(code if isinstance(code, int) else 0)


_STREAM_ERRNOS = {errno.ENOSPC, errno.EPIPE, errno.EIO, errno.EDQUOT, errno.EFBIG, errno.EBADF, errno.ECONNRESET}


def _stdout_failed(e: OSError):
    """One line on stderr, then standard output pointed at /dev/null, so that the interpreter's last
    flush of what could not be written raises nothing more."""
    import os
    import sys

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass
    try:
        sys.stderr.write(f"error: cannot write the output ({os.strerror(e.errno)}); nothing more was written\n")
        sys.stderr.flush()
    except (OSError, ValueError):
        pass
    raise SystemExit(1)


app = _App(
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
    from .environment import check_environment

    problem = check_environment()
    if problem:
        _fail(problem)


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


def _click_errors() -> tuple:
    """click's exceptions for usage errors and aborts (typer's own copy of click, and click's where
    it is installed)."""
    import importlib

    out = []
    for module in ("click.exceptions", "typer._click.exceptions"):
        try:
            m = importlib.import_module(module)
        except ImportError:
            continue
        out += [getattr(m, n) for n in ("ClickException", "Abort") if isinstance(getattr(m, n, None), type)]
    return tuple(out)


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
        from vcirun.io.single import not_read_back

        why = not_read_back(kwargs["results"]) if kwargs.get("results") is not None else None
        if why:
            _fail(why)
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


def check_output(path, option: str = "--output", suffixes=None, also=(), example: str = "out") -> None:
    """An output file the command will write, checked before anything is computed (CliError naming the
    option): not a directory, a device or a FIFO; a known suffix when `suffixes` is given; its folder
    an existing writable directory or one that can be created (the nearest existing ancestor is a
    writable directory). `also`: the other files written beside it (e.g. a figure's .png)."""
    import os
    from pathlib import Path

    if path is None:
        return
    text = str(path)
    if "\x00" in text or not text.strip():
        raise CliError(f"{option}: {text!r} is not a file path")
    p = Path(text)
    if p.is_dir():
        raise CliError(f"{option} {p}: is a directory; give a file path such as {p / example}")
    if suffixes is not None and p.suffix.lower() not in suffixes:
        raise CliError(f"{option} {p}: unknown format {p.suffix or '(no suffix)'!r}; use "
                       f"{', '.join(suffixes)}")
    for q in (p, *also):
        q = Path(q)
        try:
            if q.is_dir():
                raise CliError(f"{option} {q}: is a directory; give a file path such as {q / example}")
            if q.exists() and not q.is_file():
                raise CliError(f"{option} {q}: not a regular file (a device, FIFO or socket); choose another path")
            if q.exists() and not os.access(q, os.W_OK):
                raise CliError(f"{option} {q}: exists and cannot be written; choose another path")
            parent = q.parent
            while not parent.exists() and parent != parent.parent:
                parent = parent.parent
        except OSError as e:   # a name too long, a component without permission, a symlink loop
            raise CliError(f"{option} {q}: cannot use this path ({e.strerror or type(e).__name__})") from None
        if not parent.is_dir():
            raise CliError(f"{option} {q}: {parent} is a file, not a directory; choose another path")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise CliError(f"{option} {q}: cannot write in {parent}; choose another path")
