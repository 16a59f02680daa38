"""How much a sweep will store: the size of its results file before it runs (`vcirun validate`, and a
note at the start of `vcirun sweep`), from the run record's stored rows (vcirun.core.sizes.stored_bytes)
at the config's `store` setting, with the impact record counted empty (a lower bound where runs have
many impacts; the trajectories dominate otherwise). Above STORE_WARN_BYTES the note is a warning that
names `store: {every: k}` and `store: metrics`."""
from __future__ import annotations

from dataclasses import dataclass

from ..core.grid import grid_steps
from ..core.sizes import format_bytes, stored_bytes

__all__ = ["STORE_WARN_BYTES", "StoreEstimate", "estimate_store", "store_estimate_of"]

STORE_WARN_BYTES = 2 * 2**30
TOL_MAX_STEPS = 1 << 22   # the steps of a run of tol= at most (vcirun.run.choose.MAX_STEPS; a test holds them equal)


@dataclass(frozen=True)
class StoreEstimate:
    total: float          # bytes of every run of the config
    runs: int
    every: int            # the config's store: 1 full, k every k-th, 0 metrics
    largest: float        # bytes of the largest run (the finest h)
    h_largest: float
    tol_most: float = 0.0  # runs of tol: the bytes of all of them at the choice's step limit (0: none)

    @property
    def warn(self) -> bool:
        return max(self.total, self.tol_most) > STORE_WARN_BYTES

    def line(self) -> str:
        what = {0: "impact records and summaries only (store: metrics)", 1: "every grid state"}.get(
            self.every, f"every {self.every}th grid state")
        text = (f"about {format_bytes(self.total)} for {self.runs} runs ({what}; the largest run, h = "
                f"{self.h_largest:g}, {format_bytes(self.largest)})")
        if self.tol_most:
            text += (f"; runs of tol: store the grid of the step they choose, which is known only when they run: "
                     f"up to {format_bytes(self.tol_most)} at the choice's limit of {TOL_MAX_STEPS} steps a run")
        return text

    def advice(self) -> str:
        """Above STORE_WARN_BYTES: the config keys that make it smaller."""
        most = max(self.total, self.tol_most)
        k = max(2, int(round(4 * most / STORE_WARN_BYTES)) * max(self.every, 1))
        return (f"{'up to ' if self.tol_most > self.total else ''}more than {format_bytes(STORE_WARN_BYTES)}; "
                f"store: {{every: {k}}} keeps every {k}th grid state (about {format_bytes(most * max(self.every, 1) / k)}"
                f"{' at most' if self.tol_most > self.total else ''}), store: metrics none")


def estimate_store(cfg, n: int, m: int, pending=None, friction: bool = True) -> StoreEstimate:
    """The stored size of `pending` runs (default: every run of the config) of a system with n
    coordinates and m constraints, with friction or not (the friction rows are stored only for runs
    with friction data)."""
    hs = [s.h for s in pending] if pending is not None else [
        h for h in cfg.h for _ in range(len(cfg.methods) * len(cfg.initial_conditions()))]
    every = cfg.store_every
    per_h = {h: stored_bytes(grid_steps(h, cfg.T)[2], n, m, every=every, friction=friction) for h in set(hs)}
    h_big = max(per_h, key=per_h.get) if per_h else float("nan")
    # (a run of tol: takes h as its largest step: its grid has at least T / h steps, at most the limit)
    tol_most = (len(hs) * stored_bytes(TOL_MAX_STEPS, n, m, every=every, friction=friction)
                if getattr(cfg, "tol", None) else 0.0)
    return StoreEstimate(float(sum(per_h[h] for h in hs)), len(hs), every, float(per_h.get(h_big, 0.0)), h_big,
                         float(tol_most))


def store_estimate_of(cfg) -> StoreEstimate:
    """The estimate of a validated config (builds its system to know n and m)."""
    from .config.semantics import build_system

    _, _, sysm = build_system(cfg)
    return estimate_store(cfg, sysm.n, sysm.m, friction=bool(sysm.has_friction))
