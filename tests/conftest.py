"""Shared fixtures: compiled modules per (system, method) and a seeded random generator.

Compiled modules are cached in-process by the default vcirun.codegen.kernel_cache.KernelCache and on
disk under $VCIRUN_CACHE_DIR (default ~/.cache/vcirun): a cold run pays numba's compile time once per
(system, kernel set); set VCIRUN_CACHE_DIR to an empty directory to measure a cold run.

The suite runs on the compiled tier (VCIRUN_TIER=compiled, unless set otherwise): its runs are sized for
compiled loops, and the tests of the interpreted tier and of the switch between the two
(tests/unit/test_tiers.py) ask for their tiers themselves. It runs the shared build
(VCIRUN_BUILD=shared, unless set otherwise): in the default auto build a module that runs HOT_S
seconds in a worker would start a specialized build in the background, which costs the suite a
compile and makes which module ran depend on the order of the tests; tests/unit/test_specialize.py
tests the auto build.
"""
from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("VCIRUN_TIER", "compiled")   # (before vcirun reads it; subprocesses inherit it)
os.environ.setdefault("VCIRUN_BUILD", "shared")


def _compiled(system, method):
    """(MechanicalSystem, compiled module, parameter vector) for a built-in name or a system."""
    from vcirun.codegen.build import load_module
    from vcirun.scenes.registry import get_scene
    from vcirun.methods.table import resolve_method

    s = get_scene(system) if isinstance(system, str) else system
    return s, load_module(s, resolve_method(method).kernel_set()), s.param_values()


@pytest.fixture(scope="session")
def compiled():
    """compiled(system, method) -> (system, module, prm); modules are memoised by vcirun itself."""
    return _compiled


@pytest.fixture
def rng():
    return np.random.default_rng(20140527)


@pytest.fixture(autouse=True)
def _build_log(request):
    """With $VCIRUN_TEST_BUILD_LOG set: one JSON line per test that generated a kernel module (its
    node id, the modules, the test's wall time), to find the tests that pay the cold builds."""
    import os

    path = os.environ.get("VCIRUN_TEST_BUILD_LOG")
    if not path:
        yield
        return
    import json
    import time

    from vcirun.codegen.kernel_cache import default

    t0 = time.perf_counter()
    with default().report() as built:
        yield
    new = [e for e in built.entries if not e["cached"]]
    if new:
        with open(path, "a") as f:
            f.write(json.dumps({"test": request.node.nodeid, "wall_s": round(time.perf_counter() - t0, 2),
                                "modules": [f"{e['system']}|{e['kernels']}" for e in new]}) + "\n")


@pytest.fixture
def warm_index_lock():
    """Held by the tests that delete or damage warm-index entries of the kernel cache or expect them
    intact (tests/unit/test_warm_start.py, test_kernel_cache.py): xdist workers, and test runs of other
    checkouts, share that cache, and one such test between another's cold and warm child fails it.
    An exclusive lock on a file named after the cache directory, so every run on one cache takes turns."""
    import fcntl
    import hashlib
    import tempfile
    from pathlib import Path

    from vcirun.codegen.kernel_cache import default

    tag = hashlib.sha256(str(default().cache_dir().resolve()).encode()).hexdigest()[:16]
    with open(Path(tempfile.gettempdir()) / f"vcirun-test-warm-index-{tag}.lock", "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)
