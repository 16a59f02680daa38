"""What both integration paths of the exact reference hand to its event loop (vcirun.reference_solution.loop):
one segment of motion (`Flight`), its dense output, root refinement on it, and the work budget.

A backend (vcirun.reference_solution.taylor.TaylorBackend, vcirun.reference_solution.dop853.Dop853Backend) provides
`segment(t0, y0, T, A, R) -> Flight`: from (t0, y0), on the dynamics of the held set A (free flight
for A = ()), with R the contacts resting on their surface without being held, until the first event
or T. The event kinds:
    "impact"  contact i (not held) reaches phi_i = 0 moving in (y1 is the state at the root);
    "release" held contact i: its force mu_i crosses 0 downwards;
    "pressed" resting contact i: its normal acceleration along the flow turns negative (pushed in);
    "lift"    resting contact i has left its surface (the next segment watches it as a free contact);
    "drift"   the held constraints drifted past their bound (project and go on: no event);
    "end"     T reached.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Flight", "Constant", "first_root", "last_crossing", "ReferenceCostError", "Budget"]


@dataclass
class Flight:
    """One segment [t0, t1] of the exact solve: the state y1 at t1 (before any impact law or
    projection), why it ended (`reason`, the contact concerned or -1) and its dense output `piece`
    (callable like an OdeSolution on [t0, t1])."""

    t0: float
    t1: float
    y1: np.ndarray
    reason: str
    contact: int
    piece: object


class Constant:
    """Dense output of an empty interval (a segment that ends where it starts)."""

    def __init__(self, y):
        self.y = np.array(y, dtype=float)

    def __call__(self, t):
        ts = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.repeat(self.y[:, None], ts.size, axis=1)
        return out[:, 0] if np.ndim(t) == 0 else out


def first_root(g, a, b, samples=64):
    """The first downward crossing of g on [a, b] with g(b) < 0: dense samples bracket it (the first
    sample pair g >= 0 > g), brentq refines it to ~4 eps relative; b when g < 0 at every sample."""
    from scipy.optimize import brentq

    ts = np.linspace(a, b, samples + 1)
    gs = [g(s) for s in ts]
    for k in range(samples):
        if gs[k] >= 0.0 > gs[k + 1]:
            if gs[k] == 0.0:
                return float(ts[k])
            return float(brentq(g, ts[k], ts[k + 1], xtol=1e-300, rtol=4 * np.finfo(float).eps))
    return float(a) if gs[0] < 0.0 else float(b)


def last_crossing(g, a, b, samples=64):
    """The last downward crossing of g on [a, b] with g(b) < 0 (a contact that rose by round-off and
    came back: the root where it last left phi >= 0); a if g < 0 at every sample."""
    from scipy.optimize import brentq

    ts = np.linspace(a, b, samples + 1)
    gs = [g(s) for s in ts]
    for k in range(samples - 1, -1, -1):
        if gs[k] >= 0.0 > gs[k + 1]:
            if gs[k] == 0.0:
                return float(ts[k])
            return float(brentq(g, ts[k], ts[k + 1], xtol=1e-300, rtol=4 * np.finfo(float).eps))
    return float(a)


class ReferenceCostError(ValueError):
    """The exact solve would exceed its work budget (a ValueError: the arguments ask for it)."""


class Budget:
    """The work bound of one exact solve: `charge(work, t)` after each unit of work (DOP853: its
    right-hand-side evaluations; Taylor: its steps, each ~20 times the work of one evaluation) raises
    ReferenceCostError once `minimum` units reached only time t and the projection to T exceeds `limit`,
    or `limit` itself is spent. `unit` names the work in the message."""

    def __init__(self, T, q0, p0, limit, minimum, unit):
        self.T, self.limit, self.minimum, self.unit = float(T), float(limit), float(minimum), unit
        self.scale = float(max(np.max(np.abs(q0)), np.max(np.abs(p0))))
        self._next = self.minimum

    def exceeded(self, work, t) -> bool:
        """Whether `charge(work, t)` would raise (checked every 0.5 % of the minimum)."""
        if work < self._next:
            return False
        self._next = work + max(1.0, 0.005 * self.minimum)
        projected = work * self.T / t if t > 0 else np.inf
        return work >= self.limit or projected > self.limit

    def charge(self, work, t) -> None:
        if work < self.minimum:
            return
        projected = work * self.T / t if t > 0 else np.inf
        if work >= self.limit or projected > self.limit:
            raise ReferenceCostError(
                f"T: the exact reference would need about {projected:.1e} {self.unit} to reach T = {self.T:g} "
                f"({int(work):,} reached t = {t:.3g}; the limit is {self.limit:.0e}): the initial state "
                f"(max |q0|, |p0| = {self.scale:.3g}) is too large or T too long for an exact solve; lower T, give "
                "a smaller initial state, or use a method reference (method='CVA', h=...)")
