"""The C backend of the generated kernels (vcirun.codegen.c_emit, vcirun.codegen.cc).

1. Every translated kernel computes the same bits as its numba source executed as Python, at random
   arguments, for the system, step and modified-Hamiltonian kernels of several scenes (one forced).
2. What the translator does not cover stays numba source, with the reason.
3. No compiler (or a failing one): the module is numba source.
4. In a fresh process a module with C kernels is loaded from numba's on-disk cache without one
   numba compilation (the callers reference the C symbols by name), and the C and the numba
   backends give the same trajectories.
"""
from __future__ import annotations

import ctypes
import json
import os
import subprocess
import sys
import textwrap
import types

import numpy as np
import pytest

from vcirun.codegen import c_emit, c_link, c_translate, cc, derive
from vcirun.codegen.build import _PKG
from vcirun.scenes.registry import get_scene
from vcirun.methods.table import resolve_method

pytestmark = pytest.mark.skipif(cc.compiler() is None, reason="no C compiler")

CASES = [("cart_pendulum", "CVA"), ("cart_pendulum", "MCVAC"), ("cart_pendulum", "MCVAA"), ("double_pendulum", "VCI"),
         ("n_pendulum_3", "MCVAC"), ("damped_oscillator", "SVC"), ("double_pendulum", "midpoint")]


def _generated(system, method):
    """The generated part of the module text (kernels, dispatchers, constants), numba source."""
    s = get_scene(system)
    ks = resolve_method(method).kernel_set()
    return derive.generated_source(s, ks), s


def _python(text: str):
    mod = types.ModuleType("vk_python")
    mod.__dict__["njit"] = lambda *a, **k: (a[0] if a and callable(a[0]) else (lambda f: f))
    exec(compile(text.replace("from numba import njit", ""), "vk_python", "exec"), mod.__dict__)
    return mod


@pytest.mark.parametrize("system,method,segment", [c + (None,) for c in CASES] + [("n_pendulum_3", "MCVAC", 15)])
def test_c_kernels_equal_their_numba_source(system, method, segment, tmp_path, rng, monkeypatch):
    """(segment: split every kernel longer than 2 x 15 statements into chained functions)"""
    if segment:
        monkeypatch.setattr(c_translate, "SEGMENT_LINES", segment)
    text, s = _generated(system, method)
    tr = c_emit.translate_module(text, salt="test")
    assert {"sys_M", "sys_node"} <= {k.name for k in tr.kernels}
    if method.startswith("MCVA"):
        assert {"mh_FA", "mh_value", "mh_grad", "mh_hess"} <= {k.name for k in tr.kernels}
    if segment:
        assert "_s1(" in tr.c_source(next(k for k in tr.kernels if k.name == "mh_grad"))
    so = cc.compile_shared(tr.units(cc.opt_level), tmp_path / "k.so")
    lib = ctypes.CDLL(str(so))
    py = _python(text)
    n = s.n
    size = 8 * n * n + 64   # every array argument at least as long as any kernel indexes
    for k in tr.kernels:
        fn = getattr(lib, tr.prefix + k.name)
        fn.restype = ctypes.c_double if k.returns == "double" else ctypes.c_int64
        for trial in range(3):
            pyargs, cargs, outs = [], [], []
            for a, kind in k.args:
                if kind in ("s", "-"):
                    x = float(rng.uniform(-1.0, 1.0)) if a != "h" else [0.0, 0.013, -0.07][trial]
                    pyargs.append(x)
                    if kind == "s":
                        cargs.append(ctypes.c_double(x))
                    continue
                shape = (size,) if kind == "1" else (4 * n, 4 * n)
                arr = rng.uniform(-1.0, 1.0, shape)
                if a in ("W",):  # symmetric, as W = A^-1 is
                    arr = 0.5 * (arr + arr.T)
                if a == "prm":
                    arr = np.abs(arr) + 0.5   # masses, lengths > 0
                pa, ca = arr.copy(), arr.copy()
                pyargs.append(pa)
                outs.append((pa, ca))
                cargs.append(ca.ctypes.data_as(ctypes.POINTER(ctypes.c_double)))
                if kind == "2":
                    cargs.append(ctypes.c_int64(arr.shape[1]))
            rp = getattr(py, k.name)(*pyargs)
            rc = fn(*cargs)
            if k.returns == "double":
                assert (rp == rc) or (np.isnan(rp) and np.isnan(rc)), f"{k.name}: {rp!r} != {rc!r}"
            for pa, ca in outs:
                same = (pa == ca) | (np.isnan(pa) & np.isnan(ca))
                assert same.all(), f"{k.name}: outputs differ by up to {np.nanmax(np.abs(pa - ca)):.3g}"


def test_unsupported_constructs_stay_numba():
    text = textwrap.dedent('''
        NDOF = 2


        @njit(cache=True, nogil=True, error_model="numpy")
        def leaf(q, prm, out):
            a = math.sin(q[0]) * prm[1]
            for k in range(NDOF):
                out[k] = a * k
            return 0


        @njit(cache=True, nogil=True, error_model="numpy")
        def caller(q, prm, out):
            leaf(q, prm, out)
            return 0


        @njit(cache=True, nogil=True, error_model="numpy")
        def pair(q, prm):
            a, b = q[0], q[1]
            return a + b


        @njit(cache=True, nogil=True, error_model="numpy", inline="always")
        def dispatcher(sid, q, prm, out):
            return 0
        ''')
    tr = c_emit.translate_module(text)
    assert [k.name for k in tr.kernels] == ["leaf"]
    assert set(tr.skipped) == {"caller", "pair"}
    new = c_link.replace_kernels(text, tr, "x.so", "0" * 64)
    assert "def caller(q, prm, out):\n    leaf(q, prm, out)" in new
    assert f"ExternalFunction({tr.prefix + 'leaf'!r}" in new
    assert new.count("_bind(__file__, 'x.so'") == 1


def test_no_compiler_means_numba_source(monkeypatch, tmp_path):
    s = get_scene("cart_pendulum")
    ks = resolve_method("CVA").kernel_set()
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    assert cc.compiler() is None and cc.backend() == "numba" and cc.identity() == "numba"
    text = derive.module_source(s, ks, c_dir=tmp_path)
    assert "ExternalFunction" not in text and not list(tmp_path.glob("*.so"))
    monkeypatch.setenv(cc.BACKEND_ENV, "c")
    with pytest.raises(ValueError, match="VCIRUN_KERNEL_BACKEND=c but no C compiler"):
        cc.backend()
    monkeypatch.setenv(cc.BACKEND_ENV, "fortran")
    with pytest.raises(ValueError, match="VCIRUN_KERNEL_BACKEND: unknown kernel backend 'fortran'"):
        cc.backend()


def test_small_kernels_stay_numba_and_large_ones_go_to_c(monkeypatch, tmp_path):
    s = get_scene("cart_pendulum")
    text = derive.module_source(s, resolve_method("MCVAC").kernel_set(), [], c_dir=tmp_path)
    assert "ExternalFunction('vkc_" in text and len(list(tmp_path.glob("*.so"))) == 1
    small = [k.name for k in c_emit.translate_module(text[:text.index("\nfull = ")]).kernels]
    assert "mh_grad" not in small   # already bound to C in `text`
    entry = c_link.C_LOG[-1]
    assert "mh_grad" in entry["c"] and "SVC_PmJc" in entry["numba"] and "below" in entry["numba"]["SVC_PmJc"]
    monkeypatch.setenv(cc.C_MIN_ENV, "many")
    with pytest.raises(ValueError, match="VCIRUN_C_MIN_STATEMENTS: expected a number of statements"):
        cc.min_statements()


def test_failing_compiler_falls_back_to_numba(monkeypatch, tmp_path):
    s = get_scene("cart_pendulum")
    ks = resolve_method("CVA").kernel_set()
    monkeypatch.setenv(cc.C_MIN_ENV, "0")
    monkeypatch.setenv("CC", "false")   # found on PATH, fails every call
    assert cc.backend() == "c"
    with pytest.warns(RuntimeWarning, match="the kernels stay in numba"):
        text = derive.module_source(s, ks, c_dir=tmp_path)
    assert "ExternalFunction" not in text and not list(tmp_path.glob("*.so"))


_RUN = """
import json, sys
import numpy as np
from numba.core import event
import vcirun
from vcirun.codegen import build
from vcirun.codegen.kernel_cache import default
compiles = set()   # functions numba compiled (a load from its cache runs no compiler pass)
class L(event.Listener):
    def on_start(self, ev): compiles.add(ev.data["qualname"])
    def on_end(self, ev): pass
event.register("numba:run_pass", L())
with default().report() as built:
    tr = vcirun.simulate("oscillator_wall", "CVA", h=0.05, T=3.0)
entry = built.entries[-1]
mod = default().loaded[entry["key"]]
mod.mass_matrix_ok(tr.q[0], np.array([1.0, 1.0, 0.5]), np.empty((1, 1)))  # (the warm path's check: compiled too)
text = (build.cache_dir() / ("vk_" + entry["key"] + ".py")).read_text()
print(json.dumps({"q": tr.q.ravel().tolist(), "p": tr.p.ravel().tolist(), "impacts": len(tr.impacts),
                  "compiles": sorted(compiles), "cached": entry["cached"],
                  "c_kernels": text.count("ExternalFunction(")}))
"""


def _run(cache, **env):
    e = dict(os.environ, VCIRUN_CACHE_DIR=str(cache), **env)
    r = subprocess.run([sys.executable, "-c", _RUN], env=e, capture_output=True, text=True, cwd=str(_PKG.parent))
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.mark.slow  # two cold builds in fresh processes (~80 s cold); `make test-all`
def test_c_module_is_cached_across_processes_and_matches_numba(tmp_path):
    cold = _run(tmp_path / "c", VCIRUN_C_MIN_STATEMENTS="0")   # every leaf kernel in C (they are small)
    warm = _run(tmp_path / "c", VCIRUN_C_MIN_STATEMENTS="0")
    assert cold["c_kernels"] >= 5 and "integrate" in cold["compiles"] and not cold["cached"]
    assert warm["cached"] and warm["compiles"] == [], f"numba recompiled {warm['compiles']} in a new process"
    assert warm["q"] == cold["q"] and warm["p"] == cold["p"] and cold["impacts"] > 0
    nb = _run(tmp_path / "numba", VCIRUN_KERNEL_BACKEND="numba")
    assert nb["c_kernels"] == 0
    assert nb["impacts"] == cold["impacts"]
    np.testing.assert_allclose(nb["q"], cold["q"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(nb["p"], cold["p"], rtol=0, atol=1e-12)
