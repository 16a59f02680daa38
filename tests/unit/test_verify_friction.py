"""`vcirun verify` on systems with Coulomb friction.

Correct friction scenes pass: the derivative table checks sys_slips and sys_friction against the
declaration and sys_dslips against FD of sys_slips; the stick/slip transitions are located events
compared with the exact reference's (count, contact, kind, and their times at the method's order);
the energy account takes the friction work and the frictional impact law's loss as the model's, and
its rest (the integration error) falls at the method's order; a motion that comes to rest is said
to; a hold that starts at a plastic impact is no accumulation (no window).

Deliberately wrong systems fail, each through `verify(loader=)` with the generated module run as
Python (vcirun.codegen.evaluate.run_as_python) and one thing changed: the friction force of the held
step with the wrong sign, a slip row that is not the declared one, a frictional impact whose
tangential impulse is (1 + h) times the law's.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import vcirun
from vcirun.verification import checks as ck
from vcirun.verification.window import settle_window

ROOT = Path(__file__).resolve().parents[2]
OSCILLATOR = str(ROOT / "docs" / "examples" / "coulomb_oscillator.yaml")
BALL = str(ROOT / "docs" / "examples" / "spinning_ball.yaml")
LADDER = [0.04, 0.02, 0.01, 0.005]
FORCE_ROW = "f = mu[j] * held[j] if slipping(held[j]) else 0.0"        # vcirun/maps/friction.py, _force_rows
IMPULSE = "            d[j] += la[r] * R[r, j]\n"                        # collision/impact_friction.py


def _not_passing(res):
    return [c.line() for c in res.checks if c.verdict not in (ck.PASS, ck.SKIP)]


def _derivative_rows(res, method):
    return {r["kernel"]: r for r in res.check("derivatives", method).rows}


# --- correct scenes --------------------------------------------------------------------------------

def test_coulomb_oscillator_verifies_through_its_mode_changes():
    """The Coulomb-damped oscillator (five half swings, then it sticks at t = 5 pi / sqrt(10)): every
    judged check passes with CVA and MCVAA; the five reversals and the final stick are the
    reference's, their times converge at order 2; the friction work (about 5 J) is the model's, the
    rest of the account falls at order 2; H~ less the friction work varies at order 2."""
    res = vcirun.verify(OSCILLATOR, methods="CVA,MCVAA", T=6.0, h=LADDER)
    assert res.ok and not _not_passing(res), _not_passing(res)
    rows = _derivative_rows(res, "CVA")
    assert {"sys_slips", "sys_friction", "sys_dslips"} <= set(rows)
    assert all(r["verdict"] == ck.PASS for r in rows.values())
    assert any(f"comes to rest at t = {5 * np.pi / np.sqrt(10):.6g} (floor stuck)" in n for n in res.notes), res.notes
    for m in ("CVA", "MCVAA"):
        mc = res.check("mode-change times", m)
        assert mc.verdict == ck.PASS and abs(mc.value - 2.0) < 0.15, mc.line()
        assert "the reference has 5 mode changes" in mc.note
        acc = res.check("energy account", m)
        assert acc.verdict == ck.PASS and abs(acc.value - 2.0) < 0.15, acc.line()
        assert all(abs(float(r["friction work"]) + 5.0) < 0.01 for r in acc.rows)
        assert res.check("L2 order through impacts", m).verdict == ck.PASS
    mh = res.check("modified Hamiltonian", "MCVAA")
    assert mh.verdict == ck.PASS and mh.value > 1.85 and "friction work" in mh.note


def test_spinning_ball_verifies_without_a_window():
    """Capobianco's ball (w0 = 50): a plastic frictional impact at t1 = 0.428353 that it slides
    through, then slip -> stick 0.299767 s later. The hold starts at the impact: no accumulation, no
    window; impact and mode-change times agree with the reference to round-off (the motion is
    piecewise quadratic: every method integrates it exactly, which the order checks say as warnings);
    the account's rest is round-off next to the law's 11.8 J and the friction's 0.605 J."""
    res = vcirun.verify(BALL, methods="CVA", T=1.0, h=LADDER)
    assert res.ok, [c.line() for c in res.failures]
    assert not any("window" in n for n in res.notes), res.notes
    assert "1 friction mode changes" in res.check("reference").note
    mc = res.check("mode-change times", "CVA")
    assert "the reference has 1 mode changes" in mc.note and max(mc.data["err"]) < 1e-13, mc.line()
    assert max(res.check("impact times", "CVA").data["err"]) < 1e-13
    acc = res.check("energy account", "CVA")
    assert acc.verdict == ck.PASS and acc.value < 1e-11 and "round-off" in acc.note, acc.line()
    assert abs(float(acc.rows[-1]["impact law"]) + 11.8) < 0.05 and abs(float(acc.rows[-1]["friction work"]) + 0.605) < 1e-3
    assert res.check("energy across impacts", "CVA").verdict == ck.PASS


def test_forced_block_with_friction_is_compared_with_its_reference():
    """A block at rest on the floor pushed by c t (forced, friction): held from t = 0, so the check
    that the reference follows the forced smooth solve (which ignores the floor) has no free interval
    to compare and trusts it; the stick -> slip at c t = mu_s m g (t = 2.4525) is the reference's at
    every h, and the energy account balances forcing work and friction work (interpreted tier: no
    compile)."""
    from vcirun.scenes.friction import pushed_block

    res = vcirun.verify(pushed_block(), methods="CVA", T=3.0, h=LADDER, tier="interpreted")
    assert res.ok, [c.line() for c in res.failures]
    assert res.check("reference").verdict == ck.PASS, res.check("reference").line()
    assert res.check("L2 order through impacts", "CVA").verdict == ck.PASS
    mc = res.check("mode-change times", "CVA")
    assert "the reference has 1 mode changes" in mc.note and max(mc.data["err"]) < 1e-12, mc.line()
    assert res.check("energy account", "CVA").verdict == ck.PASS


def test_a_reference_that_ends_on_painleves_paradox_is_reported():
    """The Painleve rod (mu = 1.5, B < 0 at the start): the exact reference ends at t = 0 with status
    painleve; verify says so (the reference warns, the impact checks are skipped with the message)
    instead of failing on the shorter reference."""
    res = vcirun.verify(str(ROOT / "docs" / "examples" / "painleve_rod.yaml"), methods="CVA", T=0.5,
                        h=[0.02, 0.01, 0.005], tier="interpreted")
    ref = res.check("reference")
    assert ref.verdict == ck.WARN and "the reference ends at t = 0" in ref.note, ref.line()
    assert any("status painleve" in n and "B = -0.03196" in n for n in res.notes), res.notes
    c = res.check("L2 order through impacts", "CVA")
    assert c.verdict == ck.SKIP and "painleve" in c.note


def test_a_hold_at_a_plastic_impact_is_no_accumulation():
    """settle_window on recorded event sequences: a hold that starts at an impact (plastic) cuts no
    window unless the impacts before it come closer than 2.5 coarsest steps (a block rocking down on
    its corners, each corner impact holding that corner); a hold after a Zeno sequence still does."""
    class Ref:
        def __init__(self, impacts, holds):
            self.impacts = np.array(impacts, float)
            self.held_intervals = [(a, 9.0, A) for a, A in holds]

    ball = Ref([0.428353], [(0.428353, (0,))])
    assert not settle_window(ball, 1.0, 0.04).cut
    rock = Ref([0.2238, 0.551, 0.7995, 0.9919, 1.1422, 1.2604, 1.3536],
               [(t, (i % 2,)) for i, t in enumerate([0.2238, 0.551, 0.7995, 0.9919, 1.1422, 1.2604, 1.3536])])
    w = settle_window(rock, 2.0, 0.04, ["left", "right"])
    assert w.cut and w.T == pytest.approx(1.2) and w.impacts == 5, w
    zeno = Ref([0.3, 0.5, 0.56, 0.58], [(0.59, (0,))])
    w = settle_window(zeno, 1.0, 0.02)
    assert w.cut and w.T == pytest.approx(0.52) and w.impacts == 2, w


def test_mode_change_sequences():
    """The reference's transitions take their kind from the mode they leave (slip reversed, slip ->
    stick, stick -> slip); a run's change within round-off of t = 0 (a contact starting at rest whose
    slip direction the run took from a round-off slip velocity) is left out unless the reference has
    one there; sequences differing in kind name the first difference."""
    from types import SimpleNamespace as NS

    from vcirun.verification.friction import compare, reference_mode_changes, run_mode_changes

    ref = NS(transitions=[(1.0, 0, 1), (2.0, 0, 0), (3.0, 0, -1)],
             mode_intervals=[(0.0, 1.0, (0,), (-1,)), (1.0, 2.0, (0,), (1,)), (2.0, 3.0, (0,), (0,)),
                             (3.0, 4.0, (0,), (-1,))])
    want = reference_mode_changes(ref, 4.0)
    assert [k for _, _, k in want] == [3, 1, 2]
    assert reference_mode_changes(ref, 2.5) == want[:2]
    tr = NS(mode_changes=np.array([2.4e-16, 1.0 + 1e-9, 2.0, 3.0 - 1e-9]), mode_change_contact=np.zeros(4, np.int64),
            mode_change_kind=np.array([3, 3, 1, 2]))
    events, left = run_mode_changes(tr, 4.0, want)
    assert left == [(2.4e-16, 0, 3)] and len(events) == 3
    err, diff = compare(events, want, ["floor"])
    assert diff == "" and err == pytest.approx(1e-9)
    tr.mode_change_kind = np.array([3, 3, 3, 2])
    err, diff = compare(run_mode_changes(tr, 4.0, want)[0], want, ["floor"])
    assert np.isnan(err) and "mode change 2: the run's floor slip reversed at t = 2" in diff
    assert "the reference's floor slip -> stick" in diff
    events, left = run_mode_changes(tr, 4.0, [(0.0, 0, 3)] + want)
    assert not left and len(events) == 4


# --- the verdicts -----------------------------------------------------------------------------------

def test_order_near_round_off_warns_instead_of_failing():
    """CVA4 on the rocking block with friction: L2 errors 1.4e-10, 7.3e-12, 1.1e-12 (measured), the
    last two within 100x of round-off: the bent slope warns (the ladder is too fine), where a clean
    wrong order above round-off still fails."""
    hs = np.array([0.01, 0.005, 0.0025])
    c = ck.order_check("L2 order through impacts", "CVA4", hs, [1.4e-10, 7.3e-12, 1.11e-12], 4, scale=0.77)
    assert c.verdict == ck.WARN and "100x round-off" in c.note, c.line()
    c = ck.order_check("L2 order through impacts", "X", hs, [1e-6, 1e-7, 1e-8], 2, scale=1.0)
    assert c.verdict == ck.FAIL, c.line()


def test_runs_that_converge_elsewhere_fail():
    """Large flat errors against the exact solution are a coarse ladder only if the runs also differ
    among themselves; runs that agree ever better with each other integrate another system."""
    hs = [0.04, 0.02, 0.01, 0.005]
    c = ck.order_check("L2 order through impacts", "X", hs, [2.41, 2.40, 2.39, 2.39], 2, scale=2.45)
    assert c.verdict == ck.WARN
    ck.converges_elsewhere(c, hs, [2.41, 2.40, 2.39, 2.39], [0.0189, 4.6e-3, 1.14e-3], 2.45)
    assert c.verdict == ck.FAIL and "another motion" in c.note
    chaotic = ck.order_check("L2 order through impacts", "X", hs, [2.41, 2.40, 2.39, 2.39], 2, scale=2.45)
    ck.converges_elsewhere(chaotic, hs, [2.41, 2.40, 2.39, 2.39], [2.0, 1.9, 2.2], 2.45)
    assert chaotic.verdict == ck.WARN


# --- wrong systems ---------------------------------------------------------------------------------

def _wrong_loader(kind):
    """A loader whose module is the generated one run as Python with one deliberate error."""
    from vcirun.codegen.derive import module_source
    from vcirun.codegen.evaluate import run_as_python

    def load(system, ks):
        text = module_source(system, ks)
        if kind == "sign":
            assert text.count(FORCE_ROW) == 1
            text = text.replace(FORCE_ROW, "f = -mu[j] * held[j] if slipping(held[j]) else 0.0")
        if kind == "impact":
            assert text.count(IMPULSE) == 1
            text = text.replace(IMPULSE, "            d[j] += la[r] * R[r, j] * ((1.0 + h) if r >= k else 1.0)\n")
        mod = run_as_python(text, f"wrong_{kind}_{system.name}_{abs(hash(ks))}")
        if kind == "slip":   # the slip rows leave the tangent: W_t + grad(phi) / 2
            right = mod.sys_slips

            def sys_slips(q, prm, out):
                right(q, prm, out)
                G = np.empty_like(out)
                mod.sys_dphis(q, prm, G)
                out += 0.5 * G

            mod.sys_slips = sys_slips
        return mod

    return load


def test_friction_force_of_the_wrong_sign_fails():
    """The held step pushes along the slip (the kernels are right, the map is wrong): the oscillator
    gains energy and never sticks. The mode changes differ from the reference's (its fifth a reversal
    where the reference sticks), the runs converge to another motion than the reference's, and the
    energy account does not balance (the recorded friction work is not what the forces did)."""
    res = vcirun.verify(OSCILLATOR, methods="CVA", T=6.0, h=LADDER, loader=_wrong_loader("sign"))
    assert not res.ok
    assert res.check("derivatives", "CVA").verdict == ck.PASS
    mc = res.check("mode-change times", "CVA")
    assert mc.verdict == ck.FAIL and "slip reversed" in mc.note and "slip -> stick" in mc.note, mc.line()
    l2 = res.check("L2 order through impacts", "CVA")
    assert l2.verdict == ck.FAIL and "another motion" in l2.note, l2.line()
    acc = res.check("energy account", "CVA")
    assert acc.verdict == ck.FAIL and "does not fall with h" in acc.note, acc.line()


def test_a_slip_row_that_is_not_the_declared_one_fails():
    """sys_slips returns W_t + grad(phi) / 2 (a row off the tangent, not the declared tangent row):
    the derivative table names sys_slips, and the runs converge to another motion."""
    res = vcirun.verify(OSCILLATOR, methods="CVA", T=6.0, h=LADDER, loader=_wrong_loader("slip"))
    d = res.check("derivatives", "CVA")
    assert d.verdict == ck.FAIL and "sys_slips" in d.threshold and d.value > 0.1, d.line()
    l2 = res.check("L2 order through impacts", "CVA")
    assert l2.verdict == ck.FAIL and "another motion" in l2.note, l2.line()


def test_a_frictional_impact_off_by_h_fails():
    """The spinning ball's tangential impulse (1 + h) times the law's: the impact step changes H by
    O(h) more than the law removes (the energy check, slope 1), the account's rest falls at order 1,
    the L2 error too."""
    res = vcirun.verify(BALL, methods="CVA", T=1.0, h=LADDER, loader=_wrong_loader("impact"))
    for name in ("energy across impacts", "energy account", "L2 order through impacts"):
        c = res.check(name, "CVA")
        assert c.verdict == ck.FAIL and 0.8 <= c.value <= 1.2, c.line()


# --- slow: more scenes and methods -----------------------------------------------------------------

@pytest.mark.slow
def test_rocking_block_with_friction_verifies():
    """Housner's rocking (mu = 0.8: the corners stick), plastic corner impacts down to rest on both
    corners: verified on the window before the impacts come closer than 2.5 coarsest steps, with CVA,
    MCVAA, VCI and CVA4 (CVA4 reaches 100x round-off at h = 0.005: its order warns)."""
    from vcirun.scenes.friction import rocking_block_friction

    res = vcirun.verify(rocking_block_friction(), methods="CVA,MCVAA,VCI,CVA4", T=2.0)
    assert res.ok, [c.line() for c in res.failures]
    assert any("window [0, 1.2]" in n for n in res.notes) and any("comes to rest at t = 1.708" in n for n in res.notes)
    for m in ("CVA", "MCVAA", "VCI", "CVA4"):
        assert res.check("energy across impacts", m).verdict == ck.PASS
        assert res.check("energy account", m).verdict == ck.PASS
        assert res.check("mode-change times", m).verdict != ck.FAIL


@pytest.mark.slow
def test_compass_gait_stance_with_a_sliding_foot_verifies():
    """The built-in gait's stance phase with a frictional stance foot (mu = 0.247, mu_s = 0.26, below
    the 0.274 the pinned gait needs at heel strike): the foot slides from the start and sticks at t =
    0.05286; every judged check passes with CVA, MCVAA, VCI and CVA4 (mode-change time orders 2.08, 2.08,
    2.08, 3.85 measured on the interpreted tier). The runs' slip direction at the start comes from a
    round-off slip velocity (4e-15): their reversal at t ~ 1e-16 is left out and said."""
    from vcirun.scenes.registry import scene_data
    from vcirun.scenes.walkers import compass_gait_M
    from vcirun.scenes.friction import compass_gait_stance

    D = scene_data("compass_gait")
    pin = vcirun.reference("compass_gait", T=1.0)
    q0, p0 = pin.state(0.0)[:2], pin.state(0.0)[2:]
    v0 = np.linalg.solve(np.array(compass_gait_M(q0, D.params)), p0)
    s = compass_gait_stance(*q0, *v0, mu=0.247, mu_s=0.26)
    res = vcirun.verify(s, methods="CVA,MCVAA,VCI,CVA4", T=0.73, h=[0.02, 0.01, 0.005, 0.0025, 0.00125])
    assert res.ok and not _not_passing(res), _not_passing(res)
    for m in ("CVA", "MCVAA", "VCI", "CVA4"):
        mc = res.check("mode-change times", m)
        assert mc.verdict == ck.PASS and "the reference has 1 mode changes" in mc.note, mc.line()
