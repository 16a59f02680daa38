"""Resting contact and release: held contacts in the integrators and in the exact reference.

Exact cases, none built from vcirun's integrators:
- the Zeno ball (e = 0.8): impacts accumulate at t_inf = t1 + 2 e v1 / (g (1 - e)) (vcirun.scenes.oracles.zeno_ball),
  then the ball lies on the floor;
- the ball in the box (e = 0.8), settling on the floor while it still hits the side walls
  (vcirun.scenes.oracles.ball_in_box_exact): the floor is held through the wall impacts;
- the bead on top of a circle, released where the normal force m g cos(theta) - m v^2 / R vanishes
  (vcirun.scenes.oracles.bead_release);
- a particle in a circular bowl, held for ever: a simple pendulum, solved here by solve_ivp;
- the cart-pendulum held on the floor, lifting off where the floor force
  N = (m1 + m2) g + m2 L (cos(theta) theta'^2 + sin(theta) theta'') vanishes (a pendulum with a fixed
  pivot until then, solved here), then bouncing (e = 0.3) and settling again.
Derivations: docs/derivations/contacts.md, sections 6 (reference) and 7 (integrators).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import vcirun
from convergence.helpers import fit_order
from vcirun.mechanics.loader import load_system_yaml
from vcirun.scenes.oracles import ball_in_box_exact, bead_release, zeno_ball

G = 9.81
ZENO = {"name": "zeno_ball", "coordinates": ["y"], "parameters": {"g": G, "m": 1.0, "e": 0.8},
        "mass_matrix": [["m"]], "potential": "m*g*y",
        "constraints": [{"name": "floor", "phi": "y", "restitution": "e"}]}
BEAD = {"name": "bead_on_circle", "coordinates": ["x", "y"], "parameters": {"g": G, "R": 1.0, "m": 1.0},
        "mass_matrix": [["m", "0"], ["0", "m"]], "potential": "m*g*y",
        "constraints": [{"name": "surface", "phi": "sqrt(x**2 + y**2) - R", "restitution": 0.0}]}
BOWL = {"name": "bowl", "coordinates": ["x", "y"], "parameters": {"g": G, "R": 1.0, "m": 1.0},
        "mass_matrix": [["m", "0"], ["0", "m"]], "potential": "m*g*y",
        "constraints": [{"name": "bowl", "phi": "R - sqrt(x**2 + y**2)", "restitution": 0.5}]}
CART = {"name": "cart_pendulum_e", "coordinates": ["y", "theta"],
        "parameters": {"m1": 1.0, "m2": 0.2, "L": 2.0, "g": 10.0, "e": 0.3},
        "mass_matrix": [["m1 + m2", "m2*L*sin(theta)"], ["m2*L*sin(theta)", "m2*L**2"]],
        "potential": "(m1 + m2)*g*y - m2*g*L*cos(theta)",
        "constraints": [{"name": "floor", "phi": "y", "restitution": "e"}]}
CART_P0 = (0.0, 0.2 * 4.0 * 8.0)  # theta' = 8 at theta = 0: p_theta = m2 L^2 theta'


@pytest.fixture(scope="module")
def systems():
    return {k: load_system_yaml(v) for k, v in (("zeno", ZENO), ("bead", BEAD), ("bowl", BOWL), ("cart", CART))}


# --- the exact reference ----------------------------------------------------------------------------

def test_reference_zeno_ball_against_the_closed_form(systems):
    z = zeno_ball(1.0, 0.0, G, 0.8)
    ref = vcirun.reference(systems["zeno"], T=6.0, q0=[1.0], p0=[0.0])
    n = len(ref.impacts)
    assert 40 <= n <= 80  # bounces resolved down to a flight of ~1e-6 s, then the Zeno time extrapolated
    assert np.max(np.abs(ref.impacts - z.impact_times(n))) <= 1e-11
    t0, t1, held = ref.held_intervals[-1]
    assert held == (0,) and t1 == 6.0 and abs(t0 - z.t_inf) <= 1e-11
    tt = np.linspace(0.0, 6.0, 3001)
    assert np.max(np.abs(ref(tt)[:, 0] - z.state(tt)[0])) <= 1e-12
    after = tt[tt > z.t_inf + 1e-9]
    assert np.max(np.abs(ref.state(after))) <= 1e-15  # on the floor at rest
    assert ref.accuracy <= 1e-11 and len(ref.releases) == 0


def test_reference_bead_release_against_the_closed_form(systems):
    b = bead_release(1.0, G, 0.5)
    ref = vcirun.reference(systems["bead"], T=1.2, q0=[0.0, 1.0], p0=[0.5, 0.0])
    assert ref.held_intervals[0][:1] == (0.0,) and list(ref.release_contact) == [0]
    assert abs(ref.releases[0] - b.t_r) <= 1e-10
    tt = np.linspace(0.0, 1.2, 1201)
    assert np.max(np.abs(ref(tt) - b.state(tt)[0])) <= 1e-10  # held arc, then the free parabola
    assert len(ref.impacts) == 0


def _cart_liftoff(prm, thetadot0):
    """The cart held on y = 0 is a pendulum with a fixed pivot; its floor force N(theta, theta') and
    the first time N = 0 (solve_ivp, written from the equations here)."""
    m1, m2, L, g = prm["m1"], prm["m2"], prm["L"], prm["g"]

    def acc(th):
        return -(g / L) * np.sin(th)

    def N(t, z):
        return (m1 + m2) * g + m2 * L * (np.cos(z[0]) * z[1] ** 2 + np.sin(z[0]) * acc(z[0]))

    N.terminal, N.direction = True, -1.0
    sol = solve_ivp(lambda t, z: [z[1], acc(z[0])], (0.0, 5.0), [0.0, thetadot0], method="DOP853",
                    rtol=1e-13, atol=1e-14, events=N, dense_output=True)
    return float(sol.t_events[0][0]), sol


def test_reference_cart_lifts_off_where_the_floor_force_vanishes(systems):
    t_off, pend = _cart_liftoff(CART["parameters"], 8.0)
    ref = vcirun.reference(systems["cart"], T=3.0, q0=[0.0, 0.0], p0=list(CART_P0))
    assert abs(ref.releases[0] - t_off) <= 1e-10
    tt = np.linspace(0.0, t_off, 200)
    # held on the floor: the index-reduced solve drifts by at most its restart bound, 1e3 atol
    assert np.max(np.abs(ref(tt)[:, 0])) <= 1e-9
    assert np.max(np.abs(ref(tt)[:, 1] - pend.sol(tt)[0])) <= 1e-10   # the pendulum's angle
    # then free flight, bounces with e = 0.3 that accumulate, and the cart held again to T
    assert len(ref.impacts) >= 3 and ref.held_intervals[-1][1] == 3.0
    assert ref.accuracy <= 1e-9


def test_reference_without_resting_contact_raises_where_a_contact_would_be_held(systems):
    with pytest.raises(RuntimeError, match="resting_contact"):
        vcirun.reference(systems["bead"], T=1.0, q0=[0.0, 1.0], p0=[0.5, 0.0], resting_contact=False)


# --- the integrators ----------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["CVA", pytest.param("VCI", marks=pytest.mark.slow),
                                    pytest.param("MCVAC", marks=pytest.mark.slow)])
@pytest.mark.parametrize("h", [1e-2, 1e-3])
def test_zeno_ball_settles_and_stays(systems, method, h):
    """Impacts accumulate; the floor is held once a bounce leaves less than |phi''| h of normal
    velocity (docs/derivations/contacts.md 7.2), i.e. at most the 2 h / (1 - e) of flights left before t_inf
    early, and the ball then lies on the floor exactly."""
    z = zeno_ball(1.0, 0.0, G, 0.8)
    tr = vcirun.simulate(systems["zeno"], method, h=h, T=6.0, q0=[1.0], p0=[0.0])
    assert tr.status == "ok", tr.message
    act = tr.contact_active[:, 0]
    k = int(np.argmax(act))
    assert act[k:].all() and not act[:k].any()
    assert z.t_inf - 2.5 * h / (1 - 0.8) <= tr.t[k] <= z.t_inf + h
    assert np.max(np.abs(tr.q[k:])) == 0.0 and np.max(np.abs(tr.p[k:])) == 0.0
    assert np.all(tr.contact_force[k + 1:, 0] > 0.0)
    # the ball held early sits where the exact one still makes bounces of height <= (g h)^2 / 2g
    assert np.max(np.abs(tr.q[k:, 0] - z.state(tr.t[k:])[0])) <= G * h ** 2
    if method != "VCI":  # (VCI's discrete ball settles into an h-scale bounce instead: test_extremes_contact)
        slow = vcirun.simulate(systems["zeno"], method, h=h, T=6.0, q0=[1.0], p0=[0.0], resting_contact=False)
        assert slow.status == "accumulation"


@pytest.mark.parametrize("method", ["CVA", "VCI", "MCVAC"])
@pytest.mark.parametrize("h", [1e-2, 2.5e-3])
def test_ball_in_box_floor_held_through_wall_impacts(method, h):
    """e = 0.8: the floor impacts accumulate while the ball still crosses the box; the floor stays held
    through the side-wall impacts (the impact law of the other contacts during a hold). SVC integrates
    the free and the held flight exactly, so CVA and MCVAC keep x to round-off against the closed form;
    VCI's partial-step energies move its wall-impact times by O(h^2)."""
    tr = vcirun.simulate("ball_in_box", method, h=h, T=8.0, params={"e": 0.8})
    assert tr.status == "ok", tr.message
    ex = ball_in_box_exact(tr.t, 0.3, 0.6, 0.7, 0.0, width=1.0, height=1.0, g=9.81, e=0.8)
    act = tr.contact_active
    assert not act[:, 1:].any()                       # only the floor is ever held
    k = int(np.argmax(act[:, 0]))
    assert act[k:, 0].all()
    assert ex.t_rest - 2.5 * h / (1 - 0.8) <= tr.t[k] <= ex.t_rest + h
    walls = tr.impacts[np.isin(tr.impact_contact, (2, 3)) & (tr.impacts > tr.t[k])]
    assert len(walls) >= 2                            # wall impacts while the floor is held
    assert np.max(np.abs(tr.q[k:, 1])) <= 1e-30 and np.max(np.abs(tr.p[k:, 1])) <= 1e-30
    # VCI: its wall-impact times are off by O(h^2) (measured x errors 4.2e-3 = 42 h^2 at h = 1e-2,
    # 5.3e-4 = 84 h^2 at 2.5e-3; the constant depends on where in the step the impacts fall)
    x_tol = 1e-13 if method != "VCI" else 100 * h ** 2
    assert np.max(np.abs(tr.q[:, 0] - ex.x)) <= x_tol


@pytest.mark.parametrize("method", ["CVA", pytest.param("VCI", marks=pytest.mark.slow),
                                    pytest.param("MCVAC", marks=pytest.mark.slow)])
def test_bead_release_time_converges(systems, method):
    """Held from the top (a start at rest on the surface, pressed in), released where the contact
    force, linearly interpolated inside the step, turns tensile: O(h^2) in the release time (the
    held state's O(h^2) error plus the interpolation's h^2 |N''| / 8 |N'|). Measured errors
    -4.2e-6, 4.1e-7, -9.4e-8, -6.7e-8, 1.7e-8 at h = 4e-3 ... 2.5e-4: within 0.3 h^2."""
    b = bead_release(1.0, G, 0.5)
    for h in (4e-3, 2e-3, 1e-3, 5e-4, 2.5e-4):
        tr = vcirun.simulate(systems["bead"], method, h=h, T=1.2, q0=[0.0, 1.0], p0=[0.5, 0.0])
        assert tr.status == "ok", tr.message
        assert len(tr.releases) == 1 and list(tr.release_contact) == [0] and len(tr.impacts) == 0
        assert abs(tr.releases[0] - b.t_r) <= 0.5 * h ** 2, (h, tr.releases[0] - b.t_r)
        act = tr.contact_active[:, 0]
        before, after = tr.t <= tr.releases[0], tr.t > tr.releases[0] + h
        assert act[before].all() and not act[after].any()
        r = np.hypot(tr.q[:, 0], tr.q[:, 1])
        assert np.max(np.abs(r[before] - 1.0)) <= 1e-15      # on the circle while held
        assert np.all(tr.contact_force[before, 0] >= 0.0) and np.all(tr.contact_force[after, 0] == 0.0)


@pytest.mark.parametrize("method", ["CVA", pytest.param("VCI", marks=pytest.mark.slow),
                                    pytest.param("MCVAC", marks=pytest.mark.slow)])
def test_held_phase_is_second_order_and_conserves_energy(systems, method):
    """A particle held in a bowl for ever is a simple pendulum. The held step is the method's
    discrete Lagrangian restricted to phi = 0 (a constrained variational integrator, symplectic on
    T*C): energy error O(h^2) without drift, the constraint to round-off, L2 order 2. Measured
    (T = 40): max |H - H0| 5.0e-4, 1.26e-4, 3.1e-5 at h = 2e-2, 1e-2, 5e-3, the same in the first and
    the last quarter of the run; L2 order 2.00."""
    T, hs = 40.0, (2e-2, 1e-2, 5e-3)
    pend = solve_ivp(lambda t, z: [z[1], -G * np.sin(z[0])], (0, T), [0.0, 1.0], method="DOP853",
                     rtol=1e-13, atol=1e-14, dense_output=True)
    errs, dHs = [], []
    for h in hs:
        tr = vcirun.simulate(systems["bowl"], method, h=h, T=T, q0=[0.0, -1.0], p0=[1.0, 0.0])
        assert tr.status == "ok" and tr.contact_active.all() and len(tr.releases) == 0, tr.message
        th = pend.sol(tr.t)[0]
        d = tr.q - np.column_stack([np.sin(th), -np.cos(th)])
        errs.append(float(np.sqrt(h * np.sum(d * d))))
        assert np.max(np.abs(np.hypot(tr.q[:, 0], tr.q[:, 1]) - 1.0)) <= 1e-15
        dH = np.abs(tr.H - tr.H[0])
        K = len(dH) // 4
        assert dH[-K:].max() <= 1.05 * dH[:K].max()   # no drift
        dHs.append(float(dH.max()))
    slope, _ = fit_order(hs, errs)
    assert 1.9 <= slope <= 2.1, errs
    assert 1.9 <= np.log(dHs[0] / dHs[-1]) / np.log(hs[0] / hs[-1]) <= 2.1, dHs


def test_cart_lift_off_bounces_and_resettles_second_order(systems):
    """Held from the start, lift-off, three to five bounces with e = 0.3 that accumulate, held again
    to T: the whole trajectory converges at order 2 against the exact reference (measured L2 5.3e-4,
    1.4e-4, 3.4e-5, 8.5e-6 at h = 4e-3 ... 5e-4), the lift-off time to O(h^2)."""
    ref = vcirun.reference(systems["cart"], T=3.0, q0=[0.0, 0.0], p0=list(CART_P0))
    hs = (4e-3, 2e-3, 1e-3, 5e-4)
    errs = []
    for h in hs:
        tr = vcirun.simulate(systems["cart"], "CVA", h=h, T=3.0, q0=[0.0, 0.0], p0=list(CART_P0))
        assert tr.status == "ok", tr.message
        assert tr.contact_active[0, 0] and tr.contact_active[-1, 0]
        assert abs(tr.releases[0] - ref.releases[0]) <= h ** 2  # measured 0.5 h^2, 0.85 h^2, 0.03 h^2, 0.25 h^2
        d = tr.q - ref(tr.t)
        errs.append(float(np.sqrt(h * np.sum(d * d))))
    slope, _ = fit_order(hs, errs)
    assert slope >= 1.9, errs
