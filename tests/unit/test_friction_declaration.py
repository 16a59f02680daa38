"""Coulomb friction declared on contacts (vcirun/mechanics/friction.py, loader.py, bodies.py):

  * the hand-written form: friction (number or parameter), static_friction, slip rows and
    tangent_gap (the row is its gradient);
  * the bodies form: the slip row from the geometry against independent rigid-body kinematics (the
    velocity v_C + omega x (P - C) of the material point at the contact, taken along the tangent
    t = (n_y, -n_x)): a point of a block, a disc rim on a floor and on an incline (a rolling disc has
    zero slip), two spinning discs;
  * bad declarations: an error naming the field and the fix (mu < 0, NaN, infinite, mu_s < mu, a
    parameter that does not exist or has a negative value, a slip row of the wrong length or with
    foreign symbols, friction without a slip row, a zero row, a row parallel to grad phi, slip and
    tangent_gap together); a slip row on a frictionless contact is accepted;
  * frictionless declarations are unchanged: explicit friction 0 gives the same system fingerprint
    (kernel cache key) as no friction, and FRICTION is false there.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import sympy as sp

from vcirun.mechanics.bodies import Body, CircleContact, Joint, PointContact, planar_system
from vcirun.mechanics.loader import load_system_yaml
from vcirun.mechanics.system import Constraint, MechanicalSystem


def _block(**contact):
    """A free block (x, y, theta) on the floor y = 0, hand-written; one corner's contact."""
    return {"name": "block", "coordinates": ["x", "y", "theta"],
            "parameters": {"m": 1.0, "g": 9.81, "a": 1.0, "b": 0.4, "mu": 0.3, "neg": -0.1},
            "mass_matrix": [["m", 0, 0], [0, "m", 0], [0, 0, "m*(a**2 + b**2)/12"]],
            "potential": "m*g*y",
            "constraints": [{"name": "corner", "phi": "y - b/2*sin(theta) - a/2*cos(theta)", **contact}]}


def _corner_row():
    # the corner (b/2, -a/2) of the block: x_P = x + b/2 cos th + a/2 sin th; t = (1, 0) on the floor
    th, a, b = sp.symbols("theta a b")
    return [sp.Integer(1), sp.Integer(0), -b / 2 * sp.sin(th) + a / 2 * sp.cos(th)]


def _same_row(row, want):
    assert len(row) == len(want)
    for r, w in zip(row, want):
        assert sp.simplify(sp.sympify(r) - w) == 0, (row, want)


# --- the hand-written form ------------------------------------------------------------------------------

def test_hand_written_slip_row_and_coefficients():
    s = load_system_yaml(_block(friction="mu", static_friction=0.5,
                                slip=[1, 0, "-b/2*sin(theta) + a/2*cos(theta)"]))
    c = s.constraints[0]
    assert c.friction == sp.Symbol("mu") and c.static_friction == sp.Float(0.5)
    _same_row(c.slip, _corner_row())
    assert s.has_friction
    mu, mus = s.friction_values()
    assert mu.tolist() == [0.3] and mus.tolist() == [0.5]
    mu, mus = s.friction_values(s.param_values({"mu": 0.45}))
    assert mu.tolist() == [0.45] and mus.tolist() == [0.5]
    W = s.slip_matrix_value([0.1, 0.2, 0.3])
    assert np.allclose(W, [[1.0, 0.0, -0.2 * math.sin(0.3) + 0.5 * math.cos(0.3)]], rtol=0, atol=1e-15)


def test_tangent_gap_gives_its_gradient_and_mu_s_defaults_to_mu():
    s = load_system_yaml(_block(friction=0.25, tangent_gap="x + b/2*cos(theta) + a/2*sin(theta)"))
    _same_row(s.constraints[0].slip, _corner_row())
    mu, mus = s.friction_values()
    assert mu.tolist() == [0.25] and mus.tolist() == [0.25]


def test_slip_row_on_a_frictionless_contact_is_accepted_and_unused():
    s = load_system_yaml(_block(slip=[1, 0, 0]))
    assert not s.has_friction
    assert s.slip_matrix == sp.zeros(1, 3)


def test_static_friction_alone_is_friction():
    s = load_system_yaml(_block(static_friction=0.4, slip=[1, 0, 0]))
    assert s.has_friction
    mu, mus = s.friction_values()
    assert mu.tolist() == [0.0] and mus.tolist() == [0.4]


@pytest.mark.parametrize("contact, field, words", [
    ({"friction": -0.1, "slip": [1, 0, 0]}, "constraints[0].friction", "< 0"),
    ({"friction": float("nan"), "slip": [1, 0, 0]}, "constraints[0].friction", "NaN"),
    ({"friction": float("inf"), "slip": [1, 0, 0]}, "constraints[0].friction", "infinite"),
    ({"friction": "nu", "slip": [1, 0, 0]}, "constraints[0].friction", "not a parameter"),
    ({"friction": "neg", "slip": [1, 0, 0]}, "constraints[0].friction", "parameters.neg"),
    ({"friction": True, "slip": [1, 0, 0]}, "constraints[0].friction", "number >= 0"),
    ({"friction": 0.5, "static_friction": 0.3, "slip": [1, 0, 0]}, "constraints[0].static_friction", "mu_s"),
    ({"friction": "mu", "static_friction": 0.2, "slip": [1, 0, 0]}, "constraints[0].static_friction", "mu_s"),
    ({"friction": 0.5, "slip": [1, 0]}, "constraints[0].slip", "3 expressions"),
    ({"friction": 0.5, "slip": "x"}, "constraints[0].slip", "3 expressions"),
    ({"friction": 0.5, "slip": [1, 0, "zeta"]}, "constraints[0].slip[2]", "zeta"),
    ({"friction": 0.5}, "constraints[0].friction", "slip"),
    ({"friction": 0.5, "slip": [0, 0, 0]}, "constraints[0].slip", "zero"),
    ({"friction": 0.5, "slip": ["sin(theta)**2 + cos(theta)**2 - 1", 0, 0]}, "constraints[0].slip", "zero"),
    # grad phi = (0, 1, -b/2 cos th + a/2 sin th): the row 2 grad phi slides only with the normal velocity
    ({"friction": 0.5, "slip": [0, 2, "-b*cos(theta) + a*sin(theta)"]}, "constraints[0].slip", "parallel"),
    ({"friction": 0.5, "tangent_gap": "(y - b/2*sin(theta) - a/2*cos(theta))**3"}, "constraints[0].slip",
     "parallel"),
    ({"friction": 0.5, "tangent_gap": "a"}, "constraints[0].tangent_gap", "does not depend"),
    ({"friction": 0.5, "slip": [1, 0, 0], "tangent_gap": "x"}, "constraints[0].tangent_gap", "not both"),
])
def test_bad_friction_declarations_name_the_field(contact, field, words):
    with pytest.raises(ValueError) as e:
        load_system_yaml(_block(**contact))
    msg = str(e.value)
    assert f"system.{field}" in msg and words in msg, msg


def test_python_constraint_errors_name_the_constraint():
    x, y = sp.symbols("x y")
    kw = dict(name="pt", q=[x, y], params={"m": 1.0}, M=sp.eye(2), V=0)
    with pytest.raises(ValueError, match=r"constraints\[0\] \(floor\)\.friction: friction on a contact without"):
        MechanicalSystem(**kw, constraints=[Constraint("floor", y, friction=0.2)])
    with pytest.raises(ValueError, match=r"constraints\[0\] \(floor\)\.slip: must be a list of 2"):
        MechanicalSystem(**kw, constraints=[Constraint("floor", y, friction=0.2, slip=(1,))])
    s = MechanicalSystem(**kw, constraints=[Constraint("floor", y, friction=sp.Rational(1, 5), slip=(1, 0))])
    assert s.friction_values()[0].tolist() == [0.2]


def test_one_coordinate_cannot_slide():
    # with one coordinate every row is parallel to grad phi: a 1-dof contact has no tangential motion
    with pytest.raises(ValueError, match="parallel"):
        load_system_yaml({"name": "one", "coordinates": ["x"], "mass_matrix": [[1]], "potential": "x**2/2",
                          "constraints": [{"phi": "x + 1", "friction": 0.3, "slip": [2]}]})


def test_friction_zero_keeps_the_fingerprint():
    a = load_system_yaml(_block())
    b = load_system_yaml(_block(friction=0, slip=[1, 0, 0]))
    c = load_system_yaml(_block(friction=0.3, slip=[1, 0, 0]))
    assert a.fingerprint() == b.fingerprint() != c.fingerprint()
    assert not a.has_friction and not b.has_friction
    d = load_system_yaml(_block(friction=0.3, slip=[1, 0, 1]))
    e = load_system_yaml(_block(friction=0.3, static_friction=0.4, slip=[1, 0, 0]))
    assert len({c.fingerprint(), d.fingerprint(), e.fingerprint()}) == 3


# --- the bodies form --------------------------------------------------------------------------------------

def _cross(w, r):
    """omega x r in the plane: omega (-r_y, r_x)."""
    return w * np.array([-r[1], r[0]])


def _rot(a):
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def test_block_corner_on_the_floor():
    s = planar_system("blk", [Body("block", "m", "m*(a**2 + b**2)/12")],
                      [Joint("free", "block", coordinates=("x", "y", "theta"))],
                      [PointContact("corner", "block", ("b/2", "-a/2"), friction="mu")],
                      params={"m": 1.0, "a": 1.0, "b": 0.4, "mu": 0.3}, gravity=9.81, q0=[0, 1, 0])
    _same_row(s.constraints[0].slip, _corner_row())


@pytest.mark.parametrize("slope", [0.0, 0.3, -1.1])
def test_disc_rim_on_a_line_is_the_material_point_and_rolling_has_zero_slip(slope, rng):
    # a disc of radius R (centre x, y; angle th) on the line through the origin with normal
    # (-sin slope, cos slope): the material point at the contact is C - R n
    R = 0.15
    n = np.array([-math.sin(slope), math.cos(slope)])
    s = planar_system("disc", [Body("d", "m", "m*R**2/2")], [Joint("free", "d", coordinates=("x", "y", "th"))],
                      [PointContact("line", "d", radius="R", normal=(float(-math.sin(slope)), float(math.cos(slope))),
                                    friction=0.4)],
                      params={"m": 1.0, "R": R}, q0=(2 * R * n).tolist() + [0.0])
    t = np.array([n[1], -n[0]])
    for _ in range(20):
        q, qd = rng.uniform(-2, 2, 3), rng.uniform(-3, 3, 3)
        vP = qd[:2] + _cross(qd[2], -R * n)
        W = s.slip_matrix_value(q)
        assert abs(float(W[0] @ qd) - float(vP @ t)) <= 1e-13 * (1 + np.abs(qd).max())
        # rolling: the centre moves along t at -R omega
        roll = np.array([*(-R * qd[2] * t), qd[2]])
        assert abs(float(W[0] @ roll)) <= 1e-14


def test_two_spinning_discs_slide_at_the_relative_velocity_of_their_contact_points(rng):
    # disc A on a free joint, disc B on a free joint with a centre offset in its frame
    s = planar_system(
        "discs", [Body("A", "mA", "mA*rA**2/2", radius="rA"), Body("B", "mB", "mB*rB**2/2", ("c", 0), radius="rB")],
        [Joint("free", "A", coordinates=("xa", "ya", "tha")), Joint("free", "B", coordinates=("xb", "yb", "thb"))],
        [CircleContact("AB", ("A", "B"), friction="mu", static_friction="mus")],
        params={"mA": 1.0, "mB": 2.0, "rA": 0.3, "rB": 0.5, "c": 0.2, "mu": 0.2, "mus": 0.3},
        q0=[0.0, 3.0, 0.0, 0.0, 0.0, 0.0])
    rA, rB, c = 0.3, 0.5, 0.2
    assert s.friction_values()[1].tolist() == [0.3]
    for _ in range(20):
        q, qd = rng.uniform(-2, 2, 6), rng.uniform(-3, 3, 6)
        CA, CB = q[:2], q[3:5] + _rot(q[5]) @ np.array([c, 0.0])
        vA = qd[:2]
        vB = qd[3:5] + _cross(qd[5], CB - q[3:5])   # B's centre is off its frame origin
        d = CA - CB
        n = d / np.linalg.norm(d)
        t = np.array([n[1], -n[0]])
        PA, PB = CA - rA * n, CB + rB * n
        vPA = vA + _cross(qd[2], PA - CA)
        vPB = vB + _cross(qd[5], PB - CB)
        W = s.slip_matrix_value(q)
        assert abs(float(W[0] @ qd) - float((vPA - vPB) @ t)) <= 1e-12 * (1 + np.abs(qd).max())
        # a translation of A along the normal does not slide
        along_n = np.zeros(6)
        along_n[:2] = n
        assert abs(float(W[0] @ along_n)) <= 1e-13


def test_bodies_friction_errors_name_the_field():
    def block(**kw):
        return planar_system("blk", [Body("block", 1.0, 0.1)], [Joint("free", "block", coordinates=("x", "y", "th"))],
                             [PointContact("corner", "block", (0.2, -0.5), **kw)], params={"mu": 0.3}, gravity=9.81,
                             q0=[0, 1, 0])

    with pytest.raises(ValueError, match=r"system\.contacts\[0\]\.friction: -1\.0 < 0"):
        block(friction=-1.0)
    with pytest.raises(ValueError, match=r"system\.contacts\[0\]\.static_friction: mu_s = 0\.2 < friction mu = 0\.3"):
        block(friction="mu", static_friction=0.2)
    with pytest.raises(ValueError, match=r"system\.contacts\[0\]\.friction: 'nu' is not a parameter"):
        block(friction="nu")
    # a body that cannot move along the line: a point on a vertical prismatic joint
    with pytest.raises(ValueError, match=r"system\.contacts\[0\]\.slip: the slip row is zero"):
        planar_system("cart", [Body("c", 1.0)], [Joint("prismatic", "c", coordinate="y", axis=(0, 1))],
                      [PointContact("floor", "c", friction=0.3)], gravity=9.81, q0=[1.0])
    assert block(friction=0).fingerprint() == block().fingerprint()


def test_bodies_yaml_friction_keys():
    s = load_system_yaml({
        "name": "disc_yaml", "parameters": {"m": 1.0, "R": 0.1, "mu": 0.2}, "gravity": 9.81,
        "bodies": [{"name": "d", "mass": "m", "inertia": "2/5*m*R**2"}],
        "joints": [{"type": "free", "body": "d", "coordinates": ["x", "y", "phi"]}],
        "contacts": [{"name": "floor", "body": "d", "radius": "R", "friction": "mu", "static_friction": 0.25}],
        "q0": {"y": 1.0}})
    _same_row(s.constraints[0].slip, [1, 0, sp.Symbol("R")])
    mu, mus = s.friction_values()
    assert mu.tolist() == [0.2] and mus.tolist() == [0.25]
    with pytest.raises(ValueError, match=r"system\.contacts\[0\]\.friction: is NaN"):
        load_system_yaml({"bodies": [{"name": "d", "mass": 1}], "joints": [{"type": "free", "body": "d",
                          "coordinates": ["x", "y", "phi"]}],
                          "contacts": [{"body": "d", "friction": float("nan")}], "q0": {"y": 1.0}})


# --- the friction examples of docs/examples are the scenes of vcirun.scenes.friction ------------------------

def _examples():
    from pathlib import Path

    from vcirun.scenes import friction as F

    ex = Path(__file__).resolve().parents[2] / "docs" / "examples"
    return [(ex / "spinning_ball.yaml", F.spinning_ball(50.0)), (ex / "incline.yaml", F.incline(0.4, mu=0.3, mu_s=0.35,
                                                                                              v0=2.0)),
            (ex / "coulomb_oscillator.yaml", F.coulomb_oscillator(1.0)), (ex / "painleve_rod.yaml",
                                                                        F.painleve_rod(0.9, xdot0=-1.0, mu=1.5)),
            (ex / "chain5_friction.yaml", None)]


@pytest.mark.parametrize("k", range(5))
def test_friction_examples_declare_the_scenes(k):
    path, built = _examples()[k]
    assert len(path.read_text().splitlines()) < 30
    s = load_system_yaml(path)
    assert s.has_friction and np.min(s.phi_values(s.default_q0)) >= -1e-15
    if built is None:   # the chain: friction at every link end
        assert all(c.friction == sp.Symbol("mu") for c in s.constraints) and s.m == 6
        return
    assert [str(x) for x in s.q] == [str(x) for x in built.q]
    assert all(built.params[k] == v for k, v in s.params.items())   # (the builders also name mu_s)
    assert sp.simplify(s.M - built.M) == sp.zeros(s.n, s.n) and sp.simplify(s.V - built.V) == 0
    for a, b in zip(s.constraints, built.constraints):
        assert sp.simplify(a.phi - b.phi) == 0 and float(a.restitution) == float(b.restitution)
        _same_row(a.slip, [sp.sympify(e) for e in b.slip])
    for x, y in zip(s.friction_values(), built.friction_values()):
        assert np.array_equal(x, y)
    assert np.allclose(s.default_q0, built.default_q0, rtol=0, atol=1e-15)
    assert np.allclose(s.default_p0, built.default_p0, rtol=0, atol=1e-15)
