"""Coulomb friction in the exact reference: the modes of a held contact, its forces, the mode of a
contact that comes to rest, and the frictional impact law (docs/derivations/friction.md, "The exact
reference").

A held contact i is in one of the modes (a tuple S aligned with the held set A):

    slip s = +1 / -1  sliding, its slip velocity v_t,i = W_t,i v of sign s; it carries the force
                      (G_i - mu_i s W_t,i)^T lam_n,i (Coulomb's law while sliding, kinetic mu_i);
    STICK             the slip row held too (v_t,i = 0), the force G_i^T lam_n,i + W_t,i^T lam_t,i with
                      |lam_t,i| <= mu_s,i lam_n,i;
    SMOOTH            no friction at these parameters (mu_i = mu_s,i = 0): its normal row alone.

With the constrained rows C = [G_A; W_t,K] (K: the sticking contacts) and the force directions
D = [G_A - mu S W_t,A; W_t,K] (S = 0 for the sticking and smooth rows), the held dynamics are

    qdot = v,   pdot = F + D^T lam,   Kmat lam = -(C M^-1 (F - Mdot v) + kappa),   Kmat = C M^-1 D^T,

kappa = (v^T Hess phi_i v)_{i in A}, (v^T dW_t,i/dq v)_{i in K} (sys_ddphis, sys_dslips): the normal
accelerations of the held contacts and the slip accelerations of the sticking ones are zero. Without
sliding contacts Kmat is the symmetric positive definite C M^-1 C^T; a sliding contact makes it
non-symmetric, and det Kmat <= 0 is Painleve's paradox (for one contact Kmat = B, the normal
acceleration per unit of normal force: the held problem has no solution or two).

The events of a held phase (located on both paths of the reference):
    release  lam_n,i crosses 0 downwards (any mode);
    stick    a sliding contact's v_t,i reaches 0: it sticks if the stick test holds there
             (|lam_t,i| <= mu_s,i lam_n,i in the modes with i sticking), else its slip reverses;
    slip     a sticking contact's lam_t,i reaches +-mu_s,i lam_n,i: it slides, s = -sign(lam_t,i);
    painleve det Kmat reaches 0 with a sliding contact (PainleveError ends the solve).
At an impact the touching contacts take the frictional impact law of vcirun/collision/friction_law.py
(through vcirun.reference_solution.friction_law.friction_impact; normal and tangential impulses, kinetic mu).
"""
from __future__ import annotations

from itertools import combinations
from typing import NamedTuple

import numpy as np


__all__ = ["SMOOTH", "STICK", "Forces", "PainleveError", "coefficients", "held_forces", "settle", "stick_offsets",
           "contact_modes", "held_set", "response", "impact", "mode_name"]

_EPS = float(np.finfo(float).eps)
# the friction modes of a held contact: sliding is +1 / -1 (the sign of its slip velocity), sticking 0,
# a contact without friction 2 (vcirun.reference_solution.held reads them from here)
STICK, SMOOTH = 0, 2
# the held set's LCP tolerance on forces, relative to the largest free normal acceleration
FORCE_LCP_TOL = 1e-12
CONE_TOL = 64 * _EPS   # relative: |lam_t| <= mu_s lam_n (1 + CONE_TOL) is inside the static cone


class PainleveError(RuntimeError):
    """A sliding held contact whose held problem has no solution or several (det Kmat <= 0): the
    contact, the time and B (Kmat for one contact, its determinant for several)."""

    def __init__(self, contact: int, name: str, t: float, B: float):
        self.contact, self.name, self.t, self.B = int(contact), str(name), float(t), float(B)
        super().__init__(f"painleve: contact {name} slides with B = {B:.6g} <= 0 at t={t:.17g} (B = G M^-1 "
                         "(G - mu s W_t)^T, its normal acceleration per unit normal force: the held contact "
                         "problem with sliding friction has no solution or several, Painleve's paradox)")


def mode_name(s) -> str:
    return {1: "slip+", -1: "slip-", STICK: "stick", SMOOTH: "smooth"}[int(s)]


_COEFFS: dict = {}


def coefficients(mod, prm):
    """(mu, mu_s) of every contact at the parameter vector (checked: vcirun.core.system_data.friction_at),
    or None where no contact has friction there (the frictionless reference, unchanged)."""
    key = (id(mod), np.asarray(prm, float).tobytes())
    if key not in _COEFFS:
        from ..core.system_data import friction_at

        out = None
        if getattr(mod, "FRICTION", False):
            mu, mus = friction_at(mod, prm, getattr(mod, "__name__", "system"))
            if np.any(mu > 0.0) or np.any(mus > 0.0):
                out = (mu, mus)
        _COEFFS[key] = out
    return _COEFFS[key]


class Forces(NamedTuple):
    """The held forces of (A, S): lam_n (|A|) the normal forces, lam_t (|A|) the tangential forces of
    the sticking contacts (0 for the others), pdot the momentum rate, K the matrix C M^-1 D^T."""

    lam_n: np.ndarray
    lam_t: np.ndarray
    pdot: np.ndarray
    K: np.ndarray


RANK_TOL = 1e-10   # relative: a sticking row within this of the span of the rows before it is dependent


def independent_sticks(C, k) -> list:
    """The rows k.. of C (slip rows of sticking contacts) that are independent of rows 0..k-1 and of
    the ones kept before them (relative tolerance RANK_TOL): several sticking contacts of one rigid body
    (a link with both ends on the floor) constrain the same tangential motion, and their tangential
    forces are statically indeterminate."""
    keep = list(range(k))
    for r in range(k, len(C)):
        trial = C[keep + [r]]
        if len(trial) > C.shape[1]:
            continue   # (more rows than coordinates: dependent)
        sv = np.linalg.svd(trial, compute_uv=False)
        if sv[-1] > RANK_TOL * sv[0]:
            keep.append(r)
    return keep[k:]


def held_forces(g, A, S) -> Forces:
    """The forces of the held set A in the modes S at the state of the vcirun.reference_solution.held._Geometry g
    (see the module docstring). Sticking rows that depend on the others are dropped from the dynamics
    (they constrain nothing more); the tangential force the kept ones carry is shared among all the
    sticking contacts as the least-norm distribution (lstsq of W_t^T lam_t = the kept rows' force)."""
    mu, _ = coefficients(g._mod, g._prm)
    A = list(A)
    k = len(A)
    Gn = g.G[A]
    D = Gn.copy()
    stick = [a for a in range(k) if S[a] == STICK]
    for a in range(k):
        if S[a] in (1, -1):
            D[a] = Gn[a] - mu[A[a]] * S[a] * g.Wt[A[a]]
    kappa = g.c[A]
    C = Gn
    kept = []
    if stick:
        Ws = g.Wt[[A[a] for a in stick]]
        kept = [r - k for r in independent_sticks(np.vstack([Gn, Ws]), k)]
        C, D = np.vstack([Gn, Ws[kept]]), np.vstack([D, Ws[kept]])
        kappa = np.concatenate([kappa, g.dslip[[A[stick[r]] for r in kept]]])
    X = np.linalg.solve(g.M, D.T)
    K = C @ X
    b = C @ np.linalg.solve(g.M, g.F - g.Mdv) + kappa
    lam = np.linalg.solve(K, -b) if k else np.zeros(0)
    lam_t = np.zeros(k)
    if stick:
        if len(kept) == len(stick):
            lam_t[stick] = lam[k:]
        else:   # the tangential force of the kept rows, shared among every sticking contact (least norm)
            f_t = Ws[kept].T @ lam[k:]
            lam_t[stick] = np.linalg.lstsq(Ws.T, f_t, rcond=None)[0]
    return Forces(lam[:k], lam_t, g.F + D.T @ lam, K)


def response(K, S) -> float:
    """B of a held set with sliding contacts: det K (K itself for one contact)."""
    return float(np.linalg.det(K)) if len(K) else 1.0


def _slip_tol(g, i, tol) -> float:
    """|v_t,i| below this is at rest tangentially (as held_set's |u_i| test)."""
    w = max(map(abs, g.Wt[i].tolist()), default=0.0)
    return tol * w * (1.0 + max(map(abs, g.v.tolist()), default=0.0))


def stick_offsets(g, A, S) -> dict:
    """{contact: offset} for the sliding contacts of (A, S) whose slip velocity is round-off at the state
    of g: a slip that starts from rest (at the static cone, or reversing) with a slip acceleration that
    may be round-off itself (mu_s = mu: the force balance at the cone is exact). Its stick event then
    fires only past s v_t = -offset, 1e3 eps (1 + |W_t,i| |v|) times 4, and the root s v_t = 0 before it
    is refined on the dense output: a round-off crossing at the slip's start is no event."""
    out = {}
    vn = max(map(abs, g.v.tolist()), default=0.0)
    for i, s in zip(A, S):
        if s in (1, -1):
            level = 1e3 * _EPS * (1.0 + max(map(abs, g.Wt[i].tolist()), default=0.0) * vn)
            if abs(g.wt[i]) <= level:
                out[int(i)] = 4.0 * level
    return out


def contact_modes(g, A, tol) -> tuple:
    """The modes of contacts A coming to rest at the state of g: SMOOTH without friction, sliding with
    the sign of a slip velocity beyond round-off, else STICK (settle then applies the stick test)."""
    mu, mus = coefficients(g._mod, g._prm)
    wt = g.wt
    out = []
    for i in A:
        if mu[i] == 0.0 and mus[i] == 0.0:
            out.append(SMOOTH)
        elif abs(wt[i]) > _slip_tol(g, i, tol):
            out.append(1 if wt[i] > 0.0 else -1)
        else:
            out.append(STICK)
    return tuple(out)


def settle(g, A, S) -> tuple:
    """S with every sticking contact whose stick test fails (|lam_t,i| > mu_s,i lam_n,i) sliding the way
    its force would push it, s = -sign(lam_t,i), the worst first, until the tests hold."""
    _, mus = coefficients(g._mod, g._prm)
    S = list(S)
    for _ in range(len(A) + 1):
        if STICK not in S:
            break
        f = g.forces(A, tuple(S))
        worst, over = None, 0.0
        for a, i in enumerate(A):
            if S[a] == STICK:
                excess = abs(f.lam_t[a]) - mus[i] * max(f.lam_n[a], 0.0) * (1.0 + CONE_TOL)
                if excess > over:
                    worst, over = a, excess
        if worst is None:
            break
        S[worst] = -1 if f.lam_t[worst] > 0.0 else 1
    return tuple(S)


def held_set(mod, t, q, p, prm, candidates, tol, geo, names=None) -> tuple:
    """(A, S): the contacts to hold at (t, q, p) and their modes, the frictional form of
    vcirun.reference_solution.held.held_set: among the candidates on their surface at rest, modes from the slip
    velocities (contact_modes, then the stick test), the first active subset (smallest first) whose
    normal forces are >= 0 and leaves the other contacts' normal accelerations >= 0, then the contacts
    with a compressive force beyond the tolerance. A sliding candidate whose held problem is singular
    (B <= 0) raises PainleveError."""
    g = geo   # the vcirun.reference_solution.held._Geometry at (t, q, p)
    near = g.near(candidates, tol)
    if not near:
        return (), ()
    S_near = settle(g, tuple(near), contact_modes(g, tuple(near), tol))
    if any(s in (1, -1) for s in S_near):
        _painleve(g, tuple(near), S_near, names)
    b = g.free_acc(near)
    scale = max(float(np.max(np.abs(b))), float(np.max(np.abs(g.G[near] @ np.linalg.solve(g.M, g.F)))), _EPS)
    lcp_tol = FORCE_LCP_TOL * max(1.0, float(np.max(np.abs(b))))
    chosen = None
    paradox = None   # a sliding subset whose own problem is Painleve's (B <= 0): the cause if none fits
    for size in range(len(near) + 1):
        for sub in combinations(range(len(near)), size):
            A = tuple(near[j] for j in sub)
            S = settle(g, A, tuple(S_near[j] for j in sub))
            if paradox is None and any(x in (1, -1) for x in S):
                try:
                    _painleve(g, A, S, names)
                except PainleveError as e:
                    paradox = e
                    continue
            try:
                f = g.forces(A, S)
            except np.linalg.LinAlgError:
                continue
            if np.any(f.lam_n < 0.0):
                continue
            acc = g.held_acc(A, S) if A else g.free_acc(range(g.m))
            if any(acc[i] < -lcp_tol for i in near if i not in A):
                continue
            chosen = (A, S, f)
            break
        if chosen is not None:
            break
    if chosen is None:
        if paradox is not None:   # (a flat box sliding with mu above b / a: its leading corner alone)
            raise paradox
        raise RuntimeError(f"reference: no consistent contact forces for the contacts {near} at t={t:.6g}")
    A, S, f = chosen
    Wd = np.array([g.G[i] @ np.linalg.solve(g.M, g.G[i]) for i in A])
    keep = [a for a in range(len(A)) if f.lam_n[a] * Wd[a] > tol * scale]
    A = tuple(A[a] for a in keep)
    S = settle(g, A, tuple(S[a] for a in keep))
    return A, S


def _painleve(g, A, S, names):
    """PainleveError if the held problem of the sliding set (A, S) is singular: B = det K <= 0."""
    try:
        K = g.forces(A, S).K
    except np.linalg.LinAlgError:
        K = None
    if K is None or response(K, S) <= 0.0:
        i = next(i for i, s in zip(A, S) if s in (1, -1))
        B = 0.0 if K is None else response(K, S)
        raise PainleveError(i, names[i] if names is not None else f"{i}", g.t, B)


def check_painleve(g, A, S, names) -> None:
    """PainleveError where a held set with sliding contacts has B <= 0 (at a mode change)."""
    if any(s in (1, -1) for s in S):
        _painleve(g, tuple(A), tuple(S), names)


# --- the frictional impact law -------------------------------------------------------------------------

def impact(g, contacts, e_of):
    """The frictional impact law (vcirun.reference_solution.friction_law.friction_impact: the unit
    vcirun/collision/friction_law.py) at (q, p-) for the touching `contacts` (an index list, as
    impact_direction's `active`): (case, lam_n (m), lam_t (m), dp) with p+ = p- + dp. A contact
    separating (u_n > 0) takes no restitution, as collision/impact.py's law. g: the
    vcirun.reference_solution.held._Geometry at (t, q, p-)."""
    mu, _ = coefficients(g._mod, g._prm)
    idx = [int(i) for i in contacts]
    k = len(idx)
    rows = np.vstack([g.G[idx], g.Wt[idx]])
    W = rows @ np.linalg.solve(g.M, rows.T)
    W = 0.5 * (W + W.T)   # symmetric to round-off: made exactly so
    u = rows @ g.v
    e = np.array([e_of[i] if u[a] <= 0.0 else 0.0 for a, i in enumerate(idx)])
    from .friction_law import friction_impact  # the law's compiled unit, vcirun/collision/friction_law.py

    case, lam = friction_impact(W, u, e, mu[idx])
    lam_n, lam_t = np.zeros(g.m), np.zeros(g.m)
    lam_n[idx], lam_t[idx] = lam[:k], lam[k:]
    return case, lam_n, lam_t, rows.T @ lam
