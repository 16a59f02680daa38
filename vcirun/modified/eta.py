"""Modified Hamiltonians from the discrete Lagrangian (Sections 3.2-3.4, Appendix A): the symbolic side.

eta as a stationary value, its exact derivatives on a DAG of symbolic nodes, and the truncated
modified Hamiltonian as expressions in them (`derive_modified`). Their kernels (the primitives' CSE
program, the value, the reverse-mode gradient, eta's Hessian) are emitted by
vcirun/codegen/mh_kernels.py; the numba units that run them are vcirun/maps/gauss.py and
vcirun/collision/reset_mcva.py.

eta as a stationary value
-------------------------
eta(q, p) = p . (qbar - q)/h - Ld(q, qbar, h)/h with qbar implicit, D2 Ld(q, qbar, h) = p (eqs. 22, 24).
In the velocity parametrisation qbar = q + h vbar this is a partial Legendre transform in the
velocity,  eta(q, p) = stat_v [p . v - ell(q, v)],  ell(q, v) = Ld(q, q + h v, h) / h,  regular as h -> 0
(ell -> L, eta -> H). For a composition Ld (SVA = SE1 then SE2 half steps, SVB the reverse; the
composition is the definition we trust, see discrete/lagrangians.py) the interior nodes are
stationary too, so with u = (w_1, ..., w_K) the stage velocities (q_{i+1} = q_i + f_i h w_i,
v(u) = sum f_i w_i) we have in every case

    eta(q, p) = G(q, p, u*),   G(q, p, u) = p . v(u) - ell(q, u),   F(q, p, u*) = dG/du = 0.

The stationarity in u gives the envelope identities D_q eta = -ell_q = -(p + D1 Ld)/h and
D_p eta = v(u*) = vbar (Appendix A step 3, verified), so eta's derivatives need u*'s. These come from
the implicit function theorem applied to F(z, u*(z)) = 0, z = (q, p), A = dF/du = -ell_uu, W = A^{-1}:
writing D^beta F = A u_beta + R_beta (R_beta free of the top-order derivative u_beta),

    u_beta = -W R_beta,   R_(j) = dF/dz_j (partial),   R_(beta + i) = (D_i A) u_beta + D_i R_beta,

with D_i the total derivative d/dz_i = partial_i + sum_k u_{k,(i)} partial_{u_k} (+ u_{k,beta+i} for
u_{k,beta}). W stays a leaf that is never differentiated. Everything is forward-mode differentiation
done symbolically on a DAG of small named nodes, so expressions never swell: the partial derivatives
of ell in (q, u) are the leaves ("primitives", one CSE pass), every other node is a short polynomial
in earlier nodes, u and W. At run time u* is found by Newton on F and W = A^{-1} numerically
(vcirun/maps/gauss.py). This replaces Appendix A step 2, whose printed second derivatives of
qbar are not used (D_pp qbar and D_qp qbar are printed with the wrong sign, see
tests/convergence/test_modified_series.py).

Modified Hamiltonian
--------------------
H~^{O(h^s)} = sum_{i=1..s} h^{i-1} H_i[eta] with H_i the symplectic-Euler series of vcirun/modified/
series.py (derived there from the Hamilton-Jacobi equation).

What keeps the symbolic work small as n grows (forming every jet of eta up to order s entry by entry
costs n^2.9 symbolic time and 1.1 MB of source for MCVAC at n = 8):
- Primitives from per-node tensors: every Ld the MCVA family takes is a quadrature rule of L in
  each stage, so each derivative of ell is a short sum of d^A M_bc and d^A V at the nodes (one
  entry's derivative each) times stage velocities (`StationaryEta._tensor_prim`); ell itself, whose
  size grows as n^2, is never differentiated.
- The value from the index-free series (`series.directional_series`): each monomial of H_2..H_4 is
  a q/p contraction tree, i.e. a derivative of eta along the frozen directions A = (0, eta_q),
  B = (eta_p, 0), or a sum over j of two such with one free index: O(n) jets of order <= s - 1,
  not all O(n^(s-1)) of them.
- The gradient by reverse mode over the value's program, closed by the implicit function theorem
  for u* and W (`vcirun.codegen.mh_kernels.emit_grad_kernel`): no jets of order s at all.
- Above 4 stage velocities, U_beta = -W R_beta and its adjoint are numba loops, not m^2 unrolled
  products.
Every step was checked against the previous kernels (values, gradients, Hessians equal to
6e-16 relative on the cart-pendulum, the double pendulum and a 3-link pendulum, for every Ld and
s), and by tests/unit/test_mh_primitives.py. Measurements: docs/performance.md (Scaling).
"""
from __future__ import annotations

import time
from functools import lru_cache
from itertools import product

import sympy as sp

from ..discrete.lagrangians import LIBRARY, get_ld, ld_expression
from .series import directional_series

DERIVE_LOG: list[dict] = []  # timings of each derivation (for reports/benchmarks)

PREFIX = "mh_"  # prefix of every symbol (and so of every generated name)
_P = PREFIX


class StationaryEta:
    """eta(q, p) = stat_u [p . v(u) - ell(q, u)] for discrete Lagrangian `ld_name` of `system`.
    per_node=False: primitives by differentiating ell itself (the reference the tests compare to)."""

    def __init__(self, system, ld_name: str, per_node: bool = True):
        # A forced system: eta is that of the conservative discrete Lagrangian (ell below is built
        # from L alone); the force enters the partial flow's equations, not H~ (docs/derivations/forcing.md).
        ld = get_ld(ld_name)
        n = system.n
        self.n = n
        self.h = sp.Symbol("hh")
        self.q = list(system.q)
        self.p = [sp.Symbol(f"{_P}p{i}") for i in range(n)]
        self.stages = tuple(ld.stages)
        self.m = len(self.stages) * n
        m = self.m
        self.u = [sp.Symbol(f"{_P}u{k}") for k in range(m)]
        h = self.h
        C = [[0] * n for _ in range(m)]  # C[k][j] = d v_j / d u_k
        for st, (name, frac) in enumerate(self.stages):
            for j in range(n):
                C[st * n + j][j] = sp.nsimplify(frac)
        self.C = C
        self.v = [sum(C[k][j] * self.u[k] for k in range(m)) for j in range(n)]
        self.params = system.param_symbols
        self.xvars = self.q + self.u  # variables of the primitives ell_alpha
        self.prim_expr: dict = {}
        self.tensor_def: dict = {}    # node-tensor symbol -> explicit expression in (q, u, h, prm)
        self._nodes = self._quadrature(system) if per_node else None
        if self._nodes is None:  # not a quadrature rule of L (or asked for): differentiate ell itself
            qs = list(self.q)
            ell = 0
            for st, (name, frac) in enumerate(self.stages):
                f = sp.nsimplify(frac)
                qn = [a + f * h * b for a, b in zip(qs, self.u[st * n:(st + 1) * n])]
                ell += ld_expression(system, LIBRARY[name], qs, qn, f * h)
                qs = qn
            ell = sp.expand(ell / h)
            if any(pw.base == h and pw.exp.is_negative for pw in ell.atoms(sp.Pow)) or ell.has(sp.zoo, sp.nan):
                raise ValueError(f"ld: {ld_name} is not regular as h -> 0 in the velocity parametrisation")
            self.prim_expr[()] = ell
        self.ell = self.prim(())
        self.F = [sum(C[k][j] * self.p[j] for j in range(n)) - self.prim((n + k,)) for k in range(m)]
        self.A = sp.Matrix(m, m, lambda a, b: -self.prim((n + a, n + b)))

    # -- primitives from per-node tensors ---------------------------------------------------------
    # Every Ld of MH_LDS is a quadrature rule of L in each stage (vcirun.codegen.tensor), so
    #     ell(q, u) = sum_N c_N L(x_N, w_s(N)),   x_N = q + h sum_t beta_Nt w_t,
    # (c_N = f_s W_i, beta_Nt = f_t for t < s, C_i f_s for t = s). A y = (q, u) derivative of L(x_N, w)
    # is a sum over the choices x- or w-derivative for each index, and L = 1/2 w^T M(x) w - V(x) is
    # quadratic in w, so every primitive is a short sum of the node tensors d^A M_bc (x_N), d^A V(x_N)
    # (each the derivative of ONE entry, at the node) times u's: no diff of ell, whose size grows as n^2.
    def _quadrature(self, system):
        from ..discrete.quadrature import quadrature_nodes

        nodes = []
        for s_, (name, frac) in enumerate(self.stages):
            qn = quadrature_nodes(LIBRARY[name])
            if qn is None:
                return None
            f = sp.nsimplify(frac)
            for c, w in qn:
                c = sp.nsimplify(c)
                beta = {t: sp.nsimplify(self.stages[t][1]) for t in range(s_)}
                beta[s_] = c * f
                beta = {t: b for t, b in beta.items() if b != 0}
                nodes.append((f * sp.nsimplify(w), s_, beta))
        self._M = system.M
        self._V = system.V
        # the entries (b, c) of M whose derivative d^A M_bc is not identically 0 for a multi-index A:
        # M_bc not 0 and depending on every q_a of A (n of the n^2 for a diagonal M and A = (), none
        # for a constant M and A != ()); the sums over b, c below run over these only
        q = list(self.q)
        self._deps = {(b, c): {a for a, qa in enumerate(q) if system.M[b, c].has(qa)}
                      for b in range(self.n) for c in range(self.n) if system.M[b, c] != 0}
        self._nzmemo: dict = {}
        self._vdeps = {a for a, qa in enumerate(q) if sp.sympify(system.V).has(qa)}
        self._dmemo: dict = {}
        return nodes

    def _d(self, kind, A, b=0, c=0):
        """d^A M_bc (kind 'M', b <= c) or d^A V (kind 'V') as an expression in q (memoised)."""
        key = (kind, A, b, c)
        if key not in self._dmemo:
            if not A:
                self._dmemo[key] = sp.sympify(self._M[b, c] if kind == "M" else self._V)
            else:
                self._dmemo[key] = sp.diff(self._d(kind, A[:-1], b, c), self.q[A[-1]])
        return self._dmemo[key]

    def _tensor(self, N, kind, A, b=0, c=0):
        """Symbol of d^A M_bc or d^A V at node N (0 if structurally zero); defined in tensor_def."""
        A = tuple(sorted(A))
        b, c = min(b, c), max(b, c)
        e = self._d(kind, A, b, c)
        if e == 0:
            return sp.S.Zero
        sym = sp.Symbol(f"{_P}T{N}{kind}_{b}_{c}_" + "_".join(map(str, A)) if kind == "M"
                        else f"{_P}T{N}V_" + "_".join(map(str, A)))
        if sym not in self.tensor_def:
            _, s_, beta = self._nodes[N]
            h, n = self.h, self.n
            x = {qa: qa + h * sum(bt * self.u[t * n + a] for t, bt in beta.items()) for a, qa in enumerate(self.q)}
            self.tensor_def[sym] = e.xreplace(x) if beta else e
        return sym

    def _nz(self, A) -> list:
        """[(b, c), ...]: the entries of M with d^A M_bc possibly nonzero (see _quadrature)."""
        if A not in self._nzmemo:
            need = set(A)
            self._nzmemo[A] = [bc for bc, dep in self._deps.items() if need <= dep]
        return self._nzmemo[A]

    def _may_be_nonzero(self, A, B) -> bool:
        """Can the node tensor of (A, B) in _tensor_prim be nonzero (d^A of an entry of M, or of V,
        that depends on every q_a of A)? False only where it is identically 0."""
        if len(B) == 2:
            dep = self._deps.get((B[0], B[1]))
            return dep is not None and set(A) <= dep
        if len(B) == 1:
            return any(b == B[0] for b, _ in self._nz(A))
        return bool(self._nz(A)) or set(A) <= self._vdeps

    def _tensor_prim(self, alpha):
        n = self.n
        h = self.h
        total = sp.S.Zero
        for N, (cN, s_, beta) in enumerate(self._nodes):
            w = self.u[s_ * n:(s_ + 1) * n]
            # each y index -> [(coefficient, 'x' | 'w', component)]
            choices = []
            for j in alpha:
                if j < n:
                    choices.append([(sp.S.One, "x", j)])
                else:
                    t, b = divmod(j - n, n)
                    opts = [(h * beta[t], "x", b)] if t in beta else []
                    if t == s_:
                        opts.append((sp.S.One, "w", b))
                    choices.append(opts)
            terms: dict = {}
            for combo in product(*choices):
                A = tuple(sorted(c[2] for c in combo if c[1] == "x"))
                B = tuple(sorted(c[2] for c in combo if c[1] == "w"))
                if len(B) > 2 or not self._may_be_nonzero(A, B):
                    continue   # (a structurally zero tensor: its coefficient is not even formed)
                coef = sp.Mul(*[c[0] for c in combo])
                terms[A, B] = terms.get((A, B), 0) + coef
            for (A, B), coef in terms.items():
                if coef == 0:
                    continue
                if len(B) == 2:
                    val = self._tensor(N, "M", A, *B)
                elif len(B) == 1:
                    val = sp.Add(*[self._tensor(N, "M", A, B[0], c) * w[c] for b, c in self._nz(A) if b == B[0]])
                else:
                    val = sp.Rational(1, 2) * sp.Add(*[self._tensor(N, "M", A, b, c) * w[b] * w[c]
                                                       for b, c in self._nz(A)]) - self._tensor(N, "V", A)
                total += cN * coef * val
        return total

    def explicit(self, e):
        """e with the node-tensor symbols replaced by their definitions (explicit in q, u, h, prm)."""
        return sp.sympify(e).xreplace(self.tensor_def) if self.tensor_def else sp.sympify(e)

    def prim(self, alpha):
        """d^|alpha| ell / dx_alpha, x = (q, u), for a multi-index alpha: an expression in the node
        tensors (quadrature Lds) or explicit in (q, u) (otherwise)."""
        alpha = tuple(sorted(alpha))
        if alpha not in self.prim_expr:
            if self._nodes is not None:
                self.prim_expr[alpha] = self._tensor_prim(alpha)
            else:
                self.prim_expr[alpha] = sp.diff(self.prim(alpha[:-1]), self.xvars[alpha[-1]])
        return self.prim_expr[alpha]


class DerivativeDag:
    """Symbolic forward-mode total derivatives d/dz_j of eta on a DAG of named nodes."""

    def __init__(self, st: StationaryEta):
        self.st = st
        n, m = st.n, st.m
        self.n, self.m = n, m
        self.W = [[sp.Symbol(f"{_P}W{min(a, b)}_{max(a, b)}") for b in range(m)] for a in range(m)]
        self.kind: dict = {}
        for i, s in enumerate(st.q):
            self.kind[s] = ("z", i)
        for i, s in enumerate(st.p):
            self.kind[s] = ("z", n + i)
        for k, s in enumerate(st.u):
            self.kind[s] = ("u", k)
        for a in range(m):
            for b in range(a, m):
                self.kind[self.W[a][b]] = ("W", a, b)
        # directions A = (0, eta_q), B = (eta_p, 0) of the index-free series (series.directional_series):
        # z-indices 2n (A) and 2n + 1 (B). Their components are frozen symbols for the forward
        # derivatives (kind "dir") and ordinary program variables (defs) for the reverse sweep.
        self.dirsym = {2 * n: [sp.Symbol(f"{_P}dA{j}") for j in range(n)],
                       2 * n + 1: [sp.Symbol(f"{_P}dB{j}") for j in range(n)]}
        for syms in self.dirsym.values():
            for x in syms:
                self.kind[x] = ("dir",)
        self._dirs_defined = False
        self.prim_expr = st.prim_expr         # alpha -> expression (shared with st)
        self.prim_sym: dict = {}              # alpha -> symbol (or constant)
        self.defs: dict = {}                  # node symbol -> expression (creation order = topological)
        self._dmemo: dict = {}
        self._E: dict = {}
        self._count = 0

    # -- leaves: partial derivatives of ell in (q, u) -------------------------------------------
    def L(self, alpha):
        alpha = tuple(sorted(alpha))
        if alpha in self.prim_sym:
            return self.prim_sym[alpha]
        e = self.st.prim(alpha)
        if e.is_number:
            self.prim_sym[alpha] = e
        else:
            s = sp.Symbol(f"{_P}L" + "_".join(map(str, alpha)))
            self.kind[s] = ("prim", alpha)
            self.prim_sym[alpha] = s
        return self.prim_sym[alpha]

    def _node(self, e):
        """Name e unless it is trivial (number, symbol, or a number times a symbol)."""
        e = sp.sympify(e)
        if e.is_number or e.is_Symbol:
            return e
        if e.is_Mul and len(e.args) == 2 and e.args[0].is_number and e.args[1].is_Symbol:
            return e
        self._count += 1
        s = sp.Symbol(f"{_P}n{self._count}")
        self.kind[s] = ("node",)
        self.defs[s] = e
        return s

    # -- total derivatives ------------------------------------------------------------------------
    # Derivatives of u* come from differentiating F(z, u*(z)) = 0: with A = dF/du and
    # D^beta F = A u_beta + R_beta (R_beta free of the top-order u_beta),
    #     u_beta = -W R_beta,   R_{(j)} = dF/dz_j (partial),   R_{beta+i} = (D_i A) u_beta + D_i R_beta,
    # so W is a leaf that is never differentiated (no dW = -W dA W expansions: they cost m^4 terms).
    def R(self, beta):
        """R_beta (m entries) for a sorted multi-index beta over z."""
        beta = tuple(sorted(beta))
        key = ("R", beta)
        if key not in self._dmemo:
            n, m = self.n, self.m
            if len(beta) == 1:
                j = beta[0]
                if j < n:   # dF_l/dq_j = -ell_{u_l q_j}
                    r = [self._node(-self.L((n + l, j))) for l in range(m)]
                elif j < 2 * n:       # dF_l/dp_j = C[l][j]
                    r = [sp.sympify(self.st.C[l][j - n]) for l in range(m)]
                elif j == 2 * n:      # along A = (0, dA): sum_j dA_j C[l][j]
                    d = self.directions()[j]
                    r = [self._node(sum(self.st.C[l][i] * d[i] for i in range(n))) for l in range(m)]
                else:                 # along B = (dB, 0): -sum_j dB_j ell_{u_l q_j}
                    d = self.directions()[j]
                    r = [self._node(-sum(d[i] * self.L((n + l, i)) for i in range(n))) for l in range(m)]
            else:
                i, rest = beta[0], beta[1:]
                r = []
                for l in range(m):
                    e = self.D(self.R(rest)[l], i)
                    for k in range(m):
                        uk = self.U(k, rest)
                        if uk != 0:
                            dA = self.Dsym(self.L((n + l, n + k)), i)   # D_i A_lk = -D_i ell_{u_l u_k}
                            if dA != 0:
                                e -= dA * uk
                    r.append(self._node(e))
            self._dmemo[key] = r
        return self._dmemo[key]

    def U(self, k, beta):
        """d^|beta| u*_k / dz_beta: always a named symbol (its derivative is U(k, beta + i)) or 0."""
        beta = tuple(sorted(beta))
        if not beta:
            return self.st.u[k]
        key = ("U", k, beta)
        if key not in self._dmemo:
            e = -sum(self.W[k][l] * r for l, r in enumerate(self.R(beta)))
            e = sp.sympify(e)
            if e == 0:
                self._dmemo[key] = sp.S.Zero
            else:
                self._count += 1
                sym = sp.Symbol(f"{_P}n{self._count}")
                self.kind[sym] = ("U", k, beta)
                self.defs[sym] = e
                self._dmemo[key] = sym
        return self._dmemo[key]

    def Dsym(self, s, j):
        if s.is_number:
            return sp.S.Zero
        k = self.kind.get(s)
        if k is None:   # h, parameters
            return sp.S.Zero
        key = (s, j)
        if key in self._dmemo:
            return self._dmemo[key]
        tag = k[0]
        if tag == "dir":
            return sp.S.Zero
        if tag == "z":
            if j < 2 * self.n:
                r = sp.S.One if k[1] == j else sp.S.Zero
            else:  # component of the direction: A moves p only, B moves q only
                i = k[1] - (self.n if j == 2 * self.n else 0)
                r = self.directions()[j][i] if 0 <= i < self.n and (k[1] >= self.n) == (j == 2 * self.n) else sp.S.Zero
        elif tag == "u":
            r = self.U(k[1], (j,))
        elif tag == "U":
            r = self.U(k[1], k[2] + (j,))
        elif tag == "W":
            raise AssertionError("W = A^{-1} is a leaf: it must never be differentiated")
        elif tag == "prim":
            alpha = k[1]
            if j < self.n:
                e = self.L(alpha + (j,))
            elif j == 2 * self.n + 1:  # along B: the q-part of the direction
                e = sum(di * self.L(alpha + (i,)) for i, di in enumerate(self.directions()[j]))
            else:
                e = 0
            for kk in range(self.m):
                du = self.U(kk, (j,))
                if du != 0:
                    lk = self.L(alpha + (self.n + kk,))
                    if lk != 0:
                        e += lk * du
            r = self._node(e)
        else:
            r = self._node(self.D(self.defs[s], j))
        self._dmemo[key] = r
        return r

    def D(self, e, j):
        e = sp.sympify(e)
        out = sp.S.Zero
        # (symbols in name order: a set's order follows the hash seed, and the order in which nodes
        # are created decides the generated program, hence its rounding)
        for s in sorted(e.free_symbols, key=lambda x: x.name):
            ds = self.Dsym(s, j)
            if ds != 0:
                out += sp.diff(e, s) * ds
        return out

    # -- derivatives of eta -----------------------------------------------------------------------
    def E(self, alpha):
        """d^|alpha| eta / dz_alpha for a sorted multi-index alpha over z = (q, p) and the frozen
        directions (index 2n: A, 2n + 1: B)."""
        alpha = tuple(sorted(alpha))
        if alpha in self._E:
            return self._E[alpha]
        n = self.n
        if not alpha:    # eta = G(q, p, u*)
            r = self._node(sum(pj * vj for pj, vj in zip(self.st.p, self.st.v)) - self.L(()))
        elif len(alpha) == 1:  # envelope identities: eta_q = -ell_q, eta_p = v(u*)
            j = alpha[0]
            if j < 2 * n:
                r = self._node(-self.L((j,)) if j < n else self.st.v[j - n])
            else:  # D_A eta = dA . eta_p, D_B eta = dB . eta_q
                d = self.directions()[j]
                r = self._node(sum(d[i] * (self.st.v[i] if j == 2 * n else -self.L((i,))) for i in range(n)))
        else:
            r = self._node(self.D(self.E(alpha[1:]), alpha[0]))
        self._E[alpha] = r
        return r

    def directions(self) -> dict:
        """{2n: dA, 2n + 1: dB} with dA = eta_q, dB = eta_p, defined (in defs) on first use."""
        if not self._dirs_defined:
            self._dirs_defined = True
            for j in range(self.n):
                self.defs[self.dirsym[2 * self.n][j]] = -self.L((j,))
                self.defs[self.dirsym[2 * self.n + 1][j]] = self.st.v[j]
        return self.dirsym

    def directional_expr(self, terms):
        """sum c * value(descriptor) of series.directional_series: ('jet', dirs) = D_dirs eta,
        ('pair', du, dv) = sum_j D_du eta_{q_j} D_dv eta_{p_j}."""
        n = self.n
        idx = {"A": 2 * n, "B": 2 * n + 1}
        out = sp.S.Zero
        for c, d in terms:
            coef = sp.Rational(c.numerator, c.denominator)
            if d[0] == "jet":
                out += coef * self.E(tuple(idx[x] for x in d[1]))
            else:
                du = tuple(idx[x] for x in d[1])
                dv = tuple(idx[x] for x in d[2])
                out += coef * sum(self.E((j,) + du) * self.E((n + j,) + dv) for j in range(n))
        return out


@lru_cache(maxsize=None)
def derive_modified(system, ld_name: str, mh_order: int):
    """(StationaryEta, DerivativeDag, outputs) for one (system, Ld, s); cached per process.
    Only the directional jets of eta that the VALUE of H~^{O(h^s)} needs (order <= s - 1) and eta's
    Hessian are derived: the gradient is the reverse-mode adjoint of the value's program."""
    t0 = time.perf_counter()
    st = StationaryEta(system, ld_name)
    dag = DerivativeDag(st)
    n, h = st.n, st.h
    terms = [dag._node(dag.directional_expr(Ti)) for Ti in directional_series(mh_order)]
    value = sum(h ** i * t for i, t in enumerate(terms))
    hess = [[dag.E((i, j)) for j in range(2 * n)] for i in range(2 * n)]
    DERIVE_LOG.append({"system": system.name, "ld": ld_name, "mh_order": mh_order,
                       "derive_s": time.perf_counter() - t0, "nodes": len(dag.defs), "primitives": len(dag.prim_sym)})
    return st, dag, {"terms": terms, "value": value, "hess": hess}
