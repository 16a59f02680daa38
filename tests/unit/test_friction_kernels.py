"""The friction kernels of a generated module (vcirun.codegen.roles: sys_slips, sys_dslips,
sys_friction, FRICTION; emitted by vcirun.codegen.derive.friction_kernels), compiled, on random
states of several systems with friction:

  * sys_slips against the declaration's slip rows (sympy.lambdify: no code generation), zero rows
    where a contact has no friction;
  * sys_dslips = v^T (dW_t,i/dq) v against a 4th-order central difference of sys_slips along v, times
    v (the velocity term of d(v_t)/dt), and through `vcirun.verification.fd.check_kernels` (the table
    `vcirun verify` runs);
  * sys_friction against the declared coefficients, with parameter overrides (no recompilation);
  * frictionless systems (every built-in scene): FRICTION false, zero slip rows and coefficients.
"""
from __future__ import annotations

import numpy as np
import pytest

from vcirun.codegen.build import load_module
from vcirun.codegen.evaluate import python_module_for
from vcirun.codegen.kernel_set import SYSTEM_KERNELS
from vcirun.mechanics.bodies import Body, CircleContact, Joint, PointContact, planar_system
from vcirun.mechanics.loader import load_system_yaml
from vcirun.scenes.registry import BUILTIN_SCENES, get_scene
from vcirun.verification import fd


def _discs():
    """Two free discs (B's centre off its frame origin) with friction between them and with the floor."""
    return planar_system(
        "fric_discs", [Body("A", "mA", "mA*rA**2/2", radius="rA"), Body("B", "mB", "mB*rB**2/2", ("c", 0), radius="rB")],
        [Joint("free", "A", coordinates=("xa", "ya", "tha")), Joint("free", "B", coordinates=("xb", "yb", "thb"))],
        [CircleContact("AB", ("A", "B"), friction="mu", static_friction="mus"),
         PointContact("floorA", "A", radius="rA", friction=0.3),
         PointContact("floorB", "B", ("c", 0), radius="rB")],          # frictionless: a zero row
        params={"mA": 1.0, "mB": 2.0, "rA": 0.3, "rB": 0.5, "c": 0.2, "mu": 0.2, "mus": 0.35, "g": 9.81},
        gravity="g", q0=[0.0, 2.0, 0.0, 0.0, 0.6, 0.0])


def _chain():
    """Three links, the first on a free joint, friction at every link end (angle-dependent rows)."""
    bodies = [Body(f"link{i}", "m", "m*l**2/12", ("l/2", 0)) for i in range(1, 4)]
    joints = [Joint("free", "link1", coordinates=("x", "y", "theta1"))]
    joints += [Joint("revolute", f"link{i}", f"link{i - 1}", ("l", 0), f"theta{i}", absolute=True) for i in (2, 3)]
    contacts = [PointContact("end0", "link1", friction="mu")]
    contacts += [PointContact(f"end{i}", f"link{i}", ("l", 0), friction="mu", static_friction=0.5)
                 for i in range(1, 4)]
    return planar_system("fric_chain3", bodies, joints, contacts, params={"m": 0.2, "l": 0.3, "g": 9.81, "mu": 0.4},
                         gravity="g", q0=[0.0, 0.5, 0.35, -0.25, 0.35])


def _hand():
    """A hand-written particle in a parabolic bowl with a tangent_gap (its row is grad psi)."""
    return load_system_yaml({
        "name": "fric_bowl", "coordinates": ["x", "y"], "parameters": {"m": 1.0, "g": 9.81, "k": 0.7, "mu": 0.25},
        "mass_matrix": [["m", 0], [0, "m"]], "potential": "m*g*y",
        "constraints": [{"name": "bowl", "phi": "y - k*x**2", "friction": "mu",
                         "tangent_gap": "x + k*x*y + sin(x)*y**2"}]})


SYSTEMS = {"discs": _discs, "chain": _chain, "bowl": _hand}


@pytest.fixture(scope="module", params=sorted(SYSTEMS))
def frictional(request):
    s = SYSTEMS[request.param]()
    return s, load_module(s, SYSTEM_KERNELS)


def _slips(mod, q, prm, m, n):
    W = np.empty((m, n))
    mod.sys_slips(np.ascontiguousarray(q, float), prm, W)
    return W


def test_flag_and_coefficients(frictional):
    s, mod = frictional
    assert mod.FRICTION is True and s.has_friction
    for over in (None, {"mu": 0.0}, {"mu": 0.7}):
        prm = s.param_values(over)
        mu, mus = np.empty(s.m), np.empty(s.m)
        mod.sys_friction(prm, mu, mus)
        want = s.friction_values(prm)
        assert np.array_equal(mu, want[0]) and np.array_equal(mus, want[1])


def test_slip_rows_are_the_declaration(frictional, rng):
    s, mod = frictional
    prm = s.param_values()
    zero = [i for i, c in enumerate(s.constraints) if c.friction == 0 and c.static_friction is None]
    for _ in range(10):
        q = rng.uniform(-1.5, 1.5, s.n)
        W = _slips(mod, q, prm, s.m, s.n)
        ref = s.slip_matrix_value(q, prm)
        assert np.max(np.abs(W - ref)) <= 1e-13 * (1.0 + np.max(np.abs(ref)))
        assert not np.any(W[zero])


def test_dslips_is_the_velocity_term_of_the_slip_rate(frictional, rng):
    s, mod = frictional
    prm = s.param_values()
    worst = 0.0
    for _ in range(10):
        q, v = rng.uniform(-1.5, 1.5, s.n), rng.uniform(-2.0, 2.0, s.n)
        out = np.empty(s.m)
        mod.sys_dslips(q, v, prm, out)
        e = 1e-3

        def f(a):
            return _slips(mod, q + a * v, prm, s.m, s.n) @ v

        ref = (-f(2 * e) + 8 * f(e) - 8 * f(-e) + f(-2 * e)) / (12 * e)
        worst = max(worst, float(np.max(np.abs(out - ref)) / (1.0 + np.max(np.abs(ref)))))
        assert np.max(np.abs(ref)) > 0 or s.name == "fric_discs"
    assert worst < 1e-8, worst


def test_verify_table_checks_dslips(frictional, rng):
    s, mod = frictional
    prm = s.param_values()
    probes = [fd.Probe(rng.uniform(-1.0, 1.0, s.n), rng.uniform(-1.0, 1.0, s.n), 0.0, 0.01) for _ in range(3)]
    rows = {r["kernel"]: r for r in fd.check_kernels(mod, prm, probes)}
    assert rows["sys_dslips"]["worst"] < fd.FD_THRESHOLDS[0], rows["sys_dslips"]


@pytest.mark.parametrize("name", sorted(BUILTIN_SCENES))
def test_builtin_friction_kernels_are_their_declarations(name):
    """The built-in friction scenes (rocking_block_friction, spinning_ball, ...) have FRICTION and their
    declared coefficients; every other built-in has FRICTION off and zero friction kernels."""
    s = get_scene("n_pendulum_3" if name == "n_pendulum" else name)
    mod = python_module_for(s, SYSTEM_KERNELS)   # the generated text, uncompiled
    prm = s.param_values()
    assert mod.FRICTION is s.has_friction
    if s.has_friction:
        mu, mus = np.empty(s.m), np.empty(s.m)
        mod.sys_friction(prm, mu, mus)
        assert np.array_equal(mu, s.friction_values()[0]) and np.array_equal(mus, s.friction_values()[1])
        assert np.any(mu > 0)
        return
    W = _slips(mod, np.full(s.n, 0.3), prm, s.m, s.n)
    mu, mus, dd = np.ones(s.m), np.ones(s.m), np.ones(s.m)
    mod.sys_friction(prm, mu, mus)
    mod.sys_dslips(np.full(s.n, 0.3), np.ones(s.n), prm, dd)
    assert not W.any() and not mu.any() and not mus.any() and not dd.any()


def test_friction_at_checks_overrides(frictional):
    from vcirun.core.system_data import friction_at

    s, mod = frictional
    names = [c.name for c in s.constraints]
    mu, mus = friction_at(mod, s.param_values(), s.name, names)
    assert np.array_equal(mu, s.friction_values()[0]) and np.array_equal(mus, s.friction_values()[1])
    with pytest.raises(ValueError, match=rf"contact '{names[0]}' has friction mu = -0.1, mu_s = "):
        friction_at(mod, s.param_values({"mu": -0.1}), s.name, names)
    if "mus" in s.params:
        with pytest.raises(ValueError, match=r"contact 'AB' has static friction mu_s = 0.1 < mu = 0.2"):
            friction_at(mod, s.param_values({"mus": 0.1}), s.name, names)
