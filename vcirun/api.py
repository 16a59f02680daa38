"""The Python API: `simulate`, `reference`, `l2_error`. The CLI and the sweep runner go through these."""
from __future__ import annotations

import hashlib
import math
import os
import time
from pathlib import Path

import numpy as np

from . import trajectory as tr
from . import validation
from .codegen import build
from .codegen.build import load_module
from .methods import resolve_method
from .scenedata import SystemData, check_mass_matrix, scene_args, scene_data

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
    if q0 is not None or p0 is not None:
        if q0 is None or p0 is None:
            raise ValueError("initial state: give both q0 and p0 (or beta)")
        q0, p0 = np.asarray(q0, float).ravel(), np.asarray(p0, float).ravel()
        kind = "state"
    elif beta is not None:
        if d.ic_map is None:
            raise ValueError(f"beta: system {d.name} has no initial-condition map; give q0 and p0")
        qq, qdot = d.ic_map(float(beta))
        q0, p0 = np.array(qq, dtype=float), np.array(qdot, dtype=float)
        kind = "legendre"
    elif d.default_q0 is not None:
        q0, p0 = np.array(d.default_q0, float), np.array(d.default_p0, float)
        kind = "state"
    else:
        raise ValueError(f"initial state: system {d.name} needs q0 and p0 (or beta)")
    if q0.shape != (d.n,) or p0.shape != (d.n,):
        raise ValueError(f"initial state: q0 and p0 must have length {d.n}")
    if sysm is not None:
        sysm.check_hyperregular(q0, prm)
    return kind, q0, p0, sysm is not None


def _initial_state(d: SystemData, mod, start, prm):
    """(q0, p0) from `_start_state`. The Legendre transform uses the module's compiled M(q) on every
    path, so warm and cold starts compute the same bits; on the warm path the hyperregularity check
    uses it too (compiled: mass_matrix_ok; numpy's check then only words the error)."""
    kind, q0, p0, checked = start
    if kind == "legendre" or not checked:
        q0 = np.ascontiguousarray(q0, dtype=float)
        Mq = np.empty((q0.shape[0], q0.shape[0]))
        ok = mod.mass_matrix_ok(q0, prm, Mq)   # M(q0) once, for the check and the Legendre transform
        if not checked and not ok:
            check_mass_matrix(d.name, q0, Mq)
        if kind == "legendre":
            p0 = Mq @ p0
    return q0, p0


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
    mopts = {k: options.pop(k) for k in list(options) if k in _METHOD_OPTIONS}
    unknown = set(options) - set(DEFAULT_TOLERANCES)
    if unknown:
        raise ValueError(f"options: unknown option {sorted(unknown)[0]!r} (known: "
                         f"{', '.join(sorted(set(DEFAULT_TOLERANCES) | _METHOD_OPTIONS | {'params', 'constrained', 'energies'}))})")
    validation.check_simulate_args(h=h, T=T, t0=t0, beta=beta, q0=q0, p0=p0, params=params, constrained=constrained,
                                   energies=energies, tolerances=options, system=system)  # (issue 22)
    tol = DEFAULT_TOLERANCES | options
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
    n = sysd.n
    cap_imp = max(64, N // 4 + 16)
    t_start = time.perf_counter()
    while True:
        # (np.empty where the loop writes every entry that is read back: rows up to the last
        # step reached, impacts and partial steps up to their counts, info)
        out = dict(
            Q=np.empty((N + 1, n)), P=np.empty((N + 1, n)), Hs=np.full(N + 1, np.nan), Eds=np.full(N + 1, np.nan),
            Hm=np.full(N + 1, np.nan), imp_t=np.empty(cap_imp), imp_q=np.empty((cap_imp, n)),
            imp_pm=np.empty((cap_imp, n)), imp_pp=np.empty((cap_imp, n)), imp_step=np.zeros(N, dtype=np.bool_),
            partial_log=np.empty(2 * cap_imp + 16), iters_log=np.zeros(N, dtype=np.int64),
            info=np.zeros(5, dtype=np.int64))
        # (issue 8) no np.errstate here: the compiled loop never touches numpy's error state, and
        # with NUMBA_DISABLE_JIT=1 the caller's np.errstate(all="raise") must reach the numerics
        # (the floating-point hygiene check of tests/extremes runs the whole loop that way).
        mod.integrate(q0, p0, float(t0), h, N, prm, bool(constrained), float(tol["newton_tol"]), int(tol["max_iter"]),
                      float(tol["event_tol"]), int(tol["max_impacts_step"]), *out.values(), bool(energies))
        # (issue 8) the loop reports ST_ACCUMULATION also when the impact record is full; that is a
        # buffer size, not impacts accumulating: rerun with room for every impact the caps allow.
        full_record = int(out["info"][2]) >= cap_imp
        if not (int(out["info"][0]) == 4 and full_record) or cap_imp >= N * int(tol["max_impacts_step"]) + 16:
            break
        cap_imp = min(4 * cap_imp, N * int(tol["max_impacts_step"]) + 16)
    wall = time.perf_counter() - t_start
    info = out["info"]
    status_code, fail, n_imp, n_par, steps = info.tolist()
    status = tr.STATUS_CODES[status_code]
    K = steps + 1  # grid points actually reached
    t = t0 + h * np.arange(N + 1)
    message = ""
    if status != tr.OK:
        message = (f"{status} in step {fail} (t = {t0 + fail * h:.6g}) from q = {out['Q'][fail].tolist()}, "
                   f"p = {out['P'][fail].tolist()}")
        cause = _failure_cause(mod, status, out["Q"][: fail + 1], out["P"][fail], t0, fail, h, prm, tol,
                               float(out["Hs"][0]), out["imp_t"][:n_imp])
        if cause:
            message += f"; cause: {cause}"
    # (issue 22) an energy that is not finite from the start (e.g. q0 = 1e300) is a failure, not ok
    bad_start = validation.nonfinite_start(out["Hs"][0], out["Eds"][0] if energies else None,
                                           out["Hm"][0] if energies and meth.reset == "mcva" else None, q0, p0)
    if bad_start and status == tr.OK:
        status, fail, message = tr.NONFINITE, 0, f"{tr.NONFINITE} at t = {t0:.6g}: {bad_start}"
    return tr.Trajectory(
        method=meth.name, system=sysd.name, h=h, T=N * h, t=t[:K], q=out["Q"][:K], p=out["P"][:K], H=out["Hs"][:K],
        Ed=out["Eds"][:K], Hmod=out["Hm"][:K] if meth.reset == "mcva" else None,
        impacts=out["imp_t"][:n_imp].copy(), impact_q=out["imp_q"][:n_imp].copy(),
        impact_p_minus=out["imp_pm"][:n_imp].copy(), impact_p_plus=out["imp_pp"][:n_imp].copy(),
        impact_step=out["imp_step"][:steps].copy(), partial_steps=out["partial_log"][:n_par].copy(),
        newton_iters=out["iters_log"][:steps].copy(), status=status, message=message,
        fail_step=fail, fail_time=(t0 + fail * h) if fail >= 0 else float("nan"), beta=beta, wall_time=wall,
        tolerances={k: tol[k] for k in ("newton_tol", "event_tol", "max_iter", "max_impacts_step")},
        options={"params": dict(zip(sysd.params, prm.tolist())), "constrained": bool(constrained), **mopts})


# --- failure causes (issue 8: every stop names its cause) ----------------------------------------

def accumulation_onset(impacts, h) -> float:
    """Start of the final run of impacts that each follow the previous one by less than one step h
    (impacts denser than the grid): the time an accumulation began. nan without impacts."""
    imp = np.asarray(impacts, float)
    if imp.size == 0:
        return float("nan")
    k = imp.size - 1
    while k > 0 and imp[k] - imp[k - 1] < h:
        k -= 1
    return float(imp[k])


def _fastest_mode(mod, q, p, prm) -> float:
    """Largest |eigenvalue| of the linearized Hamilton's equations at (q, p) (central differences): the
    fastest local time scale 1/omega of the motion (a nearly singular M makes some modes fast)."""
    n = q.shape[0]
    y = np.concatenate([q, p])
    J = np.empty((2 * n, 2 * n))
    fa, fb = np.empty(2 * n), np.empty(2 * n)
    for j in range(2 * n):
        e = 1e-6 * max(1.0, abs(y[j]))
        ya, yb = y.copy(), y.copy()
        ya[j] += e
        yb[j] -= e
        mod.hamilton_rhs(ya, prm, fa)
        mod.hamilton_rhs(yb, prm, fb)
        J[:, j] = (fa - fb) / (2 * e)
    return float(np.max(np.abs(np.linalg.eigvals(J))))


def _failure_cause(mod, status, Q, p, t0, fail, h, prm, tol, H0, impacts) -> str:
    """A short diagnosis of a failed run from its grid states Q[0..fail] (p: momentum at Q[fail]);
    "" if nothing specific is found (the status itself then says what failed). Never raises."""
    try:
        q = Q[-1]
        t = t0 + fail * h
        n = q.shape[0]
        causes = []
        if status == tr.ACCUMULATION:
            onset = accumulation_onset(impacts, h)
            k = int(np.sum(impacts >= onset)) if np.isfinite(onset) else 0
            last = float(impacts[-1] - impacts[-2]) if len(impacts) > 1 else float("nan")
            return (f"impacts accumulate: accumulation began at t = {onset:.9g} ({k} impacts since, each less "
                    f"than one step h after the previous, the last {last:.3g} apart; limit: more than "
                    f"max_impacts_step = {int(tol['max_impacts_step'])} impacts in one step or such a run "
                    f"longer than max_impacts_step steps); an event-driven scheme cannot follow impacts denser "
                    f"than its grid (the motion is settling into contact)")
        if status == tr.EVENT_FAILED:
            return "the collision-time search did not bracket the root to event_tol * h within 200 iterations"
        A = np.empty((n, n))
        worst, t_worst = 0.0, t
        idx = np.union1d(np.linspace(0, len(Q) - 1, 500).astype(int), np.arange(max(0, len(Q) - 100), len(Q)))
        for k in idx:  # conditioning of M along the motion
            mod.sys_M(Q[k], prm, A)
            c = float(np.linalg.cond(A)) if np.all(np.isfinite(A)) else np.inf
            if not c <= worst:
                worst, t_worst = c, t0 + k * h
        if not worst < 1e4:  # built-in scenes at default parameters: cond(M) < 30
            causes.append(f"mass matrix nearly singular along the motion (cond(M) = {worst:.3g} at t = {t_worst:.6g})")
        elif status == tr.NEWTON_FAILED and worst >= 1e3 and t_worst >= t - 100 * h:
            # conditioning still moderate on the grid but worst right before the failure: the step
            # that failed was heading into a singular configuration between grid points
            causes.append(f"mass matrix approaching singularity at the failure (cond(M) = {worst:.3g} at "
                          f"t = {t_worst:.6g}, the largest along the motion)")
        H = float(mod.hamiltonian(q, p, prm))
        if not np.isfinite(H) or abs(H - H0) > 10.0 * max(1.0, abs(H0)):
            causes.append(f"the discrete motion had diverged (H = {H:.4g}, H(0) = {H0:.4g}): step h too large")
        elif status in (tr.NEWTON_FAILED, tr.NONFINITE):
            w = _fastest_mode(mod, q, p, prm)
            if h * w > 2.0:
                causes.append(f"step h too large for the fastest local mode of the motion (h * omega = {h * w:.3g} "
                              f"> 2, the stability limit of the Verlet-type maps)")
        if status == tr.RESET_FAILED and not causes:
            qt, pt, vt = np.empty(n), np.empty(n), np.empty(n)
            code, _, E_pre, _ = mod.collision_time(q, p, h, h, t, prm, float(tol["newton_tol"]), int(tol["max_iter"]),
                                                   float(tol["event_tol"]), qt, pt, vt)
            if code == 1:
                g = np.empty(n)
                mod.sys_dphi(qt, prm, g)
                mod.sys_M(qt, prm, A)
                Wg = np.linalg.solve(A, g)
                vn = float(Wg @ pt)                       # d phi / dt before the impact
                gWg = float(g @ Wg)
                ke_n = 0.5 * vn * vn / gWg if gWg > 0 else 0.0   # kinetic energy of the normal motion
                speed = float(np.linalg.norm(np.linalg.solve(A, pt)) * np.linalg.norm(g))
                mismatch = abs(E_pre - float(mod.hamiltonian(qt, pt, prm)))
                w = _fastest_mode(mod, qt, pt, prm)
                if abs(vn) <= 1e-6 * speed:
                    causes.append(f"zero normal velocity at the contact (d phi/dt = {vn:.3g}; grazing or resting "
                                  "contact): no elastic reset exists")
                elif ke_n < 10 * mismatch:
                    causes.append(f"no reflecting root of the reset equations: the normal kinetic energy "
                                  f"{ke_n:.3g} (d phi/dt = {vn:.3g}, effective mass 1/(g^T M^-1 g) = {1 / gWg:.3g}) "
                                  f"is not large against the energy error the reset must absorb (pre-impact "
                                  f"discrete energy - H = {mismatch:.3g}): a grazing contact or a tiny effective mass")
                elif h * w > 2.0:
                    causes.append(f"no reflecting root of the reset equations: step h too large for the fastest "
                                  f"local mode at the impact (h * omega = {h * w:.3g} > 2)")
                else:
                    causes.append(f"Newton found no reflecting root of the reset equations (cond(M) at the impact "
                                  f"= {np.linalg.cond(A):.3g}, h * omega = {h * w:.3g}, normal kinetic energy "
                                  f"{ke_n:.3g})")
        if status == tr.NONFINITE and not causes:
            causes.append("the state overflowed")
        return "; ".join(causes)
    except Exception:  # a diagnosis must never turn a failure record into an exception
        return ""
