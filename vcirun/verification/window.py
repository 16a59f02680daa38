"""The window of the impact checks on a system that comes to rest.

Where the exact motion settles onto a surface (its reference holds a contact after a Zeno sequence
or a plastic impact: `ref.held_intervals` starting after t = 0), a run at step h resolves the
bounces while their flights are long against h and holds the contact at the first bounce whose flight
is shorter than about 2 h (docs/derivations/contacts.md 7.2): from there on runs at different h
follow different event sequences, by design, and neither impact counts nor the L2 error through the
accumulation measure the method's order. The impact checks are therefore made on [0, T_w], T_w before
the first reference impact whose next flight is shorter than SETTLE_FLIGHTS coarsest steps (the
midpoint between it and the impact before), rounded down to the coarsest grid so the ladder stays
nested. A hold that starts at an impact leaving the contact at rest (a plastic impact, e = 0: the
spinning ball landing, a walker's foot) is no accumulation: every run takes that impact and holds
from it, so only the flights before it are judged.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SETTLE_FLIGHTS = 2.5   # a run holds a contact whose next flight is shorter than about 2 h: a margin above it
HOLD_AT_IMPACT = 1e-12  # a hold starting within this (relative) of an impact starts at that impact


@dataclass(frozen=True)
class Window:
    """T: the end of the impact checks' runs (the full T where no window is needed); note: what the
    report says about it (empty without a window); impacts: reference impacts inside it."""

    T: float
    note: str = ""
    impacts: int = 0

    @property
    def cut(self) -> bool:
        return bool(self.note)


def settle_window(ref, T, h_max, names=None) -> Window:
    """The window of the impact checks for the reference `ref` on [0, T] and the coarsest step h_max:
    the holds of the reference in time order, each with the impacts before it; the first hold before
    which an interval between events is shorter than SETTLE_FLIGHTS h_max sets it."""
    imp = np.asarray(ref.impacts, float)
    holds = sorted((a, A) for a, _, A in getattr(ref, "held_intervals", []) if a > 0.0)
    for t_hold, held in holds:
        ev = np.unique(imp[imp <= t_hold])
        if ev.size == 0:
            continue
        if abs(t_hold - ev[-1]) <= HOLD_AT_IMPACT * max(1.0, abs(t_hold)):
            # the hold starts at an impact that leaves the contact at rest (a plastic impact): every run
            # takes that impact and holds from it, so it is no accumulation; only the intervals before it
            # count (a block rocking on its corners: each corner impact holds that corner)
            flights = np.diff(ev)
        else:
            flights = np.diff(np.append(ev, t_hold))
        short = np.flatnonzero(flights < SETTLE_FLIGHTS * h_max)
        if short.size:
            return _cut(imp, ev, flights, int(short[0]), t_hold, held, h_max, names)
    return Window(float(T), "", len(imp))


def _cut(imp, ev, flights, i, t_hold, held, h_max, names) -> Window:
    end = 0.5 * (ev[i - 1] + ev[i]) if i > 0 else 0.5 * ev[0]
    Tw = float(np.floor(end / h_max + 1e-9) * h_max)
    who = ", ".join(names[j] if names is not None and j < len(names) else f"contact {j}" for j in held)
    inside = int(np.sum(imp <= Tw))
    note = (f"the exact motion comes to rest ({who} held from t = {t_hold:.6g}, after impacts down to "
            f"{np.min(flights):.2g} s apart); a run holds a contact at the first bounce whose flight is shorter "
            f"than about 2 h, so the impact checks use the window [0, {Tw:g}], which ends before the first impact "
            f"(t = {ev[i]:.6g}) followed by a flight shorter than {SETTLE_FLIGHTS:g} x the coarsest h = {h_max:g} "
            f"({inside} reference impacts inside; smaller h widen it)")
    return Window(Tw, note, inside)
