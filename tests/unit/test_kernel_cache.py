"""The kernel cache as one object (vcirun.codegen.kernel_cache): what a call built is its report, each
KernelCache has its own memory, a substitute loader is a parameter, and the modules that load
kernels keep no mutable state at module level (counted by tests/module_state.py)."""
from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import vcirun
from vcirun.codegen.kernel_cache import BuildReport, KernelCache, default, of

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from module_state import mutable_containers  # noqa: E402

PKG = Path(vcirun.__file__).resolve().parent


def test_the_counter_finds_mutated_containers_only(tmp_path):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "a.py").write_text(textwrap.dedent("""
        import threading
        __all__ = ["f"]
        NAMES = ["x", "y"]            # read only
        _memo = {}                    # item assignment
        LOG: list = []                # append through the module name, from b.py
        _seen = set()                 # never mutated
        _local = threading.local()    # attribute assignment
        def f(k):
            _memo[k] = NAMES[0]
            _local.v = k
            return k in _seen
        """))
    (pkg / "b.py").write_text("from . import a\n\ndef g():\n    a.LOG.append(1)\n    del a._memo['x']\n")
    assert [n for _, n in mutable_containers(pkg)] == ["LOG", "_local", "_memo"]


def test_modules_that_load_kernels_hold_no_module_level_state():
    owned = {PKG / p for p in ("codegen/build.py", "codegen/modules.py", "codegen/kernel_cache.py", "codegen/cache.py",
                               "codegen/compile_notes.py", "codegen/cache_lock.py", "codegen/tiers.py",
                               "codegen/background.py", "codegen/compile_worker.py", "run/resolve.py",
                               "run/plan.py")}
    found = [(p.relative_to(PKG).as_posix(), n) for p, n in mutable_containers(PKG) if p in owned]
    assert found == [], found


def test_a_report_holds_the_loads_of_its_block_and_a_new_cache_is_a_new_process(warm_index_lock):
    vcirun.simulate("cart_pendulum", "CVA", h=2e-2, T=1.0, beta=3.2)   # compiled and indexed (once per cache)
    kc = KernelCache()
    assert not kc.loaded and not kc.plans and not kc.warm_hits
    with kc.report() as first:
        a = vcirun.simulate("cart_pendulum", "CVA", h=2e-2, T=1.0, beta=3.2, loader=kc)
    assert [(e["system"], e["cached"], e["warm_index"]) for e in first.entries] == [("cart_pendulum", True, True)]
    assert not first.compiled and first.generated == 0
    with kc.report() as second:
        b = vcirun.simulate("cart_pendulum", "CVA", h=2e-2, T=1.0, beta=3.2, loader=kc)
    assert second.entries == [] and len(kc.plans) == 1   # loaded and planned already: nothing loaded again
    assert np.array_equal(a.q, b.q) and np.array_equal(a.p, b.p)
    assert BuildReport([{"cached": True, "core_cold": True}]).compiled


def test_the_loader_argument():
    assert of(None) is default()
    kc = KernelCache()
    assert of(kc) is kc
    fn = lambda s, k: None  # noqa: E731
    assert of(fn).loader is fn and not of(fn).warm and of(fn) is not of(fn)
    with pytest.raises(ValueError, match="^loader: expected a KernelCache or a function"):
        of(3)
