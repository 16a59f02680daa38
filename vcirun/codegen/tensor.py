"""Step kernels from per-slot tensors: the default kernel path of vcirun.codegen.

The expanded path (vcirun.discrete.lagrangians.step_expressions) differentiates the whole Ld in
(q0, v, h) symbolically: every entry of dPm/dv mixes M(q0), M(q0 + h v), their derivatives and V,
and CSE has to rediscover the shared pieces in n^2 growing expressions. For the mechanical
Lagrangian L(q, v) = 1/2 v^T M(q) v - V(q) every explicit discrete Lagrangian of the library is a
quadrature rule

    Ld(q0, q1, h) = h sum_i W_i L(x_i, v),   x_i = q0 + C_i (q1 - q0) = q0 + C_i h v,   v = (q1 - q0)/h

(SE1: C = 0; SE2: C = 1; midpoint: C = 1/2; SVC: C in {0, 1}, W = 1/2 each; the nodes are read off
the Ld's own `build` function by `quadrature_nodes`, so a new Ld of this form is picked up and any
other falls back to the expanded path). Its slot derivatives are small contractions of the tensors

    M(q) (n x n),  dM[a, j, b] = dM_aj / dq_b,  dV(q),  and only for interior nodes 0 < C < 1
    d2M[j, l, a, b] = d^2 M_jl / dq_a dq_b,  d2V(q).

With, at a node x = x_i,
    T[a, b] = sum_j dM_aj/dq_b (x) v_j
    gL[a]   = dL/dq_a (x, v) = 1/2 sum_j v_j T[j, a] - dV_a(x)
    S[a, b] = d^2 L/dq_a dq_b (x, v) = 1/2 v^T (d^2 M/dq_a dq_b) v - d^2 V/dq_a dq_b
and dx/dq0 = (1 - C), dx/dq1 = C, dv/dq0 = -1/h, dv/dq1 = 1/h, dx/dv = C h (at fixed q0):

    Pm   = -D1 Ld - f^- = sum_i W_i [M(x_i) v - h (1 - C_i) gL_i] - a h f(q0, v, t)
    Pp   =  D2 Ld + f^+ = sum_i W_i [M(x_i) v + h C_i gL_i]       + b h f(q1, v, t + h)
    dPm/dv              = sum_i W_i [M(x_i) + C_i h T_i - h (1 - C_i) (T_i^T + C_i h S_i)]
                          - a h df/dqdot(q0, v, t)
    Ed   = -D3 Ld       = sum_i W_i [1/2 v^T M(x_i) v + V(x_i)]    (D3 at fixed q0, q1: the h in
                          front gives L, dv/dh = -v/h gives -v^T M v; the force does not enter Ed)
    dEd/dv              = sum_i W_i [M(x_i) v + C_i h (1/2 v^T dM/dq(x_i) v + dV(x_i))]

(a, b) = the Ld's forcing_weights (trapezoidal discrete Lagrange-d'Alembert forces f^- = a h f(q0,
v, t), f^+ = b h f(q1, v, t + h), as in step_expressions; forced systems stay on this path: f and
df/dqdot are derived once, like the tensors). No formula divides by h: the kernels are regular at
h = 0 (partial steps of length 0 right at an impact) and for h < 0 (stages of compositions with
negative fractions). Second derivatives enter only dPm/dv of an Ld with an interior node
(midpoint), and only then are they derived; dEd/dv (R^VCI) needs first derivatives only.

Symbolic work: the upper triangle of M, the structurally nonzero entries of dM (d2M), dV (d2V) --
each the derivative of one small entry -- go through ONE CSE pass (`tensor_data`); nothing of
the step (no q0 + h v, no slot derivative) is ever a sympy expression. Emission: each of
`<LD>_PmJc(q0, v, h, t, prm, c, r, J)`, `<LD>_Ppc(q0, v, h, t, prm, c, out, cn)`, `<LD>_Ed(q0, v, h,
prm)` and `<LD>_Edv(q0, v, h, prm, out)` is ONE numba function of straight-line scalar code: for each
node the CSE'd tensor code is instantiated with the node's coordinates x_i (a renaming, no sympy),
then the contractions are written out over the structural nonzeros only (the n-link pendulum's dM
has 2 n (n - 1) nonzeros of n^3). Its size is O(tensor kernel + nnz(dM) + n^2) per node.

Node data (`node_source`): c = sys_node(q) holds the first-order tensors of q (template T1). A node
at C = 0 sits at the step's start q0 and does not move with v, so PmJc and Ppc read its tensors
from c (computed once per step or stage) instead of once per Newton iteration, and Ppc writes cn =
sys_node(q0 + h v), bit for bit the data of the next stage's start (the full step swaps c and cn;
the velocity guess takes M from c). An SVC stage thus costs 3 node evaluations (2 Newton
iterations + Pp) instead of 7. <LD>_PmJ and <LD>_Pp keep the plain signatures (the expanded
kernels'), as wrappers that compute c first.

Why this form (measured, n = 2 and 8, against the expanded kernels): a generic numba routine
parameterised by arrays (C, W) behind per-Ld wrappers, and loops over constant sparsity arrays,
compute the same numbers, but every jitted function costs ~0.25 s of compile time however small and
every work array is a heap allocation (~40 ns): they were 3-6x slower per call at n = 2. Scalar
code has no allocation, and numba compiles it like the expanded kernels (only smaller).
"""
from __future__ import annotations

import re
import weakref
from dataclasses import dataclass

import sympy as sp

from ..discrete.quadrature import quadrature_nodes
from .kernels import ZERO_FILL_MIN, _code

_NJ = '@njit(cache=True, nogil=True, error_model="numpy")'


# --- which Lds are quadrature rules: vcirun.discrete.quadrature -----------------------------------
def needs_second_derivatives(nodes) -> bool:
    """dPm/dv needs d2M, d2V only through the term h^2 C (1 - C) S: interior nodes."""
    return any(c * (1.0 - c) != 0.0 for c, _ in nodes)


# --- symbolic tensors: one CSE pass each, with placeholder names --------------------------------
# (names no system symbol plausibly has: a parameter printed s_vcTQ0 would be renamed)
_QP = "vcTQ"   # coordinate placeholders vcTQ0.. (printed s_vcTQ0..); qdot vcTV0..; time vcTT
_TMP = "vcTC"  # CSE temporaries vcTC0..
_OUT = "vcTG"  # outputs vcTG0..


@dataclass
class Template:
    """CSE'd code of a list of expressions in placeholder coordinates: `lines` assign TG<k>."""

    lines: list
    zero: set  # output indices that are structurally 0

    def instantiate(self, tag: str, coords, qdots=None, t=None) -> list:
        """The lines with coordinates -> `coords`, CSE temps -> <tag>c<k>, outputs -> <tag>_<k>."""
        subs = [(re.compile(rf"\bs_{_QP}(\d+)\b"), lambda m: coords[int(m.group(1))]),
                (re.compile(rf"\b{_TMP}(\d+)\b"), lambda m: f"{tag}c{m.group(1)}"),
                (re.compile(rf"\b{_OUT}(\d+)\b"), lambda m: f"{tag}_{m.group(1)}")]
        if qdots is not None:
            subs.append((re.compile(r"\bs_vcTV(\d+)\b"), lambda m: qdots[int(m.group(1))]))
        if t is not None:
            subs.append((re.compile(r"\bs_vcTT\b"), lambda m: t))
        out = []
        for ln in self.lines:
            for rx, fn in subs:
                ln = rx.sub(fn, ln)
            out.append(ln)
        return out


def _template(exprs, system, qdot=False, time=False) -> Template:
    sub = {s: sp.Symbol(f"{_QP}{a}") for a, s in enumerate(system.q)}
    if qdot:
        sub |= {s: sp.Symbol(f"vcTV{a}") for a, s in enumerate(system.qd)}
    if time:
        sub[system.t] = sp.Symbol("vcTT")
    exprs = [sp.sympify(e).xreplace(sub) for e in exprs]
    zero = {k for k, e in enumerate(exprs) if e == 0}
    repl, red = sp.cse(exprs, symbols=sp.numbered_symbols(_TMP), order="none")
    tmp = {s for s, _ in repl}
    lines = [f"{s.name} = {_code(e, tmp)}" for s, e in repl]
    lines += [f"{_OUT}{k} = {_code(e, tmp)}" for k, e in enumerate(red) if k not in zero]
    return Template(lines, zero)


_TD_MEMO: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def tensor_data(system, second: bool) -> dict:
    """tensor_data_uncached, memoised per system (the system kernels and the step kernels of one
    module share one derivation; a second-order entry serves first-order requests)."""
    memo = _TD_MEMO.setdefault(system, {})
    fp = system.fingerprint()
    for sec in ((True,) if second else (False, True)):
        if (fp, sec) in memo:
            return memo[fp, sec]
    memo[fp, second] = tensor_data_uncached(system, second)
    return memo[fp, second]


def tensor_data_uncached(system, second: bool) -> dict:
    """Entries and sparsity pattern of the tensors of `system`, and their CSE'd templates:
      g1 = [M_ij (i <= j: MI, MJ)] + [dM_ij/dq_k, structural nonzeros (DI, DJ, DK)] + [dV_k]
      g0 = [M_ij (i <= j)] + [V]                                   (Ed needs no derivative)
      g2 = [d2M_ij/dq_a dq_b, nonzeros, i <= j, a <= b (I2, J2, A2, B2)] + [d2V, nonzeros, a <= b
           (VA, VB)]                                                (only with second=True)
      forcing: [f_a] + [df_a/dqdot_b]                              (forced systems)"""
    n = system.n
    q = list(system.q)
    M = system.M
    MI, MJ, g_m = [], [], []
    DI, DJ, DK, g_dm = [], [], [], []
    dM = {}
    for i in range(n):
        for j in range(i, n):
            MI.append(i)
            MJ.append(j)
            g_m.append(M[i, j])
            free = M[i, j].free_symbols
            for k in range(n):
                if q[k] not in free:  # (structurally zero: no derivative to take)
                    continue
                d = sp.diff(M[i, j], q[k])
                if d != 0:
                    dM[i, j, k] = d
                    DI.append(i)
                    DJ.append(j)
                    DK.append(k)
                    g_dm.append(d)
    dV = [sp.diff(system.V, s) for s in q]
    out = {"MI": MI, "MJ": MJ, "DI": DI, "DJ": DJ, "DK": DK, "n_g1": len(g_m) + len(g_dm) + n,
           "T1": _template(g_m + g_dm + dV, system), "T0": _template(g_m + [system.V], system)}
    if second:
        I2, J2, A2, B2, g_2m = [], [], [], [], []
        for (i, j, a), d in dM.items():
            for b in range(a, n):
                d2 = sp.diff(d, q[b])
                if d2 != 0:
                    I2.append(i)
                    J2.append(j)
                    A2.append(a)
                    B2.append(b)
                    g_2m.append(d2)
        VA, VB, g_2v = [], [], []
        for a in range(n):
            free = dV[a].free_symbols
            for b in range(a, n):
                if q[b] not in free:
                    continue
                d2 = sp.diff(dV[a], q[b])
                if d2 != 0:
                    VA.append(a)
                    VB.append(b)
                    g_2v.append(d2)
        out |= {"I2": I2, "J2": J2, "A2": A2, "B2": B2, "VA": VA, "VB": VB, "T2": _template(g_2m + g_2v, system)}
    if system.is_forced:
        f = system.forcing
        fv = f.jacobian(list(system.qd))
        out["TF"] = _template(list(f) + [fv[a, b] for a in range(n) for b in range(n)], system, qdot=True, time=True)
    return out


# --- emission ------------------------------------------------------------------------------------
def _f(x: float) -> str:
    return repr(float(x))


def _sum(terms) -> str:
    """terms: [(sign +1/-1, text)] -> a Python sum (0.0 if empty)."""
    if not terms:
        return "0.0"
    out = ("-" if terms[0][0] < 0 else "") + terms[0][1]
    for s, t in terms[1:]:
        out += (" - " if s < 0 else " + ") + t
    return out


class _Gen:
    """Straight-line body of one step kernel."""

    def __init__(self, system, td):
        self.system, self.td, self.n = system, td, system.n
        self.lines = []
        self.midx = {(a, j): k for k, (a, j) in enumerate(zip(td["MI"], td["MJ"]))}
        self.nm = len(td["MI"])
        self.ndm = len(td["DI"])

    def __call__(self, line: str):
        self.lines.append("    " + line)

    def prologue(self, q0="q0", v="v"):
        """Parameters and inputs (arrays named q0, v; v=None: no velocity) as locals q0_a, v_a
        (unused ones cost nothing)."""
        for i, s in enumerate(self.system.param_symbols):
            self(f"s_{''.join(c if c.isalnum() else '_' for c in s.name)} = prm[{i}]")
        for a in range(self.n):
            self(f"q0_{a} = {q0}[{a}]")
            if v is not None:
                self(f"v_{a} = {v}[{a}]")

    def coords(self, i: int, c: float) -> list:
        """Names of node i's coordinates x = q0 + C h v."""
        if c == 0.0:
            return [f"q0_{a}" for a in range(self.n)]
        ch = "h" if c == 1.0 else f"ch{i}"
        if c != 1.0:
            self(f"ch{i} = {_f(c)} * h")
        for a in range(self.n):
            self(f"x{i}_{a} = q0_{a} + {ch} * v_{a}")
        return [f"x{i}_{a}" for a in range(self.n)]

    def tensors(self, key: str, tag: str, coords):
        for ln in self.td[key].instantiate(tag, coords):
            self(ln)

    def node(self, i: int, c: float, w: float, key: str = "T1", cached: str | None = None) -> tuple:
        """Open quadrature node i (x = q0 + C h v): its coordinates and tensor template `key`, as
        locals named n<i>_*; with `cached` (C = 0 only) the first-order tensors are read from that
        node-data array (sys_node at q0) instead of computed. Returns (tag, coordinate names)."""
        self(f"# node {i}: C = {c!r}, W = {w!r}" + (f" (tensors from {cached})" if cached else ""))
        tag = f"n{i}"
        xs = self.coords(i, c)
        if cached is not None:
            assert c == 0.0
            self.load(tag, cached)
        else:
            self.tensors(key, tag, xs)
        return tag, xs

    def load(self, tag: str, arr: str):
        """<tag>_k = arr[k] for the structural nonzeros k of template T1 (the node-data layout)."""
        for k in range(self.td["n_g1"]):
            if k not in self.td["T1"].zero:
                self(f"{tag}_{k} = {arr}[{k}]")

    def store(self, tag: str, arr: str):
        """arr[k] = <tag>_k: the node data of a node whose T1 tensors are open as <tag>_*."""
        for k in range(self.td["n_g1"]):
            if k not in self.td["T1"].zero:
                self(f"{arr}[{k}] = {tag}_{k}")

    def add_weighted_Mv(self, tag, w, out: dict):
        """out[a] += W (M(x) v)_a for node `tag`; returns the M v locals."""
        mv = self.Mv(tag)
        for a in range(self.n):
            out[a].append((1, f"{_f(w)} * {mv[a]}"))
        return mv

    def M(self, tag, a, b) -> str | None:
        k = self.midx[min(a, b), max(a, b)]
        return None if k in self.td["T1"].zero else f"{tag}_{k}"

    def Mv(self, tag) -> dict:
        out = {}
        for a in range(self.n):
            ts = [(1, f"{m} * v_{j}") for j in range(self.n) if (m := self.M(tag, a, j))]
            out[a] = f"{tag}mv_{a}"
            self(f"{out[a]} = {_sum(ts)}")
        return out

    def dV(self, tag, a) -> str | None:
        k = self.nm + self.ndm + a
        return None if k in self.td["T1"].zero else f"{tag}_{k}"

    def T(self, tag) -> dict:
        """T[a, b] = sum_j dM_aj/dq_b v_j as locals <tag>t_a_b (structural nonzeros only)."""
        terms = {}
        for k, (a, j, b) in enumerate(zip(self.td["DI"], self.td["DJ"], self.td["DK"])):
            d = f"{tag}_{self.nm + k}"
            terms.setdefault((a, b), []).append((1, f"{d} * v_{j}"))
            if a != j:
                terms.setdefault((j, b), []).append((1, f"{d} * v_{a}"))
        T = {}
        for (a, b), ts in sorted(terms.items()):
            T[a, b] = f"{tag}t_{a}_{b}"
            self(f"{T[a, b]} = {_sum(ts)}")
        return T

    def vTv(self, tag, T) -> dict:
        """sum_j v_j T[j, a] = v^T dM/dq_a v as locals <tag>q_a (None where structurally 0)."""
        out = {}
        for a in range(self.n):
            ts = [(1, f"v_{j} * {T[j, a]}") for j in range(self.n) if (j, a) in T]
            if ts:
                out[a] = f"{tag}q_{a}"
                self(f"{out[a]} = {_sum(ts)}")
        return out

    def gL(self, tag, T) -> dict:
        """gL[a] = dL/dq_a = 1/2 v^T dM/dq_a v - dV_a as locals <tag>l_a."""
        vtv = self.vTv(tag, T)
        out = {}
        for a in range(self.n):
            ts = [(1, f"0.5 * {vtv[a]}")] if a in vtv else []
            if (d := self.dV(tag, a)):
                ts.append((-1, d))
            out[a] = f"{tag}l_{a}"
            self(f"{out[a]} = {_sum(ts)}")
        return out

    def S(self, tag, coords) -> dict:
        """S[a, b] (a <= b) = 1/2 v^T d2M/dq_a dq_b v - d2V/dq_a dq_b as locals <tag>s_a_b."""
        td = self.td
        t2 = tag + "h"
        self.tensors("T2", t2, coords)
        terms = {}
        for k, (p, r, a, b) in enumerate(zip(td["I2"], td["J2"], td["A2"], td["B2"])):
            coef = "0.5 * " if p == r else ""
            terms.setdefault((a, b), []).append((1, f"{coef}{t2}_{k} * v_{p} * v_{r}"))
        off = len(td["I2"])
        for k, (a, b) in enumerate(zip(td["VA"], td["VB"])):
            terms.setdefault((a, b), []).append((-1, f"{t2}_{off + k}"))
        S = {}
        for (a, b), ts in sorted(terms.items()):
            S[a, b] = f"{tag}s_{a}_{b}"
            self(f"{S[a, b]} = {_sum(ts)}")
        return S

    def force(self, coords, t: str) -> list:
        """f(coords, v, t) and df/dqdot as locals fo_<k> (f_a: k = a; df_a/dqdot_b: k = n + a n + b)."""
        for ln in self.td["TF"].instantiate("fo", coords, [f"v_{a}" for a in range(self.n)], t):
            self(ln)
        return [None if k in self.td["TF"].zero else f"fo_{k}" for k in range(self.n * (self.n + 1))]

    def body(self) -> str:
        return "\n".join(self.lines) + "\n"


def _header(name, args, doc) -> str:
    return f'{_NJ}\ndef {name}({args}):\n    """{doc}"""\n'


def _pmj_source(system, td, name, nodes, fa) -> str:
    n = system.n
    e = _Gen(system, td)
    e.prologue()
    r_terms = {a: [] for a in range(n)}
    J_terms = {(a, b): [] for a in range(n) for b in range(n)}
    for i, (c, w) in enumerate(nodes):
        tag, xs = e.node(i, c, w, cached="c" if c == 0.0 else None)
        T = e.T(tag)
        e.add_weighted_Mv(tag, w, r_terms)
        wf = _f(w)
        for a in range(n):
            for b in range(n):
                if (m := e.M(tag, a, b)):
                    J_terms[a, b].append((1, f"{wf} * {m}"))
        if c != 1.0:  # -h W (1 - C) [gL, and its direct v-derivative T^T]
            e(f"hm{i} = {_f(w * (1.0 - c))} * h")
            gl = e.gL(tag, T)
            for a in range(n):
                r_terms[a].append((-1, f"hm{i} * {gl[a]}"))
                for b in range(n):
                    if (b, a) in T:
                        J_terms[a, b].append((-1, f"hm{i} * {T[b, a]}"))
        if c != 0.0:  # d(M(x) v)/dv through x = q0 + C h v
            e(f"hc{i} = {_f(w * c)} * h")
            for (a, b), t in T.items():
                J_terms[a, b].append((1, f"hc{i} * {t}"))
        if c * (1.0 - c) != 0.0:  # d gL/dv through x: -h^2 W C (1 - C) S
            e(f"k{i} = {_f(w * c * (1.0 - c))} * (h * h)")
            S = e.S(tag, xs)
            for a in range(n):
                for b in range(n):
                    if (key := (min(a, b), max(a, b))) in S:
                        J_terms[a, b].append((-1, f"k{i} * {S[key]}"))
    if system.is_forced and fa != 0.0:  # f^- = FA h f(q0, v, t), d f^-/dv = FA h df/dqdot
        e(f"# f^- = {fa!r} h f(q0, v, t)")
        fo = e.force([f"q0_{a}" for a in range(n)], "t")
        e(f"fh = {_f(fa)} * h")
        for a in range(n):
            if fo[a]:
                r_terms[a].append((-1, f"fh * {fo[a]}"))
            for b in range(n):
                if fo[n + a * n + b]:
                    J_terms[a, b].append((-1, f"fh * {fo[n + a * n + b]}"))
    for a in range(n):
        e(f"r[{a}] = {_sum(r_terms[a])}")
    fill = sum(1 for t in J_terms.values() if not t) >= ZERO_FILL_MIN  # (a sparse J: zeros by a loop)
    if fill:
        e(f"for i_ in range({n}):")
        e(f"    for j_ in range({n}):")
        e("        J[i_, j_] = 0.0")
    for a in range(n):
        for b in range(n):
            if J_terms[a, b] or not fill:
                e(f"J[{a}, {b}] = {_sum(J_terms[a, b])}")
    e("return 0")
    doc = (f"Pm = -D1 Ld - f^- and J = dPm/dv; Ld = h sum_i W_i L(q0 + C_i h v, v), (C, W) = {list(nodes)}:\n"
           f"    Pm = sum_i W_i [M_i v - h (1 - C_i) gL_i] - {fa!r} h f(q0, v, t),\n"
           f"    J = sum_i W_i [M_i + C_i h T_i - h (1 - C_i) (T_i^T + C_i h S_i)] - {fa!r} h df/dqdot;\n"
           f"    c = sys_node(q0): a node at C = 0 costs nothing per Newton iteration (vcirun.codegen.tensor).")
    return _header(f"{name}_PmJc", "q0, v, h, t, prm, c, r, J", doc) + e.body()


def _pp_source(system, td, name, nodes, fb) -> str:
    n = system.n
    e = _Gen(system, td)
    e.prologue()
    out = {a: [] for a in range(n)}
    end = None  # tag of the tensors at q1 = q0 + h v
    for i, (c, w) in enumerate(nodes):
        tag, _ = e.node(i, c, w, cached="c" if c == 0.0 else None)  # C = 0: only M is used
        e.add_weighted_Mv(tag, w, out)
        if c != 0.0:
            e(f"hc{i} = {_f(w * c)} * h")
            gl = e.gL(tag, e.T(tag))
            for a in range(n):
                out[a].append((1, f"hc{i} * {gl[a]}"))
        if c == 1.0:
            end = tag
    q1 = [f"x{len(nodes)}_{a}" for a in range(n)]
    if end is None or (system.is_forced and fb != 0.0):
        e.coords(len(nodes), 1.0)
    if end is None:  # no node at q1 (SE1, midpoint): its tensors cost one extra node here
        e.tensors("T1", "ne", q1)
        end = "ne"
    if system.is_forced and fb != 0.0:  # f^+ = FB h f(q1, v, t + h), q1 = q0 + h v
        e(f"# f^+ = {fb!r} h f(q0 + h v, v, t + h)")
        fo = e.force(q1, "(t + h)")
        e(f"fh = {_f(fb)} * h")
        for a in range(n):
            if fo[a]:
                out[a].append((1, f"fh * {fo[a]}"))
    for a in range(n):
        e(f"out[{a}] = {_sum(out[a])}")
    e.store(end, "cn")
    e("return 0")
    doc = (f"Pp = D2 Ld + f^+ = sum_i W_i [M_i v + h C_i gL_i] + {fb!r} h f(q0 + h v, v, t + h),\n"
           f"    (C, W) = {list(nodes)}; c = sys_node(q0) in, cn = sys_node(q0 + h v) out (the same bits:\n"
           f"    the next stage of a composition starts there) (vcirun.codegen.tensor).")
    return _header(f"{name}_Ppc", "q0, v, h, t, prm, c, out, cn", doc) + e.body()


def node_source(system) -> str:
    """NODE_LEN, sys_node(q, prm, c) and sys_node_M(c, A): the node data of a point q, i.e. the
    first-order tensors of template T1 (M_ij for i <= j, the structural nonzeros of dM, dV) in their
    template order, and M(q) rebuilt from it. The full step (vcirun.maps.steps) keeps the node data
    of each stage's start point: the C = 0 node of Pm, J and Pp reads it instead of recomputing
    it every Newton iteration, Pp hands over the data of its end point to the next stage, and the
    velocity guess takes M from it."""
    n = system.n
    td = tensor_data(system, False)
    e = _Gen(system, td)
    e.prologue("q", None)
    e.tensors("T1", "n0", [f"q0_{a}" for a in range(n)])
    e.store("n0", "c")
    e("return 0")
    src = f"NODE_LEN = {td['n_g1']}\n\n\n"
    src += _header("sys_node", "q, prm, c", "Node data of q: the T1 tensors (vcirun.codegen.tensor.node_source).")
    src += e.body() + "\n\n"
    body = []
    entries = [(a, b, e.midx[min(a, b), max(a, b)]) for a in range(n) for b in range(n)]
    fill = sum(1 for *_, k in entries if k in td["T1"].zero) >= ZERO_FILL_MIN  # (a sparse M: zeros by a loop)
    if fill:
        body += [f"    for i_ in range({n}):", f"        for j_ in range({n}):", "            A[i_, j_] = 0.0"]
    for a, b, k in entries:
        if k not in td["T1"].zero:
            body.append(f"    A[{a}, {b}] = c[{k}]")
        elif not fill:
            body.append(f"    A[{a}, {b}] = 0.0")
    src += _header("sys_node_M", "c, A", "M(q) from the node data c of q.") + "\n".join(body) + "\n    return 0\n"
    return src


def _wrapper_source(name) -> str:
    """<LD>_PmJ and <LD>_Pp with the plain signatures (no node data: one sys_node call first), for
    callers outside the full step and for the tests."""
    return (_header(f"{name}_PmJ", "q0, v, h, t, prm, r, J",
                    f"{name}_PmJc with the node data of q0 computed here (vcirun.codegen.tensor).")
            + f"    c = scratch(NODE_LEN)\n    sys_node(q0, prm, c)\n    return {name}_PmJc(q0, v, h, t, prm, c, r, J)\n\n\n"
            + _header(f"{name}_Pp", "q0, v, h, t, prm, out",
                      f"{name}_Ppc with the node data of q0 computed here (vcirun.codegen.tensor).")
            + f"    c = scratch(NODE_LEN)\n    cn = scratch(NODE_LEN)\n    sys_node(q0, prm, c)\n"
            f"    return {name}_Ppc(q0, v, h, t, prm, c, out, cn)\n")


def _ed_source(system, td, name, nodes) -> str:
    e = _Gen(system, td)
    e.prologue()
    nm = len(td["MI"])
    zero = td["T0"].zero
    terms = []
    for i, (c, w) in enumerate(nodes):
        tag = f"n{i}"
        xs = e.coords(i, c)
        e.tensors("T0", tag, xs)
        q = []
        for k, (a, b) in enumerate(zip(td["MI"], td["MJ"])):
            if k not in zero:
                q.append((1, f"{tag}_{k} * v_{a} * v_{b}" if a == b else f"2.0 * {tag}_{k} * v_{a} * v_{b}"))
        Vt = [] if nm in zero else [(1, f"{tag}_{nm}")]
        e(f"{tag}e = 0.5 * ({_sum(q)}) + {_sum(Vt)}")
        terms.append((1, f"{_f(w)} * {tag}e"))
    e(f"return {_sum(terms)}")
    doc = f"Ed = -D3 Ld = sum_i W_i [1/2 v^T M(x_i) v + V(x_i)] (unforced part), (C, W) = {list(nodes)}."
    return _header(f"{name}_Ed", "q0, v, h, prm", doc) + e.body()


def _edv_source(system, td, name, nodes) -> str:
    n = system.n
    e = _Gen(system, td)
    e.prologue()
    out = {a: [] for a in range(n)}
    for i, (c, w) in enumerate(nodes):
        tag, _ = e.node(i, c, w)
        e.add_weighted_Mv(tag, w, out)
        if c != 0.0:  # C h (1/2 v^T dM/dq_a v + dV_a)
            e(f"hc{i} = {_f(w * c)} * h")
            vtv = e.vTv(tag, e.T(tag))
            for a in range(n):
                ts = ([(1, f"0.5 * {vtv[a]}")] if a in vtv else []) + ([(1, d)] if (d := e.dV(tag, a)) else [])
                if ts:
                    out[a].append((1, f"hc{i} * ({_sum(ts)})"))
    for a in range(n):
        e(f"out[{a}] = {_sum(out[a])}")
    e("return 0")
    doc = f"dEd/dv = sum_i W_i [M_i v + C_i h (1/2 v^T dM/dq(x_i) v + dV(x_i))], (C, W) = {list(nodes)}."
    return _header(f"{name}_Edv", "q0, v, h, prm, out", doc) + e.body()


def dhq_source(system) -> str:
    """sys_dHq(q, x, prm, out): dH/dq at fixed x = M(q)^-1 p, which is -dL/dq(q, x) = -(1/2 x^T dM/dq
    x - dV/dq): the first-order tensor template and the contraction of the step kernels (the same
    numbers as system.dH_dq_at without expanding x^T dM/dq_k x symbolically)."""
    n = system.n
    td = tensor_data(system, False)
    e = _Gen(system, td)
    e.prologue("q", "x")
    e.tensors("T1", "n0", [f"q0_{a}" for a in range(n)])
    gl = e.gL("n0", e.T("n0"))
    for a in range(n):
        e(f"out[{a}] = -{gl[a]}")
    e("return 0")
    doc = "dH/dq at fixed x = M^-1 p: -(1/2 x^T dM/dq x - dV/dq) (vcirun.codegen.tensor)."
    return _header("sys_dHq", "q, x, prm, out", doc) + e.body()


def tensor_ld_source(system, names, edv_names=()) -> tuple[str, list]:
    """Source of the tensor kernels for the explicit Lds `names` that are quadrature rules (with
    <LD>_Edv for those in edv_names). Returns (source, names handled); the caller generates the
    others on the expanded path."""
    from ..discrete.lagrangians import get_ld

    lds = {nm: get_ld(nm) for nm in names}
    nodes = {nm: quadrature_nodes(ld) for nm, ld in lds.items()}
    handled = [nm for nm in names if nodes[nm] is not None]
    if not handled:
        return "", []
    second = any(needs_second_derivatives(nodes[nm]) for nm in handled)
    td = tensor_data(system, second)
    head = ["# --- step kernels from per-slot tensors (vcirun.codegen.tensor) ---",
            f"# tensors per node n<i>_<k>: M_ij (i <= j) {list(zip(td['MI'], td['MJ']))},",
            f"# dM_ij/dq_k (structural nonzeros, i <= j) {list(zip(td['DI'], td['DJ'], td['DK']))}, dV/dq"]
    if second:
        head += [f"# second derivatives n<i>h_<k>: d2M_ij/dq_a dq_b (nonzeros, i <= j, a <= b) "
                 f"{list(zip(td['I2'], td['J2'], td['A2'], td['B2']))}, d2V/dq_a dq_b {list(zip(td['VA'], td['VB']))}"]
    parts = ["\n".join(head)]
    for nm in handled:
        fa, fb = (float(x) for x in lds[nm].forcing_weights)
        parts.append(_pmj_source(system, td, nm, nodes[nm], fa))
        parts.append(_pp_source(system, td, nm, nodes[nm], fb))
        parts.append(_wrapper_source(nm))
        parts.append(_ed_source(system, td, nm, nodes[nm]))
        if nm in edv_names:
            parts.append(_edv_source(system, td, nm, nodes[nm]))
    return "\n\n".join(parts) + "\n", handled
