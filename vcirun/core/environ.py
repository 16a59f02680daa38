"""Environment variables read on a per-call path.

`os.environ.get` of a name that is not set raises and catches a KeyError inside the mapping (about
1.4 us here), and one `vcirun.simulate` call reads several names that are usually unset (the build
mode, the kernel path, the tier, the memory limit). `getenv` looks the name up in the mapping's own
dict (CPython keeps os.environ's encoded items in `os.environ._data`, updated by every assignment to
os.environ), and falls back to `os.environ.get` where that dict is not there. The standard library
only: every layer may import this.
"""
from __future__ import annotations

import os

_DATA = getattr(os.environ, "_data", None)
_ENCODE = getattr(os.environ, "encodekey", None)   # (the mapping's own key and value codecs)
_DECODE = getattr(os.environ, "decodevalue", None)


_KEYS: dict = {}   # name -> its encoded key in _DATA; a tuple of names -> the tuple of their keys


def getenv(name: str, default=None):
    """os.environ.get(name, default), without the exception of an unset name."""
    key = _KEYS.get(name)
    if key is None:
        if not isinstance(_DATA, dict) or _ENCODE is None or _DECODE is None:
            return os.environ.get(name, default)
        key = _KEYS[name] = _ENCODE(name)
    v = _DATA.get(key)
    return default if v is None else _DECODE(v)


def snapshot(names: tuple) -> tuple:
    """The values of `names` as the environment holds them now (None where unset; the mapping's own
    encoded form where it has one), for a cache key: two snapshots of the same names are equal exactly
    when every name has the same value."""
    keys = _KEYS.get(names)
    if keys is None:
        if not isinstance(_DATA, dict) or _ENCODE is None:
            return tuple(os.environ.get(name) for name in names)
        keys = _KEYS[names] = tuple(map(_ENCODE, names))
    return tuple(map(_DATA.get, keys))


def jit_disabled() -> bool:
    """NUMBA_DISABLE_JIT=1: numba compiles nothing (every module runs as Python)."""
    return getenv("NUMBA_DISABLE_JIT", "0") not in ("", "0")
