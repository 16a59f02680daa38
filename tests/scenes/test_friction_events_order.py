"""Friction's events against impacts, and the impact law's modes after an impulse
(vcirun/collision/algorithm1.py; docs/derivations/friction.md, "Events inside a step" and "Frictional
impacts in the integrators"), each against an exact account of the case:

- a held contact's mode event and another contact's collision in one grid step: the collision first;
- a body that lands flat and sticks: at rest after the impact, its corners stuck (no slip in the
  rounding of its landing velocity, no Painleve status, no mode-change records);
- an impact whose tangential impulse presses the contact in (no rebound at e > 0): every method takes
  the law's p+, as at e = 0;
- elastic impacts with friction accumulating: they lose energy and are held, like e < 1."""
from __future__ import annotations

import re

import numpy as np
import pytest

import vcirun

BOX = """\
name: landing_box
parameters: {m: 1.288, a: 0.6723, b: 0.8316, g: 9.81, e: 0.0, mu: 3.0}
gravity: g
bodies:
  - name: block
    mass: m
    inertia: "m*(a**2 + b**2)/12"
    outline: [["-b/2", "-a/2"], ["b/2", "-a/2"], ["b/2", "a/2"], ["-b/2", "a/2"]]
joints:
  - {type: free, body: block, coordinates: [x, y, theta]}
contacts:
  - {name: left, body: block, point: ["-b/2", "-a/2"], restitution: e, friction: mu}
  - {name: right, body: block, point: ["b/2", "-a/2"], restitution: e, friction: mu}
"""

ROD = """\
name: landing_rod
parameters: {m: 1.0, l: 0.5, g: 9.81, e: 0.5, mu: 0.4}
gravity: g
bodies:
  - {name: rod, mass: m, inertia: "m*l**2/3"}
joints:
  - {type: free, body: rod, coordinates: [x, y, theta]}
contacts:
  - {name: end, body: rod, point: ["-l", 0], restitution: e, friction: mu}
"""


def _phis(name, method, h, tr):
    from vcirun.run.plan import plan

    p = plan(name, method, h=h, T=tr.t[-1] - tr.t[0], t0=0.0, constrained=None, energies=True, resting_contact=True,
             options={}, start=dict(beta=None, q0=None, p0=None, params=None), kc=None, tier=None)
    mod, prm = p.module(), p.params(None)
    out = np.empty((len(tr.q), int(mod.NCON)))
    for k, q in enumerate(tr.q):
        mod.sys_phis(q, prm, out[k])
    return out


@pytest.mark.parametrize("method", ["CVA4", "CVA6"])
def test_a_mode_event_after_a_collision_in_the_same_step_waits_for_it(method):
    """The three-link chain with friction at h = 4e-3: in the step from t = 0.460 a held end's slip
    reverses at 0.4628 while the middle joint's contact reaches the floor at 0.4608. Taking the mode's
    end first would carry the chain 8.5e-4 into the floor, and the next held step would pull it out with
    an impulse whose friction work is +1658 J. The collision is taken first: no grid state
    inside a constraint, the friction work of every step <= 0, and H never above H(0)."""
    h = 4e-3
    tr = vcirun.simulate("link_chain_friction_3", method, h=h, T=1.0)
    assert tr.status == "ok", tr.message
    assert _phis("link_chain_friction_3", method, h, tr).min() > -1e-12
    assert tr.friction_work.max() <= 1e-12
    assert np.nanmax(tr.H) <= tr.H[0] + 1e-9


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    path = tmp_path_factory.mktemp("box") / "landing_box.yaml"
    path.write_text(BOX)
    return str(path)


@pytest.mark.parametrize("method", ["CVA", "VCI"])
def test_a_box_that_lands_flat_and_sticks_stays_at_rest(box, method):
    """Dropped flat from 1 cm at (vx, vy) = (0.5, -1) with e = 0 and mu = 3: the plastic impact stops
    both corners (|Pt| = m vx = 0.644 inside the cone), and the box is at rest after t = 0.00955. Its
    corners' slip velocities after the impulse are the rounding of the landing velocity (1e-17), which
    read against the box at rest would set them slipping (with mu > 1.92 into Painleve's case, below it
    with a slip -> stick record at the impact). The tolerance is the rounding of the momentum before the
    impulse: stuck at once, no mode change, at rest where the reference is."""
    m, a = 1.288, 0.6723
    q0, p0 = [0.0, a / 2 + 0.01, 0.0], [0.5 * m, -1.0 * m, 0.0]
    for mu in (1.5, 3.0):
        tr = vcirun.simulate(box, method, h=1e-3, T=0.05, q0=q0, p0=p0, params={"mu": mu})
        assert tr.status == "ok", tr.message
        assert len(tr.mode_changes) == 0, (tr.mode_changes, tr.mode_change_kind)
        assert tr.contact_mode[-1].tolist() == [2, 2]
        x_rest = 0.5 * 0.00955242456233   # vx times the impact time of the exact reference
        assert abs(tr.q[-1, 0] - x_rest) < 1e-10 and abs(tr.q[-1, 2]) < 1e-12


@pytest.fixture(scope="module")
def rod(tmp_path_factory):
    path = tmp_path_factory.mktemp("rod") / "landing_rod.yaml"
    path.write_text(ROD)
    return str(path)


def _rod_start(m, l, th0, y0, vx, vy, w):
    return [0.0, y0, th0], [m * vx, m * vy, m * l * l / 3 * w]


def test_an_impact_whose_friction_presses_the_contact_in_takes_the_law_in_every_method(rod):
    """A rod end landing with e = 0.519 and mu = 1.992: the law's tangential impulse stops the slip and
    presses the end in, so it leaves with no normal velocity (no rebound). R^VCI's energy balance has
    the double root of e = 0 there: its multiplier would miss the law's impulse by 0.027 at h = 1e-2
    (the slip after it 3.8e-2 instead of 0, reversed by friction). Every method takes the law's p+: the
    impulses of VCI and MCVAC are CVA's, which is the law's."""
    m, l, e, mu = 1.880, 0.394, 0.519, 1.992
    q0, p0 = _rod_start(m, l, 0.7417, 0.266400, -1.273, -2.949, 4.051)
    prm = dict(m=m, l=l, e=e, mu=mu)
    law = vcirun.simulate(rod, "CVA", h=1e-2, T=0.05, q0=q0, p0=p0, params=prm)
    assert law.status == "ok"
    for method in ("VCI", "MCVAC"):
        tr = vcirun.simulate(rod, method, h=1e-2, T=0.05, q0=q0, p0=p0, params=prm)
        assert tr.status == "ok", tr.message
        assert abs(tr.impact_impulse[0] - law.impact_impulse[0]) <= 1e-12 * abs(law.impact_impulse[0])
        assert abs(tr.impact_impulse_t[0] - law.impact_impulse_t[0]) <= 1e-12 * abs(law.impact_impulse_t[0])


def test_elastic_impacts_with_friction_accumulate_and_are_held(rod):
    """e = 1 and mu = 4.33: friction takes energy at every rebound (0.074 m/s out for 0.133 in), so the
    impacts accumulate to a rest. Dense elastic impacts of a frictionless conservative motion stop the
    run (`accumulation`); with friction they lose energy and are held, and VCI at h = 1e-4 ends where
    CVA does."""
    m, l = 1.8164152273389282, 0.3221273816094278
    q0, p0 = _rod_start(m, l, 0.8525222609484108, 0.2444707098330269, -1.8821322969529006, -1.7174192767951013,
                        -1.7654827100564896)
    prm = dict(m=m, l=l, e=1.0, mu=4.3342878318668605)
    ref = vcirun.simulate(rod, "CVA", h=1e-4, T=0.3, q0=q0, p0=p0, params=prm)
    tr = vcirun.simulate(rod, "VCI", h=1e-4, T=0.3, q0=q0, p0=p0, params=prm)
    assert ref.status == "ok" and tr.status == "ok", tr.message
    assert tr.contact_active[-1].all()
    assert np.max(np.abs(tr.q[-1] - ref.q[-1])) < 1e-6


def test_the_reference_holds_elastic_impacts_that_friction_makes_accumulate(rod):
    """e = 1 with mu = 0.84: the frictional law slows each rebound of the rod end, and the impacts
    accumulate at t = 0.0441. The exact reference holds the contact there (elastic impacts without
    friction do not accumulate and stay an error), and the integrators' runs, which hold it where
    the impacts become denser than the grid, end within 2e-7 of it."""
    m, l = 0.8890699973260017, 0.8100087812888994
    q0, p0 = _rod_start(m, l, 0.3562085356170906, 0.28306403348922576, -0.6604595034446588, -0.8338567734868132,
                        -0.9927319568047039)
    prm = dict(m=m, l=l, e=1.0, mu=0.8398026955069208)
    ref = vcirun.reference(rod, T=0.2, q0=q0, p0=p0, params=prm)
    assert ref.status == "ok" and ref.held_intervals and ref.held_intervals[-1][1] == pytest.approx(0.2)
    # the first landing from the free flight's closed form: y0 + vy t - g t^2 / 2 = l sin(th0 + w t)
    from scipy.optimize import brentq

    y0, vy, th0, w = q0[1], -0.8338567734868132, q0[2], -0.9927319568047039
    gap = lambda t: y0 + vy * t - 9.81 * t * t / 2 - l * np.sin(th0 + w * t)   # noqa: E731
    assert abs(ref.impacts[0] - brentq(gap, 0.0, 0.05, xtol=1e-15)) < 1e-10
    assert abs(ref.held_intervals[0][0] - 0.04414) < 1e-4
    tr = vcirun.simulate(rod, "CVA", h=1e-3, T=0.2, q0=q0, p0=p0, params=prm)
    assert tr.status == "ok" and np.max(np.abs(tr.q[-1] - ref(tr.t[-1]))) < 1e-6


def test_the_reference_ends_a_flat_slide_in_painleves_case_with_the_status(box):
    """The box flat on both corners, sliding at 1 m/s with mu = 2.5 > b / a: no set of its corners has
    consistent forces, and the leading corner alone has B < 0 (Painleve's case). The reference ends at
    t = 0 with status painleve, as the integrators do, instead of raising that no forces exist."""
    m, a = 1.288, 0.6723
    q0, p0 = [0.0, a / 2, 0.0], [m * 1.0, 0.0, 0.0]
    ref = vcirun.reference(box, T=0.3, q0=q0, p0=p0, params={"mu": 2.5})
    assert ref.status == "painleve" and "contact right" in ref.message
    # the leading corner's B from the equations: 1/m + b^2 / (4 I) - mu a b / (4 I), I = m (a^2 + b^2) / 12
    b, inertia = 0.8316, m * (a * a + 0.8316 ** 2) / 12
    B = 1 / m + b * b / (4 * inertia) - 2.5 * a * b / (4 * inertia)
    assert B < 0 and abs(float(re.search(r"B = (-?[0-9.e+-]+)", ref.message).group(1)) - B) < 1e-5
    tr = vcirun.simulate(box, "CVA", h=1e-3, T=0.3, q0=q0, p0=p0, params={"mu": 2.5})
    assert tr.status == "painleve"
