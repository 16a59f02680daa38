"""The Python API: `simulate`, `reference`, `l2_error`. The CLI and the sweep runner go through these."""
from __future__ import annotations

import hashlib
import math
import os
import time
from pathlib import Path

import numpy as np

from . import record
from . import trajectory as tr
from . import validation
from .codegen import build
from .codegen.build import load_module
from .diagnosis import accumulation_onset, failure_cause  # noqa: F401 (accumulation_onset: public here)
from .methods import resolve_method
from .scenedata import SystemData, check_mass_matrix, requested_start, scene_args, scene_data, start_tolerance

DEFAULT_TOLERANCES = {"newton_tol": 1e-12, "event_tol": 1e-13, "max_iter": 50, "max_impacts_step": 64}
_METHOD_OPTIONS = {"ld", "mh_order", "flow_order"}


def _is_yaml_source(s: str) -> bool:
    """A YAML system file: a name ending in .yaml/.yml, or an existing file that is not a built-in
    scene's name (a built-in name always means the scene: no file-system lookup per call)."""
    return s.endswith((".yaml", ".yml")) or (scene_args(s) is None and Path(s).is_file())


def resolve_system(system, params: dict | None = None):
    """A MechanicalSystem from a built-in name, a YAML file path, or an instance (symbolic: imports sympy)."""
    from .mechanics.system import MechanicalSystem

    if isinstance(system, MechanicalSystem):
        if params:
            system.param_values(params)  # validates the names
        return system
    if isinstance(system, (str, Path)):
        s = str(system)
        if _is_yaml_source(s):
            from .mechanics.loader import load_system_yaml

            return load_system_yaml(s)
        from .mechanics.scenes import get_scene

        return get_scene(s)
    raise ValueError(f"system: expected a built-in name, a YAML path or a MechanicalSystem, got {type(system).__name__}")


# --- warm start (issue 7): a system given by name or file without the symbolic system ----------------

def _warmable(system) -> bool:
    """A built-in scene name or an existing file: something the warm index may know."""
    if not isinstance(system, (str, Path)):
        return False
    s = str(system)
    return Path(s).is_file() if _is_yaml_source(s) else scene_args(s) is not None


def _warm_ident(system):
    """(("scene", name) or ("yaml", sha256 of the file), file bytes or None) for a system the warm index
    can serve, else (None, None) (instances, unknown names, missing files: the symbolic path decides)."""
    if not isinstance(system, (str, Path)):
        return None, None
    s = str(system)
    if _is_yaml_source(s):
        try:
            data = Path(s).read_bytes()
        except OSError:
            return None, None
        return ("yaml", hashlib.sha256(data).hexdigest()), data
    if scene_args(s) is None:
        return None, None
    return ("scene", s), None


def _data_from_entry(ident, entry) -> SystemData | None:
    """The numeric system of a warm index entry (None if it does not fit: then the symbolic path runs)."""
    try:
        names = [k for k, _ in entry["params"]]
        if ident[0] == "scene":
            d = scene_data(ident[1])
            if d.name != entry["name"] or d.n != entry["n"] or list(d.params) != names:
                return None
            return d
        n = int(entry["n"])
        vec = lambda v: None if v is None else np.array(v, dtype=float)  # noqa: E731
        d = SystemData(name=str(entry["name"]), n=n, params={k: v for k, v in entry["params"]},
                       default_q0=vec(entry["default_q0"]), default_p0=vec(entry["default_p0"]),
                       description=str(entry.get("description", "")))
        if (entry.get("ic_map") or (d.default_q0 is None) != (d.default_p0 is None)
                or any(a is not None and a.shape != (n,) for a in (d.default_q0, d.default_p0))
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in d.params.values())):
            return None
        return d
    except (KeyError, TypeError, ValueError):
        return None


def _entry_data(sysm) -> dict:
    """What the warm index stores about a symbolic system (built-in scenes take the rest from
    vcirun.scenedata; YAML systems have no initial-condition map)."""
    vec = lambda a: None if a is None else np.asarray(a, float).tolist()  # noqa: E731
    return {"name": sysm.name, "n": sysm.n, "params": [[k, v] for k, v in sysm.params.items()],
            "default_q0": vec(sysm.default_q0), "default_p0": vec(sysm.default_p0),
            "description": sysm.description, "ic_map": sysm.ic_map is not None}


_WARM_HITS: dict = {}


def resolve_numeric(system, ks: build.KernelSet):
    """(SystemData, loader, symbolic system or None) for `system` (built-in name, YAML path or
    MechanicalSystem) and kernel set `ks`; loader() returns the compiled module.

    A built-in name or a YAML file whose (identity, ks) is in the warm index is served from it:
    no symbolic system, no sympy. Otherwise (and always for a MechanicalSystem instance) the
    symbolic system is built and its module loaded or generated; names and files are then indexed.
    A substitute for `load_module` (tests monkeypatch it to run modules uncompiled) is always used:
    it turns the warm index off."""
    genuine = load_module is build.load_module
    ident, raw = _warm_ident(system) if genuine else (None, None)
    if ident is not None:
        memo = (ident, ks, os.environ.get("VCIRUN_KERNEL_PATH", ""))
        hit = _WARM_HITS.get(memo)
        if hit is not None:   # this process has read the entry already: no file access per call
            return hit
        entry = build.warm_lookup(ident, ks)
        d = _data_from_entry(ident, entry) if entry is not None else None
        if d is not None:
            hit = (d, lambda: build.load_cached_module(entry["module"], d.name, ks), None)
            _WARM_HITS[memo] = hit
            return hit
    sysm = resolve_system(system)
    d = SystemData.of(sysm)

    def load():
        mod = load_module(sysm, ks)
        if ident is not None and (raw is None or _warm_ident(system)[1] == raw):  # the file we hashed
            build.warm_record(ident, ks, build.module_key(sysm, ks), _entry_data(sysm))
        return mod

    return d, load, sysm


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


def grid_steps(h, T) -> tuple[float, float, int]:
    """Validated (h, T, N) of the grid t_k = k h, k = 0..N, N = round(T / h)."""
    h, T = float(h), float(T)
    if not (h > 0 and math.isfinite(h)):
        raise ValueError(f"h: must be a positive finite step (got {h})")
    if not (T > 0 and math.isfinite(T)):
        raise ValueError(f"T: must be a positive finite time (got {T})")
    N = int(round(T / h))
    if N < 1:
        raise ValueError(f"T: must be at least one step h (got T={T}, h={h})")
    return h, T, N


def simulate(system, method, *, h, T, beta=None, q0=None, p0=None, params=None, constrained=None,
             t0=0.0, energies=True, **options) -> tr.Trajectory:
    """Simulate `system` with `method` on the grid t_k = t0 + k h, k = 0..N, N = round(T / h).

    system : built-in name ('cart_pendulum', 'double_pendulum', 'oscillator_wall', ...), YAML path,
             or MechanicalSystem.
    method : 'CVA', 'VCI', 'MCVAA', 'MCVAC', 'MCVA' (options ld=, mh_order=, flow_order=), or a
             discrete Lagrangian ('SE1', 'SE2', 'SVA', 'SVB', 'SVC', 'midpoint') for smooth
             integration with the constraint ignored.
    beta   : the scene's initial-condition map (Xi(beta) for the cart-pendulum); or give q0 and p0.
    params : parameter overrides; constrained: False ignores the constraint (default: per method).
    options: newton_tol, event_tol, max_iter, max_impacts_step.
    energies: False skips H, Ed (and the MCVA family's Hmod) along the grid, leaving NaN after t0;
             for runs that only need the trajectory, e.g. timing against solve_ivp, which does
             not evaluate H either.
    Numerical failure is returned as the trajectory's status (never raised); bad input raises
    ValueError naming the field.

    A built-in scene or YAML file whose kernel module is cached and indexed starts without any
    symbolic work (see `resolve_numeric`); the initial state's Legendre transform uses the compiled
    mass matrix on every path, so warm and cold starts give the same bits.
    """
    mopts, tol = _split_options(options)
    validation.check_simulate_args(h=h, T=T, t0=t0, beta=beta, q0=q0, p0=p0, params=params, constrained=constrained,
                                   energies=energies, tolerances=tol, system=system)  # (issue 22)
    h, T, N = grid_steps(h, T)
    if not _warmable(system):
        system = resolve_system(system)  # bad names and files raise here, before a bad method does
    meth = resolve_method(method, **mopts)
    sysd, load, sysm = resolve_numeric(system, meth.kernel_set())
    prm = sysd.param_values(params)
    validation.check_run_memory(N, sysd.n)  # before any buffer is allocated (issue 22)
    start = _start_state(sysd, beta, q0, p0, prm, sysm)
    if constrained is None:
        constrained = meth.constrained
    mod = load()
    q0, p0 = _initial_state(sysd, mod, start, prm)
    if constrained:
        _check_admissible(sysd, mod, q0, prm, lambda i: _constraint_text(sysm or resolve_system(system), i))
    settings = record.settings_vector(constrained=bool(constrained), energies=bool(energies), **tol)
    t_start = time.perf_counter()
    out, counters = _run_loop(mod, q0, p0, float(t0), h, N, prm, settings, sysd.n, int(tol["max_impacts_step"]))
    wall = time.perf_counter() - t_start
    arrays = record.trim(out, counters, modified=meth.reset == "mcva")
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
    # (issue 22) an energy that is not finite from the start (e.g. q0 = 1e300) is a failure, not ok
    bad_start = validation.nonfinite_start(arrays["H"][0], arrays["Ed"][0] if energies else None,
                                           arrays["Hmod"][0] if energies and arrays.get("Hmod") is not None
                                           else None, q0, p0)
    if bad_start and status == tr.OK:
        status, fail, message = tr.NONFINITE, 0, f"{tr.NONFINITE} at t = {t0:.6g}: {bad_start}"
    return tr.Trajectory(
        method=meth.name, system=sysd.name, h=h, T=N * h, t=t0 + h * np.arange(counters["steps"] + 1), **arrays,
        status=status, message=message, fail_step=fail, fail_time=(t0 + fail * h) if fail >= 0 else float("nan"),
        beta=beta, wall_time=wall, tolerances={k: tol[k] for k in DEFAULT_TOLERANCES},
        options={"params": dict(zip(sysd.params, prm.tolist())), "constrained": bool(constrained), **mopts})


def _split_options(options: dict) -> tuple[dict, dict]:
    """(method options, tolerances with defaults) from simulate's **options (unknown names rejected)."""
    mopts = {k: options.pop(k) for k in list(options) if k in _METHOD_OPTIONS}
    unknown = set(options) - set(DEFAULT_TOLERANCES)
    if unknown:
        raise ValueError(f"options: unknown option {sorted(unknown)[0]!r} (known: "
                         f"{', '.join(sorted(set(DEFAULT_TOLERANCES) | _METHOD_OPTIONS | {'params', 'constrained', 'energies'}))})")
    return mopts, DEFAULT_TOLERANCES | options


def _run_loop(mod, q0, p0, t0, h, N, prm, settings, n, max_impacts_step) -> tuple[tuple, dict]:
    """(output buffers, counters) of the compiled loop. The impact record starts at N / 4 + 16
    entries; the loop reports ST_ACCUMULATION also when it is full, which is a buffer size, not
    impacts accumulating (issue 8): then it reruns with room for every impact the caps allow."""
    cap_imp, most = max(64, N // 4 + 16), N * max_impacts_step + 16
    while True:
        out = record.allocate(N, n, cap_imp, 2 * cap_imp + 16)
        info = np.zeros(len(record.COUNTERS), dtype=np.int64)
        # (issue 8) no np.errstate here: the compiled loop never touches numpy's error state, and
        # with NUMBA_DISABLE_JIT=1 the caller's np.errstate(all="raise") must reach the numerics
        # (the floating-point hygiene check of tests/extremes runs the whole loop that way).
        mod.integrate(q0, p0, t0, h, N, prm, settings, out, info)
        counters = dict(zip(record.COUNTERS, info.tolist()))
        full_record = counters["n_impacts"] >= cap_imp
        if not (counters["status"] == record.STATUS_OF["accumulation"] and full_record) or cap_imp >= most:
            return out, counters
        cap_imp = min(4 * cap_imp, most)
