"""Symbolic mechanical systems L = 1/2 qdot^T M(q) qdot - V(q) with unilateral constraints phi_i(q) >= 0,
each with a restitution coefficient (one elastic constraint is the paper's case) and optionally Coulomb
friction (vcirun.mechanics.friction).

A `MechanicalSystem` is pure data plus derived sympy objects; it never computes numbers itself:
the only bridge to numbers is `vcirun.codegen`. Parameters stay symbols so that a parameter change
does not recompile anything (their values are passed to kernels at run time).
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np
import sympy as sp

from ..core.system_data import check_mass_matrix, param_vector, requested_start, restitution_parameters
from .friction import check_constraint_friction, coefficient, static_coefficient
from .friction import has_friction as contact_has_friction
from .hybrid import check_constraint_hybrid, guarded, law_first, reset_map_exprs

# constraints from which the gap Min is kept unevaluated (see _set_constraints)
MIN_EVALUATED_BELOW = 9


@dataclass(eq=False)
class Constraint:
    """One unilateral constraint phi(q) >= 0: its name, phi (sympy, in q and the parameters) and its
    restitution coefficient e in [0, 1] (a number, or a parameter symbol so that params={"e": 0.8}
    changes it without recompiling); Coulomb friction (vcirun.mechanics.friction): the kinetic
    coefficient mu (`friction`, a number >= 0 or a parameter symbol; 0: frictionless), the static one
    mu_s >= mu (`static_friction`, None: mu) and the slip row W_t(q) (`slip`, n expressions in q and the
    parameters, or None): the slip velocity is W_t(q) qdot, the friction force opposes it."""

    name: str
    phi: sp.Expr
    restitution: sp.Expr = sp.Integer(1)
    # declared resets and guards (vcirun.mechanics.hybrid): the arming function w(q) of `when` (armed
    # where w > 0), the map (q+, qdot+) of `reset` in the pre-impact (q, qdot), plastic: restitution 0
    when: sp.Expr | None = None
    reset_q: tuple | None = None
    reset_qd: tuple | None = None
    plastic: bool = False
    surface: sp.Expr | None = None   # phi without its guard (set by the system)
    friction: sp.Expr = sp.Integer(0)
    static_friction: sp.Expr | None = None
    slip: tuple | None = None
    field: str = ""   # where it was declared (the friction checks' messages); set by the readers


@dataclass(eq=False)
class MechanicalSystem:
    """A hyperregular mechanical Lagrangian system with holonomic unilateral constraints.

    name      : identifier (used in records and kernel cache keys)
    q         : list of n coordinate symbols
    params    : ordered dict symbol-name -> float value (the symbols appear in M, V, phi, forcing)
    M         : n x n symmetric sympy Matrix in q and params
    V         : sympy expression, potential energy
    phi       : sympy expression, the constraint function of a one-constraint system, phi(q) >= 0
                (elastic); or None with `constraints`
    constraints: list of Constraint (name, phi_i, restitution e_i), admissible set all phi_i >= 0.
                After construction `constraints` always holds the list and `phi` is phi_1 for one
                constraint, the gap function min_i phi_i for several (what the event search follows)
    forcing   : optional length-n sympy Matrix f(q, qdot, t) (generalized forces), symbols `qd` and `t`
    ic_map    : optional callable beta -> (q0, qdot0) (a scene's initial-condition family, e.g. Xi)
    default_q0, default_p0: optional default start state; default_beta: optional default beta of
                ic_map, the start of a system without a default state (vcirun.core.system_data);
                ic_map_params: ic_map takes (beta, {parameter: value}), a start that follows overrides
    """

    name: str
    q: list
    params: dict
    M: sp.Matrix
    V: sp.Expr
    phi: sp.Expr | None = None
    forcing: sp.Matrix | None = None
    qd: list = field(default_factory=list)
    t: sp.Symbol = field(default_factory=lambda: sp.Symbol("t"))
    ic_map: object = None
    default_q0: np.ndarray | None = None
    default_p0: np.ndarray | None = None
    description: str = ""
    constraints: list | None = None
    default_beta: float | None = None
    ic_map_params: bool = False   # ic_map takes (beta, {parameter: value}) (vcirun.core.system_data.requested_start)
    drawing: object = field(default=None, repr=False, compare=False)   # vcirun.mechanics.drawing.Drawing, for animations

    def __post_init__(self):
        self.q = list(self.q)
        n = len(self.q)
        self.M = sp.Matrix(self.M)
        if self.M.shape != (n, n):
            raise ValueError(f"system {self.name}: mass_matrix must be {n}x{n} (got {self.M.shape[0]}x{self.M.shape[1]})")
        if any(sp.simplify(self.M[i, j] - self.M[j, i]) != 0 for i in range(n) for j in range(i + 1, n)):
            raise ValueError(f"system {self.name}: mass_matrix must be symmetric (fix the off-diagonal entries)")
        if not self.qd:
            self.qd = [sp.Symbol(f"{s.name}_dot") for s in self.q]
        if self.forcing is not None:
            self.forcing = sp.Matrix(self.forcing).reshape(n, 1)
        self.V = sp.sympify(self.V)
        self.params = dict(self.params)
        self._check_declaration()  # first: dynamicsymbols would make the constraint checks misleading
        self._set_constraints()

    def _set_constraints(self) -> None:
        if (self.constraints is None) == (self.phi is None):
            raise ValueError(f"system {self.name}: give either phi (one elastic constraint) or constraints")
        if self.constraints is None:
            self.constraints = [Constraint("phi", self.phi)]
        cons = []
        for i, c in enumerate(self.constraints):
            if not isinstance(c, Constraint):
                raise ValueError(f"system {self.name}: constraints[{i}] must be a Constraint")
            raw = sp.sympify(c.surface if c.surface is not None else c.phi)
            when = None if c.when is None else sp.sympify(c.when)
            e0 = sp.Integer(0) if c.plastic else sp.sympify(c.restitution)
            fld = c.field or f"system {self.name}: constraints[{i}] ({c.name})"
            mu = coefficient(c.friction, self.params, f"{fld}.friction")
            mus = None if c.static_friction is None else coefficient(c.static_friction, self.params,
                                                                     f"{fld}.static_friction", "static_friction")
            if c.slip is not None and (isinstance(c.slip, (str, bytes)) or not hasattr(c.slip, "__len__")):
                raise ValueError(f"{fld}.slip: must be a list of {self.n} expressions (got {c.slip!r})")
            c = Constraint(str(c.name), guarded(raw, when), e0, when,
                           None if c.reset_q is None else tuple(sp.sympify(x) for x in c.reset_q),
                           None if c.reset_qd is None else tuple(sp.sympify(x) for x in c.reset_qd),
                           bool(c.plastic), raw, mu, mus,
                           None if c.slip is None else tuple(sp.sympify(x) for x in c.slip), str(c.field))
            if not (c.surface.free_symbols & set(self.q)):
                # phi constant in q: either no configuration is admissible or the constraint never acts
                raise ValueError(f"system {self.name}: constraint {c.name}: phi = {c.phi} does not depend on the "
                                 f"coordinates ({', '.join(s.name for s in self.q)}); give phi(q) as a function of them")
            e = c.restitution
            if e.is_Symbol:
                if e.name not in self.params:
                    raise ValueError(f"system {self.name}: constraint {c.name}: restitution {e} is neither a number "
                                     f"nor a parameter ({', '.join(self.params) or 'none declared'})")
            elif not (e.is_number and 0 <= float(e) <= 1):
                raise ValueError(f"system {self.name}: constraint {c.name}: restitution must be a number in [0, 1] "
                                 f"or a parameter name (got {e})")
            cons.append(c)
        names = [c.name for c in cons]
        if len(set(names)) != len(names):
            raise ValueError(f"system {self.name}: constraint names must be distinct (got {names})")
        self.constraints = cons
        # the gap min_i phi_i: sympy evaluates Min by comparing its arguments pairwise (0.2 s at 8
        # contacts, 48 s at 100, hours at 1000); kernels use it only below MIN_EVALUATED_BELOW
        # contacts (vcirun.codegen.derive.GAP_LOOP_MIN, the same number: above it sys_phi is a loop)
        self.phi = cons[0].phi if len(cons) == 1 else sp.Min(*[c.phi for c in cons],
                                                             evaluate=len(cons) < MIN_EVALUATED_BELOW)
        check_constraint_hybrid(self)
        check_constraint_friction(self)

    @property
    def reset_map(self) -> tuple | None:
        """(q+, qdot+) of the declared reset map in the pre-impact (q, qdot), None without one."""
        return reset_map_exprs(self)

    @property
    def reset_law_first(self) -> bool:
        """The impact law (plastic: restitution 0, or a restitution) acts before the declared map."""
        return law_first(self)

    def _check_declaration(self) -> None:
        """Name the cause when a declaration holds what the code generator cannot take: sympy
        Functions of time (pydy / sympy.physics.mechanics `dynamicsymbols`) or their derivatives, and
        free symbols that are neither coordinates nor parameters (nor, in forcing, velocities or t).
        Without this, such a system fails deep inside code generation."""
        from sympy.core.function import AppliedUndef

        parts = [("coordinates", sp.Matrix(self.q)), ("mass_matrix", self.M), ("potential", sp.Matrix([self.V]))]
        if self.phi is not None:
            parts.append(("constraint", sp.Matrix([sp.sympify(self.phi)])))
        for i, c in enumerate(self.constraints or []):
            if hasattr(c, "phi"):
                parts.append((f"constraints[{i}]", sp.Matrix([sp.sympify(c.phi), sp.sympify(c.restitution)])))
            if getattr(c, "slip", None) is not None and not isinstance(c.slip, (str, bytes)):
                parts.append((f"constraints[{i}].slip", sp.Matrix([sp.sympify(e) for e in c.slip])))
        if self.forcing is not None:
            parts.append(("forcing", self.forcing))
        for fld, expr in parts:
            funcs = sorted({str(f) for f in expr.atoms(AppliedUndef)} | {str(d) for d in expr.atoms(sp.Derivative)})
            if funcs:
                raise ValueError(
                    f"system {self.name}: {fld} contains {', '.join(funcs[:3])}{' ...' if len(funcs) > 3 else ''}, "
                    "sympy Functions of time (pydy / sympy.physics.mechanics dynamicsymbols); declare the coordinates "
                    "as plain Symbols (q1, q2 = sympy.symbols('q1 q2')) and substitute them into M, V, phi and "
                    "forcing, e.g. sympy.physics.mechanics.msubs(expr, {q1(t).diff(t): q1_dot, q1(t): q1})")
        bad_q = [str(c) for c in self.q if not isinstance(c, sp.Symbol)]
        if bad_q:
            raise ValueError(f"system {self.name}: coordinates must be sympy Symbols (got {', '.join(bad_q[:3])})")
        known = set(self.q) | set(self.param_symbols)
        for fld, expr in parts[1:]:
            allowed = known | (set(self.qd) | {self.t} if fld == "forcing" else set())
            extra = sorted((s for s in expr.free_symbols if s not in allowed), key=str)
            if extra:
                names = {str(s) for s in allowed}
                why = "; ".join(f"{s} has the name of a coordinate or parameter but other assumptions "
                                f"({getattr(s, '_assumptions_orig', None) or s.assumptions0}): use plain "
                                f"sympy.Symbol({str(s)!r})" if str(s) in names else
                                f"{s} is neither a coordinate ({', '.join(map(str, self.q))}) nor a parameter "
                                f"({', '.join(self.params) or 'none'})" for s in extra[:3])
                raise ValueError(f"system {self.name}: {fld}: {why}"
                                 + ("; velocities <coordinate>_dot and t are allowed in forcing only"
                                    if fld != "forcing" and any(s in set(self.qd) | {self.t} for s in extra) else ""))

    # --- basic sizes and symbols -------------------------------------------------------------
    @property
    def n(self) -> int:
        return len(self.q)

    @property
    def param_symbols(self) -> list:
        return [sp.Symbol(k) for k in self.params]

    def param_values(self, overrides: dict | None = None) -> np.ndarray:
        """Parameter vector in declaration order, with overrides applied (unknown names rejected)."""
        return param_vector(self.name, self.params, overrides, restitution_parameters(self))

    # --- derived symbolic objects ------------------------------------------------------------
    def lagrangian(self, q=None, qd=None):
        """L(q, qdot) = 1/2 qdot^T M(q) qdot - V(q), optionally at other symbols/expressions."""
        q = self.q if q is None else list(q)
        qd = self.qd if qd is None else list(qd)
        sub = dict(zip(self.q, q))
        M = self.M.subs(sub, simultaneous=True)
        v = sp.Matrix(qd)
        return (v.T * M * v)[0, 0] / 2 - self.V.subs(sub, simultaneous=True)

    def forcing_at(self, q, qd, t):
        """Generalized force f(q, qdot, t) at given expressions (zero vector if unforced)."""
        if self.forcing is None:
            return sp.zeros(self.n, 1)
        sub = dict(zip(self.q, q)) | dict(zip(self.qd, qd)) | {self.t: t}
        return self.forcing.subs(sub, simultaneous=True)

    @property
    def m(self) -> int:
        """Number of unilateral constraints."""
        return len(self.constraints)

    @property
    def grad_phi(self) -> sp.Matrix:
        """grad phi of a one-constraint system (several: `constraint_jacobian`)."""
        if self.m != 1:
            raise ValueError(f"system {self.name}: {self.m} constraints; use constraint_jacobian")
        return sp.Matrix([sp.diff(self.phi, s) for s in self.q])

    @property
    def constraint_jacobian(self) -> sp.Matrix:
        """G (m x n): row i is grad phi_i."""
        return sp.Matrix([[sp.diff(c.phi, s) for s in self.q] for c in self.constraints])

    @property
    def has_friction(self) -> bool:
        """Some contact has a friction coefficient that is not literally 0 (a number > 0 or a parameter):
        the module constant FRICTION."""
        return any(contact_has_friction(c) for c in self.constraints)

    @property
    def slip_matrix(self) -> sp.Matrix:
        """W_t (m x n): row i is constraint i's slip row, zero where the contact has no friction."""
        return sp.Matrix([[sp.sympify(e) for e in c.slip] if contact_has_friction(c) else [0] * self.n
                          for c in self.constraints])

    @property
    def friction_coefficients(self) -> tuple:
        """((mu_1, ..., mu_m), (mu_s1, ..., mu_sm)) as sympy numbers or parameter symbols."""
        return (tuple(sp.sympify(c.friction) for c in self.constraints),
                tuple(static_coefficient(c) for c in self.constraints))

    def hamiltonian_symbolic(self):
        """H(q, p) = 1/2 p^T M(q)^{-1} p + V(q) with symbols p_i; only sensible for small n."""
        p = sp.Matrix([sp.Symbol(f"p_{s.name}") for s in self.q])
        return (p.T * self.M.inv() * p)[0, 0] / 2 + self.V, list(p)

    @property
    def is_forced(self) -> bool:
        return self.forcing is not None and any(e != 0 for e in self.forcing)

    @property
    def bandwidth(self) -> int:
        """Half-bandwidth b of the coupling of the coordinates: every entry (i, j) with |i - j| > b of
        M(q), of the Hessian of L in (q, qdot) and of the Jacobian of the force is zero for every state.
        Hence so is that entry of each discrete Lagrangian's step Jacobian dPm/dv (a sum of those blocks
        at its nodes), and the steps solve it as a band matrix: b = 0 for a line of free balls (M = m I),
        b = n - 1 for a pendulum chain. Read off the expressions' symbols (a term of a sum couples the
        coordinates it contains), so b never understates the coupling; it may overstate it."""
        if getattr(self, "_band", None) is None:
            n = self.n
            index = {s: i for i, s in enumerate(self.q)} | {s: i for i, s in enumerate(self.qd)}

            def coupled(expr):
                return {index[s] for s in sp.sympify(expr).free_symbols if s in index}

            b = 0
            cliques = [coupled(t) for t in sp.Add.make_args(self.V)]
            for i in range(n):
                for j in range(n):
                    if self.M[i, j] != 0:
                        b = max(b, abs(i - j))
                        # T = 1/2 sum M_ij qd_i qd_j: its (q, qdot) Hessian couples i, j and M_ij's coordinates
                        cliques += [coupled(t) | {i, j} for t in sp.Add.make_args(self.M[i, j])]
            if self.forcing is not None:
                cliques += [coupled(f) | {i} for i, f in enumerate(self.forcing)]
            for c in cliques:
                if c:
                    b = max(b, max(c) - min(c))
            self._band = b
        return self._band

    def fingerprint(self) -> str:
        """Hash of the symbolic content (not the parameter values): the kernel cache key part."""
        if getattr(self, "_fp", None):
            return self._fp
        cons = [(c.name, sp.srepr(c.phi), sp.srepr(c.restitution)) for c in self.constraints]
        # friction enters only where some contact has it (a frictionless system keeps its cache keys)
        fric = [(c.name, sp.srepr(c.friction), sp.srepr(static_coefficient(c)), sp.srepr(sp.Matrix(c.slip)))
                for c in self.constraints if contact_has_friction(c)]
        # one elastic constraint named "phi" fingerprints as the single-phi case (its cache keys unchanged)
        phi = sp.srepr(self.phi) if cons == [("phi", sp.srepr(self.phi), sp.srepr(sp.Integer(1)))] else cons
        text = repr((self.name, [str(s) for s in self.q], list(self.params), sp.srepr(self.M),
                     sp.srepr(self.V), phi,
                     sp.srepr(self.forcing) if self.forcing is not None else None)
                    + ((sp.srepr(self.reset_map), self.reset_law_first) if self.reset_map is not None else ())
                    + ((("friction", fric),) if fric else ()))
        self._fp = hashlib.sha256(text.encode()).hexdigest()[:16]
        return self._fp

    # --- numeric helpers that need no compiled kernels (validation, initial conditions) ------
    def _lambdas(self):
        if not hasattr(self, "_lam"):
            args = (self.q, self.param_symbols)
            self._lam = (sp.lambdify(args, self.M, "numpy"),
                         sp.lambdify(args, [c.phi for c in self.constraints], "numpy"))
        return self._lam

    def dH_dq_at(self, x) -> sp.Matrix:
        """dH/dq at fixed x = M(q)^-1 p: -1/2 x^T dM/dq_i x + dV/dq_i (no symbolic inverse of M)."""
        xv = sp.Matrix(list(x))
        return sp.Matrix([-(xv.T * sp.diff(self.M, s) * xv)[0, 0] / 2 + sp.diff(self.V, s) for s in self.q])

    def numpy_functions(self) -> dict:
        """Plain numpy callables (sympy.lambdify), as a numpy/scipy user would write the model:
        M(q, prm), dHq(q, x, prm) = dH/dq at x = M^-1 p, V(q, prm), phis(q, prm) (the m constraint
        values), G(q, prm) (m x n, rows grad phi_i), f(q, qdot, t, prm) (the generalized force; None for
        an unforced system); for one constraint also phi(q, prm) and grad_phi(q, prm).
        For baselines and checks; the integrators use the compiled kernels instead."""
        if not hasattr(self, "_npf"):
            q, ps = list(self.q), self.param_symbols
            x = list(sp.symbols(f"xm0:{self.n}"))
            dHq = self.dH_dq_at(x)
            self._npf = {"M": sp.lambdify((q, ps), self.M, "numpy"),
                         "dHq": sp.lambdify((q, x, ps), dHq, "numpy"),
                         "V": sp.lambdify((q, ps), self.V, "numpy"),
                         "phis": sp.lambdify((q, ps), [c.phi for c in self.constraints], "numpy"),
                         "G": sp.lambdify((q, ps), self.constraint_jacobian, "numpy"),
                         "f": (sp.lambdify((q, list(self.qd), self.t, ps), self.forcing, "numpy")
                               if self.is_forced else None)}
            if self.m == 1:
                self._npf |= {"phi": sp.lambdify((q, ps), self.phi, "numpy"),
                              "grad_phi": sp.lambdify((q, ps), self.grad_phi, "numpy")}
        return self._npf

    def mass_matrix(self, q, params=None) -> np.ndarray:
        prm = self.param_values() if params is None else np.asarray(params, float)
        return np.array(self._lambdas()[0](list(q), list(prm)), dtype=float)

    def phi_values(self, q, params=None) -> np.ndarray:
        """(phi_1(q), ..., phi_m(q))."""
        prm = self.param_values() if params is None else np.asarray(params, float)
        return np.array(self._lambdas()[1](list(q), list(prm)), dtype=float).ravel()

    def phi_value(self, q, params=None) -> float:
        """The gap min_i phi_i(q) (phi(q) for one constraint)."""
        return float(np.min(self.phi_values(q, params)))

    def constraint_jacobian_value(self, q, params=None) -> np.ndarray:
        prm = self.param_values() if params is None else np.asarray(params, float)
        return np.array(self.numpy_functions()["G"](list(q), list(prm)), dtype=float).reshape(self.m, self.n)

    def restitution_values(self, params=None) -> np.ndarray:
        """(e_1, ..., e_m) at the parameter values."""
        vals = dict(zip(self.params, self.param_values() if params is None else np.asarray(params, float)))
        return np.array([float(c.restitution.subs({sp.Symbol(k): v for k, v in vals.items()}))
                         for c in self.constraints])

    def friction_values(self, params=None) -> tuple:
        """(mu, mu_s), two arrays of length m at the parameter values (zeros where frictionless)."""
        vals = {sp.Symbol(k): v for k, v in zip(self.params, self.param_values() if params is None
                                                  else np.asarray(params, float))}
        mu, mus = self.friction_coefficients
        return (np.array([float(sp.sympify(x).subs(vals)) for x in mu]),
                np.array([float(sp.sympify(x).subs(vals)) for x in mus]))

    def slip_matrix_value(self, q, params=None) -> np.ndarray:
        """W_t(q) (m x n), zero rows where a contact has no friction."""
        if not hasattr(self, "_slip_lam"):
            self._slip_lam = sp.lambdify((self.q, self.param_symbols), self.slip_matrix, "numpy")
        prm = self.param_values() if params is None else np.asarray(params, float)
        return np.array(self._slip_lam(list(q), list(prm)), dtype=float).reshape(self.m, self.n)

    def check_hyperregular(self, q, params=None) -> None:
        """The Legendre transform must be invertible: M(q) symmetric positive definite."""
        check_mass_matrix(self.name, q, self.mass_matrix(q, params))

    def legendre(self, q, qdot, params=None):
        """FL: (q, qdot) -> (q, p = M(q) qdot)."""
        q = np.asarray(q, float)
        return q.copy(), self.mass_matrix(q, params) @ np.asarray(qdot, float)

    def initial_state(self, beta=None, q0=None, p0=None, params=None):
        """(q0, p0) from explicit values, the scene's initial-condition map at beta, or its default."""
        kind, q0, p0 = requested_start(self, beta, q0, p0, params)  # the same rule as vcirun.simulate
        if kind == "legendre":
            q0, p0 = self.legendre(q0, p0, params)
        self.check_hyperregular(q0, params)
        return q0, p0
