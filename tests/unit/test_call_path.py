"""The per-call path of `vcirun.simulate` hands the loop's grid and step rows to the Trajectory and
copies the records (vcirun.run.plan.Buffers, take; Trajectory.of_run): the values are record.trim's
and Trajectory(**values)'s, a reused buffer never reaches a returned Trajectory, and one run's
arrays are never changed by the next."""
from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

import vcirun
from vcirun.core import record
from vcirun.run import api
from vcirun.run.plan import Buffers, take
from vcirun.run.trajectory import DERIVED, RUN_FIELDS, Trajectory


def _filled(N, n, m, cap, rng):
    out = record.allocate(N, n, m=m, cap_impacts=cap)
    for a in out:
        if a.dtype == np.bool_:
            a[...] = rng.random(a.shape) < 0.5
        else:
            a[...] = rng.integers(-5, 5, a.shape) if a.dtype.kind == "i" else rng.standard_normal(a.shape)
    return out


@pytest.mark.parametrize("seed", range(6))
def test_take_gives_the_values_of_record_trim(seed):
    rng = np.random.default_rng(seed)
    N, n, m = int(rng.integers(1, 40)), int(rng.integers(1, 4)), int(rng.integers(1, 4))
    cap = record.impact_capacity(N)
    out = _filled(N, n, m, cap, rng)
    steps = int(rng.integers(0, N + 1))
    counters = {"status": 0, "fail_step": -1, "steps": steps, "n_impacts": int(rng.integers(0, 3)) * int(seed % 2),
                "n_partial": int(rng.integers(0, 5)), "n_releases": int(seed % 3 == 0), "n_mode_changes": 0}
    for modified in (False, True):
        ref = record.trim(out, counters, modified)
        got = take(out, counters, modified)
        for k in ref.keys() - got.keys():   # (a record with no entries: left to the Trajectory's first read)
            assert record.FIELD[k].axis not in ("grid", "step") and ref[k].shape[0] == 0, k
        for k in got:
            if ref[k] is None:
                assert got[k] is None, k
                continue
            assert got[k].dtype == ref[k].dtype and got[k].shape == ref[k].shape, k
            assert np.array_equal(got[k], ref[k]), k
            f = record.FIELD[k]
            if f.axis in ("grid", "step"):
                assert np.shares_memory(got[k], out[record.FIELDS.index(f)]) or got[k].size == 0, k
            else:   # a record: never a view of the buffer the next run reuses
                assert got[k].size == 0 or not np.shares_memory(got[k], out[record.FIELDS.index(f)]), k


def test_empty_records_take_in_place_arithmetic_as_every_record():
    tr = vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=0.1, beta=3.2)   # no impact, release or mode change
    assert tr.impacts.size == 0 and tr.releases.size == 0 and tr.mode_changes.size == 0
    tr.impacts -= 1.0
    tr.releases += 2.0
    for f in record.FIELDS:
        if f.axis not in ("grid", "step"):
            a = getattr(tr, f.name)
            assert a.shape == f.shape(0, 2, 1) and a.flags.writeable and a.flags.owndata, f.name


def test_of_run_is_the_dataclass_constructor():
    tr = vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=2.0, beta=3.2)
    values = {f.name: getattr(tr, f.name) for f in dataclasses.fields(Trajectory) if f.name in RUN_FIELDS}
    values.update(status=tr.status, wall_time=tr.wall_time, beta=tr.beta)
    a, b = Trajectory.of_run(dict(values)), Trajectory(**values)
    for f in dataclasses.fields(Trajectory):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert np.array_equal(x, y) and x.dtype == y.dtype, f.name
        else:
            assert x == y or (x != x and y != y), f.name   # (NaN: fail_time of a run that did not fail)


def test_a_run_gives_every_field_of_run_fields():
    tr = vcirun.simulate("cart_pendulum", "MCVAA", h=1e-2, T=1.0, beta=3.2)
    for name in RUN_FIELDS:   # (given by the run or made on first read, not a default: each holds a value)
        assert name in tr.__dict__ or name in DERIVED, name
        assert getattr(tr, name) is not None, name
    assert tr.Hmod is not None and len(tr.Hmod) == len(tr.t)


def test_fields_made_on_first_read_are_the_calls_own():
    """A run's derived fields (the grid times, options, tolerances, dynamics, run_args, its empty records)
    are made when first read, from the kept plan that later calls share: read after other calls with
    other parameters, steps and methods, they are those of the same call read at once."""
    call = dict(h=1e-2, T=0.5, beta=3.2, params={"m2": 0.3}, newton_tol=1e-11)
    b = vcirun.simulate("cart_pendulum", "CVA", **call)
    early = {name: getattr(b, name) for name in DERIVED}   # (read at once)
    a = vcirun.simulate("cart_pendulum", "CVA", **call)
    assert "_derive" in a.__dict__ and "options" not in a.__dict__   # (nothing read yet)
    vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=0.5, beta=3.2, newton_tol=1e-11)
    vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=0.3, beta=3.0)
    vcirun.simulate("cart_pendulum", "MCVAA", h=1e-2, T=0.5, beta=2.0)
    for name, y in early.items():
        x = getattr(a, name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), name
        elif name == "dynamics":
            assert x.module is y.module and np.array_equal(x.prm, y.prm), name
        elif name == "run_args":
            assert dataclasses.replace(x, q0=None, p0=None) == dataclasses.replace(y, q0=None, p0=None), name
            assert np.array_equal(x.q0, y.q0) and np.array_equal(x.p0, y.p0), name
        else:
            assert x == y, name
    assert a.options == {"params": {"m1": 1.0, "m2": 0.3, "L": 2.0, "g": 10.0}, "constrained": True}
    assert a.tolerances["newton_tol"] == 1e-11 and a.tolerances["event_tol"] == 1e-13
    assert np.array_equal(a.t, 1e-2 * np.arange(51)) and a.t.shape == (51,)
    assert a.dynamics.prm.tolist() == [1.0, 0.3, 2.0, 10.0]
    assert a.run_args.params == {"m2": 0.3} and np.array_equal(a.run_args.q0, a.q[0])
    assert a.releases.shape == (0,) and a.impact_q.shape == (0, 2) and a.impact_contact.dtype == np.int64
    assert a.releases is a.releases   # (made once, then kept)
    b = pickle.loads(pickle.dumps(vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=0.5, beta=3.2)))
    assert "_derive" not in b.__dict__ and b.tolerances["newton_tol"] == 1e-12 and len(b.t) == 51
    assert b.mode_changes.shape == (0,) and b.options["params"]["m2"] == 0.2


def test_consecutive_runs_never_share_their_arrays():
    api._LOCAL.buffers = Buffers(keep_grid=False)
    a = vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=5.0, beta=3.2)
    keep = {k: np.array(getattr(a, k), copy=True) for k in ("q", "p", "H", "impacts", "impact_q", "newton_iters",
                                                               "impact_step", "contact_active", "t")}
    b = vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=5.0, beta=2.9)
    c = vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=5.0, beta=3.2)
    assert len(a.impacts) > 0 and not np.array_equal(a.q, b.q)
    for k, v in keep.items():
        assert np.array_equal(getattr(a, k), v), k            # not overwritten by the later runs
        assert np.array_equal(getattr(c, k), v), k            # the same start gives the same bits
        assert not np.shares_memory(getattr(a, k), getattr(c, k)) or v.size == 0, k


def test_a_plan_made_from_a_kept_one_computes_its_own_grid_times():
    """simulate(tol=) makes its runs' plans from the kept plan of h = T (dataclasses.replace): the grid
    times a plain call with h = T left on that plan are not theirs."""
    vcirun.simulate("cart_pendulum", "CVA", T=0.01)   # h = min(1e-2, T) = T: a grid of two times
    tr = vcirun.simulate("cart_pendulum", "CVA", T=0.01, tol=1e-9)
    assert len(tr.t) == len(tr.q) > 2
    assert np.array_equal(tr.t, tr.h * np.arange(len(tr.q)))
    tr.to_xarray()


def test_changing_an_empty_record_of_one_run_leaves_the_others():
    a = vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=0.1, beta=3.2)
    a.releases.flags.writeable = False
    a.impact_q.shape = (0, 1, 2)
    b = vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=0.1, beta=3.2)
    assert b.releases.flags.writeable and b.impact_q.shape == (0, 2)
    b.releases += 1.0


def test_every_run_says_its_tier_and_build_and_a_saved_one_keeps_them(tmp_path):
    from vcirun.run.trajectory import read_trajectory

    for tr in (vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=1.0, beta=3.2),
               vcirun.simulate("cart_pendulum", T=1.0, tol=1e-4, beta=3.2)):   # (made by the choice's Runner)
        assert tr.tier == "compiled" and tr.build in ("shared", "specialized"), (tr.tier, tr.build)
        tr.save(tmp_path / "run.h5")
        back = read_trajectory(tmp_path / "run.h5")
        assert (back.tier, back.build) == (tr.tier, tr.build)
    assert Trajectory(method="CVA", system="x", h=0.1, T=1.0, t=np.zeros(1)).build is None


def test_rows_a_run_does_not_return_are_never_another_runs():
    """The rows a run does not return (Plan.rows: the modified energy of a method without one, the
    friction rows of a module without friction) are the Buffers' own: a run that returned its Hmod keeps
    it through later runs of methods without one, and a module without friction gives zeros of the
    grid's, the steps' and the impacts' lengths (its tangential impulses), also where the run stopped
    early."""
    api._LOCAL.buffers = Buffers(keep_grid=False)
    a = vcirun.simulate("cart_pendulum", "MCVAA", h=1e-2, T=5.0, beta=3.2)
    keep = a.Hmod.copy()
    for beta in (3.0, 3.4):
        b = vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=5.0, beta=beta)
        assert b.Hmod is None and "contact_mode" not in b.__dict__
    assert np.array_equal(a.Hmod, keep) and np.isfinite(keep).all()
    assert b.contact_mode.shape == (501, 1) and b.contact_mode.dtype == np.int8 and not b.contact_mode.any()
    assert b.friction_work.shape == (500,) and b.friction_work.dtype == np.float64 and not b.friction_work.any()
    assert len(b.impacts) > 0 and "impact_impulse_t" not in b.__dict__
    assert b.impact_impulse_t.shape == b.impacts.shape and not b.impact_impulse_t.any()
    c = vcirun.simulate("cart_pendulum", "CVA", h=0.5, T=5.0, beta=3.2, newton_tol=1e-300, max_iter=1)
    assert c.status != "ok" and len(c.friction_work) == len(c.newton_iters) and len(c.contact_mode) == len(c.q)
    f = vcirun.simulate("rocking_block_friction", "CVA", h=1e-2, T=1.0)   # (friction: rows of its own)
    assert "contact_mode" in f.__dict__ and f.contact_mode.any() and len(f.friction_work) == len(f.t) - 1
    assert "impact_impulse_t" in f.__dict__ and f.impact_impulse_t.any()
