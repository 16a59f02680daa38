"""The Python API: `simulate`, `reference`, `l2_error`. The CLI and the sweep runner go through these."""
from __future__ import annotations

import math
import threading

import numpy as np

from ..codegen import kernel_cache
from ..core import record
from ..core.bounds import nonfinite_start
from ..core.grid import GridWarning
from ..core.system_data import start_beta
from . import trajectory as tr
from .diagnosis import failure_cause
from .pilot import RunArgs
from .plan import Buffers, first_call, plan, ready_start, run_loop, start_state, take

_LOCAL = threading.local()   # this thread's reused loop buffers (vcirun.run.plan.Buffers)


DEFAULT_H = 1e-2   # h when neither h nor tol is given (as `vcirun simulate`), at most T


def simulate(system, method=None, *, T, h=None, tol=None, beta=None, q0=None, p0=None, params=None,
             constrained=None, t0=0.0, energies=True, resting_contact=True, max_time=None, tier=None, loader=None,
             **options) -> tr.Trajectory:
    """Simulate `system` with `method` on the grid t_k = t0 + k h, k = 0..N, N = floor(T / h).

    system : built-in name ('cart_pendulum', 'double_pendulum', 'oscillator_wall', ...), YAML path,
             or MechanicalSystem.
    method : 'CVA', 'VCI', 'MCVAA', 'MCVAC', 'MCVA' (options ld=, mh_order=, flow_order=), or a
             discrete Lagrangian ('SE1', 'SE2', 'SVA', 'SVB', 'SVC', 'midpoint') for smooth
             integration with the constraint ignored.
    beta   : the scene's initial-condition map (Xi(beta) for the cart-pendulum); or give q0 and p0.
    params : parameter overrides; constrained: False ignores the constraint (default: per method).
    options: newton_tol, event_tol, max_iter, max_impacts_step.
    resting_contact: True (default) holds contacts that come to rest (accumulating impacts, a start
             resting on a surface, a small bounce with e < 1) and releases them where the contact
             force turns tensile; False stops such runs with status `accumulation` (and a resting
             start with `reset_failed`).
    energies: False skips H, Ed (and the MCVA family's Hmod) along the grid, leaving NaN after t0;
             for runs that only need the trajectory, e.g. timing against solve_ivp, which does
             not evaluate H either.
    tier   : "auto" (default, or $VCIRUN_TIER): the compiled kernels when they are cached, else the
             interpreted ones at once while the compiled ones are built in the background (later
             calls switch); "compiled": wait for them; "interpreted": run the generated kernels as
             Python. Same numbers either way (vcirun.codegen.tiers); `traj.tier` says which ran.
    loader : where the kernels come from: None (the kernel cache), a
             vcirun.codegen.kernel_cache.KernelCache, or a function (symbolic system, kernel set) ->
             module used instead of the cache, e.g. vcirun.codegen.evaluate.python_module_for to
             run the generated module as Python (no warm index, no plan kept between calls).
    h      : the step; default min(1e-2, T) (as `vcirun simulate`).
    tol    : an L2 trajectory error to reach (the norm of `vcirun.l2_error`, absolute, in q's units):
             the method (unless given; None or 'auto'), its options and h are chosen by pilot runs to
             reach it at the least cost (vcirun.run.choose; docs/tolerance.md); h is then the largest
             step allowed,
             max_time a budget in seconds for the final run. The returned trajectory carries
             `tr.choice` (candidates, predicted error and cost of each, the reason, the status) and
             its error estimate `tr.choice.estimate`.
    Numerical failure is returned as the trajectory's status (never raised); bad input raises
    ValueError naming the field.

    A built-in scene or YAML file whose kernel module is cached and indexed starts without any
    symbolic work (see `resolve_numeric`); the initial state's Legendre transform uses the compiled
    mass matrix on every path, so warm and cold starts give the same bits.
    """
    if tol is not None or max_time is not None:
        from .choose import simulate_to_tolerance

        return simulate_to_tolerance(system, None if method == "auto" else method, T=T, tol=tol, h_max=h,
                                     max_time=max_time, beta=beta, q0=q0, p0=p0, params=params,
                                     constrained=constrained, t0=t0, energies=energies,
                                     resting_contact=resting_contact, options=options, build=trajectory_of,
                                     tier=tier, loader=loader)
    if method is None:
        raise ValueError("method: give a method (CVA, VCI, MCVAA, MCVAC, CVA4, ...) or tol= to have one chosen")
    if h is None:
        h = _default_h(T)
    p = plan(system, method, h=h, T=T, t0=t0, constrained=constrained, energies=energies,
             resting_contact=resting_contact, options=options, start=dict(beta=beta, q0=q0, p0=p0, params=params),
             kc=kernel_cache.of(loader), tier=tier)
    sysd, h, N, t0 = p.sysd, p.h, p.N, p.t0
    prm = p.params(params)
    p.check_memory()  # before any buffer is allocated
    beta = start_beta(sysd, beta, q0, p0)  # a scene's default beta, recorded in the trajectory
    start = start_state(sysd, beta, q0, p0, prm, p.sysm)
    mod = p.module()
    buffers = getattr(_LOCAL, "buffers", None)
    if buffers is None:
        buffers = _LOCAL.buffers = Buffers(keep_grid=False)
    q0, p0 = ready_start(p, mod, start, prm, buffers)
    if p.note:
        import warnings

        warnings.warn(p.note, GridWarning, stacklevel=2)  # Python shows each distinct note once
    first_call(mod, p, q0, p0, prm)
    out, counters, wall = run_loop(mod, q0, p0, t0, h, N, prm, p.settings, sysd.n, p.max_impacts_step, buffers,
                                   p.rows(mod)[0])   # (the rows a run does not return are the buffers' own)
    p.ran(wall)
    return trajectory_of(p, mod, out, counters, q0, p0, prm, beta, wall,
                         call=(system, beta, q0, p0, params, constrained, resting_contact, options, t0))


def _default_h(T):
    """DEFAULT_H, at most T (a T that is not a number is left to simulate's checks)."""
    try:
        return min(DEFAULT_H, float(T)) if float(T) > 0 else DEFAULT_H
    except (TypeError, ValueError):
        return DEFAULT_H


def run_args(p, system, beta, q0, p0, params, constrained, resting_contact, options, t0):
    """What `Trajectory.error_estimate` needs to run companions of this call (vcirun.run.pilot.RunArgs):
    the start as the run took it (q0, p0 after the Legendre transform), the plan's system and method."""
    return RunArgs(system=p.system, method=p.meth, t0=float(t0), q0=q0, p0=p0, params=params,
                   constrained=constrained, resting_contact=resting_contact,
                   options={k: v for k, v in options.items() if k not in ("ld", "mh_order", "flow_order")},
                   tier=p.tier, kc=p.kc)


class _Derive:
    """The fields of a run's Trajectory that follow from the call alone, made on their first read
    (vcirun.run.trajectory.DERIVED): the grid times, the tolerances and options, the dense output's
    dynamics, run_args (where the call handed its arguments), each record the run left empty and the
    rows its module never writes (a module without friction: its friction rows and tangential
    impulses, zeros). The values are those of the plan, parameters and arguments of the call; a
    caller that reads none of them does not pay for them."""

    __slots__ = ("args",)

    def __init__(self, args: tuple):
        self.args = args   # (plan, module, parameter vector, counters, contacts, call)

    def __call__(self, name: str):
        p, mod, prm, counters, m, call = self.args
        if name == "t":
            return p.grid(counters["steps"])
        if name == "tolerances":
            return p.tolerances()
        if name == "options":
            return {"params": dict(zip(p.sysd.params, prm.tolist())), "constrained": p.constrained, **p.mopts}
        if name == "dynamics":   # (its own parameters: a change through tr.dynamics.prm stays out of options)
            return tr._dynamics(mod, prm.copy())
        if name == "run_args":
            return None if call is None else run_args(p, *call)
        # a row the run left out: its zeros (Plan.rows: a module without friction never writes its
        # friction rows and writes 0 in its tangential impulses), or a record with no entries
        f = record.FIELD[name]
        rows = counters["steps"] + 1 if f.axis == "grid" else counters[_COUNTS[f.axis]]
        return np.zeros(f.shape(rows, p.sysd.n, m), np.bool_ if f.dtype == "bool" else f.dtype)


_COUNTS = {"step": "steps", "impact": "n_impacts", "partial": "n_partial", "release": "n_releases",
           "mode": "n_mode_changes"}   # the counter of each axis's rows (the grid has steps + 1)


def trajectory_of(p, mod, out, counters, q0, p0, prm, beta, wall, call=None) -> tr.Trajectory:
    """The Trajectory of one finished loop of plan `p` (its grid rows are the Trajectory's), with the
    tier and build the plan ran. call: the arguments of `run_args` after `p` (system, beta, q0, p0,
    params, constrained, resting_contact, options, t0), for `tr.run_args`; the fields that follow from
    the call alone are made on first read (`_Derive`)."""
    h, t0, tol, energies = p.h, p.t0, p.tol, p.energies
    m = int(mod.NCON)
    _, own, records = p.rows(mod)
    arrays = take(out, counters, p.ks.modified is not None, own, records,   # (meth.has_modified_energy)
                  p.fields(tr.run_defaults))
    status, fail = record.STATUS_CODES[counters["status"]], counters["fail_step"]
    message = ""
    if status != tr.OK:
        Q = out[record.FIELDS.index(record.FIELD["q"])]
        P = out[record.FIELDS.index(record.FIELD["p"])]
        message = (f"{status} in step {fail} (t = {t0 + fail * h:.6g}) from q = {Q[fail].tolist()}, "
                   f"p = {P[fail].tolist()}")
        impacts, modes = arrays.get("impacts"), arrays.get("contact_mode")   # (absent: none, no friction)
        cause = failure_cause(mod, status, Q[: fail + 1], P[fail], t0, fail, h, prm, tol, float(arrays["H"][0]),
                              np.empty(0) if impacts is None else impacts,
                              modes=None if modes is None else modes[: fail + 1])
        if cause:
            message += f"; cause: {cause}"
    # an energy that is not finite from the start (e.g. q0 = 1e300) is a failure, not ok
    H0, Hmod = arrays["H"][0], arrays["Hmod"]
    bad_start = "" if (math.isfinite(H0) and (Hmod is None or math.isfinite(Hmod[0]))
                       and math.isfinite(arrays["Ed"][0])) else nonfinite_start(
        H0, arrays["Ed"][0] if energies else None, Hmod[0] if energies and Hmod is not None else None, q0, p0)
    if bad_start and status == tr.OK:
        status, fail, message = tr.NONFINITE, 0, f"{tr.NONFINITE} at t = {t0:.6g}: {bad_start}"
    arrays["status"], arrays["message"], arrays["fail_step"] = status, message, fail
    arrays["fail_time"] = (t0 + fail * h) if fail >= 0 else float("nan")
    arrays["beta"], arrays["wall_time"] = beta, wall
    arrays["tier"], arrays["build"] = p.tier_used, p.build_used
    return tr.Trajectory.of_run(arrays, _Derive((p, mod, prm, counters, m, call)), complete=True)
