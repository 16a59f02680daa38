"""The interpreted and the compiled tier (vcirun.codegen.tiers): the same numbers, the choice by argument
and environment, the background compile that builds the compiled tier and the switch to it, a compile
that fails, and kills of either process at any moment.

The numbers: every golden case of bench/golden.py plus a declared reset, on both tiers, bit for bit where
the arithmetic is the same and to 1e-12 otherwise (the default suite: one case per method and per kind
of scene; the whole set is slow). The background tests run on a fresh cache (VCIRUN_CACHE_DIR in a
temporary directory) in subprocesses; they compile a module each and are slow."""
from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import vcirun
from vcirun.codegen import tiers

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "bench"))
from golden import CASES  # noqa: E402

FIELDS = ("q", "p", "H", "impacts", "impact_impulse", "contact_force")
DECLARED = ("rimless_wheel", "CVA", 0.01, 2.0, {})
QUICK = [c for c in CASES if c[0] == "cart_pendulum" and c[2] == 0.05] + [
    ("ball_in_box", "CVA", 0.01, 3.0, {"params": {"e": 0.9}}),                               # several contacts
    ("bouncing_ball", "VCI", 0.01, 3.0, {"params": {"c": 0.3}}),                             # held
    ("damped_oscillator", "MCVAC", 0.01, 5.0, {}),                                           # forced
    DECLARED]                                                                                 # declared reset


def _run(case, tier):
    s, m, h, T, kw = case
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return vcirun.simulate(s, m, h=h, T=T, tier=tier, **kw)


def _worst(a, b) -> float:
    """The largest difference of the golden fields, relative to each field's scale (0.0: the same bits)."""
    worst = 0.0
    for f in FIELDS:
        x, y = (np.asarray(getattr(t, f, np.zeros(0)), float) for t in (a, b))
        assert x.shape == y.shape, f
        if x.size and not np.array_equal(x, y, equal_nan=True):
            worst = max(worst, float(np.nanmax(np.abs(x - y))) / max(1.0, float(np.nanmax(np.abs(x)))))
    return worst


def _check_same(case):
    a, b = _run(case, "compiled"), _run(case, "interpreted")
    assert (a.tier, b.tier) == ("compiled", "interpreted")
    assert a.status == b.status and len(a.impacts) == len(b.impacts), case
    worst = _worst(a, b)
    print(case[:2], "worst relative difference", worst)
    assert worst <= 1e-12, (case, worst)
    return worst


@pytest.mark.parametrize("case", QUICK, ids=lambda c: f"{c[0]}-{c[1]}-{c[2]}")
def test_the_tiers_give_the_same_numbers(case):
    _check_same(case)


@pytest.mark.slow
@pytest.mark.parametrize("case", [c for c in CASES if c not in QUICK], ids=lambda c: f"{c[0]}-{c[1]}-{c[2]}")
def test_the_tiers_give_the_same_numbers_on_every_golden_case(case):
    _check_same(case)


def _unit_solve_band():
    """maps/linalg.py's solve_band as the unit wrote it, run as Python (no replacement)."""
    import types

    from vcirun.codegen import evaluate, units

    mod = types.ModuleType("linalg_as_written")
    mod.__dict__["njit"] = evaluate._njit
    text = units.Unit("maps/linalg.py").body.replace("from numba import njit", "")
    exec(compile(text, "linalg.py", "exec"), mod.__dict__)  # noqa: S102
    return mod.solve_band


@settings(max_examples=300, deadline=None)
@given(n=st.integers(1, 9), bw=st.integers(0, 8), seed=st.integers(0, 2**32 - 1),
       zero_col=st.booleans(), scale=st.sampled_from([1e-300, 1e-8, 1.0, 1e8, 1e300]))
def test_the_interpreted_solver_has_the_bits_of_the_units(n, bw, seed, zero_col, scale):
    """The interpreted tier's list solver (vcirun.codegen.evaluate.solve_band_lists) against the unit's
    own solve_band run as Python: the same return, solution and destroyed matrix, bit for bit, on
    banded, badly scaled and singular matrices."""
    from vcirun.codegen.evaluate import PYTHON_REPLACEMENTS, solve_band_lists

    assert PYTHON_REPLACEMENTS["solve_band"] is solve_band_lists
    bw = min(bw, n - 1)
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n + 1, n + 1)) * scale   # (larger than n: the solvers use the top-left block)
    A[np.abs(np.subtract.outer(np.arange(n + 1), np.arange(n + 1))) > bw] = 0.0
    if zero_col:
        A[:, rng.integers(n)] = 0.0
    b = rng.standard_normal(n + 1)
    A1, b1, A2, b2 = A.copy(), b.copy(), A.copy(), b.copy()
    ok1 = _unit_solve_band()(A1, b1, n, bw)
    ok2 = solve_band_lists(A2, b2, n, bw)
    assert ok1 == ok2
    assert np.array_equal(b1, b2, equal_nan=True) and np.array_equal(A1, A2, equal_nan=True)


def test_the_tier_is_asked_for_by_argument_or_environment(monkeypatch):
    monkeypatch.delenv(tiers.ENV, raising=False)
    assert tiers.requested() == "auto" and tiers.requested("Compiled") == "compiled"
    monkeypatch.setenv(tiers.ENV, "interpreted")
    assert tiers.requested() == "interpreted" and tiers.requested("auto") == "auto"
    monkeypatch.setenv(tiers.ENV, "fast")
    with pytest.raises(ValueError, match=r"^VCIRUN_TIER: 'fast' is not a tier \(use auto, interpreted or compiled\)"):
        vcirun.simulate("cart_pendulum", "CVA", h=0.05, T=0.5)
    with pytest.raises(ValueError, match=r"^tier: 3 is not a tier"):
        vcirun.simulate("cart_pendulum", "CVA", h=0.05, T=0.5, tier=3)
    monkeypatch.setenv(tiers.ENV, "interpreted")
    tr = vcirun.simulate("cart_pendulum", "CVA", h=0.05, T=0.5)
    assert tr.tier == "interpreted" and tr.ok
    assert vcirun.simulate("cart_pendulum", "CVA", h=0.05, T=0.5, tier="compiled").tier == "compiled"


def test_ensemble_and_reference_take_a_tier():
    a = vcirun.ensemble("cart_pendulum", "CVA", h=0.05, T=1.0, beta=[3.2, 4.0], tier="interpreted")
    b = vcirun.ensemble("cart_pendulum", "CVA", h=0.05, T=1.0, beta=[3.2, 4.0], tier="compiled")
    assert (a.attrs["tier"], b.attrs["tier"]) == ("interpreted", "compiled")
    assert np.array_equal(a.q_final.values, b.q_final.values)
    ra = vcirun.reference("cart_pendulum", T=2.0, beta=3.2, tier="interpreted")
    rb = vcirun.reference("cart_pendulum", T=2.0, beta=3.2, tier="compiled")
    assert np.max(np.abs(ra.impacts - rb.impacts)) <= 1e-12
    with pytest.raises(ValueError, match="^tier:"):
        vcirun.reference("cart_pendulum", T=2.0, beta=3.2, tier="jit")


# --- the background compile (fresh caches, subprocesses) --------------------------------------------

CHILD = r"""
import json, sys, time
import numpy as np
import vcirun
from vcirun.codegen import background
from vcirun.codegen.kernel_cache import default
out = []
waits = json.loads(sys.argv[1])
for i, wait in enumerate(waits):
    time.sleep(wait if wait >= 0 else 0)
    if wait < 0:   # until the background compile of the module has failed (at most -wait seconds)
        kc, t0 = default(), time.monotonic()
        key = next(iter(kc._generated))
        while background.state(kc.cache_dir(), key) != "failed" and time.monotonic() - t0 < -wait:
            time.sleep(1.0)
    tr = vcirun.simulate("cart_pendulum", "VCI", h=1e-2, T=2.0, beta=3.2)
    out.append({"tier": tr.tier, "q": tr.q.tobytes().hex(), "status": tr.status})
print(json.dumps(out))
"""


def _env(cache, **extra):
    env = dict(os.environ, VCIRUN_CACHE_DIR=str(cache), PYTHONPATH=str(ROOT))
    env.pop(tiers.ENV, None)   # (the suite's VCIRUN_TIER=compiled: these children choose their own)
    env.update(extra)
    return env


def _child(cache, waits, **extra):
    r = subprocess.run([sys.executable, "-c", CHILD, json.dumps(waits)], capture_output=True, text=True,
                       env=_env(cache, **extra), timeout=1800)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1]), r.stderr


def _info(cache) -> str:
    r = subprocess.run([sys.executable, "-m", "vcirun.cli.main", "cache", "info"], capture_output=True, text=True,
                       env=_env(cache))
    assert r.returncode == 0, r.stderr
    return r.stdout


def _wait_compiled(cache, timeout=1500.0) -> None:
    t0 = time.monotonic()
    while "compiled tier ready for" not in _info(cache):
        assert time.monotonic() - t0 < timeout, _info(cache)
        time.sleep(2.0)


def _zombies() -> list:
    """This test process's children that have exited and were not reaped."""
    out = []
    for d in Path("/proc").iterdir():
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[-1].split()
        if fields[0] == "Z" and int(fields[1]) == os.getpid():
            out.append(int(d.name))
    return out


@pytest.mark.slow
def test_first_run_is_interpreted_then_every_process_switches(tmp_path):
    cache = tmp_path / "cache"
    runs, err = _child(cache, [0.0])
    assert runs[0]["tier"] == "interpreted" and runs[0]["status"] == "ok"
    assert "runs on the interpreted tier now" in err and "being built in the background" in err, err
    assert len([l for l in err.splitlines() if "interpreted tier" in l]) == 1, err
    info = _info(cache)
    assert "being compiled:" in info or "compiled tier ready for" in info, info
    _wait_compiled(cache)
    again, err2 = _child(cache, [0.0])
    assert again[0]["tier"] == "compiled" and again[0]["q"] == runs[0]["q"]
    assert "interpreted" not in err2 and "compiling" not in err2, err2


def _tamper(cache) -> tuple:
    """Give the cached generated text of the module a statement numba cannot type (valid Python, no effect
    on the numbers) in sys_M, sealed as the cache seals it: the compiled tier fails, the interpreted one
    runs. Returns (path, original bytes)."""
    from vcirun.codegen import cache_store

    path = next((cache / "kernels").glob("vg_*.py"))
    data = path.read_bytes()
    key = path.name[3:-3]
    body, meta = cache_store.unseal_text(data, key)
    body = body.replace("def sys_M(q, prm, out):\n", "def sys_M(q, prm, out):\n    _untypable = object()\n", 1)
    meta.pop("sha256")
    path.write_text(cache_store.seal_text(body, meta))
    return path, data


@pytest.mark.slow
def test_a_failed_background_compile_leaves_the_interpreted_tier_and_says_so_once(tmp_path):
    cache = tmp_path / "cache"
    first, _ = _child(cache, [0.0], VCIRUN_TIER="interpreted")   # the kernels derived, nothing compiled
    path, original = _tamper(cache)
    runs, err = _child(cache, [0.0, -900.0, 1.0, 1.0])   # the second run once the compile has failed
    assert [r["tier"] for r in runs] == ["interpreted"] * 4 and all(r["q"] == first[0]["q"] for r in runs)
    assert err.count("the background compile of cart_pendulum/VCI[SVC] failed") == 1, err
    assert "TypingError" in err, err
    assert "background compile failed: cart_pendulum/VCI[SVC]" in _info(cache)
    again, err = _child(cache, [0.0])   # a failed compile is not started again by the next process
    assert again[0]["tier"] == "interpreted" and "failed" in err
    path.write_bytes(original)
    (cache / "kernels" / f"vk_{path.name[3:-3]}.py").unlink()
    runs, err = _child(cache, [0.0], VCIRUN_TIER="compiled")   # asked for: compiled here
    assert runs[0]["tier"] == "compiled" and runs[0]["q"] == first[0]["q"], err
    assert "background compile failed" not in _info(cache)


@pytest.mark.slow
def test_kills_of_either_process_at_random_moments_leave_the_cache_usable(tmp_path):
    """The caller or the background compile killed (SIGKILL) at random moments, three rounds each: the
    next call restarts the compile, the runs keep their numbers, no process is left a zombie, and the
    compiled tier arrives in the end."""
    cache = tmp_path / "cache"
    ref, _ = _child(cache, [0.0], VCIRUN_TIER="interpreted")
    rng = random.Random(20140527)
    for victim in ("caller", "compiler") * 3:
        p = subprocess.Popen([sys.executable, "-c", CHILD, json.dumps([0.0])], env=_env(cache),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        if victim == "caller":
            time.sleep(rng.uniform(0.5, 8.0))
            p.kill()
            p.communicate()
        else:
            out, _ = p.communicate(timeout=900)
            assert json.loads(out.strip().splitlines()[-1])[0]["q"] == ref[0]["q"]
            time.sleep(rng.uniform(0.5, 15.0))
            for line in _info(cache).splitlines():
                if line.startswith("being compiled:") and "process " in line:
                    pid = int(line.split("process ")[1].split()[0].rstrip(")"))
                    try:
                        os.kill(pid, signal.SIGKILL)
                    except ProcessLookupError:
                        pass
        assert _zombies() == []
    runs, _ = _child(cache, [0.0])   # restarts the compile if no process holds it
    _wait_compiled(cache)
    runs, err = _child(cache, [0.0])
    assert runs[0]["tier"] == "compiled" and runs[0]["q"] == ref[0]["q"], err
    time.sleep(1.0)
    assert _zombies() == []
