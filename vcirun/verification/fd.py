"""Finite differences, the symplecticity defect, and the derivative checks of generated kernels.

Stencils (shared with the test suite): `map_jacobian` (4th-order central), `gradient`, `jacobian`,
`mixed_hessian`; `omega` and `symplecticity_defect` (max |J^T Omega J - Omega|).

`KERNEL_CHECKS` is the table `vcirun verify` runs: kernel name -> how it is checked, against which
lower-level kernel (FD of a value kernel, or an identity between kernels). A row whose kernels a
module does not define is skipped, so the table keeps working when names are added; explicit
discrete Lagrangian kernels <LD>_* are checked for every explicit stage the module defines, against
FD of the discrete Lagrangian Ld(q0, q1, h) evaluated numerically from the module's own L(q, v) =
1/2 v^T M(q) v - V(q) (sys_M, sys_V) by the library's quadrature rule (vcirun.discrete.lagrangians).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Relative-error thresholds: (pass, warn). FD rows are limited by the stencil (4th order, step 1e-3
# relative: ~1e-11 on smooth kernels) and by round-off in the differenced value; identity rows by
# round-off alone.
FD_THRESHOLDS = (1e-6, 1e-4)
IDENTITY_THRESHOLDS = (1e-10, 1e-7)
FD_STEP = 1e-3
# A map whose Newton solve does not converge at a probe's step h (h times the motion's fastest rate
# beyond what the method's stage equations solve: a 12-link pendulum's MCVAC stages at h = 0.04) is
# checked at h / 2, h / 4, ... down to the finest step of the verification's ladder, and the row names
# the step; a map that converges at none of them fails. These checks test the kernels, and a step the
# integrator cannot take says nothing about them (the orders and H~ checks judge the steps).
MAX_HALVINGS = 6   # (0.04 / 2^6 = 0.000625, the default ladder's finest step)


def smaller_steps(h: float, h_min: float | None = None):
    """h, then h / 2, h / 4, ... down to h_min (default h / 2^MAX_HALVINGS)."""
    floor = h / 2 ** MAX_HALVINGS if h_min is None else h_min
    x = h
    yield x
    while 0.5 * x >= floor * (1.0 - 1e-12):
        x *= 0.5
        yield x


def _steps(x, d):
    return d * np.maximum(1.0, np.abs(np.asarray(x, float)))


def gradient(f, x, d=FD_STEP):
    """Gradient of scalar f at vector x (4th-order central stencil, steps d * max(1, |x_i|))."""
    x = np.asarray(x, float)
    e = _steps(x, d)
    g = np.empty(x.size)
    for i in range(x.size):
        u = np.zeros(x.size)
        u[i] = e[i]
        g[i] = (-f(x + 2 * u) + 8 * f(x + u) - 8 * f(x - u) + f(x - 2 * u)) / (12 * e[i])
    return g


def map_jacobian(f, y, d=1e-3):
    """Jacobian of f: R^m -> R^k at y by the 4th-order central stencil (error O(d^4) + O(eps/d))."""
    y = np.asarray(y, float)
    m = y.size
    cols = []
    for j in range(m):
        e = np.zeros(m)
        e[j] = d * max(1.0, abs(y[j]))
        cols.append((-f(y + 2 * e) + 8 * f(y + e) - 8 * f(y - e) + f(y - 2 * e)) / (12 * e[j]))
    return np.column_stack(cols)


jacobian = map_jacobian


def mixed_hessian(f, x, d=3e-3):
    """Hessian of scalar f at x: 4th-order central stencils for the diagonal and the mixed entries."""
    x = np.asarray(x, float)
    m = x.size
    e = _steps(x, d)
    H = np.empty((m, m))
    f0 = f(x)
    for i in range(m):
        u = np.zeros(m)
        u[i] = e[i]
        H[i, i] = (-f(x + 2 * u) + 16 * f(x + u) - 30 * f0 + 16 * f(x - u) - f(x - 2 * u)) / (12 * e[i] ** 2)
        for j in range(i):
            w = np.zeros(m)
            w[j] = e[j]

            def g(a, b):
                return f(x + a * u + b * w)

            val = (8 * (g(1, -2) + g(2, -1) + g(-2, 1) + g(-1, 2)) - 8 * (g(-1, -2) + g(-2, -1) + g(1, 2) + g(2, 1))
                   - (g(2, -2) + g(-2, 2) - g(-2, -2) - g(2, 2)) + 64 * (g(-1, -1) + g(1, 1) - g(1, -1) - g(-1, 1)))
            H[i, j] = H[j, i] = val / (144 * e[i] * e[j])
    return H


def omega(n):
    """The canonical symplectic matrix on (q, p) in R^2n."""
    return np.block([[np.zeros((n, n)), np.eye(n)], [-np.eye(n), np.zeros((n, n))]])


def symplecticity_defect(J):
    """max |J^T Omega J - Omega| (entrywise)."""
    n = J.shape[0] // 2
    W = omega(n)
    return float(np.max(np.abs(J.T @ W @ J - W)))


def rel_err(a, b, floor=0.0):
    """max |a - b| / max(max |b|, floor): relative error of a against the reference b."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    den = max(float(np.max(np.abs(b))) if b.size else 0.0, floor, 1e-300)
    return float(np.max(np.abs(a - b)) / den) if a.size else 0.0


# --- derivative checks of a compiled module ----------------------------------------------------------

@dataclass
class Probe:
    """One state at which kernels are checked: q, p (n,), time t, step h."""
    q: np.ndarray
    p: np.ndarray
    t: float
    h: float


class _Ctx:
    """What the checks need: the module, the parameter vector, an optional generalized force
    f(q, qdot, t) (numpy; None if unforced), and small wrappers around the kernels."""

    def __init__(self, mod, prm, force=None, h_min=None):
        self.mod, self.prm, self.force = mod, prm, force
        self.n = int(mod.NDOF)
        self.h_min = h_min   # the finest step a Newton-solved map is tried at (smaller_steps)

    def M(self, q):
        A = np.empty((self.n, self.n))
        self.mod.sys_M(np.ascontiguousarray(q, float), self.prm, A)
        return A

    def H(self, q, p):
        return float(self.mod.hamiltonian(np.ascontiguousarray(q, float), np.ascontiguousarray(p, float), self.prm))

    def L(self, q, v):
        q, v = np.asarray(q, float), np.asarray(v, float)
        return 0.5 * float(v @ self.M(q) @ v) - float(self.mod.sys_V(np.ascontiguousarray(q), self.prm))

    def f(self, q, v, t):
        if self.force is None:
            return np.zeros(self.n)
        return np.asarray(self.force(np.asarray(q, float), np.asarray(v, float), float(t)), float)


def _floor(value):
    # FD of a value of size |f| carries round-off ~ eps |f| / step; derivatives far below 1e-5 (1 + |f|)
    # are compared in absolute terms at that floor (e.g. dH/dq = 0 at an equilibrium)
    return 1e-5 * (1.0 + abs(value))


def _check_declared(c, s):
    """sys_M, sys_V, sys_phi (the gap min_i phi_i) and sys_phis against the declaration itself
    (sympy.lambdify: no code generation)."""
    if c.declared is None:
        return []
    mod, prm = c.mod, c.prm
    M = c.declared["M"](s.q)
    V, phis = c.declared["V"](s.q), c.declared["phis"](s.q)
    rows = [("sys_M", "the declared mass matrix (sympy.lambdify)", rel_err(c.M(s.q), M, 1e-300), IDENTITY_THRESHOLDS),
            ("sys_V", "the declared potential (sympy.lambdify)", rel_err(mod.sys_V(s.q, prm), V, 1.0),
             IDENTITY_THRESHOLDS),
            ("sys_phi", "the declared constraint (the gap min_i phi_i for several; sympy.lambdify)",
             rel_err(mod.sys_phi(s.q, prm), float(np.min(phis)), 1.0), IDENTITY_THRESHOLDS)]
    if hasattr(mod, "sys_phis"):
        out = np.empty(phis.size)
        mod.sys_phis(s.q, prm, out)
        rows.append(("sys_phis", "the declared constraints phi_i (sympy.lambdify)", rel_err(out, phis, 1.0),
                     IDENTITY_THRESHOLDS))
    return rows


def _ncon(mod):
    return int(getattr(mod, "NCON", 1))


def _phis(c, q):
    out = np.empty(_ncon(c.mod))
    c.mod.sys_phis(np.ascontiguousarray(q, float), c.prm, out)
    return out


def _check_dphis(c, s):
    """The constraint Jacobian (rows grad phi_i) against FD of sys_phis."""
    m, n = _ncon(c.mod), c.n
    G = np.empty((m, n))
    c.mod.sys_dphis(s.q, c.prm, G)
    rows = [("sys_dphis", "FD of sys_phis in q", rel_err(G, map_jacobian(lambda q: _phis(c, q), s.q),
             _floor(float(np.max(np.abs(_phis(c, s.q)))))), FD_THRESHOLDS)]
    if hasattr(c.mod, "sys_dphis_nz"):   # the structural nonzeros the per-step contact loops read
        row, col = np.asarray(c.mod.DPHI_ROW), np.asarray(c.mod.DPHI_COL)
        gv = np.empty(len(col))
        c.mod.sys_dphis_nz(s.q, c.prm, gv)
        S = np.zeros((m, n))
        for i in range(m):
            S[i, col[row[i]:row[i + 1]]] = gv[row[i]:row[i + 1]]
        rows.append(("sys_dphis_nz", "sys_dphis (its nonzeros scattered by DPHI_ROW, DPHI_COL)",
                     rel_err(S, G, 1.0), IDENTITY_THRESHOLDS))
    return rows


def _check_held_contact(c, s):
    """The velocity terms along v = M^-1 p: sys_ddphis = v^T Hess(phi_i) v (4th-order second
    difference of sys_phis along v) and sys_Mdotv = (dM/dq . v) v (FD of sys_M along v, times v)."""
    mod, prm, n, m = c.mod, c.prm, c.n, _ncon(c.mod)
    v = np.linalg.solve(c.M(s.q), s.p)
    rows = []
    if hasattr(mod, "sys_ddphis") and hasattr(mod, "sys_phis"):
        out = np.empty(m)
        mod.sys_ddphis(s.q, v, prm, out)
        # a second difference: step ~ eps^(1/6) (truncation e^4, round-off eps |phi| / e^2), and a floor on
        # the scale |v|^2 / |q|^2 of the term (an exactly linear phi_i has v^T Hess v = 0)
        qs, vs = max(1.0, float(np.max(np.abs(s.q)))), max(float(np.max(np.abs(v))), 1e-300)
        e = 3e-3 * qs / vs
        f = lambda a: _phis(c, s.q + a * v)  # noqa: E731
        ref = (-f(2 * e) + 16 * f(e) - 30 * f(0.0) + 16 * f(-e) - f(-2 * e)) / (12 * e * e)
        floor = 1e-3 * (1.0 + float(np.max(np.abs(f(0.0))))) * (vs / qs) ** 2
        rows.append(("sys_ddphis", "v^T Hess(phi_i) v by a 4th-order second difference of sys_phis along v",
                     rel_err(out, ref, floor), FD_THRESHOLDS))
    if hasattr(mod, "sys_Mdotv"):
        out = np.empty(n)
        mod.sys_Mdotv(s.q, v, prm, out)
        dM = map_jacobian(lambda a: c.M(s.q + a[0] * v).ravel(), np.zeros(1)).reshape(n, n)
        ref = dM @ v
        rows.append(("sys_Mdotv", "(dM/dq . v) v by FD of sys_M along v", rel_err(out, ref, 1e-5 * (1.0 + float(
            np.max(np.abs(c.M(s.q) @ v))))), FD_THRESHOLDS))
    return rows


def _check_friction(c, s):
    """Modules with friction (FRICTION): sys_slips against the declared slip rows and sys_friction
    against the declared coefficients (sympy: no code generation; where `declared` has them), and
    sys_dslips = v^T (dW_t,i/dq) v against FD of sys_slips along v = M^-1 p, times v (d/da W_t(q + a
    v) v at a = 0): the velocity term the held step and the exact reference take as the slip rows'
    derivative."""
    mod, prm, n, m = c.mod, c.prm, c.n, _ncon(c.mod)
    if not getattr(mod, "FRICTION", False):
        return []
    v = np.linalg.solve(c.M(s.q), s.p)

    def slips(q):
        W = np.empty((m, n))
        mod.sys_slips(np.ascontiguousarray(q, float), prm, W)
        return W

    rows = []
    if c.declared is not None and "slips" in c.declared:
        W = c.declared["slips"](s.q)
        rows.append(("sys_slips", "the declared slip rows W_t(q) (zero for frictionless contacts; sympy.lambdify)",
                     rel_err(slips(s.q), W, 1.0), IDENTITY_THRESHOLDS))
    if c.declared is not None and "friction" in c.declared:
        mu, mus = np.empty(m), np.empty(m)
        mod.sys_friction(prm, mu, mus)
        want_mu, want_mus = c.declared["friction"]
        rows.append(("sys_friction", "the declared mu and mu_s at the parameter values",
                     max(rel_err(mu, want_mu, 1.0), rel_err(mus, want_mus, 1.0)), IDENTITY_THRESHOLDS))
    out = np.empty(m)
    mod.sys_dslips(s.q, v, prm, out)
    # the step along v scaled like sys_ddphis' (a displacement of 1e-3 max(1, |q|) in q)
    e = FD_STEP * max(1.0, float(np.max(np.abs(s.q)))) / max(float(np.max(np.abs(v))), 1e-300)
    f = lambda a: slips(s.q + a * v) @ v  # noqa: E731
    ref = (-f(2 * e) + 8 * f(e) - 8 * f(-e) + f(-2 * e)) / (12 * e)
    rows.append(("sys_dslips", "FD of sys_slips along v, times v", rel_err(out, ref, _floor(float(
        np.max(np.abs(f(0.0)))))), FD_THRESHOLDS))
    return rows


def _check_force(c, s):
    """Forced modules: sys_force against the declared force (sympy.lambdify), sys_force_jac against FD
    of sys_force, dynamics_rhs = hamilton_rhs + (0, f), force_power = f . v."""
    mod, prm, n = c.mod, c.prm, c.n
    if c.force is None or not getattr(mod, "FORCED", True):
        return []
    v = np.linalg.solve(c.M(s.q), s.p)

    def f_of(q, vv):
        out = np.empty(n)
        mod.sys_force(np.ascontiguousarray(q, float), np.ascontiguousarray(vv, float), s.t, prm, out)
        return out

    f = f_of(s.q, v)
    ref = c.f(s.q, v, s.t)
    scale = 1e-5 * (1.0 + float(np.max(np.abs(ref))))
    rows = [("sys_force", "the declared force f(q, qdot, t) (sympy.lambdify)", rel_err(f, ref, scale), IDENTITY_THRESHOLDS)]
    if hasattr(mod, "sys_force_jac"):
        fq, fv = np.empty((n, n)), np.empty((n, n))
        mod.sys_force_jac(s.q, v, s.t, prm, fq, fv)
        e = max(rel_err(fq, map_jacobian(lambda q: f_of(q, v), s.q), scale),
                rel_err(fv, map_jacobian(lambda vv: f_of(s.q, vv), v), scale))
        rows.append(("sys_force_jac", "FD of sys_force in q and in qdot", e, FD_THRESHOLDS))
    if hasattr(mod, "dynamics_rhs") and hasattr(mod, "hamilton_rhs"):
        y = np.concatenate([s.q, s.p])
        a, b = np.empty(2 * n), np.empty(2 * n)
        mod.dynamics_rhs(s.t, y, prm, a)
        mod.hamilton_rhs(y, prm, b)
        b[n:] += ref
        rows.append(("dynamics_rhs", "hamilton_rhs + (0, declared f)", rel_err(a, b, 1.0), IDENTITY_THRESHOLDS))
    if hasattr(mod, "force_power"):
        P = float(mod.force_power(s.q, v, s.t, prm))
        rows.append(("force_power", "declared f . v", rel_err(P, float(ref @ v), scale), IDENTITY_THRESHOLDS))
    return rows


def _gap_branch(c, q):
    """The smooth function whose gradient sys_dphi is at q: sys_phi itself for one constraint; for
    several, the constraint sys_dphi selects (the first smallest phi_i). The gap min_i phi_i has a kink
    where two phi_i are equal (a block resting on both corners, balls touching in a row): a difference
    stencil across the kink mixes two gradients, so the kernels are checked against the selected
    branch (a kernel that selected another constraint than the gap's argmin fails it)."""
    mod, prm = c.mod, c.prm
    if _ncon(mod) == 1 or not hasattr(mod, "sys_phis"):
        return lambda x: float(mod.sys_phi(np.ascontiguousarray(x, float), prm)), None
    k = int(np.argmin(_phis(c, q)))
    return (lambda x: float(_phis(c, x)[k])), k


def _check_dphi(c, s):
    mod, prm, n = c.mod, c.prm, c.n
    g = np.empty(n)
    mod.sys_dphi(s.q, prm, g)
    phi, k = _gap_branch(c, s.q)
    what = "FD of sys_phi in q" if k is None else "FD in q of the smallest phi_i (sys_phis), the gap's branch"
    return [("sys_dphi", what, rel_err(g, gradient(phi, s.q), _floor(phi(s.q))), FD_THRESHOLDS)]


def _check_dhq(c, s):
    mod, prm, n = c.mod, c.prm, c.n
    x = np.linalg.solve(c.M(s.q), s.p)
    g = np.empty(n)
    mod.sys_dHq(s.q, x, prm, g)
    fd = gradient(lambda q: c.H(q, s.p), s.q)
    return [("sys_dHq", "FD of hamiltonian in q at fixed p (x = M^-1 p)", rel_err(g, fd, _floor(c.H(s.q, s.p))),
             FD_THRESHOLDS)]


def _check_hamiltonian(c, s):
    x = np.linalg.solve(c.M(s.q), s.p)
    direct = 0.5 * float(s.p @ x) + float(c.mod.sys_V(s.q, c.prm))
    H = c.H(s.q, s.p)
    return [("hamiltonian", "1/2 p^T M^-1 p + V from sys_M, sys_V (numpy solve)", rel_err(H, direct, 1.0),
             IDENTITY_THRESHOLDS)]


def _check_rhs(c, s):
    n = c.n
    out = np.empty(2 * n)
    c.mod.hamilton_rhs(np.concatenate([s.q, s.p]), c.prm, out)
    gq = gradient(lambda q: c.H(q, s.p), s.q)
    gp = gradient(lambda p: c.H(s.q, p), s.p)
    fl = _floor(c.H(s.q, s.p))
    return [("hamilton_rhs", "(dH/dp, -dH/dq) by FD of hamiltonian", rel_err(out, np.concatenate([gp, -gq]), fl),
             FD_THRESHOLDS)]


def _check_gdot(c, s):
    n = c.n
    out = np.empty(2 * n)
    c.mod.hamilton_rhs(np.concatenate([s.q, s.p]), c.prm, out)
    qdot = out[:n]
    branch, k = _gap_branch(c, s.q)
    phi = lambda a: branch(s.q + a[0] * qdot)  # noqa: E731
    fd = gradient(phi, np.zeros(1))[0]
    val = float(c.mod.gdot(s.q, s.p, c.prm))
    what = "FD of sys_phi along qdot = M^-1 p" + ("" if k is None else " (the gap's branch: the smallest phi_i)")
    return [("gdot", what, rel_err(val, fd, _floor(phi(np.zeros(1)))), FD_THRESHOLDS)]


def _check_cva_lambda(c, s):
    g = np.empty(c.n)
    lam = float(c.mod.cva_lambda(s.q, s.p, c.prm, g))
    H0 = c.H(s.q, s.p)
    return [("cva_lambda", "H(q, p + lam grad phi) = H(q, p) (the R^CVA reflection)",
             rel_err(c.H(s.q, s.p + lam * g), H0, 1.0), IDENTITY_THRESHOLDS)]


def _stage_names(mod):
    from ..discrete.lagrangians import LIBRARY

    return [nm for nm, ld in LIBRARY.items() if ld.explicit and hasattr(mod, f"{nm}_PmJ")]


def _ld_value(c, name):
    """Ld(q0, q1, h) of explicit Lagrangian `name` from the module's L (the library's quadrature rule)."""
    from ..discrete.lagrangians import LIBRARY

    build = LIBRARY[name].build
    return lambda q0, q1, h: float(build(c.L, list(q0), list(q1), h))


def _check_ld(c, s):
    from ..discrete.lagrangians import LIBRARY

    mod, prm, n = c.mod, c.prm, c.n
    rows = []
    v = np.linalg.solve(c.M(s.q), s.p)
    h, t, q0 = s.h, s.t, s.q
    q1 = q0 + h * v
    for nm in _stage_names(mod):
        Ld = _ld_value(c, nm)
        a, b = LIBRARY[nm].forcing_weights
        r, J = np.empty(n), np.empty((n, n))
        getattr(mod, f"{nm}_PmJ")(q0, v, h, t, prm, r, J)
        ref = -gradient(lambda x: Ld(x, q1, h), q0, FD_STEP * h) - a * h * c.f(q0, v, t)
        scale = _floor(Ld(q0, q1, h) / h)
        rows.append((f"{nm}_PmJ (r)", "-D1 Ld - f^- by FD of Ld in q0", rel_err(r, ref, scale), FD_THRESHOLDS))

        def r_of(vv):
            rr, JJ = np.empty(n), np.empty((n, n))
            getattr(mod, f"{nm}_PmJ")(q0, np.ascontiguousarray(vv), h, t, prm, rr, JJ)
            return rr

        rows.append((f"{nm}_PmJ (J)", "dPm/dv by FD of its r in v", rel_err(J, map_jacobian(r_of, v), scale),
                     FD_THRESHOLDS))
        pp = np.empty(n)
        getattr(mod, f"{nm}_Pp")(q0, v, h, t, prm, pp)
        ref = gradient(lambda x: Ld(q0, x, h), q1, FD_STEP * h) + b * h * c.f(q1, v, t + h)
        rows.append((f"{nm}_Pp", "D2 Ld + f^+ by FD of Ld in q1", rel_err(pp, ref, scale), FD_THRESHOLDS))
        Ed = float(getattr(mod, f"{nm}_Ed")(q0, v, h, prm))
        ref = -gradient(lambda x: Ld(q0, q1, x[0]), np.array([h]), FD_STEP * abs(h))[0]
        rows.append((f"{nm}_Ed", "-D3 Ld by FD of Ld in h at fixed q0, q1", rel_err(Ed, ref, scale), FD_THRESHOLDS))
        if hasattr(mod, f"{nm}_Edv"):
            ev = np.empty(n)
            getattr(mod, f"{nm}_Edv")(q0, v, h, prm, ev)
            ref = gradient(lambda vv: float(getattr(mod, f"{nm}_Ed")(q0, np.ascontiguousarray(vv), h, prm)), v)
            rows.append((f"{nm}_Edv", f"FD of {nm}_Ed in v", rel_err(ev, ref, scale), FD_THRESHOLDS))
        if hasattr(mod, f"{nm}_PmJc") and hasattr(mod, "sys_node"):
            # (unwritten slots, e.g. structural zeros of M, stay NaN in both: compared as equal)
            cn0, cn1, cq1 = (np.full(int(mod.NODE_LEN), np.nan) for _ in range(3))
            mod.sys_node(q0, prm, cn0)
            mod.sys_node(q1, prm, cq1)
            rc, Jc, ppc = np.empty(n), np.empty((n, n)), np.empty(n)
            getattr(mod, f"{nm}_PmJc")(q0, v, h, t, prm, cn0, rc, Jc)
            getattr(mod, f"{nm}_Ppc")(q0, v, h, t, prm, cn0, ppc, cn1)
            same_slots = np.array_equal(np.isnan(cn1), np.isnan(cq1))
            e = max(rel_err(rc, r), rel_err(Jc, J), rel_err(ppc, pp),
                    rel_err(np.nan_to_num(cn1), np.nan_to_num(cq1), 1.0) if same_slots else np.inf)
            rows.append((f"{nm}_PmJc, {nm}_Ppc", f"= {nm}_PmJ, {nm}_Pp with node data sys_node(q0); end node "
                         "= sys_node(q1)", e, IDENTITY_THRESHOLDS))
    return rows


def _check_step(c, s):
    """ld_step of an explicit Ld solves the DEL equations: Pm(q0, v) = p0, q1 = q0 + h v, p1 = Pp."""
    mod, prm, n = c.mod, c.prm, c.n
    if c.full_stages is None or len(c.full_stages) != 1:
        return []   # a composition: its stages are checked above, the composition by the symplecticity check
    nm = c.full_stages[0][0]
    q1, p1, v = np.empty(n), np.empty(n), np.empty(n)
    it, _ = mod.ld_step(s.q, s.p, s.h, s.t, prm, 1e-14, 50, q1, p1, v)
    if it < 0:
        return [("ld_step", "Newton on the DEL equations", np.inf, IDENTITY_THRESHOLDS)]
    r, J, pp = np.empty(n), np.empty((n, n)), np.empty(n)
    getattr(mod, f"{nm}_PmJ")(s.q, v, s.h, s.t, prm, r, J)
    getattr(mod, f"{nm}_Pp")(s.q, v, s.h, s.t, prm, pp)
    e = max(rel_err(r, s.p, 1.0), rel_err(q1, s.q + s.h * v, 1.0), rel_err(p1, pp, 1.0))
    return [("ld_step", f"DEL residual: {nm}_PmJ(q0, v) = p0, q1 = q0 + h v, p1 = {nm}_Pp", e, (1e-9, 1e-7))]


# FD steps of the modified Hamiltonian's checks, coarse to fine: the stencils' truncation falls as d^4
# and their round-off grows as eps / d (gradient) and eps / d^2 (Hessian), while a wrong kernel's
# difference does not fall (a 12-link chain at h = 0.04: the gradient 3.5e-3 at 1e-3, 1.8e-7 at 1e-4,
# 1.5e-9 at 3e-5; the Hessian 5e-3 at 3e-3, 9e-7 at 3e-4, 1e-8 at 1e-4)
GRADIENT_STEPS = (FD_STEP, 3e-4, 1e-4, 3e-5, 1e-5)
HESSIAN_STEPS = (3e-3, 1e-3, 3e-4, 1e-4)


def falling_min(err, steps, threshold):
    """The smallest err(d) along `steps`, taken in turn until it is a hundredth of `threshold` or stops
    falling (to less than a third of the previous step's)."""
    best = np.inf
    for d in steps:
        x = err(d)
        if x <= 0.01 * threshold or not x < best / 3:
            return min(x, best)
        best = x
    return best


def _check_mh(c, s):
    """The modified-Hamiltonian kernels at probe s: at its step, else at the largest smaller step
    (smaller_steps) where mh_gradient's Newton converges and mh_energy is defined at every point of the
    FD stencils; the rows name the step when it is not the probe's."""
    rows = []
    for h in smaller_steps(s.h, c.h_min):   # (see MAX_HALVINGS)
        at = "" if h == s.h else f" (at h = {h:g}: the stage equations are not solved at h = {s.h:g} at this state)"
        rows = _mh_rows(c, s, h, at)
        if all(np.isfinite(r[2]) for r in rows):
            break
    return rows


def _mh_rows(c, s, h, at):
    mod, prm, n = c.mod, c.prm, c.n
    rows = []
    y = np.concatenate([s.q, s.p])
    m = int(mod.MH_M)
    u, W = np.empty(m), np.empty((m, m))
    grad, hess = np.empty(2 * n), np.empty((2 * n, 2 * n))
    mod.mh_guess(s.q, s.p, prm, u)
    it, val = mod.mh_gradient(s.q, s.p, h, prm, u, W, grad, hess)
    if it < 0 or not np.isfinite(val):
        return [("mh_gradient", f"Newton on the stationary stage velocities, at h = {s.h:g} and every step down to "
                 f"{h:g}", np.inf, FD_THRESHOLDS)]
    E = lambda y: float(mod.mh_energy(np.ascontiguousarray(y[:n]), np.ascontiguousarray(y[n:]), h, prm))  # noqa: E731
    floor = _floor(val)
    rows.append(("mh_gradient (grad)", "FD of mh_energy in (q, p) at the step where the difference stops falling" + at,
                 falling_min(lambda d: rel_err(grad, gradient(E, y, d), floor), GRADIENT_STEPS, FD_THRESHOLDS[0]),
                 FD_THRESHOLDS))
    terms = np.empty(int(mod.MH_ORDER))

    def eta(yy):
        out = np.empty(int(mod.MH_ORDER))
        mod.mh_terms(np.ascontiguousarray(yy[:n]), np.ascontiguousarray(yy[n:]), h, prm, out)
        return float(out[0])

    floor = _floor(eta(y))   # (the gradient's floor is the energy's)
    rows.append(("mh_gradient (hess)", "Hessian of eta (mh_terms[0]) by 4th-order FD at the step where the difference "
                 "stops falling" + at, falling_min(lambda d: rel_err(hess, mixed_hessian(eta, y, d), floor), HESSIAN_STEPS,
                                                    FD_THRESHOLDS[0]), FD_THRESHOLDS))
    tot = float(mod.mh_terms(s.q, s.p, h, prm, terms))
    series = sum(h ** i * terms[i] for i in range(len(terms)))
    rows.append(("mh_terms", "eta + h H2 + ... + h^(s-1) H_s = mh_energy" + at, max(rel_err(series, val, 1.0),
                 rel_err(tot, val, 1.0)), IDENTITY_THRESHOLDS))
    return rows


# kernel names a row needs (all of them) -> check; rows whose names a module lacks are skipped
KERNEL_CHECKS = [
    (("sys_M", "sys_V", "sys_phi"), _check_declared),   # needs `declared` (check_kernels)
    (("sys_force", "sys_M"), _check_force),             # forced modules, against the declared force
    (("sys_phi", "sys_dphi"), _check_dphi),
    (("sys_phis", "sys_dphis"), _check_dphis),          # several constraints
    (("sys_M",), _check_held_contact),                  # sys_ddphis, sys_Mdotv where defined
    (("sys_M", "sys_slips", "sys_dslips"), _check_friction),   # modules with friction
    (("sys_dHq", "sys_M", "hamiltonian"), _check_dhq),
    (("hamiltonian", "sys_M", "sys_V"), _check_hamiltonian),
    (("hamilton_rhs", "hamiltonian"), _check_rhs),
    (("gdot", "sys_phi", "hamilton_rhs"), _check_gdot),
    (("cva_lambda", "hamiltonian"), _check_cva_lambda),
    (("sys_M", "sys_V"), _check_ld),          # every explicit stage <LD>_PmJ, _Pp, _Ed, _Edv, _PmJc, _Ppc
    (("ld_step", "FULL_STAGES"), _check_step),
    (("mh_energy", "mh_gradient", "mh_guess", "mh_terms", "MH_M", "MH_ORDER"), _check_mh),
]


def check_kernels(mod, prm, probes, force=None, full_stages=None, declared=None, h_min=None):
    """Run every applicable row of KERNEL_CHECKS at every probe. full_stages: the kernel set's
    ((explicit Ld name, fraction), ...) (the DEL residual of ld_step needs the stage's name);
    declared: numpy callables {"M", "V", "phis"} of q from the declaration, and for systems with friction
    "slips" (q -> W_t(q)) and "friction" (the arrays mu, mu_s) (None: those rows are skipped).
    h_min: the finest step at which a map whose Newton solve does not converge at a probe's step is
    tried (`smaller_steps`; default the probe's step / 2^MAX_HALVINGS).
    Returns a list of dicts {kernel, against, worst (relative error over the probes), thresholds},
    one per kernel row."""
    c = _Ctx(mod, np.asarray(prm, float), force, h_min)
    c.full_stages, c.declared = full_stages, declared
    worst: dict = {}
    for names, fn in KERNEL_CHECKS:
        if not all(hasattr(mod, k) for k in names):
            continue
        for s in probes:
            s = Probe(np.ascontiguousarray(s.q, float), np.ascontiguousarray(s.p, float), float(s.t), float(s.h))
            for kernel, against, err, thr in fn(c, s):
                err = float(err) if np.isfinite(err) else float("inf")
                cur = worst.get(kernel)
                if cur is None or not err <= cur["worst"]:
                    worst[kernel] = {"kernel": kernel, "against": against, "worst": err, "thresholds": thr}
    return list(worst.values())
