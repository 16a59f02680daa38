"""A `simulate(tol=...)` that reaches no candidate's tolerance returns the most accurate run it made,
and an estimate of that run never says "ok" where a finer run of the same method shows impacts the run
misses: Richardson on two coarse runs that agree with each other (both missing the same impacts) is
not an error bound."""
from __future__ import annotations

import numpy as np

import vcirun
from vcirun.methods.table import resolve_method
from vcirun.run.ladder import estimate_of
from vcirun.run.pilot import Run


def _run(N, impacts, q_scale=0.0, T=1.0):
    """A Run on N steps of [0, T] with q(t) = (t, q_scale t^2) and the impacts of contact 0 at `impacts`."""
    t = np.linspace(0.0, T, N + 1)
    q = np.column_stack([t, q_scale * t * t])
    imp = np.asarray(impacts, float)
    return Run(method=resolve_method("CVA"), N=N, h=T / N, t0=0.0, q=q, p=q.copy(), impacts=imp,
               impact_contact=np.zeros(len(imp), np.int64), releases=np.zeros(0), release_contact=np.zeros(0, np.int64),
               held=False, status="ok", wall=0.0, cpu=0.0)


def test_a_finer_run_with_other_impacts_makes_a_coarse_estimate_unresolved():
    runs = {16: _run(16, [0.3]), 32: _run(32, [0.3], 1e-9), 64: _run(64, [0.3, 0.7], 2e-9)}
    est = estimate_of(runs, 32, 2.0)
    assert est.status == "unresolved" and est.l2 is None, est
    assert "finer run of the same method (N = 64)" in est.message, est.message
    # without the finer run the pair's Richardson estimate stands: the check reads only runs finer than N
    alone = estimate_of({16: runs[16], 32: runs[32]}, 32, 2.0)
    assert alone.status == "ok" and alone.l2 is not None
    # a finer run with the same impacts leaves the estimate as it was
    same = estimate_of({16: runs[16], 32: runs[32], 64: _run(64, [0.3], 2e-9)}, 32, 2.0)
    assert same.status == "ok" and same.l2 == alone.l2


def test_tol_not_reached_returns_no_false_number():
    """The rocking block with friction (T = 2): the candidates' pilots see the impact sequence change
    with h up to their budget (on this machine to N = 1024 .. 8192). The run returned is the finest made
    and its estimate is not a number; the coarse pairs that agree (a block at rest after two impacts,
    where the exact motion rocks 61 times) are not taken for a resolved run. A machine whose pilots get
    further may resolve the motion: then the number must be right."""
    T = 2.0
    tr = vcirun.simulate("rocking_block_friction", T=T, tol=1e-5)
    c = tr.choice
    ref = vcirun.reference("rocking_block_friction", T=T)
    if c.estimate.status == "ok":   # a number only for a run whose impacts are the reference's
        assert len(tr.impacts) == len(ref.impacts), (c.method, c.N, len(tr.impacts), len(ref.impacts))
        lo, hi = c.estimate.l2_bounds
        assert lo <= vcirun.l2_error(tr, ref) <= hi
    else:
        assert c.estimate.status == "unresolved" and c.estimate.l2 is None
    if c.status == "not_reached":
        assert c.N >= 512, (c.method, c.N)   # the finest run any candidate made, or a resolved one
