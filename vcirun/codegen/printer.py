"""sympy -> numba-friendly Python source for scalar expressions."""
from __future__ import annotations

import sympy as sp
from sympy.printing.pycode import PythonCodePrinter


class KernelPrinter(PythonCodePrinter):
    """Prints `math.*` calls; small integer powers become products (numba does not turn pow(x, 2)
    into a multiply), x**0.5 becomes math.sqrt; floats keep full precision."""

    def _print_Pow(self, expr, rational=False):
        base, e = expr.as_base_exp()
        if e.is_Integer and 1 <= abs(int(e)) <= 4:
            b = self.parenthesize(base, 100)  # always parenthesize compound bases
            prod = "*".join([b] * abs(int(e)))
            return prod if int(e) > 0 else f"(1.0/({prod}))"
        if e == sp.Rational(1, 2):
            return f"math.sqrt({self._print(base)})"
        if e == -sp.Rational(1, 2):
            return f"(1.0/math.sqrt({self._print(base)}))"
        return f"math.pow({self._print(base)}, {self._print(sp.Float(e) if e.is_Rational else e)})"

    def _print_Rational(self, expr):
        return f"({float(expr.p)!r}/{float(expr.q)!r})"

    def _print_Integer(self, expr):
        return f"{float(expr)!r}"

    def _print_Float(self, expr):
        return repr(float(expr))

    def _print_Abs(self, expr):
        return f"abs({self._print(expr.args[0])})"

    def _print_Add(self, expr, order=None):
        # Python's compiler recurses once per operator of a chain a + b + c + ... and gives up near
        # 3000: a longer sum is printed as parenthesized sums of at most MAX_CHAIN terms each (shorter
        # ones exactly as sympy prints them)
        if len(expr.args) <= MAX_CHAIN:
            return super()._print_Add(expr, order=order)
        terms = self._as_ordered_terms(expr, order=order)
        groups = [terms[i:i + MAX_CHAIN // 2] for i in range(0, len(terms), MAX_CHAIN // 2)]
        return " + ".join(f"({self._print(sp.Add(*g, evaluate=False))})" for g in groups)


# the longest sum printed as one chain (Python compiles chains of about 3000 operators)
MAX_CHAIN = 2000


_printer = KernelPrinter({"fully_qualified_modules": True, "standard": "python3"})


def pycode(expr) -> str:
    return _printer.doprint(expr)
