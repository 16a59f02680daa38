"""Held (resting) contacts in the exact reference: the index-reduced constrained dynamics, the
projection onto the held manifold, which contacts are held (the contact-force LCP), the contacts at
rest, and accumulation (the Zeno time extrapolated from a contact's flights). The held phases
themselves are segments of the backends (vcirun.reference_solution.taylor, vcirun.reference_solution.dop853) driven by
the event loop (vcirun.reference_solution.loop).
Derivations: docs/derivations/contacts.md, "Held contacts in the reference".

`mod` is the system-only compiled module (vcirun.codegen.build.load_module(system, SYSTEM_KERNELS)),
`prm` the parameter vector, y = (q, p) or (q, p, W) (a forced solve carries the work
W = int f . qdot as a last component: the held force does no work, so W' = f . qdot as when free).
A is a sequence of contact indices (the held set). No sympy here (the reference layer's rule).

With v = M^-1 p, F = -dH/dq + f (the p-part of dynamics_rhs) and G = G_A (rows grad phi_i, i in A):

    qdot = v,   pdot = F + G^T mu,   W mu = -(G M^-1 (F - Mdot v) + c),   W = G M^-1 G^T,

c_i = v^T Hess(phi_i) v, Mdot v = sys_Mdotv(q, v); mu_i >= 0 is the compressive contact force
(it pushes along +grad phi_i). Release: mu_i crosses 0 downwards.

With Coulomb friction a held contact also has a mode (sliding with the sign of its slip velocity, or
sticking), given as a tuple S aligned with A; the forces of (A, S) are vcirun.reference_solution.coulomb's.
S None (or every contact SMOOTH) is the frictionless dynamics above, computed as above.
"""
from __future__ import annotations

import math
from itertools import combinations

import numpy as np

from .coulomb import FORCE_LCP_TOL, SMOOTH, STICK, held_forces, independent_sticks

__all__ = ["HELD_TOL", "ZENO_FLIGHT", "held_multipliers", "free_normal_accelerations", "held_rhs", "project",
           "held_set", "initially_held", "plastic_entry", "at_rest", "zeno_extrapolation", "accumulating"]

HELD_TOL = 1e-10    # relative: |phi_i|, |u_i| below this count as on the surface at rest (DOP853's precision;
#                     the Taylor path uses its own, vcirun.reference_solution.taylor.REST_TOL)
# s: a contact's flight shorter than this ends bounce resolution (accumulation). The held state at
# t_inf is then exact to O(d^3) ~ 1e-18 and t_inf to O(d^2) (0 for a constant normal force), and
# the bounces left are well above the touch tolerances
ZENO_FLIGHT = 1e-6
_EPS = np.finfo(float).eps


# --- the constrained dynamics -------------------------------------------------------------------

class _Geometry:
    """M, v = M^-1 p, F, all phi_i, G (m x n) and u = G v at one state; c_i = v^T Hess phi_i v and
    Mdot v on first use."""

    __slots__ = ("n", "m", "t", "q", "p", "M", "v", "F", "phis", "G", "u", "_c", "_Mdv", "_mod", "_prm", "_minv_f",
                 "_held_acc", "_Wt", "_dslip", "_forces")

    def __init__(self, mod, t, q, p, prm):
        n, m = int(mod.NDOF), int(mod.NCON)
        self.n, self.m, self.t = n, m, float(t)
        self._mod, self._prm = mod, prm
        self.q = np.ascontiguousarray(q, dtype=float)
        self.p = np.ascontiguousarray(p, dtype=float)
        out = np.empty(2 * n)
        mod.dynamics_rhs(float(t), np.concatenate([self.q, self.p]), prm, out)
        self.v, self.F = out[:n].copy(), out[n:].copy()
        self.M = np.empty((n, n))
        mod.sys_M(self.q, prm, self.M)
        self.phis = np.empty(m)
        mod.sys_phis(self.q, prm, self.phis)
        self.G = np.empty((m, n))
        mod.sys_dphis(self.q, prm, self.G)
        self.u = self.G @ self.v
        self._c = self._Mdv = self._minv_f = self._Wt = self._dslip = None
        self._held_acc = {}
        self._forces = {}

    @property
    def c(self):
        if self._c is None:
            self._c = np.empty(self.m)
            self._mod.sys_ddphis(self.q, self.v, self._prm, self._c)
        return self._c

    @property
    def Mdv(self):
        if self._Mdv is None:
            self._Mdv = np.empty(self.n)
            self._mod.sys_Mdotv(self.q, self.v, self._prm, self._Mdv)
        return self._Mdv

    @property
    def Wt(self):
        """The slip rows W_t (m x n, zero rows where a contact has no friction)."""
        if self._Wt is None:
            self._Wt = np.empty((self.m, self.n))
            self._mod.sys_slips(self.q, self._prm, self._Wt)
        return self._Wt

    @property
    def wt(self):
        """The slip velocities W_t v."""
        return self.Wt @ self.v

    @property
    def dslip(self):
        """v^T dW_t,i/dq v: the velocity terms of d(v_t,i)/dt."""
        if self._dslip is None:
            self._dslip = np.empty(self.m)
            self._mod.sys_dslips(self.q, self.v, self._prm, self._dslip)
        return self._dslip

    def forces(self, A, S):
        """The held forces of the held set A in the friction modes S (vcirun.reference_solution.coulomb.Forces),
        kept per (A, S)."""
        key = (tuple(A), tuple(S))
        if key not in self._forces:
            self._forces[key] = held_forces(self, tuple(A), tuple(S))
        return self._forces[key]

    def near(self, candidates=None, tol=None):
        """The contacts among `candidates` (default all) on their surface, |phi_i| <= tol (1 + |q| |grad
        phi_i| + |t| |grad phi_i| |v|) (the last term: an event time's round-off times the speed), with a
        numerically zero normal velocity, |u_i| <= tol |grad phi_i| (1 + |v|)."""
        tol = HELD_TOL if tol is None else tol
        qn = max(map(abs, self.q.tolist()), default=0.0)   # (plain floats: the arrays are tiny)
        vn = max(map(abs, self.v.tolist()), default=0.0)
        phis, u, G, at = self.phis.tolist(), self.u.tolist(), self.G.tolist(), abs(self.t)
        out = []
        for i in (range(self.m) if candidates is None else candidates):
            i = int(i)
            gn = max(map(abs, G[i]), default=0.0)
            if abs(phis[i]) <= tol * (1.0 + qn * gn + at * gn * vn) and abs(u[i]) <= tol * gn * (1.0 + vn):
                out.append(i)
        return out

    def W(self, A):
        """G_A M^-1 G_A^T and X = M^-1 G_A^T."""
        G = self.G[list(A)]
        X = np.linalg.solve(self.M, G.T)
        return G @ X, X

    def free_acc(self, A):
        """d^2/dt^2 phi_A with no contact force: G M^-1 (F - Mdot v) + c (the velocity terms: vdot =
        M^-1 (pdot - Mdot v) from p = M v)."""
        idx = list(A)
        return self.G[idx] @ np.linalg.solve(self.M, self.F - self.Mdv) + self.c[idx]

    def mu(self, A, S=None):
        """The normal forces of the held set A (in the friction modes S: vcirun.reference_solution.coulomb)."""
        if _frictional(S):
            return self.forces(A, S).lam_n
        W, _ = self.W(A)
        return np.linalg.solve(W, -self.free_acc(A))

    def held_acc(self, A, S=None):
        """d^2/dt^2 phi_i of every contact along the held flow of A (0 for i in A, up to round-off):
        G M^-1 (F + G_A^T mu - Mdot v) + c (kept per A; in the friction modes S: with the forces of
        vcirun.reference_solution.coulomb)."""
        A = tuple(A)
        if _frictional(S):
            key = (A, tuple(S))
            if key not in self._held_acc:
                self._held_acc[key] = self.G @ np.linalg.solve(self.M, self.forces(A, S).pdot - self.Mdv) + self.c
            return self._held_acc[key]
        if A not in self._held_acc:
            f = self.F - self.Mdv
            if A:
                f = f + self.G[list(A)].T @ self.mu(A)
            self._held_acc[A] = self.G @ np.linalg.solve(self.M, f) + self.c
        return self._held_acc[A]

    def acc_scale(self):
        return max(float(np.max(np.abs(self.G @ np.linalg.solve(self.M, self.F)))), float(np.max(np.abs(self.c))),
                   _EPS)


def _frictional(S) -> bool:
    """Some held contact of the modes S has friction (a mode other than SMOOTH)."""
    return S is not None and any(s != SMOOTH for s in S)


def held_multipliers(mod, t, q, p, prm, A) -> np.ndarray:
    """mu (len(A)) of the held contacts A at (t, q, p): the solution of
    G M^-1 (F + G^T mu - Mdot v) + (v^T Hess phi_i v)_i = 0, i.e. d^2/dt^2 phi_A = 0; mu_i > 0 is
    compressive (the force G^T mu pushes along +grad phi_i)."""
    A = tuple(int(i) for i in A)
    if not A:
        return np.empty(0)
    return _Geometry(mod, t, q, p, prm).mu(A)


def free_normal_accelerations(mod, t, q, p, prm) -> np.ndarray:
    """d^2/dt^2 phi_i (all m contacts) along the free motion through (t, q, p)."""
    g = _Geometry(mod, t, q, p, prm)
    return g.free_acc(range(g.m))


def held_rhs(mod, prm, A, S=None):
    """f(t, y) for solve_ivp: the held dynamics qdot = v, pdot = F + G_A^T mu (with friction modes S:
    the forces of vcirun.reference_solution.coulomb; and W' = f . v when y carries the work as a last
    component, len(y) = 2n + 1)."""
    A = tuple(int(i) for i in A)
    n = int(mod.NDOF)
    forced = bool(mod.FORCED)
    fric = _frictional(S)

    def rhs(t, y):
        g = _Geometry(mod, t, y[:n], y[n:2 * n], prm)
        out = np.empty(len(y))
        out[:n] = g.v
        out[n:2 * n] = g.F
        if fric:
            out[n:2 * n] = g.forces(A, S).pdot
        elif A:
            out[n:2 * n] += g.G[list(A)].T @ g.mu(A)
        if len(y) > 2 * n:
            out[2 * n] = mod.force_power(g.q, g.v.copy(), float(t), prm) if forced else 0.0
        return out

    return rhs


# --- the projection ---------------------------------------------------------------------------

def project(mod, q, p, prm, A, iters=8, stick=()):
    """(q, p) projected onto phi_A(q) = 0 and the hidden constraint G_A M^-1 p = 0 (and W_t,i M^-1 p = 0
    for the sticking contacts i of `stick`: their slip velocities).

    Positions: Newton along M^-1 G^T, q <- q - M^-1 G^T (G M^-1 G^T)^-1 phi_A(q) (the M-orthogonal
    direction, so the correction changes the kinetic metric least), G and M re-evaluated each
    iteration, until |phi_A| stops decreasing or reaches round-off. Momenta at the new q:
    p <- p - G^T (G M^-1 G^T)^-1 G M^-1 p, the M^-1-orthogonal projection (the plastic impulse
    that removes the normal velocities u_A and changes nothing tangentially)."""
    A = [int(i) for i in A]
    q = np.array(q, dtype=float)
    p = np.array(p, dtype=float)
    if not A:
        return q, p
    n, m = int(mod.NDOF), int(mod.NCON)
    M = np.empty((n, n))
    phis = np.empty(m)
    G = np.empty((m, n))
    best = math.inf
    for _ in range(iters):
        mod.sys_phis(q, prm, phis)
        r = phis[A].copy()
        err = float(np.max(np.abs(r)))
        if err == 0.0 or err >= best:
            break
        best = err
        mod.sys_M(q, prm, M)
        mod.sys_dphis(q, prm, G)
        X = np.linalg.solve(M, G[A].T)
        q = q - X @ np.linalg.solve(G[A] @ X, r)
    mod.sys_M(q, prm, M)
    mod.sys_dphis(q, prm, G)
    Ga = G[A]
    if stick:
        Wt = np.empty((m, n))
        mod.sys_slips(q, prm, Wt)
        Ga = np.vstack([Ga, Wt[list(stick)]])
        Ga = Ga[list(range(len(A))) + independent_sticks(Ga, len(A))]   # (dependent sticking rows add nothing)
    X = np.linalg.solve(M, Ga.T)
    p = p - Ga.T @ np.linalg.solve(Ga @ X, X.T @ p)
    return q, p


def _project_y(mod, y, prm, A, S=None):
    n = int(mod.NDOF)
    stick = [i for i, s in zip(A, S) if s == STICK] if _frictional(S) else ()
    q, p = project(mod, y[:n], y[n:2 * n], prm, A, stick=stick)
    out = np.array(y, dtype=float)
    out[:n], out[n:2 * n] = q, p
    return out


# --- which contacts are held -------------------------------------------------------------------

# Normal accelerations within FORCE_LCP_TOL max(1, |b|) of zero are zero to the contact-force LCP
# (FORCE_LCP_TOL: vcirun.reference_solution.coulomb, beside the friction modes STICK, SMOOTH).


def press_level(g, tol) -> float:
    """How far below zero a resting contact's normal acceleration must be to count as pushed in: twice
    the larger of the rest tolerance times the acceleration scale of the _Geometry g and the force
    LCP's zero, so that every contact found pushed in gets a compressive force from held_set."""
    b = float(np.max(np.abs(g.free_acc(list(range(g.m)))))) if g.m else 0.0
    return 2.0 * max(tol * g.acc_scale(), FORCE_LCP_TOL * max(1.0, b))


def _force_lcp(W, b):
    """The contact-force LCP at acceleration level: a = b + W mu >= 0, mu >= 0, mu_i a_i = 0, by
    enumeration of the active sets (smallest first; the small m of the scenes). W positive definite:
    exactly one set qualifies. Returns mu (singular subsets are skipped; None if no set qualifies)."""
    k = len(b)
    tol = FORCE_LCP_TOL * max(1.0, float(np.max(np.abs(b))) if k else 1.0)
    for size in range(k + 1):
        for S in combinations(range(k), size):
            mu = np.zeros(k)
            if S:
                S = list(S)
                Wss = W[np.ix_(S, S)]
                if np.linalg.cond(Wss) > 1e12:
                    continue
                mu[S] = np.linalg.solve(Wss, -b[S])
                if np.any(mu[S] < 0.0):
                    continue
            a = b + W @ mu
            if np.all(a >= -tol):
                return mu
    return None


def held_set(mod, t, q, p, prm, candidates=None, tol=HELD_TOL, geo=None) -> tuple:
    """The contacts to hold at (t, q, p): among `candidates` (default all), those on the surface
    (|phi_i| <= tol (1 + |q| |grad phi_i|)) at rest (|u_i| <= tol (|grad phi_i| |v| + |grad phi_i|),
    u = G M^-1 p) whose force from the contact-force LCP (a = b + W mu >= 0, mu >= 0, complementary;
    b the free normal accelerations) is compressive, mu_i W_ii > tol times the acceleration scale.
    A contact at rest whose free normal acceleration is >= 0 needs no force and is not held.
    geo: the _Geometry at (t, q, p) if the caller has it."""
    g = _Geometry(mod, t, q, p, prm) if geo is None else geo
    near = g.near(candidates, tol)
    if not near:
        return ()
    W, _ = g.W(near)
    b = g.free_acc(near)
    mu = _force_lcp(W, b)
    if mu is None:
        raise RuntimeError(f"reference: no consistent contact forces for the contacts {near} at t={t:.6g}")
    scale = max(float(np.max(np.abs(b))), float(np.max(np.abs(g.G[near] @ np.linalg.solve(g.M, g.F)))), _EPS)
    return tuple(i for a, i in enumerate(near) if mu[a] * W[a, a] > tol * scale)


def initially_held(mod, q, p, prm, tol=HELD_TOL, t=0.0) -> tuple:
    """Case (c): a start on phi_i = 0 with zero normal velocity and a compressive force (held_set
    over all contacts at the initial state)."""
    return held_set(mod, t, q, p, prm, None, tol)


def plastic_entry(mod, t, q, p_plus, prm, contacts, tol=HELD_TOL) -> tuple:
    """Case (b): after an impact (p_plus from the impact law) the contacts of `contacts` left with a
    normal velocity that is numerically zero (e = 0) and a compressive force are held; returns that
    set (the caller projects: project(mod, q, p_plus, prm, A))."""
    return held_set(mod, t, q, p_plus, prm, contacts, tol)


# --- accumulation ----------------------------------------------------------------------------

def zeno_extrapolation(times) -> float:
    """The accumulation time of a contact's impacts from its last three impact times
    t_{k-2} < t_{k-1} < t_k: flights d1 = t_{k-1} - t_{k-2}, d2 = t_k - t_{k-1}, ratio r = d2 / d1,
    t_inf = t_k + d2 r / (1 - r) (the geometric sum of the remaining flights). Exact for a geometric
    sequence (constant normal acceleration, restitution e: r = e); in general the ratio drifts by
    O(flight) and t_inf is off by O(d2^2) (docs/derivations/contacts.md 6.4: -k d2^2 / (6 (1 - e)^2) for linear drag k).
    ValueError unless 0 < r < 1."""
    ts = np.asarray(times, dtype=float).ravel()
    if ts.size < 3 or not np.all(np.isfinite(ts[-3:])):
        raise ValueError(f"times: need the last three finite impact times of the contact (got {ts.size})")
    t0, t1, t2 = ts[-3:]
    d1, d2 = t1 - t0, t2 - t1
    if not (d1 > 0.0 and d2 > 0.0):
        raise ValueError(f"times: the last three impact times must increase (flights {d1:.3g}, {d2:.3g})")
    r = d2 / d1
    if not r < 1.0:
        raise ValueError(f"times: the flights do not shrink (ratio {r:.6g} >= 1): no accumulation point")
    return float(t2 + d2 * r / (1.0 - r))


def accumulating(times, flight=ZENO_FLIGHT, e=None) -> bool:
    """True when a contact's impact times (its own, in order) show accumulation: at least three, the
    last flight shorter than `flight` and than the one before. With the contact's restitution e, also
    the flight ratio r = d2 / d1 within 1e-3 of e (as d -> 0, r = e (1 + O(d)) under any smooth
    compressive normal acceleration), which rules out shrinking flights that do not accumulate (e = 1
    with drag: r = 1 - O(d), flights ~ 1/j, no finite Zeno time)."""
    ts = np.asarray(times, dtype=float).ravel()
    if ts.size < 3:
        return False
    d1, d2 = ts[-2] - ts[-3], ts[-1] - ts[-2]
    if not (0.0 < d2 < flight and d2 < d1):
        return False
    return e is None or (float(e) < 1.0 and abs(d2 / d1 - float(e)) <= 1e-3)


# --- contacts at rest ---------------------------------------------------------------------------

def at_rest(mod, t, q, p, prm, tol=HELD_TOL, geo=None) -> tuple:
    """The contacts on their surface (|phi_i| small) with a numerically zero normal velocity (the
    tolerances of held_set), whatever their force. geo: the _Geometry at (t, q, p) if the caller has it."""
    g = _Geometry(mod, t, q, p, prm) if geo is None else geo
    return tuple(g.near(None, tol))


def approach_time(g, A, contacts) -> float:
    """The shortest time any of `contacts` could need to reach its surface from the state of the
    _Geometry g, moving on the held flow of A: (u + sqrt(u^2 + 2 |a| max(phi, 0))) / |a| with phi_i, u_i,
    a_i its gap, normal velocity and normal acceleration, a_i taken towards the surface (phi / -u for
    a = 0 and u < 0; inf if none can). A contact leaving its surface (u > 0) gets the time of its hop.
    The integrators' steps are bounded by a multiple of it, so that a short flight is never a small
    part of one step."""
    if not contacts:
        return np.inf
    acc, phis, u = g.held_acc(tuple(A)).tolist(), g.phis.tolist(), g.u.tolist()
    tau = np.inf
    for i in contacts:
        a, ph, ui = abs(acc[i]), max(phis[i], 0.0), u[i]
        if a > 0.0:
            ti = (ui + math.sqrt(ui * ui + 2.0 * a * ph)) / a
        else:
            ti = ph / -ui if ui < 0.0 else np.inf
        tau = min(tau, ti)
    return tau
