"""`vcirun cache info` and `vcirun cache clear`: the kernel cache."""
from __future__ import annotations

import typer

from .app import _fail, app


cache_app = typer.Typer(help="The kernel cache every vcirun command and `make` share ($VCIRUN_CACHE_DIR, "
                             "default ~/.cache/vcirun).", no_args_is_help=True)
app.add_typer(cache_app, name="cache")


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


SHOWN = 40   # scene/kernel-set names listed by `cache info` without --all


def ready_text(compiled, all_names: bool = False) -> str:
    """The line of compiled modules: each scene/kernel-set name once, with how many modules it has (one per
    build mode, kernel path and vcirun or numba version), the first SHOWN names unless all_names."""
    from collections import Counter

    count = Counter(compiled)
    names = [f"{k} (x{v})" if v > 1 else k for k, v in sorted(count.items())]
    more = len(names) - SHOWN if not all_names and len(names) > SHOWN else 0
    text = (f"compiled tier ready for {len(compiled)} module(s) of {len(count)} scene/kernel set(s): "
            + ", ".join(names[: len(names) - more]))
    return text + (f", ... and {more} more (--all lists them)" if more else "")


@cache_app.command("info", epilog="Example:\n\n  vcirun cache info\n\n  vcirun cache info --all")
def cache_info(all_names: bool = typer.Option(False, "--all", help="List every compiled scene/kernel set.")):
    """Where the compiled kernels are, how much space they take, what is compiled and what is being
    compiled (in the background or by another run)."""
    from vcirun.codegen import cache
    from vcirun.codegen.cache_store import CacheError

    try:
        i = cache.info()
    except CacheError as e:
        _fail(str(e))
    typer.echo(f"{i.path}: {i.modules} compiled modules, {i.cores} shared cores, {i.index_entries} warm-start entries, "
               f"{i.files} files, {_mb(i.bytes)} (of these {i.shared_objects} C kernel libraries, {i.numba_files} numba "
               f"files" + (f", {i.quarantined} files set aside by a failed check" if i.quarantined else "") + ")")
    if i.compiled:
        typer.echo(ready_text(i.compiled, all_names))
    import time

    for what, who in i.building:
        since = who.get("since")
        took = f" for {time.time() - since:.0f} s" if isinstance(since, (int, float)) else ""
        typer.echo(f"being compiled: {what} (process {who.get('pid', '?')}{took})")
    for system, reason, log in i.failed:
        typer.echo(f"background compile failed: {system}: {reason} (log {log}; runs stay interpreted; "
                   "`vcirun cache clear` or --tier compiled tries again)")
    typer.echo("It grows with every vcirun version and system; `vcirun cache clear` empties it (the next run of "
               "each system compiles again).")


@cache_app.command("clear", epilog="Example:\n\n  vcirun cache clear")
def cache_clear():
    """Delete every cached kernel (exit status 1 if some file could not be removed)."""
    from vcirun.codegen import cache
    from vcirun.codegen.cache_store import CacheError

    try:
        r = cache.clear()
    except CacheError as e:
        _fail(str(e))
    i = r.before
    if r.failed:
        p, why = r.failed[0]
        _fail(f"kernel cache {i.path}: could not remove {len(r.failed)} of {len(r.failed) + r.removed_files} files "
              f"({p}: {why}); removed {r.removed_files} files ({_mb(r.removed_bytes)}); make {p.parent} writable "
              f"and run `vcirun cache clear` again")
    typer.echo(f"removed {i.modules} compiled modules, {i.cores} shared cores and {r.removed_files} files in all "
               f"({_mb(r.removed_bytes)}) from {i.path}")
