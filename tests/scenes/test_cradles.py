"""The cradle both ways (docs/bodies.md): touching balls follow Moreau's simultaneous law (ball 1
strikes the row, balls 2..20 move on together, as formula (1.4) of docs/derivations/contacts.md says
for N balls), balls hung 1 mm apart collide one pair at a time down the row and the last ball swings out
to the release height; the built-in cradle_K and cradle_gap_K are the same two mechanisms."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import vcirun

EX = Path(__file__).resolve().parents[2] / "docs" / "examples"


@pytest.fixture(scope="module")
def runs():
    return {name: vcirun.simulate(str(EX / f"{name}.yaml"), "CVA", h=1e-3, T=1.2)
            for name in ("cradle20", "cradle20_gaps")}


def test_touching_balls_move_on_together(runs):
    tr = runs["cradle20"]
    assert tr.status == "ok"
    k = int(np.searchsorted(tr.t, 0.8))
    assert tr.q[k, 0] == pytest.approx(-0.2151, abs=1e-4)
    assert np.ptp(tr.q[k, 1:]) <= 1e-12 and tr.q[k, 1] == pytest.approx(0.0239, abs=1e-4)
    first = tr.impacts == tr.impacts[0]
    assert first.sum() == 19          # one simultaneous impact of all 19 contacts


def test_balls_hung_apart_collide_pairwise_and_the_last_swings_out(runs):
    tr = runs["cradle20_gaps"]
    assert tr.status == "ok"
    assert list(tr.impact_contact[:19]) == list(range(19))          # c1, c2, ..., c19 in turn
    assert np.all(np.diff(tr.impacts[:19]) > 1e-3)                   # one pair at a time
    after = tr.t > 0.55
    assert tr.q[after, 19].max() == pytest.approx(0.3, abs=1e-3)     # to ball 1's release height
    assert np.abs(tr.q[after, :19]).max() < 1e-3                     # the others stay (within the gap)
    assert tr.energy_account().error < 1e-6 * tr.energy_account().scale


def test_built_in_cradles_are_the_examples():
    a = vcirun.simulate("cradle_gap_20", "CVA", h=1e-3, T=0.6)
    b = vcirun.simulate(str(EX / "cradle20_gaps.yaml"), "CVA", h=1e-3, T=0.6)
    assert len(a.impacts) == len(b.impacts) == 19
    np.testing.assert_allclose(a.q, b.q, atol=1e-12)
