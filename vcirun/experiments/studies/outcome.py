"""Runs that never raise, and what the studies read off a run (status, cause, energy error).

Every study function goes through `run`: a ValueError from `vcirun.simulate` (input it refuses, with the
field and cause) becomes the record 'rejected: ...', any other exception 'crash: ...' -- a crash is a
finding, never the end of a study.
"""
from __future__ import annotations

import numpy as np

from ...run.api import simulate
from ...run.resolve import resolve_system
from ...codegen.build import load_module
from ...methods.table import resolve_method

__all__ = ["run", "outcome", "cause", "energy_error", "compiled"]


def run(system, method, **kw):
    """simulate(...) that turns an exception into a record: (trajectory or None, '' or 'rejected: ...'
    (ValueError: input simulate() refuses, with the field and cause) or 'crash: ...' (anything else))."""
    try:
        return simulate(system, method, **kw), ""
    except ValueError as e:  # bad input, named by simulate(): a rejection, not a crash
        return None, f"rejected: {e}"
    except Exception as e:  # a crash is a finding, never the end of the study
        return None, f"crash: {type(e).__name__}: {e}"


def outcome(tr, crash) -> str:
    """The run's status, or the rejection / crash record when there is no trajectory."""
    return crash if tr is None else tr.status


def cause(tr) -> str:
    """The cause vcirun.run.api appended to a failure message ('' if none)."""
    if tr is None or "; cause: " not in tr.message:
        return ""
    return tr.message.split("; cause: ", 1)[1]


def energy_error(tr) -> float:
    """max |H - H(0)| over the run (nan without a trajectory)."""
    if tr is None or len(tr.H) == 0:
        return float("nan")
    return float(np.nanmax(np.abs(tr.H - tr.H[0])))


def compiled(system, method="CVA", params=None):
    """(MechanicalSystem, parameter vector, compiled module of `method`): the kernels the constructions use."""
    s = resolve_system(system)
    return s, s.param_values(params), load_module(s, resolve_method(method).kernel_set())
