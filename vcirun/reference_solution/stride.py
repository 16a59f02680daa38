"""The exact return map of a hybrid system on the section of one constraint's impact: a walker's stride
map, from the state just after an impact (and its declared reset) to the state just after the k-th
next impact of the same constraint, on the exact reference's event loop (vcirun.reference_solution.loop with
stop_after; the Taylor path at machine precision where the system is expressible, else DOP853 at rtol).

`ReferenceReturnMap` has the interface of vcirun.experiments.periodic.ReturnMap (P(x) -> (x+, return
time), `jacobian(x, fd_step)`), so `vcirun.periodic_orbit(system, "reference", guess=...)` finds the
exact fixed point by Newton on it. Its Jacobian is the same fourth-order central difference (stencil
+-delta, +-2 delta, delta = fd_step max(1, |x_j|)); the exact map is smooth in x to round-off, so the
Jacobian is accurate to about eps / fd_step + fd_step^4 |D^5 P|. FD_STEP, the default, is where the
two meet on the exact map of the compass gait (|p| ~ 17, so delta ~ 1e-3 there): 4e-11 on its multipliers (fd_step 1e-4,
2.5e-5, 1e-5 against 5e-5), where fd_step 1e-3 puts 1.5e-7 on them and 1.9e-7 degrees on the slope of
its period doubling.
"""
from __future__ import annotations

import numpy as np

from ..codegen.build import load_module
from ..codegen.kernel_set import SYSTEM_KERNELS
from .exact import _solve_dop853, _solve_taylor
from .taylor import TOL, NotExpressible, TaylorFailure, taylor_model

FD_STEP = 5e-5

__all__ = ["ReferenceReturnMap", "fd_jacobian"]


class ReferenceReturnMap:
    """P(x) of the exact solution on the section of constraint `section` (an index or a name; default:
    the constraint with a declared reset, else the first), after k impacts there. path: "auto"
    (Taylor where expressible, else DOP853), "taylor" or "dop853"; rtol: DOP853's. T_max bounds the
    time searched for a return (doubling from 4 s)."""

    def __init__(self, system, *, section=None, k=1, params=None, path="auto", rtol=1e-13, T_max=64.0,
                 resting_contact=True):
        from ..run.resolve import resolve_system

        self.system = resolve_system(system)
        if path not in ("auto", "taylor", "dop853"):
            raise ValueError(f"path: must be 'auto', 'taylor' or 'dop853' (got {path!r})")
        self.k = int(k)
        if self.k < 1:
            raise ValueError(f"k: impacts per return must be >= 1 (got {k})")
        self.params = dict(params or {})
        self.prm = self.system.param_values(self.params or None)
        self.n = self.system.n
        self.mod = load_module(self.system, SYSTEM_KERNELS)
        self.section = _section(section, self.system)
        self.rtol, self.T_max, self.resting_contact = float(rtol), float(T_max), bool(resting_contact)
        self.model = taylor_model(self.system)
        why = self.model.expressible() if path != "dop853" else "the DOP853 path was asked for"
        if why is not None and path == "taylor":
            raise NotExpressible(why)
        self.kind = "taylor" if why is None else "dop853"
        self.kind_reason = why or ""
        self.evaluations = 0
        self._T = None

    def _solve(self, q0, p0, T, tol=TOL):
        stop = (self.section, self.k)
        if self.kind == "taylor":
            try:
                return _solve_taylor(self.system, self.mod, self.model, q0, p0, self.prm, T, tol, self.resting_contact,
                                     stop_after=stop)
            except TaylorFailure as e:
                self.kind, self.kind_reason = "dop853", str(e)
        return _solve_dop853(self.system, self.mod, q0, p0, self.prm, T, self.rtol, self.resting_contact,
                             stop_after=stop)

    def __call__(self, x, tol=TOL):
        """(P(x), return time); tol: the Taylor path's tolerance (machine precision). Raises
        RuntimeError when no return to the section is reached within T_max."""
        x = np.asarray(x, float)
        if x.shape != (2 * self.n,):
            raise ValueError(f"x: must be the state (q, p), {2 * self.n} numbers (got shape {x.shape})")
        q0, p0 = x[: self.n].copy(), x[self.n:].copy()
        T = self._T or 4.0
        while True:
            sol = self._solve(q0, p0, T, tol)
            self.evaluations += 1
            if sol.after is not None:
                t, y = sol.after
                self._T = max(self._T or 0.0, 2.0 * t)
                return np.array(y[: 2 * self.n], float), float(t)
            if T >= self.T_max:
                break
            T = min(2.0 * T, self.T_max)
        name = self.system.constraints[self.section].name
        raise RuntimeError(f"reference return map: fewer than {self.k} impacts of {name} within T = {T:g} from "
                           f"{x.tolist()} (it does not return to the section; T_max: a longer search)")

    def jacobian(self, x, fd_step=FD_STEP):
        """DP(x) by the fourth-order central difference (see the module docstring)."""
        return fd_jacobian(self, x, fd_step)


def fd_jacobian(P, x, fd_step=FD_STEP):
    """DP(x) of a return map P (P(x) -> (x+, return time)) by the fourth-order central difference,
    stencil +-delta, +-2 delta with delta = fd_step max(1, |x_j|)."""
    x = np.asarray(x, float)
    m = x.shape[0]
    J = np.empty((m, m))
    for j in range(m):
        d = fd_step * max(1.0, abs(x[j]))
        e = np.zeros(m)
        e[j] = d
        f = [P(x + s * e)[0] for s in (2.0, 1.0, -1.0, -2.0)]
        J[:, j] = (-f[0] + 8.0 * f[1] - 8.0 * f[2] + f[3]) / (12.0 * d)
    return J


def _section(section, system) -> int:
    names = [c.name for c in system.constraints]
    if section is None:
        return next((i for i, c in enumerate(system.constraints)
                     if c.reset_q is not None or c.reset_qd is not None), 0)
    if isinstance(section, (int, np.integer)) and not isinstance(section, bool):
        if not 0 <= int(section) < len(names):
            raise ValueError(f"section: constraint index {section} out of range (0..{len(names) - 1})")
        return int(section)
    if section not in names:
        raise ValueError(f"section: {section!r} is not a constraint name (declared: {', '.join(names)})")
    return names.index(section)
