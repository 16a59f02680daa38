"""Energy accounts: where the energy of a run (a Trajectory) or of the exact reference went.

    H(t) - H(t0) = sum over the terms of their contribution up to t  +  the rest,

one row per term (docs/derivations/energy_account.md derives each):

- "impact law": minus the energy the impact law removes -- Newton's/Moreau's restitution loss
  L = -1/2 sum_i lam_i (1 - e_i) u-_i at each impact (0 exactly when every e_i = 1), the plastic
  projections of contacts that are held (their normal velocities zeroed), and what a declared reset
  map removes. For a run it is evaluated from the recorded pre-impact state (q, p-) by the law itself,
  not read off the jump of the run's H: the energy-based resets (R^VCI, R^MCVA) move H by the law's
  loss plus their own O(h^p) error, and that error belongs to the rest.
- "forcing work": int f(q, qdot, t) . qdot dt along the motion (0 for an unforced system). For a run:
  3-point Gauss-Legendre quadrature on every piece of the dense output (pieces end at grid points and
  impacts, so no velocity jump is straddled), error O(h^4) from the interpolant; for the exact
  reference: the work integral the solve carries as a state.
- the rest: what no term explains -- the integration error (for the exact reference: the accuracy of
  the solve).

- "friction work" (systems with friction): the work of the held contacts' friction forces while they
  slide, which the loop sums per step (the friction impulses of each stage against its mean slip
  velocity: docs/derivations/friction.md, "Held contacts with friction"). The frictional impact law's
  own loss (friction at impacts) is in "impact law".

A term is one `EnergyTerm`. Each term's `series` is its
cumulative contribution on the account's time grid; `rest_series` is H - H(t0) minus all of them,
`error` its largest magnitude, the figure `vcirun simulate` prints as the energy error.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["EnergyTerm", "EnergyEvent", "EnergyAccount", "trajectory_account", "reference_account",
           "LAW", "FORCING", "FRICTION"]

LAW = "impact law"
FORCING = "forcing work"
FRICTION = "friction work"
_DOC = {LAW: "restitution, friction and plastic losses of the impacts (and what a declared reset removes)",
        FORCING: "work of the generalized force f along the motion",
        FRICTION: "work of the held contacts' friction forces (sliding), summed by the loop over each step"}
# Gauss-Legendre nodes and weights on [0, 1] (3 points: exact for polynomials of degree 5)
_GL_X = 0.5 + 0.5 * np.array([-np.sqrt(0.6), 0.0, np.sqrt(0.6)])
_GL_W = np.array([5.0, 8.0, 5.0]) / 18.0


@dataclass(frozen=True)
class EnergyTerm:
    """One row of an account: its contribution to H(t) - H(t0) (negative: energy removed) at the
    account's times (`series`) and at the end (`total`)."""

    name: str
    total: float
    series: np.ndarray = field(repr=False)
    doc: str = ""


@dataclass(frozen=True)
class EnergyEvent:
    """One impact event (simultaneous impacts: one event): its time, contacts, the energy the law
    removes (`loss` >= 0), and the change of H across it in the record, H(q, p-) - H(q+, p+) (`jump`;
    equal to `loss` up to round-off for CVA, the law's own update)."""

    time: float
    contacts: tuple
    loss: float
    jump: float


@dataclass
class EnergyAccount:
    """H(t) - H(t0) split into named terms and the rest (see the module docstring). t: the times of
    the account (a run: its grid; the exact reference: a dense grid with every event), H: the
    Hamiltonian there, scale: the energy scale relative figures use (max(|H0|, largest kinetic
    energy))."""

    t: np.ndarray = field(repr=False)
    H: np.ndarray = field(repr=False)
    terms: tuple
    events: tuple = field(default=(), repr=False)
    scale: float = float("nan")
    notes: tuple = ()
    quadrature: str = ""

    @property
    def H0(self) -> float:
        return float(self.H[0])

    @property
    def change(self) -> float:
        """H at the last finite entry minus H(t0)."""
        k = np.flatnonzero(np.isfinite(self.H))
        return float(self.H[k[-1]] - self.H[0]) if k.size else float("nan")

    def term(self, name) -> EnergyTerm | None:
        return next((x for x in self.terms if x.name == name), None)

    def total(self, name) -> float:
        """The total of term `name` (0.0 if the account has no such row)."""
        x = self.term(name)
        return 0.0 if x is None else x.total

    @property
    def law_loss(self) -> float:
        """Energy the impact law removed (>= 0): minus the law's term."""
        return -self.total(LAW)

    @property
    def rest_series(self) -> np.ndarray:
        out = np.asarray(self.H, float) - self.H0
        for x in self.terms:
            out = out - x.series
        return out

    @property
    def rest(self) -> float:
        """The rest at the end (the last finite entry)."""
        r = self.rest_series
        k = np.flatnonzero(np.isfinite(r))
        return float(r[k[-1]]) if k.size else float("nan")

    @property
    def error(self) -> float:
        """max |rest| over the account's times: the integration error (NaN without energies)."""
        r = np.abs(self.rest_series)
        return float(np.nanmax(r)) if np.isfinite(r).any() else float("nan")

    @property
    def relative_error(self) -> float:
        return self.error / self.scale if self.scale > 0 and np.isfinite(self.scale) else float("nan")

    def rows(self) -> list:
        """[(name, value)]: the change, each term, the rest at the end, the largest rest."""
        out = [("energy change H(T) - H(t0)", self.change)]
        out += [(x.name, x.total) for x in self.terms]
        out += [("rest (integration error) at the end", self.rest), ("largest |rest| over the run", self.error)]
        return out

    def table(self) -> str:
        """The account as aligned text lines."""
        rows = self.rows()
        w = max(len(k) for k, _ in rows)
        # (+ 0.0: a sum of zeros printed as 0, not -0)
        lines = [f"{k:<{w}}  {v + 0.0: .6e}" for k, v in rows]
        if self.events:
            lines.append(f"{len(self.events)} impact events; the law removed {self.law_loss + 0.0:.6e}")
        lines += list(self.notes)
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.table()


# --- a run --------------------------------------------------------------------------------------------

def _module(traj):
    """(module, parameter vector) of a trajectory's dynamics (attached on demand, as dense output)."""
    dyn = traj.dynamics
    if dyn is None or getattr(dyn, "module", None) is None:
        from ..scenes.registry import scene_info

        if scene_info(traj.system) is None and dyn is None:
            raise ValueError(f"energy account: the dynamics of system {traj.system!r} are not attached; call "
                             "tr.attach_dynamics(system) with its YAML path or MechanicalSystem")
        traj.attach_dynamics()
        dyn = traj.dynamics
    return dyn.module, dyn.prm


class _Kernels:
    """The few compiled kernels an account evaluates, called from Python with their scratch arrays."""

    def __init__(self, mod, prm):
        self.mod, self.prm = mod, np.ascontiguousarray(prm, float)
        self.n, self.m = int(mod.NDOF), int(mod.NCON)
        self._M = np.empty((self.n, self.n))
        self._G = np.empty((self.m, self.n))

    def H(self, q, p) -> float:
        return float(self.mod.hamiltonian(np.ascontiguousarray(q, float), np.ascontiguousarray(p, float), self.prm))

    def M(self, q):
        self.mod.sys_M(np.ascontiguousarray(q, float), self.prm, self._M)
        return self._M.copy()

    def G(self, q):
        self.mod.sys_dphis(np.ascontiguousarray(q, float), self.prm, self._G)
        return self._G.copy()


def _event_groups(traj):
    """[(first entry, last entry + 1)] of the impact record's events: consecutive entries with the
    same time and configuration (a simultaneous impact has one entry per contact)."""
    t = np.asarray(traj.impacts, float)
    n = traj.q.shape[1]
    Q = np.asarray(traj.impact_q, float).reshape(len(t), n)
    groups, a = [], 0
    for k in range(1, len(t) + 1):
        if k == len(t) or t[k] != t[a] or not np.array_equal(Q[k], Q[a]):
            groups.append((a, k))
            a = k
    return groups


def _law_loss(K, q, pm, pp, h, event_tol):
    """(loss, q+) of one event of a run: the energy the impact law removes from (q, p-), Newton/Moreau
    (impact_direction's dE) or the declared map (declared_reset's dE), plus the plastic projection of
    the contacts the record leaves at rest (normal velocity zeroed in p+ though the law's p+ leaves
    them moving: held by the run); q+ the configuration after (the map's, else q)."""
    mod, n, m = K.mod, K.n, K.m
    d, lam, active = np.empty(n), np.empty(m), np.empty(m, np.int64)
    q, pm = np.ascontiguousarray(q, float), np.ascontiguousarray(pm, float)
    if bool(getattr(mod, "FRICTION", False)):   # the frictional law: its dE is restitution, friction and plastic loss
        k, s0, dE = mod.friction_impact_direction(q, pm, float(h), float(event_tol), K.prm, d, lam, np.empty(m),
                                                  active)
    else:
        k, s0, dE = mod.impact_direction(q, pm, float(h), float(event_tol), K.prm, d, lam, active)
    if k > 0 and bool(getattr(mod, "RESET_MAP", False)):
        qn, pmap = np.empty(n), np.empty(n)
        dE = mod.declared_reset(q, pm, d, s0, K.prm, qn, pmap)
        return float(dE), qn
    plaw = pm + (s0 * d if k > 0 else 0.0)
    X = np.linalg.solve(K.M(q), K.G(q).T)      # columns M^-1 grad phi_i (M symmetric)
    u_law, u_pp, u_pm = X.T @ plaw, X.T @ pp, X.T @ pm   # normal velocities
    scale = max(float(np.max(np.abs(u_pm))), float(np.max(np.abs(u_law))), 1e-300)
    tol = 1e-9 * scale
    A = np.flatnonzero((np.abs(u_pp) <= tol) & (np.abs(u_law) > tol))
    loss = float(dE) if k > 0 else 0.0
    if A.size:   # 1/2 u_A^T W_AA^+ u_A: what zeroing u_A along M^-1 G_A^T removes
        W = K.G(q)[A] @ X[:, A]
        loss += 0.5 * float(u_law[A] @ np.linalg.lstsq(W, u_law[A], rcond=None)[0])
    return loss, q


def _power_integrals(traj, K):
    """(node index of each grid point, cumulative work at each node of the dense output): 3-point
    Gauss-Legendre on each piece, the state at the nodes by the dense output's Hermite pieces."""
    d = traj._dense_output()
    n = K.n
    pieces = d.pieces
    d._slopes(pieces, "right")
    d._slopes(pieces + 1, "left")
    a, b = d.times[pieces], d.times[pieces + 1]
    dt = b - a
    y0, y1 = d.right[pieces], d.left[pieces + 1]
    m0, m1 = d.FR[pieces] * dt[:, None], d.FL[pieces + 1] * dt[:, None]
    work = np.zeros(len(pieces))
    v = np.empty(n)
    out = np.empty(2 * n)
    for s, wgt in zip(_GL_X, _GL_W):
        s2, s3 = s * s, s * s * s
        Y = (2 * s3 - 3 * s2 + 1) * y0 + (s3 - 2 * s2 + s) * m0 + (-2 * s3 + 3 * s2) * y1 + (s3 - s2) * m1
        ts = a + s * dt
        P = np.empty(len(pieces))
        for j in range(len(pieces)):
            y = np.ascontiguousarray(Y[j])
            K.mod.dynamics_rhs(float(ts[j]), y, K.prm, out)
            v[:] = out[:n]
            P[j] = K.mod.force_power(y[:n], v, float(ts[j]), K.prm)
        work += wgt * dt * P
    cum = np.zeros(len(d.times))
    cum[pieces + 1] = work
    cum = np.cumsum(cum)
    return np.flatnonzero(d.is_grid), cum


def trajectory_account(traj) -> EnergyAccount:
    """The energy account of a run (`Trajectory.energy_account`)."""
    from .energy import energy_scale

    mod, prm = _module(traj)
    K = _Kernels(mod, prm)
    t = np.asarray(traj.t, float)
    H = np.array(traj.H, float)
    notes = []
    if len(t) == 0:
        raise ValueError("energy account: this trajectory holds no grid states (stored with store_trajectories: "
                         "false?)")
    missing = ~np.isfinite(H)
    if missing.any() and np.isfinite(traj.q).all():   # energies=False: H from the grid states
        for k in np.flatnonzero(missing):
            H[k] = K.H(traj.q[k], traj.p[k])
    h = float(traj.h)
    event_tol = float((traj.tolerances or {}).get("event_tol", 1e-13))
    law = np.zeros(len(t))
    events = []
    # a resting start is projected onto its surface before the loop records H(t0): the recorded
    # (q0, p0) is the start as given, H[0] the projected one
    H_given = K.H(traj.q[0], traj.p[0])
    if np.isfinite(H_given) and H_given - H[0] > 1e-14 * max(1.0, abs(H_given)):
        notes.append(f"resting start: its plastic projection removed {H_given - H[0]:.3e} before t0 "
                     "(the account starts after it)")
    n = traj.q.shape[1]
    Qi = np.asarray(traj.impact_q, float).reshape(-1, n)
    Pm = np.asarray(traj.impact_p_minus, float).reshape(-1, n)
    Pp = np.asarray(traj.impact_p_plus, float).reshape(-1, n)
    contact = np.asarray(traj.impact_contact)
    for a, b in _event_groups(traj):
        tau = float(traj.impacts[a])
        if not (t[0] <= tau <= t[-1]):
            continue   # (a failed run may record impacts of its last step)
        loss, qplus = _law_loss(K, Qi[a], Pm[a], Pp[a], h, event_tol)
        jump = K.H(Qi[a], Pm[a]) - K.H(qplus, Pp[a])
        events.append(EnergyEvent(tau, tuple(int(c) for c in contact[a:b]), loss, jump))
        law[np.searchsorted(t, tau, side="left"):] -= loss
    terms = [EnergyTerm(LAW, float(law[-1]), law, _DOC[LAW])]
    fw = getattr(traj, "friction_work", None)
    if bool(getattr(mod, "FRICTION", False)) and fw is not None and len(fw) == len(t) - 1:
        W = np.concatenate([[0.0], np.cumsum(np.asarray(fw, float))])
        terms.append(EnergyTerm(FRICTION, float(W[-1]), W, _DOC[FRICTION]))
    quad = ""
    if bool(getattr(mod, "FORCED", False)):
        grid_nodes, cum = _power_integrals(traj, K)
        W = cum[grid_nodes]
        terms.append(EnergyTerm(FORCING, float(W[-1]), W, _DOC[FORCING]))
        quad = "forcing work: 3-point Gauss-Legendre on each dense-output piece (error O(h^4))"
    try:
        scale = energy_scale(traj)
    except (ValueError, TypeError):
        scale = abs(float(H[0]))
    return EnergyAccount(t=t, H=H, terms=tuple(terms), events=tuple(events), scale=float(scale), notes=tuple(notes),
                         quadrature=quad)


# --- the exact reference ------------------------------------------------------------------------------

def reference_account(pieces, n, impacts, mod, prm, T, forced, impact_contact=None, samples=2001,
                      friction=None) -> EnergyAccount:
    """The account of an exact solve from its dense pieces [(t0, t1, dense)] (states of width 2n, plus
    the work integral as component 2n when forced): H on `samples` points and at both sides of every
    piece boundary; the law's term is the sum of H's jumps at the boundaries (impacts, and the plastic
    projections of contacts the solve holds: between boundaries the solve is the smooth flow), the
    forcing term the carried work. The rest is then the solve's own energy error.

    friction = (mode_intervals, power): the solve's [(t0, t1, held set, modes)] and power(t, y, A, S),
    the friction forces' power at a state (sum over sliding contacts of -mu lam_n |v_t|). Its integral
    is the friction-work term: 5-point Gauss-Legendre between consecutive account times inside every
    interval with a sliding contact (error far below the solve's tolerance), computed from the forces
    and slip velocities, never from H, so the rest stays a check of the solve."""
    K = _Kernels(mod, prm)
    t0 = float(pieces[0][0])

    def at(j, tt):
        return np.asarray(pieces[j][2](np.atleast_1d(np.asarray(tt, float))), float).T

    bounds = [j for j in range(len(pieces) - 1) if pieces[j + 1][0] > t0]
    grid = np.linspace(t0, float(T), samples)
    starts = np.array([p[0] for p in pieces])
    idx = np.clip(np.searchsorted(starts, grid, side="right") - 1, 0, len(pieces) - 1)
    Y = np.empty((len(grid), 2 * n + (1 if forced else 0)))
    for j in np.unique(idx):
        sel = idx == j
        Y[sel] = at(j, grid[sel])
    # the boundaries: H of the left and right states, the law's jump between them
    tb = np.array([pieces[j][1] for j in bounds], float)
    jumps = np.zeros(len(bounds))
    YL = np.empty((len(bounds), Y.shape[1]))
    YR = np.empty((len(bounds), Y.shape[1]))
    for k, j in enumerate(bounds):
        YL[k] = at(j, tb[k])[0]
        YR[k] = at(j + 1, pieces[j + 1][0])[0]
        jumps[k] = K.H(YL[k, :n], YL[k, n:2 * n]) - K.H(YR[k, :n], YR[k, n:2 * n])
    # the account's times: the grid and both sides of each boundary (left first), in time order
    tt = np.concatenate([grid, tb, tb])
    side = np.concatenate([np.full(len(grid), 2), np.zeros(len(tb)), np.ones(len(tb))])   # 0 left, 1 right, 2 grid
    YY = np.vstack([Y, YL, YR])
    order = np.lexsort((side, tt))
    tt, side, YY = tt[order], side[order], YY[order]
    H = np.array([K.H(y[:n], y[n:2 * n]) for y in YY])
    # law series: the jumps of the boundaries at or before each time (a boundary's left side: before it)
    cum = np.concatenate([[0.0], np.cumsum(jumps)])
    passed = np.searchsorted(tb, tt, side="right") - (side == 0)
    passed = np.clip(passed, 0, len(tb))
    law = -cum[passed]
    terms = [EnergyTerm(LAW, float(law[-1]), law, _DOC[LAW])]
    if friction is not None:
        W = _friction_work(friction, pieces, tt, at)
        terms.append(EnergyTerm(FRICTION, float(W[-1]), W, _DOC_REFERENCE_FRICTION))
    if forced:
        W = YY[:, 2 * n]
        terms.append(EnergyTerm(FORCING, float(W[-1]), W - W[0], _DOC[FORCING]))
    imp = np.asarray(impacts, float)
    con = np.zeros(len(imp), np.int64) if impact_contact is None else np.asarray(impact_contact)
    events = []
    for tau in np.unique(imp):
        k = np.flatnonzero(np.abs(tb - tau) <= 4 * np.finfo(float).eps * max(1.0, abs(tau)))
        loss = float(jumps[k].sum()) if k.size else 0.0
        events.append(EnergyEvent(float(tau), tuple(int(c) for c in con[imp == tau]), loss, loss))
    scale = abs(float(H[0]))
    if len(YY):
        for y in YY[:: max(1, len(YY) // 500)]:
            M = K.M(y[:n])
            scale = max(scale, 0.5 * float(y[n:2 * n] @ np.linalg.solve(M, y[n:2 * n])))
    return EnergyAccount(t=tt, H=H, terms=tuple(terms), events=tuple(events), scale=scale)


_DOC_REFERENCE_FRICTION = "work of the held contacts' friction forces (sliding), integrated along the exact solve"
_GAUSS5 = np.polynomial.legendre.leggauss(5)


def _friction_work(friction, pieces, tt, at) -> np.ndarray:
    """The friction work from the first account time to each of `tt` (sorted): the power integrated
    between consecutive account times inside each interval with a sliding contact."""
    intervals, power = friction
    starts = np.array([p[0] for p in pieces])
    x, w = _GAUSS5
    inc = np.zeros(len(tt))
    for t0, t1, A, S in intervals:
        if t1 <= t0 or not any(s in (1, -1) for s in S):
            continue
        cuts = np.unique(np.concatenate([[t0, t1], tt[(tt > t0) & (tt < t1)]]))
        for a, b in zip(cuts[:-1], cuts[1:]):
            nodes = 0.5 * (a + b) + 0.5 * (b - a) * x
            j = int(np.clip(np.searchsorted(starts, 0.5 * (a + b), side="right") - 1, 0, len(pieces) - 1))
            Y = at(j, nodes)
            val = 0.5 * (b - a) * float(sum(wk * power(tk, y, A, S) for wk, tk, y in zip(w, nodes, Y)))
            inc[np.searchsorted(tt, b, side="left")] += val   # reached at b (and after)
    return np.cumsum(inc)
