"""The record of one simulation run (the `Trajectory` returned by `vcirun.simulate`)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import record

# Status strings a run can end with (codes and meanings: vcirun.record.STATUSES). Failures are data:
# they carry the step, time and state.
OK, NEWTON_FAILED, EVENT_FAILED, RESET_FAILED, ACCUMULATION, NONFINITE = (name for name, _ in record.STATUSES)
STATUS_CODES = record.STATUS_CODES


def _record_fields(cls):
    """One dataclass field per vcirun.record.FIELDS row, default None (`__post_init__` makes it an
    empty array of the row's dtype, except rows defined only for some methods, e.g. Hmod)."""
    for f in record.FIELDS:
        cls.__annotations__[f.name] = "np.ndarray | None"
        setattr(cls, f.name, None)
    return cls


@dataclass
@_record_fields
class Trajectory:
    method: str
    system: str
    h: float
    T: float
    t: np.ndarray
    status: str = OK
    message: str = ""
    fail_step: int = -1
    fail_time: float = float("nan")
    beta: float | None = None
    wall_time: float = 0.0
    tolerances: dict = field(default_factory=dict)
    options: dict = field(default_factory=dict)

    def __post_init__(self):
        n = self.q.shape[1] if isinstance(self.q, np.ndarray) and self.q.ndim == 2 else 0
        for f in record.FIELDS:
            if getattr(self, f.name) is None and f.only is None:
                dt = np.bool_ if f.dtype == "bool" else np.dtype(f.dtype)
                setattr(self, f.name, np.zeros((0, n) if f.dof else (0,), dt))

    @property
    def ok(self) -> bool:
        return self.status == OK

    @property
    def n_steps(self) -> int:
        return len(self.t) - 1

    def __repr__(self) -> str:
        return (f"Trajectory(method={self.method!r}, system={self.system!r}, h={self.h:g}, T={self.T:g}, "
                f"steps={self.n_steps}, impacts={len(self.impacts)}, status={self.status!r})")


_SIZES = {"grid": "N+1", "step": "N", "impact": "m", "partial": "K"}
Trajectory.__doc__ = (
    "Time-major record of a run on the grid t_k = t0 + k h (N = grid steps taken, n = degrees of freedom,\n"
    "m = impacts, K = partial steps). t (N+1,) grid times; the arrays, one per vcirun.record.FIELDS row:\n"
    + "\n".join(f"  {f.name} ({_SIZES[f.axis]}{', n' if f.dof else ''}{',' if not f.dof else ''}) {f.dtype}: {f.doc}"
                + (" (None for other methods)" if f.only == "modified" else "") for f in record.FIELDS)
    + "\nand status, message, fail_step, fail_time, beta, wall_time, tolerances, options.")
