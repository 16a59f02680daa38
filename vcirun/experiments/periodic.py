"""Periodic orbits of a hybrid system and their stability: a fixed point of the return map on a section
(the state just after an impact of one constraint: the stride map of a walker), by Newton on the
discrete map of a method at step h.

The return map P(x), x = (q, p) just after the reset, runs Algorithm 1 from x (vcirun.simulate) up to
the k-th impact on the section and returns the state just after it: q+ = the declared map of the
recorded impact configuration (the identity without one), p+ = the recorded momentum after the
reset. Its Jacobian is the fourth-order central finite difference of that discrete map (stencil
+-delta, +-2 delta, delta = fd_step max(1, |x_j|)): the map is smooth in x to round-off (Newton
and the event search converge far below their tolerances), so the Jacobian is accurate to about
eps / fd_step + fd_step^4 |D^5 P| (default: FD_STEP of vcirun.reference_solution.stride on the exact map,
METHOD_FD_STEP on a method's). The eigenvalues of DP are the orbit's Floquet multipliers; the image
of P lies on the section (codimension one for an impact surface), so one multiplier is ~0.

method "reference": the exact return map (vcirun.reference_solution.stride.ReferenceReturnMap) with the same
Jacobian, the orbit the methods' converge to in h.

`continuation` follows a fixed point along a parameter (the previous point as the next guess),
detects period doubling where a multiplier crosses -1, and follows the period-two orbit from there.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.grid import MIN_H
from ..core.values import check_number, describe
from ..run.api import simulate
from ..run.resolve import resolve_numeric, resolve_system
from ..methods.table import resolve_method
from ..reference_solution.stride import FD_STEP, ReferenceReturnMap, fd_jacobian

# A method's map carries its Newton and event-search noise (up to ~newton_tol relative), which a
# smaller step amplifies: at 5e-5 CVA's multipliers on the compass gait no longer converge in h.
METHOD_FD_STEP = 1e-3


@dataclass
class PeriodicOrbit:
    """fixed_point: (q, p) on the section just after the reset; period: the return time; eigenvalues:
    the multipliers of the return map (|.| descending); jacobian: DP at the fixed point; residual:
    max |P(x) - x|; iterations: Newton steps; k: impacts per return (2: a period-two orbit)."""

    fixed_point: tuple
    period: float
    eigenvalues: np.ndarray
    jacobian: np.ndarray
    residual: float
    iterations: int
    method: str
    h: float
    k: int = 1
    params: dict = field(default_factory=dict)
    jacobian_kind: str = "fd"

    @property
    def stable(self) -> bool:
        return bool(np.max(np.abs(self.eigenvalues)) < 1.0)

    def to_dict(self) -> dict:
        q, p = self.fixed_point
        return {"q": q.tolist(), "p": p.tolist(), "period": self.period,
                "eigenvalues_real": self.eigenvalues.real.tolist(), "eigenvalues_imag": self.eigenvalues.imag.tolist(),
                "residual": self.residual, "iterations": self.iterations, "method": self.method, "h": self.h,
                "k": self.k, "params": dict(self.params), "stable": self.stable,
                "jacobian_kind": self.jacobian_kind}


def _why_no_return(tr, hits, k) -> str:
    """What the last run did instead of returning: its impacts, and the range each coordinate covered
    (a walker that rocks back and forth, or one that fell, never reaches its next strike)."""
    span = ", ".join(f"{name} in [{lo:.4g}, {hi:.4g}]" for name, lo, hi in
                     zip(tr.coordinate_names, tr.q.min(axis=0), tr.q.max(axis=0)))
    other = len(tr.impacts) - len(hits)
    return (f"the run made {len(hits)} of the {k} impact(s) on the section" + (f" and {other} on other contacts"
            if other else "") + f"; over [0, {tr.t[-1]:g}] {span} (the motion turns back, stops or falls before "
            "it reaches the section: start nearer the orbit, or choose parameters that have one)")


class ReturnMap:
    """P(x) of (system, method, h) on the section of constraint `section` (an index or name; default:
    the constraint with a declared reset, else the first), after k impacts there."""

    def __init__(self, system, method, *, h, section=None, k=1, params=None, T_max=None, **options):
        h, k = check_step(h), check_impacts(k)
        if T_max is not None:
            T_max = check_number("T_max", T_max, gt=0)
        self.system = resolve_system(system) if isinstance(system, str) else system
        self.method, self.h, self.k = method, h, k
        self.params = dict(params or {})
        self.options = options
        meth = resolve_method(method)
        sysd, load, sysm = resolve_numeric(self.system, meth.kernel_set())
        self.n = sysd.n
        self.mod = load(options.get("tier"))
        # one tier for every evaluation of this map (a Newton iteration never mixes them)
        self.options = dict(options, tier="interpreted" if load.tier == "interpreted" else "compiled")
        self.prm = sysd.param_values(self.params)
        names = [c.name for c in sysm.constraints] if sysm is not None else None
        self.section = _section_index(section, sysm, names)
        self.T_max = T_max
        self._T = None
        self.evaluations = 0
        self.last_impact_times = np.empty(0)

    def _plus(self, q_minus, p_plus):
        qo, qdo = np.empty(self.n), np.empty(self.n)
        self.mod.sys_reset_map(np.ascontiguousarray(q_minus, float), np.zeros(self.n), self.prm, qo, qdo)
        return qo, np.array(p_plus, float)

    def __call__(self, x):
        """(P(x), return time); raises RuntimeError when the run fails or reaches no return."""
        x = np.asarray(x, float)
        q0, p0 = x[: self.n], x[self.n:]
        T = self._T or 4.0
        for _ in range(8):
            T = self.h * max(1.0, np.ceil(T / self.h - 1e-9))   # a whole number of steps, at least one
            try:
                tr = simulate(self.system, self.method, h=self.h, T=T, q0=q0, p0=p0, params=self.params or None,
                              energies=False, **self.options)
            except ValueError as e:
                field, _, why = str(e).partition(": ")
                if field not in ("T", "h"):
                    raise
                # the span is the return map's own search (T = 4 s, doubled until k impacts), not the user's
                raise ValueError(f"h: the return map's search for {self.k} impact{'s' * (self.k > 1)} on the "
                                 f"section runs over T = {T:g} s at h = {self.h:g}, and {why}") from None
            self.evaluations += 1
            hits = np.flatnonzero(tr.impact_contact == self.section) if len(tr.impacts) else np.array([], int)
            if len(hits) >= self.k:
                j = hits[self.k - 1]
                t = float(tr.impacts[j])
                self.last_impact_times = np.array(tr.impacts[: j + 1], float)   # every impact up to the return
                self._T = max(self._T or 0.0, 1.25 * t + 4 * self.h)
                qp, pp = self._plus(tr.impact_q[j], tr.impact_p_plus[j])
                return np.concatenate([qp, pp]), t
            if not tr.ok:
                raise RuntimeError(f"return map: the run from {x.tolist()} stopped ({tr.status}: {tr.message}) "
                                   f"after {len(hits)} of {self.k} impacts on the section")
            if (self.T_max is not None and T >= self.T_max) or not np.isfinite(2.0 * T):
                break
            T *= 2.0
        raise RuntimeError(f"return map: no return to the section within T = {tr.t[-1]:g} from {x.tolist()}: "
                           + _why_no_return(tr, hits, self.k))

    def jacobian(self, x, fd_step=METHOD_FD_STEP):
        """DP(x) by the fourth-order central difference (see the module docstring)."""
        return fd_jacobian(self, x, fd_step)

    def piece_jacobian(self, x, fd_step):
        """DP(x) of the smooth piece of the map that holds x: the piece is where every impact up to the
        return stays in the same step (VCI's map jumps where an impact time crosses a grid point). The
        fourth-order central difference where its stencil (+-delta, +-2 delta, delta = fd_step max(1,
        |x_j|)) stays on the piece; else the fourth-order one-sided one (0, delta, .. 4 delta) on the
        side that does."""
        x = np.asarray(x, float)
        m = x.shape[0]

        def at(y):
            f, _ = self(y)
            return f, tuple(np.floor(self.last_impact_times / self.h).astype(int))

        f0, piece = at(x)
        J = np.empty((m, m))
        for j in range(m):
            d = fd_step * max(1.0, abs(x[j]))
            e = np.zeros(m)
            e[j] = d
            pts = {s: at(x + s * e) for s in (2, 1, -1, -2)}
            if all(pts[s][1] == piece for s in pts):
                f = [pts[s][0] for s in (2, 1, -1, -2)]
                J[:, j] = (-f[0] + 8.0 * f[1] - 8.0 * f[2] + f[3]) / (12.0 * d)
                continue
            for side in (1, -1):
                if pts[side][1] != piece or pts[2 * side][1] != piece:
                    continue
                more = [at(x + side * s * e) for s in (3, 4)]
                if all(b == piece for _, b in more):
                    f = [f0, pts[side][0], pts[2 * side][0], more[0][0], more[1][0]]
                    J[:, j] = (-25.0 * f[0] + 48.0 * f[1] - 36.0 * f[2] + 16.0 * f[3] - 3.0 * f[4]) / (12.0 * side * d)
                    break
            else:
                raise RuntimeError(f"finite-difference Jacobian: the map jumps within 4 delta = {4 * d:.3g} on both "
                                   f"sides of x[{j}]; use jacobian 'envelope' or a smaller fd_step")
        return J


# The envelope Jacobian (periodic_orbit(..., jacobian="envelope")). VCI's map is a smooth envelope E
# plus a sawtooth h^2 G(theta, x) in the impact phase theta = t/h mod 1 (t: the impact time; a jump
# where t crosses a grid point). Each sample's theta is known from its t, so one least-squares fit
# (weights (1 - s^2)^4, ENVELOPE_POINTS equispaced s in [-1, 1] per line x + s d_j) of a polynomial in
# s of ENVELOPE_DEGREE per line plus G's model -- Legendre polynomials in theta up to
# ENVELOPE_PHASE_DEGREE, shared, and the same times s per line -- gives DE d_j free of the sawtooth.
# The lines make t sweep ENVELOPE_TEETH steps each (fewer teeth do not tell G from the polynomial;
# many per point leave G's unmodelled part aliased): d_j = w_j e_j, w_j = min(ENVELOPE_C |x_j|, the
# half-width where t moves by ENVELOPE_TEETH / 2 steps), plus a multiple of the line along which t moves
# most where t moves less along e_j. DE is taken at E's fixed point (one Newton step on the fitted E
# from the gait, which is off it by a phase-dependent O(h^2), then the fit repeated there): 2 m
# (ENVELOPE_POINTS + 2) evaluations of P (812 on the wheel, 1624 on the compass gait). Measured
# (docs/walkers.md): VCI's wheel multiplier -0.72 h^2 from the closed form at each of 21 steps
# h = 0.02 .. 6.25e-4 (order 2.00); the compass gait's 2.2 .. 2.6 h^2 at h = 0.02 .. 6.25e-4.
ENVELOPE_C = 0.05
ENVELOPE_DEGREE = 5
ENVELOPE_POINTS = 201
ENVELOPE_TEETH = 8
ENVELOPE_PHASE_DEGREE = 3


def envelope_jacobian(P, x, h, c=ENVELOPE_C, degree=ENVELOPE_DEGREE, points=ENVELOPE_POINTS,
                      teeth=ENVELOPE_TEETH, phase_degree=ENVELOPE_PHASE_DEGREE):
    """DE at the fixed point of the smooth envelope E of P near x (see ENVELOPE_C above)."""
    x = np.asarray(x, float)
    J, E = _envelope_fit(P, x, h, c, degree, points, teeth, phase_degree)
    xe = x + np.linalg.lstsq(np.eye(len(x)) - J, E - x, rcond=None)[0]
    return _envelope_fit(P, xe, h, c, degree, points, teeth, phase_degree)[0]


def _envelope_fit(P, x, h, c, degree, points, teeth, phase_degree):
    """(DE(x), E(x)) from one fit over the m lines through x (see ENVELOPE_C above)."""
    m = x.shape[0]
    eye = np.eye(m)
    floor = 1e-3 * (1.0 + float(np.max(np.abs(x))))
    w0 = c * np.maximum(np.abs(x), floor)
    dt = np.array([(P(x + w0[j] * eye[j])[1] - P(x - w0[j] * eye[j])[1]) / (2 * w0[j]) for j in range(m)])
    w = np.minimum(w0, teeth * h / (2 * np.maximum(np.abs(dt), 1e-300)))
    D = np.diag(w)
    big = int(np.argmax(np.abs(dt) * w))                      # the line along which t moves most
    sweep = 2 * np.abs(dt) * w                                 # t's range along each line
    if sweep[big] >= 2 * h:
        for j in range(m):
            if j != big and sweep[j] < teeth * h:
                D[big, j] = np.copysign((teeth * h - sweep[j]) / sweep[big] * w[big], dt[j] * dt[big])
    s = np.linspace(-1.0, 1.0, int(points))
    F, phases = [], []
    for j in range(m):
        for si in s:
            y, t = P(x + si * D[:, j])
            times = np.atleast_1d(P.last_impact_times if hasattr(P, "last_impact_times") else t)
            F.append(y)
            phases.append(times / h)
    if len({len(p) for p in phases}) != 1:
        raise RuntimeError("envelope Jacobian: the samples around the orbit differ in their number of impacts")
    F, phases = np.array(F), np.array(phases)                  # (m * points, m), (m * points, impacts)
    steps = np.floor(phases)
    theta = phases - steps
    degree, L = int(degree), int(phase_degree)
    line = np.repeat(np.arange(m), len(s))
    S = np.tile(s, m)
    cols = [np.ones_like(S)]
    for j in range(m):                                         # per-line polynomial, s^1 .. s^degree
        cols += [np.where(line == j, S ** k, 0.0) for k in range(1, degree + 1)]
    for i in range(theta.shape[1]):
        if np.ptp(steps[:, i]) < 2:                            # this impact's phase does not sweep the sawtooth
            continue
        B = [np.polynomial.legendre.legval(2 * theta[:, i] - 1, [0] * l + [1]) for l in range(1, L + 1)]
        cols += B
        for j in range(m):
            if np.ptp(steps[line == j, i]) >= 2:
                cols += [np.where(line == j, S * b, 0.0) for b in B]
    rw = np.tile((1.0 - s ** 2) ** 2, m)                       # sqrt of the weights (1 - s^2)^4
    A = np.array(cols).T
    coef = np.linalg.lstsq(A * rw[:, None], F * rw[:, None], rcond=None)[0]
    G = np.array([coef[1 + j * degree] for j in range(m)]).T   # column j: DE d_j
    return G @ np.linalg.inv(D), coef[0]


def check_step(h) -> float:
    """The step of a return map: a finite number >= MIN_H (vcirun.core.grid)."""
    h = check_number("h", h, gt=0)
    if h < MIN_H:
        raise ValueError(f"h: must be >= {MIN_H:g} (got {h:g}); smaller steps underflow the h**k terms of the "
                         "discrete Lagrangians")
    return h


def check_impacts(k) -> int:
    """k, the impacts on the section per return: a positive integer (k = 0 would accept the first
    state as its own return and let the search span grow without end)."""
    if isinstance(k, (bool, np.bool_)):
        raise ValueError(f"k: must be a positive integer, the impacts per period (got {k!r})")
    return int(check_number("k", k, ge=1, le=MAX_IMPACTS_PER_PERIOD, integer=True))


# k of a period-k orbit: each return runs until the k-th impact, every Newton step evaluates the
# map 4 (2 m) + 1 times
MAX_IMPACTS_PER_PERIOD = 10_000


def _section_index(section, sysm, names) -> int:
    if section is None:
        if sysm is None:
            return 0
        for i, c in enumerate(sysm.constraints):
            if c.reset_q is not None or c.reset_qd is not None:
                return i
        return 0
    if isinstance(section, (int, np.integer)) and not isinstance(section, bool):
        if names is not None and not 0 <= int(section) < len(names):
            raise ValueError(f"section: constraint index {section} out of range (0..{len(names) - 1})")
        return int(section)
    if names is None or section not in names:
        raise ValueError(f"section: {section!r} is not a constraint name (declared: {', '.join(names or [])})")
    return names.index(section)


def default_guess(system, params=None):
    """(q, p) of a scene's default state (its velocities kept under parameter overrides), the guess of
    periodic_orbit without one; ValueError naming `guess` if the system has none."""
    s = resolve_system(system) if isinstance(system, str) else system
    if getattr(s, "default_q0", None) is None:
        raise ValueError(f"guess: system {s.name} has no default state; give guess=(q, p)")
    q = np.asarray(s.default_q0, float)
    if params:
        v = np.linalg.solve(s.mass_matrix(q), s.default_p0)
        return q, s.mass_matrix(q, s.param_values(params)) @ v
    return q, np.asarray(s.default_p0, float)


def periodic_orbit(system, method, *, h=None, guess=None, section=None, k=1, params=None, tol=1e-12, maxit=None,
                   fd_step=None, solver="newton", jacobian=None, **options) -> PeriodicOrbit:
    """A fixed point of the return map of `method` at step h on `section` (a constraint's impact, just
    after its reset), from guess = (q, p) or the flat state (default: the scene's default state, e.g.
    the built-in walkers' gaits). k: impacts per return (2: a period-two
    orbit). method "reference": the exact return map (vcirun.reference_solution.stride.ReferenceReturnMap; no h;
    its options path, rtol, T_max), the orbit every method's converges to.

    solver "newton" (default): Newton on P(x) - x = 0 with the finite-difference Jacobian (module
    docstring), at most maxit (30) steps; converged when the step is below tol (1 + |x|), else
    RuntimeError. solver "iterate": the gait as simulated, for a stable orbit of a map that is not
    smooth in x -- VCI's stride map jumps by O(h^2) where the impact time crosses a grid point
    (R^VCI's energy target is the discrete energy of the partial step that reached the impact), so
    Newton's fixed point need not exist. x <- P(x) until successive returns differ by tol (1 + |x|),
    or for maxit (400) returns; the last return is the fixed point and `residual` says how far the
    iteration still moves (the map's jump size where it settles on a cycle across a jump). It returns
    the orbit only if its multipliers (|.| < 1) say it is stable, else RuntimeError.

    jacobian: default "envelope" with solver "iterate" on a method with a step h, else "fd".
    "envelope": the Jacobian of the map's smooth envelope at the envelope's fixed point, from
    least-squares fits that model the O(h^2) sawtooth in the impact phase (envelope_jacobian; 812
    evaluations of the map on the wheel, 1624 on the compass gait: ~0.3 s and ~1 s); VCI's
    multipliers then converge at order 2 (wheel: -0.72 h^2 from the closed form at every h = 0.02 ..
    6.25e-4), docs/walkers.md. "fd": the finite-difference Jacobian above; with solver "iterate" the
    derivative of the smooth piece of the map the gait settles on (ReturnMap.piece_jacobian, fd_step
    1e-6 by default; one-sided where the central stencil would cross a jump; VCI: order 1)."""
    if solver not in ("newton", "iterate"):
        raise ValueError(f"solver: {solver!r} is not 'newton' or 'iterate'")
    k = check_impacts(k)
    tol = check_number("tol", tol, gt=0, lt=1)
    if maxit is not None:
        maxit = check_number("maxit", maxit, ge=1, le=100_000, integer=True)
    if fd_step is not None:
        fd_step = check_number("fd_step", fd_step, gt=0, lt=1)
    if h is not None:
        h = check_step(h)
    # The stability of the gait of a map with O(h^2) jumps is that of its smooth envelope: a difference
    # quotient of the map across a jump is O(h^2) / delta (at fd_step 1e-6 it can say -16 for VCI's
    # wheel multiplier 0.5, h = 1.77e-3), its derivative on one piece is off by an O(h) slope, and the
    # iteration's successive differences say nothing once they are the size of the jumps (or when the
    # guess is already on the gait). The envelope Jacobian models the jumps and converges at order 2
    # at every h, so "iterate" decides with it unless "fd" is asked for.
    if jacobian is None:
        jacobian = "envelope" if solver == "iterate" and method != "reference" else "fd"
    if jacobian not in ("fd", "envelope"):
        raise ValueError(f"jacobian: {jacobian!r} is not 'fd' or 'envelope'")
    if jacobian == "envelope" and (solver != "iterate" or method == "reference"):
        raise ValueError("jacobian: 'envelope' needs solver 'iterate' and a method with a step h")
    if guess is None:
        guess = default_guess(system, params)
    try:
        if isinstance(guess, (tuple, list)) and len(guess) == 2 and np.ndim(guess[0]) == 1:
            x = np.concatenate([np.asarray(guess[0], float), np.asarray(guess[1], float)])
        else:
            x = np.asarray(guess, float).ravel().copy()
    except (TypeError, ValueError):
        raise ValueError(f"guess: must be (q, p) or the flat state, numbers (got {describe(guess)})") from None
    if not np.all(np.isfinite(x)):
        raise ValueError(f"guess: must be finite numbers (got {describe(guess)})")
    if method == "reference":
        if h is not None:
            raise ValueError("h: the exact return map (method 'reference') has no step; drop h")
        options.pop("tier", None)   # (the exact map's system kernels: compiled)
        P = ReferenceReturnMap(system, section=section, k=k, params=params, **options)
    elif h is None:
        raise ValueError(f"h: the return map of {method} needs a step h")
    else:
        P = ReturnMap(system, method, h=h, section=section, k=k, params=params, **options)
    if x.shape != (2 * P.n,):
        raise ValueError(f"guess: must be (q, p) with {P.n} entries each, or {2 * P.n} numbers (got {x.shape})")
    if fd_step is None:
        fd_step = 1e-6 if solver == "iterate" else FD_STEP if method == "reference" else METHOD_FD_STEP
    x, _ = P(x)   # onto the section
    if solver == "iterate":
        return _iterate(P, x, tol, 400 if maxit is None else int(maxit), fd_step, method, h, k, params, jacobian)
    maxit = 30 if maxit is None else int(maxit)
    it = 0
    step = np.inf
    while it < maxit:
        it += 1
        Px, _ = P(x)
        J = P.jacobian(x, fd_step)
        dx = np.linalg.lstsq(J - np.eye(len(x)), -(Px - x), rcond=None)[0]
        x = x + dx
        step = float(np.max(np.abs(dx)))
        if step <= tol * (1.0 + float(np.max(np.abs(x)))):
            break
    if not step <= max(tol, 1e-9) * (1.0 + float(np.max(np.abs(x)))):
        raise RuntimeError(f"periodic_orbit: Newton did not converge in {maxit} iterations (last step {step:.3g})")
    return _orbit(P, x, fd_step, it, method, h, k, params)


def _orbit(P, x, fd_step, it, method, h, k, params, jacobian="fd", piece=False) -> PeriodicOrbit:
    """The PeriodicOrbit at x: its return, period, Jacobian and multipliers (|.| descending); piece:
    the finite-difference Jacobian of the map's smooth piece at x (ReturnMap.piece_jacobian)."""
    Px, period = P(x)
    if jacobian == "envelope":
        J = envelope_jacobian(P, x, h)
    elif piece and isinstance(P, ReturnMap):
        J = P.piece_jacobian(x, fd_step)
    else:
        J = P.jacobian(x, fd_step)
    ev = np.linalg.eigvals(J)
    ev = ev[np.argsort(-np.abs(ev), kind="stable")]
    n = P.n
    return PeriodicOrbit((x[:n].copy(), x[n:].copy()), period, ev, J, float(np.max(np.abs(Px - x))), it,
                         str(method), float("nan") if h is None else float(h), int(k), dict(params or {}), jacobian)


def _iterate(P, x, tol, maxit, fd_step, method, h, k, params, jacobian="fd") -> PeriodicOrbit:
    """periodic_orbit's solver "iterate" (see there)."""
    it = 0
    while it < maxit:
        it += 1
        Px, _ = P(x)
        move = float(np.max(np.abs(Px - x)))
        x = Px
        if move <= tol * (1.0 + float(np.max(np.abs(x)))):
            break
    orb = _orbit(P, x, fd_step, it, method, h, k, params, jacobian, piece=True)
    if not orb.stable:
        raise RuntimeError(f"periodic_orbit: solver 'iterate' settled on no stable orbit (multiplier "
                           f"{orb.eigenvalues[0]:.4g} after {it} returns); use solver 'newton'")
    return orb
