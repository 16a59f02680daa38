"""The continuous nonsmooth solution to high accuracy, for error measurement.

Exact reference: Hamilton's equations with the generalized force, qdot = M^-1 p,
pdot = -dH/dq + f(q, qdot, t), integrated by DOP853 (scipy) with event location on phi(q) = 0
(direction: entering the constraint) and the exact elastic reset p+ = p- + lam grad phi,
lam = -2 g^T M^-1 p- / g^T M^-1 g (H conserved: an impulse, bounded forces do no work in zero
time), restarted after each impact; dense output on any grid. Its accuracy is self-reported as the
largest difference (trajectory and impact times) from a second solve at a 10x tighter tolerance (at
least scipy's floor of ~2.2e-14). A forced system also carries the work W(t) = int_0^t f . qdot as
an extra state, and `energy_balance` = max |H(t) - H(0) - W(t)| on a dense grid: a check of the
solve that does not rest on a second solve of the same equations.

Held contacts (issue 18, resting_contact=True): a contact that starts at rest on its surface, is
left at rest by a plastic impact, or whose impacts accumulate (Zeno time extrapolated from its
flights) is held on the index-reduced constrained dynamics (vcirun/reference/held.py) and released
where its contact force turns tensile; docs/contacts.md section 6.

Also: a fine-step method reference (the paper's choice: CVA at a small h). Closed forms (the
oscillator against a wall, the bouncing ball) are in vcirun.scenes.oracles.
"""
from __future__ import annotations

import numpy as np

from ..codegen.build import load_module
from ..codegen.kernel_set import SYSTEM_KERNELS
from ..core.system_data import start_tolerance


class Reference:
    """Callable reference solution on [t_start, T]: ref(t) -> q, shape (n,) for a scalar t and
    (len(t), n) for an array; ref.p(t), ref.state(t) likewise; ref.impacts; ref.accuracy.
    Right-continuous at impacts (the post-impact momentum at t = tau). A time outside [t_start, T]
    raises ValueError (no extrapolation)."""

    def __init__(self, segments, n, impacts, H0, T, accuracy=np.nan, kind="exact", width=None, impact_contact=None,
                 impact_impulse=None):
        self.segments = segments  # list of (t_start, t_end, dense OdeSolution)
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
        self.kind = kind
        self.energy_balance = np.nan  # forced exact solves: max |H(t) - H(0) - int f . qdot|
        # held contacts (issue 18): release times and contacts, held phases (t0, t1, held set)
        self.releases = np.zeros(0)
        self.release_contact = np.zeros(0, np.int64)
        self.held_intervals = []
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

    def p(self, t) -> np.ndarray:
        return self.state(t)[..., self.n:]


def _first_root(g, a, b, samples=64):
    """First sign change of g on [a, b] (g(a) >= 0 > g(b)): dense samples bracket it, brentq refines."""
    from scipy.optimize import brentq

    ts = np.linspace(a, b, samples + 1)
    prev = ts[0]
    for s in ts[1:]:
        if g(s) < 0.0:
            return float(brentq(g, prev, s, xtol=1e-15, rtol=4 * np.finfo(float).eps))
        prev = s
    return float(b)


def rk4_step(f, t, y, dt):
    """One classical RK4 step (the escape micro step off the surface after a reset; also used by the
    solve_ivp baseline)."""
    k1 = f(t, y)
    k2 = f(t + dt / 2, y + dt / 2 * k1)
    k3 = f(t + dt / 2, y + dt / 2 * k2)
    k4 = f(t + dt, y + dt * k3)
    return y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def step_off_surface(rhs, phi, t, y, delta, tries=40):
    """(t + d, y(t + d)) by one RK4 micro step of length d <= delta to a state with phi > 0, halving d
    up to `tries` times; None if none is found (delta <= 0 or the motion stays on the surface).

    After an elastic reset phi is ~0 (often -1e-17), and solve_ivp detects a crossing only from a
    start value >= 0, so a hop shorter than its first step would go unnoticed (measured: DOP853 at
    rtol 1e-3 over T = 300 lost the cart through the floor after 26 impacts). The micro step's local
    error is ~d^5, negligible. Used by the exact reference and the solve_ivp baseline."""
    for _ in range(tries):
        if not delta > 0.0:
            return None
        y1 = rk4_step(rhs, t, y, delta)
        if phi(y1) > 0.0:
            return t + delta, y1
        delta *= 0.5
    return None


class _HermiteSegment:
    """Dense output of the escape micro step: cubic Hermite on [t0, t1], called like an OdeSolution."""

    def __init__(self, t0, y0, f0, t1, y1, f1):
        self.t0, self.d = t0, t1 - t0
        self.c = (np.array(y0, float), np.array(f0, float) * self.d, np.array(y1, float),
                  np.array(f1, float) * self.d)

    def __call__(self, t):
        s = (np.atleast_1d(np.asarray(t, float)) - self.t0) / self.d
        y0, m0, y1, m1 = self.c
        h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
        h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
        return np.outer(y0, h00) + np.outer(m0, h10) + np.outer(y1, h01) + np.outer(m1, h11)


SIMULTANEOUS = 1e-10  # contacts whose roots lie within this many seconds impact together (LCP)


# The exact solve's budget of right-hand-side evaluations (issue 22): a normal solve needs 500 to 1,300
# per unit of time at rtol 1e-13 (~15 us each), so 5e7 is ten minutes or more. An initial state so large
# that the solver's steps collapse (beta = 1e20: velocities ~1e19) or a T far beyond it would otherwise
# run for hours; the projection is checked once MIN evaluations are spent (a few seconds).
MAX_RHS_EVALS = 5e7
MIN_RHS_EVALS_FOR_PROJECTION = 200_000


class ReferenceCostError(ValueError):
    """The exact solve would exceed MAX_RHS_EVALS (a ValueError: the arguments ask for it)."""


def _exact(system, q0, p0, prm, T, rtol, max_impacts=10_000, resting_contact=True):
    """(segments, impacts, H(q0, p0), work, held) of the exact solve; impacts: [(time, contact,
    impulse)]; work is None for an unforced system, else a callable t -> W(t) = int_0^t f . qdot (the
    extra state of every segment); held: {"releases": [(time, contact)], "intervals": [(t0, t1, A)]}.
    The event is the gap min_i phi_i over the contacts not masked: its first root is the first
    contact of any constraint.

    Held contacts (resting_contact, issue 18; vcirun/reference/held.py, docs/contacts.md 6): a start
    at rest on a surface with a compressive force, a plastic impact that leaves a contact at rest
    pressed in, or a contact whose impacts accumulate (its Zeno time extrapolated from its flights)
    continues on the constrained (index-reduced) dynamics until the contact force turns tensile
    (release) or another contact is hit. resting_contact=False keeps the old behaviour: such runs
    raise (a contact pressed in; more than max_impacts impacts)."""
    from scipy.integrate import solve_ivp  # here, not at module level: `import vcirun` stays light

    from . import held as rh

    mod = load_module(system, SYSTEM_KERNELS)  # system kernels + the continuous dynamics
    n = system.n
    forced = bool(mod.FORCED)
    buf = np.empty(2 * n)

    evals = [0]

    def rhs(t, y):
        evals[0] += 1
        if evals[0] >= MIN_RHS_EVALS_FOR_PROJECTION and evals[0] % 1000 == 0:
            _check_cost(evals[0], t, T, q0, p0)
        mod.dynamics_rhs(t, y[:2 * n], prm, buf)
        if not forced:
            return buf.copy()
        # the work of the force, W' = f(q, qdot, t) . qdot (qdot = buf[:n])
        return np.append(buf, mod.force_power(y[:n], buf[:n].copy(), t, prm))

    m = int(mod.NCON)
    mask = np.zeros(m, dtype=np.int64)  # contacts touching and not approaching at the segment's start
    rest = np.zeros(m, dtype=np.int64)  # contacts left at rest on their surface by a release (masked)
    e_of = np.empty(m)
    mod.sys_restitution(prm, e_of)

    def event(t, y):  # the gap over the contacts not touching (collision/impact.py: gap)
        return mod.gap(y[:n], prm, mask)

    event.terminal = True
    event.direction = -1.0

    def dip(t, y):  # d gap / dt: crosses 0 upwards at every local minimum of the gap along the flow
        return mod.gap_slope(y[:n], y[n:2 * n], prm, mask)

    dip.terminal = False  # recorded, checked after the solve (a terminal event at a minimum would
    dip.direction = 1.0   # restart where d phi/dt = 0 and fire again at once)

    def pressed(t, y):  # a masked contact below minus its round-off: pushed in, or back (issue 18)
        phis = np.empty(m)
        mod.sys_phis(y[:n], prm, phis)
        return float(np.min(np.where(mask == 1, phis, np.inf))) + 1e-12 * (1.0 + float(np.max(np.abs(y[:n]))))

    pressed.terminal = True
    pressed.direction = -1.0
    y = np.concatenate([q0, p0] + ([[0.0]] if forced else []))
    t = 0.0
    segments, impacts = [], []  # impacts: (time, contact index, impulse), one entry per contact impact
    releases, intervals = [], []
    times_of = [[] for _ in range(m)]  # each contact's impact times (accumulation)
    d, lam, active = np.empty(n), np.empty(m), np.empty(m, dtype=np.int64)
    held = np.zeros(m, dtype=np.int64)  # contacts held (resting): in the held segments, never here
    atol = rtol * max(1.0, float(np.max(np.abs(y))))
    A = rh.initially_held(mod, q0, p0, prm) if resting_contact else ()
    while t < T:
        if A:  # a held phase: the constrained dynamics until a release, an impact or T
            mod.touching_mask(y[:n].copy(), y[n:2 * n].copy(), 1.0, SIMULTANEOUS / 4, prm, mask, held)
            mask[rest == 1] = 1
            seg = rh.held_segment(mod, t, y, T, A, mask.copy(), prm, rtol, atol)
            segments.extend(seg.pieces)
            intervals.append((seg.t0, seg.t1, tuple(seg.held)))
            tr = rh.after_held_event(mod, seg, prm, SIMULTANEOUS / 4)
            for imp in tr.impacts:
                impacts.append(imp)
                times_of[imp[1]].append(imp[0])
            if tr.released >= 0:
                releases.append((tr.t, tr.released))
            rest[:] = 0
            rest[list(tr.rest)] = 1
            t, y, A = tr.t, tr.y, tr.held
            if seg.reason == "end":
                break
            continue
        mod.touching_mask(y[:n].copy(), y[n:2 * n].copy(), 1.0, SIMULTANEOUS / 4, prm, mask, held)
        mask[rest == 1] = 1  # at rest after a release: u is round-off of either sign; `pressed` watches it
        events = [event, dip] + ([pressed] if mask.any() else [])
        sol = solve_ivp(rhs, (t, T), y, method="DOP853", rtol=rtol, atol=atol, events=events,
                        dense_output=True)
        if sol.status < 0:
            raise RuntimeError(f"reference: DOP853 failed at t={sol.t[-1]:.6g}: {sol.message}")
        te = None
        tp = float(sol.t_events[2][0]) if len(events) == 3 and sol.status == 1 and sol.t_events[2].size else None
        if sol.status == 1 and sol.t_events[0].size:
            te = float(sol.t_events[0][0])
            ye = sol.y_events[0][0].copy()
        # Minima of phi: solve_ivp sees a crossing only where phi changes sign between two of its
        # steps, so a dip below the surface shorter than one step (a near-grazing impact) goes
        # unnoticed; its minimum is then negative. The first such minimum before the detected
        # impact means an earlier, missed impact: its first root on the dense output replaces it.
        for tm, ym in zip(sol.t_events[1], sol.y_events[1]):
            if te is not None and tm >= te:
                break
            if mod.gap(ym[:n], prm, mask) < 0.0:
                te = _first_root(lambda s: mod.gap(sol.sol(s)[:n], prm, mask), t, float(tm))
                ye = sol.sol(te).copy()
                break
        if tp is not None and (te is None or tp < te):
            # a masked contact (touching and not approaching, or left at rest by a release) went
            # below its surface: it came back (an impact: its root on the dense output) or, at rest,
            # is pushed in (resting contact: hold it)
            yp = sol.y_events[2][0].copy()
            ids = [int(i) for i in np.flatnonzero(mask)]
            phis = np.empty(m)
            mod.sys_phis(yp[:n], prm, phis)
            j = min(ids, key=lambda i: phis[i])
            geo = rh._Geometry(mod, tp, yp[:n], yp[n:2 * n], prm)
            u, gn = float(geo.G[j] @ geo.v), float(np.max(np.abs(geo.G[j])))
            if resting_contact and u < -1e-6 * gn * (1.0 + float(np.max(np.abs(geo.v)))):
                def phi_j(s_, j=j):
                    mod.sys_phis(sol.sol(s_)[:n], prm, phis)
                    return phis[j]
                te = _first_root(phi_j, t, tp)
                ye = sol.sol(te).copy()
            else:
                A = rh.held_set(mod, tp, yp[:n], yp[n:2 * n], prm, [j], 1e-6) if resting_contact else ()
                if not A:
                    raise RuntimeError(f"reference: a touching contact is pushed into its constraint at t="
                                       f"{tp:.6g} (resting contact"
                                       + (")" if resting_contact else "; resting_contact=True holds it)"))
                segments.append((t, tp, sol.sol))
                t, y, rest[:] = tp, rh._project_y(mod, yp, prm, A), 0
                continue
        segments.append((t, sol.t[-1] if te is None else te, sol.sol))
        if te is not None:
            rest[:] = 0
            # the impact law of the integrators (collision/impact.py): one contact, Newton's law;
            # several within SIMULTANEOUS seconds of each other, Moreau's LCP
            k, s0, _ = mod.impact_direction(ye[:n].copy(), ye[n:2 * n].copy(), 1.0, SIMULTANEOUS / 4, prm, d, lam,
                                            active)
            if k == 0:
                A = rh.held_set(mod, te, ye[:n], ye[n:2 * n], prm, None, 1e-6) if resting_contact else ()
                if not A:
                    raise RuntimeError(f"reference: grazing contact at t={te:.6g} (zero normal velocity"
                                       + (")" if resting_contact else "; resting_contact=True holds a contact "
                                          "pressed in)"))
                t, y = te, rh._project_y(mod, ye, prm, A)
                continue
            if k < 0:
                raise RuntimeError(f"reference: the impact law has no solution at t={te:.6g} (case {k})")
            ye[n:2 * n] = ye[n:2 * n] + s0 * d
            hit = []
            for i in np.flatnonzero(active):
                if m == 1 or lam[i] > 0.0:
                    impacts.append((te, int(i), float(s0 if m == 1 else lam[i])))
                    times_of[int(i)].append(te)
                    hit.append(int(i))
            if len(impacts) > max_impacts:
                raise RuntimeError(f"reference: more than {max_impacts} impacts (accumulation?) by t={te:.6g}"
                                   + ("" if resting_contact else "; resting_contact=True holds such contacts"))
            t, y = te, ye
            if resting_contact:
                # (b) a plastic impact leaving a contact at rest pressed in; (a) accumulating impacts
                A = rh.plastic_entry(mod, te, y[:n], y[n:2 * n], prm, hit)
                if A:
                    y = rh._project_y(mod, y, prm, A)
                    continue
                acc = [i for i in hit if rh.accumulating(times_of[i], e=e_of[i])]
                if acc:
                    mod.touching_mask(y[:n].copy(), y[n:2 * n].copy(), 1.0, SIMULTANEOUS / 4, prm, mask, held)
                    t_inf, seg = rh.zeno_entry(mod, te, y, prm, acc[0], times_of[acc[0]], mask=mask.copy(),
                                               rtol=rtol, atol=atol)
                    if t_inf < T:
                        segments.extend(seg.pieces)
                        intervals.append((te, t_inf, tuple(seg.held)))
                        t, y, A = t_inf, seg.y1, tuple(seg.held)
                        continue
            # Step off the surface before restarting: right after the reset phi is ~0 (often -1e-17)
            # and solve_ivp only sees a crossing from a start value >= 0, so a hop shorter than its
            # first step would go unnoticed. One RK4 micro step (<= 1e-9, local error ~1e-45) to
            # phi > 0, covered by a cubic Hermite segment (error ~delta^4 times the 4th derivative).
            mod.touching_mask(y[:n].copy(), y[n:2 * n].copy(), 1.0, SIMULTANEOUS / 4, prm, mask, held)
            off = step_off_surface(rhs, lambda yy: mod.gap(yy[:n], prm, mask), t, y, min(1e-9, 0.5 * (T - t)))
            if off is not None:
                t1, y1 = off
                segments.append((t, t1, _HermiteSegment(t, y, rhs(t, y), t1, y1, rhs(t1, y1))))
                t, y = t1, y1
        else:
            t = T
    work = None
    if forced:
        whole = Reference(segments, n, [], np.nan, T, width=2 * n + 1)
        work = lambda tt: whole.state(tt)[:, 2 * n]  # noqa: E731
        segments = [(a, b, _Slice(f, 2 * n)) for a, b, f in segments]
    return (segments, impacts, float(mod.hamiltonian(q0, p0, prm)), work,
            {"releases": releases, "intervals": intervals})


class _Slice:
    """The first k components of a dense segment (the forced solve carries the work as state 2n)."""

    def __init__(self, f, k):
        self.f, self.k = f, k

    def __call__(self, t):
        return self.f(t)[: self.k]


def _check_cost(evals: int, t: float, T: float, q0, p0) -> None:
    """Raise ReferenceCostError when `evals` right-hand-side evaluations reached only time t and the
    projection to T exceeds MAX_RHS_EVALS."""
    projected = evals * T / t if t > 0 else np.inf
    if evals >= MAX_RHS_EVALS or projected > MAX_RHS_EVALS:
        scale = float(max(np.max(np.abs(q0)), np.max(np.abs(p0))))
        raise ReferenceCostError(
            f"T: the exact reference would need about {projected:.1e} right-hand-side evaluations to reach "
            f"T = {T:g} ({evals:,} reached t = {t:.3g}; the limit is {MAX_RHS_EVALS:.0e}): the initial state "
            f"(max |q0|, |p0| = {scale:.3g}) is too large or T too long for an exact solve; lower T, give a smaller "
            "initial state, or use a method reference (method='CVA', h=...)")


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
              check_accuracy=True, resting_contact=True) -> Reference:
    """The nonsmooth solution on [0, T] from (q0, p0) or the scene's initial-condition map at beta.

    method='exact' (default): DOP853 + event location + exact elastic reset, at rtol; accuracy is
    estimated against a second solve at rtol / 10 (check_accuracy=False skips it).
    method='CVA' (or any method name) with h: a fine-step simulation, interpolated by cubic Hermite
    on (q, qdot = M^-1 p) between its grid points (exact at the grid points).
    resting_contact (as simulate's): contacts that come to rest are held on their surface and
    released where their force turns tensile (ref.releases, ref.release_contact, ref.held_intervals);
    False raises where a contact would have to be held."""
    from ..run.api import simulate
    from ..run.resolve import resolve_system
    from ..core.bounds import check_reference_args

    check_reference_args(T=T, rtol=rtol, method=method, h=h, beta=beta, q0=q0, p0=p0, params=params,
                         system=system, resting_contact=resting_contact, check_accuracy=check_accuracy)  # (issue 22)
    sysm = resolve_system(system)
    prm = sysm.param_values(params)
    q0, p0 = sysm.initial_state(beta=beta, q0=q0, p0=p0, params=prm)
    T = float(T)
    if method != "exact":
        if h is None:
            raise ValueError("reference.h: a fine step is required for a method reference")
        tr = simulate(sysm, method, h=h, T=T, q0=q0, p0=p0, params=params, resting_contact=resting_contact)
        if tr.status != "ok":
            raise RuntimeError(f"reference: {method} at h={h} failed: {tr.message}")
        return _grid_reference(sysm, tr, prm)
    _check_start(sysm, q0, prm)
    try:
        segs, imps, H0, work, held = _exact(sysm, q0, p0, prm, T, rtol, resting_contact=resting_contact)
        acc = np.nan
        ref = Reference(segs, sysm.n, [i[0] for i in imps], H0, T, kind="exact",
                        impact_contact=[i[1] for i in imps], impact_impulse=[i[2] for i in imps])
        ref.releases = np.array([r[0] for r in held["releases"]], float)
        ref.release_contact = np.array([r[1] for r in held["releases"]], np.int64)
        ref.held_intervals = list(held["intervals"])
        if check_accuracy:
            # estimate the returned solve's error against a tighter one (scipy's floor is ~2.2e-14)
            segs2, imps2, _, _, held2 = _exact(sysm, q0, p0, prm, T, max(rtol / 10, 2.3e-14),
                                               resting_contact=resting_contact)
            tt = np.linspace(0.0, T, 2001)
            acc = float(np.max(np.abs(ref(tt) - Reference(segs2, sysm.n, [], H0, T)(tt))))
            rel, rel2 = held["releases"], held2["releases"]
            if [i[1] for i in imps] != [i[1] for i in imps2] or [r[1] for r in rel] != [r[1] for r in rel2]:
                acc = np.inf  # the tighter solve sees another event sequence: nothing is accurate
            else:
                dt = [a[0] - b[0] for a, b in zip(imps + rel, imps2 + rel2)]
                if dt:
                    acc = max(acc, float(np.max(np.abs(dt))))
            ref.accuracy = acc
        if work is not None:
            ref.energy_balance = _energy_balance(sysm, ref, work, prm, T)
    except ReferenceCostError:
        raise
    except (ArithmeticError, ValueError, IndexError, np.linalg.LinAlgError) as e:
        # scipy's and numpy's own messages (e.g. brentq's "f(a) and f(b) must have different signs")
        # say nothing about the run: name the solve and the cause instead
        raise RuntimeError(f"reference: the exact solve of {sysm.name} failed ({type(e).__name__}: {e})") from None
    return ref


def _energy_balance(system, ref, work, prm, T) -> float:
    """max over a dense grid of |H(t) - H(0) - W(t)|, W the work integral carried by the solve."""
    mod = load_module(system, SYSTEM_KERNELS)
    tt = np.linspace(0.0, T, 2001)
    y = ref.state(tt)
    n = system.n
    H = np.array([mod.hamiltonian(y[k, :n].copy(), y[k, n:].copy(), prm) for k in range(len(tt))])
    return float(np.max(np.abs(H - ref.H0 - work(tt))))


class _Hermite:
    def __init__(self, t, y, dy):
        from scipy.interpolate import CubicHermiteSpline

        self.f = CubicHermiteSpline(t, y, dy, axis=0)

    def __call__(self, t):
        return self.f(t).T


def _grid_reference(system, tr, prm):
    mod = load_module(system, SYSTEM_KERNELS)
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
