"""Several unilateral constraints, restitution and simultaneous impacts.

Oracles: the ball in a box (decoupled: closed form, vcirun.scenes.oracles.ball_in_box_exact), Newton's
cradle (Moreau's law in closed form, vcirun.scenes.oracles.newton_cradle_velocities), and for the double
pendulum between two walls the exact reference, itself checked against the oracles here.
Derivations: docs/derivations/contacts.md.
"""
from __future__ import annotations

import numpy as np
import pytest

import vcirun
from convergence.helpers import fit_order
from vcirun.codegen.kernel_cache import default
from vcirun.mechanics.loader import load_system_yaml
from vcirun.scenes.oracles import ball_in_box_exact, newton_cradle_velocities

BOX = dict(width=1.0, height=1.0, g=9.81)
BOX_Q0, BOX_V0, BOX_T = (0.3, 0.6), (0.7, 0.0), 3.0   # the scene's default state


def _box_exact(t, e, q0=BOX_Q0, v0=BOX_V0, **box):
    return ball_in_box_exact(t, *q0, *v0, **(BOX | box), e=e)


@pytest.mark.parametrize("e", [1.0, 0.9])
def test_ball_in_box_reference_equals_the_closed_form(e):
    ref = vcirun.reference("ball_in_box", T=BOX_T, params={"e": e})
    t = np.linspace(0, BOX_T, 3001)
    ex = _box_exact(t, e)
    assert list(ref.impact_contact) == list(ex.impact_contact)
    assert np.max(np.abs(ref.impacts - ex.impact_times)) <= 1e-9
    assert np.max(np.abs(ref(t) - np.column_stack([ex.x, ex.y]))) <= 1e-8
    assert np.max(np.abs(ref.impact_impulse - ex.impact_impulse)) <= 1e-8


@pytest.mark.parametrize("e", [1.0, 0.9])
@pytest.mark.parametrize("method", ["CVA", "VCI", "MCVAC"])
def test_ball_in_box_impacts_and_errors(method, e):
    """Impact sequence and contacts as the closed form's, impact times to 1e-6 at h = 2.5e-3. SVC (and
    the SVC modified flow) integrates constant gravity exactly, so CVA and MCVAC are exact to
    round-off here (measured L2 ~2e-14); VCI's reset balances discrete energies of partial steps
    (O(h^2) per impact): order 2."""
    hs = (1e-2, 5e-3, 2.5e-3)
    errs = []
    for h in hs:
        tr = vcirun.simulate("ball_in_box", method, h=h, T=BOX_T, params={"e": e})
        assert tr.ok, tr.message
        ex = _box_exact(tr.t, e)
        assert list(tr.impact_contact) == list(ex.impact_contact), (h, tr.impact_contact, ex.impact_contact)
        d = tr.q - np.column_stack([ex.x, ex.y])
        errs.append(float(np.sqrt(h * np.sum(d * d))))
    # VCI: its O(h^2) energy error per impact (E_d of a partial step is H + O(tau^2)) changes the
    # horizontal speed, so later side-wall impacts shift by O(h^2) (measured 2.2e-4 = 35 h^2 at the
    # fifth impact, h = 2.5e-3)
    assert np.max(np.abs(tr.impacts - ex.impact_times)) <= (1e-6 if method != "VCI" else 50 * hs[-1] ** 2)
    if method == "VCI":
        slope, _ = fit_order(hs, errs, min_local_slope=-np.inf)
        assert slope >= 1.8, errs
    else:
        assert max(errs) <= 1e-10, errs


def test_ball_in_box_corner_hit_gives_two_entries():
    """From (0.5, 0.5) with velocity (0.5, g/2 - 0.5) in a box 1 wide and 2 high, the ball reaches the
    floor and the right wall at t = 1 together: two impact entries at the same time, contacts floor (0)
    and right (3), each with its own impulse (W is diagonal: Newton's law per wall)."""
    g = BOX["g"]
    q0, v0 = (0.5, 0.5), (0.5, g / 2 - 0.5)
    for method in ("CVA", "VCI", "MCVAC"):
        tr = vcirun.simulate("ball_in_box", method, h=1e-2, T=1.2, q0=q0, p0=v0, params={"e": 0.9, "height": 2.0})
        assert tr.ok, tr.message
        ex = _box_exact(tr.t, 0.9, q0, v0, height=2.0)
        assert list(ex.impact_contact) == [0, 3] and ex.impact_times[0] == ex.impact_times[1]
        assert list(tr.impact_contact) == [0, 3], (method, tr.impact_contact)
        assert tr.impacts[0] == tr.impacts[1] and abs(tr.impacts[0] - 1.0) <= 1e-9
        if method == "CVA":
            assert np.allclose(tr.impact_impulse, ex.impact_impulse, rtol=1e-9)
    ref = vcirun.reference("ball_in_box", T=1.2, q0=q0, p0=v0, params={"e": 0.9, "height": 2.0})
    assert list(ref.impact_contact) == [0, 3] and ref.impacts[0] == ref.impacts[1]


# --- Newton's cradle --------------------------------------------------------------------------------

@pytest.mark.parametrize("e", [1.0, 0.5])
@pytest.mark.parametrize("method", ["CVA", pytest.param("VCI", marks=pytest.mark.slow),
                                    pytest.param("MCVAC", marks=pytest.mark.slow)])  # (a cold build each)
def test_newton_cradle(method, e):
    """3 equal balls, the last two touching, the first approaching at speed 1: Moreau's law gives
    (-1/3, 2/3, 2/3) for e = 1 (not the sequential textbook answer (0, 0, 1): docs/derivations/contacts.md) and
    (0, 1/2, 1/2) for e = 1/2. Momentum conserved; energy conserved for e = 1 and losing
    (1 - e^2) ... as the LCP says otherwise; the recorded impulses complementary."""
    tr = vcirun.simulate("newton_cradle_3", method, h=1e-2, T=0.5, params={"e": e})
    assert tr.ok, tr.message
    v = tr.p[-1]  # m = 1
    assert np.allclose(v, newton_cradle_velocities(3, e, 1.0), atol=1e-8), v
    assert abs(np.sum(v) - 1.0) <= 1e-12
    if e == 1.0:
        assert abs(0.5 * v @ v - 0.5) <= 1e-12
    assert list(tr.impact_contact) == [0, 1] and tr.impacts[0] == tr.impacts[1]
    lam = tr.impact_impulse
    um = np.array([-1.0, 0.0])                 # normal velocities before: u_12 = v2 - v1, u_23 = v3 - v2
    up = np.array([v[1] - v[0], v[2] - v[1]])
    w = up + e * um                            # LCP slack, >= 0, complementary to lam
    assert np.all(lam >= 0) and np.all(w >= -1e-12) and np.max(np.abs(lam * w)) <= 1e-12


def test_cradle_reference_and_five_balls():
    ref = vcirun.reference("newton_cradle_3", T=0.5)
    assert np.allclose(ref.p(0.5), newton_cradle_velocities(3, 1.0, 1.0), atol=1e-10)
    tr = vcirun.simulate("newton_cradle_5", "CVA", h=1e-2, T=0.5)
    assert tr.ok and np.allclose(tr.p[-1], newton_cradle_velocities(5, 1.0, 1.0), atol=1e-8)


# --- double pendulum between two walls ----------------------------------------------------------------

@pytest.mark.parametrize("e", [1.0, 0.9])
@pytest.mark.parametrize("method", ["CVA", pytest.param("VCI", marks=pytest.mark.slow), "MCVAC"])
def test_double_pendulum_walls_orders(method, e):
    """Against the exact reference (same impact law): the reference's contact sequence at every h and
    L2 order 2."""
    T = 3.0
    ref = vcirun.reference("double_pendulum_walls", T=T, params={"e": e})
    assert len(ref.impacts) >= 3 and set(ref.impact_contact) == {0, 1}
    hs = (1e-2, 5e-3, 2.5e-3, 1.25e-3) if method != "VCI" else tuple(1e-2 / 2 ** k for k in range(6))
    errs = []
    for h in hs:
        tr = vcirun.simulate("double_pendulum_walls", method, h=h, T=T, params={"e": e})
        assert tr.ok, tr.message
        assert list(tr.impact_contact) == list(ref.impact_contact), (h, tr.impact_contact, ref.impact_contact)
        errs.append(vcirun.l2_error(tr, ref))
    assert np.max(np.abs(tr.impacts - ref.impacts)) <= 1e-4
    slope, _ = fit_order(hs, errs, min_local_slope=-np.inf if method == "VCI" else 0.5)
    assert slope >= 1.8, (slope, errs)


def test_double_pendulum_walls_impact_times_high_order():
    """Impact times to 1e-6 at h = 2.5e-3 on the double pendulum between walls (e = 0.9):
    a second-order method's impact time carries its O(h^2) trajectory error (CVA 1.2e-5 there), the
    fourth-order composition CVA4 reaches it with margin, and its impact-time error falls at its own
    order through the impacts (partial steps of the composition, Newton's law at each contact)."""
    T = 3.0
    ref = vcirun.reference("double_pendulum_walls", T=T, params={"e": 0.9})
    errs = []
    hs = (1e-2, 5e-3, 2.5e-3)
    for h in hs:
        tr = vcirun.simulate("double_pendulum_walls", "CVA4", h=h, T=T, params={"e": 0.9})
        assert tr.ok and list(tr.impact_contact) == list(ref.impact_contact)
        errs.append(float(np.max(np.abs(tr.impacts - ref.impacts))))
    assert errs[-1] <= 1e-6, errs
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(orders >= 3.5), (errs, orders)


def test_double_pendulum_walls_energy_loss_is_newtons():
    """e = 0.9: CVA's reset is Newton's law itself, so H drops at each impact by exactly the
    continuous loss (1 - e^2) u^2 / (2 W) (u, W at the recorded impact state); VCI and MCVAC lose it
    from their own energies, so their H drops by it to O(h^2)."""
    from vcirun.scenes.registry import get_scene

    s = get_scene("double_pendulum_walls")
    prm = s.param_values({"e": 0.9})
    for method, tol in (("CVA", 1e-10), ("VCI", 3e-2), ("MCVAC", 3e-2)):
        tr = vcirun.simulate("double_pendulum_walls", method, h=2.5e-3, T=3.0, params={"e": 0.9})
        assert tr.ok
        for q, pm, pp, c in zip(tr.impact_q, tr.impact_p_minus, tr.impact_p_plus, tr.impact_contact):
            Minv = np.linalg.inv(s.mass_matrix(q, prm))
            g = s.constraint_jacobian_value(q, prm)[c]
            u, W = g @ Minv @ pm, g @ Minv @ g
            loss = (1 - 0.9 ** 2) * u * u / (2 * W)
            dH = 0.5 * pm @ Minv @ pm - 0.5 * pp @ Minv @ pp
            assert abs(dH - loss) <= tol * loss, (method, dH, loss)


# --- declarations --------------------------------------------------------------------------------------

def test_yaml_constraints_with_a_restitution_parameter():
    """`constraints:` items as expressions or {name, phi, restitution}; a restitution naming a
    parameter changes with params= without a new module."""
    decl = {"name": "box_yaml", "coordinates": ["x", "y"], "parameters": {"g": 9.81, "e": 1.0},
            "mass_matrix": [["1", "0"], ["0", "1"]], "potential": "g*y",
            "constraints": [{"name": "floor", "phi": "y", "restitution": "e"}, "1 - y",
                            {"phi": "x", "restitution": 0.5}, {"name": "right", "phi": "1 - x"}],
            "q0": [0.3, 0.6], "qdot0": [0.7, 0.0]}
    s = load_system_yaml(decl)
    assert [c.name for c in s.constraints] == ["floor", "c1", "c2", "right"]
    assert list(s.restitution_values()) == [1.0, 1.0, 0.5, 1.0]
    a = vcirun.simulate(s, "CVA", h=1e-2, T=1.5)
    n_modules = len(default().loaded)
    b = vcirun.simulate(s, "CVA", h=1e-2, T=1.5, params={"e": 0.8})
    assert len(default().loaded) == n_modules  # no new module for a new restitution
    assert a.ok and b.ok and not np.allclose(a.q, b.q)
    k = list(b.impact_contact).index(0)        # the first floor impact: u+ = -0.8 u-
    assert b.impact_p_plus[k][1] == pytest.approx(-0.8 * b.impact_p_minus[k][1], rel=1e-12)
    for bad, match in (({"phi": "y", "restitution": 1.5}, "restitution"), ({"phi": "y", "restitution": "ee"},
                                                                            "not a parameter"),
                       ({"phi": "y", "stiffness": 1}, "unknown key")):
        with pytest.raises(ValueError, match=match):
            load_system_yaml(dict(decl, constraints=[bad]))


def test_single_constraint_declarations_are_unchanged():
    """`constraint:` (one elastic constraint) gives the fingerprint of the single-constraint form, so
    the kernel caches of single-constraint scenes stay valid."""
    decl = {"name": "osc", "coordinates": ["x"], "parameters": {"k": 1.0}, "mass_matrix": [["1"]],
            "potential": "0.5*k*x**2", "constraint": "x + 0.5"}
    s = load_system_yaml(decl)
    assert s.m == 1 and s.constraints[0].name == "phi" and s.phi == s.constraints[0].phi


def test_results_file_records_constraint_names_and_restitutions(tmp_path):
    """A sweep's root attributes carry the constraints in declaration order (what impact_contact
    indexes), with their restitution expressions."""
    from vcirun.io.reader import read_results
    from vcirun.experiments.config import load_config
    from vcirun.experiments.sweep import run_sweep

    cfg_path = tmp_path / "box.yaml"
    cfg_path.write_text(f"""name: box
system: {{name: ball_in_box, params: {{e: 0.9}}}}
methods: [CVA]
h: [1.0e-2]
initial_states: [{{q0: [0.3, 0.6], p0: [0.7, 0.0]}}]
T: 1.5
reference: {{kind: none}}
output: {tmp_path / 'box.h5'}
workers: 1
""")
    run_sweep(load_config(cfg_path), progress=False)
    res = read_results(tmp_path / "box.h5")
    cons = res.attrs["constraints"]
    assert [c["name"] for c in cons] == ["floor", "ceiling", "left", "right"]
    assert {c["restitution"] for c in cons} == {"e"}
    assert [r.status for r in res.runs] == ["ok"]
    from vcirun.experiments.figures import contacts_energy

    fig = contacts_energy(res)   # H(t) per method, impacts marked by contact
    labels = fig.axes[0].get_legend_handles_labels()[1]
    assert {"impact: floor", "impact: right"} <= set(labels) and len(fig.axes) == 1


def test_solve_ivp_baselines_refuse_several_constraints():
    from vcirun.experiments.baselines import solve_ivp_run

    with pytest.raises(ValueError, match="one elastic constraint; ball_in_box declares 4"):
        solve_ivp_run("ball_in_box", h=1e-2, T=1.0, rtol=1e-8)
