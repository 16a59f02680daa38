"""Checks of single input values: numbers, flags and state vectors, with one-line errors in the
phrasing of the config layer (``h: must be > 0 (got 0)``), and `describe`, a repr that stays short
whatever the value.

numpy only: every layer may import this.
"""
from __future__ import annotations

import math
import numbers
import reprlib

import numpy as np

__all__ = ["describe", "as_real", "check_number", "check_bool", "check_state_vector"]

_repr = reprlib.Repr()
_repr.maxstring = 40
_repr.maxother = 40
_repr.maxlist = _repr.maxtuple = _repr.maxdict = 4
_repr.maxlevel = 2


def describe(value) -> str:
    """A short repr, bounded whatever the value (never builds the repr of a huge structure)."""
    try:
        s = _repr.repr(value)
    except Exception:  # noqa: BLE001 - a hostile __repr__
        s = f"<{type(value).__name__}>"
    return s if len(s) <= 60 else s[:57] + "..."


def as_real(value):
    """float of a real scalar (Python or numpy number, 0-d array), else None. bool is not a number."""
    if type(value) is float:   # (the common case, before the abstract-class checks)
        return value
    if isinstance(value, (bool, np.bool_)):
        return None
    if isinstance(value, np.ndarray):
        if value.ndim != 0 or value.dtype.kind not in "iuf":
            return None
        value = value[()]
    if isinstance(value, numbers.Real):
        try:
            return float(value)
        except (OverflowError, ValueError, TypeError):
            return math.inf if value > 0 else -math.inf
    return None


def check_number(field: str, value, *, gt=None, ge=None, lt=None, le=None, integer: bool = False):
    """`value` as a float (or int with `integer`) within the bounds; ValueError '<field>: must be ...'."""
    x = as_real(value)
    if integer:
        if x is None or not math.isfinite(x) or x != math.floor(x):
            raise ValueError(f"{field}: must be an integer (got {describe(value)})")
        x = int(x)
    elif x is None or not math.isfinite(x):
        raise ValueError(f"{field}: must be a finite number (got {describe(value)})")
    # (plain comparisons: this runs several times per simulate call)
    if gt is not None and not x > gt:
        _out_of_bounds(field, ">", gt, value)
    if ge is not None and not x >= ge:
        _out_of_bounds(field, ">=", ge, value)
    if lt is not None and not x < lt:
        _out_of_bounds(field, "<", lt, value)
    if le is not None and not x <= le:
        _out_of_bounds(field, "<=", le, value)
    return x


def _out_of_bounds(field: str, op: str, bound, value):
    raise ValueError(f"{field}: must be {op} {bound:g} (got {describe(value)})")


def check_bool(field: str, value, *, allow_none: bool = False):
    if value is None and allow_none:
        return None
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise ValueError(f"{field}: must be true or false (got {describe(value)})")


def check_state_vector(field: str, value, n: int | None = None) -> np.ndarray:
    """A flat vector of finite numbers (a scalar counts as length 1)."""
    if isinstance(value, (str, bytes, dict)) or value is None:
        raise ValueError(f"{field}: must be a list of finite numbers (got {describe(value)})")
    try:
        a = np.asarray(value)
    except Exception:  # noqa: BLE001 - ragged lists and odd objects
        raise ValueError(f"{field}: must be a list of finite numbers (got {describe(value)})") from None
    if a.dtype.kind == "b" or a.dtype.kind not in "iuf" or a.ndim > 1:
        raise ValueError(f"{field}: must be a flat list of finite numbers (got {describe(value)})")
    a = a.astype(float).ravel()
    if a.size == 0 or not np.all(np.isfinite(a)):
        raise ValueError(f"{field}: must be a list of finite numbers (got {describe(value)})")
    if n is not None and a.size != n:
        raise ValueError(f"{field}: must have length {n} (got {a.size})")
    return a
