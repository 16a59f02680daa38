"""Sizes of a run before it starts: the memory its buffers take, the bytes its results take in a
file, and the limit a run (or a sweep's runs in flight) must stay under.

Both sizes are sums over the rows of the run record (`vcirun.core.record.FIELDS`) at the axis
lengths of `vcirun.core.record.axis_rows`, so a new stored field is counted by the row that declares
it. The limit: `set_memory_limit`, else `limit_memory` (a sweep config's `max_memory`, for the
calls inside the block), else the VCIRUN_MAX_MEMORY environment variable, else half the physical
memory; a run over it is refused before anything is allocated or created.

numpy only: every layer may import this.
"""
from __future__ import annotations

import contextlib
import contextvars
import functools
import math
import os
import re

from . import record
from .environ import getenv
from .values import as_real, describe

__all__ = ["run_bytes", "stored_bytes", "parse_bytes", "format_bytes", "memory_limit", "set_memory_limit",
           "limit_memory", "check_run_memory", "check_ladder_memory"]

STORED_OVERHEAD = 4096  # attributes and group structure of one run in a results file


def run_bytes(N: int, n: int, m: int = 1) -> int:
    """Bytes `vcirun.simulate` allocates for an N-step run of n coordinates and m constraints: one
    buffer per row of the run record at the lengths the loop starts with (`record.axis_rows`), and
    the time grid."""
    N, n, m = int(N), int(n), int(m)
    rows = record.axis_rows(N)
    b = 0
    for f in record.FIELDS:
        b += math.prod(f.shape(rows[f.axis], n, m)) * f.itemsize  # (math.prod: np.prod costs ~5 us a call)
    return b + 16 * (N + 1) + 128  # t and its integer arange


def stored_bytes(N: int, n: int, m: int = 1, *, store_trajectories: bool = True, impacts: int = 0,
                 partial_steps: int | None = None, releases: int = 0, mode_changes: int = 0,
                 every: int | None = None, friction: bool = True) -> int:
    """Bytes of one run's datasets in the results file (and of its result message to the client):
    every stored row of the run record ("impacts" rows always, "trajectory" rows and the times t with
    `store_trajectories`), with `impacts` impact entries, `partial_steps` partial steps (default two
    per impact), `releases` releases and `mode_changes` friction mode changes, plus the run's
    attributes. every: a sweep's `store` (1 every grid state, k every k-th and the last without the
    per-step rows, 0 none; default from store_trajectories). friction: whether the system has
    friction; without, the friction rows (record.FRICTION_ROWS) are not counted: a file stores them
    only for runs with friction data (with friction they are counted, an upper bound)."""
    N, n, m = int(N), int(n), int(m)
    impacts = int(impacts)
    every = (1 if store_trajectories else 0) if every is None else int(every)
    grid = N + 1 if every <= 1 else N // every + 1 + (1 if N % every else 0)
    rows = {"grid": grid, "step": N if every == 1 else 0, "impact": impacts,
            "partial": 2 * impacts if partial_steps is None else int(partial_steps), "release": int(releases),
            "mode": int(mode_changes)}
    b = STORED_OVERHEAD + (8 * grid if every else 0)
    for f in record.FIELDS:
        if not friction and f.name in record.FRICTION_ROWS:
            continue
        if f.stored == "impacts" or (f.stored == "trajectory" and every):
            b += math.prod(f.shape(rows[f.axis], n, m)) * f.itemsize
    return b


_UNITS = {"": 1, "b": 1, "k": 1e3, "kb": 1e3, "m": 1e6, "mb": 1e6, "g": 1e9, "gb": 1e9, "t": 1e12, "tb": 1e12,
          "kib": 2**10, "mib": 2**20, "gib": 2**30, "tib": 2**40}


def parse_bytes(value, field: str = "max_memory") -> int:
    """A byte count from a number or text such as '8 GB', '512MiB' (ValueError naming the field)."""
    x = as_real(value)
    if x is None and isinstance(value, str):
        m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*([A-Za-z]*)\s*", value)
        if m and m.group(2).lower() in _UNITS:
            x = float(m.group(1)) * _UNITS[m.group(2).lower()]
    if x is None or not math.isfinite(x) or x <= 0:
        raise ValueError(f"{field}: must be a positive size such as 8GB, 512MiB or a number of bytes "
                         f"(got {describe(value)})")
    return int(x)


def format_bytes(b: float) -> str:
    for unit, size in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if b >= size:
            v = b / size
            return f"{v:.3g} {unit}" if v < 1000 else f"{v:.0f} {unit}"
    return f"{int(b)} B"


_LIMIT: int | None = None
# a sweep's max_memory, for the runs it computes in this thread (see `limit_memory`)
_SCOPED: contextvars.ContextVar = contextvars.ContextVar("vcirun_memory_limit", default=None)


@functools.lru_cache(maxsize=1)   # (two sysconf calls per simulate otherwise; it does not change)
def _physical_memory() -> int:
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover - non-POSIX
        return 8 * 2**30


def memory_limit() -> int:
    """Bytes one run (or a sweep's runs in flight) may take: `limit_memory`'s block, else
    `set_memory_limit`, else VCIRUN_MAX_MEMORY, else half of the physical memory."""
    if _SCOPED.get() is not None:
        return _SCOPED.get()
    if _LIMIT is not None:
        return _LIMIT
    env = getenv("VCIRUN_MAX_MEMORY")
    if env:
        return parse_bytes(env, "VCIRUN_MAX_MEMORY")
    return _physical_memory() // 2


def set_memory_limit(limit) -> None:
    """Set the process-wide limit (bytes or text like '16GB'); None restores the default."""
    global _LIMIT
    _LIMIT = None if limit is None else parse_bytes(limit)


@contextlib.contextmanager
def limit_memory(limit):
    """The limit for the calls inside this block (this thread only); None: no change."""
    if limit is None:
        yield
        return
    token = _SCOPED.set(parse_bytes(limit))
    try:
        yield
    finally:
        _SCOPED.reset(token)


def check_run_memory(N: int, n: int, *, m: int = 1, copies: int = 1, extra: int = 0, limit=None, field: str = "T",
                     hint: str = "") -> int:
    """Refuse a run whose buffers (times `copies` runs at once, plus `extra` bytes) exceed the limit."""
    need = copies * run_bytes(N, n, m) + int(extra)
    lim = memory_limit() if limit is None else parse_bytes(limit)
    if need > lim:
        who = f"{copies} runs at once" if copies > 1 else "one run"
        raise ValueError(f"{field}: {N:.4g} steps of {n} coordinates need about {format_bytes(need)} for {who} "
                         f"(limit {format_bytes(lim)}); raise h or lower T"
                         + (hint or ", or raise the limit (VCIRUN_MAX_MEMORY=32GB, or max_memory in a sweep config)"))
    return need


def check_ladder_memory(hs, T: float, n: int, m: int = 1, field: str = "T") -> int:
    """Refuse a step ladder on [0, T] (`vcirun.verify`) whose largest run or whose smooth reference
    (the state at every grid point of every step, 2n + 1 numbers each) exceeds the memory limit, before
    anything runs; each step within the step cap (vcirun.core.grid.grid_steps). Returns the estimate."""
    from .grid import grid_steps

    Ns = [grid_steps(h, T)[2] for h in hs]
    run = max(run_bytes(N, n, m) for N in Ns)
    reference = 8 * (2 * n + 1) * sum(N + 1 for N in Ns)
    need, lim = run + reference, memory_limit()
    if need > lim:
        raise ValueError(f"{field}: the runs at h = {min(hs):g} on [0, {T:g}] ({max(Ns):.4g} steps of {n} coordinates) "
                         f"and the exact reference on their grids need about {format_bytes(need)} (limit "
                         f"{format_bytes(lim)}); lower T or raise the steps h, or raise the limit "
                         "(VCIRUN_MAX_MEMORY=32GB)")
    return need
