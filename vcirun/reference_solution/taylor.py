"""The exact reference's Taylor path: heyoka integrators built from the symbolic system.

heyoka (Taylor's method, compiled by LLVM) finds the events of a step by isolating the real roots of
each event function's Taylor polynomial over the step, so a sign change inside a step, a dip below a
surface shorter than any step, cannot be missed; its tolerance is machine precision (eps).

Equations (state y = (q, p), and W = int f . qdot as a last component for a forced system), with
v = M^-1 p, F = -dH/dq + f(q, v, t) = 1/2 v^T dM/dq v - dV/dq + f and, for a held set A (rows G_A of
grad phi_i, i in A), the index-reduced dynamics of vcirun.reference_solution.held:

    qdot = v,   pdot = F + G_A^T mu,   W_A mu = -(G_A M^-1 F + kappa_A),   W_A = G_A M^-1 G_A^T,

kappa_i = d u_i / dq . v (u_i = grad phi_i . M^-1 p): d u_A / dt = 0 along the flow. M^-1 is explicit:
1 / M_ii for a diagonal M, the adjugate over the determinant for n <= MAX_DENSE_N, runtime parameters
(numbers at the parameter values) for a constant M of any size; W_A^-1 likewise for |A| <= MAX_HELD.
A system beyond that (or with abs() or another function heyoka cannot differentiate) is not
expressible here: `TaylorModel.expressible()` says why, and the reference takes its DOP853 path.

Events of the integrator for the held set A and the resting set R (contacts on their surface at rest,
not held), all terminal:
    impact_i  (i not in A): phi_i + par[off_i] crosses 0 downwards; off_i = TINY, or a small offset
              for a contact of R (its phi is round-off of either sign; the root phi_i = 0 is then
              refined on the dense output);
    release_i (i in A): mu_i crosses 0 downwards;
    pressed_i (i in R): its normal acceleration along the flow, plus held.press_level at the
              segment's start, crosses 0 downwards: pushed in beyond round-off, as the loop's own
              test at a segment's start and the force LCP of held_set see it (an acceleration of
              round-off, as between identical pendulums swinging in unison, is no event);
    lift_i    (i in R): phi_i - par[lift_i] crosses 0 upwards (it has left: the next segment watches
              it with offset 0).
With Coulomb friction the held set carries its modes S (vcirun.reference_solution.coulomb): the held
dynamics take the rows and force directions of the modes (sliding: G_i - mu_i s W_t,i; sticking: the
slip row W_t,i as a further held row, kappa from d(W_t,i v)/dq . v), and the events
    stick_i   (i sliding with sign s): its slip velocity W_t,i v crosses 0 against s;
    slip_i    (i sticking): mu_s,i lam_n,i -+ lam_t,i crosses 0 downwards (the static cone reached);
    painleve  (some contact sliding): det K of the held rows crosses 0 downwards.
The held rows (normal and sticking) count against MAX_HELD.
Parameters: the system's, then off_i (m), lift_i (m), the pressed offsets (m), then M^-1 entries for
a constant dense M.

Integrators are kept per process (`taylor_model` keeps one TaylorModel per system fingerprint, which
keeps its integrators by A, R and tolerance; a forked sweep worker inherits them); heyoka's own disk
cache of compiled code (~/.cache/heyoka) lets a new process skip the LLVM build.
No sympy at import: the builder imports it (and heyoka, which imports sympy) inside functions.
"""
from __future__ import annotations

import math
import re

import numpy as np

from . import held as rh
from .flight import Constant, Flight, last_crossing
from .resets import declared_resets

__all__ = ["TaylorModel", "TaylorPiece", "TaylorBackend", "NotExpressible", "TaylorFailure", "taylor_model", "TOL",
           "TINY", "REACH", "REST_TOL", "MAX_DENSE_N", "MAX_HELD"]

TOL = float(np.finfo(float).eps)   # the reference's tolerance: machine precision
# heyoka skips the roots of a step whose event function is exactly 0 at the step's start (a start on
# the surface, phi(q0) = 0.0, leaving it: the return would be missed): every impact and pressed event
# function carries at least this offset, which moves no root by a representable amount
TINY = 1e-300
REACH = 4.0   # the first step of a segment: at most this many times the free contacts' approach time
REST_TOL = 1e-12   # relative: on the surface at rest (vcirun.reference_solution.held's criterion) at this precision
MAX_DENSE_N = 3                    # explicit adjugate inverse of a q-dependent M up to this size
MAX_HELD = 3                       # explicit W_A^-1 up to this many held contacts
_EPS = float(np.finfo(float).eps)


class NotExpressible(Exception):
    """The system (or a held set met during the solve) has no explicit Taylor form here; the message
    says why (the reference then takes its DOP853 path)."""


class TaylorFailure(RuntimeError):
    """The Taylor integrator could not go on (a non-finite state or step: an initial state so large
    that the Taylor coefficients overflow); the reference then tries its DOP853 path."""


# --- dense output --------------------------------------------------------------------------------

class TaylorPiece:
    """Dense output of one segment: the Taylor polynomials of its steps (heyoka's tc), called like an
    OdeSolution: y(t) of shape (width,) for a scalar t, (width, len(t)) for an array."""

    def __init__(self, starts, tcs, t_end):
        self.starts = np.asarray(starts, float)
        self.tcs = np.asarray(tcs, float)    # (steps, width, order + 1)
        self.t_end = float(t_end)

    def __call__(self, t):
        scalar = np.ndim(t) == 0
        ts = np.atleast_1d(np.asarray(t, float)).ravel()
        k = np.clip(np.searchsorted(self.starts, ts, side="right") - 1, 0, len(self.starts) - 1)
        tau = ts - self.starts[k]
        V = tau[:, None] ** np.arange(self.tcs.shape[2])   # the powers of tau
        out = np.einsum("qwj,qj->wq", self.tcs[k], V)
        return out[:, 0] if scalar else out


# --- the symbolic build ----------------------------------------------------------------------------

_QUIET = []


def _hy():
    import heyoka as hy  # here: heyoka imports sympy, and `import vcirun.reference_solution` stays light

    if not _QUIET:
        # heyoka logs a warning when its root isolation in a step gives up or meets a domain error
        # (seen on the tiny hops before an accumulation, whose roots it still reports); a root it does
        # not report is caught by the segment's penetration check and by the accuracy check's second
        # solve, so the warnings would only be noise on stderr
        hy.set_logger_level_error()
        _QUIET.append(True)
    return hy


def _det_adj(Mx):
    """(det, adjugate) of a small square matrix of heyoka expressions by cofactors."""
    k = len(Mx)
    if k == 1:
        return Mx[0][0], [[1.0]]
    if k == 2:
        a, b, c, d = Mx[0][0], Mx[0][1], Mx[1][0], Mx[1][1]
        return a * d - b * c, [[d, -b], [-c, a]]

    def minor(i, j):
        return [[Mx[r][s] for s in range(k) if s != j] for r in range(k) if r != i]

    cof = [[None] * k for _ in range(k)]
    for i in range(k):
        for j in range(k):
            d, _ = _det_adj(minor(i, j))
            cof[i][j] = d if (i + j) % 2 == 0 else -d
    det = sum(Mx[0][j] * cof[0][j] for j in range(k))
    return det, [[cof[j][i] for j in range(k)] for i in range(k)]


def _inverse(Mx):
    det, adj = _det_adj(Mx)
    k = len(Mx)
    return [[adj[i][j] / det for j in range(k)] for i in range(k)]


class TaylorModel:
    """heyoka's form of one MechanicalSystem: expressions, parameter layout and the integrators for
    each held set A and resting set R. Build with `taylor_model(system)` (one per system and process)."""

    def __init__(self, system):
        self.system = system
        self.n, self.m = int(system.n), int(system.m)
        self.np = len(system.params)
        self.forced = bool(system.is_forced)
        self.reason = None
        self._integrators = {}
        self._held = {}
        try:
            self._build()
        except NotExpressible as e:
            self.reason = str(e)
        except (TypeError, ValueError, NotImplementedError) as e:  # heyoka cannot convert a function
            self.reason = f"heyoka cannot express the system ({' '.join(str(e).split())[:200]})"

    def expressible(self) -> str | None:
        """None if the Taylor path can integrate this system, else the reason it cannot."""
        return self.reason

    # the parameter vector of the integrators
    @property
    def off0(self) -> int:
        return self.np

    @property
    def lift0(self) -> int:
        return self.np + self.m

    @property
    def press0(self) -> int:
        return self.np + 2 * self.m

    @property
    def minv0(self) -> int:
        return self.np + 3 * self.m

    @property
    def stick0(self) -> int:
        return self.minv0 + (self.n * self.n if self.minv_par else 0)

    def pars(self, prm, off=None, lift=None, press=None, stick=None):
        """The integrators' parameter vector: the system's parameters, the impact offsets (TINY, or a
        resting contact's round-off offset), the lift-off levels and the pressed-event offsets (TINY,
        or a resting contact's round-off level of its normal acceleration), the M^-1 entries of a
        constant dense M, and with friction the stick-event offsets (TINY, or the round-off level of the
        slip velocity of a slip that starts from rest: vcirun.reference_solution.coulomb.stick_offsets)."""
        out = np.zeros(self.stick0 + (self.m if self.system.has_friction else 0))
        out[: self.np] = prm
        out[self.off0: self.lift0] = TINY if off is None else off
        out[self.lift0: self.press0] = 1e300 if lift is None else lift
        out[self.press0: self.minv0] = TINY if press is None else press
        if self.minv_par:
            out[self.minv0:self.stick0] = np.linalg.inv(self.system.mass_matrix(np.zeros(self.n), prm)).ravel()
        if self.system.has_friction:
            out[self.stick0:] = TINY if stick is None else stick
        return out

    def _build(self):
        import sympy as sp

        hy = _hy()
        s, n, m = self.system, self.n, self.m
        # a guarded constraint (when: w(q) > 0) is followed on its surface, with its guard as an event
        # of its own (vcirun.reference_solution.resets)
        surfaces = [c.surface if c.when is not None else c.phi for c in s.constraints]
        for c, phi in zip(s.constraints, surfaces):
            if phi.has(sp.Abs, sp.Min, sp.Max, sp.Piecewise, sp.sign, sp.Heaviside):
                raise NotExpressible(f"constraint {c.name} is not smooth (abs, min, max or a piecewise form)")
        for what, ex in (("mass_matrix", s.M), ("potential", sp.Matrix([s.V])),
                         ("forcing", s.forcing if s.forcing is not None else sp.Matrix([0]))):
            if any(e.has(sp.Abs, sp.Min, sp.Max, sp.Piecewise, sp.sign, sp.Heaviside) for e in ex):
                raise NotExpressible(f"{what} is not smooth (abs, min, max or a piecewise form)")
        names = [f"q{i}" for i in range(n)] + [f"p{i}" for i in range(n)] + (["W"] if self.forced else [])
        self.vars = list(hy.make_vars(*names))
        qv, pv = self.vars[:n], self.vars[n:2 * n]
        smap = {s.q[i]: qv[i] for i in range(n)}
        smap |= {sp.Symbol(k): hy.par[j] for j, k in enumerate(s.params)}

        def floats(e):
            # heyoka takes exact rationals only with a power-of-2 denominator (1/2, 3/4): others as floats
            bad = {r: sp.Float(r, 17) for r in e.atoms(sp.Rational) if r.q & (r.q - 1)}
            return e.xreplace(bad) if bad else e

        def conv(e, table=smap):
            e = floats(sp.sympify(e))
            return hy.from_sympy(e, {k: v for k, v in table.items() if k in e.free_symbols}) if e.free_symbols \
                else hy.expression(float(e))

        M = s.M
        qset = set(s.q)
        const = not any(M[i, j].free_symbols & qset for i in range(n) for j in range(n))
        diag = all(M[i, j] == 0 for i in range(n) for j in range(n) if i != j)
        self.minv_par = False
        if diag:
            Minv = [[(1.0 / conv(M[i, i]) if i == j else hy.expression(0.0)) for j in range(n)] for i in range(n)]
        elif const:
            self.minv_par = True
            Minv = [[hy.par[self.minv0 + i * n + j] for j in range(n)] for i in range(n)]
        elif n <= MAX_DENSE_N:
            Minv = _inverse([[conv(M[i, j]) for j in range(n)] for i in range(n)])
        else:
            raise NotExpressible(f"the mass matrix is {n}x{n}, not diagonal and depends on the coordinates: "
                                 f"no explicit inverse (the Taylor path takes n <= {MAX_DENSE_N} or a constant "
                                 "or diagonal M)")
        self.Minv = Minv
        v = [hy.sum([Minv[i][j] * pv[j] for j in range(n)]) for i in range(n)]
        self.v = v
        dV = [conv(sp.diff(s.V, q)) for q in s.q]
        F = []
        for k, q in enumerate(s.q):
            dM = [[sp.diff(M[i, j], q) for j in range(n)] for i in range(n)]
            quad = [conv(dM[i][j]) * v[i] * v[j] for i in range(n) for j in range(n) if dM[i][j] != 0]
            F.append((0.5 * hy.sum(quad) if quad else hy.expression(0.0)) - dV[k])
        if self.forced:
            fmap = dict(smap) | {s.qd[i]: v[i] for i in range(n)} | {s.t: hy.time}
            f = [conv(e, fmap) for e in s.forcing]
            F = [F[i] + f[i] for i in range(n)]
            self.power = hy.sum([f[i] * v[i] for i in range(n)])
        self.F = F
        self.phi = [conv(phi) for phi in surfaces]
        self.when = [conv(c.when) if c.when is not None else None for c in s.constraints]
        G = sp.Matrix([[sp.diff(phi, q) for q in s.q] for phi in surfaces])
        self.G = [[conv(G[i, j]) for j in range(n)] for i in range(m)]
        self.u = [hy.sum([self.G[i][j] * v[j] for j in range(n)]) for i in range(m)]
        self.MinvF = [hy.sum([Minv[i][j] * F[j] for j in range(n)]) for i in range(n)]
        self._kappa = {}
        self._wkappa = {}
        if s.has_friction:   # the slip rows, slip velocities and coefficients (vcirun.reference_solution.coulomb)
            Wt = s.slip_matrix
            self.Wt = [[conv(Wt[i, j]) for j in range(n)] for i in range(m)]
            self.w = [hy.sum([self.Wt[i][j] * v[j] for j in range(n)]) for i in range(m)]
            mu, mus = s.friction_coefficients
            self.mu = [conv(x) for x in mu]
            self.mus = [conv(x) for x in mus]

    def kappa(self, i):
        """d u_i / dq . v (the velocity terms of d u_i / dt)."""
        if i not in self._kappa:
            hy = _hy()
            self._kappa[i] = hy.sum([hy.diff(self.u[i], self.vars[j]) * self.v[j] for j in range(self.n)])
        return self._kappa[i]

    def wkappa(self, i):
        """d (W_t,i v) / dq . v (the velocity terms of the slip acceleration of contact i)."""
        if i not in self._wkappa:
            hy = _hy()
            self._wkappa[i] = hy.sum([hy.diff(self.w[i], self.vars[j]) * self.v[j] for j in range(self.n)])
        return self._wkappa[i]

    def frictional_dynamics(self, A, S):
        """(pdot (n), lam (the held rows: the normal forces of A, then the tangential forces of its
        sticking contacts), det K) of the held set A in the friction modes S as heyoka expressions."""
        key = (tuple(A), tuple(S))
        if key in self._held:
            return self._held[key]
        hy = _hy()
        n = self.n
        stick = [i for i, s in zip(A, S) if s == rh.STICK]
        if len(A) + len(stick) > MAX_HELD:
            raise NotExpressible(f"{len(A) + len(stick)} held rows (contacts held with sticking friction) together: "
                                 f"no explicit inverse (the Taylor path holds up to {MAX_HELD})")
        C = [self.G[i] for i in A] + [self.Wt[i] for i in stick]
        D = []
        for i, s in zip(A, S):
            if s in (1, -1):
                D.append([self.G[i][j] - self.mu[i] * float(s) * self.Wt[i][j] for j in range(n)])
            else:
                D.append(self.G[i])
        D += [self.Wt[i] for i in stick]
        k = len(C)
        X = [[hy.sum([self.Minv[j][l] * D[r][l] for l in range(n)]) for r in range(k)] for j in range(n)]
        K = [[hy.sum([C[r][j] * X[j][c] for j in range(n)]) for c in range(k)] for r in range(k)]
        kap = [self.kappa(i) for i in A] + [self.wkappa(i) for i in stick]
        b = [hy.sum([C[r][j] * self.MinvF[j] for j in range(n)]) + kap[r] for r in range(k)]
        det, adj = _det_adj(K)
        lam = [-hy.sum([adj[r][c] * b[c] for c in range(k)]) / det for r in range(k)]
        pdot = [self.F[j] + hy.sum([D[r][j] * lam[r] for r in range(k)]) for j in range(n)]
        self._held[key] = (pdot, lam, det)
        return self._held[key]

    def held_dynamics(self, A):
        """(pdot (n), mu (|A|)) of the held set A as heyoka expressions."""
        A = tuple(A)
        if A in self._held:
            return self._held[A]
        hy = _hy()
        n = self.n
        if not A:
            out = (list(self.F), [])
        else:
            if len(A) > MAX_HELD:
                raise NotExpressible(f"{len(A)} contacts held together: no explicit inverse of their "
                                     f"{len(A)}x{len(A)} Delassus matrix (the Taylor path holds up to {MAX_HELD})")
            X = [[hy.sum([self.Minv[j][k] * self.G[a][k] for k in range(n)]) for a in A] for j in range(n)]
            W = [[hy.sum([self.G[a][j] * X[j][bi] for j in range(n)]) for bi in range(len(A))] for a in A]
            b = [hy.sum([self.G[a][j] * self.MinvF[j] for j in range(n)]) + self.kappa(a) for a in A]
            Wi = _inverse(W)
            mu = [-hy.sum([Wi[r][c] * b[c] for c in range(len(A))]) for r in range(len(A))]
            pdot = [self.F[j] + hy.sum([self.G[a][j] * mu[r] for r, a in enumerate(A)]) for j in range(n)]
            out = (pdot, mu)
        self._held[A] = out
        return out

    def normal_acceleration(self, i, pdot):
        """d u_i / dt along the flow with momentum rate pdot."""
        hy = _hy()
        n = self.n
        Mp = [hy.sum([self.Minv[j][k] * pdot[k] for k in range(n)]) for j in range(n)]
        return self.kappa(i) + hy.sum([self.G[i][j] * Mp[j] for j in range(n)])

    def integrator(self, A=(), R=(), tol=TOL, S=None):
        """The heyoka integrator of the held set A (in the friction modes S, None: frictionless) with the
        resting set R (kept per process) and its event kinds [(kind, contact)] in heyoka's event order."""
        fric = rh._frictional(S)
        key = (tuple(A), tuple(R), float(tol)) + ((tuple(S),) if fric else ())
        if key in self._integrators:
            return self._integrators[key]
        if self.reason is not None:
            raise NotExpressible(self.reason)
        hy = _hy()
        n, m = self.n, self.m
        if fric:
            pdot, mu, det = self.frictional_dynamics(A, S)
        else:
            pdot, mu = self.held_dynamics(A)
        eqs = [(self.vars[i], self.v[i]) for i in range(n)] + [(self.vars[n + i], pdot[i]) for i in range(n)]
        if self.forced:
            eqs.append((self.vars[2 * n], self.power))
        neg, pos = hy.event_direction.negative, hy.event_direction.positive
        events, kinds = [], []

        def add(expr, direction, kind):
            # an event function constant along the segment (no state, no time: e.g. the force of a
            # contact holding a body at rest under gravity) never crosses 0 there; heyoka refuses it
            if hy.get_variables(expr) or re.search(r"\bt\b", str(expr)):
                events.append(hy.t_event(expr, direction=direction))
                kinds.append(kind)

        for i in range(m):
            if i in A:
                add(mu[A.index(i)], neg, ("release", i))
            else:
                add(self.phi[i] + hy.par[self.off0 + i], neg, ("impact", i))
                if self.when[i] is not None:
                    add(self.when[i], pos, ("arm", i))
        for i in R:
            add(self.normal_acceleration(i, pdot) + hy.par[self.press0 + i], neg, ("pressed", i))
            add(self.phi[i] - hy.par[self.lift0 + i], pos, ("lift", i))
        if fric:
            rows = len(A)
            for a, (i, s) in enumerate(zip(A, S)):
                if s in (1, -1):
                    add(float(s) * self.w[i] + hy.par[self.stick0 + i], neg, ("stick", i))
                elif s == rh.STICK:
                    add(self.mus[i] * mu[a] - mu[rows], neg, ("slip", i))
                    add(self.mus[i] * mu[a] + mu[rows], neg, ("slip", i))
                    rows += 1
            if any(s in (1, -1) for s in S):
                add(det, neg, ("painleve", next(i for i, s in zip(A, S) if s in (1, -1))))
        # pars left to heyoka: as many as the highest index used (a prefix of the layout of `pars`)
        ta = hy.taylor_adaptive(eqs, np.zeros(len(eqs)), tol=float(tol), compact_mode=len(eqs) > 12,
                                **({"t_events": events} if events else {}))
        self._integrators[key] = (ta, kinds)
        return ta, kinds


_MODELS: dict = {}


def taylor_model(system) -> TaylorModel:
    """The TaylorModel of a system, built once per process (by the system's fingerprint)."""
    key = (system.fingerprint(), system.name)
    if key not in _MODELS:
        _MODELS[key] = TaylorModel(system)
    return _MODELS[key]


# --- one segment -------------------------------------------------------------------------------------

class TaylorBackend:
    """Segments of the exact solve on heyoka's integrators (see vcirun.reference_solution.loop.solve): from (t0, y0)
    on the dynamics of the held set A with the resting set R until the first event or T."""

    kind = "taylor"
    rest_tol = REST_TOL

    def __init__(self, model: TaylorModel, mod, prm, tol=TOL, budget=None):
        self.model, self.mod, self.prm, self.tol = model, mod, np.asarray(prm, float), float(tol)
        self.budget = budget
        self.steps = 0
        self._base = model.pars(self.prm)   # the parameter vector without resting contacts
        self._pars_of = {}                  # id(integrator) -> what its parameters were last set to
        self.resets = declared_resets(model.system, mod, self.prm)   # guards and the declared map, or None

    def segment(self, t0, y0, T, A, R, geo=None, S=None):
        """One segment (vcirun.reference_solution.flight); geo: the _Geometry at (t0, y0) if the caller has it.

        The first step is at most REACH times the approach time of the free contacts (a hop after an
        impact, a contact about to be reached), each next bound twice the last: heyoka's root isolation
        works on polynomials whose roots are not crowded into a tiny fraction of the step (measured: a
        Zeno hop of 6e-6 s inside a step of 3 s made it give up, with a warning only). As a safety net,
        a step that ends with a free contact below its surface (a root the step did not report) is
        taken again at a quarter of its length."""
        hy = _hy()
        model = self.model
        n, m = model.n, model.m
        A, R = tuple(A), tuple(R)
        ta, kinds = model.integrator(A, R, self.tol, S)
        g = geo if geo is not None else rh._Geometry(self.mod, t0, y0[:n], y0[n:2 * n], self.prm)
        scale = self._scales(g)
        phi0 = g.phis.tolist()
        free = [i for i in range(m) if i not in A and i not in R]
        hmax = max(REACH * rh.approach_time(g, A, free), 1e3 * _EPS * max(1.0, abs(t0)))
        floor = [-scale[i] for i in range(m)]   # penetration beyond round-off
        key = ("base",)
        off = lift = press = stick = None
        if R:   # offsets above the resting contacts' own |phi| (within the rest tolerance) and round-off
            off, lift, press = np.full(m, TINY), np.full(m, 1e300), np.full(m, TINY)
            press_level = rh.press_level(g, self.rest_tol)
            for i in R:
                off[i] = 4.0 * (abs(phi0[i]) + scale[i])
                lift[i] = floor[i] = 2.0 * off[i]
                floor[i] = -floor[i]
                press[i] = press_level
            key = (tuple(off), tuple(lift), tuple(press))
        if rh._frictional(S):
            from .coulomb import stick_offsets

            if len(g.forces(A, S).K) < len(A) + sum(1 for s in S if s == rh.STICK):
                raise NotExpressible("sticking contacts whose slip rows depend on each other (statically "
                                     "indeterminate friction): no explicit held dynamics on the Taylor path")
            stick_off = stick_offsets(g, A, S)
            if stick_off:
                stick = np.full(m, TINY)
                for i, v in stick_off.items():
                    stick[i] = v
                key = key + (tuple(stick),)
        if self._pars_of.get(id(ta)) != key:   # (parameters set by the last segment on ta are kept)
            pars = model.pars(self.prm, off, lift, press, stick) if key != ("base",) else self._base
            ta.pars[:] = pars[:len(ta.pars)]
            self._pars_of[id(ta)] = key
        ta.time = float(t0)
        ta.state[:] = y0
        if kinds:
            ta.reset_cooldowns()
        starts, tcs = [], []
        ev, retries = None, 0
        nev = len(kinds)
        outcomes = (hy.taylor_outcome.time_limit, hy.taylor_outcome.success, hy.taylor_outcome.cb_stop)
        phis = np.empty(m)
        wl = [(i, floor[i]) for i in range(m) if i not in A]
        sys_phis, prm = self.mod.sys_phis, self.prm
        rec = _Recorder(self)
        bounded = True
        while ta.time < T and ev is None:
            ts = ta.time
            rec.reset(ts)
            if bounded and hmax < T - ts:   # a short first step (after an impact, near a surface)
                oc, h = ta.step(max_delta_t=hmax, write_tc=True)
                rec(ta)
                bounded = h >= hmax * (1.0 - 1e-9)   # still held back by the bound: the next is bounded too
                hmax *= 2.0
            else:                            # the rest in heyoka's own loop, recording every step
                oc = ta.propagate_until(T, callback=rec, write_tc=True)[0]
            self.steps += len(rec.ends)
            code = int(oc)
            if not (oc in outcomes or -nev <= code <= -1):
                raise TaylorFailure(f"the Taylor integrator stopped after t={rec.ends[-1] if rec.ends else ts:.17g} "
                                    f"({str(oc).split('.')[-1]}: its coefficients or step overflowed)")
            if self.budget is not None:
                self.budget.charge(self.steps, ta.time)
            # a step that ended with a free contact inside its constraint hides a root it did not report
            k_bad = next((k for k, tc in enumerate(rec.tcs[1:] + [None])
                          if _inside(sys_phis, prm, n, ta.state if tc is None else tc[:, 0], phis, wl)), None)
            if k_bad is None:
                starts += rec.starts
                tcs += rec.tcs
                retries = 0
                if -nev <= code <= -1:
                    ev = kinds[-code - 1]
                    if self.resets is not None and ev[1] in self.resets.guarded:
                        if ev[0] == "arm":   # the guard arms (on or above the surface): no event
                            self.resets.check_arming(float(ta.time), np.array(ta.state, float), ev[1])
                            ev = None
                        elif ev[0] == "impact" and not self.resets.armed(ev[1], np.array(ta.state, float)):
                            ev = None        # the surface crossed where the guard is not armed: no event
                continue
            starts += rec.starts[:k_bad]
            tcs += rec.tcs[:k_bad]
            ys, tb = rec.tcs[k_bad][:, 0].copy(), rec.starts[k_bad]
            h = rec.ends[k_bad] - tb
            # a contact on its surface moving in at that step's start (the step before ended on its root):
            # the impact is there; otherwise the step again, shorter
            phi0 = np.empty(m)
            sys_phis(np.ascontiguousarray(ys[:n]), prm, phi0)
            u0 = rh._Geometry(self.mod, tb, ys[:n], ys[n:2 * n], prm).u
            ta.time, ta.state[:] = tb, ys
            if kinds:
                ta.reset_cooldowns()
            at = [i for i, _ in wl if i not in R and phi0[i] <= scale[i] and u0[i] < 0.0]
            if at:
                ev = ("impact", at[0])
                break
            retries += 1
            if retries > 60:
                raise RuntimeError(f"reference: the Taylor steps from t={tb:.17g} keep ending inside a constraint "
                                   "without an event")
            hmax, bounded = 0.3 * h, True
        t1 = float(ta.time) if ev is not None else float(T)
        y1 = np.array(ta.state, float)
        if ev is None and starts:   # a root exactly at T ends the last step without being reported
            self.mod.sys_phis(np.ascontiguousarray(y1[:n]), self.prm, phis)
            u1 = rh._Geometry(self.mod, t1, y1[:n], y1[n:2 * n], self.prm).u
            at = [i for i in free if abs(phis[i]) <= scale[i] and u1[i] < 0.0]
            if at:
                ev = ("impact", at[0])
        if not starts:
            return Flight(t0, t0, np.array(y0, float), ev[0] if ev else "end", ev[1] if ev else -1, Constant(y0))
        piece = TaylorPiece(starts, tcs, t1)
        if ev is None:
            return Flight(t0, t1, y1, "end", -1, piece)
        kind, i = ev
        if kind == "impact" and i in R:
            # the offset event fired at phi_i = -off_i: the impact is the root phi_i = 0 before it
            t1 = last_crossing(lambda s: self._phi(piece(s)[:n], i), t0, t1)
            y1 = piece(t1)
            piece.t_end = t1
        if kind == "stick" and stick is not None and stick[i] > TINY:
            # the offset event fired at s v_t = -off: the slip ends at the root s v_t = 0 before it
            sgn = S[A.index(i)]
            t1 = last_crossing(lambda s: sgn * self._slip(piece(s), i), t0, t1)
            y1 = piece(t1)
            piece.t_end = t1
        return Flight(t0, t1, y1, kind, i, piece)

    def _slip(self, y, i):
        n = self.model.n
        return float(rh._Geometry(self.mod, 0.0, y[:n], y[n:2 * n], self.prm).wt[i])

    def _scales(self, g):
        """Per contact: 1e3 eps (1 + |q| |grad phi_i|), well above the round-off of phi_i at the state
        of the _Geometry g."""
        qn = max(map(abs, g.q.tolist()), default=0.0)
        return [1e3 * _EPS * (1.0 + qn * max(map(abs, row), default=0.0)) for row in g.G.tolist()]

    def _phi(self, q, i):
        phis = np.empty(self.model.m)
        self.mod.sys_phis(np.ascontiguousarray(q, float), self.prm, phis)
        return phis[i]


class _Recorder:
    """heyoka's step callback: keeps each step's start time and Taylor coefficients; stops the
    propagation when the work budget would be exceeded (the caller then charges and raises)."""

    __slots__ = ("backend", "starts", "tcs", "ends", "_t")

    def __init__(self, backend):
        self.backend = backend
        self.reset(0.0)

    def reset(self, t0):
        self.starts, self.tcs, self.ends = [], [], []
        self._t = t0

    def __call__(self, ta):
        t = ta.time
        self.starts.append(self._t)
        self.tcs.append(ta.tc.copy())
        self.ends.append(t)
        self._t = t
        b = self.backend.budget
        return b is None or not b.exceeded(self.backend.steps + len(self.ends), t)


def _inside(sys_phis, prm, n, y, phis, wl) -> bool:
    """Some watched contact (index, floor) of wl is below its floor at the state y."""
    sys_phis(np.ascontiguousarray(y[:n]), prm, phis)
    return any(phis[i] < f for i, f in wl)


def order_of(tol) -> int:
    """heyoka's Taylor order at a tolerance (its rule: ceil(-ln(tol) / 2 + 1))."""
    return int(math.ceil(-math.log(tol) / 2 + 1))
