"""Why a run stopped (every stop names its cause), from its grid states and the compiled
module: `failure_cause` returns the "; cause: ..." text of `Trajectory.message`. numpy only; a
diagnosis never raises."""
from __future__ import annotations

import numpy as np

from ..core.record import STATUSES

OK, NEWTON_FAILED, EVENT_FAILED, RESET_FAILED, ACCUMULATION, NONFINITE, PAINLEVE = (name for name, _ in STATUSES)

COND_SINGULAR = 1e4   # cond(M) along the motion above this: nearly singular (built-in scenes: < 30)
COND_RISING = 1e3     # ... above this and largest right before a Newton failure: heading into it


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


def failure_cause(mod, status, Q, p, t0, fail, h, prm, tol, H0, impacts, modes=None) -> str:
    """A short diagnosis of a failed run from its grid states Q[0..fail] (p: momentum at Q[fail];
    modes: the record's contact_mode up to the failing step, for friction); "" if nothing specific is
    found (the status itself then says what failed). Never raises."""
    try:
        if status == PAINLEVE:
            return _painleve(mod, Q[-1], p, prm, t0 + fail * h, h, None if modes is None else modes[-1])
        if status == ACCUMULATION:
            return _accumulation(impacts, h, int(tol["max_impacts_step"]))
        if status == EVENT_FAILED:
            # (both event searches end so: the collision time and, with friction, a held contact's mode event)
            return ("an event search (the collision time, or a held contact's stick or slip event) did not "
                    "bracket its root to event_tol * h within 200 iterations")
        t = t0 + fail * h
        if status == NEWTON_FAILED:
            stiff = _stiff_force(mod, Q[-1], p, prm, h, t)
            if stiff:
                return stiff
        causes = _conditioning(mod, status, Q, prm, t0, h, t) + _divergence(mod, status, Q[-1], p, prm, h, H0)
        if status == RESET_FAILED and not causes:
            causes += _impact_law(mod, Q[-1], p, prm, h, t, tol) or _reset(mod, Q[-1], p, prm, h, t, tol)
        if status == NONFINITE and not causes:
            causes.append("the state overflowed")
        return "; ".join(causes)
    except Exception:  # a diagnosis must never turn a failure record into an exception
        return ""


def _accumulation(impacts, h, max_impacts_step) -> str:
    onset = accumulation_onset(impacts, h)
    k = int(np.sum(impacts >= onset)) if np.isfinite(onset) else 0
    last = float(impacts[-1] - impacts[-2]) if len(impacts) > 1 else float("nan")
    return (f"impacts accumulate: accumulation began at t = {onset:.9g} ({k} impacts since, each less "
            f"than one step h after the previous, the last {last:.3g} apart; limit: more than "
            f"max_impacts_step = {max_impacts_step} impacts in one step or such a run "
            f"longer than max_impacts_step steps); an event-driven scheme cannot follow impacts denser "
            f"than its grid (the motion is settling into contact)")


def _conditioning(mod, status, Q, prm, t0, h, t) -> list:
    """cond(M) along the motion (500 samples and the last 100 states)."""
    n = Q.shape[1]
    A = np.empty((n, n))
    worst, t_worst = 0.0, t
    idx = np.union1d(np.linspace(0, len(Q) - 1, 500).astype(int), np.arange(max(0, len(Q) - 100), len(Q)))
    for k in idx:
        mod.sys_M(Q[k], prm, A)
        c = float(np.linalg.cond(A)) if np.all(np.isfinite(A)) else np.inf
        if not c <= worst:
            worst, t_worst = c, t0 + k * h
    if not worst < COND_SINGULAR:
        return [f"mass matrix nearly singular along the motion (cond(M) = {worst:.3g} at t = {t_worst:.6g})"]
    if status == NEWTON_FAILED and worst >= COND_RISING and t_worst >= t - 100 * h:
        # conditioning still moderate on the grid but worst right before the failure: the step
        # that failed was heading into a singular configuration between grid points
        return [f"mass matrix approaching singularity at the failure (cond(M) = {worst:.3g} at "
                f"t = {t_worst:.6g}, the largest along the motion)"]
    return []


def _stiff_force(mod, q, p, prm, h, t) -> str:
    """The step h does not resolve the force's velocity dependence at (q, p) (the loop's check,
    vcirun/maps/steps.py step_resolves_force): M - a h_s df/dqdot not positive definite."""
    if not getattr(mod, "FORCED", False):
        return ""
    n = len(q)
    M = np.empty((n, n))
    mod.sys_M(q, prm, M)
    v = np.linalg.solve(M, p)
    fq, fv = np.empty((n, n)), np.empty((n, n))
    mod.sys_force_jac(q, v, t, prm, fq, fv)
    weights = [float(mod.FORCE_A[s]) * float(f) for s, f in zip(mod.FULL_STAGES, mod.FULL_FRACS)]
    with np.errstate(over="ignore", invalid="ignore"):
        sym = 0.5 * fv + 0.5 * fv.T
    for c in (max(weights + [0.0]) * h, min(weights + [0.0]) * h):
        if c != 0.0:
            lam = np.linalg.eigvalsh(0.5 * (M + M.T) - c * sym) if np.all(np.isfinite(sym)) else np.array([-np.inf])
            if not lam.min() > 0.0:
                rate = float(np.max(np.abs(np.linalg.eigvalsh(sym)))) if np.all(np.isfinite(sym)) else np.inf
                return (f"the force changes with the velocity faster than the step resolves at t = {t:.6g}: "
                        f"M - {c / h:.3g} h df/dqdot is not positive definite (|df/dqdot| up to {rate:.3g}), so "
                        f"the implicit step's root does not follow the motion: step h too large")
    return ""


def _divergence(mod, status, q, p, prm, h, H0) -> list:
    H = float(mod.hamiltonian(q, p, prm))
    if not np.isfinite(H) or abs(H - H0) > 10.0 * max(1.0, abs(H0)):
        return [f"the discrete motion had diverged (H = {H:.4g}, H(0) = {H0:.4g}): step h too large"]
    if status in (NEWTON_FAILED, NONFINITE):
        w = fastest_mode(mod, q, p, prm)
        if h * w > 2.0:
            return [f"step h too large for the fastest local mode of the motion (h * omega = {h * w:.3g} "
                    f"> 2, the stability limit of the Verlet-type maps)"]
    return []


_LCP_CASES = {-1: "has no solution (no impulses lam >= 0 leave every contact separating: contacts with "
                  "dependent gradients and different restitutions)",
              -2: "got invalid input (a non-finite or asymmetric Delassus matrix, or a contact without effective "
                  "mass)",
              -3: "is degenerate (the impulses are not unique: dependent contact gradients, e.g. a closed loop of "
                  "contacts; or a pivot undecidable within round-off)"}


def _impact_law(mod, q, p, prm, h, t, tol) -> list:
    """A reset that failed in Moreau's law of several contacts: which contacts, and why."""
    n, m = q.shape[0], int(mod.NCON)
    if m == 1:
        return []
    qt, pt, vt = np.empty(n), np.empty(n), np.empty(n)
    code, _, _, _ = mod.collision_time(q, p, h, h, t, prm, float(tol["newton_tol"]), int(tol["max_iter"]),
                                       float(tol["event_tol"]), qt, pt, vt, np.zeros(m, np.int64))
    if code != 1:
        return []
    d, lam, active = np.empty(n), np.empty(m), np.zeros(m, np.int64)
    k, _, _ = mod.impact_direction(qt, pt, h, float(tol["event_tol"]), prm, d, lam, active)
    if k >= 0:
        return []
    ids = [int(i) for i in np.flatnonzero(active)]
    if not ids:  # (the law clears `active` on failure: the contacts touching at the impact state)
        phis = np.empty(m)
        mod.sys_phis(qt, prm, phis)
        ids = [int(i) for i in np.flatnonzero(phis <= 1e-9 * (1.0 + float(np.max(np.abs(qt)))))]
    shown = ", ".join(map(str, ids[:20])) + (" ..." if len(ids) > 20 else "")
    return [f"Moreau's impact law of the {len(ids)} contacts at the impact (contact indices {shown}, as in "
            f"impact_contact) {_LCP_CASES.get(int(k), f'failed (case {int(k)})')}"]


def _reset(mod, q, p, prm, h, t, tol) -> list:
    """A reset that found no root: redo the step's collision search and look at the impact state."""
    n = q.shape[0]
    qt, pt, vt = np.empty(n), np.empty(n), np.empty(n)
    code, _, E_pre, _ = mod.collision_time(q, p, h, h, t, prm, float(tol["newton_tol"]), int(tol["max_iter"]),
                                           float(tol["event_tol"]), qt, pt, vt, np.zeros(int(mod.NCON), np.int64))
    if code != 1:
        return []
    g, A = np.empty(n), np.empty((n, n))
    mod.sys_dphi(qt, prm, g)
    mod.sys_M(qt, prm, A)
    Wg = np.linalg.solve(A, g)
    vn = float(Wg @ pt)                       # d phi / dt before the impact
    gWg = float(g @ Wg)
    ke_n = 0.5 * vn * vn / gWg if gWg > 0 else 0.0   # kinetic energy of the normal motion
    speed = float(np.linalg.norm(np.linalg.solve(A, pt)) * np.linalg.norm(g))
    mismatch = abs(E_pre - float(mod.hamiltonian(qt, pt, prm)))
    w = fastest_mode(mod, qt, pt, prm)
    if abs(vn) <= 1e-6 * speed:
        return [f"zero normal velocity at the contact (d phi/dt = {vn:.3g}; grazing or resting contact): no "
                "elastic reset exists"]
    if ke_n < 10 * mismatch:
        return [f"no reflecting root of the reset equations: the normal kinetic energy {ke_n:.3g} (d phi/dt = "
                f"{vn:.3g}, effective mass 1/(g^T M^-1 g) = {1 / gWg:.3g}) is not large against the energy error "
                f"the reset must absorb (pre-impact discrete energy - H = {mismatch:.3g}): a grazing contact or a "
                "tiny effective mass"]
    if h * w > 2.0:
        return [f"no reflecting root of the reset equations: step h too large for the fastest local mode at the "
                f"impact (h * omega = {h * w:.3g} > 2)"]
    return [f"Newton found no reflecting root of the reset equations (cond(M) at the impact = "
            f"{np.linalg.cond(A):.3g}, h * omega = {h * w:.3g}, normal kinetic energy {ke_n:.3g})"]


def fastest_mode(mod, q, p, prm) -> float:
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


def _painleve(mod, q, p, prm, t, h, mode) -> str:
    """Which slipping contact meets Painleve's paradox at the failing step: B_j = G_j M^-1 (G_j -
    mu_j s_j W_j)^T <= 0 (docs/derivations/friction.md), with the contact's name index and B. The slip
    direction s_j is the contact's recorded mode where it slips at the failing grid state, else the sign
    of its slip velocity W_j M^-1 p there; both directions only where the contact does not slide."""
    n, m = q.shape[0], int(mod.NCON)
    G, W, A = np.empty((m, n)), np.empty((m, n)), np.empty((n, n))
    mu, mus = np.empty(m), np.empty(m)
    mod.sys_dphis(q, prm, G)
    mod.sys_slips(q, prm, W)
    mod.sys_M(q, prm, A)
    mod.sys_friction(prm, mu, mus)
    Minv = np.linalg.inv(A)
    qdot = Minv @ np.asarray(p, dtype=float)
    out = []
    for j in range(m):
        if mu[j] <= 0.0:
            continue
        v = float(W[j] @ qdot)
        if mode is not None and int(mode[j]) in (1, -1):
            dirs = (int(mode[j]),)
        elif abs(v) > 1e-12 * (1.0 + float(np.max(np.abs(W[j]))) * float(np.max(np.abs(qdot)))):
            dirs = (1 if v > 0 else -1,)
        else:
            dirs = (1, -1)
        for s in dirs:
            B = float(G[j] @ Minv @ (G[j] - mu[j] * s * W[j]))
            scale = float(G[j] @ Minv @ G[j])
            if B <= 1e-12 * scale:
                out.append(f"contact {j} slipping in direction {s:+d} at t = {t:.9g} (within one step h = {h:g}) has "
                           f"B = G M^-1 (G - mu s W)^T = {B:.6g} (frictionless {scale:.6g}): Painleve's paradox, the "
                           "normal force that keeps it on its surface is not unique or does not exist (rigid-body "
                           "Coulomb friction has no solution there; docs/derivations/friction.md)")
    return "; ".join(out)
