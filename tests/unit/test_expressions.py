"""Unit tests for the whitelist expression parser (vcirun.mechanics.expressions)."""

import builtins
import time

import pytest
import sympy

from vcirun.mechanics.expressions import (
    ALLOWED_CONSTANTS,
    ALLOWED_FUNCTIONS,
    Abs,
    ExpressionError,
    parse_expression,
    parse_matrix,
)

FIELD = "system.potential"
x, y, theta, m1, m2, L, g, k = sympy.symbols("x y theta m1 m2 L g k")
SYMBOLS = {str(s): s for s in (x, y, theta, m1, m2, L, g, k)}


def parse(text):
    return parse_expression(text, SYMBOLS, FIELD)


@pytest.mark.parametrize(
    "text, expected",
    [
        ("m2*L*sin(theta)", m2 * L * sympy.sin(theta)),
        ("0.5*k*x**2", sympy.Float(0.5) * k * x**2),
        ("-g*y", -g * y),
        ("1e-3*x", sympy.Float(1e-3) * x),
        ("2.5E+2", sympy.Float(250.0)),
        ("atan2(y, x)", sympy.atan2(y, x)),
        ("pi*x", sympy.pi * x),
        ("E**x", sympy.exp(x)),
        ("+x - (y)", x - y),
        ("1/2*m1*x**2", sympy.Rational(1, 2) * m1 * x**2),
        ("abs(x) + sqrt(y) + log(k)", Abs(x) + sympy.sqrt(y) + sympy.log(k)),   # |x| of a real x
        ("  cos(theta)**2 + tanh(x)\n", sympy.cos(theta) ** 2 + sympy.tanh(x)),
        ("(x\n + y)", x + y),
        ("+".join(["x"] * 300), 300 * x),  # a long flat sum is not "deep nesting"
    ],
)
def test_valid_expressions(text, expected):
    result = parse(text)
    assert result == expected
    assert sympy.simplify(result - expected) == 0


def test_every_allowed_function_and_constant_parses():
    for name, func in ALLOWED_FUNCTIONS.items():
        args = "y, x" if name == "atan2" else "x"
        expected = func(y, x) if name == "atan2" else func(x)
        assert parse(f"{name}({args})") == expected
    for name, value in ALLOWED_CONSTANTS.items():
        assert parse(name) == value


def test_numbers_are_accepted_as_values():
    assert parse(0) == 0 and isinstance(parse(3), sympy.Integer)
    assert parse(2.5) == sympy.Float(2.5)


# (hostile or malformed text, token that must appear in the message)
REJECTED = [
    ("__import__('os').system('echo pwned')", "__import__"),
    ("__import__('os')", "__import__"),
    ("x.__class__", "__class__"),
    ("().__class__.__bases__", "__bases__"),
    ("lambda: 1", "lambda"),
    ("[i for i in range(3)]", "[i for i in range(3)]"),
    ("open('f')", "open"),
    ("eval('1')", "eval"),
    ("exec('x=1')", "exec"),
    ("import os", "import"),
    ("sin(x", "("),
    ("x)", ")"),
    ("z", "z"),
    ("x if y else 1", "x if y else 1"),
    ("'abc'", "abc"),
    ("b'abc'", "abc"),
    ("x ^ 2", "^"),
    ("sin(x, y)", "sin"),
    ("atan2(x)", "atan2"),
    ("sin(x=1)", "x=1"),
    ("sin(*x)", "*x"),
    ("x[0]", "x[0]"),
    ("True", "True"),
    ("None", "None"),
    ("1j", "1j"),
    ("(x := 3)", "x := 3"),
    ("f'{x}'", "f'{x}'"),
    ("x < y", "x < y"),
    ("x and y", "x and y"),
    ("x // 2", "//"),
    ("not x", "not"),
    ("(x + 1)(2)", "x + 1"),
    ("x(2)", "x"),
    ("__builtins__", "__builtins__"),
    ("1e999", "1e999"),
    ("9**9**9", "9**9**9"),
    ("1/0", "1/0"),
    ("-" * 101 + "x", "x"),
]


@pytest.mark.parametrize("text, token", REJECTED)
def test_rejected_expressions(text, token):
    with pytest.raises(ExpressionError) as info:
        parse(text)
    err = info.value
    message = str(err)
    assert isinstance(err, ValueError)
    assert err.field == FIELD
    assert message.startswith(FIELD + ": ")
    assert token in message and token in err.token
    assert "\n" not in message
    assert err.reason and err.reason in message


def test_specific_hints():
    with pytest.raises(ExpressionError, match=r"use \*\* for powers"):
        parse("x ^ 2")
    with pytest.raises(ExpressionError, match="takes 1 argument, got 2"):
        parse("sin(x, y)")
    with pytest.raises(ExpressionError, match=r"column 4"):  # position of the unclosed '('
        parse("sin(x")
    with pytest.raises(ExpressionError) as info:
        parse("z")
    assert "declared names: x, y, theta" in str(info.value)
    assert "allowed functions: sin, cos" in str(info.value)


@pytest.mark.parametrize("text", ["", "   ", "\n"])
def test_empty_text_rejected(text):
    with pytest.raises(ExpressionError, match=f"^{FIELD}: expression is empty"):
        parse(text)


@pytest.mark.parametrize(
    "text",
    [
        "9**9**9",  # exact power with ~10**8 digits
        "(2*x)**(3**600)",  # sympy would distribute the power onto the 2
        "x**(1/1000)",  # exact exponents are kept small
        "10.0**10.0**10.0**10.0",  # float with a 10**10-digit exponent
        "exp(exp(exp(100.0)))",
        "cosh(cosh(1000))",  # symbolic constant far beyond the double range
        "1e-300**2",  # underflows the double range
        "x + 2**1023 + 2**1023",  # folded by sympy after the per-step checks
        "x*1e308*10",
        "sqrt(-1)",  # complex constants are refused like complex literals
        "log(0)",
        "x/0",
    ],
)
def test_numeric_bombs_rejected_quickly(text):
    start = time.perf_counter()
    with pytest.raises(ExpressionError, match=f"^{FIELD}: "):
        parse(text)
    assert time.perf_counter() - start < 5.0


def test_big_but_reasonable_numbers_accepted():
    assert parse("2**1023") == sympy.Integer(2) ** 1023
    assert parse("10**-6*x") == x / 10**6
    assert parse("x**250.0") == x ** sympy.Float(250.0)
    assert parse("1e308*x") == sympy.Float(1e308) * x
    assert parse("0.0") == sympy.Float(0.0)


def test_error_position_counts_leading_whitespace():
    with pytest.raises(ExpressionError, match="column 4 near '\\)'"):
        parse("  x)")


def test_too_long_and_too_deep_rejected():
    with pytest.raises(ExpressionError, match="limit is 10000"):
        parse("x" * 10_001)
    with pytest.raises(ExpressionError, match="nested deeper than 100"):
        parse("sin(" * 101 + "x" + ")" * 101)
    assert parse("sin(" * 99 + "x" + ")" * 99) is not None
    with pytest.raises(ExpressionError):  # beyond the Python parser's own limits
        parse("-" * 9_999 + "x")


def test_non_string_rejected():
    with pytest.raises(ExpressionError, match="expected an expression string"):
        parse_expression(["x"], SYMBOLS, FIELD)
    with pytest.raises(ExpressionError, match="boolean"):
        parse_expression(True, SYMBOLS, FIELD)
    with pytest.raises(ExpressionError, match="over 1024 bits"):
        parse_expression(10**400, SYMBOLS, FIELD)
    with pytest.raises(ExpressionError, match="not finite"):
        parse_expression(float("nan"), SYMBOLS, FIELD)


def test_nothing_is_executed(tmp_path, monkeypatch):
    target = tmp_path / "vcirun_pwned"
    target.unlink(missing_ok=True)
    hostile = [
        f"__import__('pathlib').Path({str(target)!r}).touch()",
        f"open({str(target)!r}, 'w')",
        f"exec(\"open({str(target)!r}, 'w')\")",
        f"[__import__('pathlib').Path({str(target)!r}).touch() for _ in (1,)]",
        f"x + (lambda: __import__('pathlib').Path({str(target)!r}).touch())()",
    ]

    # eval/exec must never be reached, whatever the input.
    def forbidden(*args, **kwargs):
        raise AssertionError("eval/exec called")

    monkeypatch.setattr(builtins, "eval", forbidden)
    monkeypatch.setattr(builtins, "exec", forbidden)
    for text in hostile:
        with pytest.raises(ExpressionError):
            parse(text)
    assert parse("m2*L*sin(theta)") == m2 * L * sympy.sin(theta)
    assert not target.exists()


def test_parse_matrix_square():
    matrix = parse_matrix([["m1 + m2", "m2*L*cos(theta)"], ["m2*L*cos(theta)", 1.5]],
                          SYMBOLS, "system.mass_matrix")
    expected = sympy.Matrix([[m1 + m2, m2 * L * sympy.cos(theta)],
                             [m2 * L * sympy.cos(theta), sympy.Float(1.5)]])
    assert matrix.shape == (2, 2)
    assert matrix == expected


def test_parse_matrix_ragged_and_bad_entries():
    with pytest.raises(ExpressionError) as info:
        parse_matrix([["m1", 0], [0]], SYMBOLS, "system.mass_matrix")
    assert info.value.field == "system.mass_matrix[1]"
    assert str(info.value).startswith("system.mass_matrix[1]: ") and "square" in str(info.value)

    with pytest.raises(ExpressionError) as info:
        parse_matrix([["m1", 0, 0], [0, "m1", 0]], SYMBOLS, "system.mass_matrix")
    assert info.value.field == "system.mass_matrix[0]"

    with pytest.raises(ExpressionError) as info:
        parse_matrix([["m1", 0], ["z", "m1"]], SYMBOLS, "system.mass_matrix")
    assert info.value.field == "system.mass_matrix[1][0]"
    assert str(info.value).startswith("system.mass_matrix[1][0]: unknown name 'z'")

    for bad in ([], "m1", [["m1", None], [0, 1]], [[True, 0], [0, 1]]):
        with pytest.raises(ExpressionError, match=r"^system\.mass_matrix"):
            parse_matrix(bad, SYMBOLS, "system.mass_matrix")
