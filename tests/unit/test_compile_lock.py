"""vcirun.codegen.cache.first_call_lock: processes that start on the same cold module take turns at its
first call (one compiles, the others then load numba's cache), and a lock that cannot be made does
not stop the call."""
from __future__ import annotations

import multiprocessing as mp
import os
import time
import types

import pytest

from vcirun.codegen import cache


def _holder(cache_dir, log, ready, hold_s):
    os.environ["VCIRUN_CACHE_DIR"] = cache_dir
    mod = types.SimpleNamespace(__name__="vcirun_kernels_0123456789abcdef0123")
    with cache.first_call_lock(mod):
        with open(log, "a") as f:
            f.write("A in\n")
        ready.set()
        time.sleep(hold_s)
        with open(log, "a") as f:
            f.write("A out\n")


@pytest.mark.skipif(not hasattr(os, "fork"), reason="fork")
def test_second_process_waits_for_the_first(tmp_path, monkeypatch):
    monkeypatch.setenv("VCIRUN_CACHE_DIR", str(tmp_path))
    log = tmp_path / "log.txt"
    ctx = mp.get_context("fork")
    ready = ctx.Event()
    p = ctx.Process(target=_holder, args=(str(tmp_path), str(log), ready, 0.5))
    p.start()
    assert ready.wait(30)
    mod = types.SimpleNamespace(__name__="vcirun_kernels_0123456789abcdef0123")
    with cache.first_call_lock(mod):
        with open(log, "a") as f:
            f.write("B in\n")
    p.join(30)
    assert log.read_text().splitlines() == ["A in", "A out", "B in"]  # B entered only after A left


def test_other_modules_do_not_wait(tmp_path, monkeypatch):
    monkeypatch.setenv("VCIRUN_CACHE_DIR", str(tmp_path))
    a = types.SimpleNamespace(__name__="vcirun_kernels_aaaaaaaaaaaaaaaaaaaa")
    b = types.SimpleNamespace(__name__="vcirun_kernels_bbbbbbbbbbbbbbbbbbbb")
    import fcntl

    def held(m):  # is m's lock taken? (a probe on a separate descriptor)
        fd = os.open(tmp_path / "kernels" / f"vk_{m.__name__.rsplit('_', 1)[-1]}.lock", os.O_RDWR)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return False
        except BlockingIOError:
            return True
        finally:
            os.close(fd)

    with cache.first_call_lock(a):
        assert held(a)
        with cache.first_call_lock(b, timeout_s=0.0):  # another module's lock is free: taken, no wait
            assert held(b)
        assert not held(b)                              # released on leaving
        with cache.first_call_lock(a, timeout_s=0.0):  # the same module on another descriptor: gives up
            pass                                        # at once and goes ahead
    assert not held(a)


def test_unwritable_cache_goes_ahead_unlocked(tmp_path, monkeypatch):
    monkeypatch.setenv("VCIRUN_CACHE_DIR", str(tmp_path))
    from vcirun.codegen import build

    monkeypatch.setattr(build, "cache_dir", lambda: tmp_path / "no" / "such" / "dir")
    ran = []
    with cache.first_call_lock(types.SimpleNamespace(__name__="vcirun_kernels_cccccccccccccccccccc")):
        ran.append(True)
    assert ran == [True]
