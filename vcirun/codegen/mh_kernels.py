"""Emission of the modified-Hamiltonian kernels of the MCVA family (all emission lives in codegen/).

From the symbolic side (vcirun.modified.eta: eta as a stationary value, the DAG of its exact
derivatives, H~^{O(h^s)} as expressions in its nodes) this module writes the kernels the numba
units of vcirun/maps/gauss.py and vcirun/collision/reset_mcva.py call:

  mh_FA(q, p, u, h, prm, F, A)         Newton residual and Jacobian for eta's stage velocities u
  mh_value(q, p, u, W, h, prm, terms)  H~ and its terms H_1 = eta, ..., H_s
  mh_grad(q, p, u, W, h, prm, grad)    H~ and dH~/d(q, p), reverse mode (`emit_grad_kernel`)
  mh_hess(q, p, u, W, h, prm, hess)    eta's Hessian (the Gauss flow's Newton matrix)

(W = dF/du^{-1} at u*, computed numerically.) The primitives (derivatives of ell) get one CSE pass,
the DAG's nodes and the outputs a second one; above 4 stage velocities U_beta = -W R_beta and its
adjoint are loops. `modified_kernels_source(system, ks)` is what vcirun.codegen.derive calls.
"""
from __future__ import annotations

import time

import sympy as sp

from ..discrete.lagrangians import get_ld
from ..modified import FLOW_ORDERS, SUPPORTED_MH_ORDERS
from ..modified.eta import DERIVE_LOG, PREFIX, DerivativeDag, StationaryEta, derive_modified
from .kernels import Kernel, _code, _id

_P = PREFIX
_CSE2_MAX_TARGETS = 1200  # second CSE pass (over the DAG's nodes) only up to this many nodes


def _closure(dag: DerivativeDag, exprs) -> set:
    """All symbols the expressions depend on, through node definitions."""
    seen: set = set()
    stack = [s for e in exprs for s in sp.sympify(e).free_symbols]
    while stack:
        s = stack.pop()
        if s in seen:
            continue
        seen.add(s)
        if s in dag.defs:
            stack.extend(dag.defs[s].free_symbols)
    return seen


def _prim_program(st: StationaryEta, dag: DerivativeDag, used: set) -> list:
    """[(symbol, expr)] computing the primitives in `used` (and the node tensors they read) in order:
    one CSE pass over the node tensors' definitions, one over the primitives. `used` is extended by
    every symbol the program reads (inputs included)."""
    prim = [(s, dag.prim_expr[dag.kind[s][1]]) for s in dag.prim_sym.values()
            if isinstance(s, sp.Symbol) and s in used]
    for _, e in prim:
        used |= e.free_symbols
    tens = [(s, e) for s, e in st.tensor_def.items() if s in used]
    prog = []
    for items, tag in ((tens, "e"), (prim, "c")):
        if not items:
            continue
        for _, e in items:
            used |= e.free_symbols
        repl, red = sp.cse([e for _, e in items], symbols=sp.numbered_symbols(f"{_P}{tag}"), order="canonical")
        prog += list(repl) + [(s, e) for (s, _), e in zip(items, red)]
    used |= {s for s, _ in prog}
    for _, e in prog:
        used |= e.free_symbols
    return prog


_LOOP_M = 4  # above this many stage velocities, u*'s derivatives U_beta = -W R_beta are numba loops


def _u_groups(dag: DerivativeDag, entries: list, m: int):
    """Replace the DAG's U nodes (U(k, beta) = -sum_l W_kl R_beta,l) by one ('group', g) entry per
    beta, at the first one's place (R_beta is complete before any U(., beta) exists). Returns
    (entries, groups: [(beta, {k: symbol}, R_beta)]). Unrolled, the m^2 products per beta (and as
    many adjoint terms of W) made most of the source at n = 8; as loops they are O(m) lines."""
    if m <= _LOOP_M:
        return entries, []
    out, groups, gid = [], [], {}
    for ent in entries:
        k = dag.kind.get(ent[0]) if isinstance(ent[0], sp.Symbol) else None
        if k is not None and k[0] == "U":
            beta = k[2]
            if beta not in gid:
                gid[beta] = len(groups)
                groups.append((beta, {}, dag._dmemo[("R", beta)]))
                out.append(("group", gid[beta]))
            groups[gid[beta]][1][k[1]] = ent[0]
            continue
        out.append(ent)
    return out, groups


def _group_forward(g: int, group, m: int) -> list:
    beta, syms, R = group
    lines = [f"RV[{g}, {l}] = {_code(R[l])}" for l in range(m)]
    lines += [f"for k in range({m}):", "    acc = 0.0", f"    for l in range({m}):",
              f"        acc += (W[k, l] if k <= l else W[l, k]) * RV[{g}, l]", f"    UV[{g}, k] = -acc"]
    lines += [f"{_id(x)} = UV[{g}, {k}]" for k, x in sorted(syms.items())]
    return lines


def _group_arrays(groups, m: int) -> list:
    return [f"RV = np.empty(({len(groups)}, {m}))", f"UV = np.empty(({len(groups)}, {m}))"] if groups else []


def _emit_dag_kernel(name: str, st: StationaryEta, dag: DerivativeDag, outs: list, ret=None) -> str:
    """numba source of `name(q, p, u, W, h, prm, <out arrays>)`: unpack inputs, the primitives (one
    CSE pass), the DAG nodes in creation (= topological) order, then the outputs. outs =
    [(array name, [(index text, expr), ...])]; ret = scalar expression returned (or None)."""
    exprs = [e for _, items in outs for _, e in items] + ([ret] if ret is not None else [])
    used = _closure(dag, exprs)
    prog = _prim_program(st, dag, used)
    sig = ["q", "p", "u", "W", "h", "prm"] + [o for o, _ in outs]
    lines = ['@njit(cache=True, nogil=True, error_model="numpy")', f"def {name}({', '.join(sig)}):"]
    body = []
    for arr, syms in (("q", st.q), ("p", st.p), ("u", st.u)):
        for i, s in enumerate(syms):
            if s in used:
                body.append(f"{_id(s)} = {arr}[{i}]")
    for a in range(st.m):
        for b in range(a, st.m):
            if dag.W[a][b] in used:
                body.append(f"{_id(dag.W[a][b])} = W[{a}, {b}]")
    if st.h in used:
        body.append(f"{_id(st.h)} = h")
    for i, s in enumerate(st.params):
        if s in used:
            body.append(f"{_id(s)} = prm[{i}]")
    body += [f"{_id(s)} = {_code(e)}" for s, e in prog]
    # nodes and outputs: a second CSE pass (products of nodes recur across the DAG: ~40% fewer
    # operations, and numba's compile time grows with them); a temporary is emitted just before its
    # first use, where every node it reads is already defined (nodes are in topological order).
    entries, groups = _u_groups(dag, [(s, e) for s, e in dag.defs.items() if s in used], st.m)
    body += _group_arrays(groups, st.m)
    targets = [(_id(s), e) if s != "group" else ("group", e) for s, e in entries]
    targets += [(f"{arr}[{idx}]", e) for arr, items in outs for idx, e in items]
    if ret is not None:
        targets.append(("return", ret))
    exprs = [e for t, e in targets if t != "group"]
    if len(targets) <= _CSE2_MAX_TARGETS:
        repl, reduced = sp.cse(exprs, symbols=sp.numbered_symbols(f"{_P}d"), order="canonical")
    else:  # sympy's cse is superlinear: on very large DAGs (n >= 3, s = 4) it costs more than it saves
        repl, reduced = [], exprs
    reduced = iter(reduced)
    reduced = [e if t == "group" else next(reduced) for t, e in targets]
    tdef = dict(repl)
    tnames = set(tdef)
    done: set = set()

    def emit_temps(e):
        for x in sorted(e.free_symbols & tnames - done, key=lambda y: int(y.name[len(_P) + 1:])):
            if x not in done:
                emit_temps(tdef[x])
                done.add(x)
                body.append(f"{x.name} = {_code(tdef[x], tnames)}")

    for (tgt, _), e in zip(targets, reduced):
        if tgt == "group":
            body += _group_forward(e, groups[e], st.m)
            continue
        emit_temps(e)
        body.append(f"return {_code(e, tnames)}" if tgt == "return" else f"{tgt} = {_code(e, tnames)}")
    if ret is None:
        body.append("return 0")
    return "\n".join(lines + ["    " + b for b in body]) + "\n"


def _partials(e) -> dict:
    """{x: de/dx} for every symbol x of e. The DAG's nodes are polynomials in symbols: their partials
    are read off term by term in one pass (sp.diff per symbol was 2/3 of the reverse sweep's time);
    anything else (the primitives' CSE temporaries: trigonometric, powers) goes through sp.diff."""
    out: dict = {}
    for t in sp.Add.make_args(e):
        c, fs = t.as_coeff_mul()
        for i, f in enumerate(fs):
            if f.is_Symbol:
                base, k = f, 1
            elif f.is_Pow and f.base.is_Symbol and f.exp.is_Integer and f.exp > 0:
                base, k = f.base, int(f.exp)
            else:
                return {x: sp.diff(e, x) for x in sorted(e.free_symbols, key=lambda y: y.name)}
            rest = sp.Mul(c * k, *fs[:i], *fs[i + 1:], base ** (k - 1))
            out.setdefault(base, []).append(rest)
    return {x: sp.Add(*v) for x, v in out.items()}


def emit_grad_kernel(name: str, st: StationaryEta, dag: DerivativeDag, value) -> str:
    """numba source of `name(q, p, u, W, h, prm, grad)`: returns H~ and writes grad = dH~/d(q, p).

    Reverse mode (Baur-Strassen: the gradient costs a few times the value, whatever n): the value is a
    straight-line program P(q, p, u, W) -- the primitives ell_alpha(q, u) (one CSE pass), the DAG
    nodes, H~ -- and its adjoint sweep gives the explicit partials qb, pb, ub, Wb. H~(z) =
    P(z, u*(z), W(z)) with F(z, u*) = 0, W = A^{-1}, A = dF/du = -ell_uu, so (W symmetric)
        dH~ = qb dq + pb dp + ub du* + S : dW,    S = Wb symmetrised (Wb_ab / 2 off the diagonal),
        S : dW = -(W S W) : dA = G : d ell_uu,    G = W S W,
        d ell_{u_c u_d} = ell_{u_c u_d q_j} dq_j + ell_{u_c u_d u_k} du*_k,
        du*/dz_j = -W dF/dz_j,  dF/dq_j = -ell_{u q_j},  dF/dp_j = C[:, j],
    i.e. with ub' = ub + G : ell_uuu and lam = W ub':
        grad_q = qb + G : ell_uuq + lam . ell_uq,    grad_p = pb - C^T lam.
    No forward-mode order-s jets of eta are formed (one order more than the value needs; their
    cost grows as n^s)."""
    n, m = st.n, st.m
    x_dim = n + m
    # primitives the closure needs: ell_{u_c u_d x_j} (c <= d) and ell_{u_l q_j}
    L3 = {}
    for c in range(m):
        for d in range(c, m):
            for j in range(x_dim):
                v = dag.L((n + c, n + d, j))
                if v != 0:
                    L3[c, d, j] = v
    L2 = {(l, j): dag.L((n + l, j)) for l in range(m) for j in range(n)}
    L2 = {k: v for k, v in L2.items() if v != 0}
    val = sp.Symbol(f"{_P}val")
    used = _closure(dag, [value] + list(L3.values()) + list(L2.values()))
    prog = _prim_program(st, dag, used)
    nodes, groups = _u_groups(dag, [(s, e) for s, e in dag.defs.items() if s in used], m)
    prog += nodes
    prog.append((val, sp.sympify(value)))
    # adjoint sweep (prog is topologically ordered: when y is reached backwards, its adjoint is final)
    wsyms = {dag.W[a][b] for a in range(m) for b in range(a, m)}
    inputs = set(st.q) | set(st.p) | set(st.u) | wsyms
    targets = {y for y, _ in prog if y != "group"}
    for _, syms, _ in groups:
        targets |= set(syms.values())
    adj: dict = {val: [sp.S.One]}
    rev = []  # (symbol, expr) or a raw code line (str)

    def propagate(e, b):
        for x, d in _partials(e).items():
            if (x in targets or x in inputs) and d != 0:
                adj.setdefault(x, []).append(b * d)

    for k, (y, e) in enumerate(reversed(prog)):
        if y == "group":  # U_beta = -W R_beta: RB = -W^T UB, WB -= UB R_beta^T
            beta, syms, R = groups[e]
            for kk in range(m):
                parts = adj.pop(syms[kk], None) if kk in syms else None
                rev.append(f"UB[{e}, {kk}] = {_code(sp.Add(*parts)) if parts else '0.0'}")
            rev += [f"for l in range({m}):", "    acc = 0.0", f"    for k in range({m}):",
                    f"        acc += (W[k, l] if k <= l else W[l, k]) * UB[{e}, k]",
                    f"        WB[k, l] -= UB[{e}, k] * RV[{e}, l]", f"    RB[{e}, l] = -acc"]
            for l in range(m):
                if not sp.sympify(R[l]).is_number:
                    rb = sp.Symbol(f"{_P}rb{e}_{l}")
                    rev.append((rb, sp.Symbol(f"RB[{e}, {l}]")))
                    propagate(R[l], rb)
            continue
        parts = adj.pop(y, None)
        if not parts:
            continue
        b = sp.Symbol(f"{_P}b{k}")
        rev.append((b, sp.Add(*parts)))
        propagate(e, b)
    bar = lambda x: sp.Add(*adj.get(x, []))  # noqa: E731
    assert not (groups and any(w in adj for w in wsyms)), "W outside the U loops"
    used_in = set().union(*(e.free_symbols for y, e in prog if y != "group"),
                          *(r[1].free_symbols for r in rev if not isinstance(r, str)),
                          *(sp.sympify(R[l]).free_symbols for _, _, R in groups for l in range(m)))
    used_in |= set(L3.values()) | set(L2.values())
    sig = "q, p, u, W, h, prm, grad"
    lines = ['@njit(cache=True, nogil=True, error_model="numpy")', f"def {name}({sig}):",
             '    """H~ and grad = dH~/d(q, p) (reverse mode; see vcirun.codegen.mh_kernels.emit_grad_kernel)."""']
    body = []
    for arr, syms in (("q", st.q), ("p", st.p), ("u", st.u)):
        body += [f"{_id(x)} = {arr}[{i}]" for i, x in enumerate(syms) if x in used_in]
    body += [f"{_id(dag.W[a][b])} = W[{a}, {b}]" for a in range(m) for b in range(a, m) if dag.W[a][b] in used_in]
    if st.h in used_in:
        body.append(f"{_id(st.h)} = h")
    body += [f"{_id(x)} = prm[{i}]" for i, x in enumerate(st.params) if x in used_in]
    body += _group_arrays(groups, m)
    if groups:
        body += [f"UB = np.empty(({len(groups)}, {m}))", f"RB = np.empty(({len(groups)}, {m}))",
                 f"WB = np.zeros(({m}, {m}))"]
    for y, e in prog:
        body += _group_forward(e, groups[e], m) if y == "group" else [f"{_id(y)} = {_code(e)}"]
    for r in rev:
        if isinstance(r, str):
            body.append(r)
        elif r[1].is_Symbol and r[1].name.startswith("RB["):
            body.append(f"{_id(r[0])} = {r[1].name}")
        else:
            body.append(f"{_id(r[0])} = {_code(r[1])}")
    # S = Wb symmetrised (the W symbols of unrolled U nodes, or WB of the loops); G = W S W
    body.append(f"S = np.empty(({m}, {m}))")
    for a in range(m):
        for b in range(a, m):
            e = bar(dag.W[a][b])
            if groups:  # W enters through the loops only
                body.append(f"S[{a}, {b}] = " + (f"WB[{a}, {a}]" if a == b else f"0.5 * (WB[{a}, {b}] + WB[{b}, {a}])"))
            else:
                body.append(f"S[{a}, {b}] = {_code(e if a == b else e / 2)}")
            if a != b:
                body.append(f"S[{b}, {a}] = S[{a}, {b}]")
    body += [f"T = np.zeros(({m}, {m}))", f"for a in range({m}):", f"    for b in range({m}):",
             f"        for c in range({m}):", "            T[a, b] += S[a, c] * W[c, b]",
             f"G = np.zeros(({m}, {m}))", f"for a in range({m}):", f"    for b in range({m}):",
             f"        for c in range({m}):", "            G[a, b] += W[a, c] * T[c, b]"]

    def g_terms(j):
        return [f"{'G[%d, %d]' % (c, d) if c == d else '(G[%d, %d] + G[%d, %d])' % (c, d, d, c)} * {_code(v)}"
                for (c, d, jj), v in L3.items() if jj == j]

    body.append(f"ub = np.empty({m})")
    for k in range(m):
        body.append(f"ub[{k}] = " + " + ".join([_code(bar(st.u[k]))] + g_terms(n + k)))
    body += [f"lam = np.zeros({m})", f"for a in range({m}):", f"    for b in range({m}):",
             "        lam[a] += W[a, b] * ub[b]"]
    for j in range(n):
        t = [_code(bar(st.q[j]))] + g_terms(j) + [f"lam[{l}] * {_code(v)}" for (l, jj), v in L2.items() if jj == j]
        body.append(f"grad[{j}] = " + " + ".join(t))
    for j in range(n):
        t = [_code(bar(st.p[j]))] + [f"- {_code(sp.nsimplify(st.C[l][j]))} * lam[{l}]" for l in range(m)
                                     if st.C[l][j] != 0]
        body.append(f"grad[{n + j}] = " + " ".join([t[0]] + t[1:]))
    body.append(f"return {_id(val)}")
    return "\n".join(lines + ["    " + b for b in body]) + "\n"


def modified_kernels_source(system, ks) -> str:
    """Generated source for the MCVA family of `ks.modified = (ld, mh_order, flow_order)`:
    constants, mh_FA (Newton residual/Jacobian for u), mh_value (H~ and its terms), mh_grad (H~ and its
    gradient, reverse mode), mh_hess (the Hessian of eta: the Gauss flow's Newton matrix)."""
    ld_name, s, flow = ks.modified
    if s not in SUPPORTED_MH_ORDERS:
        raise ValueError(f"mh_order: {s} is not supported (choose one of {SUPPORTED_MH_ORDERS})")
    if flow not in FLOW_ORDERS:
        raise ValueError(f"flow_order: {flow} is not supported (choose one of {FLOW_ORDERS})")
    if tuple(get_ld(ld_name).stages) != tuple(ks.full_stages):
        raise ValueError(f"ld: the modified Hamiltonian's Ld {ld_name} must be the full step's")
    st, dag, out = derive_modified(system, ld_name, s)
    t0 = time.perf_counter()
    n, m = st.n, st.m
    parts = [f"MH_ORDER = {s}", f"MH_M = {m}", f"MH_NSTAGE = {len(st.stages)}", f"MH_FLOW_S = {flow // 2}", ""]
    fa = Kernel(f"{_P}FA", [("q", st.q), ("p", st.p), ("u", st.u), ("h", st.h)],
                [("F", sp.Matrix([st.explicit(e) for e in st.F])), ("A", st.A.applyfunc(st.explicit))], st.params)
    parts.append(fa.emit())
    parts.append(_emit_dag_kernel(f"{_P}value", st, dag,
                                  [("terms", [(str(i), t) for i, t in enumerate(out["terms"])])], ret=out["value"]))
    nz = 2 * n
    parts.append(emit_grad_kernel(f"{_P}grad", st, dag, out["value"]))
    parts.append(_emit_dag_kernel(
        f"{_P}hess", st, dag, [("hess", [(f"{i}, {j}", out["hess"][i][j]) for i in range(nz) for j in range(nz)])]))
    DERIVE_LOG.append({"system": system.name, "ld": ld_name, "mh_order": s, "emit_s": time.perf_counter() - t0})
    return "\n\n".join(parts) + "\n"
