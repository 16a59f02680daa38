"""Study results as JSON: numpy scalars and arrays to plain values, non-finite floats to null and back."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

__all__ = ["to_json", "nan_for_null", "save_json", "load_json"]


def to_json(x):
    """A JSON-able copy of x: dict keys as strings, tuples and arrays as lists, numpy scalars as Python
    ones, non-finite floats as None (JSON has no nan)."""
    if isinstance(x, dict):
        return {str(k): to_json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [to_json(v) for v in x]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, np.ndarray):
        return to_json(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if np.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


def nan_for_null(x):
    """Every JSON null back to nan (so a renderer prints '-' for a number that was not finite)."""
    if isinstance(x, dict):
        return {k: nan_for_null(v) for k, v in x.items()}
    if isinstance(x, list):
        return [nan_for_null(v) for v in x]
    return float("nan") if x is None else x


def save_json(res: dict, path) -> Path:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(to_json(res), indent=1))
    return p


def load_json(path):
    return json.loads(Path(path).read_text())
