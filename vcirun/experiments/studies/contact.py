"""Hard contact cases, each built from an exact construction and checked against an exact oracle.

- `grazing_case`: normal contact velocity sqrt(2 phi'' depth) -> 0 over decades (`grazing_setup`).
- `boundary_case`: impact exactly at a grid time: phi of the grid state < 0, == 0.0, > 0 by
  round-off (`boundary_start`).
- `dense_case`: two or more impacts in one step (the bouncing ball against its closed form).
- `surface_case`: initial state on phi = 0 (`surface_state`).
- `accumulation_case`: bouncing ball with linear drag through the forced DEL, against its closed form.
"""
from __future__ import annotations

import functools
import math

import numpy as np

from ...run.diagnosis import accumulation_onset
from ...run.resolve import resolve_system
from ...codegen.build import load_module
from ...codegen.kernel_set import SYSTEM_KERNELS
from ...scenes.oracles import ball_exact, ball_exact_onset, ball_position
from ...scenes.registry import find_scene
from ...scenes.scene import StudyHooks
from ...reference_solution.exact import l2_error, reference
from .outcome import cause, compiled, outcome, run

__all__ = ["grazing_setup", "grazing_case", "boundary_start", "boundary_case", "dense_case", "surface_state",
           "surface_case", "accumulation_case"]


def _hooks(system) -> StudyHooks:
    """What the scene `system` offers these studies (vcirun.scenes.scene.StudyHooks; none for a YAML system)."""
    found = find_scene(str(system))
    return (found[0].study if found is not None else None) or StudyHooks()


# --- grazing -----------------------------------------------------------------------------------

def grazing_setup(system, depth, *, beta=None, params=None, horizon=10.0) -> dict:
    """A grazing contact of given penetration depth for `system`: the unconstrained exact motion
    (DOP853, rtol 1e-12) is followed to its first local minimum of phi (phi' = 0, phi'' > 0), then
    translated so that this minimum lies `depth` inside the constraint: for the cart-pendulum the
    initial height (y is cyclic: V is linear and M independent of y), for the double pendulum the
    wall (w = x_max - depth). The contact's normal velocity is then ~ sqrt(2 phi'' depth).
    The scene says how (its StudyHooks: free_params, graze).
    Returns system name, params, q0, p0, t_star, phidd (phi'' at the minimum), vn, T."""
    from scipy.integrate import solve_ivp

    name = str(system)
    s = resolve_system(name)
    hooks = _hooks(name)
    if hooks.graze is None:
        raise ValueError(f"grazing_setup: no translation known for {name}")
    base = dict(params or {}) | hooks.free_params   # the constraint out of reach: the unconstrained motion
    prm = s.param_values(base)
    mod = load_module(s, SYSTEM_KERNELS)  # the continuous dynamics only
    q0, p0 = s.initial_state(beta=beta, params=prm)
    n = s.n
    buf = np.empty(2 * n)
    g = np.empty(n)

    def rhs(t, y):
        mod.hamilton_rhs(y, prm, buf)
        return buf.copy()

    def phidot(t, y):
        mod.sys_dphi(y[:n], prm, g)
        mod.hamilton_rhs(y, prm, buf)
        return float(g @ buf[:n])

    phidot.direction = 1.0
    phidot.terminal = True
    sol = solve_ivp(rhs, (0.0, horizon), np.concatenate([q0, p0]), method="DOP853", rtol=1e-12, atol=1e-12,
                    events=phidot, dense_output=True)
    if not sol.t_events[0].size:
        raise RuntimeError(f"grazing_setup: no local minimum of phi within {horizon} s for {name}")
    ts = float(sol.t_events[0][0])
    ys = sol.sol(ts)
    phimin = float(mod.sys_phi(ys[:n], prm))
    eps = 1e-6  # phi'' by a central difference of phi' on the dense output
    phidd = (phidot(ts + eps, sol.sol(ts + eps)) - phidot(ts - eps, sol.sol(ts - eps))) / (2 * eps)
    q0, out_params = hooks.graze(q0.copy(), dict(params or {}), phimin, depth)
    vn = math.sqrt(2 * phidd * depth) if depth > 0 else 0.0
    return {"system": name, "params": out_params, "q0": q0, "p0": p0.copy(), "t_star": ts, "phidd": phidd,
            "vn": vn, "depth": depth}


@functools.lru_cache(maxsize=64)
def _grazing_prepared(system, depth, beta, after):
    """Setups of the grazing run and of the clear run (-depth) with their exact references (cached:
    they do not depend on the method)."""
    g = grazing_setup(system, depth, beta=beta)
    c = grazing_setup(system, -depth, beta=beta)
    T = g["t_star"] + after
    ref = reference(system, T=T, q0=g["q0"], p0=g["p0"], params=g["params"], rtol=1e-12, check_accuracy=False)
    refc = reference(system, T=T, q0=c["q0"], p0=c["p0"], params=c["params"], rtol=1e-12, check_accuracy=False)
    return g, c, T, ref, refc


def grazing_case(system, method, depth, *, h, beta=None, after=0.5) -> dict:
    """Run the grazing setup (horizon t_star + after) and compare with the exact reference and with
    the run whose motion stays `depth` clear of the constraint (no contact at all).
    Stated bound for an ok run: err <= err_clear + 10 vn (T - t_star) + 1e-9, i.e. at most the
    effect of a missed reflection of normal velocity vn (the dip may fall between grid points),
    where err = max over the grid of |q - q_ref|."""
    g, c, T, ref, refc = _grazing_prepared(str(system), float(depth), None if beta is None else float(beta),
                                           float(after))
    out = {"system": str(system), "method": method, "depth": depth, "h": h, "vn": g["vn"], "t_star": g["t_star"]}
    tr, crash = run(system, method, h=h, T=T, q0=g["q0"], p0=g["p0"], params=g["params"])
    trc, _ = run(system, method, h=h, T=T, q0=c["q0"], p0=c["p0"], params=c["params"])
    out.update(status=outcome(tr, crash), cause=cause(tr), ref_impacts=int(len(ref.impacts)))
    if trc is not None and trc.ok:
        out["err_clear"] = float(np.max(np.abs(trc.q - refc(trc.t))))
    if tr is not None:
        out["impacts"] = int(len(tr.impacts))
        if tr.ok:
            out["err"] = float(np.max(np.abs(tr.q - ref(tr.t))))
            out["bound"] = out.get("err_clear", np.nan) + 10 * g["vn"] * (T - g["t_star"]) + 1e-9
    return out



# --- impacts exactly at a step boundary --------------------------------------------------------

def boundary_start(system, method, q_imp, p_imp, k, h, *, params=None, max_nudge=24, max_trials=60000):
    """Initial states whose run of `method` reaches the impact state (q_imp, p_imp) after exactly k
    full steps h. The method's full map is symmetric and the system reversible, so k backward
    steps (full map applied to (q, -p)) land on such a state to round-off; then one component of
    (q0, p0) at a time is moved by single ulps until the k-th grid state has phi < 0, phi == 0.0
    and phi > 0 (the three ways a grid point can sit on the surface; exact 0.0 needs a component
    that moves phi_k by less than its ulp). Returns {'neg'|'zero'|'pos': (q0, p0, phi_k)}."""
    s, prm, mod = compiled(system, method, params)
    n = s.n
    q, p = np.asarray(q_imp, float).copy(), -np.asarray(p_imp, float)
    qt, pt, vt = np.empty(n), np.empty(n), np.empty(n)
    for _ in range(k):
        it, _ = mod.full(q, p, h, 0.0, prm, 1e-14, 50, qt, pt, vt)
        if it < 0:
            raise RuntimeError("boundary_start: backward step failed")
        q, p = qt.copy(), pt.copy()
    x0 = np.concatenate([q, -p])

    def phi_k(x):
        qa, pa = x[:n].copy(), x[n:].copy()
        for _ in range(k):
            mod.full(qa, pa, h, 0.0, prm, 1e-12, 50, qt, pt, vt)
            qa, pa = qt.copy(), pt.copy()
        return float(mod.sys_phi(qa, prm))

    found = {}
    for comp in range(2 * n):
        for j in range(max_nudge + 1):
            for sgn in ((1,) if j == 0 else (1, -1)):
                x = x0.copy()
                for _ in range(j):
                    x[comp] = np.nextafter(x[comp], sgn * np.inf)
                f = phi_k(x)
                key = "zero" if f == 0.0 else ("neg" if f < 0 else "pos")
                if key not in found:
                    found[key] = (x[:n].copy(), x[n:].copy(), f)
            if len(found) == 3:
                return found
    # phi_k can move in steps of several ulps per nudge of any one component (the cart-pendulum's y:
    # 16 ulps of phi_k per ulp of y0): combine two components, whose steps interleave
    span = range(-12, 13)
    for ci in range(2 * n):
        for cj in range(ci + 1, 2 * n):
            for a in span:
                for b in span:
                    x = x0.copy()
                    for c, m in ((ci, a), (cj, b)):
                        for _ in range(abs(m)):
                            x[c] = np.nextafter(x[c], math.copysign(np.inf, m))
                    f = phi_k(x)
                    if f == 0.0:
                        found["zero"] = (x[:n].copy(), x[n:].copy(), f)
                        return found
    # The full map honours newton_tol, not round-off: phi_k then scatters by many ulps per nudge and
    # exact cancellation is a matter of trials. Seeded random nudges of every component around the
    # start with the smallest |phi_k| so far, of widths 1 .. 256 ulps drawn per trial: the search
    # walks down to the last representable values around 0 and then samples them densely. (Uniform
    # +-256-ulp nudges around x0 alone spread phi_k over ~2e4 representable values on the
    # cart-pendulum (MCVAA; no zero in 3000 trials), so whether 60000 trials hit 0.0 depended on the
    # platform's last bits; this search hit it after ~10^4 trials, 0.8 s.)
    rng = np.random.default_rng(20140527)
    best, fbest = x0, phi_k(x0)
    for _ in range(max_trials):
        width = int(2 ** rng.integers(0, 9))
        x = best.copy()
        for c in range(2 * n):
            x[c] = x[c] + int(rng.integers(-width, width + 1)) * np.spacing(x[c])
        f = phi_k(x)
        if f == 0.0:
            found["zero"] = (x[:n].copy(), x[n:].copy(), f)
            break
        if abs(f) < abs(fbest):
            best, fbest = x, f
    return found


def boundary_case(system, method, *, h, k, T, beta=None, params=None) -> dict:
    """Impact exactly at t = k h (the grid state's phi < 0, == 0.0, > 0 by round-off), built from the
    exact first impact of the scene's default motion. Checks per variant: status, impact time
    against k h, impact count against the exact reference from the same state, L2 error."""
    s = resolve_system(system)
    ref0 = reference(system, T=T, beta=beta, params=params, check_accuracy=False)
    te = float(ref0.impacts[0])
    seg = ref0.segments[0]
    y = seg[2](te)
    q_imp, p_imp = y[: s.n], y[s.n:]
    starts = boundary_start(system, method, q_imp, p_imp, k, h, params=params)
    out = {"system": str(system), "method": method, "h": h, "k": k, "variants": {}}
    finals = {}
    for key in ("neg", "zero", "pos"):
        if key not in starts:
            out["variants"][key] = {"status": "not constructed"}
            continue
        q0, p0, f = starts[key]
        tr, crash = run(system, method, h=h, T=T, q0=q0, p0=p0, params=params)
        rec = {"phi_k": f, "status": outcome(tr, crash)}
        if tr is not None and tr.ok:
            ref = reference(system, T=T, q0=q0, p0=p0, params=params, check_accuracy=False)
            rec.update(impacts=int(len(tr.impacts)), ref_impacts=int(len(ref.impacts)),
                       t_first=float(tr.impacts[0]) if len(tr.impacts) else float("nan"),
                       dt_first=float(tr.impacts[0] - k * h) if len(tr.impacts) else float("nan"),
                       l2=l2_error(tr, ref), min_partial=float(np.min(tr.partial_steps)) if len(tr.partial_steps) else
                       float("nan"))
            finals[key] = np.concatenate([tr.q[-1], tr.p[-1]])
        out["variants"][key] = rec
    if len(finals) >= 2:
        v = list(finals.values())
        out["spread_final"] = float(max(np.max(np.abs(a - b)) for a in v for b in v))
    return out



# --- several impacts in one step ---------------------------------------------------------------

def dense_case(system, method, *, h, T, beta=None, q0=None, p0=None, params=None) -> dict:
    """A motion with impacts less than one step apart (several in one step), against the exact
    reference, or the scene's closed form where it has one (the bouncing ball)."""
    tr, crash = run(system, method, h=h, T=T, beta=beta, q0=q0, p0=p0, params=params)
    out = {"system": str(system), "method": method, "h": h, "T": T, "status": outcome(tr, crash),
           "cause": cause(tr)}
    if tr is None or not tr.ok:
        return out
    per_step = np.bincount(np.floor((tr.impacts + 1e-12 * h) / h).astype(int)) if len(tr.impacts) else np.zeros(1)
    out.update(impacts=int(len(tr.impacts)), max_per_step=int(per_step.max()))
    closed_form = _hooks(system).closed_form
    if closed_form is not None:
        s = resolve_system(system)
        prm = dict(zip(s.params, s.param_values(params)))
        times, yex = closed_form(tr.q[0], prm, T, tr.t)
        out.update(ref_impacts=int(len(times)), err=float(np.max(np.abs(tr.q[:, 0] - yex))))
        if len(times) == len(tr.impacts):
            out["dt_impacts"] = float(np.max(np.abs(times - tr.impacts)))
    else:
        ref = reference(system, T=T, beta=beta, q0=q0, p0=p0, params=params)
        out.update(ref_impacts=int(len(ref.impacts)), l2=l2_error(tr, ref), ref_accuracy=ref.accuracy,
                   err=float(np.max(np.abs(tr.q - ref(tr.t)))))
        if len(ref.impacts) == len(tr.impacts):
            out["dt_impacts"] = float(np.max(np.abs(ref.impacts - tr.impacts)))
    return out



# --- initial state on the constraint surface ----------------------------------------------------

def surface_state(system, kind, params=None):
    """(q0, p0) on phi = 0. kind: 'out' (moving away), 'in' (moving into the constraint: the exact
    motion starts with a reflection), 'rest' (zero velocity, pushed in by gravity: resting contact,
    no elastic motion exists; cart-pendulum only: gravity pulls the double pendulum's tip away from
    its wall), 'lift' (zero normal velocity but accelerating away: tangential start).
    The scene builds the state (its StudyHooks.surface): the cart-pendulum on y = 0, the double
    pendulum with its second tip on the wall x = w = 1.2."""
    s = resolve_system(system)
    prm = s.param_values(params)
    name = str(system)
    surface = _hooks(name).surface
    if surface is None:
        raise ValueError(f"surface_state: no construction for {name}")
    q, qd = surface(kind, {k: float(v) for k, v in zip(s.params, prm)})
    return s.legendre(q, np.asarray(qd, float), prm)


def surface_case(system, method, kind, *, h, T, params=None, resting_contact=True) -> dict:
    """Start on phi = 0 (see surface_state); ok runs are compared with the exact reference, which for
    'in' starts from the reflected state (R^CVA's exact elastic reset at t = 0). 'rest' is held from
    t = 0 by both (resting contact) unless resting_contact=False (then the run fails: no elastic motion)."""
    s = resolve_system(system)
    prm, mod = s.param_values(params), load_module(s, SYSTEM_KERNELS)
    q0, p0 = surface_state(system, kind, params)
    phi0 = float(mod.sys_phi(q0, prm))
    tr, crash = run(system, method, h=h, T=T, q0=q0, p0=p0, params=params, resting_contact=resting_contact)
    out = {"system": str(system), "method": method, "kind": kind, "phi0": phi0, "status": outcome(tr, crash),
           "cause": cause(tr)}
    if tr is None or not tr.ok:
        return out
    qr, pr = q0.copy(), p0.copy()
    if kind == "in":
        g = np.empty(s.n)
        lam = mod.cva_lambda(q0, p0, prm, g)
        pr = p0 + lam * g
    try:
        ref = reference(system, T=T, q0=qr, p0=pr, params=params, resting_contact=resting_contact)
    except RuntimeError as e:
        out["ref"] = str(e)
        return out
    # the reflection at t = 0 of an inward start is an impact of the run, not of the reference
    out.update(impacts=int(len(tr.impacts)), ref_impacts=int(len(ref.impacts)) + (kind == "in"), l2=l2_error(tr, ref),
               first_impact=float(tr.impacts[0]) if len(tr.impacts) else float("nan"))
    return out



# --- impact accumulation -----------------------------------------------------------------------

def accumulation_case(method, *, h, T, y0=1.0, c=2.0, m=1.0, g=10.0, **opts) -> dict:
    """The bouncing ball with linear drag c (forced DEL) settling on the floor. The exact flights
    shrink like 3 m / (c n): impacts become denser than any grid at the exact onset (the impact
    after which every flight is shorter than h). Outcome: status accumulation with the onset it
    reports (vcirun.run.diagnosis.accumulation_onset; with resting_contact=False), or an ok run whose late bounce
    height is the error against the exact motion (which lies on the floor to within g h^2 / 8 after the
    onset); with held contacts (the default) the run records when the floor is first held."""
    params = {"c": c, "m": m, "g": g}
    tr, crash = run("bouncing_ball", method, h=h, T=T, q0=np.array([y0]), p0=np.array([0.0]), params=params, **opts)
    times, speeds = ball_exact(y0, g, c / m, T, min_flight=1e-2 * h)  # later: y_exact < g (h/100)^2 / 8
    exact_onset = ball_exact_onset(times, h)
    out = {"method": method, "h": h, "T": T, "c": c, "status": outcome(tr, crash), "exact_onset": exact_onset,
           "cause": cause(tr)}
    if tr is None:
        return out
    out.update(impacts=int(len(tr.impacts)), fail_time=tr.fail_time, wall_time=tr.wall_time)
    if tr.status == "accumulation":
        out["onset"] = accumulation_onset(tr.impacts, h)
    held = np.flatnonzero(np.asarray(tr.contact_active).any(axis=1)) if np.size(tr.contact_active) else []
    if len(held):  # resting contact: the floor is held from here on
        out["held_from"] = float(tr.t[held[0]])
    yex = ball_position(tr.t, y0, g, c / m, times, speeds)
    err = np.abs(tr.q[:, 0] - yex)
    out["err"] = float(err.max())
    late = tr.t >= exact_onset if np.isfinite(exact_onset) else np.zeros_like(tr.t, bool)
    if late.any():
        out["err_after_onset"] = float(err[late].max())
    if len(tr.impacts) > 2:
        out["last_interval"] = float(tr.impacts[-1] - tr.impacts[-2])
    return out
