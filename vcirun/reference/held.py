"""Held (resting) contacts in the exact reference (issue 18): the index-reduced constrained dynamics,
the projection onto the held manifold, a held segment with release and impact events, and the
three ways into a held phase (accumulation, plastic impact, a start at rest on the surface).
Derivations: docs/contacts.md, "Held contacts in the reference".

`mod` is the system-only compiled module (vcirun.codegen.build.load_module(system, SYSTEM_KERNELS)),
`prm` the parameter vector, y = (q, p) or (q, p, W) (a forced solve carries the work
W = int f . qdot as a last component: the held force does no work, so W' = f . qdot as when free).
A is a sequence of contact indices (the held set). No sympy here (the reference layer's rule).

With v = M^-1 p, F = -dH/dq + f (the p-part of dynamics_rhs) and G = G_A (rows grad phi_i, i in A):

    qdot = v,   pdot = F + G^T mu,   W mu = -(G M^-1 (F - Mdot v) + c),   W = G M^-1 G^T,

c_i = v^T Hess(phi_i) v, Mdot v = sys_Mdotv(q, v); mu_i >= 0 is the compressive contact force
(it pushes along +grad phi_i). Release: mu_i crosses 0 downwards.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import combinations

import numpy as np

__all__ = ["HELD_TOL", "ZENO_FLIGHT", "HeldSegment", "Transition", "held_multipliers", "free_normal_accelerations",
           "held_rhs", "project", "held_set", "initially_held", "plastic_entry", "held_segment", "after_held_event",
           "at_rest", "zeno_extrapolation", "accumulating", "zeno_entry"]

HELD_TOL = 1e-10    # relative: |phi_i|, |u_i| below this count as on the surface at rest (entry checks)
# s: a contact's flight shorter than this ends bounce resolution (accumulation). The held state at
# t_inf is then exact to O(d^3) ~ 1e-18 and t_inf to O(d^2) (0 for a constant normal force), and
# the bounces left are well above the free loop's micro step (1e-9 s) and touch tolerances
ZENO_FLIGHT = 1e-6
_EPS = np.finfo(float).eps


# --- the constrained dynamics -------------------------------------------------------------------

class _Geometry:
    """M, v = M^-1 p, F, all phi_i, G (m x n), c_i = v^T Hess phi_i v, Mdot v at one state."""

    __slots__ = ("n", "m", "q", "p", "M", "v", "F", "phis", "G", "c", "Mdv")

    def __init__(self, mod, t, q, p, prm):
        n, m = int(mod.NDOF), int(mod.NCON)
        self.n, self.m = n, m
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
        self.c = np.empty(m)
        mod.sys_ddphis(self.q, self.v, prm, self.c)
        self.Mdv = np.empty(n)
        mod.sys_Mdotv(self.q, self.v, prm, self.Mdv)

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

    def mu(self, A):
        W, _ = self.W(A)
        return np.linalg.solve(W, -self.free_acc(A))

    def held_acc(self, A):
        """d^2/dt^2 phi_i of every contact along the held flow of A (0 for i in A, up to round-off):
        G M^-1 (F + G_A^T mu - Mdot v) + c."""
        f = self.F - self.Mdv
        if A:
            f = f + self.G[list(A)].T @ self.mu(A)
        return self.G @ np.linalg.solve(self.M, f) + self.c

    def acc_scale(self):
        return max(float(np.max(np.abs(self.G @ np.linalg.solve(self.M, self.F)))), float(np.max(np.abs(self.c))),
                   _EPS)


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


def held_rhs(mod, prm, A):
    """f(t, y) for solve_ivp: the held dynamics qdot = v, pdot = F + G_A^T mu (and W' = f . v when
    y carries the work as a last component, len(y) = 2n + 1)."""
    A = tuple(int(i) for i in A)
    n = int(mod.NDOF)
    forced = bool(mod.FORCED)

    def rhs(t, y):
        g = _Geometry(mod, t, y[:n], y[n:2 * n], prm)
        out = np.empty(len(y))
        out[:n] = g.v
        out[n:2 * n] = g.F
        if A:
            out[n:2 * n] += g.G[list(A)].T @ g.mu(A)
        if len(y) > 2 * n:
            out[2 * n] = mod.force_power(g.q, g.v.copy(), float(t), prm) if forced else 0.0
        return out

    return rhs


# --- the projection ---------------------------------------------------------------------------

def project(mod, q, p, prm, A, iters=8):
    """(q, p) projected onto phi_A(q) = 0 and the hidden constraint G_A M^-1 p = 0.

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
    X = np.linalg.solve(M, G[A].T)
    Ga = G[A]
    p = p - Ga.T @ np.linalg.solve(Ga @ X, X.T @ p)
    return q, p


def _project_y(mod, y, prm, A):
    n = int(mod.NDOF)
    q, p = project(mod, y[:n], y[n:2 * n], prm, A)
    out = np.array(y, dtype=float)
    out[:n], out[n:2 * n] = q, p
    return out


def _violation(mod, y, prm, A):
    """max |phi_i| and max |u_i| over A at y (before projection: the drift of the index reduction)."""
    n = int(mod.NDOF)
    A = list(A)
    if not A:
        return 0.0, 0.0
    g = _Geometry(mod, 0.0, y[:n], y[n:2 * n], prm)
    u = g.G[A] @ g.v
    return float(np.max(np.abs(g.phis[A]))), float(np.max(np.abs(u)))


# --- which contacts are held -------------------------------------------------------------------

def _force_lcp(W, b):
    """The contact-force LCP at acceleration level: a = b + W mu >= 0, mu >= 0, mu_i a_i = 0, by
    enumeration of the active sets (smallest first; the small m of the scenes). W positive definite:
    exactly one set qualifies. Returns mu (singular subsets are skipped; None if no set qualifies)."""
    k = len(b)
    tol = 1e-12 * max(1.0, float(np.max(np.abs(b))) if k else 1.0)
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


def held_set(mod, t, q, p, prm, candidates=None, tol=HELD_TOL) -> tuple:
    """The contacts to hold at (t, q, p): among `candidates` (default all), those on the surface
    (|phi_i| <= tol (1 + |q| |grad phi_i|)) at rest (|u_i| <= tol (|grad phi_i| |v| + |grad phi_i|),
    u = G M^-1 p) whose force from the contact-force LCP (a = b + W mu >= 0, mu >= 0, complementary;
    b the free normal accelerations) is compressive, mu_i W_ii > tol times the acceleration scale.
    A contact at rest whose free normal acceleration is >= 0 needs no force and is not held."""
    g = _Geometry(mod, t, q, p, prm)
    cand = range(g.m) if candidates is None else [int(i) for i in candidates]
    qn = float(np.max(np.abs(g.q))) if g.n else 0.0
    vn = float(np.max(np.abs(g.v))) if g.n else 0.0
    near = []
    for i in cand:
        gn = float(np.max(np.abs(g.G[i])))
        u = float(g.G[i] @ g.v)
        if abs(g.phis[i]) <= tol * (1.0 + qn * gn) and abs(u) <= tol * gn * (1.0 + vn):
            near.append(i)
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
    O(flight) and t_inf is off by O(d2^2) (docs/contacts.md 6.4: -k d2^2 / (6 (1 - e)^2) for linear drag k).
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


def zeno_entry(mod, t_k, y_k, prm, contact, times, held=(), mask=None, rtol=1e-13, atol=None):
    """Case (a): contact `contact` accumulates. From its last impact (t_k, post-impact y_k) and its
    impact times (at least the last three), t_inf = zeno_extrapolation(times) and the held state at
    t_inf: y_k projected onto the held set held + (contact,) (the plastic limit of the remaining
    bounces, which carry a total normal impulse of u_k+ / W plus the held force's), then moved by
    the held flow over [t_k, t_inf]. The O(d^2) differences from the remaining bounces (d the last
    flight) are multiples of int u dt = 0 over them, so this state, and every later one, is exact to
    O(d^3) (docs/contacts.md 6.4); t_inf itself to O(d^2). Returns (t_inf, HeldSegment on
    [t_k, t_inf]) whose y1 is the held state at t_inf and whose dense output covers the interval."""
    t_inf = zeno_extrapolation(times)
    A = tuple(sorted(set(int(i) for i in held) | {int(contact)}))
    seg = held_segment(mod, t_k, y_k, t_inf, A, mask, prm, rtol, atol, release_events=False)
    return t_inf, seg


# --- the held segment ---------------------------------------------------------------------------

@dataclass
class HeldSegment:
    """A held phase [t0, t1] of the exact reference.

    sol(t) -> y (dense, (len(y),) or (len(y), len(t))), y1 the end state (projected onto the held
    manifold), reason "release" (contact `contact` released: mu crossed 0 downwards), "impact"
    (contact `contact`, not held, reached phi = 0), "pressed" (contact `contact`, at rest and not held,
    is pushed into its constraint) or "end" (T reached); held the held set A;
    mu(t) the multipliers along the segment (len(A)) or (len(A), len(t))); drift: max |phi_A| and
    max |G_A v| seen before any projection (the index reduction's drift, at the restarts and the end)."""

    t0: float
    t1: float
    y1: np.ndarray
    reason: str
    contact: int
    held: tuple
    drift: tuple = (0.0, 0.0)
    pieces: list = field(default_factory=list)  # [(t_start, t_end, OdeSolution)]
    _mu: object = None

    def sol(self, t):
        scalar = np.ndim(t) == 0
        ts = np.atleast_1d(np.asarray(t, dtype=float))
        starts = np.array([a for a, _, _ in self.pieces])
        idx = np.clip(np.searchsorted(starts, ts, side="right") - 1, 0, len(self.pieces) - 1)
        out = np.empty((len(self.y1), ts.size))
        for j in np.unique(idx):
            sel = idx == j
            out[:, sel] = self.pieces[j][2](ts[sel])
        return out[:, 0] if scalar else out

    __call__ = sol

    def mu(self, t):
        scalar = np.ndim(t) == 0
        ts = np.atleast_1d(np.asarray(t, dtype=float))
        ys = self.sol(ts)
        out = np.column_stack([self._mu(ts[k], ys[:, k]) for k in range(ts.size)]) if ts.size else \
            np.empty((len(self.held), 0))
        return out[:, 0] if scalar else out


def held_segment(mod, t0, y0, T, A, mask, prm, rtol=1e-13, atol=None, *, release_events=True,
                 drift_tol=None, max_restarts=1000) -> HeldSegment:
    """Integrate the held dynamics of the set A (DOP853, dense output) from y0 (projected first) at
    t0 until the first of: a release (mu_i, i in A, crosses 0 downwards; solve_ivp's event, located
    by brentq to ~4 eps relative on the dense output), an impact of a contact not held (the gap over
    the watched contacts crosses 0 downwards; a dip of the gap below 0 inside one step is found on
    the dense output, as in the free segments), a masked contact at rest pressed in ("pressed": its
    normal acceleration along the held flow crosses 0 downwards; at t0 already if it is negative
    there), or T.

    mask: int array (m) of the contacts touching and not approaching at t0 (vcirun's touching_mask),
    or None. A masked contact at rest (phi_i and u_i ~ 0, `at_rest`) is not watched by the gap but by
    its acceleration, with a fallback impact event at phi_i = -64 eps (1 + |q| |grad phi_i|) should
    it leave and come back; a masked contact that leaves (u_i > 0) is watched by the gap, with the
    first step at most 0.05 u_i / |phi_i''| so that a short flight is not inside it (its phi at t0 is
    round-off of either sign). atol defaults to rtol max(1, |y0|). If the constraint drift
    max |phi_A| exceeds drift_tol (default 1e3 atol) the solve stops, projects and continues (a
    restart, recorded in pieces); the jump of a restart is at most drift_tol. The end state is
    projected onto A. release_events=False: no release event (zeno_entry's short settle interval)."""
    from scipy.integrate import solve_ivp  # here: `import vcirun` stays light

    A = tuple(sorted(int(i) for i in A))
    if not A:
        raise ValueError("A: a held segment needs at least one held contact")
    n, m = int(mod.NDOF), int(mod.NCON)
    t0, T = float(t0), float(T)
    y = _project_y(mod, np.asarray(y0, dtype=float), prm, A)
    atol = rtol * max(1.0, float(np.max(np.abs(y)))) if atol is None else float(atol)
    drift_tol = 1e3 * atol if drift_tol is None else float(drift_tol)
    rhs = held_rhs(mod, prm, A)
    mask0 = np.zeros(m, dtype=np.int64) if mask is None else np.asarray(mask, dtype=np.int64).copy()
    g0 = _Geometry(mod, t0, y[:n], y[n:2 * n], prm)
    rest0 = at_rest(mod, t0, y[:n], y[n:2 * n], prm)
    acc0, u0 = g0.held_acc(A), g0.G @ g0.v
    watch = np.zeros(m, dtype=np.int64)   # 1 = not watched by the gap event (held, or masked at rest)
    watch[list(A)] = 1
    resting, first_step = [], None
    for i in range(m):
        if not mask0[i] or i in A:
            continue
        if i in rest0:
            watch[i] = 1
            resting.append(i)
            if acc0[i] < -HELD_TOL * g0.acc_scale():   # pushed in from the start: hold it (the caller)
                return HeldSegment(t0, t0, y, "pressed", i, A, (0.0, 0.0), [(t0, t0, _Constant(y))],
                                   lambda t, yy: _Geometry(mod, t, yy[:n], yy[n:2 * n], prm).mu(A))
        elif u0[i] > 0.0 and acc0[i] < 0.0:
            fs = 0.05 * u0[i] / -acc0[i]
            first_step = fs if first_step is None else min(first_step, fs)
    free = [i for i in range(m) if not watch[i]]

    def mu_at(t, yy):
        return _Geometry(mod, t, yy[:n], yy[n:2 * n], prm).mu(A)

    events, kinds = [], []
    if release_events:
        for a, i in enumerate(A):
            def rel(t, yy, a=a):
                return mu_at(t, yy)[a]
            rel.terminal, rel.direction = True, -1.0
            events.append(rel)
            kinds.append(("release", i))
    if free:
        def gap(t, yy):
            return mod.gap(yy[:n].copy(), prm, watch)
        gap.terminal, gap.direction = True, -1.0
        events.append(gap)
        kinds.append(("impact", -1))

        def dip(t, yy):
            return mod.gap_slope(yy[:n].copy(), yy[n:2 * n].copy(), prm, watch)
        dip.terminal, dip.direction = False, 1.0
        events.append(dip)
        kinds.append(("dip", -1))
    for i in resting:
        def pressed(t, yy, i=i):
            return _Geometry(mod, t, yy[:n], yy[n:2 * n], prm).held_acc(A)[i]
        pressed.terminal, pressed.direction = True, -1.0
        events.append(pressed)
        kinds.append(("pressed", i))

        def back(t, yy, i=i):
            phis = np.empty(m)
            mod.sys_phis(yy[:n].copy(), prm, phis)
            gn = np.empty((m, n))
            mod.sys_dphis(yy[:n].copy(), prm, gn)
            return phis[i] + 64 * _EPS * (1.0 + np.max(np.abs(yy[:n])) * np.max(np.abs(gn[i])))
        back.terminal, back.direction = True, -1.0
        events.append(back)
        kinds.append(("impact", i))

    def drift(t, yy):
        phis = np.empty(m)
        mod.sys_phis(yy[:n].copy(), prm, phis)
        return drift_tol - float(np.max(np.abs(phis[list(A)])))
    drift.terminal, drift.direction = True, -1.0
    events.append(drift)
    kinds.append(("drift", -1))

    pieces, worst = [], [0.0, 0.0]
    t = t0
    for _ in range(max_restarts):
        if not t < T:
            pieces.append((t, t, _Constant(y)))
            return HeldSegment(t0, t, y, "end", -1, A, tuple(worst), pieces, mu_at)
        fs = None if first_step is None or t > t0 else min(first_step, T - t)
        sol = solve_ivp(rhs, (t, T), y, method="DOP853", rtol=rtol, atol=atol, events=events, dense_output=True,
                        first_step=fs)
        if sol.status < 0:
            raise RuntimeError(f"reference: DOP853 failed in a held phase at t={sol.t[-1]:.6g}: {sol.message}")
        hit = None  # (time, kind index)
        for k, te in enumerate(sol.t_events):
            if kinds[k][0] != "dip" and te.size and (hit is None or te[0] < hit[0]):
                hit = (float(te[0]), k)
        # a dip of the gap below 0 shorter than one step: an earlier, missed impact (as in _exact)
        k_dip = next((k for k, kd in enumerate(kinds) if kd[0] == "dip"), None)
        if k_dip is not None:
            for tm, ym in zip(sol.t_events[k_dip], sol.y_events[k_dip]):
                if hit is not None and tm >= hit[0]:
                    break
                if mod.gap(ym[:n].copy(), prm, watch) < 0.0:
                    te = _first_root(lambda s: mod.gap(sol.sol(s)[:n].copy(), prm, watch), t, float(tm))
                    hit = (te, next(k for k, kd in enumerate(kinds) if kd == ("impact", -1)))
                    break
        t_end = T if hit is None else hit[0]
        pieces.append((t, t_end, sol.sol))
        y_end = np.asarray(sol.sol(t_end) if hit is not None else sol.y[:, -1], dtype=float)
        if hit is not None and kinds[hit[1]][0] != "dip":
            k = hit[1]
            idx = [j for j, te in enumerate(sol.t_events[k]) if te == hit[0]]
            if idx:
                y_end = np.asarray(sol.y_events[k][idx[0]], dtype=float)
        dphi, du = _violation(mod, y_end, prm, A)
        worst = [max(worst[0], dphi), max(worst[1], du)]
        y_end = _project_y(mod, y_end, prm, A)
        if hit is None:
            return HeldSegment(t0, T, y_end, "end", -1, A, tuple(worst), pieces, mu_at)
        kind, i = kinds[hit[1]]
        if kind == "drift":
            t, y = t_end, y_end
            continue
        if kind == "impact" and i < 0:
            phis = np.empty(m)
            mod.sys_phis(y_end[:n].copy(), prm, phis)
            i = min(free, key=lambda j: phis[j])
        return HeldSegment(t0, t_end, y_end, kind, int(i), A, tuple(worst), pieces, mu_at)
    raise RuntimeError(f"reference: more than {max_restarts} drift restarts in a held phase by t={t:.6g}")


def _first_root(g, a, b, samples=64):
    """First sign change of g on [a, b] (g(a) >= 0 > g(b)): dense samples bracket it, brentq refines
    (as vcirun.reference's; not imported from there, which imports this module)."""
    from scipy.optimize import brentq

    ts = np.linspace(a, b, samples + 1)
    prev = ts[0]
    for s in ts[1:]:
        if g(s) < 0.0:
            return float(brentq(g, prev, s, xtol=1e-15, rtol=4 * _EPS))
        prev = s
    return float(b)


class _Constant:
    """Dense output of an empty interval (the segment starts at its end)."""

    def __init__(self, y):
        self.y = np.asarray(y, dtype=float)

    def __call__(self, t):
        ts = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.repeat(self.y[:, None], ts.size, axis=1)
        return out[:, 0] if np.ndim(t) == 0 else out


# --- after a held segment -----------------------------------------------------------------------

@dataclass
class Transition:
    """What follows a held segment: the time and state to continue from (projected onto the new held
    set), the new held set (empty: free motion), the impacts applied (time, contact, impulse), one
    entry per contact as in vcirun.reference, the released contact (-1 if none) and `rest`: the
    contacts on their surface at rest that are not held (the released one among them), which the
    next free segment must mask (their normal velocity is round-off of either sign)."""

    t: float
    y: np.ndarray
    held: tuple
    impacts: list
    released: int
    rest: tuple


def at_rest(mod, t, q, p, prm, tol=HELD_TOL) -> tuple:
    """The contacts on their surface (|phi_i| small) with a numerically zero normal velocity (the
    tolerances of held_set), whatever their force."""
    g = _Geometry(mod, t, q, p, prm)
    qn = float(np.max(np.abs(g.q)))
    vn = float(np.max(np.abs(g.v)))
    out = []
    for i in range(g.m):
        gn = float(np.max(np.abs(g.G[i])))
        if abs(g.phis[i]) <= tol * (1.0 + qn * gn) and abs(float(g.G[i] @ g.v)) <= tol * gn * (1.0 + vn):
            out.append(i)
    return tuple(out)


def after_held_event(mod, seg: HeldSegment, prm, event_tol=2.5e-11, tol=HELD_TOL) -> Transition:
    """The transition at the end of a held segment, as the exact reference's loop takes it:

    - "release" of contact i: the held set becomes the contacts of A - {i} that still need a
      compressive force (held_set; at the release mu_i = 0, so the others' forces are continuous);
    - "impact" of contact j: the impact law of the integrators (mod.impact_direction: Newton's law
      for one contact, Moreau's LCP over the touching contacts, the held ones included with
      u- = 0), p+ = p- + s0 d, one impact entry per contact with lam > 0 that is not held (issue 18:
      no impact is recorded for a held contact; its impulse is the constraint's); then the held set is
      held_set over all contacts at (q, p+) (the held contacts that kept u = 0 and a compressive
      force, and j itself if its impact was plastic and it is pressed: case (b));
    - "pressed" (contact j at rest pushed in): held_set over A + {j}, no impact;
    - "end": nothing changes.
    The state is projected onto the new held set. event_tol: the impact law's simultaneity
    tolerance in seconds (vcirun.reference uses SIMULTANEOUS / 4)."""
    n, m = int(mod.NDOF), int(mod.NCON)
    t, y = seg.t1, np.array(seg.y1, dtype=float)
    impacts, released = [], -1
    if seg.reason == "end":
        return Transition(t, y, seg.held, impacts, -1, ())
    if seg.reason == "release":
        released = seg.contact
        held = held_set(mod, t, y[:n], y[n:2 * n], prm, [i for i in seg.held if i != released], tol)
    elif seg.reason == "pressed":  # a contact at rest now needs a force: hold it (no impact)
        held = held_set(mod, t, y[:n], y[n:2 * n], prm, sorted(set(seg.held) | {seg.contact}), tol)
    elif seg.reason == "impact":
        d, lam, active = np.empty(n), np.empty(m), np.empty(m, dtype=np.int64)
        k, s0, _ = mod.impact_direction(y[:n].copy(), y[n:2 * n].copy(), 1.0, event_tol, prm, d, lam, active)
        if k < 0:
            raise RuntimeError(f"reference: the impact law has no solution at t={t:.6g} (case {k})")
        if k > 0:  # k == 0: the contact reached phi = 0 without approaching (a grazing touch)
            y[n:2 * n] += s0 * d
            for i in np.flatnonzero(active):  # held contacts take part (u- = 0) but record nothing
                if (m == 1 or lam[i] > 0.0) and int(i) not in seg.held:
                    impacts.append((t, int(i), float(s0 if m == 1 else lam[i])))
        held = held_set(mod, t, y[:n], y[n:2 * n], prm, None, tol)
    else:
        raise ValueError(f"seg.reason: {seg.reason!r} is not release, impact, pressed or end")
    if held:
        y = _project_y(mod, y, prm, held)
    rest = tuple(i for i in at_rest(mod, t, y[:n], y[n:2 * n], prm, tol) if i not in held)
    return Transition(t, y, tuple(held), impacts, released, rest)
