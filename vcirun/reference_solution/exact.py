"""The continuous nonsmooth solution to high accuracy, for error measurement.

Exact reference: Hamilton's equations with the generalized force, qdot = M^-1 p,
pdot = -dH/dq + f(q, qdot, t), one event per contact (phi_i(q) = 0, entering), the impact law of the
integrators at each event (Newton's law per contact, Moreau's LCP for simultaneous contacts:
collision/impact.py), restarted after each impact; dense output on any grid. The event loop
(vcirun.reference_solution.loop) is shared by two integration paths:

- Taylor (ref.kind "taylor", vcirun.reference_solution.taylor): heyoka at machine precision; every root of
  every phi_i inside a step is isolated from its Taylor polynomial, so no event is stepped over;
- DOP853 (ref.kind "dop853", vcirun.reference_solution.dop853) for a system the Taylor path cannot express
  (ref.kind_reason says why): per-contact sign and minimum checks on the dense output of every step,
  steps bounded by the flight's own scales, at rtol.

ref.accuracy is the largest difference (q on a 2001-point grid, impact and release times) from a check
solve: Taylor at a looser tolerance (another order and step sequence: an upper estimate), DOP853 at a
10x tighter rtol (at least scipy's floor of ~2.2e-14). A check that sees another event sequence whose
trajectory q differs by more than SUB_RESOLUTION (relative) is refined (DOP853: tighter, denser,
shorter steps; Taylor: a second check tolerance) and, if it still differs, is an error: a returned
reference has a finite accuracy. A forced system also carries the work
W(t) = int_0^t f . qdot as an extra state. `energy_account()` splits H(t) - H(0) into the impact
law's losses (the jumps of H at the events), the work W and the rest; `energy_balance` = max |rest| on
a dense grid and at every event: a check of the solve that does not rest on a second solve of the
same equations.

Held contacts (resting_contact=True): a contact that starts at rest on its surface, is left at rest by
a plastic impact, or whose impacts accumulate (the Zeno time extrapolated from its flights; several
contacts accumulating together are held together) is held on the index-reduced constrained dynamics
(vcirun/reference_solution/held.py) and released where its contact force turns tensile; docs/derivations/contacts.md 6.

Coulomb friction (vcirun.reference_solution.coulomb): held contacts slide or stick, every mode change a
located event (ref.transitions), impacts take the frictional impact law (ref.impact_tangential); a
held problem with sliding contacts that has no solution or several (Painleve's paradox) ends the
reference there with ref.status "painleve" and ref.message naming the contact, the time and B.

Declared resets and guards (vcirun.mechanics.hybrid): the declared map at each impact of its
constraint, guards honoured on both paths, the state after the map checked admissible
(vcirun.reference_solution.resets); the exact return map on a section: vcirun.reference_solution.stride.

Also: a fine-step method reference (the paper's choice: CVA at a small h). Closed forms (the
oscillator against a wall, the bouncing ball, the ball in a box ...) are in vcirun.scenes.oracles.
"""
from __future__ import annotations

import functools

import numpy as np

from ..codegen.build import load_module
from ..codegen.kernel_set import SYSTEM_KERNELS
from ..core.system_data import start_tolerance
from . import held as rh
from .dop853 import Dop853Backend
from .flight import Budget, Constant, ReferenceCostError
from .loop import solve
from .resets import declared_resets
from .taylor import TOL, NotExpressible, TaylorBackend, TaylorFailure, TaylorPiece, order_of, taylor_model

CHECK_TOLS = (1e-14, 1e-15)   # the Taylor path's check solves (the second when the first sees other events)
# Two solves whose event sequences part where it hardly shows in q -- a bounce more or less before a
# Zeno hold, the order of the chatter of several contacts settling together (a rocking block landing:
# impulses of 1e-5 .. 1e-3 microseconds apart, measured q differences 1e-13 .. 2e-7) -- agree to this,
# relative: the check accepts them and reports their difference as the accuracy. A missed impact shows
# as an O(1) difference in q and is refused.
SUB_RESOLUTION = 1e-6
RTOL_FLOOR = 2.3e-14          # scipy's DOP853 refuses a tighter rtol
_EPS = float(np.finfo(float).eps)


class Reference:
    """Callable reference solution on [t_start, T]: ref(t) -> q, shape (n,) for a scalar t and
    (len(t), n) for an array; ref.p(t), ref.state(t) likewise; ref.impacts; ref.accuracy.
    Right-continuous at impacts (the post-impact momentum at t = tau). A time outside [t_start, T]
    raises ValueError (no extrapolation)."""

    def __init__(self, segments, n, impacts, H0, T, accuracy=np.nan, kind="taylor", width=None, impact_contact=None,
                 impact_impulse=None):
        self.segments = segments  # list of (t_start, t_end, dense output called like an OdeSolution)
        self.n = n
        # one entry per contact impact, as Trajectory's (simultaneous impacts: one entry each)
        self.impacts = np.asarray(impacts, float)
        self.impact_contact = (np.zeros(len(self.impacts), np.int64) if impact_contact is None
                               else np.asarray(impact_contact, np.int64))
        self.impact_impulse = (np.full(len(self.impacts), np.nan) if impact_impulse is None
                               else np.asarray(impact_impulse, float))
        self.H0 = H0
        self.T = T
        self.accuracy = accuracy
        self.kind = kind          # "taylor", "dop853" or "<method>@h=<h>"
        self.kind_reason = ""     # dop853: why the Taylor path could not express the system
        # exact solves: the energy account (vcirun.run.accounts), computed when first asked for
        # (`energy_account`, `energy_balance`: 2001 energies, ~30 ms, which a sweep's references never
        # read); _account_of makes it, None for a method reference
        self._account = None
        self._account_of = None
        # held contacts: release times and contacts, held phases (t0, t1, held set)
        self.releases = np.zeros(0)
        self.release_contact = np.zeros(0, np.int64)
        self.held_intervals = []
        # friction: the tangential impulse of each impact entry, the mode changes of held contacts
        # [(t, contact, mode after)] and the held intervals with their modes [(t0, t1, held, modes)]
        # (mode codes: vcirun.reference_solution.coulomb, +1 / -1 sliding, 0 sticking, 2 smooth)
        self.impact_tangential = np.zeros(len(self.impacts))
        self.transitions = []
        self.mode_intervals = []
        self.status = "ok"        # "painleve": the solve ended at T (< the T asked for) on Painleve's paradox
        self.message = ""
        self._width = 2 * n if width is None else width

    def __repr__(self) -> str:
        acc = "" if not np.isfinite(self.accuracy) else f", accuracy={self.accuracy:.1e}"
        return (f"Reference(kind={self.kind!r}, n={self.n}, t=[{self.segments[0][0]:g}, {self.T:g}], "
                f"impacts={len(self.impacts)}, H0={self.H0:.6g}{acc})")

    def state(self, t) -> np.ndarray:
        scalar = np.ndim(t) == 0
        t = np.atleast_1d(np.asarray(t, float)).ravel()
        t_start = self.segments[0][0]
        tol = 1e-12 * max(1.0, abs(self.T))  # grids end at N h, which may exceed T by round-off
        bad = ~((t >= t_start - tol) & (t <= self.T + tol))
        if bad.any():
            raise ValueError(f"t: {t[bad][0]:.17g} is outside the reference's interval [{t_start:g}, T = {self.T:g}]; "
                             "compute the reference with a larger T")
        out = np.empty((t.size, self._width))
        starts = np.array([s[0] for s in self.segments])
        idx = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(self.segments) - 1)
        for j in np.unique(idx):
            m = idx == j
            out[m] = self.segments[j][2](t[m]).T
        return out[0] if scalar else out

    def __call__(self, t) -> np.ndarray:
        return self.state(t)[..., : self.n]

    def __getstate__(self):
        # the account's maker holds the kernel module, which does not pickle: a copy carries the account
        if self._account_of is not None:
            self.energy_account()
        return dict(self.__dict__)

    @property
    def energy_balance(self) -> float:
        """Exact solves: the largest rest of the energy account, |H(t) - H(0) - int f . qdot + the impact
        law's losses so far| (the solve's own energy error); NaN for a method reference."""
        return np.nan if self._account is None and self._account_of is None else self.energy_account().error

    def energy_account(self):
        """H(t) - H(0) split into the impact law's losses (restitution, plastic holds, declared maps:
        the jumps of H at the solve's events), the forcing work and the rest, the solve's own energy
        error (`energy_balance` is its largest magnitude); a vcirun.run.accounts.EnergyAccount. Exact
        solves only (a method reference: the run's `energy_account`)."""
        if self._account is None and self._account_of is not None:
            self._account = self._account_of()
            self._account_of = None
        if self._account is None:
            raise ValueError(f"energy account: a {self.kind} reference has none (exact solves only)")
        return self._account

    def p(self, t) -> np.ndarray:
        return self.state(t)[..., self.n:]


# The exact solve's work budgets. DOP853: 500 to 1,300 right-hand-side evaluations per unit of time at
# rtol 1e-13 (~15 us each), so 5e7 is ten minutes or more. Taylor: one step is ~10 us and keeps its
# polynomial (width x (order + 1) numbers) for the dense output, so the bound is the memory of the
# polynomials, ~1 GB. An initial state so large that the steps collapse (beta = 1e20: velocities ~1e19)
# or a T far beyond it would otherwise run for hours; the projection to T is checked once MIN units are
# spent (a few seconds).
MAX_RHS_EVALS = 5e7
MIN_RHS_EVALS_FOR_PROJECTION = 200_000
TAYLOR_MEMORY_BYTES = 1e9
MIN_TAYLOR_STEPS_FOR_PROJECTION = 20_000


def _taylor_budget(model, T, q0, p0):
    width = 2 * model.n + (1 if model.forced else 0)
    limit = TAYLOR_MEMORY_BYTES / (8.0 * width * (order_of(TOL) + 1))
    return Budget(T, q0, p0, limit, min(MIN_TAYLOR_STEPS_FOR_PROJECTION, limit), "Taylor steps")


def _dop_budget(T, q0, p0):
    return Budget(T, q0, p0, MAX_RHS_EVALS, MIN_RHS_EVALS_FOR_PROJECTION, "right-hand-side evaluations")


def _names(system):
    return [c.name for c in system.constraints]


def _solve_taylor(sysm, mod, model, q0, p0, prm, T, tol, resting_contact, stop_after=None):
    backend = TaylorBackend(model, mod, prm, tol=tol, budget=_taylor_budget(model, T, q0, p0))
    return solve(backend, mod, q0, p0, prm, T, names=_names(sysm), resting_contact=resting_contact,
                 resets=backend.resets, stop_after=stop_after)


def _solve_dop853(sysm, mod, q0, p0, prm, T, rtol, resting_contact, samples=8, reach=2.0, stop_after=None):
    atol = rtol * max(1.0, float(np.max(np.abs(np.concatenate([q0, p0])))))
    backend = Dop853Backend(mod, prm, rtol, atol, budget=_dop_budget(T, q0, p0), samples=samples, reach=reach)
    backend.resets = declared_resets(sysm, mod, prm)
    return solve(backend, mod, q0, p0, prm, T, names=_names(sysm), resting_contact=resting_contact,
                 resets=backend.resets, stop_after=stop_after)


def _sequence(sol):
    return ([i for _, i, _ in sol.impacts], [i for _, i in sol.releases], [(i, s) for _, i, s in sol.transitions],
            sol.status)


def _first_difference(a, b, names) -> str:
    """Where the event sequences of two solves part (for the error message)."""
    names = _Names(enumerate(map(str, names)))
    ev_a = sorted([(t, "impact", i) for t, i, _ in a.impacts] + [(t, "release", i) for t, i in a.releases])
    ev_b = sorted([(t, "impact", i) for t, i, _ in b.impacts] + [(t, "release", i) for t, i in b.releases])
    for x, y in zip(ev_a, ev_b):
        if x[1:] != y[1:]:
            return (f"at t={min(x[0], y[0]):.12g}: {x[1]} of {names[x[2]]} against {y[1]} of {names[y[2]]}")
    k = min(len(ev_a), len(ev_b))
    rest = ev_a[k:] or ev_b[k:]
    return f"at t={rest[0][0]:.12g}: {len(ev_a)} events against {len(ev_b)}" if rest else "in the held phases"


class _Names(dict):
    """Contact names by index ("contact i" for an index the system does not have)."""

    def __missing__(self, i):
        return f"contact {i}"


def _taylor_steps(sol):
    """(step start times, Taylor coefficients) of a solve made of Taylor pieces, else None."""
    pieces = [p for _, _, p in sol.pieces if not isinstance(p, Constant)]
    if not pieces or not all(isinstance(p, TaylorPiece) for p in pieces):
        return None
    return np.concatenate([p.starts for p in pieces]), np.concatenate([p.tcs for p in pieces])


def _difference(sysm, a, b, H0, T) -> tuple:
    """(difference, round-off, scale) of two solves: the largest difference of q and, if they have the
    same event sequence, of the impact and release times; the round-off the events leave,
    4 eps (1 + K) (max |q| + T max |qdot|) for K events (two solves that integrate polynomial flights
    exactly repeat each other's round-off, so their difference alone can be 0); and max |q|. q is
    compared at the step starts of both Taylor solves (each one's dense output at the other's steps;
    smooth in between), or on a 2001-point grid."""
    n = sysm.n
    w = 2 * n + (1 if sysm.is_forced else 0)
    T = min([T] + [s.t_end for s in (a, b) if s.t_end is not None])   # (a solve that ended early: to there)
    ra, rb = Reference(a.pieces, n, [], H0, T, width=w), Reference(b.pieces, n, [], H0, T, width=w)
    sa, sb = _taylor_steps(a), _taylor_steps(b)
    if sa is not None and sb is not None:
        tt = np.concatenate([sa[0], sb[0]])
        qa = np.concatenate([sa[1][:, :n, 0], ra.state(sb[0])[:, :n]])
        qb = np.concatenate([rb.state(sa[0])[:, :n], sb[1][:, :n, 0]])
        speed = float(np.max(np.abs(sa[1][:, :n, 1])))
    else:
        tt = np.linspace(0.0, T, 2001)
        qa, qb = ra.state(tt)[:, :n], rb.state(tt)[:, :n]
        speed = float(np.max(np.abs(np.diff(qa, axis=0)))) / (tt[1] - tt[0]) if T > 0.0 else 0.0
    if sysm.reset_map is not None and a.impacts and _sequence(a) == _sequence(b):
        # a declared map moves q at each impact: between the two solves' impact times the one is past
        # the jump and the other not; those points compare the times (dt below), not q
        keep = np.ones(len(tt), bool)
        for x, y in zip(a.impacts, b.impacts):
            lo, hi = min(x[0], y[0]), max(x[0], y[0])
            keep &= ~((tt >= lo - 4 * _EPS * max(1.0, abs(lo))) & (tt <= hi + 4 * _EPS * max(1.0, abs(hi))))
        tt, qa, qb = tt[keep], qa[keep], qb[keep]
    acc = float(np.max(np.abs(qa - qb)))
    dt = [x[0] - y[0] for x, y in zip(a.impacts + a.releases + a.transitions, b.impacts + b.releases + b.transitions)]
    if a.t_end is not None and b.t_end is not None:
        dt.append(a.t_end - b.t_end)
    if dt and _sequence(a) == _sequence(b):
        acc = max(acc, float(np.max(np.abs(dt))))
    events = len(a.impacts) + len(a.releases) + len(a.intervals)
    scale = float(np.max(np.abs(qa)))
    return acc, 4.0 * _EPS * (1 + events) * (scale + T * speed), scale


def _exact(sysm, q0, p0, prm, T, rtol, check_accuracy, resting_contact, path="auto", tier="compiled"):
    """(Solution, accuracy, kind, why) of the exact solve: the Taylor path where the system is
    expressible, else DOP853 (why: the reason); path "taylor" or "dop853" asks for one."""
    mod = load_module(sysm, SYSTEM_KERNELS, tier)
    model = taylor_model(sysm)
    H0 = float(mod.hamiltonian(q0, p0, prm))
    why = model.expressible() if path != "dop853" else "the DOP853 path was asked for"
    if why is not None and path == "taylor":
        raise NotExpressible(why)
    if why is None:
        try:
            sol = _solve_taylor(sysm, mod, model, q0, p0, prm, T, TOL, resting_contact)
            if not check_accuracy:
                return sol, np.nan, "taylor", ""
            for tol in CHECK_TOLS:
                chk = _solve_taylor(sysm, mod, model, q0, p0, prm, T, tol, resting_contact)
                diff, roundoff, scale = _difference(sysm, sol, chk, H0, T)
                if _sequence(chk) == _sequence(sol) or diff <= SUB_RESOLUTION * (1.0 + scale):
                    return sol, max(diff, roundoff), "taylor", ""
            raise RuntimeError(f"reference: the event sequence of {sysm.name} is ill-conditioned: the Taylor solve at "
                               f"machine precision and its checks at tolerances {', '.join(map(str, CHECK_TOLS))} part "
                               + _first_difference(sol, chk, _names(sysm)))
        except (NotExpressible, TaylorFailure) as e:
            if path == "taylor":
                raise
            why = str(e)
    # DOP853: when the tighter check sees another event sequence, both are refined (tighter, denser
    # checks, shorter steps); a sequence that still differs is an error, never an infinite accuracy
    attempts = [(rtol, 8, 2.0), (max(rtol / 10, RTOL_FLOOR), 16, 1.0), (RTOL_FLOOR, 32, 0.5)]
    for r, samples, reach in attempts:
        sol = _solve_dop853(sysm, mod, q0, p0, prm, T, r, resting_contact, samples, reach)
        if not check_accuracy:
            return sol, np.nan, "dop853", why
        chk = _solve_dop853(sysm, mod, q0, p0, prm, T, max(r / 10, RTOL_FLOOR), resting_contact, 2 * samples,
                            reach / 2)
        diff, roundoff, scale = _difference(sysm, sol, chk, H0, T)
        if _sequence(chk) == _sequence(sol) or diff <= SUB_RESOLUTION * (1.0 + scale):
            # DOP853's error does not shrink tenfold with rtol where its error estimate vanishes
            # (polynomial flights: the events' round-off dominates): ten times the difference
            return sol, max(10.0 * diff, roundoff), "dop853", why
    raise RuntimeError(f"reference: the DOP853 solve of {sysm.name} and its tighter check see different event "
                       f"sequences {_first_difference(sol, chk, _names(sysm))}, down to rtol {RTOL_FLOOR:g}")


class _Slice:
    """The first k components of a dense segment (the forced solve carries the work as state 2n)."""

    def __init__(self, f, k):
        self.f, self.k = f, k

    def __call__(self, t):
        return self.f(t)[: self.k]


def _check_start(system, q0, prm) -> None:
    """A start inside the constraint is bad input, named as such (not a grazing or accumulation
    failure later): phi(q0) < 0 beyond round-off relative to the size of q0 and grad phi."""
    phis, G = system.phi_values(q0, prm), system.constraint_jacobian_value(q0, prm)
    for i, c in enumerate(system.constraints):
        what = f"phi = {c.phi}" if system.m == 1 else f"constraint {c.name} (phi = {c.phi})"
        if not np.isfinite(phis[i]):
            raise ValueError(f"initial state: phi(q0) = {phis[i]} is not finite at q0={np.asarray(q0).tolist()} "
                             f"for {what}")
        if phis[i] < -start_tolerance(q0, G[i]):
            raise ValueError(f"initial state: q0={np.asarray(q0).tolist()} lies inside the constraint: "
                             f"phi(q0) = {phis[i]:.6g} < 0 for {what}; start where phi(q0) >= 0")


def reference(system, *, T, beta=None, q0=None, p0=None, params=None, rtol=1e-13, method="exact", h=None,
              check_accuracy=True, resting_contact=True, tier=None) -> Reference:
    """The nonsmooth solution on [0, T] from (q0, p0) or the scene's initial-condition map at beta.

    method='exact' (default): the event-driven solve of the module docstring. ref.kind says which path
    produced it: "taylor" (heyoka at machine precision; rtol does not apply) or "dop853" (at rtol, for a
    system the Taylor path cannot express; ref.kind_reason says why). ref.accuracy is the largest
    difference from the check solve (check_accuracy=False skips it: NaN); a check that sees another
    event sequence after refinement raises instead of returning a reference.
    method='CVA' (or any method name) with h: a fine-step simulation, interpolated by cubic Hermite
    on (q, qdot = M^-1 p) between its grid points (exact at the grid points).
    resting_contact (as simulate's): contacts that come to rest are held on their surface and
    released where their force turns tensile (ref.releases, ref.release_contact, ref.held_intervals);
    False raises where a contact would have to be held.
    tier: the system kernels' tier (vcirun.codegen.tiers; default $VCIRUN_TIER, else auto: interpreted
    while the compiled ones are built in the background); the same reference either way."""
    from ..core.bounds import check_reference_args
    from ..run.api import simulate
    from ..run.resolve import resolve_system

    check_reference_args(T=T, rtol=rtol, method=method, h=h, beta=beta, q0=q0, p0=p0, params=params,
                         system=system, resting_contact=resting_contact, check_accuracy=check_accuracy)
    from ..codegen.tiers import requested

    tier = requested(tier)
    sysm = resolve_system(system)
    prm = sysm.param_values(params)
    q0, p0 = sysm.initial_state(beta=beta, q0=q0, p0=p0, params=prm)
    T = float(T)
    if method != "exact":
        if h is None:
            raise ValueError("reference.h: a fine step is required for a method reference")
        tr = simulate(sysm, method, h=h, T=T, q0=q0, p0=p0, params=params, resting_contact=resting_contact,
                      tier=tier)
        if tr.status != "ok":
            raise RuntimeError(f"reference: {method} at h={h} failed: {tr.message}")
        return _grid_reference(sysm, tr, prm, tier)
    return solve_exact(sysm, q0, p0, prm, T, rtol=rtol, check_accuracy=check_accuracy,
                       resting_contact=resting_contact, tier=tier)


def solve_exact(sysm, q0, p0, prm, T, *, rtol=1e-13, check_accuracy=True, resting_contact=True,
                path="auto", tier="compiled") -> Reference:
    """The exact Reference of the MechanicalSystem sysm from (q0, p0) at the parameter vector prm
    (`reference` after its validation); path "auto" (Taylor where expressible, else DOP853),
    "taylor" (NotExpressible if it cannot) or "dop853"; tier: the system kernels' (vcirun.codegen.tiers)."""
    q0, p0 = np.asarray(q0, float), np.asarray(p0, float)
    _check_start(sysm, q0, prm)
    try:
        sol, acc, kind, why = _exact(sysm, q0, p0, prm, T, rtol, check_accuracy, resting_contact, path, tier)
        mod = load_module(sysm, SYSTEM_KERNELS, tier)
        H0 = float(mod.hamiltonian(q0, p0, prm))
        n = sysm.n
        pieces = sol.pieces
        if mod.FORCED:
            pieces = [(a, b, _Slice(f, 2 * n)) for a, b, f in sol.pieces]
        T_end = T if sol.t_end is None else sol.t_end
        ref = Reference(pieces, n, [i[0] for i in sol.impacts], H0, T_end, accuracy=acc, kind=kind,
                        impact_contact=[i[1] for i in sol.impacts], impact_impulse=[i[2] for i in sol.impacts])
        ref.kind_reason = why
        ref.releases = np.array([r[0] for r in sol.releases], float)
        ref.release_contact = np.array([r[1] for r in sol.releases], np.int64)
        ref.held_intervals = list(sol.intervals)
        ref.impact_tangential = np.array(sol.tangential, float) if sol.tangential else np.zeros(len(sol.impacts))
        ref.transitions = list(sol.transitions)
        ref.mode_intervals = list(sol.mode_intervals)
        ref.status, ref.message = sol.status, sol.message
        if check_accuracy and not np.isfinite(acc):
            raise RuntimeError(f"reference: the accuracy check of {sysm.name} is not finite ({acc}): the solve "
                               "cannot be trusted")
        ref._account_of = functools.partial(_account, sysm.name, sol.pieces, n, ref.impacts, mod, prm, T,
                                            ref.impact_contact, ref.mode_intervals)
    except ReferenceCostError:
        raise
    except (ArithmeticError, ValueError, IndexError, np.linalg.LinAlgError) as e:
        # scipy's and numpy's own messages (e.g. brentq's "f(a) and f(b) must have different signs")
        # say nothing about the run: name the solve and the cause instead
        raise RuntimeError(f"reference: the exact solve of {sysm.name} failed ({type(e).__name__}: {e})") from None
    return ref


class _Hermite:
    def __init__(self, t, y, dy):
        from scipy.interpolate import CubicHermiteSpline

        self.f = CubicHermiteSpline(t, y, dy, axis=0)

    def __call__(self, t):
        return self.f(t).T


def _grid_reference(system, tr, prm, tier="compiled"):
    mod = load_module(system, SYSTEM_KERNELS, tier)
    n = system.n
    buf = np.empty(2 * n)
    dq = np.empty_like(tr.q)
    dp = np.empty_like(tr.p)
    for k in range(len(tr.t)):
        mod.dynamics_rhs(tr.t[k], np.concatenate([tr.q[k], tr.p[k]]), prm, buf)  # forced: the slopes include f
        dq[k], dp[k] = buf[:n], buf[n:]
    # split at impact steps so that interpolation never straddles a velocity jump
    y = np.hstack([tr.q, tr.p])
    dy = np.hstack([dq, dp])
    cuts = [0] + [k + 1 for k in np.flatnonzero(tr.impact_step)] + [len(tr.t) - 1]
    cuts = sorted(set(cuts))
    segs = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        if b - a >= 1:
            segs.append((tr.t[a], tr.t[b], _Hermite(tr.t[a:b + 1], y[a:b + 1], dy[a:b + 1])))
    return Reference(segs, n, tr.impacts, float(tr.H[0]), tr.T, accuracy=np.nan, kind=f"{tr.method}@h={tr.h:g}")


def l2_error(traj, ref) -> float:
    """The L2 trajectory error used everywhere: sqrt(h * sum_k |q_k - q_ref(t_k)|^2) over the grid
    points k = 0..N of the run (a Riemann sum of the continuous L2 norm of q - q_ref on [0, T])."""
    d = traj.q - ref(traj.t)
    return float(np.sqrt(traj.h * np.sum(d * d)))


def _account(name, pieces, n, impacts, mod, prm, T, impact_contact, mode_intervals):
    """The energy account of an exact solve (vcirun.run.accounts.reference_account), with the solve's
    failure message where its arithmetic fails."""
    from ..run.accounts import reference_account

    try:
        return reference_account(pieces, n, impacts, mod, prm, T, bool(mod.FORCED), impact_contact=impact_contact,
                                 friction=_friction_account(mod, prm, n, mode_intervals))
    except (ArithmeticError, ValueError, IndexError, np.linalg.LinAlgError) as e:
        raise RuntimeError(f"reference: the energy account of {name} failed ({type(e).__name__}: {e})") from None


def _friction_account(mod, prm, n, mode_intervals):
    """(mode intervals, power) for the energy account's friction work, or None without friction: the
    power of the friction forces at a state, -sum over the sliding contacts of mu lam_n |v_t| (a
    sticking contact's v_t is 0; docs/derivations/friction.md)."""
    from .coulomb import coefficients

    fric = coefficients(mod, prm)
    if fric is None or not mode_intervals:
        return None
    mu = fric[0]

    def power(t, y, A, S):
        g = rh._Geometry(mod, t, y[:n], y[n:2 * n], prm)
        lam_n, wt = g.forces(A, S).lam_n, g.wt
        return -sum(mu[i] * lam_n[a] * abs(wt[i]) for a, (i, s) in enumerate(zip(A, S)) if s in (1, -1))

    return mode_intervals, power
