"""CVA written the way a numpy/scipy user would write it: the yardstick of `make bench`.

Same algorithm as vcirun's compiled CVA (SVC full step solved for the step velocity by Newton with
the analytic Jacobian, first collision time located to 1e-13 h, R^CVA reset p+ = p- + lam grad phi
conserving H, the remaining time of the step integrated after the impact), with the slot
derivatives from `sympy.lambdify` (numpy), `np.linalg.solve` and `scipy.optimize.brentq`, in a
Python loop. It is checked against vcirun's CVA (same trajectory to ~1e-9) before it is timed.
"""
from __future__ import annotations

import numpy as np
import sympy as sp
from scipy.optimize import brentq

from vcirun.discrete.lagrangians import LIBRARY, step_expressions
from vcirun.scenes.registry import get_scene


class PlainCVA:
    def __init__(self, scene="cart_pendulum", newton_tol=1e-12, event_tol=1e-13):
        s = get_scene(scene)
        self.s = s
        self.n = s.n
        ex = step_expressions(s, LIBRARY["SVC"], need_energy=False)
        q0, v, h, t = ex["symbols"]
        args = (q0, v, h, t, s.param_symbols)
        self._Pm = sp.lambdify(args, ex["Pm"], "numpy")
        self._J = sp.lambdify(args, ex["Pm_v"], "numpy")
        self._Pp = sp.lambdify(args, ex["Pp"], "numpy")
        self._M = sp.lambdify((s.q, s.param_symbols), s.M, "numpy")
        self._phi = sp.lambdify((s.q, s.param_symbols), s.phi, "numpy")
        self._g = sp.lambdify((s.q, s.param_symbols), s.grad_phi, "numpy")
        self.prm = [float(x) for x in s.param_values()]
        self.ntol, self.etol = newton_tol, event_tol

    def phi(self, q):
        return float(self._phi(q, self.prm))

    def step(self, q, p, tau):
        """SVC step of length tau from (q, p): Newton on Pm(q, v, tau) = p from v = M^-1 p."""
        prm = self.prm
        v = np.linalg.solve(np.asarray(self._M(q, prm), float), p)
        for _ in range(50):
            r = np.asarray(self._Pm(q, v, tau, 0.0, prm), float).ravel() - p
            d = np.linalg.solve(np.asarray(self._J(q, v, tau, 0.0, prm), float), r)
            v = v - d
            if np.max(np.abs(d)) <= self.ntol * (1 + np.max(np.abs(v))):
                break
        return q + tau * v, np.asarray(self._Pp(q, v, tau, 0.0, prm), float).ravel()

    def reset(self, q, pm):
        g = np.asarray(self._g(q, self.prm), float).ravel()
        x = np.linalg.solve(np.asarray(self._M(q, self.prm), float), g)
        return pm - 2.0 * float(x @ pm) / float(x @ g) * g

    def simulate(self, q0, p0, h, N):
        q, p = np.array(q0, float), np.array(p0, float)
        Q = np.empty((N + 1, self.n))
        Q[0] = q
        impacts = []
        for k in range(N):
            q1, p1 = self.step(q, p, h)
            if self.phi(q1) > 0.0:
                q, p = q1, p1
            else:
                tau_max, tc = h, k * h
                while tau_max > 0.0:
                    q1, p1 = self.step(q, p, tau_max)
                    if self.phi(q1) >= 0.0:
                        q, p = q1, p1
                        break
                    a = 0.0
                    if self.phi(q) <= 0.0:          # on the surface after an impact: step off it first
                        a = tau_max
                        while self.phi(self.step(q, p, a)[0]) <= 0.0 and a > 1e-3 * self.etol * h:
                            a *= 0.5
                    tau = brentq(lambda s: self.phi(self.step(q, p, s)[0]), a, tau_max, xtol=self.etol * h)
                    qc, pc = self.step(q, p, tau)
                    q, p = qc, self.reset(qc, pc)
                    impacts.append(tc + tau)
                    tc += tau
                    tau_max -= tau
            Q[k + 1] = q
        return Q, np.array(impacts)
