"""Energies and parameters: high energy (Xi(beta), beta up to 100), mass ratios m2/m1 = 1e-4 .. 1e4, and
a nearly singular mass matrix (double pendulum, m1 -> 0 with aligned links: cond(M) = 4/m1).
"""
from __future__ import annotations

import math

import numpy as np

from ...run.resolve import resolve_system
from ...reference_solution.exact import l2_error, reference
from .outcome import cause, energy_error, outcome, run

__all__ = ["energy_case", "mass_ratio_case", "singular_mass_case"]


def energy_case(method, beta, *, hs, T) -> dict:
    """Cart-pendulum from Xi(beta): L2 error against the exact reference per h and the observed order."""
    ref = reference("cart_pendulum", T=T, beta=beta)
    th = ref(np.linspace(0.0, T, 4001))[:, 1]
    out = {"method": method, "beta": beta, "T": T, "ref_impacts": int(len(ref.impacts)),
           "ref_accuracy": ref.accuracy, "theta_span": float(np.ptp(th)), "runs": []}
    for h in hs:
        tr, crash = run("cart_pendulum", method, h=h, T=T, beta=beta)
        r = {"h": h, "status": outcome(tr, crash), "cause": cause(tr)}
        if tr is not None and tr.ok:
            r.update(l2=l2_error(tr, ref), impacts=int(len(tr.impacts)), dH=energy_error(tr), H0=float(tr.H[0]))
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
        r = {"h": h, "status": outcome(tr, crash), "cause": cause(tr)}
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
        r = {"h": h, "status": outcome(tr, crash), "cause": cause(tr)}
        if tr is not None:
            r.update(dH=energy_error(tr), impacts=int(len(tr.impacts)))
            if tr.ok and ref is not None:
                r["l2"] = l2_error(tr, ref)
        out["runs"].append(r)
    return out
