"""The exact reference's DOP853 path, for systems the Taylor path cannot express (vcirun.reference_solution.taylor).

scipy's DOP853 is stepped here one step at a time, and each step is checked on its dense output for
every watched function separately, at `samples` + 1 points:

- each contact i not held: a downward crossing of phi_i between two samples, a rise from just below
  the surface (right after an impact) followed by a crossing, and every local minimum of phi_i (its
  normal velocity u_i changes sign upwards between two samples) that lies below 0 -- a dip shorter
  than the sample spacing, the near-grazing impact that a sign test alone misses;
- each held contact: its force mu_i crossing 0 downwards (a release);
- each resting contact: its normal acceleration crossing 0 downwards (pushed in), and its phi_i below
  minus its round-off offset (it left and came back, by less than the offset; the root is refined);
- with friction (modes S of the held contacts, vcirun.reference_solution.coulomb): a sliding contact's slip
  velocity reaching 0 (stick), a sticking contact's tangential force reaching the static cone (slip),
  and det K of a held set with sliding contacts reaching 0 (painleve).

The step is bounded by the flight's own scales: no longer than `reach` times the time any contact
not held could need to reach its surface, (u + sqrt(u^2 + 2 |a| max(phi, 0))) / |a| (phi_i, u_i and
a_i its gap, normal velocity and normal acceleration, a_i taken towards the surface), so a free flight
whose polynomial motion DOP853's error estimate cannot see still steps onto each surface. Roots are
refined by brentq on the dense output. Held phases integrate the index-reduced dynamics
(vcirun.reference_solution.held.held_rhs) and stop for a projection when the constraints drift past drift_tol.
"""
from __future__ import annotations

import numpy as np

from . import held as rh
from .flight import Constant, Flight, last_crossing

__all__ = ["Dop853Backend", "step_off_surface", "rk4_step"]

_EPS = float(np.finfo(float).eps)


def rk4_step(f, t, y, dt):
    """One classical RK4 step (the solve_ivp baseline's escape micro step off the surface)."""
    k1 = f(t, y)
    k2 = f(t + dt / 2, y + dt / 2 * k1)
    k3 = f(t + dt / 2, y + dt / 2 * k2)
    k4 = f(t + dt, y + dt * k3)
    return y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def step_off_surface(rhs, phi, t, y, delta, tries=40):
    """(t + d, y(t + d)) by one RK4 micro step of length d <= delta to a state with phi > 0, halving d
    up to `tries` times; None if none is found (delta <= 0 or the motion stays on the surface).
    solve_ivp detects a crossing only from a start value >= 0, so a hop shorter than its first step
    would go unnoticed after a reset (phi ~ -1e-17): the solve_ivp baseline steps off first."""
    for _ in range(tries):
        if not delta > 0.0:
            return None
        y1 = rk4_step(rhs, t, y, delta)
        if phi(y1) > 0.0:
            return t + delta, y1
        delta *= 0.5
    return None


class Dop853Backend:
    """Segments of the exact solve on DOP853 at (rtol, atol) with per-contact checks (see the module)."""

    kind = "dop853"
    rest_tol = rh.HELD_TOL

    def __init__(self, mod, prm, rtol, atol, budget=None, samples=8, reach=2.0):
        self.mod, self.prm = mod, np.asarray(prm, float)
        self.rtol, self.atol, self.budget = float(rtol), float(atol), budget
        self.samples, self.reach = int(samples), float(reach)
        self.n, self.m = int(mod.NDOF), int(mod.NCON)
        self.forced = bool(mod.FORCED)
        self.nfev = 0
        self._buf = np.empty(2 * self.n)
        self.resets = None   # set by the caller for a system with declared resets or guards

    # --- the right-hand sides ----------------------------------------------------------------
    def _free_rhs(self, t, y):
        n, mod = self.n, self.mod
        mod.dynamics_rhs(t, y[:2 * n], self.prm, self._buf)
        if not self.forced:
            return self._buf.copy()
        return np.append(self._buf, mod.force_power(y[:n], self._buf[:n].copy(), t, self.prm))

    def _rhs(self, A, S=None):
        return self._free_rhs if not A else rh.held_rhs(self.mod, self.prm, A, S)

    # --- what is watched ---------------------------------------------------------------------
    def _phis_u(self, y):
        n = self.n
        q, p = np.ascontiguousarray(y[:n]), np.ascontiguousarray(y[n:2 * n])
        phis, G, out = np.empty(self.m), np.empty((self.m, n)), np.empty(2 * n)
        self.mod.sys_phis(q, self.prm, phis)
        self.mod.sys_dphis(q, self.prm, G)
        self.mod.dynamics_rhs(0.0, np.concatenate([q, p]), self.prm, out)   # (qdot = M^-1 p, whatever t)
        return phis, G @ out[:n]

    def rest_offset(self, q, i) -> float:
        G = np.empty((self.m, self.n))
        self.mod.sys_dphis(np.ascontiguousarray(q, float), self.prm, G)
        return 1e3 * _EPS * (1.0 + float(np.max(np.abs(q))) * float(np.max(np.abs(G[i]))))

    def _max_step(self, t, y, A, free):
        """reach times the shortest time a free contact could need to reach its surface."""
        if not free:
            return np.inf
        g = rh._Geometry(self.mod, t, y[:self.n], y[self.n:2 * self.n], self.prm)
        return max(self.reach * rh.approach_time(g, A, free), 1e3 * _EPS * max(1.0, abs(t)))

    # --- one segment -------------------------------------------------------------------------
    def segment(self, t0, y0, T, A, R, geo=None, S=None):
        from scipy.integrate import DOP853, OdeSolution

        A, R = tuple(A), list(R)
        S = None if S is None else tuple(S)
        n, m = self.n, self.m
        phi0, _ = self._phis_u(np.asarray(y0, float))
        # above the resting contact's own |phi| (within the rest tolerance) and its round-off
        off = {i: 4.0 * (abs(phi0[i]) + self.rest_offset(y0[:n], i)) for i in R}
        drift_tol = 1e3 * self.atol
        stick_off = {}
        if rh._frictional(S):   # a slip that starts from rest: its stick event past round-off only
            from .coulomb import stick_offsets

            stick_off = stick_offsets(rh._Geometry(self.mod, t0, y0[:n], y0[n:2 * n], self.prm), A, S)
        solver = DOP853(self._rhs(A, S), float(t0), np.array(y0, float), float(T), rtol=self.rtol, atol=self.atol)
        ts, interps = [float(t0)], []
        while solver.status == "running":
            free = [i for i in range(m) if i not in A and i not in R]
            solver.max_step = self._max_step(solver.t, solver.y, A, free)
            nf0 = solver.nfev
            solver.step()
            self.nfev += solver.nfev - nf0
            if solver.status == "failed":
                raise RuntimeError(f"reference: DOP853 failed at t={solver.t:.6g} (held: {list(A)})")
            if self.budget is not None:
                self.budget.charge(self.nfev, solver.t)
            dense = solver.dense_output()
            ts.append(float(solver.t))
            interps.append(dense)
            hit = self._check(dense, solver.t_old, solver.t, A, R, off, free, S, stick_off)
            if hit is not None:
                te, kind, i = hit
                piece = OdeSolution(ts, interps)
                y1 = np.asarray(dense(te), float)
                if kind == "impact" and i in R:   # the offset check fired: the root phi_i = 0 before it
                    te = last_crossing(lambda s: self._phis_u(piece(s))[0][i], t0, te)
                    y1 = np.asarray(piece(te), float)
                if kind == "stick" and i in stick_off:   # likewise: the root s v_t = 0 before s v_t = -off
                    sgn = S[A.index(i)]
                    te = last_crossing(lambda s: sgn * self._geo(s, piece(s)).wt[i], t0, te)
                    y1 = np.asarray(piece(te), float)
                return Flight(float(t0), float(te), y1, kind, int(i), piece)
            for i in list(R):  # a resting contact that rose past twice its offset is watched as free
                if self._phis_u(solver.y)[0][i] > 2.0 * off[i]:
                    R.remove(i)
            if A:
                phis, _ = self._phis_u(solver.y)
                if float(np.max(np.abs(phis[list(A)]))) > drift_tol and solver.status == "running":
                    return Flight(float(t0), float(solver.t), np.array(solver.y, float), "drift", -1,
                                  OdeSolution(ts, interps))
        if len(interps) == 0:
            return Flight(float(t0), float(t0), np.array(y0, float), "end", -1, Constant(y0))
        return Flight(float(t0), float(solver.t), np.array(solver.y, float), "end", -1, OdeSolution(ts, interps))

    def _geo(self, t, y):
        return rh._Geometry(self.mod, t, y[:self.n], y[self.n:2 * self.n], self.prm)

    def _check(self, dense, ta, tb, A, R, off, free, S=None, stick_off=None):
        """The earliest event inside the step [ta, tb]: (time, kind, contact) or None."""
        from scipy.optimize import brentq

        K = self.samples
        ss = np.linspace(ta, tb, K + 1)
        Y = np.asarray(dense(ss), float)
        n = self.n
        PH, U = np.empty((K + 1, self.m)), np.empty((K + 1, self.m))
        for k in range(K + 1):
            PH[k], U[k] = self._phis_u(Y[:, k])
        cands = []   # (bracket (a, b), function g with g(a) >= 0 > g(b), kind, contact)

        def phi_of(i, shift=0.0):
            return lambda s: self._phis_u(dense(s))[0][i] + shift

        def u_of(i):
            return lambda s: self._phis_u(dense(s))[1][i]

        for i in free:
            g, u = PH[:, i], U[:, i]
            for k in range(K):
                # "inside" at a sample: below the surface, or exactly on it moving in
                if g[k + 1] < 0.0 or (g[k + 1] == 0.0 and u[k + 1] < 0.0):
                    if g[k] > 0.0:
                        cands.append(((ss[k], ss[k + 1]), phi_of(i), "impact", i))
                        break
                    if g[k] == 0.0 and u[k] < 0.0:   # on the surface moving in at the sample: the impact
                        cands.append(((ss[k], ss[k]), phi_of(i), "impact", i))
                        break
                    if u[k] > 0.0 > u[k + 1]:  # rose from the surface (or just below it) and fell back
                        tm = brentq(u_of(i), ss[k], ss[k + 1], xtol=1e-300, rtol=4 * _EPS)
                        if phi_of(i)(tm) > 0.0:
                            cands.append(((tm, ss[k + 1]), phi_of(i), "impact", i))
                            break
                    continue
                if u[k] < 0.0 <= u[k + 1] and g[k] >= 0.0:  # a minimum between samples
                    tm = brentq(u_of(i), ss[k], ss[k + 1], xtol=1e-300, rtol=4 * _EPS) if u[k + 1] > 0.0 \
                        else ss[k + 1]
                    if phi_of(i)(tm) < 0.0:
                        cands.append(((ss[k], tm), phi_of(i), "impact", i))
                        break
        for i in R:
            g = PH[:, i] + off[i]
            k = next((k for k in range(K) if g[k] >= 0.0 > g[k + 1]), None)
            if k is not None:
                cands.append(((ss[k], ss[k + 1]), phi_of(i, off[i]), "impact", i))
        if R or A:
            geo = [rh._Geometry(self.mod, s, Y[:n, k], Y[n:2 * n, k], self.prm) for k, s in enumerate(ss)]
            if R:   # (pushed in while still on its surface: a contact that rose past its offset has left)
                acc = np.array([g.held_acc(A, S) for g in geo])
                for i in R:
                    k = next((k for k in range(K) if acc[k, i] >= 0.0 > acc[k + 1, i] and PH[k, i] <= 2.0 * off[i]),
                             None)
                    if k is not None:
                        cands.append(((ss[k], ss[k + 1]), self._acc_of(dense, A, i, S), "pressed", i))
            if A:
                mu = np.array([g.mu(A, S) for g in geo])
                for a, i in enumerate(A):
                    k = next((k for k in range(K) if mu[k, a] >= 0.0 > mu[k + 1, a]), None)
                    if k is not None:
                        cands.append(((ss[k], ss[k + 1]), self._mu_of(dense, A, a, S), "release", i))
                if rh._frictional(S):
                    self._friction_candidates(dense, ss, geo, A, S, cands, stick_off or {})
        if not cands:
            return None
        best = None
        for (a, b), g, kind, i in sorted(cands, key=lambda c: c[0][0]):
            if best is not None and a > best[0]:
                break
            ga = g(a) if b > a else 0.0
            te = a if ga == 0.0 else (float(brentq(g, a, b, xtol=1e-300, rtol=4 * _EPS)) if ga > 0.0 > g(b) else b)
            if best is None or te < best[0]:
                best = (te, kind, i)
        return best

    def _acc_of(self, dense, A, i, S=None):
        n = self.n

        def f(s):
            y = dense(s)
            return rh._Geometry(self.mod, s, y[:n], y[n:2 * n], self.prm).held_acc(A, S)[i]
        return f

    def _mu_of(self, dense, A, a, S=None):
        n = self.n

        def f(s):
            y = dense(s)
            return rh._Geometry(self.mod, s, y[:n], y[n:2 * n], self.prm).mu(A, S)[a]
        return f

    def _friction_candidates(self, dense, ss, geo, A, S, cands, stick_off):
        """The friction events of the held set A in the modes S on the samples ss (geometries geo): a
        sliding contact's s v_t (+ its stick offset, vcirun.reference_solution.coulomb.stick_offsets) crossing 0
        downwards (stick), a sticking contact's mu_s lam_n -+ lam_t crossing 0 downwards (slip), det K
        crossing 0 downwards with sliding contacts (painleve)."""
        from .coulomb import coefficients, response

        _, mus = coefficients(self.mod, self.prm)
        K = len(ss) - 1
        n = self.n

        def at(fn):
            def f(s):
                y = dense(s)
                return fn(rh._Geometry(self.mod, s, y[:n], y[n:2 * n], self.prm))
            return f

        def watch(values, fn, kind, i):
            k = next((k for k in range(K) if values[k] >= 0.0 > values[k + 1]), None)
            if k is not None:
                cands.append(((ss[k], ss[k + 1]), at(fn), kind, i))

        for a, (i, s) in enumerate(zip(A, S)):
            if s in (1, -1):
                fn = (lambda g, i=i, s=s, o=stick_off.get(i, 0.0): s * g.wt[i] + o)
                watch([fn(g) for g in geo], fn, "stick", i)
            elif s == rh.STICK:
                for sign in (1.0, -1.0):
                    fn = (lambda g, a=a, i=i, sign=sign: mus[i] * g.forces(A, S).lam_n[a] - sign * g.forces(A, S).lam_t[a])
                    watch([fn(g) for g in geo], fn, "slip", i)
        if any(s in (1, -1) for s in S):
            j = next(i for i, s in zip(A, S) if s in (1, -1))
            fn = (lambda g: response(g.forces(A, S).K, S))
            watch([fn(g) for g in geo], fn, "painleve", j)
