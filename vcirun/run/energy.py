"""How well a run kept its energy: the largest |H - H0| (and |Hmod - Hmod0| for the MCVA family),
relative to the run's energy scale max(|H0|, the largest kinetic energy on the grid) -- |H0| alone
depends on the zero of V and may be ~0. `vcirun simulate` prints these numbers."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["EnergyDrift", "energy_scale", "energy_drift"]


def energy_scale(traj) -> float:
    """max(|H0|, the largest kinetic energy 1/2 p . qdot on (up to 2000 of) the grid states): what a
    relative energy error is relative to (|H0| alone depends on the zero of V and may be ~0)."""
    H0 = abs(float(traj.H[0]))
    if traj.dynamics is None or len(traj.t) == 0:
        return H0
    n = traj.q.shape[1]
    ke = 0.0
    for k in np.unique(np.linspace(0, len(traj.t) - 1, min(2000, len(traj.t))).astype(int)):
        y = np.concatenate([traj.q[k], traj.p[k]])
        qdot = traj.dynamics(traj.t[k], y)[:n]
        ke = max(ke, 0.5 * float(traj.p[k] @ qdot))
    return max(H0, ke)


@dataclass(frozen=True)
class EnergyDrift:
    """dH = max |H - H0| (None without a finite H0), scale = `energy_scale` (None with dH None),
    relative: dH / scale is meaningful (scale finite and > 0); dHmod = max |Hmod - Hmod0| (None
    without a finite Hmod0)."""

    dH: float | None
    scale: float | None
    dHmod: float | None

    @property
    def relative(self) -> bool:
        return self.scale is not None and bool(np.isfinite(self.scale)) and self.scale > 0


def energy_drift(traj) -> EnergyDrift:
    """The energy errors of a trajectory along its grid (NaN entries, e.g. energies=False, skipped)."""
    dH = scale = dHmod = None
    H = np.asarray(traj.H, float)
    if H.size and np.isfinite(H[0]):
        dH = float(np.nanmax(np.abs(H - H[0])))
        scale = energy_scale(traj)
    if traj.Hmod is not None and len(traj.Hmod) and np.isfinite(traj.Hmod[0]):
        dHmod = float(np.nanmax(np.abs(traj.Hmod - traj.Hmod[0])))
    return EnergyDrift(dH, scale, dHmod)
