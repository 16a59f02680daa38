"""Numerical stability at the extremes (issue 8): the stress suite's cases, oracles and report.

Every function here runs one family of hard cases through the public API (`vcirun.simulate`,
`vcirun.reference`) and returns plain data (dicts of floats and strings, JSON-ready) that the study
(`bench/extremes_study.py`, configured by `configs/extremes.yaml`) renders into `docs/extremes.md`
and that `tests/extremes` asserts on. Nothing here changes how a run is computed.

Cases (outcome = the status, and for `ok` the error against an exact oracle):

- step size      `step_limit`: log scan of h from 1e-5 up, then bisection of the first ok -> failure
                 transition: the stable range [1e-5, h*] and the status just past h*.
- long horizons  `long_run`: 1e6 steps, drift of H (and of the truncated modified Hamiltonian for
                 the MCVA family) as the least-squares slope over time and the running maximum.
- contact        `grazing_case` (normal contact velocity sqrt(2 a depth) -> 0 over decades),
                 `boundary_case` (impact exactly at a grid time: phi of the grid state < 0, == 0.0,
                 > 0 by round-off), `dense_case` (two or more impacts in one step),
                 `surface_case` (initial state on phi = 0), `accumulation_case` (bouncing ball with
                 linear drag through the forced DEL, against its closed form).
- parameters     `energy_case` (Xi(beta), beta up to 100: the pendulum rotates), `mass_ratio_case`
                 (m2/m1 = 1e-4 .. 1e4), `singular_mass_case` (double pendulum, m1 -> 0 with aligned
                 links: cond(M) = 4/m1).
- hygiene        `hygiene_case`: the whole loop run uncompiled (NUMBA_DISABLE_JIT=1) inside
                 np.errstate(all="raise"), so any overflow / invalid operation / division by zero
                 raises.
"""
from __future__ import annotations

import functools
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from .api import accumulation_onset, resolve_system, simulate
from .codegen.build import load_module
from .methods import METHODS, resolve_method
from .reference import l2_error, reference

__all__ = ["run", "step_limit", "drift_slope", "long_run", "ball_exact", "ball_exact_onset", "grazing_setup",
           "grazing_case", "boundary_start", "boundary_case", "dense_case", "surface_case", "accumulation_case",
           "energy_case", "mass_ratio_case", "singular_mass_case", "hygiene_case", "render_markdown",
           "load_study_config", "run_study"]


# --- running without ever raising --------------------------------------------------------------

def run(system, method, **kw):
    """simulate(...) that turns an exception into a record: (trajectory or None, '' or 'rejected: ...'
    (ValueError: input simulate() refuses, with the field and cause) or 'crash: ...' (anything else))."""
    try:
        return simulate(system, method, **kw), ""
    except ValueError as e:  # bad input, named by simulate(): a rejection, not a crash
        return None, f"rejected: {e}"
    except Exception as e:  # a crash is a finding, never the end of the study
        return None, f"crash: {type(e).__name__}: {e}"


def _outcome(tr, crash):
    return crash if tr is None else tr.status


def _cause(tr) -> str:
    if tr is None or "; cause: " not in tr.message:
        return ""
    return tr.message.split("; cause: ", 1)[1]


def _module(system, method="CVA", params=None):
    s = resolve_system(system)
    return s, s.param_values(params), load_module(s, resolve_method(method).kernel_set())


# --- step size ---------------------------------------------------------------------------------

def step_limit(system, method, *, T, beta=None, q0=None, p0=None, params=None, h_min=1e-5, h_max=2.0,
               per_decade=4, rel=1e-3) -> dict:
    """Scan h = h_min * 10^(k / per_decade) up to h_max (every point run: any crash is recorded), then
    bisect (geometrically, to h_past / h_limit < 1 + rel) between the last ok h below the first
    failure and that failure. Returns h_limit (largest ok h of the range [h_min, h_limit] in which
    every scanned h is ok), h_past with its status and message, the energy error at h_limit, the
    scan, and the ok steps above the first failure (non-monotone behaviour)."""
    kw = dict(T=T, beta=beta, q0=q0, p0=p0, params=params)
    ks = np.arange(0, int(math.floor(per_decade * math.log10(h_max / h_min) + 1e-9)) + 1)
    grid = [float(h_min * 10 ** (k / per_decade)) for k in ks]
    scan, crashes, dHs = [], [], []
    E_scale = np.nan
    for h in grid:
        tr, crash = run(system, method, h=h, **kw)
        scan.append((h, _outcome(tr, crash)))
        dHs.append(_dH(tr) if tr is not None and tr.ok else np.inf)
        if tr is not None and not np.isfinite(E_scale):
            E_scale = energy_scale(system, tr, params)
        if crash and not crash.startswith("rejected"):
            crashes.append((h, crash))
    first_fail = next((i for i, (_, st) in enumerate(scan) if st != "ok"), None)
    # the accuracy limit: largest scanned h below which every run keeps max |H - H0| <= 10 % E_scale
    acc = next((i for i, d in enumerate(dHs) if not d <= 0.1 * E_scale), len(dHs))
    out = {"system": str(system), "method": method, "T": T, "h_min": h_min, "h_max": h_max, "scan": scan,
           "crashes": crashes, "dH_scan": dHs, "E_scale": E_scale, "h_energy10": grid[acc - 1] if acc > 0 else None}
    if first_fail is None:
        tr, _ = run(system, method, h=grid[-1], **kw)
        out.update(h_limit=grid[-1], h_past=None, status_past="(none up to h_max)", message_past="",
                   dH_at_limit=_dH(tr), ok_above=[])
        return out
    if first_fail == 0:
        out.update(h_limit=None, h_past=grid[0], status_past=scan[0][1], message_past="", dH_at_limit=np.nan,
                   ok_above=[])
        return out
    a, b = grid[first_fail - 1], grid[first_fail]
    tb, cb = run(system, method, h=b, **kw)
    while b / a > 1 + rel:
        c = math.sqrt(a * b)
        tc, cc = run(system, method, h=c, **kw)
        if cc and not cc.startswith("rejected"):
            crashes.append((c, cc))
        if tc is not None and tc.ok:
            a = c
        else:
            b, tb, cb = c, tc, cc
    ta, _ = run(system, method, h=a, **kw)
    out.update(h_limit=a, h_past=b, status_past=_outcome(tb, cb), message_past=(tb.message if tb else cb),
               dH_at_limit=_dH(ta), ok_above=[h for h, st in scan[first_fail:] if st == "ok"])
    return out


def energy_scale(system, tr, params=None) -> float:
    """max(|H(0)|, largest kinetic energy H - V(q) along the run (<= 2000 grid points)): the energy
    against which an energy error is 'small' (H(0) alone can be 0, e.g. the double pendulum)."""
    s, prm, mod = _module(system, "CVA", params)
    idx = np.unique(np.linspace(0, len(tr.t) - 1, 2000).astype(int))
    ke = max(float(tr.H[k] - mod.sys_V(tr.q[k], prm)) for k in idx)
    return max(abs(float(tr.H[0])), ke)


def _dH(tr) -> float:
    if tr is None or len(tr.H) == 0:
        return float("nan")
    return float(np.nanmax(np.abs(tr.H - tr.H[0])))


# --- long horizons -----------------------------------------------------------------------------

def drift_slope(t, E) -> float:
    """Least-squares slope of E(t) - E(0) over t (energy units per unit time); nan if < 2 finite points."""
    t = np.asarray(t, float)
    E = np.asarray(E, float)
    m = np.isfinite(E)
    if m.sum() < 2:
        return float("nan")
    tt = t[m] - t[m].mean()
    return float(np.dot(tt, E[m] - E[m].mean()) / np.dot(tt, tt))


def long_run(system, method, *, h, steps, beta=None, q0=None, p0=None, params=None,
             checkpoints=(10_000, 100_000, 1_000_000)) -> dict:
    """`steps` steps from Xi(beta) (or q0, p0): drift slope and running maximum of |H - H(0)| at each
    checkpoint (and of Hmod for the MCVA family)."""
    tr, crash = run(system, method, h=h, T=steps * h, beta=beta, q0=q0, p0=p0, params=params)
    out = {"system": str(system), "method": method, "h": h, "steps": steps, "status": _outcome(tr, crash)}
    if tr is None:
        return out
    out.update(steps_done=tr.n_steps, impacts=int(len(tr.impacts)), wall_time=tr.wall_time, H0=float(tr.H[0]),
               message=tr.message)
    for name, E in (("H", tr.H), ("Hmod", tr.Hmod)):
        if E is None:
            continue
        dev = np.abs(E - E[0])
        out[f"slope_{name}"] = drift_slope(tr.t, E)
        out[f"maxdev_{name}"] = {int(c): float(np.nanmax(dev[: c + 1])) for c in checkpoints if c <= tr.n_steps}
        out[f"rel_{name}"] = float(np.nanmax(dev) / max(abs(E[0]), 1e-300))
    return out


# --- the bouncing ball with linear drag (closed form) -------------------------------------------

def _flight(v, g, k):
    """Time for y(0) = 0, y'(0) = v > 0 to return to y = 0 under y'' = -g - k y', and the return speed.
    Newton on f(T) = -(g/k) T - (v + g/k) expm1(-k T) / k from the series guess
    T ~ (2 v / g) / (1 + k v / (3 g)); f'(T) = -(return speed), so it is well conditioned."""
    if k == 0.0:
        return 2 * v / g, v
    T = (2 * v / g) / (1 + k * v / (3 * g))
    for _ in range(30):
        e = math.exp(-k * T)
        f = -(g / k) * T - (v + g / k) * math.expm1(-k * T) / k
        df = -(g / k) + (v + g / k) * e
        dT = f / df
        T -= dT
        if abs(dT) <= 1e-15 * T:
            break
    return T, g / k - (v + g / k) * math.exp(-k * T)


def ball_exact(y0, g, k, T, *, min_flight=1e-9, max_impacts=2_000_000):
    """Exact impact times and post-impact speeds of a ball dropped from rest at y0 onto y = 0 with
    y'' = -g - k y' (k = c/m) and elastic impacts, up to time T or until a flight is shorter than
    min_flight (then the ball lies on the floor to within g min_flight^2 / 8). Returns (times, speeds)."""
    if k == 0.0:
        t1 = math.sqrt(2 * y0 / g)
        v = g * t1
    else:
        from scipy.optimize import brentq

        t1 = brentq(lambda s: y0 - (g / k) * s - (g / k**2) * math.expm1(-k * s), 0.0,
                    10 * math.sqrt(2 * y0 / g) + 10.0, xtol=1e-15, rtol=1e-15)
        v = (g / k) * (-math.expm1(-k * t1))
    ts, vs = [t1], [v]
    t = t1
    while t < T and len(ts) < max_impacts:
        dt, v = _flight(v, g, k)
        t += dt
        ts.append(t)
        vs.append(v)
        if dt < min_flight:
            break
    return np.array(ts), np.array(vs)


def ball_position(t, y0, g, k, times, speeds):
    """y(t) of the exact ball (see ball_exact) on the times t; 0 after the last computed impact."""
    t = np.asarray(t, float)
    y = np.zeros_like(t)
    first = t < times[0]
    s = t[first]
    y[first] = y0 - g * s**2 / 2 if k == 0 else y0 - (g / k) * s - (g / k**2) * np.expm1(-k * s)
    j = np.searchsorted(times, t, side="right") - 1
    m = (j >= 0) & (j < len(times) - 1)
    s = t[m] - times[j[m]]
    v = speeds[j[m]]
    y[m] = v * s - g * s**2 / 2 if k == 0 else -(g / k) * s - (v + g / k) * np.expm1(-k * s) / k
    return y


def ball_exact_onset(times, h) -> float:
    """The exact accumulation onset on a grid of step h: the impact after which every flight is
    shorter than h (the flights of the damped ball decrease monotonically)."""
    d = np.diff(times)
    k = np.flatnonzero(d < h)
    return float(times[k[0]]) if k.size else float("nan")


# --- grazing -----------------------------------------------------------------------------------

def grazing_setup(system, depth, *, beta=None, params=None, horizon=10.0) -> dict:
    """A grazing contact of given penetration depth for `system`: the unconstrained exact motion
    (DOP853, rtol 1e-12) is followed to its first local minimum of phi (phi' = 0, phi'' > 0), then
    translated so that this minimum lies `depth` inside the constraint: for the cart-pendulum the
    initial height (y is cyclic: V is linear and M independent of y), for the double pendulum the
    wall (w = x_max - depth). The contact's normal velocity is then ~ sqrt(2 phi'' depth).
    Returns system name, params, q0, p0, t_star, phidd (phi'' at the minimum), vn, T."""
    from scipy.integrate import solve_ivp

    name = str(system)
    s = resolve_system(name)
    base = dict(params or {})
    if name == "double_pendulum":
        base["w"] = 100.0  # out of reach: the unconstrained motion
    prm = s.param_values(base)
    mod = load_module(s, METHODS["CVA"].kernel_set())
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
    out_params = dict(params or {})
    q0 = q0.copy()
    if name == "cart_pendulum":
        q0[0] -= phimin + depth         # phi = y: shift the whole motion down
    elif name == "double_pendulum":
        out_params["w"] = 100.0 - phimin - depth   # phi = w - x_tip: move the wall
    else:
        raise ValueError(f"grazing_setup: no translation known for {name}")
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
    out.update(status=_outcome(tr, crash), cause=_cause(tr), ref_impacts=int(len(ref.impacts)))
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
    s, prm, mod = _module(system, method, params)
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
        rec = {"phi_k": f, "status": _outcome(tr, crash)}
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
    reference (cart-pendulum) or the closed form (bouncing ball without drag)."""
    tr, crash = run(system, method, h=h, T=T, beta=beta, q0=q0, p0=p0, params=params)
    out = {"system": str(system), "method": method, "h": h, "T": T, "status": _outcome(tr, crash),
           "cause": _cause(tr)}
    if tr is None or not tr.ok:
        return out
    per_step = np.bincount(np.floor((tr.impacts + 1e-12 * h) / h).astype(int)) if len(tr.impacts) else np.zeros(1)
    out.update(impacts=int(len(tr.impacts)), max_per_step=int(per_step.max()))
    if str(system) == "bouncing_ball":
        s = resolve_system(system)
        prm = dict(zip(s.params, s.param_values(params)))
        y0 = float(tr.q[0, 0])
        times, speeds = ball_exact(y0, prm["g"], prm["c"] / prm["m"], T)
        times = times[times <= T]
        yex = ball_position(tr.t, y0, prm["g"], prm["c"] / prm["m"], times, speeds)
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
    Cart-pendulum: y = 0; double pendulum: the second tip on the wall x = w = 1.2."""
    s = resolve_system(system)
    prm = s.param_values(params)
    name = str(system)
    if name == "cart_pendulum":
        q = np.array([0.0, {"lift": np.pi}.get(kind, 0.3)])
        qd = {"out": [1.0, 0.5], "in": [-1.0, 0.5], "rest": [0.0, 0.0], "lift": [0.0, 10.0]}[kind]
    elif name == "double_pendulum":
        w = float(prm[list(s.params).index("w")])
        th1 = 0.3
        th2 = math.asin(w - math.sin(th1))    # l1 = l2 = 1: tip exactly at x = w
        q = np.array([th1, th2])
        # normal direction of the tip: d x_tip = cos th1 dth1 + cos th2 dth2
        qd = {"out": [0.0, -1.0], "in": [0.0, 1.0], "lift": [-1.0, math.cos(th1) / math.cos(th2)]}[kind]
    else:
        raise ValueError(f"surface_state: no construction for {name}")
    return s.legendre(q, np.asarray(qd, float), prm)


def surface_case(system, method, kind, *, h, T, params=None) -> dict:
    """Start on phi = 0 (see surface_state); ok runs are compared with the exact reference, which for
    'in' starts from the reflected state (R^CVA's exact elastic reset at t = 0)."""
    s, prm, mod = _module(system, "CVA", params)
    q0, p0 = surface_state(system, kind, params)
    phi0 = float(mod.sys_phi(q0, prm))
    tr, crash = run(system, method, h=h, T=T, q0=q0, p0=p0, params=params)
    out = {"system": str(system), "method": method, "kind": kind, "phi0": phi0, "status": _outcome(tr, crash),
           "cause": _cause(tr)}
    if tr is None or not tr.ok:
        return out
    qr, pr = q0.copy(), p0.copy()
    if kind == "in":
        g = np.empty(s.n)
        lam = mod.cva_lambda(q0, p0, prm, g)
        pr = p0 + lam * g
    try:
        ref = reference(system, T=T, q0=qr, p0=pr, params=params)
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
    reports (vcirun.api.accumulation_onset), or an ok run whose late bounce height is the error
    against the exact motion (which lies on the floor to within g h^2 / 8 after the onset)."""
    params = {"c": c, "m": m, "g": g}
    tr, crash = run("bouncing_ball", method, h=h, T=T, q0=np.array([y0]), p0=np.array([0.0]), params=params, **opts)
    times, speeds = ball_exact(y0, g, c / m, T, min_flight=1e-2 * h)  # later: y_exact < g (h/100)^2 / 8
    exact_onset = ball_exact_onset(times, h)
    out = {"method": method, "h": h, "T": T, "c": c, "status": _outcome(tr, crash), "exact_onset": exact_onset,
           "cause": _cause(tr)}
    if tr is None:
        return out
    out.update(impacts=int(len(tr.impacts)), fail_time=tr.fail_time, wall_time=tr.wall_time)
    if tr.status == "accumulation":
        out["onset"] = accumulation_onset(tr.impacts, h)
    yex = ball_position(tr.t, y0, g, c / m, times, speeds)
    err = np.abs(tr.q[:, 0] - yex)
    out["err"] = float(err.max())
    late = tr.t >= exact_onset if np.isfinite(exact_onset) else np.zeros_like(tr.t, bool)
    if late.any():
        out["err_after_onset"] = float(err[late].max())
    if len(tr.impacts) > 2:
        out["last_interval"] = float(tr.impacts[-1] - tr.impacts[-2])
    return out


# --- energy and parameters ---------------------------------------------------------------------

def energy_case(method, beta, *, hs, T) -> dict:
    """Cart-pendulum from Xi(beta): L2 error against the exact reference per h and the observed order."""
    ref = reference("cart_pendulum", T=T, beta=beta)
    th = ref(np.linspace(0.0, T, 4001))[:, 1]
    out = {"method": method, "beta": beta, "T": T, "ref_impacts": int(len(ref.impacts)),
           "ref_accuracy": ref.accuracy, "theta_span": float(np.ptp(th)), "runs": []}
    for h in hs:
        tr, crash = run("cart_pendulum", method, h=h, T=T, beta=beta)
        r = {"h": h, "status": _outcome(tr, crash), "cause": _cause(tr)}
        if tr is not None and tr.ok:
            r.update(l2=l2_error(tr, ref), impacts=int(len(tr.impacts)), dH=_dH(tr), H0=float(tr.H[0]))
        out["runs"].append(r)
    _order(out["runs"])
    return out


def _order(runs):
    ok = [r for r in runs if "l2" in r]
    for a, b in zip(ok[:-1], ok[1:]):
        if a["l2"] > 0 and b["l2"] > 0:
            b["order"] = math.log(a["l2"] / b["l2"]) / math.log(a["h"] / b["h"])


def mass_ratio_case(method, ratio, *, hs, T, beta=3.2) -> dict:
    """Cart-pendulum with m1 = 1, m2 = ratio (the mass unit is irrelevant: m1 = 1/ratio, m2 = 1 is the
    same run). The mass matrix's condition number over the exact motion is reported (at theta =
    pi/2 it is ~ 4 m2 / m1 for m2 >> m1)."""
    params = {"m1": 1.0, "m2": float(ratio)}
    s = resolve_system("cart_pendulum")
    prm = s.param_values(params)
    ref = reference("cart_pendulum", T=T, beta=beta, params=params)
    Q = ref(np.linspace(0.0, T, 1001))
    cond = max(float(np.linalg.cond(s.mass_matrix(q, prm))) for q in Q)
    out = {"method": method, "ratio": ratio, "T": T, "ref_impacts": int(len(ref.impacts)),
           "ref_accuracy": ref.accuracy, "cond_max": cond, "runs": []}
    for h in hs:
        tr, crash = run("cart_pendulum", method, h=h, T=T, beta=beta, params=params)
        r = {"h": h, "status": _outcome(tr, crash), "cause": _cause(tr)}
        if tr is not None and tr.ok:
            r.update(l2=l2_error(tr, ref), impacts=int(len(tr.impacts)))
        out["runs"].append(r)
    _order(out["runs"])
    return out


def singular_mass_case(method, m1, *, hs, T, q0=None, p0=None, with_reference=True) -> dict:
    """Double pendulum with a nearly massless middle joint: M = [[(m1 + m2) l1^2, m2 l1 l2 c],
    [m2 l1 l2 c, m2 l2^2]], det = m1 m2 l1^2 l2^2 at c = cos(th1 - th2) = 1, so the default release
    (both links horizontal) has cond(M) = 4/m1 at t = 0. m1 = 0 is rejected up front (not
    hyperregular); from a non-aligned start with m1 = 0 the motion reaches singular states."""
    params = {"m1": float(m1)}
    s = resolve_system("double_pendulum")
    prm = s.param_values(params)
    out = {"method": method, "m1": m1, "T": T, "runs": []}
    try:
        q0_, p0_ = s.initial_state(q0=q0, p0=p0, params=prm) if q0 is not None else s.initial_state(params=prm)
    except ValueError as e:
        out["input_error"] = str(e)
        return out
    out["cond0"] = float(np.linalg.cond(s.mass_matrix(q0_, prm)))
    ref = None
    try:  # (stiff: DOP853 needs ~90 s for m1 = 1e-8)
        if with_reference:
            ref = reference("double_pendulum", T=T, q0=q0_, p0=p0_, params=params)
            out.update(ref_impacts=int(len(ref.impacts)), ref_accuracy=ref.accuracy)
    except Exception as e:  # the reference may fail too on a degenerate Lagrangian
        out["ref_error"] = f"{type(e).__name__}: {e}"
    for h in hs:
        tr, crash = run("double_pendulum", method, h=h, T=T, q0=q0_, p0=p0_, params=params)
        r = {"h": h, "status": _outcome(tr, crash), "cause": _cause(tr)}
        if tr is not None:
            r.update(dH=_dH(tr), impacts=int(len(tr.impacts)))
            if tr.ok and ref is not None:
                r["l2"] = l2_error(tr, ref)
        out["runs"].append(r)
    return out


# --- floating-point hygiene --------------------------------------------------------------------

_HYGIENE_SCRIPT = r"""
import json, sys, numpy as np, vcirun
cases = json.loads(sys.argv[1])
out = []
# positive control: the check is live (an overflow inside the uncompiled loop code raises)
from vcirun.api import resolve_system
from vcirun.codegen.build import load_module
from vcirun.methods import METHODS
s = resolve_system("cart_pendulum"); mod = load_module(s, METHODS["CVA"].kernel_set())
with np.errstate(all="raise"):
    try:
        mod.hamiltonian(np.array([0.0, 0.0]), np.array([1e200, 1e200]), s.param_values())
        control = "no exception"
    except FloatingPointError as e:
        control = "FloatingPointError: " + str(e)
for c in cases:
    rec = dict(c)
    try:
        with np.errstate(all="raise"):
            tr = vcirun.simulate(c["system"], c["method"], h=c["h"], T=c["T"], **c.get("kw", {}))
            rec["status"] = tr.status
            rec["impacts"] = int(len(tr.impacts))
            rec["finite"] = bool(np.all(np.isfinite(tr.q)) and np.all(np.isfinite(tr.p)) and np.all(np.isfinite(tr.H)))
        if c.get("reference"):
            # scipy's solve_ivp takes nextafter(0, inf), a subnormal, at t = 0: underflow there is by design
            with np.errstate(all="raise", under="ignore"):
                ref = vcirun.reference(c["system"], T=c["T"], **c.get("kw", {}))
                rec["l2"] = vcirun.l2_error(tr, ref)
    except Exception as e:
        rec["status"] = "raised " + type(e).__name__ + ": " + str(e)
    out.append(rec)
print(json.dumps({"control": control, "cases": out}))
"""


def hygiene_case(cases, *, timeout=600.0) -> dict:
    """Run each {'system', 'method', 'h', 'T', 'kw', 'reference'} with NUMBA_DISABLE_JIT=1 in a fresh
    interpreter inside np.errstate(all="raise"): every kernel, Newton iteration, event search and
    reset then executes as numpy scalar arithmetic, so a hidden overflow, invalid operation or
    division by zero raises FloatingPointError. Includes a positive control (an overflow that must
    raise). The compiled path uses the same source, so its arithmetic is what was checked."""
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", _HYGIENE_SCRIPT, json.dumps(cases)], capture_output=True, text=True,
                       env=env, timeout=timeout)
    if p.returncode != 0:
        return {"error": p.stderr[-2000:], "cases": [], "control": ""}
    res = json.loads(p.stdout.strip().splitlines()[-1])
    res["wall_time"] = time.perf_counter() - t0
    return res


# --- configuration and the whole study ---------------------------------------------------------

def load_study_config(path) -> dict:
    """configs/extremes.yaml: plain YAML (see the file's comments); unknown top-level keys rejected."""
    import yaml

    cfg = yaml.safe_load(Path(path).read_text())
    known = {"name", "description", "methods", "output", "json", "step_limit", "long_horizon", "grazing",
             "boundary", "dense", "surface", "accumulation", "energy", "mass_ratio", "singular_mass", "hygiene"}
    bad = set(cfg) - known
    if bad:
        raise ValueError(f"{path}: unknown key {sorted(bad)[0]!r} (known: {', '.join(sorted(known))})")
    return cfg


def _methods_available(methods, log):
    ok = []
    for m in methods:
        try:
            resolve_method(m)
            ok.append(m)
        except Exception as e:
            log(f"method {m} unavailable: {e}")
    return ok


def run_study(cfg: dict, log=print, only=None) -> dict:
    """Run every section of the study config; returns the results dict (JSON-ready)."""
    methods = _methods_available(cfg.get("methods", ["CVA", "VCI"]), log)
    res = {"name": cfg.get("name", "extremes"), "methods": methods, "started": time.strftime("%Y-%m-%d %H:%M:%S")}
    want = (lambda k: k in cfg and (only is None or k in only))
    t_all = time.perf_counter()

    def section(name, fn):
        if want(name):
            t0 = time.perf_counter()
            res[name] = fn(cfg[name])
            log(f"[{name}] {time.perf_counter() - t0:.1f} s")

    section("step_limit", lambda c: [
        step_limit(sc["system"], m, T=sc["T"], beta=sc.get("beta"), h_min=c.get("h_min", 1e-5),
                   h_max=c.get("h_max", 2.0), per_decade=c.get("per_decade", 4), rel=c.get("rel", 1e-3))
        for sc in c["scenes"] for m in methods])
    section("long_horizon", lambda c: [
        long_run(c.get("system", "cart_pendulum"), m, h=c["h"], steps=c["steps"], beta=c.get("beta"))
        for m in methods])
    section("grazing", lambda c: [
        grazing_case(sc["system"], m, d, h=c["h"], beta=sc.get("beta"), after=c.get("after", 0.5))
        for sc in c["scenes"] for m in methods for d in c["depths"]])
    section("boundary", lambda c: [
        boundary_case(sc["system"], m, h=c["h"], k=sc["k"], T=sc["T"], beta=sc.get("beta"))
        for sc in c["scenes"] for m in methods])
    section("dense", lambda c: [
        dense_case(sc["system"], m, h=sc["h"], T=sc["T"], beta=sc.get("beta"),
                   q0=np.array(sc["q0"]) if "q0" in sc else None, p0=np.array(sc["p0"]) if "p0" in sc else None,
                   params=sc.get("params"))
        for sc in c["scenes"] for m in methods])
    section("surface", lambda c: [
        surface_case(sc["system"], m, kind, h=c["h"], T=c["T"])
        for sc in c["scenes"] for kind in sc["kinds"] for m in methods])
    section("accumulation", lambda c: [
        accumulation_case(m, h=h, T=c["T"], y0=c.get("y0", 1.0), c=c.get("c", 2.0)) for m in methods for h in c["h"]])
    section("energy", lambda c: [energy_case(m, b, hs=c["h"], T=c["T"]) for b in c["betas"] for m in methods])
    section("mass_ratio", lambda c: [mass_ratio_case(m, r, hs=c["h"], T=c["T"]) for r in c["ratios"] for m in methods])
    section("singular_mass", lambda c: [singular_mass_case(m, m1, hs=c["h"], T=c["T"]) for m1 in c["m1"]
                                        for m in methods]
            + [singular_mass_case(m, 0.0, hs=c["h"], T=c["T"], q0=np.array(c["nonaligned_q0"]), p0=np.zeros(2))
               for m in methods])
    section("hygiene", lambda c: hygiene_case([
        {"system": sc["system"], "method": m, "h": sc["h"], "T": sc["T"], "kw": sc.get("kw", {}),
         "reference": bool(sc.get("reference", False))} for sc in c["scenes"] for m in methods]))
    res["wall_time"] = time.perf_counter() - t_all
    return res


# --- the report --------------------------------------------------------------------------------

def _g(x, fmt=".2g"):
    if x is None:
        return "-"
    try:
        if not np.isfinite(x):
            return "-"
    except TypeError:
        return str(x)
    return format(x, fmt)


def _short(status, cause=""):
    if status == "ok":
        return "ok"
    c = cause.split(" (")[0].split(":")[0] if cause else ""
    return f"**{status}**" + (f" ({c})" if c else "")


def _overview(res: dict) -> list:
    """The summary table (per method: stable h per scene, drift slopes, outcome of each hard case)."""
    methods = res.get("methods", [])
    if not methods:
        return []

    def pick(section, **kw):
        return [r for r in res.get(section, []) if all(r.get(k) == v for k, v in kw.items())]

    def stable(m, scene):
        r = pick("step_limit", method=m, system=scene)
        if not r:
            return "-"
        r = r[0]
        if r.get("h_past") is None or not np.isfinite(r["h_past"]):
            return f"<= {r['h_max']:g} (no failure)"
        return f"<= {_g(r['h_limit'], '.3g')}, then {r['status_past']}"

    def graze(m):
        rs = pick("grazing", method=m)
        if not rs:
            return "-"
        ok = sum(1 for r in rs if r["status"] == "ok" and r.get("err", np.inf) <= r.get("bound", -1))
        return f"{ok}/{len(rs)} ok within bound" if ok == len(rs) else f"{ok}/{len(rs)} ok; " + ", ".join(
            sorted({r["status"] for r in rs if r["status"] != "ok"}))

    def boundary(m):
        rs = pick("boundary", method=m)
        vs = [v for r in rs for v in r["variants"].values()]
        if not vs:
            return "-"
        ok = [v for v in vs if v.get("status") == "ok" and v.get("impacts") == v.get("ref_impacts")]
        dt = max((abs(v["dt_first"]) for v in ok), default=np.nan)
        return f"{len(ok)}/{len(vs)} ok, impact at k h to {_g(dt, '.0e')}"

    def dense(m):
        out = []
        for r in pick("dense", method=m):
            sc = "cart" if r["system"] == "cart_pendulum" else "ball"
            if r["status"] == "ok":
                out.append(f"{sc}: ok {r.get('impacts')}/{r.get('ref_impacts')} impacts")
            else:
                out.append(f"{sc}: {r['status'].split(':')[0]}")
        return "; ".join(out) or "-"

    def surface(m):
        rs = pick("surface", method=m)
        if not rs:
            return "-"
        ok = [r for r in rs if r["status"] == "ok" and r.get("impacts") == r.get("ref_impacts")]
        other = sorted({f"{r['kind']}: {r['status']}" for r in rs if r not in ok})
        return f"{len(ok)}/{len(rs)} ok" + ("; " + ", ".join(other) if other else "")

    def accum(m):
        rs = pick("accumulation", method=m)
        if not rs:
            return "-"
        r = rs[0]
        if r["status"] == "accumulation":
            return f"accumulation, onset {_g(r.get('onset'), '.3g')} (exact {_g(r['exact_onset'], '.3g')}), h = {r['h']:g}"
        if r["status"] == "ok":
            return f"ok: settles, err {_g(r.get('err_after_onset'))} after onset, h = {r['h']:g}"
        return r["status"].split(":")[0] + (" (forced system)" if "forced" in r["status"] else "")

    def energy(m):
        r = next((x for x in pick("energy", method=m) if x["beta"] == max(y["beta"] for y in res["energy"])), None)
        if r is None:
            return "-"
        last = r["runs"][-1]
        return (f"L2 {_g(last.get('l2'))} at h = {last['h']:g}" + (f", order {last['order']:.2f}" if "order" in last
                                                                   else "")) if "l2" in last else last["status"]

    def ratio(m):
        rs = pick("mass_ratio", method=m)
        if not rs:
            return "-"
        conv = [r["ratio"] for r in rs if all(x["status"] == "ok" for x in r["runs"][1:])
                and r["runs"][-1].get("order", 0) > 1.8]
        hard = [r for r in rs if r["ratio"] not in conv]
        out = [f"order 2 for {', '.join(f'{x:g}' for x in conv)}"] if conv else []
        for r in hard:
            ok = [x for x in r["runs"] if x["status"] == "ok"]
            fails = sorted({x["status"] for x in r["runs"] if x["status"] != "ok"})
            best = min(ok, key=lambda x: x["h"]) if ok else None
            out.append(f"{r['ratio']:g}: " + (f"L2 {_g(best.get('l2'))} at h = {best['h']:g}" if best else "no ok run")
                       + (f", {'/'.join(fails)} at larger h (cause named)" if fails else ""))
        return "; ".join(out)

    def singular(m):
        rs = pick("singular_mass", method=m)
        if not rs:
            return "-"
        parts = []
        for r in rs:
            tag = f"{r['m1']:g}" if r["m1"] else "0 (non-aligned)"
            if "input_error" in r:
                parts.append(f"0 (aligned): ValueError at input")
                continue
            ok = [x for x in r["runs"] if x["status"] == "ok"]
            named = all(x["cause"] for x in r["runs"] if x["status"] != "ok")
            txt = f"{tag}: " + (f"ok for h <= {max(x['h'] for x in ok):g}" if ok else "stops")
            if any(x["status"] != "ok" for x in r["runs"]):
                txt += ", stops above" * bool(ok) + (" (cause named)" if named else " (a failure without cause)")
            bad = [x for x in ok if x.get("dH", 0) > 3.0]   # 10 % of the scene's energy scale, 29 J
            if bad:
                txt += f"; ok runs with max abs(H - H0) up to {_g(max(x['dH'] for x in bad))}"
            parts.append(txt)
        return "; ".join(parts)

    def hyg(m):
        cs = [c for c in res.get("hygiene", {}).get("cases", []) if c["method"] == m]
        if not cs:
            return "-"
        ok = sum(1 for c in cs if c["status"] == "ok")
        return "clean" if ok == len(cs) else f"{ok}/{len(cs)} clean"

    def long(m):
        r = next(iter(pick("long_horizon", method=m)), None)
        if r is None:
            return "-", "-"
        return _g(r.get("slope_H"), ".1e"), _g(r.get("slope_Hmod"), ".1e")

    L = ["## Overview\n", "Per method: the stable step range (every run ok from h = 1e-5 up to the limit, T = 5), the "
         "drift slopes over 1e6 steps of the cart-pendulum (J/s), and the outcome of each hard case (details and "
         "bounds in the sections below).\n"]
    cols = ["method", "stable h, cart-pendulum", "stable h, double pendulum", "dH/dt", "dHmod/dt", "grazing",
            "impact at a grid point", "several impacts per step", "start on the surface", "accumulation",
            "beta = 100", "mass ratio m2/m1", "nearly singular M (m1)", "FP hygiene"]
    L.append("| " + " | ".join(cols) + " |")
    L.append("|" + "---|" * len(cols))
    for m in methods:
        sH, sM = long(m)
        L.append("| " + " | ".join([m, stable(m, "cart_pendulum"), stable(m, "double_pendulum"), sH, sM, graze(m),
                                    boundary(m), dense(m), surface(m), accum(m), energy(m), ratio(m), singular(m),
                                    hyg(m)]) + " |")
    L.append("")
    L += _findings(res)
    return L


def _findings(res: dict) -> list:
    """What the tables say, with the numbers read from the results."""
    L = ["### What it shows\n"]

    def lr(m, key):
        r = next((x for x in res.get("long_horizon", []) if x["method"] == m), None)
        return r.get(key) if r else None

    L.append("- **Never a crash, never a hang.** Every run of the study returns a status; failures carry "
             "step, time, state and (vcirun.api) a cause: `mass matrix nearly singular along the motion (cond(M) = "
             "..)`, `the discrete motion had diverged (H = ..)`, `step h too large for the fastest local mode (h * "
             "omega = ..)`, `zero normal velocity at the contact (grazing or resting contact)`, `no reflecting root "
             "of the reset equations: ..`, `impacts accumulate: accumulation began at t = ..`. Bad input (a mass "
             "matrix that is not positive definite at q0, forcing for the MCVA family) raises ValueError naming it.")
    L.append("- **Step size.** The Newton limit is not monotone in h and is not an accuracy limit: the cart-pendulum "
             "with CVA returns `ok` up to h = 2 with energy errors of 100 % and more; compare the column with the 10 % "
             "energy criterion. Past the limit the status is `newton_failed`.")
    if res.get("long_horizon"):
        d = {m: lr(m, "maxdev_Hmod") for m in res["methods"]}
        parts = []
        for m in ("MCVAA", "MCVAC"):
            if d.get(m):
                v = list(d[m].values())
                parts.append(f"{m} {_g(v[-2])} -> {_g(v[-1])} J from 1e5 to 1e6 steps (x{v[-1] / v[-2]:.1f}; slope "
                             f"{_g(lr(m, 'slope_Hmod'), '.1e')} J/s)")
        # the growth factors of this run are stated as measured; the realizations of earlier runs
        # (the motion is chaotic) are quoted beside them, because one run decides nothing
        L.append("- **Long horizon.** CVA and VCI drift in H (slopes above; max abs(H - H0) grows with the horizon). "
                 "Truncated modified Hamiltonian in this run: " + "; ".join(parts) + " (a drift would give x10 over "
                 "the decade, a random walk over the ~8000 impacts about x3). The motion is chaotic: a change of one "
                 "ulp anywhere (initial state, kernel path, Newton stopping) gives another realization. MCVAA over "
                 "eight realizations: 5.1e-4 .. 2.6e-3 J after 1e6 steps, x2.1 .. x4.7 from 1e5 steps: sub-linear. "
                 "MCVAC: x5 (-9.7e-6 J/s, first session), x2.3 (-5.0e-7 J/s, the realizations of 2026-11-23), x12 "
                 "(-2.0e-5 J/s, 0.19 J, 2026-12-01): its third-order truncation H~^{O(h^3)} drifted in that realization, "
                 "so sub-linear growth is not claimed for MCVAC; every realization stayed below 1 % of H0.")
    L.append("- **Grazing.** A contact whose normal velocity is below ~ phi'' h is invisible to the grid (the dip lies "
             "between grid points) and is missed; the error is then that of a missed reflection, 2 vn (T - t*), "
             "which vanishes with the depth. No grazing case fails.")
    L.append("- **Impact at a grid point.** phi of the grid state < 0, == 0.0 or > 0 by round-off gives the same "
             "impact (to 1e-16 for CVA/VCI, to the partial flow's local error for MCVA); R^VCI's post-impact "
             "momentum jumps by O(h^2) across the grid point (the pre- and post-impact step lengths swap).")
    L.append("- **Several impacts per step.** CVA and the MCVA family resolve them (partial steps between impacts); "
             "R^VCI balances a short pre-impact step against a post-impact step over the rest of the step, which "
             "fails (cart) or loses bounces (ball): VCI is not suited to impacts denser than the grid.")
    L.append("- **Accumulation** is reported when more than `max_impacts_step` impacts fall in one step or when "
             "impacts less than one step apart continue for more than `max_impacts_step` steps; the onset is the "
             "first impact of that run (`vcirun.api.accumulation_onset`, in the message). With linear drag the "
             "exact flights shrink like 3 m / (c n): the impact rate grows without bound, so the ball must be "
             "stopped. CVA stops there; VCI's discrete ball instead settles into an h-scale bounce whose height "
             "is within the stated O(h^2) bound of the exact (resting) motion. A conservative bounce denser than "
             "the grid for more than max_impacts_step steps is also reported (raise max_impacts_step to continue).")
    L.append("- **Energies and parameters.** Second order holds up to beta = 100 and for m2/m1 = 1e-4 .. 1e2. "
             "m2/m1 = 1e4 and m1 -> 0 make the mass matrix ill-conditioned and some local modes fast (omega ~ 3e6 "
             "for the cart at theta = pi/2): large steps stop with the cause named, small steps run. Known gap: "
             "m1 = 0 from a non-aligned start at h <= 1e-4 steps across the singular configuration (no exact "
             "continuation exists) and returns ok with a large energy error: simulate checks hyperregularity only at "
             "q0 (a strict xfail test pins it).")
    L.append("- **Floating point.** With numpy errors raised, the whole loop (uncompiled) and the Python side pass on "
             "the normal scenes; the exact reference needs `under=\"ignore\"` only because scipy's solve_ivp takes "
             "the subnormal nextafter(0, inf) at t = 0.")
    L.append("")
    return L


def render_markdown(res: dict, command: str) -> str:
    """docs/extremes.md from the study results."""
    L = []
    methods = res.get("methods", [])
    L.append("# Numerical stability at the extremes (issue 8)\n")
    L.append(f"Produced by `{command}` (config `configs/extremes.yaml`; raw numbers in "
             f"`results/extremes.json`); {res.get('started', '')}, {res.get('wall_time', 0):.0f} s on this machine. "
             "Methods: " + ", ".join(methods) + ". Every hard case below is also a test in `tests/extremes/` "
             "(fast, or `@pytest.mark.slow`).\n")
    L += _overview(res)
    if "step_limit" in res:
        L.append("## Step size: stable range and what happens just past it\n")
        L.append("h scanned from 1e-5 (4 points per decade up to h = 2, every point run; T = 5), then bisected to "
                 "0.1 % between the last ok step below the first failure and that failure. *Stable range* = every scanned h up "
                 "to h* returns `ok`; *max abs(H - H0)* is the energy error of the run at h* (an ok run there is "
                 "not necessarily accurate); *ok above* lists scanned steps above h* that are ok again "
                 "(the Newton limit is not monotone); E = max(abs(H0), largest kinetic energy of the h = 1e-5 run).\n")
        L.append("| scene | method | stable h range | status just past h* | max abs(H - H0) at h* | ok above h* | "
                 "largest scanned h with max abs(H - H0) <= 10 % E | crashes |")
        L.append("|---|---|---|---|---|---|---|---|")
        for r in res["step_limit"]:
            rng = f"[{r['h_min']:g}, {_g(r['h_limit'], '.4g')}]" if r.get("h_limit") else "none"
            cause = r["message_past"].split("; cause: ")[1] if "; cause: " in r.get("message_past", "") else ""
            has_past = r.get("h_past") is not None and np.isfinite(r["h_past"])
            past = (f"{_short(r['status_past'], cause)} at {_g(r['h_past'], '.4g')}" if has_past
                    else f"none up to h = {r['h_max']:g}")
            above = ", ".join(_g(h, ".3g") for h in r.get("ok_above", [])) or "-"
            L.append(f"| {r['system']} | {r['method']} | {rng} | {past} | {_g(r['dH_at_limit'])} | {above} | "
                     f"{_g(r.get('h_energy10'), '.3g')} | {len(r['crashes'])} |")
        L.append("")
    if "long_horizon" in res:
        rs = res["long_horizon"]
        if rs:
            r0 = rs[0]
            L.append(f"## Long horizon: {r0['steps']:.0e} steps of the cart-pendulum with impacts\n")
            L.append(f"h = {r0['h']}, Xi(3.2), T = {r0['steps'] * r0['h']:g} s. Slope = least-squares slope of "
                     "E(t) - E(0) over the whole run; max abs dev = max over [0, t] of abs(E - E(0)) after 1e4, 1e5, 1e6 "
                     "steps (bounded error: the three stay alike; drift: they grow).\n")
            L.append("| method | status | impacts | slope of H (J/s) | max abs(H - H0) @1e4 / 1e5 / 1e6 | slope of Hmod | "
                     "max abs(Hmod - Hmod0) @1e4 / 1e5 / 1e6 | wall (s) |")
            L.append("|---|---|---|---|---|---|---|---|")
            for r in rs:
                devH = " / ".join(_g(v) for v in r.get("maxdev_H", {}).values()) or "-"
                devM = " / ".join(_g(v) for v in r.get("maxdev_Hmod", {}).values()) or "-"
                L.append(f"| {r['method']} | {r['status']} | {r.get('impacts', '-')} | {_g(r.get('slope_H'), '.2e')} | "
                         f"{devH} | {_g(r.get('slope_Hmod'), '.2e')} | {devM} | {_g(r.get('wall_time'), '.1f')} |")
            L.append("")
    L.append("## Hard cases\n")
    if "grazing" in res:
        L.append("### Grazing contact\n")
        L.append("The unconstrained motion translated so that its first minimum of phi lies `depth` inside the "
                 "constraint (cart-pendulum at Xi(100): the spinning pendulum lifts the cart, y is cyclic; double "
                 "pendulum: the wall moved to x_max - depth); normal contact velocity vn = sqrt(2 phi'' depth). "
                 "Cell: status, impacts found / exact, max error vs the exact reference; bound = error of the run "
                 "that stays clear + 10 vn (T - t*) (a missed reflection).\n")
        scenes = sorted({r["system"] for r in res["grazing"]})
        for sc in scenes:
            rows = [r for r in res["grazing"] if r["system"] == sc]
            depths = sorted({r["depth"] for r in rows}, reverse=True)
            L.append(f"{sc}, h = {rows[0]['h']}:\n")
            L.append("| depth | vn | " + " | ".join(methods) + " |")
            L.append("|---|---|" + "---|" * len(methods))
            for d in depths:
                cells = []
                for m in methods:
                    r = next((x for x in rows if x["depth"] == d and x["method"] == m), None)
                    if r is None:
                        cells.append("-")
                    elif r["status"] == "ok":
                        cells.append(f"ok {r.get('impacts')}/{r.get('ref_impacts')}, {_g(r.get('err'))} (bound {_g(r.get('bound'))})")
                    else:
                        cells.append(_short(r["status"], r.get("cause", "")))
                vn = next(x["vn"] for x in rows if x["depth"] == d)
                L.append(f"| {d:.0e} | {_g(vn)} | " + " | ".join(cells) + " |")
            L.append("")
    if "boundary" in res:
        L.append("### Impact exactly at a step boundary\n")
        L.append("Initial states built by stepping back k full steps from the exact first impact state (symmetric "
                 "maps, reversible systems), then moved by single ulps until the k-th grid state has phi < 0, "
                 "phi == 0.0, phi > 0. Cell: status, impact time - k h, impacts / exact, L2 error.\n")
        L.append("| scene | method | phi_k < 0 | phi_k == 0.0 | phi_k > 0 | spread of final states |")
        L.append("|---|---|---|---|---|---|")
        for r in res["boundary"]:
            cells = []
            for key in ("neg", "zero", "pos"):
                v = r["variants"].get(key, {})
                if v.get("status") == "ok":
                    cells.append(f"ok, {_g(v.get('dt_first'), '.1e')}, {v.get('impacts')}/{v.get('ref_impacts')}, "
                                 f"L2 {_g(v.get('l2'))}")
                else:
                    cells.append(v.get("status", "-"))
            L.append(f"| {r['system']} (h = {r['h']}, k = {r['k']}) | {r['method']} | " + " | ".join(cells)
                     + f" | {_g(r.get('spread_final'))} |")
        L.append("")
    if "dense" in res:
        L.append("### Several impacts in one step\n")
        L.append("| scene | method | status | impacts / exact | max per step | max impact-time error | error |")
        L.append("|---|---|---|---|---|---|---|")
        for r in res["dense"]:
            err = r.get("l2", r.get("err"))
            L.append(f"| {r['system']} (h = {r['h']}, T = {r['T']}) | {r['method']} | {_short(r['status'], r.get('cause', ''))} | "
                     f"{r.get('impacts', '-')}/{r.get('ref_impacts', '-')} | {r.get('max_per_step', '-')} | "
                     f"{_g(r.get('dt_impacts'))} | {_g(err)} ({'L2' if 'l2' in r else 'max'}) |")
        L.append("")
    if "surface" in res:
        L.append("### Initial state on the constraint surface\n")
        L.append("out = moving away, in = moving into the constraint (exact motion: reflected at t = 0), lift = zero "
                 "normal velocity accelerating away, rest = zero velocity pushed into the constraint (resting "
                 "contact: no elastic motion exists).\n")
        L.append("| scene | kind | " + " | ".join(methods) + " |")
        L.append("|---|---|" + "---|" * len(methods))
        keys = []
        for r in res["surface"]:
            if (r["system"], r["kind"]) not in keys:
                keys.append((r["system"], r["kind"]))
        for sc, kind in keys:
            cells = []
            for m in methods:
                r = next((x for x in res["surface"] if x["system"] == sc and x["kind"] == kind and x["method"] == m), None)
                if r is None:
                    cells.append("-")
                elif r["status"] == "ok" and "l2" in r:
                    cells.append(f"ok {r['impacts']}/{r['ref_impacts']} impacts, L2 {_g(r['l2'])}")
                else:
                    cells.append(_short(r["status"], r.get("cause", "")))
            L.append(f"| {sc} | {kind} | " + " | ".join(cells) + " |")
        L.append("")
    if "accumulation" in res:
        L.append("### Impact accumulation: bouncing ball with linear drag (forced DEL)\n")
        rs = res["accumulation"]
        if rs:
            L.append(f"Dropped from y0 = 1 with drag c = {rs[0]['c']} (m = 1, g = 10), T = {rs[0]['T']}. Exact onset = the "
                     "impact after which every exact flight is shorter than h. Reported onset = the start of the run "
                     "of impacts less than one step apart that triggered the status. err after onset = max abs(y - "
                     "y_exact) on the grid after the exact onset.\n")
        L.append("| method | h | status | reported onset | exact onset | stopped at | impacts | err after onset |")
        L.append("|---|---|---|---|---|---|---|---|")
        for r in rs:
            L.append(f"| {r['method']} | {r['h']} | {r['status']} | {_g(r.get('onset'), '.4g')} | "
                     f"{_g(r['exact_onset'], '.4g')} | {_g(r.get('fail_time'), '.4g')} | {r.get('impacts', '-')} | "
                     f"{_g(r.get('err_after_onset'))} |")
        L.append("")
    if "energy" in res:
        L.append("### High energy: Xi(beta) up to beta = 100\n")
        L.append("L2 error against the exact reference (T = 5) per h, observed order in parentheses; theta span = "
                 "range of the exact pendulum angle (> 2 pi: full rotations).\n")
        hs = [r["h"] for r in res["energy"][0]["runs"]]
        L.append("| beta | H0 (J) | theta span | method | " + " | ".join(f"h = {h:g}" for h in hs) + " |")
        L.append("|---|---|---|---|" + "---|" * len(hs))
        for r in res["energy"]:
            H0 = next((x["H0"] for x in r["runs"] if "H0" in x), np.nan)
            cells = [(f"{_g(x['l2'])}" + (f" ({x['order']:.2f})" if "order" in x else "")) if "l2" in x
                     else _short(x["status"], x.get("cause", "")) for x in r["runs"]]
            L.append(f"| {r['beta']} | {_g(H0, '.4g')} | {_g(r['theta_span'], '.3g')} | {r['method']} | " + " | ".join(cells) + " |")
        L.append("")
    if "mass_ratio" in res:
        L.append("### Mass ratios m2/m1 = 1e-4 .. 1e4 (cart-pendulum, Xi(3.2))\n")
        hs = [r["h"] for r in res["mass_ratio"][0]["runs"]]
        L.append(f"L2 error against the exact reference (T = {res['mass_ratio'][0]['T']}), observed order in parentheses.\n")
        L.append("| m2/m1 | max cond(M) | exact impacts | method | " + " | ".join(f"h = {h:g}" for h in hs) + " |")
        L.append("|---|---|---|---|" + "---|" * len(hs))
        for r in res["mass_ratio"]:
            cells = [(f"{_g(x['l2'])}" + (f" ({x['order']:.2f})" if "order" in x else "")) if "l2" in x
                     else _short(x["status"], x.get("cause", "")) for x in r["runs"]]
            L.append(f"| {r['ratio']:g} | {_g(r['cond_max'])} | {r['ref_impacts']} | {r['method']} | " + " | ".join(cells) + " |")
        L.append("")
    if "singular_mass" in res:
        L.append("### Nearly singular mass matrix (double pendulum, m1 -> 0)\n")
        hs = [x["h"] for r in res["singular_mass"] for x in r["runs"]]
        hs = sorted(set(hs), reverse=True)
        L.append("cond0 = cond(M) at the start (links aligned: 4/m1). Cell: status, L2 error against the exact "
                 "reference where that reference is itself accurate (its self-estimate in the last column).\n")
        L.append("| m1 | cond0 | method | " + " | ".join(f"h = {h:g}" for h in hs) + " | reference |")
        L.append("|---|---|---|" + "---|" * len(hs) + "---|")
        for r in res["singular_mass"]:
            if "input_error" in r:
                L.append(f"| {r['m1']:g} | inf | {r['method']} | " + " | ".join(["ValueError at input (M not positive "
                         "definite at q0)"] + ["-"] * (len(hs) - 1)) + " | - |")
                continue
            cells = []
            for h in hs:
                x = next((x for x in r["runs"] if x["h"] == h), None)
                if x is None:
                    cells.append("-")
                elif x["status"] == "ok":
                    good = r.get("ref_accuracy", np.inf) < 1e-6
                    cells.append(f"ok, L2 {_g(x.get('l2'))}" if good and "l2" in x else f"ok, dH {_g(x.get('dH'))}")
                else:
                    cells.append(_short(x["status"], x.get("cause", "")))
            refc = (f"acc {_g(r.get('ref_accuracy'))}" if "ref_accuracy" in r else r.get("ref_error", "-")[:60])
            tag = f"{r['m1']:g}" + (" (non-aligned start)" if r["m1"] == 0 else "")
            L.append(f"| {tag} | {_g(r.get('cond0'))} | {r['method']} | " + " | ".join(cells) + f" | {refc} |")
        L.append("")
    if "hygiene" in res:
        hy = res["hygiene"]
        L.append("### Floating-point hygiene\n")
        L.append("The whole loop run uncompiled (`NUMBA_DISABLE_JIT=1`) inside `np.errstate(all=\"raise\")` (the exact reference, for the runs that have one: with `under=\"ignore\"`, since scipy's solve_ivp takes the subnormal nextafter(0, inf) at t = 0), so every "
                 "overflow, invalid operation or division by zero in kernels, Newton, event search and resets raises. "
                 f"Positive control (H at p = 1e200): {hy.get('control', '-')}.\n")
        L.append("| scene | h | T | method | outcome | impacts | finite |")
        L.append("|---|---|---|---|---|---|---|")
        for c in hy.get("cases", []):
            L.append(f"| {c['system']} | {c['h']} | {c['T']} | {c['method']} | {c['status']} | {c.get('impacts', '-')} | "
                     f"{c.get('finite', '-')} |")
        if hy.get("error"):
            L.append(f"\nhygiene run failed: `{hy['error'][-300:]}`")
        L.append("")
    return "\n".join(L) + "\n"
