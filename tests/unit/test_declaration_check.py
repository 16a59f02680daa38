"""A declaration the code generator cannot take is refused at construction, naming the cause: pydy /
sympy.physics.mechanics dynamicsymbols (Functions of t), stray symbols, parameters with assumptions."""
from __future__ import annotations

import pytest
import sympy as sp

from vcirun.mechanics.system import MechanicalSystem


def _system(**kw):
    y, th = sp.symbols("y theta")
    m = sp.Symbol("m")
    base = dict(name="user", q=[y, th], params={"m": 1.0}, M=sp.Matrix([[m, 0], [0, m]]), V=m * y, phi=y)
    return MechanicalSystem(**(base | kw))


def test_plain_declaration_is_accepted():
    assert _system().n == 2


def test_dynamicsymbols_are_named():
    me = pytest.importorskip("sympy.physics.mechanics")
    q1, q2 = me.dynamicsymbols("q1 q2")
    m = sp.Symbol("m")
    with pytest.raises(ValueError, match=r"coordinates contains q1\(t\), q2\(t\), sympy Functions of time .*dynamicsymbols"):
        MechanicalSystem(name="pydy", q=[q1, q2], params={"m": 1.0}, M=sp.eye(2) * m, V=m * q1, phi=q1)
    y, th = sp.symbols("y theta")
    with pytest.raises(ValueError, match=r"mass_matrix contains q2\(t\).*msubs"):
        _system(M=sp.Matrix([[m, 0], [0, m + sp.cos(q2) ** 2]]))
    with pytest.raises(ValueError, match=r"potential contains Derivative\(q1\(t\), t\)"):
        _system(V=sp.Derivative(q1, me.dynamicsymbols._t) ** 2)


def test_stray_symbols_are_named():
    with pytest.raises(ValueError, match=r"potential: k is neither a coordinate \(y, theta\) nor a parameter \(m\)"):
        _system(V=sp.Symbol("k") * sp.Symbol("y"))
    with pytest.raises(ValueError, match=r"other assumptions \(\{'positive': True\}\)"):
        _system(M=sp.Matrix([[sp.Symbol("m", positive=True), 0], [0, 1]]))
    with pytest.raises(ValueError, match="allowed in forcing only"):
        _system(phi=sp.Symbol("y_dot"))
    # velocities and t are fine in forcing
    yd = sp.Symbol("y_dot")
    s = _system(forcing=sp.Matrix([-yd * sp.Symbol("m") + sp.sin(sp.Symbol("t")), 0]))
    assert s.is_forced
