"""The auto build (vcirun.codegen.specialize): a hot shared module is built again as a specialized module
in the background, and runs switch to it with the same bits."""
from __future__ import annotations

import sys
import time

import numpy as np
import pytest

import vcirun
from vcirun.codegen import background, build, cache_store, specialize
from vcirun.codegen.kernel_cache import KernelCache, default
from vcirun.methods.table import resolve_method
from vcirun.scenes.registry import get_scene

RUN = dict(h=0.01, T=3.0, params={"e": 0.9})


def _same(a, b):
    assert a.status == b.status == "ok"
    for f in ("q", "p", "H", "impacts", "impact_contact", "impact_impulse"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)


def _plan(kc):
    """The plan kc keeps (a run after the first: a cold run's plan holds the symbolic system, not kept)."""
    (p,) = kc.plans.values()
    return p


def test_the_specialized_key_is_derived_from_the_shared_key(monkeypatch):
    s, ks = get_scene("ball_in_box"), resolve_method("CVA").kernel_set()
    monkeypatch.setenv("VCIRUN_BUILD", "shared")
    shared = build.module_key_of(s, ks)
    for mode in ("auto", "shared"):
        monkeypatch.setenv("VCIRUN_BUILD", mode)
        assert build.module_key_of(s, ks) == shared
        with build.building("specialized"):
            assert build.build_mode() == "specialized"
            assert build.module_key_of(s, ks) == build.specialized_key(shared)
    monkeypatch.setenv("VCIRUN_BUILD", "specialized")
    assert build.module_key_of(s, ks) == build.specialized_key(shared) != shared
    monkeypatch.setenv("VCIRUN_BUILD", "bogus")
    with pytest.raises(ValueError, match="VCIRUN_BUILD: 'bogus' is not a build mode"):
        build.build_mode()


def test_auto_takes_a_specialized_module_another_process_built(monkeypatch):
    monkeypatch.setenv("VCIRUN_BUILD", "specialized")
    spec = vcirun.simulate("ball_in_box", "CVA", **RUN)   # (built, or loaded, and marked compiled)
    monkeypatch.setenv("VCIRUN_BUILD", "shared")
    shar = vcirun.simulate("ball_in_box", "CVA", **RUN)
    monkeypatch.setenv("VCIRUN_BUILD", "auto")
    kc = KernelCache()   # a process that has loaded nothing
    auto = vcirun.simulate("ball_in_box", "CVA", loader=kc, **RUN)
    _same(vcirun.simulate("ball_in_box", "CVA", loader=kc, **RUN), auto)
    assert auto.build == "specialized" and spec.build == "specialized" and shar.build == "shared"
    assert not hasattr(_plan(kc).module(), "SHARED_CORE") and _plan(kc)._up.state == "ready"
    _same(auto, spec)
    _same(auto, shar)


def test_a_hot_module_starts_its_specialized_build_once(monkeypatch):
    monkeypatch.setenv("VCIRUN_BUILD", "auto")
    monkeypatch.setattr(specialize, "HOT_S", 0.0)
    monkeypatch.setattr(specialize, "POLL_S", 0.0)
    jobs = []

    class Running:   # a background process that has not finished
        def poll(self):
            return None

    monkeypatch.setattr(background, "start", lambda job, d: jobs.append(job) or Running())
    kc = KernelCache()
    sysm, ks = get_scene("cart_pendulum"), resolve_method("MCVAA").kernel_set()
    key = build.specialized_key(kc.module_key(sysm, ks))
    d = kc.cache_dir()
    monkeypatch.setattr(background, "state", lambda d_, k: "none" if k == key else "compiled")
    first = None
    for _ in range(3):
        tr = vcirun.simulate("cart_pendulum", "MCVAA", h=0.01, T=1.0, beta=3.2, loader=kc)
        first = first or tr
        _same(tr, first)
    assert len(jobs) == 1, "one build per module, not one per run"
    job = jobs[0]
    assert (job.key, job.build, job.system, job.nprm) == (key, "specialized", "cart_pendulum", len(sysm.params))
    # its input: the shared module's generated text, sealed under the specialized key
    text, meta = cache_store.unseal_text(cache_store.read(d / f"vg_{key}.py"), key)
    assert text == kc.generated(kc.module_key(sysm, ks), ks)[0] and meta["kernels"] == ks.key_text()
    assert hasattr(_plan(kc).module(), "SHARED_CORE") and _plan(kc)._up.state == "building"


def test_a_failed_specialized_build_leaves_the_shared_one_said_once(monkeypatch):
    monkeypatch.setenv("VCIRUN_BUILD", "auto")
    monkeypatch.setattr(specialize, "HOT_S", 0.0)
    monkeypatch.setattr(specialize, "POLL_S", 0.0)
    sysm, ks = get_scene("cart_pendulum"), resolve_method("MCVAA").kernel_set()
    key = build.specialized_key(KernelCache().module_key(sysm, ks))
    looks = []

    def state(d, k):   # the build this process starts fails
        if k != key:
            return "compiled"
        looks.append(k)
        return "none" if len(looks) == 1 else "failed"

    class Running:
        def poll(self):
            return None

    monkeypatch.setattr(background, "state", state)
    monkeypatch.setattr(background, "start", lambda job, d: Running())
    monkeypatch.setattr(background, "failure", lambda d_, k: {"reason": "RuntimeError: no compiler"})
    told = []
    monkeypatch.setattr(cache_store, "LISTENERS", [told.append])   # (the notices, as the CLI gets them)
    run = lambda kc: vcirun.simulate("cart_pendulum", "MCVAA", h=0.01, T=1.0, beta=3.2, loader=kc)  # noqa: E731
    kc = KernelCache()
    runs = [run(kc) for _ in range(4)]
    said = [m for m in told if "specialized build" in m]
    assert len(said) == 1 and "RuntimeError: no compiler" in said[0] and "stay on the shared build" in said[0]
    assert _plan(kc)._up.state == "off" and {r.build for r in runs} == {"shared"}
    later = KernelCache()   # a later process finds the failure record: quiet, shared
    runs.append(run(later))
    assert len([m for m in told if "specialized build" in m]) == 1
    (up,) = later.upgrades.values()
    assert up.state == "off" and runs[-1].build == "shared"
    for r in runs[1:]:
        _same(r, runs[0])


def test_interpreted_runs_and_pinned_builds_do_not_specialize(monkeypatch):
    monkeypatch.setenv("VCIRUN_BUILD", "shared")
    kc = KernelCache()
    vcirun.simulate("cart_pendulum", "CVA", h=0.01, T=0.5, beta=3.2, loader=kc)
    assert not kc.upgrades
    monkeypatch.setenv("VCIRUN_BUILD", "auto")
    kc = KernelCache()
    vcirun.simulate("cart_pendulum", "CVA", h=0.01, T=0.5, beta=3.2, loader=kc, tier="interpreted")
    assert not kc.upgrades


@pytest.mark.slow
def test_a_hot_module_switches_to_its_specialized_build_with_the_same_bits(monkeypatch, tmp_path):
    """The whole path on an empty cache: shared first, the background build, the switch."""
    monkeypatch.setenv("VCIRUN_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("VCIRUN_BUILD", "auto")
    monkeypatch.setattr(specialize, "HOT_S", 0.0)
    kc = KernelCache()
    run = lambda: vcirun.simulate("ball_in_box", "CVA", loader=kc, **RUN)  # noqa: E731
    first = run()
    assert first.build == "shared"
    t0 = time.monotonic()
    while (tr := run()).build != "specialized":
        _same(tr, first)
        assert tr.build == "shared" and time.monotonic() - t0 < 600
        time.sleep(0.2)
    _same(tr, first)
    (up,) = kc.upgrades.values()
    assert up.state == "ready" and not hasattr(_plan(kc).module(), "SHARED_CORE")
    assert default() is not kc


def test_a_sweep_keeps_each_module_on_the_build_its_first_run_found(monkeypatch, tmp_path):
    """A sweep times its runs: a specialized module that appears mid-sweep is left for the next sweep."""
    from vcirun.codegen import kernel_cache
    from vcirun.experiments.config import parse_config
    from vcirun.experiments.sweep import run_sweep

    monkeypatch.setenv("VCIRUN_BUILD", "specialized")
    vcirun.simulate("ball_in_box", "CVA", **RUN)   # (the specialized module in the cache)
    monkeypatch.setenv("VCIRUN_BUILD", "auto")
    monkeypatch.setattr(specialize, "HOT_S", 0.0)
    monkeypatch.setattr(specialize, "POLL_S", 0.0)
    kc = KernelCache()
    monkeypatch.setattr(kernel_cache, "_DEFAULT", kc)   # (a process that has loaded nothing)
    sysm, ks = get_scene("ball_in_box"), resolve_method("CVA").kernel_set()
    spec_key = build.specialized_key(kc.module_key(sysm, ks))
    looks = []
    real_state = background.state

    def state(d, key):   # the specialized build "finishes" after the sweep's first looks
        if key != spec_key:
            return real_state(d, key)
        looks.append(key)
        return "compiled" if len(looks) > 2 else "none"

    monkeypatch.setattr(background, "state", state)
    monkeypatch.setattr(background, "start", lambda job, d: None)
    cfg = parse_config({"name": "hold", "system": {"name": "ball_in_box", "params": {"e": 0.9}}, "methods": ["CVA"],
                        "h": [2e-2, 1e-2, 5e-3, 2.5e-3], "initial_states": [{"q0": [0.3, 0.4], "p0": [1.0, 0.5]}],
                        "T": 1.0,
                        "timing_repeats": 1, "reference": {"kind": "none"}, "output": str(tmp_path / "s.h5")})
    s = run_sweep(cfg, workers=1, progress=False)
    assert s.computed == 4 and len(looks) > 2
    ds = vcirun.open_results(tmp_path / "s.h5")
    assert set(np.asarray(ds["build"]).ravel().tolist()) == {"shared"}, "one build for every run of the sweep"
    assert kc.switch_builds   # (restored after the sweep)
    assert vcirun.simulate("ball_in_box", "CVA", **RUN).build == "specialized"   # the next run takes it
    # the next sweep in this process starts on the specialized build and keeps it
    s = run_sweep(cfg, output=tmp_path / "s2.h5", workers=1, progress=False)
    ds = vcirun.open_results(tmp_path / "s2.h5")
    assert s.computed == 4 and set(np.asarray(ds["build"]).ravel().tolist()) == {"specialized"}


def test_a_sweep_resumed_over_shared_runs_stays_shared_else_takes_what_is_built(monkeypatch):
    from vcirun.experiments.sweep import builds_for_sweep

    taken = []
    monkeypatch.setattr(specialize, "take_built", taken.append)
    kc = KernelCache()
    builds_for_sweep(kc, [{"build": "specialized"}, {"status": "ok"}])
    assert kc.specialize and taken == [kc]
    builds_for_sweep(kc, [{"build": "specialized"}, {"build": "shared"}])
    assert not kc.specialize and taken == [kc]
    assert specialize.upgrade(kc, None, "compiled") is None   # (no module is specialized while it holds)


def test_a_marker_without_its_module_or_machine_code_is_dropped(tmp_path):
    class Load:
        key = "0" * 20

    up = specialize.Upgrade(KernelCache(), Load())
    d = tmp_path
    (d / "__pycache__").mkdir()
    marker, module = background.marker_path(d, up.key), d / f"vk_{up.key}.py"
    text = "import math\n\n\n@njit(cache=True)\ndef integrate(q0, p0):\n    return q0\n"   # (decorator on line 4)
    index = d / "__pycache__" / f"vk_{up.key}.integrate-4.py{sys.version_info[0]}{sys.version_info[1]}.nbi"
    sealed = cache_store.seal_text(text, {"key": up.key})
    for files in ([], [(module, sealed)], [(index, "")], [(module, "garbage"), (index, "")],
                  [(module, sealed), (index.with_name(index.name.replace("-4.", "-5.")), "")]):
        marker.write_text("{}")
        for f, content in files:
            f.write_text(content)
        assert not up._built(d) and not marker.exists(), files
        for f, _ in files:
            f.unlink()
    marker.write_text("{}")
    module.write_text(sealed)
    index.write_text("")
    assert up._built(d) and marker.exists()


def test_the_index_a_loaded_module_has_is_the_one_looked_for(monkeypatch):
    """numba_cache.index_exists names the file numba wrote for a specialized module's loop."""
    from vcirun.codegen import numba_cache

    monkeypatch.setenv("VCIRUN_BUILD", "specialized")
    vcirun.simulate("ball_in_box", "CVA", **RUN)   # (built and run: numba's index written)
    kc = default()
    key = kc.module_key(get_scene("ball_in_box"), resolve_method("CVA").kernel_set())
    path = kc.cache_dir() / f"vk_{key}.py"
    body = cache_store.unseal_text(cache_store.read(path), key)[0]
    assert numba_cache.index_exists(path, "integrate", body)
    assert not numba_cache.index_exists(path, "no_such_function", body)


def test_an_uncompiled_run_marks_nothing_compiled(tmp_path):
    """NUMBA_DISABLE_JIT=1 runs the specialized module's text as Python: no marker, or the auto build of a
    later process would take a module numba never compiled (and compile it in the foreground)."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, NUMBA_DISABLE_JIT="1", VCIRUN_CACHE_DIR=str(tmp_path), VCIRUN_BUILD="auto")
    code = "import vcirun; print(vcirun.simulate('bouncing_ball', 'CVA', h=0.05, T=0.5).build)"
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split()[-1] == "None"   # (no build: nothing compiled)
    assert list((tmp_path / "kernels").glob("vk_*.py")) and not list((tmp_path / "kernels").glob("*.ready"))


def test_a_sweep_says_which_methods_runs_mix_builds():
    from types import SimpleNamespace

    from vcirun.experiments.sweep import _mixed_builds

    runs = [{"label": "CVA", "build": "shared"}, {"label": "CVA", "build": "specialized"},
            {"label": "CVA", "build": "specialized"}, {"label": "VCI", "build": "shared"}, {"label": "MCVAC"}]
    writer = SimpleNamespace(complete_runs={str(i): a for i, a in enumerate(runs)})
    assert _mixed_builds(writer) == {"CVA": {"shared": 1, "specialized": 2}}
