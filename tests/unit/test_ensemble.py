"""vcirun.ensemble: each run equals vcirun.simulate with the same arguments, bit for bit (final state,
status, counters, energy error; trajectories when asked), over random initial states and parameter
sets, for the methods of the paper, a forced scene and a scene of several contacts; a refused start
or a failed run is a status, not an exception for the batch."""
from __future__ import annotations

import threading

import numpy as np
import pytest

import vcirun

pytestmark = pytest.mark.filterwarnings("ignore::vcirun.run.api.GridWarning")


def _energy_error(tr) -> float:
    if not np.isfinite(tr.H[0]):
        return np.nan
    return float(np.nanmax(np.abs(tr.H - tr.H[0])))


def _assert_equal_runs(ds, kwargs_of, system, method, **common):
    for i in range(ds.sizes["run"]):
        tr = vcirun.simulate(system, method, **common, **kwargs_of(i))
        row = ds.isel(run=i)
        assert str(row.status.values) == tr.status, (i, tr.message)
        np.testing.assert_array_equal(row.q_final.values, tr.q[-1])
        np.testing.assert_array_equal(row.p_final.values, tr.p[-1])
        assert int(row.n_impacts) == len(tr.impacts) and int(row.n_steps) == len(tr.t) - 1
        assert int(row.fail_step) == tr.fail_step
        np.testing.assert_array_equal(row.energy_error.values, _energy_error(tr))
        if "q" in ds:
            k = len(tr.t)
            np.testing.assert_array_equal(row.q.values[:k], tr.q)
            np.testing.assert_array_equal(row.H.values[:k], tr.H)
            assert np.isnan(row.q.values[k:]).all()


@pytest.mark.parametrize("method", ["CVA", "VCI", "MCVAA", "MCVAC"])
def test_cart_pendulum_runs_equal_simulate(method):
    betas = np.random.default_rng(30).uniform(2.0, 4.8, 12)
    ds = vcirun.ensemble("cart_pendulum", method, h=2e-2, T=2.0, beta=betas, workers=2)
    assert ds.sizes == {"run": 12, "coordinate": 2}
    assert list(ds.coordinate.values) == ["x", "theta"] or len(ds.coordinate) == 2
    np.testing.assert_array_equal(ds.beta.values, betas)
    _assert_equal_runs(ds, lambda i: {"beta": float(betas[i])}, "cart_pendulum", method, h=2e-2, T=2.0)


def test_trajectories_when_asked_and_parameter_sets():
    betas = np.random.default_rng(31).uniform(2.0, 4.8, 5)
    g = np.random.default_rng(32).uniform(5.0, 15.0, 5)
    ds = vcirun.ensemble("cart_pendulum", "CVA", h=5e-2, T=1.0, beta=betas, params={"g": g}, outputs="trajectory")
    assert ds.q.dims == ("run", "t", "coordinate") and ds.sizes["t"] == 21
    _assert_equal_runs(ds, lambda i: {"beta": float(betas[i]), "params": {"g": float(g[i])}}, "cart_pendulum", "CVA",
                       h=5e-2, T=1.0)
    sets = [{"m2": 0.1 + 0.1 * i} for i in range(4)]   # one beta shared by every parameter set
    ds = vcirun.ensemble("cart_pendulum", "VCI", h=5e-2, T=1.0, beta=3.2, params=sets)
    _assert_equal_runs(ds, lambda i: {"beta": 3.2, "params": sets[i]}, "cart_pendulum", "VCI", h=5e-2, T=1.0)


def test_forced_scene_and_several_contacts():
    rng = np.random.default_rng(33)
    x0, v0 = rng.uniform(0.5, 1.5, (6, 1)), rng.uniform(-1.0, 1.0, (6, 1))
    ds = vcirun.ensemble("damped_oscillator", "CVA", h=1e-2, T=2.0, q0=x0, p0=v0)
    assert (ds.status == "ok").all()
    _assert_equal_runs(ds, lambda i: {"q0": x0[i], "p0": v0[i]}, "damped_oscillator", "CVA", h=1e-2, T=2.0)
    q0 = rng.uniform(0.2, 0.8, (6, 2))
    p0 = rng.uniform(-3.0, 3.0, (6, 2))
    ds = vcirun.ensemble("ball_in_box", "CVA", h=1e-2, T=1.5, q0=q0, p0=p0)
    assert (ds.n_impacts > 0).any()
    _assert_equal_runs(ds, lambda i: {"q0": q0[i], "p0": p0[i]}, "ball_in_box", "CVA", h=1e-2, T=1.5)


def test_a_refused_start_or_a_failure_is_a_status_of_its_run():
    betas = np.array([3.2, np.nan, 4.0, 3.6])
    ds = vcirun.ensemble("cart_pendulum", "CVA", h=2e-2, T=1.0, beta=betas, max_iter=1)
    assert ds.status.values[1] == "invalid_input" and "beta" in ds.attrs["messages"][0]
    assert np.isnan(ds.q_final.values[1]).all()
    ok = [0, 2, 3]
    _assert_equal_runs(ds.isel(run=ok), lambda j: {"beta": float(betas[ok[j]])}, "cart_pendulum", "CVA",
                       h=2e-2, T=1.0, max_iter=1)
    assert set(ds.status.values[ok]) != {"ok"}   # one Newton iteration is not enough somewhere
    q0 = np.array([[1.0, 0.5], [-1.0, 0.5]])   # the second starts inside phi = y >= 0 (below the floor)
    ds = vcirun.ensemble("cart_pendulum", "CVA", h=2e-2, T=0.5, q0=q0, p0=np.zeros((2, 2)))
    assert list(ds.status.values) == ["ok", "invalid_input"]
    with pytest.raises(ValueError, match="inside the constraint"):
        vcirun.simulate("cart_pendulum", "CVA", h=2e-2, T=0.5, q0=q0[1], p0=[0.0, 0.0])


def test_bad_arguments_of_the_whole_batch_raise_naming_the_field():
    with pytest.raises(ValueError, match="beta: give either beta or q0 and p0"):
        vcirun.ensemble("cart_pendulum", "CVA", h=0.1, T=1, beta=[3.0], q0=np.zeros((1, 2)), p0=np.zeros((1, 2)))
    with pytest.raises(ValueError, match="params.g: has 2 runs, beta has 3"):
        vcirun.ensemble("cart_pendulum", "CVA", h=0.1, T=1, beta=[3.0, 3.1, 3.2], params={"g": [9.0, 10.0]})
    with pytest.raises(ValueError, match="p0: has 2 runs, q0 has 3"):
        vcirun.ensemble("cart_pendulum", "CVA", h=0.1, T=1, q0=np.zeros((3, 2)), p0=np.zeros((2, 2)))
    with pytest.raises(ValueError, match="params.nope: unknown parameter"):
        vcirun.ensemble("cart_pendulum", "CVA", h=0.1, T=1, beta=[3.0], params={"nope": [1.0]})
    with pytest.raises(ValueError, match="outputs: must be one of"):
        vcirun.ensemble("cart_pendulum", "CVA", h=0.1, T=1, beta=[3.0], outputs="all")
    with pytest.raises(ValueError, match="q0: must have shape"):
        vcirun.ensemble("cart_pendulum", "CVA", h=0.1, T=1, q0=np.zeros((3, 5)), p0=np.zeros((3, 5)))
    with pytest.raises(ValueError, match="beta: must be numbers"):
        vcirun.ensemble("cart_pendulum", "CVA", h=0.1, T=1, beta=["a", "b"])
    with pytest.raises(ValueError, match="q0: must be numbers"):
        vcirun.ensemble("cart_pendulum", "CVA", h=0.1, T=1, q0=[[1.0, 0.5], [1.0]], p0=np.zeros((2, 2)))
    with pytest.raises(ValueError, match="h: must"):
        vcirun.ensemble("cart_pendulum", "CVA", h=-0.1, T=1, beta=[3.0])


def test_batches_stream_the_same_runs():
    from vcirun.run.ensemble import iter_ensemble

    betas = np.random.default_rng(35).uniform(2.0, 4.8, 7)
    whole = vcirun.ensemble("cart_pendulum", "CVA", h=5e-2, T=1.0, beta=betas)
    parts = list(iter_ensemble("cart_pendulum", "CVA", h=5e-2, T=1.0, beta=betas, batch=3))
    assert [p.sizes["run"] for p in parts] == [3, 3, 1]
    assert [int(r) for p in parts for r in p.run.values] == list(range(7))
    for name in ("q_final", "p_final", "status", "n_impacts", "energy_error"):
        np.testing.assert_array_equal(np.concatenate([p[name].values for p in parts]), whole[name].values)


def test_one_scene_is_not_serialised_by_the_core_lock():
    """The ensemble's threads call the loop with the shared core's lock held once for the batch:
    while it runs, a second thread's call into the same module waits; the ensemble's own runs do not."""
    from vcirun.codegen import shared

    betas = np.full(8, 3.2)
    seen = []
    real = shared.exclusive

    def spy(mod):
        cm = real(mod)

        class _Spy:
            def __enter__(self):
                fast = cm.__enter__()
                seen.append((threading.current_thread().name, fast.integrate))
                return fast

            def __exit__(self, *a):
                return cm.__exit__(*a)

        return _Spy()

    shared.exclusive, old = spy, shared.exclusive
    try:
        ds = vcirun.ensemble("cart_pendulum", "CVA", h=5e-2, T=1.0, beta=betas, workers=2)
    finally:
        shared.exclusive = old
    assert [name for name, _ in seen] == [threading.current_thread().name]   # once, by the caller, for the batch
    loop = seen[0][1]
    assert loop.targetoptions.get("nogil") is True   # the threads' loop releases the GIL (numba dispatcher)
    assert len({tuple(r) for r in ds.q_final.values}) == 1   # identical starts, identical bits in every thread
