"""Safe parsing of user-written math expressions into sympy objects.

Config files carry expressions such as ``"m2*L*sin(theta)"`` or ``"0.5*k*x**2"``.
They are never handed to ``eval``/``exec``/``sympify`` (all of which run Python code):
the text is parsed with :func:`ast.parse` and the tree is walked against an explicit
whitelist, building sympy objects node by node. Anything off the whitelist raises
:class:`ExpressionError` whose one-line message names the config field, the offending
token and what to write instead.

Accepted grammar: int/float literals (incl. ``1e-3``), declared names, ``pi``, ``E``,
binary ``+ - * / **``, unary ``+ -``, parentheses and calls ``f(arg, ...)`` of
:data:`ALLOWED_FUNCTIONS` with positional arguments.
"""

from __future__ import annotations

import ast
import math
import numbers
import operator
import re
import unicodedata

import sympy

from ..core.limits import cap

__all__ = [
    "ALLOWED_CONSTANTS",
    "ALLOWED_FUNCTIONS",
    "ExpressionError",
    "MAX_DEPTH",
    "MAX_LENGTH",
    "MAX_NODES",
    "parse_expression",
    "parse_matrix",
]

# characters, nesting levels of the syntax tree, and numbers, names and operations of one expression
# (the caps table, vcirun.core.limits, says why)
MAX_LENGTH = cap("expression_characters")
MAX_DEPTH = cap("expression_depth")
MAX_NODES = cap("expression_nodes")
# Exact integers/rationals are capped so "9**9**9" (or sympy's root extraction on huge
# integers) cannot eat the machine; 1024 bits (~308 digits) is far beyond physical needs.
_MAX_INT_BITS = 1024
# sympy expands exact powers eagerly ((2*x)**n -> 2**n * x**n, 3**(p/q) -> 3**(p//q), and
# (re + I*im)**n when asked whether x**n is real), so exact exponents stay small (numerator
# and denominator); a float exponent (x**250.0) is never expanded.
_MAX_EXPONENT = 100
_MAX_TOKEN_CHARS = 60  # offending tokens are shortened so messages stay one readable line

class Abs(sympy.Abs):
    """abs() of a user expression: |u| of a real argument. Coordinates are plain sympy symbols (not
    declared real), for which sympy writes d|x|/dx with re(x) and im(x), which no kernel can print;
    here d|u|/dx = sign(u) du/dx, as for every real u (the kernels' arguments are real). The class
    keeps sympy's name, so every printer prints it as abs (sympy's printers dispatch on the name)."""

    def fdiff(self, argindex=1):
        return sign(self.args[0])

    def _eval_derivative(self, x):
        return sign(self.args[0]) * sympy.diff(self.args[0], x)


class sign(sympy.sign):  # noqa: N801 - sympy's name, for its printers
    """sign(u) of a real u, the derivative of `Abs`: its own derivative is 0 wherever it is defined
    (u != 0), which is what the generated Jacobians and Hessians need."""

    def fdiff(self, argindex=1):
        return sympy.S.Zero

    def _eval_derivative(self, x):
        return sympy.S.Zero


ALLOWED_FUNCTIONS: dict[str, object] = {
    "sin": sympy.sin,
    "cos": sympy.cos,
    "tan": sympy.tan,
    "exp": sympy.exp,
    "log": sympy.log,
    "sqrt": sympy.sqrt,
    "sinh": sympy.sinh,
    "cosh": sympy.cosh,
    "tanh": sympy.tanh,
    "asin": sympy.asin,
    "acos": sympy.acos,
    "atan": sympy.atan,
    "atan2": sympy.atan2,
    "abs": Abs,
}
_ARITY = {name: 1 for name in ALLOWED_FUNCTIONS} | {"atan2": 2}
_ARITHMETIC = {"+": operator.add, "-": operator.sub, "*": operator.mul,
               "/": operator.truediv, "**": operator.pow}

ALLOWED_CONSTANTS: dict[str, sympy.Expr] = {"pi": sympy.pi, "E": sympy.E}

_FUNCS_HINT = "allowed functions: " + ", ".join(ALLOWED_FUNCTIONS)
_GRAMMAR_HINT = ("only numbers, declared names, pi, E, + - * / **, parentheses and calls "
                 "like sin(x) are allowed")
_BINOP_SYMBOLS = {
    ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.Pow: "**",
    ast.FloorDiv: "//", ast.Mod: "%", ast.MatMult: "@", ast.LShift: "<<",
    ast.RShift: ">>", ast.BitOr: "|", ast.BitXor: "^", ast.BitAnd: "&",
}
_UNARY_SYMBOLS = {ast.UAdd: "+", ast.USub: "-", ast.Not: "not", ast.Invert: "~"}
# Human names for rejected node types (anything else falls back to the class name).
_NODE_NAMES = {
    ast.Attribute: "attribute access", ast.Subscript: "subscript", ast.Slice: "slice",
    ast.Lambda: "lambda", ast.ListComp: "comprehension", ast.SetComp: "comprehension",
    ast.DictComp: "comprehension", ast.GeneratorExp: "generator expression",
    ast.Compare: "comparison", ast.BoolOp: "boolean operator",
    ast.IfExp: "conditional expression", ast.NamedExpr: "assignment expression (:=)",
    ast.Starred: "starred argument", ast.JoinedStr: "f-string",
    ast.FormattedValue: "f-string", ast.Tuple: "tuple", ast.List: "list", ast.Set: "set",
    ast.Dict: "dict", ast.Await: "await", ast.Yield: "yield", ast.YieldFrom: "yield",
}


class ExpressionError(ValueError):
    """A user expression was rejected.

    Attributes ``field`` (config location, e.g. ``"system.potential"``), ``token`` (the
    offending piece of text) and ``reason`` (what is wrong and how to fix it; it quotes
    the token). ``str(err)`` is the single line ``"<field>: <reason>"``.
    """

    def __init__(self, field: str, token: str, reason: str):
        self.field = field
        self.token = token
        self.reason = reason
        # One line, whatever the inputs hold, so it reads well in CLI/log output.
        super().__init__(" ".join(f"{field}: {reason}".split()))


def _number_problem(value) -> str | None:
    """Why a sympy number is out of the safe range, or None if it is fine."""
    if getattr(value, "is_Rational", False) and (
            max(abs(value.p).bit_length(), value.q.bit_length()) > _MAX_INT_BITS):
        return f"exact number over {_MAX_INT_BITS} bits (write it as a float, e.g. 1e300)"
    if getattr(value, "is_Number", False) and value.is_finite:
        as_float = float(value)
        if math.isinf(as_float):
            return "number beyond the floating-point range (~1.8e308)"
        if as_float == 0.0 and not value.is_zero:  # e.g. 1e-300**2: sympy would chase its digits
            return "nonzero number below the floating-point range (~1e-308)"
    return None


def _constant_problem(value: sympy.Expr) -> str | None:
    """Like _number_problem, for a symbol-free expression such as cosh(1e3) or pi**40.

    sympy keeps these unevaluated but evaluates them numerically when asked about their sign,
    and f(g(huge)) then needs astronomically many digits; keeping every constant inside the
    double range (and real) keeps every later evaluation cheap.
    """
    try:
        re_part, im_part = value.evalf(15).as_real_imag()
    except Exception:  # noqa: BLE001 - any sympy failure means we cannot vouch for it
        return "constant that cannot be evaluated"
    problem = _number_problem(re_part) or _number_problem(im_part)
    if not problem and im_part.is_Number and not im_part.is_zero:
        problem = "complex value (only real expressions are allowed)"
    return problem


def _short(token: str) -> str:
    return token if len(token) <= _MAX_TOKEN_CHARS else token[: _MAX_TOKEN_CHARS - 3] + "..."


def _sum(*terms):
    return sympy.Add(*terms)


def _product(*factors):
    return sympy.Mul(*factors)


def _reciprocal(x):
    return sympy.Pow(x, sympy.S.NegativeOne)   # (what a / b builds for b)


class _Builder:
    """Walks a parsed tree and builds the sympy expression; one instance per text."""

    def __init__(self, text: str, symbols: dict, field: str):
        self.text = text
        self.symbols = symbols
        self.field = field

    def fail(self, token: str, reason: str) -> ExpressionError:
        return ExpressionError(self.field, token, reason)

    def segment(self, node: ast.AST) -> str:
        """The source text of `node`, shortened (a one-line text is sliced by the node's columns:
        ast.get_source_segment splits the whole text per call, quadratic over a long sum)."""
        if "\n" not in self.text and getattr(node, "end_col_offset", None) is not None:
            seg = self.text.encode()[node.col_offset:node.end_col_offset].decode("utf-8", "replace")
        else:
            seg = ast.get_source_segment(self.text, node)
        return _short(seg if seg is not None else type(node).__name__)

    def walk(self, node: ast.AST, depth: int) -> sympy.Expr:
        if depth > MAX_DEPTH:
            tok = self.segment(node)
            raise self.fail(tok, f"expression nested deeper than {MAX_DEPTH} levels (at {tok!r}, "
                                 f"column {node.col_offset + 1}); split it or simplify it")
        if isinstance(node, ast.Constant):
            return self.constant(node)
        if isinstance(node, ast.Name):
            return self.name(node)
        if isinstance(node, ast.BinOp):
            return self.binop(node, depth)
        if isinstance(node, ast.UnaryOp):
            return self.unaryop(node, depth)
        if isinstance(node, ast.Call):
            return self.call(node, depth)
        tok = self.segment(node)
        kind = _NODE_NAMES.get(type(node), f"{type(node).__name__} expression")
        raise self.fail(tok, f"{kind} {tok!r} is not allowed; {_GRAMMAR_HINT}")

    def constant(self, node: ast.Constant) -> sympy.Expr:
        value, tok = node.value, self.segment(node)
        # bool is a subclass of int, so it must be rejected before the int branch.
        if isinstance(value, bool):
            raise self.fail(tok, f"boolean {tok!r} is not allowed; write 1 or 0")
        if isinstance(value, int):  # e.g. a long hex literal
            return self.checked(sympy.Integer(value), tok)
        if isinstance(value, float):
            if not math.isfinite(value):  # e.g. 1e999 overflows to inf
                raise self.fail(tok, f"number {tok!r} is not finite; use a smaller literal")
            return sympy.Float(value)
        kind = {str: "string", bytes: "bytes literal", complex: "complex number"}.get(
            type(value), "constant")
        raise self.fail(tok, f"{kind} {tok!r} is not allowed; only real numbers such as 2, "
                             "0.5 or 1e-3 are accepted")

    def name(self, node: ast.Name) -> sympy.Expr:
        ident = node.id
        if ident.startswith("__"):
            raise self.fail(ident, f"name {ident!r} is not allowed (dunder names are forbidden)")
        # Declared names shadow the constants: the user chose them explicitly.
        if ident in self.symbols:
            return self.symbols[ident]
        if ident in ALLOWED_CONSTANTS:
            return ALLOWED_CONSTANTS[ident]
        if ident in ALLOWED_FUNCTIONS:
            raise self.fail(ident, f"{ident!r} is a function; call it, e.g. {ident}(x)")
        raise self.fail(ident, f"unknown name {ident!r} ({self.names_hint()}; {_FUNCS_HINT})")

    def names_hint(self) -> str:
        names = list(self.symbols)
        shown = ", ".join(names[:30]) + (", ..." if len(names) > 30 else "")
        return f"declared names: {shown or '(none)'}; constants: pi, E"

    def binop(self, node: ast.BinOp, depth: int) -> sympy.Expr:
        # Walk the left spine iteratively: "a + b + c + ..." is a left-leaning chain, and a
        # long sum should not count as deep nesting nor recurse once per term. The terms of a run
        # of + and - are added once, at its end (sympy's a + b flattens the whole sum each time:
        # quadratic over a long sum); numbers they fold are checked at the end of parse_expression.
        spine = []
        while isinstance(node, ast.BinOp):
            spine.append(node)
            node = node.left
        acc = self.walk(node, depth + 1)
        terms = None     # the pending terms of a run of + and -
        factors = None   # ... and factors of a run of * and /
        for op_node in reversed(spine):  # innermost first = left-to-right source order
            op = type(op_node.op)
            sym = _BINOP_SYMBOLS.get(op, type(op_node.op).__name__)
            if op is ast.BitXor:
                tok = self.segment(op_node)
                raise self.fail("^", f"operator '^' in {tok!r} is not allowed; "
                                     "use ** for powers, e.g. x**2")
            if sym not in ("+", "-", "*", "/", "**"):
                tok = self.segment(op_node)
                raise self.fail(sym, f"operator {sym!r} in {tok!r} is not allowed; "
                                     "use + - * / **")
            right = self.walk(op_node.right, depth + 1)
            if sym in ("+", "-"):
                if factors is not None:
                    acc, factors = self.apply(_product, factors, op_node.left), None
                if terms is None:
                    terms = [acc]
                terms.append(right if sym == "+" else self.apply(operator.neg, (right,), op_node))
                continue
            if terms is not None:
                acc, terms = self.apply(_sum, terms, op_node.left), None
            if sym in ("*", "/"):
                if factors is None:
                    factors = [acc]
                factors.append(right if sym == "*" else self.apply(_reciprocal, (right,), op_node))
                continue
            if factors is not None:
                acc, factors = self.apply(_product, factors, op_node.left), None
            self.check_power(acc, right, op_node)
            acc = self.apply(_ARITHMETIC[sym], (acc, right), op_node)
        if terms is not None:
            acc = self.apply(_sum, terms, spine[0])
        if factors is not None:
            acc = self.apply(_product, factors, spine[0])
        return acc

    def check_power(self, base: sympy.Expr, exponent: sympy.Expr, node) -> None:
        """Refuse exact powers sympy would expand into huge numbers, before computing them."""
        if not getattr(exponent, "is_Rational", False):
            return
        tok = self.segment(node)
        # Integer powers of plain numbers (10**-6, 2**64) are bounded by the size check below.
        plain = getattr(base, "is_Rational", False) and exponent.is_Integer
        if not plain and max(abs(exponent.p), exponent.q) > _MAX_EXPONENT:
            raise self.fail(tok, f"exact exponent in {tok!r} is too large (numerator and "
                                 f"denominator at most {_MAX_EXPONENT}); use a float exponent, "
                                 "e.g. x**250.0")
        coeff = base.as_coeff_Mul()[0] if isinstance(base, sympy.Expr) else None
        if getattr(coeff, "is_Rational", False) and coeff not in (0, 1, -1):
            bits = abs(float(exponent)) * max(math.log2(abs(coeff.p)), math.log2(coeff.q))
            if bits > _MAX_INT_BITS:
                raise self.fail(tok, f"exact power {tok!r} is too large (over {_MAX_INT_BITS} "
                                     "bits); write it as a float, e.g. 1e300")

    def apply(self, fn, args, node) -> sympy.Expr:
        """Build ``fn(*args)`` with sympy, keeping numeric results within safe bounds (`node`: the
        syntax node or text the messages quote)."""
        try:
            value = fn(*args)
        except Exception as exc:  # noqa: BLE001 - sympy may fail in many ways on odd input
            tok = node if isinstance(node, str) else self.segment(node)
            raise self.fail(tok, f"cannot evaluate {tok!r} ({type(exc).__name__})") from None
        return self.checked(value, node)

    def checked(self, value: sympy.Expr, node) -> sympy.Expr:
        # Bounded numbers at every step mean no later step can blow up (10.0**10.0**10.0**10.0
        # would otherwise make mpmath build a 10**10-digit exponent). The numeric factor of a
        # product counts too: (2*x)**n puts 2**n there.
        if not isinstance(value, sympy.Expr):
            return value
        problem = _number_problem(value.as_coeff_Mul()[0])
        if not problem and value.is_number and not value.is_Number:
            problem = _constant_problem(value)
        if problem:
            tok = node if isinstance(node, str) else self.segment(node)
            raise self.fail(tok, f"{problem} in {tok!r}")
        return value

    def unaryop(self, node: ast.UnaryOp, depth: int) -> sympy.Expr:
        op = type(node.op)
        if op not in (ast.UAdd, ast.USub):
            sym = _UNARY_SYMBOLS.get(op, op.__name__)
            tok = self.segment(node)
            raise self.fail(sym, f"operator {sym!r} in {tok!r} is not allowed; "
                                 "only unary + and - are")
        operand = self.walk(node.operand, depth + 1)
        return -operand if op is ast.USub else operand

    def call(self, node: ast.Call, depth: int) -> sympy.Expr:
        func, tok = node.func, self.segment(node)
        if not isinstance(func, ast.Name):
            self.walk(func, depth + 1)  # reports attribute access, lambdas, ... precisely
            ftok = self.segment(func)
            raise self.fail(ftok, f"{ftok!r} cannot be called; only {_FUNCS_HINT}")
        name = func.id
        if name.startswith("__"):
            raise self.fail(name, f"name {name!r} is not allowed (dunder names are forbidden)")
        if name not in ALLOWED_FUNCTIONS:
            what = "is not a function" if name in self.symbols or name in ALLOWED_CONSTANTS \
                else "is not an allowed function"
            raise self.fail(name, f"{name!r} {what} in {tok!r} ({_FUNCS_HINT})")
        if node.keywords:
            kw = self.segment(node.keywords[0])
            raise self.fail(kw, f"keyword argument {kw!r} in {tok!r} is not allowed; "
                                "pass arguments by position")
        for arg in node.args:
            if isinstance(arg, ast.Starred):
                star = self.segment(arg)
                raise self.fail(star, f"starred argument {star!r} in {tok!r} is not allowed")
        want = _ARITY[name]
        if len(node.args) != want:
            raise self.fail(name, f"{name} takes {want} argument{'s' * (want > 1)}, got "
                                  f"{len(node.args)} in {tok!r}")
        args = [self.walk(arg, depth + 1) for arg in node.args]
        return self.apply(ALLOWED_FUNCTIONS[name], args, tok)


def _syntax_error(text: str, lead: str, exc: SyntaxError, field: str) -> ExpressionError:
    """Translate a SyntaxError on the stripped ``text`` into an ExpressionError whose
    position refers to the original text (``lead`` is the whitespace stripped in front)."""
    lineno, offset = exc.lineno, exc.offset
    msg = exc.msg or "invalid syntax"
    if not lineno or not offset:  # e.g. "x +": Python reports no useful column
        tok = _short(text)
        return ExpressionError(field, tok, f"syntax error in {tok!r}: {msg}")
    lines = text.splitlines() or [""]
    line = lines[lineno - 1] if lineno <= len(lines) else ""
    found = re.compile(r"\w+|\S").search(line, offset - 1)
    tok = _short(found.group() if found else "end of text")
    # Map the position back through the leading whitespace we stripped before parsing.
    shift_lines = lead.count("\n")
    col = offset + (len(lead) - lead.rfind("\n") - 1 if lineno == 1 else 0)
    where = f"column {col}" if "\n" not in text else f"line {lineno + shift_lines}, column {col}"
    return ExpressionError(field, tok, f"syntax error at {where} near {tok!r}: {msg} "
                                       "(check parentheses and operators)")


def _number(value, field: str) -> sympy.Expr:
    """A number given directly (e.g. by YAML) instead of as text, under the same bounds."""
    tok = _short(repr(value))
    if isinstance(value, bool):  # bool is an Integral; True in a config is a mistake
        raise ExpressionError(field, tok, f"boolean {tok} is not a number; write 1 or 0")
    if isinstance(value, numbers.Integral):
        number = sympy.Integer(int(value))
    elif math.isfinite(float(value)):
        number = sympy.Float(float(value))
    else:
        raise ExpressionError(field, tok, f"number {tok} is not finite")
    problem = _number_problem(number)
    if problem:
        raise ExpressionError(field, tok, f"{problem}: {tok}")
    return number


def _check_ascii(text: str, field: str) -> None:
    """Expressions are ASCII: Python's parser reads identifiers through NFKC normalisation, so a
    full-width or mathematical letter would silently become its ASCII look-alike ('ｋ' is read as 'k')."""
    if text.isascii():
        return
    col, ch = next((i, c) for i, c in enumerate(text) if not c.isascii())
    norm = unicodedata.normalize("NFKC", ch)
    hint = (f"write {norm!r}" if norm.isascii() and norm.strip()
            else "use ASCII names, digits and operators only")
    raise ExpressionError(field, ch, f"non-ASCII character {ch!r} (U+{ord(ch):04X} "
                                     f"{unicodedata.name(ch, 'unnamed character')}) at column {col + 1}; "
                                     f"expressions must be ASCII ({hint})")


def parse_expression(text: str, symbols: dict[str, sympy.Symbol], field: str) -> sympy.Expr:
    """Parse ``text`` against the whitelist and return the sympy expression it denotes.

    ``symbols`` maps the names the user may write to sympy objects (declared names take
    precedence over ``pi``/``E``). ``field`` names the config location for error messages.
    A plain int/float is also accepted (YAML gives ``potential: 0`` as a number).
    Raises :class:`ExpressionError` for anything outside the grammar; the text is never
    executed.
    """
    if isinstance(text, numbers.Real):
        return _number(text, field)
    if not isinstance(text, str):
        raise ExpressionError(field, type(text).__name__,
                              f"expected an expression string, got {type(text).__name__}")
    if len(text) > MAX_LENGTH:
        tok = _short(text)
        raise ExpressionError(field, tok, f"expression {tok!r} is {len(text)} characters "
                                          f"long; the limit is {MAX_LENGTH}")
    _check_ascii(text, field)
    stripped = text.strip()
    if not stripped:
        raise ExpressionError(field, "", "expression is empty; write e.g. 0 or m*g*y")
    # compile() rejects leading whitespace in eval mode ("unexpected indent"), so strip it.
    lead = text[: len(text) - len(text.lstrip())]
    try:
        tree = ast.parse(stripped, mode="eval")
    except SyntaxError as exc:
        raise _syntax_error(stripped, lead, exc, field) from None
    except (RecursionError, MemoryError, ValueError):  # parser limits on pathological input
        tok = _short(stripped)
        raise ExpressionError(field, tok, f"expression {tok!r} is too deeply nested or too "
                                          "complex to parse; simplify it") from None
    n_nodes = sum(1 for node in ast.walk(tree.body) if not isinstance(node, (ast.operator, ast.unaryop, ast.Load)))
    if n_nodes > MAX_NODES:
        tok = _short(stripped)
        raise ExpressionError(field, tok, f"expression {tok!r} has {n_nodes} numbers, names and operations; "
                                          f"the limit is {MAX_NODES} (split it with parameters or simplify it)")
    expr = _Builder(stripped, symbols, field).walk(tree.body, 0)
    # 1/0 or log(0) give zoo/nan in sympy instead of raising: refuse them here.
    if isinstance(expr, sympy.Basic) and expr.has(sympy.zoo, sympy.nan, sympy.oo, -sympy.oo):
        tok = _short(stripped)
        raise ExpressionError(field, tok, f"expression {tok!r} is undefined or infinite "
                                          "(division by zero?)")
    # sympy folds numbers inside sums (x + 2**1023 + 2**1023) past the per-step checks.
    problems = (_number_problem(n) for n in expr.atoms(sympy.Number)) \
        if isinstance(expr, sympy.Basic) else ()
    problem = next((p for p in problems if p), None)
    if problem:
        tok = _short(stripped)
        raise ExpressionError(field, tok, f"{problem} in {tok!r}")
    return expr


def parse_matrix(entries, symbols: dict[str, sympy.Symbol], field: str) -> sympy.Matrix:
    """Parse an ``n x n`` list of lists of expression strings / numbers into a sympy Matrix.

    Errors name the exact location, e.g. ``system.mass_matrix[1][0]`` for a bad entry or
    ``system.mass_matrix[1]`` for a row of the wrong length.
    """
    if not isinstance(entries, (list, tuple)) or not entries:
        raise ExpressionError(field, _short(repr(entries)),
                              "expected a non-empty square list of rows, e.g. [[m, 0], [0, m]]")
    n = len(entries)
    rows = []
    for i, row in enumerate(entries):
        where = f"{field}[{i}]"
        if not isinstance(row, (list, tuple)):
            raise ExpressionError(where, _short(repr(row)),
                                  f"row {_short(repr(row))} must be a list of {n} entries")
        if len(row) != n:
            raise ExpressionError(where, _short(repr(row)),
                                  f"row {_short(repr(row))} has {len(row)} entries but the "
                                  f"matrix has {n} rows; it must be square ({n} x {n})")
        parsed = []
        for j, value in enumerate(row):
            at = f"{where}[{j}]"
            if not isinstance(value, (str, numbers.Real)):
                raise ExpressionError(at, _short(repr(value)), f"entry {_short(repr(value))} "
                                      "must be an expression string or a number")
            parsed.append(parse_expression(value, symbols, at))
        rows.append(parsed)
    return sympy.Matrix(rows)
