"""Built-in scenes and YAML-declared systems.

A YAML system equivalent to the built-in cart-pendulum generates the same compiled dynamics
(trajectories agree to round-off); a mass matrix that is not positive definite at q0, or not
symmetric, is rejected with a ValueError that says so.
"""
from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
import yaml

import vcirun
from vcirun.scenes.registry import BUILTIN_SCENES, get_scene
from vcirun.mechanics import load_system_yaml

CART_YAML = """
name: cart_pendulum_yaml
description: the paper's Section 5.1 cart-pendulum, declared by hand
coordinates: [y, theta]
parameters: {m1: 1.0, m2: 0.2, L: 2.0, g: 10.0}
mass_matrix:
  - ["m1 + m2", "m2*L*sin(theta)"]
  - ["m2*L*sin(theta)", "m2*L**2"]
potential: "(m1 + m2)*g*y - m2*g*L*cos(theta)"
constraint: "y"
"""


def test_cart_pendulum_scene_is_the_papers():
    s = get_scene("cart_pendulum")
    assert s.params == {"m1": 1.0, "m2": 0.2, "L": 2.0, "g": 10.0}
    assert s.phi == s.q[0]
    for beta in (0.5, 2.0):  # Xi(beta) = FL([beta, 0], [0, 3.5 - 0.18 beta])
        q0, p0 = s.initial_state(beta=beta)
        qd = np.array([0.0, 3.5 - 0.18 * beta])
        assert np.array_equal(q0, [beta, 0.0])
        assert np.allclose(p0, s.mass_matrix(q0) @ qd, rtol=1e-15, atol=0)
        assert np.allclose(p0, [0.2 * 2.0 * np.sin(0.0) * qd[1], 0.2 * 4.0 * qd[1]], rtol=1e-15)


@pytest.mark.parametrize("name", ["n_pendulum_3" if name == "n_pendulum" else name for name in BUILTIN_SCENES])
def test_builtin_scene_lagrangian_and_legendre(name, rng):
    """L = 1/2 qd^T M qd - V, FL = M qd, and M symmetric positive definite at random states."""
    s = get_scene(name)
    L = sp.lambdify([*s.q, *s.qd, *s.param_symbols], s.lagrangian(), "math")
    V = sp.lambdify([*s.q, *s.param_symbols], s.V, "math")
    prm = s.param_values()
    for _ in range(3):
        q, qd = rng.uniform(-1, 1, s.n), rng.uniform(-1, 1, s.n)
        M = s.mass_matrix(q)
        assert np.allclose(M, M.T, rtol=0, atol=1e-15) and np.all(np.linalg.eigvalsh(M) > 0)
        assert abs(L(*q, *qd, *prm) - (0.5 * qd @ M @ qd - V(*q, *prm))) < 1e-13
        assert np.allclose(s.legendre(q, qd)[1], M @ qd, rtol=1e-15, atol=1e-15)


def test_yaml_system_runs_and_matches_the_builtin(tmp_path):
    path = tmp_path / "cart.yaml"
    path.write_text(CART_YAML)
    user = load_system_yaml(path)
    builtin = get_scene("cart_pendulum")
    assert user.n == 2 and list(user.params) == list(builtin.params)
    q0, p0 = builtin.initial_state(beta=1.0)
    ref = vcirun.simulate("cart_pendulum", "SVC", h=0.02, T=2.0, q0=q0, p0=p0)
    run = vcirun.simulate(str(path), "SVC", h=0.02, T=2.0, q0=q0, p0=p0)  # by path, as a user would
    assert ref.ok and run.ok and run.system == "cart_pendulum_yaml"
    assert run.q.shape == ref.q.shape == (101, 2)
    assert np.max(np.abs(run.q - ref.q)) < 1e-12
    assert np.max(np.abs(run.p - ref.p)) < 1e-12
    assert np.max(np.abs(run.H - ref.H)) < 1e-12
    assert np.ptp(run.q[:, 1]) > 0.5  # the pendulum actually swings


NOT_PD_YAML = """
coordinates: [x, z]
parameters: {m: 1.0}
mass_matrix: [["m", "0"], ["0", "m*x"]]
potential: "0.5*(x**2 + z**2)"
constraint: "z + 1"
"""


def test_non_positive_definite_mass_matrix_at_q0_is_a_clear_error(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(NOT_PD_YAML + "q0: [-1.0, 0.0]\nqdot0: [0.0, 0.0]\n")
    with pytest.raises(ValueError, match="not positive definite at q0"):
        load_system_yaml(path)
    # declared without q0: loads, and simulate rejects the bad initial state before compiling
    path.write_text(NOT_PD_YAML)
    system = load_system_yaml(path)
    with pytest.raises(ValueError, match=r"mass_matrix is not positive definite at q0=.*hyperregular"):
        vcirun.simulate(system, "SVC", h=0.1, T=1.0, q0=[0.0, 0.0], p0=[0.0, 1.0])
    with pytest.raises(ValueError, match="hyperregular"):
        vcirun.simulate(str(path), "SVC", h=0.1, T=1.0, q0=[-2.0, 0.0], p0=[0.0, 1.0])


def test_positive_definiteness_error_prints_q0_as_plain_numbers():
    system = load_system_yaml(yaml.safe_load(NOT_PD_YAML))
    with pytest.raises(ValueError) as err:
        system.initial_state(q0=[0.0, 0.0], p0=[0.0, 1.0])
    assert "q0=[0.0, 0.0]" in str(err.value), str(err.value)


def test_asymmetric_mass_matrix_is_a_clear_error():
    data = {"coordinates": ["x", "z"], "parameters": {"m": 1.0}, "mass_matrix": [["m", "x"], ["0", "m"]],
            "potential": "x**2", "constraint": "z"}
    with pytest.raises(ValueError, match="mass_matrix must be symmetric"):
        load_system_yaml(data)


def test_warm_path_checks_the_mass_matrix_at_q0_compiled(monkeypatch):
    """A built-in scene served from the warm index never builds the symbolic system, so the
    hyperregularity check at q0 is the module's compiled mass_matrix_ok (a Cholesky attempt); numpy's
    check_mass_matrix then words the error. Cart-pendulum M = [[m1 + m2, m2 L sin], [., m2 L^2]]."""
    from vcirun.run import plan, resolve

    vcirun.simulate("cart_pendulum", "CVA", h=0.1, T=0.2, beta=3.2)  # compiles and indexes the module

    def no_symbolic(*a, **k):
        raise AssertionError("the warm path must not build the symbolic system")

    monkeypatch.setattr(plan, "resolve_system", no_symbolic)
    monkeypatch.setattr(resolve, "resolve_system", no_symbolic)
    ok = vcirun.simulate("cart_pendulum", "CVA", h=0.1, T=0.2, beta=3.2)
    assert ok.status == "ok"
    for m1 in (-1.5, -0.2):  # M[0, 0] = m1 + m2 < 0 (indefinite) and = 0 (singular; m2 = 0.2)
        with pytest.raises(ValueError, match="mass_matrix is not positive definite at q0"):
            vcirun.simulate("cart_pendulum", "CVA", h=0.1, T=0.2, beta=3.2, params={"m1": m1})
    with pytest.raises(ValueError, match="mass_matrix is not finite at q0"):  # m2 L^2 overflows
        vcirun.simulate("cart_pendulum", "CVA", h=0.1, T=0.2, q0=[1.0, 0.5], p0=[0.0, 0.0], params={"L": 1e200})
    with pytest.raises(ValueError, match=r"q0: must be a list of finite numbers"):  # refused before any work
        vcirun.simulate("cart_pendulum", "CVA", h=0.1, T=0.2, q0=[1.0, np.nan], p0=[0.0, 0.0])
    # just positive definite: m1 + m2 = 1e-9 > 0 with the pendulum hanging (sin theta = 0) is accepted
    tr = vcirun.simulate("cart_pendulum", "CVA", h=1e-3, T=2e-3, q0=[1.0, 0.0], p0=[0.0, 0.0],
                         params={"m1": -0.2 + 1e-9})
    assert tr.q.shape == (3, 2)


def test_the_gap_of_many_contacts_is_an_unevaluated_min():
    """The gap min_i phi_i of many contacts is kept as written: sympy's evaluation compares its
    arguments pairwise (48 s at 100 contacts, hours at 1000), and the kernels read it only below
    derive.GAP_LOOP_MIN contacts (above, sys_phi is a loop over sys_phis)."""
    from vcirun.codegen.derive import GAP_LOOP_MIN
    from vcirun.mechanics.system import MIN_EVALUATED_BELOW, Constraint, MechanicalSystem

    assert MIN_EVALUATED_BELOW == GAP_LOOP_MIN
    x, y = sp.symbols("x y")
    for k in (2, MIN_EVALUATED_BELOW - 1, MIN_EVALUATED_BELOW, 400):
        ang = 2 * np.pi * (np.arange(k) + 0.5) / k
        phis = [1 - float(np.cos(a)) * x - float(np.sin(a)) * y for a in ang]
        s = MechanicalSystem(name=f"gon{k}", q=[x, y], params={}, M=sp.eye(2), V=sp.Integer(0),
                             constraints=[Constraint(f"w{i}", f) for i, f in enumerate(phis)])
        assert isinstance(s.phi, sp.Min) and set(s.phi.args) == set(phis)
        assert len(s.phi.args) == k
        q = np.array([0.3, -0.2])
        at = {x: sp.Float(q[0]), y: sp.Float(q[1])}   # (xreplace: subs would re-evaluate the symbolic Min)
        assert float(s.phi.xreplace(at)) == min(float(f.xreplace(at)) for f in phis)
