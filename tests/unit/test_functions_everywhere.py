"""Every function a user expression may call (vcirun.mechanics.expressions.ALLOWED_FUNCTIONS) in every
place a declaration takes an expression: the mass matrix, the potential, a constraint, the forcing, a
declared reset (positions and velocities) and a spring of the bodies form. Each is derived and printed
into the kernels of MCVAC (the system's kernels and the modified energy's higher derivatives). abs()
is the case that needs care: sympy's d|x|/dx of a symbol not declared real is written with re and
im, which no kernel prints. One slow test compiles and runs a system with every function in every
place."""
from __future__ import annotations

import re

import numpy as np
import pytest
import sympy as sp

import vcirun
from vcirun.codegen.derive import generated_source
from vcirun.mechanics.expressions import ALLOWED_FUNCTIONS, parse_expression
from vcirun.mechanics.loader import load_system_yaml
from vcirun.methods.table import METHODS

# an argument in [0.1, 0.3] wherever x is: inside every function's domain (asin, acos, log, sqrt)
U = "(0.2 + 0.1*sin({v}))"


def call(fn: str, v: str = "x") -> str:
    u = U.format(v=v)
    if fn == "atan2":
        return f"atan2({u}, 1.5)"
    if fn == "abs":
        return f"abs({v} - 0.3)"   # a kink inside the region the runs visit
    return f"{fn}({u})"


def hand_written(fns) -> dict:
    """A two-coordinate system with the functions `fns` in M, V, phi, the forcing and a declared reset
    (positions and velocities)."""
    every = lambda v: " + ".join(call(f, v) for f in fns)  # noqa: E731
    return {
        "name": "functions", "coordinates": ["x", "y"], "parameters": {"m": 1.0, "k": 1.0},
        "mass_matrix": [[f"m*(3 + 0.01*({every('x')}))", "0"], ["0", "m"]],
        "potential": f"0.5*k*x**2 + 0.5*k*y**2 + 0.01*({every('y')})",
        # (a declared reset needs a system of one constraint; the map keeps phi(q+) = phi(q-) = 0)
        "constraints": [{"name": "wall", "phi": f"x + 1 + 0.001*({every('x')})",
                         "reset": {"q": ["x", f"y + 0.001*({every('x')})"],
                                   "qdot": [f"-x_dot + 0.001*({every('x')})", f"y_dot + 0.001*({every('y_dot')})"]}}],
        "forcing": [f"-0.01*x_dot + 0.001*({every('x_dot')})", "0"],
        "q0": [0.2, 0.1], "qdot0": [-1.5, -0.3],
    }


def bodies(fns) -> dict:
    """A bodies declaration whose spring has the functions `fns` in its stiffness and rest length."""
    every = " + ".join(call(f, "y") for f in fns)
    return {
        "name": "spring_functions", "parameters": {"m": 1.0, "k": 2.0, "g": 9.81}, "gravity": "g",
        "bodies": [{"name": "a", "mass": "m"}, {"name": "b", "mass": "m"}],
        "joints": [{"type": "prismatic", "body": "a", "coordinate": "x", "axis": [1, 0]},
                   {"type": "prismatic", "body": "b", "coordinate": "y", "axis": [0, 1]}],
        "contacts": [{"name": "floor", "body": "b", "line": {"point": [0, -1], "normal": [0, 1]}}],
        "springs": [{"a": "a", "b": "b", "k": f"k*(1 + 0.01*({every}))", "length": f"0.5 + 0.01*({every})"}],
        "q0": {"x": 0.2, "y": 0.1},
    }


@pytest.mark.parametrize("fn", sorted(ALLOWED_FUNCTIONS))
@pytest.mark.parametrize("form", ["hand_written", "bodies"])
def test_every_function_prints_in_every_place(fn, form):
    system = load_system_yaml(hand_written([fn]) if form == "hand_written" else bodies([fn]))
    # MCVAC's kernels hold the system's (M, V, phi, forcing, reset) and the modified energy's derivatives
    src = generated_source(system, METHODS["MCVAC"].kernel_set())
    bad = re.findall(r"\b(?:re|im|Derivative|DiracDelta|zoo|Abs|sign)\(", src)
    assert not bad, (fn, bad)
    assert re.search(r"def \w*reset\w*\(", src) or form == "bodies"


def test_abs_has_the_derivative_of_a_real_argument():
    x, y = sp.symbols("x y")
    e = parse_expression("abs(x - 2*y)**3 + abs(x)", {"x": x, "y": y}, "f")
    for point in ((0.7, 0.1), (-0.4, 0.3), (0.5, 0.9)):
        for v in (x, y):
            d = float(e.diff(v).subs({x: point[0], y: point[1]}))
            h = 1e-6
            up = float(e.subs({x: point[0] + h * (v == x), y: point[1] + h * (v == y)}))
            dn = float(e.subs({x: point[0] - h * (v == x), y: point[1] - h * (v == y)}))
            assert d == pytest.approx((up - dn) / (2 * h), rel=1e-7, abs=1e-9)
        assert float(e.diff(x, 2).subs({x: point[0], y: point[1]})) == pytest.approx(
            6 * abs(point[0] - 2 * point[1]), rel=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("form", ["hand_written", "bodies"])
def test_every_function_compiles_and_runs(tmp_path, form):
    fns = sorted(ALLOWED_FUNCTIONS)
    system = load_system_yaml(hand_written(fns) if form == "hand_written" else bodies(fns))
    for method in ("CVA", "MCVAC"):
        tr = vcirun.simulate(system, method, h=1e-2, T=2.0)
        assert tr.status == "ok", (method, tr.message)
        assert np.all(np.isfinite(tr.q)) and np.all(np.isfinite(tr.H))
