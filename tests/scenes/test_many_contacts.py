"""Any contact count within the caps runs: no contacts x contacts array on the loop's stack beyond
vcirun.maps.linalg.STACK_DOUBLES doubles (larger ones are on the heap). A particle bouncing inside a
regular 1000-gon has 1000 constraints of which one or two take part in an impact; with the Delassus
matrix of every contact on the stack (8 MB at 1000 contacts) its first impact overflowed the stack.
"""
from __future__ import annotations

import numpy as np
import pytest

import vcirun
from vcirun.mechanics.loader import load_system_yaml

pytestmark = pytest.mark.slow

K = 1000


def polygon_box(k: int):
    ang = 2 * np.pi * (np.arange(k) + 0.5) / k
    walls = [{"name": f"w{i}", "phi": f"1 - ({float(np.cos(a))!r})*x - ({float(np.sin(a))!r})*y"} for i, a in enumerate(ang)]
    return load_system_yaml({"name": f"polygon_{k}", "coordinates": ["x", "y"], "parameters": {"m": 1.0, "g": 1.0},
                             "mass_matrix": [["m", 0], [0, "m"]], "potential": "m*g*y", "constraints": walls,
                             "q0": [0.0, 0.0], "p0": [0.7, 0.3]})


def test_a_particle_in_a_1000_gon_bounces_off_its_walls():
    tr = vcirun.simulate(polygon_box(K), "CVA", h=1e-2, T=4.0)
    assert tr.status == "ok", tr.message
    assert len(tr.impacts) >= 2
    # elastic walls, R^CVA: H is kept at every impact (the record's p- and p+)
    H = tr.H
    assert np.max(np.abs(H - H[0])) < 1e-2
    # every impact is at a wall: |q| . n_i = 1 for the recorded contact's normal
    ang = 2 * np.pi * (np.asarray(tr.impact_contact) + 0.5) / K
    reach = tr.impact_q[:, 0] * np.cos(ang) + tr.impact_q[:, 1] * np.sin(ang)
    assert np.max(np.abs(reach - 1.0)) < 1e-9
