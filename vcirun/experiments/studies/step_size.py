"""Step size and long horizons: the stable step range of a method and its energy drift over 1e6 steps.

- `step_limit`: log scan of h from h_min up, then bisection of the first ok -> failure transition:
  the stable range [h_min, h*] and the status just past h*.
- `long_run`: `steps` steps, drift of H (and of the truncated modified Hamiltonian for the MCVA
  family) as the least-squares slope over time and the running maximum at checkpoints.
"""
from __future__ import annotations

import math

import numpy as np

from .outcome import compiled, energy_error, outcome, run

__all__ = ["step_limit", "energy_scale", "drift_slope", "long_run"]


def step_limit(system, method, *, T, beta=None, q0=None, p0=None, params=None, h_min=1e-5, h_max=2.0,
               per_decade=4, rel=1e-3) -> dict:
    """Scan h = h_min * 10^(k / per_decade) up to h_max (every point run: any crash is recorded), then
    bisect (geometrically, to h_past / h_limit < 1 + rel) between the last ok h below the first
    failure and that failure. Returns h_limit (largest ok h of the range [h_min, h_limit] in which
    every scanned h is ok), h_past with its status and message, the energy error at h_limit, the
    scan, and the ok steps above the first failure (non-monotone behaviour)."""
    kw = dict(T=T, beta=beta, q0=q0, p0=p0, params=params)
    ks = np.arange(0, int(math.floor(per_decade * math.log10(h_max / h_min) + 1e-9)) + 1)
    grid = [float(h_min * 10 ** (k / per_decade)) for k in ks]
    scan, crashes, dHs = [], [], []
    E_scale = np.nan
    for h in grid:
        tr, crash = run(system, method, h=h, **kw)
        scan.append((h, outcome(tr, crash)))
        dHs.append(energy_error(tr) if tr is not None and tr.ok else np.inf)
        if tr is not None and not np.isfinite(E_scale):
            E_scale = energy_scale(system, tr, params)
        if crash and not crash.startswith("rejected"):
            crashes.append((h, crash))
    first_fail = next((i for i, (_, st) in enumerate(scan) if st != "ok"), None)
    # the accuracy limit: largest scanned h below which every run keeps max |H - H0| <= 10 % E_scale
    acc = next((i for i, d in enumerate(dHs) if not d <= 0.1 * E_scale), len(dHs))
    out = {"system": str(system), "method": method, "T": T, "h_min": h_min, "h_max": h_max, "per_decade": per_decade,
           "rel": rel, "scan": scan,
           "crashes": crashes, "dH_scan": dHs, "E_scale": E_scale, "h_energy10": grid[acc - 1] if acc > 0 else None}
    if first_fail is None:
        tr, _ = run(system, method, h=grid[-1], **kw)
        out.update(h_limit=grid[-1], h_past=None, status_past="(none up to h_max)", message_past="",
                   dH_at_limit=energy_error(tr), ok_above=[])
        return out
    if first_fail == 0:
        out.update(h_limit=None, h_past=grid[0], status_past=scan[0][1], message_past="", dH_at_limit=np.nan,
                   ok_above=[])
        return out
    a, b = grid[first_fail - 1], grid[first_fail]
    tb, cb = run(system, method, h=b, **kw)
    while b / a > 1 + rel:
        c = math.sqrt(a * b)
        tc, cc = run(system, method, h=c, **kw)
        if cc and not cc.startswith("rejected"):
            crashes.append((c, cc))
        if tc is not None and tc.ok:
            a = c
        else:
            b, tb, cb = c, tc, cc
    ta, _ = run(system, method, h=a, **kw)
    out.update(h_limit=a, h_past=b, status_past=outcome(tb, cb), message_past=(tb.message if tb else cb),
               dH_at_limit=energy_error(ta), ok_above=[h for h, st in scan[first_fail:] if st == "ok"])
    return out


def energy_scale(system, tr, params=None) -> float:
    """max(|H(0)|, largest kinetic energy H - V(q) along the run (<= 2000 grid points)): the energy
    against which an energy error is 'small' (H(0) alone can be 0, e.g. the double pendulum)."""
    s, prm, mod = compiled(system, "CVA", params)
    idx = np.unique(np.linspace(0, len(tr.t) - 1, 2000).astype(int))
    ke = max(float(tr.H[k] - mod.sys_V(tr.q[k], prm)) for k in idx)
    return max(abs(float(tr.H[0])), ke)




def drift_slope(t, E) -> float:
    """Least-squares slope of E(t) - E(0) over t (energy units per unit time); nan if < 2 finite points."""
    t = np.asarray(t, float)
    E = np.asarray(E, float)
    m = np.isfinite(E)
    if m.sum() < 2:
        return float("nan")
    tt = t[m] - t[m].mean()
    return float(np.dot(tt, E[m] - E[m].mean()) / np.dot(tt, tt))


def long_run(system, method, *, h, steps, beta=None, q0=None, p0=None, params=None,
             checkpoints=(10_000, 100_000, 1_000_000)) -> dict:
    """`steps` steps from Xi(beta) (or q0, p0): drift slope and running maximum of |H - H(0)| at each
    checkpoint (and of Hmod for the MCVA family)."""
    tr, crash = run(system, method, h=h, T=steps * h, beta=beta, q0=q0, p0=p0, params=params)
    out = {"system": str(system), "method": method, "h": h, "steps": steps, "beta": beta, "status": outcome(tr, crash)}
    if tr is None:
        return out
    out.update(steps_done=tr.n_steps, impacts=int(len(tr.impacts)), wall_time=tr.wall_time, H0=float(tr.H[0]),
               message=tr.message)
    for name, E in (("H", tr.H), ("Hmod", tr.Hmod)):
        if E is None:
            continue
        dev = np.abs(E - E[0])
        out[f"slope_{name}"] = drift_slope(tr.t, E)
        out[f"maxdev_{name}"] = {int(c): float(np.nanmax(dev[: c + 1])) for c in checkpoints if c <= tr.n_steps}
        out[f"rel_{name}"] = float(np.nanmax(dev) / max(abs(E[0]), 1e-300))
    return out
