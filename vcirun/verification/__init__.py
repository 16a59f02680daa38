"""Verification of methods on a user's system (`vcirun verify`), and the numerical helpers the test
suite shares with it.

- orders.py  : fit_order (round-off plateau masked), local slopes, the asymptotic h, drift slope
- fd.py      : finite-difference stencils, the symplecticity defect, the derivative checks of
               generated kernels (a table: kernel -> against which lower-level kernel)
- harness.py : Python drivers of the compiled maps (step, run_map), the exact smooth solution
- checks.py  : the verdicts (pass / warn / fail / skip, the number, the threshold)
- suite.py   : `verify(...)` -> VerifyResult
- verdict.py : the Markdown report and the log-log figure
"""
from __future__ import annotations


def __getattr__(name):
    if name in ("verify", "VerifyResult"):
        from . import suite as runner

        return getattr(runner, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
