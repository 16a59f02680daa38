"""Mechanisms declared by bodies, joints and contact geometry (vcirun/mechanics/bodies.py,
bodies_yaml.py; docs/bodies.md).

  * the cart-pendulum, the double pendulum (with one wall and between two walls) and the line of
    balls declared by bodies give the built-ins' M, V and phi (symbolic identity), and the same
    trajectories to 1e-12 (compiled, CVA);
  * the examples of docs/examples (rocking block, 5-link chain, 20-ball cradle) take < 30 lines;
    every collision integrator runs on them (-m slow);
  * the first hit of the 20-ball cradle: the impulses of the compiled impact law at the exact impact
    state and the reference's against an independent NNLS solve of the LCP written from the geometry;
  * bad declarations: errors that name the field (a contact starting inside, a body without joint,
    a loop of parents, a joint type, a circle without radius, a repeat).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import sympy as sp
from scipy.optimize import nnls

import vcirun
from vcirun.mechanics.bodies import (
    Body,
    CircleContact,
    Damper,
    Joint,
    PointContact,
    Spring,
    planar_system,
)
from vcirun.mechanics.loader import load_system_yaml
from vcirun.methods.table import METHODS
from vcirun.scenes.registry import get_scene

EX = Path(__file__).resolve().parents[2] / "docs" / "examples"


def _same(a, b):
    assert [str(s) for s in a.q] == [str(s) for s in b.q]
    assert sp.simplify(a.M - b.M) == sp.zeros(a.n, a.n)
    assert sp.simplify(a.V - b.V) == 0
    assert a.m == b.m
    for ca, cb in zip(a.constraints, b.constraints):
        assert sp.simplify(ca.phi - cb.phi) == 0 and sp.simplify(ca.restitution - cb.restitution) == 0


def test_cart_pendulum_and_double_pendulum_by_bodies_are_the_builtins():
    _same(load_system_yaml(EX / "cart_pendulum_bodies.yaml"), get_scene("cart_pendulum"))
    _same(load_system_yaml(EX / "double_pendulum_bodies.yaml"), get_scene("double_pendulum"))


def _double_pendulum_walls():
    d = get_scene("double_pendulum_walls")
    tip = ("link2", (0, "-l2"))
    return planar_system(
        "dpw_bodies", [Body("link1", "m1", com=(0, "-l1")), Body("link2", "m2", com=(0, "-l2"))],
        [Joint("revolute", "link1", coordinate="theta1"),
         Joint("revolute", "link2", "link1", (0, "-l1"), "theta2", absolute=True)],
        [PointContact("right", *tip, line_point=("w", 0), normal=(-1, 0), restitution="e"),
         PointContact("left", *tip, line_point=("-w", 0), normal=(1, 0), restitution="e")],
        params=d.params, gravity="g", q0=d.default_q0)


def _line_of_balls(n):
    d = get_scene(f"newton_cradle_{n}")
    return planar_system(
        "balls_bodies", [Body(f"b{i}", "m", radius="d/2") for i in range(1, n + 1)],
        [Joint("prismatic", f"b{i}", coordinate=f"x{i}") for i in range(1, n + 1)],
        [CircleContact(f"c{i}{i + 1}", (f"b{i + 1}", f"b{i}"), restitution="e") for i in range(1, n)],
        params=d.params, q0=d.default_q0)


def test_walls_and_line_of_balls_by_bodies_are_the_builtins():
    _same(_double_pendulum_walls(), get_scene("double_pendulum_walls"))
    _same(_line_of_balls(4), get_scene("newton_cradle_4"))


@pytest.mark.parametrize("scene,source", [("cart_pendulum", "cart_pendulum_bodies.yaml"),
                                          ("double_pendulum", "double_pendulum_bodies.yaml")])
def test_trajectories_by_bodies_reproduce_the_builtins(scene, source):
    q0, p0 = get_scene(scene).initial_state(beta=3.2 if scene == "cart_pendulum" else None)
    kw = {"q0": q0, "p0": p0}
    a = vcirun.simulate(scene, "CVA", h=0.01, T=3.0, **kw)
    b = vcirun.simulate(str(EX / source), "CVA", h=0.01, T=3.0, **kw)
    assert a.status == b.status == "ok" and len(a.impacts) == len(b.impacts) > 0
    assert np.max(np.abs(a.q - b.q)) <= 1e-12 and np.max(np.abs(a.p - b.p)) <= 1e-12
    assert np.max(np.abs(np.asarray(a.impacts) - np.asarray(b.impacts))) <= 1e-12


EXAMPLES = {"rocking_block.yaml": (3, 2), "chain5.yaml": (7, 6), "cradle20.yaml": (20, 19), "cradle20_gaps.yaml": (20, 19)}


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_examples_are_short_and_declare_the_mechanism(name):
    path = EX / name
    assert len(path.read_text().splitlines()) < 30
    s = load_system_yaml(path)
    assert (s.n, s.m) == EXAMPLES[name]
    assert np.min(s.phi_values(s.default_q0)) >= 0.0
    np.linalg.cholesky(s.mass_matrix(s.default_q0))


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(EXAMPLES))
@pytest.mark.parametrize("method", list(METHODS))
def test_every_method_runs_on_the_examples(name, method):
    # (the chain until it lies flat on the floor, at rest on its six ends)
    tr = vcirun.simulate(str(EX / name), method, h=2e-3, T=1.2 if name == "chain5.yaml" else 0.6)
    assert tr.status == "ok", tr.message
    assert len(tr.impacts) > 0


@pytest.mark.parametrize("n,method", [(3, "CVA"), (3, "VCI"), (3, "MCVAC"), (5, "VCI"), (10, "CVA"), (10, "VCI"),
                                      (10, "MCVAC")])
def test_link_chains_settle_flat_on_the_floor(n, method):
    # A chain dropped in a zigzag lands end after end (e = 0.3); its links rock, each impact lifting
    # another end by less and less, until all N + 1 ends rest on the floor (docs/derivations/
    # contacts.md 7.4). The end state is known exactly: every phi_i = 0 (flat on y = 0, so H = 0),
    # and the frictionless floor never changes the horizontal momentum p_x = 0.
    tr = vcirun.simulate(f"link_chain_{n}", method, h=1e-3, T=1.5)
    assert tr.status == "ok", tr.message
    assert tr.contact_active[-1].all() and len(tr.impacts) > 2 * n
    assert np.max(np.abs(get_scene(f"link_chain_{n}").phi_values(tr.q[-1]))) <= 1e-12
    assert abs(tr.H[-1]) <= 1e-12 * tr.H[0]
    assert np.max(np.abs(tr.p[:, 0])) <= 1e-12


def _cradle_first_hit(n, m=0.1, L=1.0, g=9.81, th=0.3):
    """The state just before ball 1 (released at rest from -th) hits the others at theta = 0, and the
    impulses of Moreau's law (e = 1) there by NNLS, from the geometry: phi_i = |C_i - C_(i+1)| - 2r has
    gradient L (-1 at theta_i, +1 at theta_(i+1)) at theta = 0, M = m L^2 I, u- = (-L omega, 0, ...)."""
    omega = np.sqrt(2.0 * g * (1.0 - np.cos(th)) / L)
    q, p = np.zeros(n), np.zeros(n)
    p[0] = m * L * L * omega
    G = np.zeros((n - 1, n))
    for i in range(n - 1):
        G[i, i], G[i, i + 1] = -L, L
    W = G @ G.T / (m * L * L)
    um = G @ p / (m * L * L)
    C = np.linalg.cholesky(W)
    lam, _ = nnls(C.T, -np.linalg.solve(C, 2.0 * um), maxiter=100 * n)
    return q, p, lam


def test_cradle20_first_hit_against_an_independent_lcp_solve():
    from vcirun.codegen.build import load_module
    from vcirun.codegen.kernel_set import SYSTEM_KERNELS

    s = load_system_yaml(EX / "cradle20.yaml")
    q, p, ref = _cradle_first_hit(20)
    mod = load_module(s, SYSTEM_KERNELS)
    prm = s.param_values()
    d, lam, active = np.empty(20), np.empty(19), np.empty(19, np.int64)
    k, s0, dE = mod.impact_direction(q, p, 1.0, 1e-13, prm, d, lam, active)
    assert k == 19 and s0 == 1.0 and dE == 0.0
    assert np.max(np.abs(lam - ref)) <= 1e-12 * np.max(ref)
    # the reference: its first impact at the time of the closed form, every contact's impulse
    r = vcirun.reference(str(EX / "cradle20.yaml"), T=0.6, check_accuracy=False)  # (first hit at ~0.5 s)
    first = r.impacts == r.impacts[0]  # (with round-off impulses of contacts that touch after it)
    got = np.zeros(19)
    np.add.at(got, r.impact_contact[first], r.impact_impulse[first])
    assert abs(r.impacts[0] - _cradle_hit_time()) <= 1e-9
    assert np.max(np.abs(got - ref)) <= 1e-10 * np.max(ref)
    # right after it: ball 1 back at -0.9 its speed, the others at 0.1 of it ((1.4), e = 1)
    p_hit = 0.1 * np.sqrt(2.0 * 9.81 * (1.0 - np.cos(0.3)))
    assert abs(r.p(r.impacts[0])[0] + 0.9 * p_hit) <= 1e-9 and np.all(np.abs(r.p(r.impacts[0])[1:] - 0.1 * p_hit) <= 1e-9)


def _cradle_hit_time(th=0.3, g=9.81, L=1.0):
    """The time a pendulum released at rest from -th takes to reach theta = 0: a quarter period,
    sqrt(L/g) K(sin^2(th/2)) (complete elliptic integral of the first kind)."""
    from scipy.special import ellipk

    return float(np.sqrt(L / g) * ellipk(np.sin(th / 2) ** 2))


def test_springs_dampers_and_gravity_vector():
    s = planar_system("spring_box", [Body("box", "m")], [Joint("free", "box", coordinates=("x", "y", "a"))],
                      [PointContact("floor", "box", radius="r")],
                      springs=[Spring("ground", "box", "k", "l0", point_a=(0, 1))], dampers=[Damper("ground", "box", "c")],
                      params={"m": 1.0, "k": 2.0, "l0": 0.5, "c": 0.3, "r": 0.1}, gravity=(0, "-m"))
    x, y = sp.symbols("x y")
    k, l0, c, m = sp.symbols("k l0 c m")
    assert sp.simplify(s.V - (m * m * y + k * (sp.sqrt(x**2 + (y - 1) ** 2) - l0) ** 2 / 2)) == 0
    xd, yd = sp.symbols("x_dot y_dot")
    rho = sp.sqrt(x**2 + y**2)
    f = -c * (x * xd + y * yd) / rho * sp.Matrix([x / rho, y / rho, 0])
    assert sp.simplify(s.forcing - f) == sp.zeros(3, 1)
    assert s.constraints[0].phi == y - sp.Symbol("r")


def _yaml(**kw):
    base = {"name": "t", "parameters": {"m": 1.0}, "gravity": 9.81,
            "bodies": [{"name": "a", "mass": "m"}],
            "joints": [{"type": "free", "body": "a", "coordinates": ["x", "y", "th"]}],
            "contacts": [{"name": "floor", "body": "a", "point": [0, -0.5]}], "q0": {"y": 1.0}}
    base.update(kw)
    return base


@pytest.mark.parametrize("change,words", [
    ({"q0": {"y": 0.2}}, ["system.contacts[0]", "'floor'", "phi = -0.3", "wrong side", "flip the normal"]),
    ({"joints": [{"type": "hinge", "body": "a"}]}, ["system.joints[0].type", "hinge", "revolute"]),
    ({"bodies": [{"name": "a", "mass": "m"}, {"name": "b", "mass": "m"}]}, ["body 'b' has no joint"]),
    ({"joints": [{"type": "revolute", "body": "a", "parent": "a", "coordinate": "t"}]}, ["loop"]),
    ({"contacts": [{"name": "c", "circles": ["a", "a"]}]}, ["system.contacts[0].circles", "two different"]),
    ({"bodies": [{"name": "a", "mass": "m"}, {"name": "b", "mass": "m"}],
      "joints": [{"type": "free", "body": "a", "coordinates": ["x", "y", "th"]},
                 {"type": "revolute", "body": "b", "coordinate": "u"}],
      "contacts": [{"name": "c", "circles": ["a", "b"]}]}, ["system.contacts[0].radii", "no radius"]),
    ({"contacts": [{"name": "c{i}", "repeat": [3, 1], "body": "a"}]}, ["system.contacts[0].repeat", "first <= last"]),
    ({"bodies": [{"name": "a", "mass": "mm"}]}, ["system.bodies[0].mass"]),
    ({"contacts": [{"name": "f", "body": "a", "point": [0, -0.5], "restitution": 2}]},
     ["system.contacts[0].restitution", "[0, 1]"]),
])
def test_bad_declarations_name_the_field(change, words):
    with pytest.raises(ValueError) as err:
        load_system_yaml(_yaml(**change))
    for w in words:
        assert w in str(err.value), str(err.value)


def test_repeat_expands_indices():
    s = load_system_yaml(EX / "chain5.yaml")
    assert [str(c) for c in s.q] == ["x", "y"] + [f"theta{i}" for i in range(1, 6)]
    assert [c.name for c in s.constraints] == [f"end{i}" for i in range(6)]


def test_builtin_mechanisms():
    for name, (n, m) in {"rocking_block": (3, 2), "link_chain_4": (6, 5), "cradle_6": (6, 5)}.items():
        s = get_scene(name)
        assert (s.n, s.m) == (n, m) and np.min(s.phi_values(s.default_q0)) >= 0.0
    # the hanging cradle's mass matrix is diagonal and constant: m L^2 I
    assert get_scene("cradle_6").M == sp.Symbol("L") ** 2 * sp.Symbol("m") * sp.eye(6)
