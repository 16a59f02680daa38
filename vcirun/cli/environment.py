"""The environment variables vcirun and numba read, checked before a command starts: a bad value is one
`error:` line naming the variable and what to write, not a traceback in the middle of a run (or, for
numba's own variables, a warning with numba's traceback and a run that goes on with a default).

Each check reads the variable the way the code that uses it does; `check_environment` returns the
first problem (or None) and costs nothing unless a variable is set (numba is imported only when a
NUMBA_ variable is).
"""
from __future__ import annotations

import math
import os
import warnings

__all__ = ["check_environment"]


def _number(name: str, text: str, *, ge: float = 0.0, integer: bool = False, what: str = "a number") -> str | None:
    try:
        v = float(text) if not integer else int(text.strip())
    except ValueError:
        return f"{name}: must be {what} (got {text!r})"
    if not math.isfinite(v) or v < ge:
        return f"{name}: must be {what} (got {text!r})"
    return None


def _choice(name: str, text: str, choices, default_empty: bool = True) -> str | None:
    v = text.strip().lower()
    if (default_empty and not v) or v in choices:
        return None
    return f"{name}: {text!r} is not a choice (use {' or '.join(choices)}, or unset it)"


def _vcirun(env) -> str | None:
    if "VCIRUN_COMMIT_INTERVAL" in env:
        p = _number("VCIRUN_COMMIT_INTERVAL", env["VCIRUN_COMMIT_INTERVAL"],
                    what="a number of seconds >= 0, e.g. 1")
        if p:
            return p
    if "VCIRUN_MAX_MEMORY" in env and env["VCIRUN_MAX_MEMORY"]:
        from ..core.sizes import parse_bytes

        try:
            parse_bytes(env["VCIRUN_MAX_MEMORY"], "VCIRUN_MAX_MEMORY")
        except ValueError as e:
            return str(e)
    if "VCIRUN_TIER" in env:
        p = _choice("VCIRUN_TIER", env["VCIRUN_TIER"], ("auto", "interpreted", "compiled"))
        if p:
            return p
    if "VCIRUN_BUILD" in env:
        p = _choice("VCIRUN_BUILD", env["VCIRUN_BUILD"], ("auto", "shared", "specialized"))
        if p:
            return p
    if "VCIRUN_CORE_NDOF" in env:
        p = _choice("VCIRUN_CORE_NDOF", env["VCIRUN_CORE_NDOF"], ("runtime", "fixed"))
        if p:
            return p
    if "VCIRUN_KERNEL_BACKEND" in env:
        p = _choice("VCIRUN_KERNEL_BACKEND", env["VCIRUN_KERNEL_BACKEND"], ("c", "numba"))
        if p:
            return p
    if "VCIRUN_KERNEL_PATH" in env and env["VCIRUN_KERNEL_PATH"]:
        p = _choice("VCIRUN_KERNEL_PATH", env["VCIRUN_KERNEL_PATH"], ("tensor", "expanded"))
        if p:
            return p
    if env.get("VCIRUN_C_MIN_STATEMENTS", "").strip():
        p = _number("VCIRUN_C_MIN_STATEMENTS", env["VCIRUN_C_MIN_STATEMENTS"], integer=True,
                    what="a whole number of statements >= 0")
        if p:
            return p
    if "VCIRUN_CACHE_DIR" in env and not env["VCIRUN_CACHE_DIR"].strip():
        return ("VCIRUN_CACHE_DIR: is set but empty; unset it (the kernel cache is then ~/.cache/vcirun) or set it "
                "to a directory")
    return None


def _numba(env) -> str | None:
    """numba's variables: those numba cannot parse (it warns with a traceback and uses its default),
    and NUMBA_NUM_THREADS below 1 (numba raises when its threading layer starts)."""
    if "NUMBA_NUM_THREADS" in env:
        p = _number("NUMBA_NUM_THREADS", env["NUMBA_NUM_THREADS"], ge=1, integer=True,
                    what="a whole number of threads >= 1")
        if p:
            return p
    if "NUMBA_OPT" in env:
        v = env["NUMBA_OPT"].strip().lower()
        if v not in ("0", "1", "2", "3", "max"):
            return f"NUMBA_OPT: {env['NUMBA_OPT']!r} is not an optimisation level (use 0, 1, 2, 3 or max, or unset it)"
    import sys

    if "numba" in sys.modules:   # its configuration was read already (and said what it could not parse)
        return None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        import numba.core.config  # noqa: F401 - reads every NUMBA_ variable
    for w in caught:
        text = str(w.message)
        if "could not be parsed" in text:
            first = text.splitlines()[0]
            name = first.split("'")[1] if first.count("'") >= 2 else "a NUMBA_ variable"
            return (f"{name}: numba cannot read its value {env.get(name, '')!r}; unset it or give a value numba "
                    "documents (https://numba.readthedocs.io/en/stable/reference/envvars.html)")
    return None


def check_environment(env=None) -> str | None:
    """The first problem with the environment variables vcirun or numba read, or None."""
    env = os.environ if env is None else env
    problem = _vcirun(env)
    if problem is None and any(k.startswith("NUMBA_") for k in env):
        problem = _numba(env)
    return problem
