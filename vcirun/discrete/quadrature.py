"""Which explicit discrete Lagrangians are quadrature rules of L (read off their own definition).

Ld(q0, q1, h) = h sum_i W_i L(q0 + C_i (q1 - q0), (q1 - q0)/h): SE1 (C = 0), SE2 (C = 1), midpoint
(C = 1/2), SVC (C in {0, 1}, W = 1/2 each). The per-slot tensor step kernels
(vcirun.codegen.tensor) and the per-node primitives of the modified Hamiltonian
(vcirun.modified.eta) are built on these nodes; an Ld of another form returns None.
"""
from __future__ import annotations

from functools import lru_cache

import sympy as sp


@lru_cache(maxsize=None)
def quadrature_nodes(ld) -> tuple | None:
    """((C_i, W_i), ...) if Ld(q0, q1, h) = h sum_i W_i L(q0 + C_i (q1 - q0), (q1 - q0)/h) for any L
    (read off ld.build applied to an undefined function of 2 coordinates), else None."""
    build = getattr(ld, "build", None)
    if build is None:
        return None
    a = sp.symbols("tq0_0:2")
    b = sp.symbols("tq1_0:2")
    h = sp.Symbol("th")
    Lf = sp.Function("Lf")
    try:
        expr = sp.expand(build(lambda q, v: Lf(*q, *v), list(a), list(b), h))
    except Exception:  # an Ld that does not accept a generic L: not a quadrature rule
        return None
    nodes = []
    for term in sp.Add.make_args(expr):
        calls = term.atoms(sp.core.function.AppliedUndef)
        if len(calls) != 1:
            return None
        call = calls.pop()
        # (rational functions of the symbols: cancel and expand decide them exactly, without
        # simplify's heuristics and its import of sympy.physics.units, 0.4 s of a first call)
        w = sp.cancel(term / (h * call))
        if not w.is_number or len(call.args) != 4:
            return None
        x, v = call.args[:2], call.args[2:]
        if any(sp.cancel(v[k] - (b[k] - a[k]) / h) != 0 for k in range(2)):
            return None
        c = sp.cancel((x[0] - a[0]) / (b[0] - a[0]))
        if not c.is_number or sp.expand(x[1] - (a[1] + c * (b[1] - a[1]))) != 0:
            return None
        nodes.append((float(c), float(w)))
    return tuple(nodes) if nodes else None
