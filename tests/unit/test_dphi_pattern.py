"""The constraint Jacobian's structural nonzeros (sys_dphis_nz with DPHI_ROW, DPHI_COL): the loops over
every contact on every step (touching, normal velocities, touch tolerances) run over them instead of
the dense G.

Checked over random states of scenes with several contacts, one contact, friction and bodies: the
pattern holds every nonzero of sys_dphis, in ascending columns, and scattered it is sys_dphis bit for
bit; the normal velocities built on it are G M^-1 p of the dense matrices (an independent numpy
solve).
"""
from __future__ import annotations

import numpy as np
import pytest

SCENES = ("newton_cradle", "ball_in_box", "double_pendulum_walls", "rocking_block", "link_chain_friction",
          "cart_pendulum", "cradle")


@pytest.mark.parametrize("scene", SCENES)
def test_pattern_scatters_to_the_dense_jacobian(scene, compiled, rng):
    system, mod, prm = compiled(scene, "CVA")
    n, m = int(mod.NDOF), int(mod.NCON)
    row, col = np.asarray(mod.DPHI_ROW), np.asarray(mod.DPHI_COL)
    nnz = int(mod.DPHI_NNZ)
    assert row.shape == (m + 1,) and row[0] == 0 and np.all(np.diff(row) >= 0) and col.shape == (nnz,)
    assert row[-1] == nnz or (row[-1] == 0 and nnz == 1)          # (one padding zero without any nonzero)
    for i in range(m):
        assert np.all(np.diff(col[row[i]:row[i + 1]]) > 0)          # ascending columns within a row
    G, gv, dense = np.empty((m, n)), np.empty(nnz), np.empty((m, n))
    for _ in range(25):
        q = rng.uniform(-1.5, 1.5, n)
        mod.sys_dphis(q, prm, G)
        mod.sys_dphis_nz(q, prm, gv)
        dense[:] = 0.0
        for i in range(m):
            dense[i, col[row[i]:row[i + 1]]] = gv[row[i]:row[i + 1]]
        assert np.array_equal(dense, G), scene                       # every nonzero is in the pattern, same bits
        p = rng.uniform(-2.0, 2.0, n)
        M = system.mass_matrix(q, prm)
        u = mod.normal_velocities(q, p, prm)
        ref = G @ np.linalg.solve(M, p)
        assert np.allclose(u, ref, rtol=1e-10, atol=1e-12 * (1.0 + np.abs(ref).max())), scene


def test_pattern_of_a_chain_is_sparse(compiled):
    """A cradle of N balls: each contact involves its two neighbours, 2 (N - 1) nonzeros of (N - 1) N."""
    system, mod, _ = compiled("newton_cradle_20", "CVA")
    assert int(mod.DPHI_NNZ) == 2 * 19
    assert list(mod.DPHI_ROW) == list(range(0, 2 * 19 + 1, 2))
    assert list(mod.DPHI_COL) == [c for i in range(19) for c in (i, i + 1)]
