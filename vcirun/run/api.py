"""The Python API: `simulate`, `reference`, `l2_error`. The CLI and the sweep runner go through these."""
from __future__ import annotations

import math
import time

import numpy as np

from ..core import record
from . import trajectory as tr
from ..core.bounds import check_simulate_args, nonfinite_start
from ..core.grid import GridWarning, grid_note
from ..core.sizes import check_run_memory
from ..core.tolerances import DEFAULT_TOLERANCES, split_options
from .diagnosis import failure_cause
from ..methods.table import resolve_method
from .resolve import _warmable, resolve_numeric, resolve_system
from ..core.system_data import SystemData, check_mass_matrix, requested_start, start_beta, start_tolerance


def _start_state(d: SystemData, beta, q0, p0, prm, sysm=None):
    """Validate the requested initial state before any kernel is loaded: ("state", q0, p0) or
    ("legendre", q0, qdot0) (p0 = M(q0) qdot0 is computed by `_initial_state` with the compiled M).
    Same rules and messages as MechanicalSystem.initial_state; with the symbolic system at hand
    (cold path) the hyperregularity check runs here, before anything is generated or compiled."""
    kind, q0, p0 = requested_start(d, beta, q0, p0)
    if sysm is not None:
        sysm.check_hyperregular(q0, prm)
    return kind, q0, p0, sysm is not None


def _initial_state(d: SystemData, mod, start, prm):
    """(q0, p0) from `_start_state`. The Legendre transform uses the module's compiled M(q) on every
    path, so warm and cold starts compute the same bits; on the warm path the hyperregularity check
    uses it too (compiled: mass_matrix_ok; numpy's check then only words the error)."""
    kind, q0, p0, checked = start
    # on every path, so that a cold start compiles (and caches) what a warm start calls
    q0 = np.ascontiguousarray(q0, dtype=float)
    Mq = np.empty((q0.shape[0], q0.shape[0]))
    ok = mod.mass_matrix_ok(q0, prm, Mq)   # M(q0) once, for the check and the Legendre transform
    if not checked and not ok:
        check_mass_matrix(d.name, q0, Mq)
    if kind == "legendre":
        p0 = Mq @ p0
    return q0, p0


def _check_admissible(d: SystemData, mod, q0, prm, phi_text) -> None:
    """A start inside the constraint is bad input (ValueError naming phi(q0), its value and the
    constraint phi_text() -- called only then: on the warm path it builds the symbolic system), not a
    run that ends later as `reset_failed` or `accumulation`; a start on the surface (to round-off)
    is allowed."""
    m = int(mod.NCON)
    phis, G = np.empty(m), np.empty((m, d.n))
    mod.sys_phis(q0, prm, phis)
    mod.sys_dphis(q0, prm, G)
    for i in range(m):
        if not math.isfinite(phis[i]) or phis[i] < -start_tolerance(q0, G[i]):
            raise ValueError(f"initial state: q0={q0.tolist()} lies inside the constraint of system {d.name}: "
                             f"phi(q0) = {phis[i]:.6g} < 0 for {phi_text(i)}; start where phi(q0) >= 0 "
                             "(or pass constrained=False)")


def _constraint_text(sysm, i: int) -> str:
    c = sysm.constraints[i]
    return f"phi = {c.phi}" if sysm.m == 1 else f"constraint {c.name} (phi = {c.phi})"


_FIRST_CALLS: set = set()


def simulate(system, method, *, h, T, beta=None, q0=None, p0=None, params=None, constrained=None,
             t0=0.0, energies=True, resting_contact=True, **options) -> tr.Trajectory:
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
    Numerical failure is returned as the trajectory's status (never raised); bad input raises
    ValueError naming the field.

    A built-in scene or YAML file whose kernel module is cached and indexed starts without any
    symbolic work (see `resolve_numeric`); the initial state's Legendre transform uses the compiled
    mass matrix on every path, so warm and cold starts give the same bits.
    """
    mopts, tol = split_options(options)
    h, T, N = check_simulate_args(h=h, T=T, t0=t0, beta=beta, q0=q0, p0=p0, params=params, constrained=constrained,
                                  energies=energies, tolerances=tol, system=system, resting_contact=resting_contact)
    if not _warmable(system):
        system = resolve_system(system)  # bad names and files raise here, before a bad method does
    meth = resolve_method(method, **mopts)
    sysd, load, sysm = resolve_numeric(system, meth.kernel_set())
    prm = sysd.param_values(params)
    check_run_memory(N, sysd.n)  # before any buffer is allocated
    beta = start_beta(sysd, beta, q0, p0)  # a scene's default beta, recorded in the trajectory
    start = _start_state(sysd, beta, q0, p0, prm, sysm)
    if constrained is None:
        constrained = meth.constrained
    mod = load()
    q0, p0 = _initial_state(sysd, mod, start, prm)
    if constrained:
        _check_admissible(sysd, mod, q0, prm, lambda i: _constraint_text(sysm or resolve_system(system), i))
    note = grid_note(h, T)
    if note:
        import warnings

        warnings.warn(note, GridWarning, stacklevel=2)  # Python shows each distinct note once
    settings = record.settings_vector(constrained=bool(constrained), energies=bool(energies),
                                      resting_contact=bool(resting_contact), **tol)
    if mod.__name__ not in _FIRST_CALLS:
        # numba's first call of the loop (load from its cache, or compile) is not integration: one
        # untimed step with arguments of the same types, so wall_time measures the integration only
        from ..codegen.cache import first_call_lock, note_first_call

        _FIRST_CALLS.add(mod.__name__)
        t_first = time.perf_counter()
        with first_call_lock(mod):  # one compile per module across processes (sweep and test workers)
            _run_loop(mod, q0, p0, float(t0), h, 1, prm, settings, sysd.n, int(tol["max_impacts_step"]))
        note_first_call(mod, meth.kernel_set(), time.perf_counter() - t_first)
    t_start = time.perf_counter()
    out, counters = _run_loop(mod, q0, p0, float(t0), h, N, prm, settings, sysd.n, int(tol["max_impacts_step"]))
    wall = time.perf_counter() - t_start
    arrays = record.trim(out, counters, modified=meth.has_modified_energy)
    status, fail = record.STATUS_CODES[counters["status"]], counters["fail_step"]
    message = ""
    if status != tr.OK:
        Q = out[record.FIELDS.index(record.FIELD["q"])]
        P = out[record.FIELDS.index(record.FIELD["p"])]
        message = (f"{status} in step {fail} (t = {t0 + fail * h:.6g}) from q = {Q[fail].tolist()}, "
                   f"p = {P[fail].tolist()}")
        cause = failure_cause(mod, status, Q[: fail + 1], P[fail], t0, fail, h, prm, tol, float(arrays["H"][0]),
                              arrays["impacts"])
        if cause:
            message += f"; cause: {cause}"
    # an energy that is not finite from the start (e.g. q0 = 1e300) is a failure, not ok
    bad_start = nonfinite_start(arrays["H"][0], arrays["Ed"][0] if energies else None,
                                           arrays["Hmod"][0] if energies and arrays.get("Hmod") is not None
                                           else None, q0, p0)
    if bad_start and status == tr.OK:
        status, fail, message = tr.NONFINITE, 0, f"{tr.NONFINITE} at t = {t0:.6g}: {bad_start}"
    return tr.Trajectory(
        method=meth.name, system=sysd.name, h=h, T=N * h, t=t0 + h * np.arange(counters["steps"] + 1), **arrays,
        status=status, message=message, fail_step=fail, fail_time=(t0 + fail * h) if fail >= 0 else float("nan"),
        beta=beta, wall_time=wall, tolerances={k: tol[k] for k in DEFAULT_TOLERANCES},
        options={"params": dict(zip(sysd.params, prm.tolist())), "constrained": bool(constrained), **mopts},
        coordinates=getattr(sysd, "coordinates", None), dynamics=tr._dynamics(mod, prm))


def _run_loop(mod, q0, p0, t0, h, N, prm, settings, n, max_impacts_step) -> tuple[tuple, dict]:
    """(output buffers, counters) of the compiled loop. The impact record starts at N / 4 + 16
    entries; the loop reports ST_ACCUMULATION also when it is full, which is a buffer size, not
    impacts accumulating: then it reruns with room for every impact the caps allow."""
    cap_imp, most = record.impact_capacity(N), N * max_impacts_step + 16
    while True:
        out = record.allocate(N, n, m=int(mod.NCON), cap_impacts=cap_imp)
        info = np.zeros(len(record.COUNTERS), dtype=np.int64)
        # no np.errstate here: the compiled loop never touches numpy's error state, and
        # with NUMBA_DISABLE_JIT=1 the caller's np.errstate(all="raise") must reach the numerics
        # (the floating-point hygiene check of tests/extremes runs the whole loop that way).
        mod.integrate(q0, p0, t0, h, N, prm, settings, out, info)
        counters = dict(zip(record.COUNTERS, info.tolist()))
        full_record = counters["n_impacts"] + int(mod.NCON) > cap_imp  # (an impact adds up to NCON entries)
        if not (counters["status"] == record.STATUS_OF["accumulation"] and full_record) or cap_imp >= most:
            return out, counters
        cap_imp = min(4 * cap_imp, most)
