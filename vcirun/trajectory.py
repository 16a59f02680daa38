"""The record of one simulation run (the `Trajectory` returned by `vcirun.simulate`)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Status strings a run can end with. Failures are data: they carry the step, time and state.
OK = "ok"
NEWTON_FAILED = "newton_failed"          # a full/partial step or reset solve did not converge
EVENT_FAILED = "event_failed"            # the collision-time search did not converge
RESET_FAILED = "reset_failed"            # the reset map found no nontrivial root
ACCUMULATION = "accumulation"            # impacts denser than the grid for > max_impacts_step steps (or in one step)
NONFINITE = "nonfinite"                  # a state became inf/NaN
STATUS_CODES = {0: OK, 1: NEWTON_FAILED, 2: EVENT_FAILED, 3: RESET_FAILED, 4: ACCUMULATION, 5: NONFINITE}


@dataclass
class Trajectory:
    """Time-major record of a run on the grid t_k = k h.

    Arrays (N = number of grid steps taken, n = degrees of freedom, m = impacts):
      t (N+1,), q (N+1, n), p (N+1, n)         grid states in T*Q
      H (N+1,)                                 continuous Hamiltonian at the grid states
      Ed (N+1,)                                discrete energy -D3 Ld of the full step taken from
                                               each grid state (trial step; defined everywhere)
      Hmod (N+1,) or None                      truncated modified Hamiltonian (MCVA family)
      impacts (m,)                             impact times, ascending
      impact_q (m, n), impact_p_minus (m, n), impact_p_plus (m, n)
      impact_step (N,) bool                    True where the step k -> k+1 contained an impact
      partial_steps (K,)                       every partial step length Delta tau taken
      newton_iters (N,) int                    Newton iterations spent in step k -> k+1
    """

    method: str
    system: str
    h: float
    T: float
    t: np.ndarray
    q: np.ndarray
    p: np.ndarray
    H: np.ndarray
    Ed: np.ndarray
    impacts: np.ndarray
    impact_q: np.ndarray
    impact_p_minus: np.ndarray
    impact_p_plus: np.ndarray
    impact_step: np.ndarray
    partial_steps: np.ndarray
    newton_iters: np.ndarray
    status: str = OK
    message: str = ""
    fail_step: int = -1
    fail_time: float = float("nan")
    Hmod: np.ndarray | None = None
    beta: float | None = None
    wall_time: float = 0.0
    tolerances: dict = field(default_factory=dict)
    options: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status == OK

    @property
    def n_steps(self) -> int:
        return len(self.t) - 1

    def __repr__(self) -> str:
        return (f"Trajectory(method={self.method!r}, system={self.system!r}, h={self.h:g}, T={self.T:g}, "
                f"steps={self.n_steps}, impacts={len(self.impacts)}, status={self.status!r})")
