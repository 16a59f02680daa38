"""The event loop of the exact reference, shared by its Taylor and DOP853 paths.

Between events a backend integrates one segment (vcirun.reference_solution.flight: `segment(t0, y0, T, A, R)`);
here each event is resolved the way the integrators resolve it:

- an impact: the impact law of the integrators (collision/impact.py `impact_direction`: Newton's law
  for one contact, Moreau's LCP over every contact touching within SIMULTANEOUS seconds, held ones
  included with u- = 0), one impact entry per contact with a positive impulse that is not held;
  then the held set at the new state (vcirun.reference_solution.held.held_set: the contacts left on their
  surface at rest whose contact force is compressive, a plastic impact among them);
- accumulation: a contact whose impacts accumulate (its flights shrink below ZENO_FLIGHT, at the ratio
  e for a single contact, at a steady ratio when several contacts exchange impulses, or its next
  flight is already shorter) is held from the extrapolated Zeno time on, together with every contact
  accumulating with it; from its last impact to that time the motion follows the held dynamics of all
  of them (the plastic limit of the remaining bounces, whose heights are below |a| ZENO_FLIGHT^2 / 8);
- a release (a held contact's force turns tensile), a resting contact pushed in (it is held), a
  resting contact that lifts off (watched as a free contact from then on);
- with Coulomb friction (vcirun.reference_solution.coulomb): each held contact has a mode (sliding either way,
  sticking); a sliding contact whose slip velocity reaches 0 sticks if the stick test holds, else its
  slip reverses; a sticking contact whose tangential force reaches the static cone slides; impacts
  take the frictional impact law (normal and tangential impulses); a held problem with sliding
  contacts that has no solution or several (Painleve, B <= 0) ends the solve with the status
  "painleve" and a message naming the contact, the time and B.

Progress is guarded: an event that leaves the state, the time and the held set as the previous one
left them, twice in a row, or more than `max_events` events, end in a RuntimeError that names the
time and the contacts (never a hang). The backend's Budget bounds the integration work.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import coulomb as rf
from . import held as rh
from .flight import Constant, Flight

__all__ = ["SIMULTANEOUS", "MAX_IMPACTS", "MAX_EVENTS", "Solution", "solve", "NoProgressError"]

SIMULTANEOUS = 1e-10   # contacts whose roots lie within this many seconds impact together (LCP)
MAX_IMPACTS = 10_000   # without resting contact: accumulation shows as this many impacts
MAX_EVENTS = 200_000   # every event (impacts, releases, holds, lift-offs) of one solve
ROUNDOFF_IMPULSE = 64 * float(np.finfo(float).eps)   # relative to the largest impulse of an impact
_EPS = float(np.finfo(float).eps)


class NoProgressError(RuntimeError):
    """The event loop stopped making progress (the same state and time after two events in a row)."""


@dataclass
class Solution:
    """The exact solve: dense pieces [(t0, t1, dense)], impacts [(t, contact, impulse)] (one entry per
    contact), releases [(t, contact)], held intervals [(t0, t1, held set)]; with friction also the
    tangential impulse of each impact entry (`tangential`), the mode changes [(t, contact, mode after)]
    (`transitions`, vcirun.reference_solution.coulomb's mode codes), the held intervals with their modes
    [(t0, t1, held set, modes)] (`mode_intervals`); status "ok" or "painleve" (message: why)."""

    pieces: list = field(default_factory=list)
    impacts: list = field(default_factory=list)
    releases: list = field(default_factory=list)
    intervals: list = field(default_factory=list)
    after: tuple | None = None   # (t, state after the impact) where a solve with stop_after ended
    tangential: list = field(default_factory=list)
    transitions: list = field(default_factory=list)
    mode_intervals: list = field(default_factory=list)
    status: str = "ok"
    message: str = ""
    t_end: float | None = None   # where a solve that ended early (status "painleve") stopped

    def add(self, fl: Flight, A, merge=False, S=None) -> None:
        """Record a segment; merge: it continues the previous held interval (a restart without event)."""
        if fl.t1 > fl.t0 or not self.pieces:
            self.pieces.append((fl.t0, fl.t1, fl.piece))
        if A and fl.t1 > fl.t0:
            if merge and self.intervals and self.intervals[-1][2] == tuple(A) and self.intervals[-1][1] == fl.t0:
                self.intervals[-1] = (self.intervals[-1][0], fl.t1, tuple(A))
            else:
                self.intervals.append((fl.t0, fl.t1, tuple(A)))
            if S is not None:
                last = self.mode_intervals[-1] if self.mode_intervals else None
                if last is not None and last[1] == fl.t0 and last[2:] == (tuple(A), tuple(S)):
                    self.mode_intervals[-1] = (last[0], fl.t1, tuple(A), tuple(S))
                else:
                    self.mode_intervals.append((fl.t0, fl.t1, tuple(A), tuple(S)))


class _Progress:
    """Counts events and refuses a loop that repeats itself."""

    def __init__(self, names, max_events):
        self.names, self.max_events = names, max_events
        self.events, self.repeats, self.last = 0, 0, None

    def what(self, contacts) -> str:
        return ", ".join(self.names[i] for i in contacts) if contacts else "none"

    def after(self, t, y, A, reason, contact, S=None) -> None:
        """Called with the state the next segment starts from, after each event (A with its modes S)."""
        held = tuple(A)
        A = held if S is None else (held, tuple(S))
        self.events += 1
        if self.events > self.max_events:
            raise NoProgressError(f"reference: more than {self.max_events:,} events by t={t:.17g} (the last: "
                                  f"{reason} of contact {self.what([contact])}, held: {self.what(held)})")
        if self.last is not None:
            t0, y0, A0 = self.last
            if (A0 == A and abs(t - t0) <= 4 * _EPS * max(1.0, abs(t))
                    and float(np.max(np.abs(y - y0))) <= 64 * _EPS * (1.0 + float(np.max(np.abs(y))))):
                self.repeats += 1
                if self.repeats >= 2:
                    raise NoProgressError(
                        f"reference: no progress at t={t:.17g}: the {reason} of contact {self.what([contact])} "
                        f"repeats without a change of state (held: {self.what(held)})")
            else:
                self.repeats = 0
        self.last = (t, np.array(y, float), A)


def _on_surface(mod, t, y, prm, contacts):
    """y with its positions moved onto phi_i = 0 for the impacting contacts whose phi_i is round-off
    (the event's root leaves |phi_i| ~ eps (|q| + |t| |v|) of either sign): the rebound then starts on
    the surface, and a small rebound u+ does not turn that round-off into a flight-time error
    |phi_i| / u+ (ill-conditioned as e u- -> 0)."""
    n = int(mod.NDOF)
    g = rh._Geometry(mod, t, y[:n], y[n:2 * n], prm)
    qn, vn = max(map(abs, g.q.tolist()), default=0.0), max(map(abs, g.v.tolist()), default=0.0)
    phis, G = g.phis.tolist(), g.G.tolist()
    on = []
    for j in contacts:
        gn = max(map(abs, G[j]), default=0.0)
        if 0.0 < abs(phis[j]) <= 1e3 * _EPS * (1.0 + qn * gn + abs(t) * gn * vn):
            on.append(int(j))
    if not on:
        return y
    out = np.array(y, float)
    X = np.linalg.solve(g.M, g.G[on].T)   # one Newton step along M^-1 G^T: phi is round-off already
    out[:n] = g.q - X @ np.linalg.solve(g.G[on] @ X, g.phis[on])
    return out


def _geometry(mod, t, y, prm):
    n = int(mod.NDOF)
    return rh._Geometry(mod, t, y[:n], y[n:2 * n], prm)


def _immediate(g, t, y, A, R, tol=rh.HELD_TOL, S=None):
    """An event at the segment's start: a touching contact moving in (an impact now) or a resting
    contact pushed in; None if neither. g: the _Geometry at y; tol: the backend's rest tolerance."""
    u, phis, G = g.u.tolist(), g.phis.tolist(), g.G.tolist()   # (plain floats: the arrays are tiny)
    qn, vn = max(map(abs, g.q.tolist()), default=0.0), max(map(abs, g.v.tolist()), default=0.0)
    for i in range(g.m):
        if i in A or i in R:
            continue
        gn = max(map(abs, G[i]), default=0.0)
        if phis[i] <= 64 * _EPS * (1.0 + qn * gn) and u[i] < -tol * gn * (1.0 + vn):
            return Flight(t, t, np.array(y, float), "impact", i, Constant(y))
    if R:
        acc = g.held_acc(tuple(A), S)
        level = rh.press_level(g, tol)
        for i in R:
            if acc[i] < -level:
                return Flight(t, t, np.array(y, float), "pressed", i, Constant(y))
    return None


def _group(times_of, e_of, hit, t, geo, A, S=None, mu_of=None):
    """(contacts whose impacts accumulate at this impact, their Zeno time): those just hit whose own
    flights shrink below ZENO_FLIGHT at the ratio e (rh.accumulating) or, with several contacts, at a
    steady ratio below 1, or whose next flight, 2 u+ / |a| (u+ its normal velocity after the impact, a
    its normal acceleration on the held flow of A, pulling it back), is already shorter than
    ZENO_FLIGHT -- a rebound too small to resolve, whose bounces end by t + 2 u+ / (|a| (1 - e)) for a
    constant a; and every other contact accumulating with them (last impact within a few flights).
    The Zeno time labels the held interval; the motion from this impact on is the held one either way.
    An elastic contact (e >= 1) accumulates only with friction (mu_of[i] > 0), whose impulses take energy
    at every rebound; its Zeno time is then labelled by the next landing."""
    acc, t_inf = set(), t
    a = geo.held_acc(tuple(A), S) if hit else None

    def dissipates(i):
        return e_of[i] < 1.0 or (mu_of is not None and mu_of[i] > 0.0)

    for i in hit:
        if not dissipates(i):
            continue
        if rh.accumulating(times_of[i], e=e_of[i]) or _steady(times_of[i]):
            acc.add(i)
            t_inf = max(t_inf, rh.zeno_extrapolation(times_of[i]))
        elif a[i] < 0.0 and 2.0 * max(float(geo.u[i]), 0.0) < rh.ZENO_FLIGHT * -a[i]:
            acc.add(i)
            t_inf = max(t_inf, t + 2.0 * max(float(geo.u[i]), 0.0) / (-a[i] * (1.0 - e_of[i] if e_of[i] < 1.0
                                                                               else 1.0)))
    if not acc:
        return set(), t
    for j in range(len(times_of)):
        if j not in acc and times_of[j] and t - times_of[j][-1] <= 8 * rh.ZENO_FLIGHT and dissipates(j) \
                and (rh.accumulating(times_of[j]) or _steady(times_of[j])):
            acc.add(j)
            t_inf = max(t_inf, rh.zeno_extrapolation(times_of[j]))
    return acc, t_inf


def _too_many(sol, times_of, e_of, names, max_impacts, t, resting_contact) -> str:
    """The error of a solve past max_impacts: the busiest contact, its restitution and its last flight."""
    j = max(range(len(times_of)), key=lambda c: len(times_of[c]))
    ts = times_of[j]
    flight = f", the last {ts[-1] - ts[-2]:.2g} s apart" if len(ts) > 1 else ""
    if e_of[j] >= 1.0:
        why = "elastic impacts do not accumulate: lower T"
    elif resting_contact:
        why = "impacts accumulating without a steady ratio: lower T"
    else:
        why = "accumulating impacts? resting_contact=True holds such contacts"
    return (f"reference: more than {max_impacts:,} impacts by t={t:.6g} ({len(ts):,} of contact {names[j]}, "
            f"e = {e_of[j]:g}{flight}); {why}")


def _steady(times) -> bool:
    """Flights shrinking geometrically at a steady ratio r <= 0.999: the last below ZENO_FLIGHT, the
    last two ratios within 1 % of each other."""
    if len(times) < 5:
        return False
    d = np.diff(np.asarray(times[-4:], float))
    if not (np.all(d > 0.0) and d[-1] < rh.ZENO_FLIGHT and d[2] < d[1] < d[0]):
        return False
    r1, r2 = d[1] / d[0], d[2] / d[1]
    return r2 <= 0.999 and abs(r2 - r1) <= 1e-2 * r2


_LAW_COMPILED: set = set()   # system modules whose impact law this process has called


def solve(backend, mod, q0, p0, prm, T, *, names, resting_contact=True, max_impacts=MAX_IMPACTS,
          max_events=MAX_EVENTS, resets=None, stop_after=None) -> Solution:
    """The exact nonsmooth solution on [0, T] from (q0, p0) on `backend`'s segments (see the module).
    resets: the system's DeclaredResets (vcirun.reference_solution.resets; None: Newton's law alone);
    stop_after = (contact, k): end at the k-th impact of that contact, its state after the impact law
    (and the declared map) in sol.after."""
    n, m = int(mod.NDOF), int(mod.NCON)
    forced = bool(mod.FORCED)
    y = np.concatenate([np.asarray(q0, float), np.asarray(p0, float)] + ([[0.0]] if forced else []))
    e_of = np.empty(m)
    mod.sys_restitution(prm, e_of)
    d, lam, active = np.empty(n), np.empty(m), np.empty(m, dtype=np.int64)
    if mod.__name__ not in _LAW_COMPILED:
        # compile (or load) the impact law now, not at the first impact: a sweep's preflight, whose
        # short reference meets none, then leaves it in the kernel cache for every worker
        mod.impact_direction(y[:n].copy(), y[n:2 * n].copy(), 1.0, SIMULTANEOUS / 4, prm, d, lam, active)
        _LAW_COMPILED.add(mod.__name__)
    fric = rf.coefficients(mod, prm)   # None: no friction at these parameters (S stays None)
    if fric is not None and resets is not None and resets.mapped:
        raise ValueError("reference: friction together with a declared reset map is not supported (the map "
                         "replaces the impact law, the frictional law would be skipped)")
    sol = Solution()
    times_of = [[] for _ in range(m)]
    progress = _Progress(names, max_events)
    t, stop = 0.0, float(T)   # stop < T: a Zeno settle phase, held on its set until the Zeno time
    tol = float(getattr(backend, "rest_tol", rh.HELD_TOL))   # on the surface at rest: the path's precision

    def hold(t, y, candidates, geo=None):
        """(held set, modes) at (t, y) among the candidates (None: all)."""
        if fric is None:
            q, p = (None, None) if geo is not None else (y[:n], y[n:2 * n])
            return rh.held_set(mod, t, q, p, prm, candidates, tol, geo=geo), None
        g = geo if geo is not None else _geometry(mod, t, y, prm)
        return rf.held_set(mod, t, None, None, prm, candidates, tol, geo=g, names=names)

    try:
        A, S = hold(t, y, None) if resting_contact else ((), None if fric is None else ())
        if A:
            y = rh._project_y(mod, y, prm, A, S)
        geo = None   # the _Geometry at (t, y), when an event's handling computed it
        restart = False
        while True:
            geo = geo or _geometry(mod, t, y, prm)
            R = tuple(i for i in rh.at_rest(mod, t, None, None, prm, tol, geo=geo) if i not in A)
            fl = _immediate(geo, t, y, A, R, tol, S) if t < stop else None
            if fl is None:
                if t < stop:
                    fl = backend.segment(t, y, stop, A, R, geo=geo, **({} if S is None else {"S": S}))
                else:
                    fl = Flight(t, t, y, "end", -1, Constant(y))
            geo = None
            sol.add(fl, A, merge=restart, S=S)
            restart = fl.reason in ("lift", "drift")
            t, y = fl.t1, np.array(fl.y1, float)
            i = fl.contact
            if fl.reason == "end":
                if stop >= T:
                    break
                stop = float(T)       # the Zeno time: hold what is at rest and pressed
                A, S = hold(t, y, None)
            elif fl.reason in ("lift", "drift"):
                pass
            elif fl.reason == "release":
                sol.releases.append((t, i))
                y = rh._project_y(mod, y, prm, A, S)   # (the released contact too: it leaves from rest)
                A, S = hold(t, y, [j for j in A if j != i])
            elif fl.reason in ("stick", "slip"):
                S0 = S
                A, S = _mode_change(mod, t, y, prm, A, S, i, fl.reason, names)
                if S != S0:
                    sol.transitions.append((t, i, S[A.index(i)]))
            elif fl.reason == "painleve":
                g = _geometry(mod, t, y, prm)
                rf.check_painleve(g, A, S, names)   # (raises; B at the located root is 0 to round-off)
                j = next(j for j, s in zip(A, S) if s in (1, -1))
                raise rf.PainleveError(j, names[j], t, rf.response(g.forces(A, S).K, S))
            elif fl.reason == "pressed":
                geo = _geometry(mod, t, y, prm)
                if not geo.near([i], tol):
                    pass   # it had left its surface before its acceleration turned: a free contact now
                elif not resting_contact:
                    raise RuntimeError(f"reference: a touching contact ({names[i]}) is pushed into its constraint at "
                                       f"t={t:.6g} (resting contact; resting_contact=True holds it)")
                else:
                    y = rh._project_y(mod, y, prm, sorted(set(A) | {i}))   # it rests on its surface
                    A, S = hold(t, y, sorted(set(A) | {i}))
                    geo = None
            elif fl.reason == "impact":
                if A:   # the held contacts take part in the impact law (touching, u- = 0): on their surface,
                    y = rh._project_y(mod, y, prm, A, S)   # not off it by the held phase's drift
                k, s0, _ = mod.impact_direction(y[:n].copy(), y[n:2 * n].copy(), 1.0, SIMULTANEOUS / 4, prm, d, lam,
                                                active)
                if k < 0:
                    raise RuntimeError(f"reference: the impact law has no solution at t={t:.6g} (case {k}; contact "
                                       f"{names[i]})")
                hit = []
                if resets is not None:
                    resets.check_impact(t, y, i)
                if k > 0:
                    y = _on_surface(mod, t, y, prm, [j for j in np.flatnonzero(active) if j not in A])
                    touching = [int(j) for j in np.flatnonzero(active)]
                    lam_t = None
                    if fric is not None and any(fric[0][j] > 0.0 for j in touching):
                        # the frictional impact law on the same touching contacts
                        g_imp = rh._Geometry(mod, t, y[:n], y[n:2 * n], prm)
                        case, lam_n, lam_t, dp = rf.impact(g_imp, touching, e_of)
                        if case < 0:
                            raise RuntimeError(f"reference: the frictional impact law has no solution at t={t:.6g} "
                                               f"(case {case}; contact {names[i]})")
                        lam[:] = lam_n
                        s0 = lam_n[i] if m == 1 else 1.0
                        y[n:2 * n] += dp
                    elif resets is not None and resets.mapped and not A:
                        y = resets.apply(t, y, d, s0, i)   # the declared map (the impact law first if declared)
                        s0 = s0 if mod.RESET_LAW_FIRST else 0.0   # the recorded impulse: the impact law's
                    else:
                        y[n:2 * n] += s0 * d
                    # an impulse at the round-off of the others (a touching contact with u- ~ eps beside
                    # one that hits: the side wall a plastic impact left the ball on) is no impact
                    floor = ROUNDOFF_IMPULSE * max(float(np.max(lam)), 0.0) if m > 1 else 0.0
                    for j in np.flatnonzero(active):
                        j = int(j)
                        if (m == 1 or lam[j] > floor) and j not in A:
                            sol.impacts.append((t, j, float(s0 if m == 1 else lam[j])))
                            sol.tangential.append(0.0 if lam_t is None else float(lam_t[j]))
                            times_of[j].append(t)
                            hit.append(j)
                    if len(sol.impacts) > max_impacts:
                        raise RuntimeError(_too_many(sol, times_of, e_of, names, max_impacts, t, resting_contact))
                    if stop_after is not None and len(times_of[stop_after[0]]) >= stop_after[1] \
                            and stop_after[0] in hit:
                        sol.after = (t, np.array(y, float))
                        break
                if resting_contact:
                    geo = _geometry(mod, t, y, prm)
                    A, S = hold(t, y, None, geo=geo)
                    acc, t_inf = (_group(times_of, e_of, hit, t, geo, A, S, None if fric is None else fric[0])
                                  if hit else (set(), t))
                    if acc:   # held from here (a Zeno time past T: to T, within the bounce heights left)
                        A, stop = tuple(sorted(set(A) | acc)), min(max(t_inf, t), float(T))
                        if S is not None:
                            S = _modes_for(geo, A, tol)
                elif k == 0:
                    acc0 = rh.free_normal_accelerations(mod, t, y[:n], y[n:2 * n], prm)
                    if acc0[i] < 0.0:
                        raise RuntimeError(f"reference: grazing contact {names[i]} at t={t:.6g} (zero normal velocity; "
                                           "resting_contact=True holds a contact pressed in)")
            else:
                raise ValueError(f"reason: {fl.reason!r} is not an event of the exact solve")
            if A:
                y = rh._project_y(mod, y, prm, A, S)
                geo = None
            progress.after(t, y, A, fl.reason, i, S)
    except rf.PainleveError as e:
        sol.status, sol.message, sol.t_end = "painleve", str(e), e.t
        if not sol.pieces:   # (at the start: the solution is the start state alone)
            sol.pieces.append((t, t, Constant(y)))
    return sol


def _turning_back(g, A, S, a) -> bool:
    """Whether held contact A[a], sliding with sign s, has no slip acceleration against s at the state
    of g (s d(v_t)/dt >= 0 to round-off of its terms): its slip velocity crossed 0 by round-off only (a
    slip that starts from rest with a zero acceleration, as at the static cone with mu_s = mu), not at
    the end of a slip, which decelerates through 0."""
    i, s = A[a], S[a]
    pdot = g.forces(A, S).pdot
    acc = g.Wt[i] @ np.linalg.solve(g.M, pdot - g.Mdv) + g.dslip[i]
    terms = np.abs(g.Wt[i]) @ np.abs(np.linalg.solve(g.M, np.abs(g.F) + np.abs(pdot - g.F) + np.abs(g.Mdv)))
    return s * acc >= -1e3 * _EPS * (terms + abs(g.dslip[i]))


def _modes_for(g, A, tol):
    """The modes of the held set A at the state of g (the accumulation hold adds contacts to A)."""
    return rf.settle(g, tuple(A), rf.contact_modes(g, tuple(A), tol))


def _mode_change(mod, t, y, prm, A, S, i, reason, names):
    """(A, S) after a stick or slip event of held contact i at (t, y): a sliding contact that came to
    rest sticks if the stick test holds (the modes with it sticking, vcirun.reference_solution.coulomb.settle),
    else its slip reverses; a sticking contact at the static cone slides against its force."""
    g = _geometry(mod, t, y, prm)
    a = A.index(i)
    if reason == "stick" and _turning_back(g, A, S, a):
        return A, S   # a crossing by round-off at a slip's start: the slip goes on the same way
    S = list(S)
    if reason == "stick":
        S[a] = rf.STICK
        S = list(rf.settle(g, A, tuple(S)))   # (a failed stick test makes it slide the other way)
    else:
        f = g.forces(A, tuple(S))
        S[a] = -1 if f.lam_t[a] > 0.0 else 1
    S = tuple(S)
    rf.check_painleve(g, A, S, names)
    return A, S
