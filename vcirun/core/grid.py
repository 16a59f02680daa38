"""The time grid of a run: t_k = t0 + k h, k = 0..N, with N = floor(T / h) as in the paper.

`grid_count` is the rule for N, used by `vcirun.simulate`, the config checks, the sweep's
preflight and reference span, the verification suite and the baselines alike. T / h is floored
to a relative 1e-9, so T = 5, h = 1e-3 gives N = 5000 although 5 / 1e-3 = 4999.999... in floating
point; where T is not a multiple of h the grid ends at N h < T (`grid_note` says so, and
`vcirun.simulate` warns once with `GridWarning`).

numpy only: every layer may import this.
"""
from __future__ import annotations

import math

from .limits import cap
from .values import check_number

__all__ = ["MAX_STEPS", "MIN_H", "GridWarning", "grid_count", "grid_steps", "grid_note", "grid_end"]

# MAX_STEPS: the caps table (vcirun.core.limits). Below MIN_H the h**k terms of the discrete
# Lagrangians and of the modified Hamiltonians (k <= 6) leave the normal floating-point range.
MAX_STEPS = cap("steps")
MIN_H = 1e-50
_REL = 1e-9  # relative slack of the floor: T / h within 1e-9 of an integer counts as that integer


class GridWarning(UserWarning):
    """T is not a multiple of h: the grid ends at N h < T (said once per (T, h))."""


def grid_count(h: float, T: float) -> int:
    """N = floor(T / h) up to a relative 1e-9: the number of steps of the grid on [0, T]."""
    r = T / h
    return int(math.floor(r + _REL * max(1.0, r)))


def grid_steps(h, T, *, h_field: str = "h", T_field: str = "T") -> tuple[float, float, int]:
    """Validated (h, T, N): h and T finite and > 0, h >= MIN_H, 1 <= N = grid_count(h, T) <= MAX_STEPS.
    ValueError names the field (`h_field`, `T_field`) and says what to change."""
    h = check_number(h_field, h, gt=0)
    T = check_number(T_field, T, gt=0)
    if h < MIN_H:
        raise ValueError(f"{h_field}: must be >= {MIN_H:g} (got {h:g}); smaller steps underflow the h**k terms "
                         "of the discrete Lagrangians")
    steps = T / h
    if not steps <= MAX_STEPS:
        raise ValueError(f"{h_field}: T / h = {steps:.3g} steps is too many (at most {MAX_STEPS:.0e}); "
                         "raise h or lower T")
    N = grid_count(h, T)
    if N < 1:
        raise ValueError(f"{T_field}: must be at least one step h (got T={T:g}, h={h:g})")
    return h, T, N


def grid_end(h: float, T: float) -> float:
    """The last grid time N h (<= T up to the rule's relative 1e-9)."""
    return grid_count(h, T) * h


def grid_note(h: float, T: float) -> str:
    """'' if T is a multiple of h, else the sentence that says where the grid ends."""
    N = grid_count(h, T)
    if abs(N * h - T) <= _REL * max(1.0, abs(T)):
        return ""
    return (f"T = {T:g} is not a multiple of h = {h:g}: the grid ends at N h = {N * h:.12g} "
            f"(N = floor(T / h) = {N}, as in the paper); the trajectory's T is that end time")
