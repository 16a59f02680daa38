"""Declared resets and guards in the exact reference (vcirun.mechanics.hybrid: `reset`, `plastic`, `when`).

A guarded constraint acts only where its arming function w(q) > 0. Both paths follow its surface
phi (unguarded) and its guard separately: a downward crossing of phi where w <= 0 is no event (the
compass gait's swing foot crossing the slope at mid-stride, theta_s < 0); the guard arming (w
crossing 0 upwards) where phi < 0 is an error, the state being inside the constraint from then on.
The Taylor path has both as heyoka events (vcirun.reference_solution.taylor); DOP853 follows the guarded gap
of the kernels (Piecewise((phi, w > 0), (1, True))), and the event loop checks at each of its
impacts that the surface is at its root there (a jump of the guarded gap from 1 to phi < 0 where the
guard arms is refused by the same error).

At an impact of the constraint with the declared map, the loop applies the impact law first where
the constraint declares `plastic` or a restitution (RESET_LAW_FIRST) and then the map, as the
integrators do (the kernel `declared_reset`): q+, qdot+ = the map of (q-, qdot-), p+ = M(q+) qdot+.
The state after the map must be admissible: phi_j(q+) >= -tol for every constraint j whose guard is
armed at q+ (tol: the start tolerance of vcirun.core.system_data), else a RuntimeError names the
constraint, the time and the states.
"""
from __future__ import annotations

import numpy as np

from ..core.system_data import start_tolerance

__all__ = ["DeclaredResets", "declared_resets"]

_EPS = float(np.finfo(float).eps)


class DeclaredResets:
    """The declared map and guards of one system at the parameter vector prm (numeric)."""

    def __init__(self, system, mod, prm):
        import sympy as sp

        self.system, self.mod, self.prm = system, mod, np.asarray(prm, float)
        self.n, self.m = int(system.n), int(system.m)
        self.names = [c.name for c in system.constraints]
        self.mapped = bool(mod.RESET_MAP)
        qs, ps = list(system.q), system.param_symbols
        self.guarded = [i for i, c in enumerate(system.constraints) if c.when is not None]
        self._w = {i: sp.lambdify((qs, ps), system.constraints[i].when, "math") for i in self.guarded}
        self._surface = {i: sp.lambdify((qs, ps), system.constraints[i].surface, "math") for i in self.guarded}
        self._grad = {i: sp.lambdify((qs, ps), [sp.diff(system.constraints[i].surface, s) for s in qs], "math")
                      for i in self.guarded}

    def armed(self, i, q) -> bool:
        """Whether contact i acts at q (no guard: always)."""
        return i not in self._w or float(self._w[i](list(map(float, q[: self.n])), list(self.prm))) > 0.0

    def surface(self, i, q) -> float:
        """phi_i(q) without its guard."""
        return float(self._surface[i](list(map(float, q[: self.n])), list(self.prm)))

    def scale(self, i, q) -> float:
        """1e3 eps (1 + |q| |grad phi_i|): well above the round-off of phi_i at q."""
        g = self._grad[i](list(map(float, q[: self.n])), list(self.prm))
        return 1e3 * _EPS * (1.0 + float(np.max(np.abs(q[: self.n]))) * max(abs(float(x)) for x in g))

    def check_arming(self, t, y, i) -> None:
        """The guard of contact i arms at (t, y): its surface must not be below round-off there."""
        phi = self.surface(i, y)
        if phi < -self.scale(i, y):
            raise RuntimeError(f"reference: the guard of constraint {self.names[i]} (when: "
                               f"{self.system.constraints[i].when} > 0) arms at t={t:.12g} with phi = {phi:.3g} < 0 "
                               f"at q={np.asarray(y[: self.n]).tolist()}: the state is inside the constraint where "
                               "it starts to act; change the guard so that it arms where phi >= 0")

    def check_impact(self, t, y, i) -> None:
        """An impact of a guarded contact lies on its surface (not where the guard arms inside it)."""
        if i in self._w:
            self.check_arming(t, y, i)

    def apply(self, t, y, d, s0, i) -> np.ndarray:
        """The state after the impact of contact i at (t, y) (y: the state before it; d, s0: the
        impact law's direction and multiplier): the declared map, checked admissible."""
        n = self.n
        q, pm = np.ascontiguousarray(y[:n], float), np.ascontiguousarray(y[n:2 * n], float)
        qp, pp = np.empty(n), np.empty(n)
        self.mod.declared_reset(q, pm, np.ascontiguousarray(d, float), float(s0), self.prm, qp, pp)
        if not (np.all(np.isfinite(qp)) and np.all(np.isfinite(pp))):
            raise RuntimeError(f"reference: the declared reset of constraint {self.names[i]} gives a non-finite "
                               f"state at t={t:.12g} (q- = {q.tolist()}, p- = {pm.tolist()} -> q+ = {qp.tolist()}, "
                               f"p+ = {pp.tolist()})")
        phis, G = np.empty(self.m), np.empty((self.m, n))
        self.mod.sys_phis(qp, self.prm, phis)
        self.mod.sys_dphis(qp, self.prm, G)
        for j in range(self.m):
            if phis[j] < -start_tolerance(qp, G[j]):
                raise RuntimeError(f"reference: the declared reset of constraint {self.names[i]} at t={t:.12g} maps "
                                   f"q- = {q.tolist()} to q+ = {qp.tolist()}, inside constraint {self.names[j]} "
                                   f"(phi = {phis[j]:.3g} < 0, guard armed): the map must leave the state admissible")
        out = np.array(y, float)
        out[:n], out[n:2 * n] = qp, pp
        return out


def declared_resets(system, mod, prm) -> DeclaredResets | None:
    """The DeclaredResets of a system with a declared map or a guard, None otherwise (the event loop
    then applies Newton's law alone, unchanged)."""
    if not (bool(mod.RESET_MAP) or any(c.when is not None for c in system.constraints)):
        return None
    return DeclaredResets(system, mod, prm)
