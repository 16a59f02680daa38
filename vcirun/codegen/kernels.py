"""Kernel specifications and their emission as numba source.

A `Kernel` is a named function of vector/scalar inputs with one or more outputs. Every output of one
kernel goes through ONE common-subexpression pass (pydy-style), so shared pieces (M(q), sin/cos)
are computed once. Parameters are a runtime vector `prm` (never baked in): a parameter sweep does
not recompile anything.
"""
from __future__ import annotations

from dataclasses import dataclass

import sympy as sp

from .printer import pycode


# A matrix output with at least this many zero entries (a Jacobian of contacts that each involve a few
# of many coordinates, a constant diagonal M) is zero-filled by a loop and only its nonzero entries
# are written: generated code and compile time grow with the nonzeros, not with the matrix size.
# (Below it every entry is written, as statements.)
ZERO_FILL_MIN = 64


@dataclass
class Kernel:
    """name: python identifier; inputs: [(argname, [symbols] | symbol)]; outputs: [(argname, expr or
    Matrix)]. A kernel whose single output is a scalar returns it; otherwise outputs are written into
    caller-provided arrays (appended to the signature, after `prm`)."""

    name: str
    inputs: list
    outputs: list
    params: list  # parameter symbols, in the order of the runtime vector prm

    def signature(self) -> str:
        args = [a for a, _ in self.inputs] + ["prm"]
        if not self.returns_scalar:
            args += [o for o, _ in self.outputs]
        return ", ".join(args)

    @property
    def returns_scalar(self) -> bool:
        return len(self.outputs) == 1 and not isinstance(self.outputs[0][1], sp.MatrixBase)

    def emit(self) -> str:
        lines = ['@njit(cache=True, nogil=True, error_model="numpy")', f"def {self.name}({self.signature()}):"]
        body = []
        used = set()
        flat = []  # (target, expr)
        fills = []  # outputs with many zero entries: one loop writes the zeros, `flat` the others
        for oname, val in self.outputs:
            if isinstance(val, sp.MatrixBase):
                if val.shape[1] == 1:
                    ents = [(f"{oname}[{i}]", val[i, 0]) for i in range(val.shape[0])]
                else:
                    ents = [(f"{oname}[{i}, {j}]", val[i, j]) for i in range(val.shape[0]) for j in range(val.shape[1])]
                if sum(1 for _, e in ents if e == 0) >= ZERO_FILL_MIN:
                    fills.append((oname, val.shape))
                    ents = [(t, e) for t, e in ents if e != 0]
                flat += ents
            else:
                flat.append(("__ret__", sp.sympify(val)))
        exprs = [e for _, e in flat]
        for e in exprs:
            used |= {s.name for s in e.free_symbols}
        # unpack inputs that are used
        for aname, syms in self.inputs:
            if isinstance(syms, (list, tuple)):
                for i, s in enumerate(syms):
                    if s.name in used:
                        body.append(f"{_id(s)} = {aname}[{i}]")
            elif syms.name in used:
                body.append(f"{_id(syms)} = {aname}")
        for i, s in enumerate(self.params):
            if s.name in used:
                body.append(f"{_id(s)} = prm[{i}]")
        for oname, (r, c) in fills:
            if c == 1:
                body += [f"for i_ in range({r}):", f"    {oname}[i_] = 0.0"]
            else:
                body += [f"for i_ in range({r}):", f"    for j_ in range({c}):", f"        {oname}[i_, j_] = 0.0"]
        repl, reduced = sp.cse(exprs, symbols=sp.numbered_symbols("cse"), order="none")
        tmp = {s for s, _ in repl}
        for s, e in repl:
            body.append(f"{s.name} = {_code(e, tmp)}")
        ret = None
        for (target, _), e in zip(flat, reduced):
            if target == "__ret__":
                ret = _code(e, tmp)
            else:
                body.append(f"{target} = {_code(e, tmp)}")
        body.append(f"return {ret}" if ret is not None else "return 0")
        return "\n".join(lines + ["    " + b for b in body]) + "\n"


def _id(s) -> str:
    """Symbols may carry names that are not identifiers in generated code."""
    return "s_" + "".join(c if c.isalnum() else "_" for c in s.name)


def _code(e, tmp=frozenset()) -> str:
    e = sp.sympify(e)
    sub = {s: sp.Symbol(_id(s)) for s in e.free_symbols if s not in tmp}
    return pycode(e.xreplace(sub))
