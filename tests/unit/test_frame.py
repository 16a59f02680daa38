"""Arrays without reference counting (vcirun.codegen.frame): borrowed views and stack
scratch compute what owned arrays compute, the unit check enforces the stack rules, and the compiled
loop allocates nothing per step (numba's own allocation counters, no timing)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from numba import njit

from vcirun.codegen import units
from vcirun.codegen.frame import borrow, keep, scratch, scratch2, scratch_i


@njit(cache=False)
def _with_frame(x, A):
    xb = borrow(x)
    xb[0] = 7.0                      # a borrowed view writes through to the owner
    n = x.shape[0]
    v = scratch(n)
    M = scratch2(n, n)
    k = scratch_i(n)
    for i in range(n):
        v[i] = x[i] * 2.0
        k[i] = i
        for j in range(n):
            M[i, j] = A[i, j] + v[i]
    s = 0.0
    for i in range(n):
        for j in range(n):
            s += M[i, j] * k[j]
    keep(x)
    return s


def test_borrow_and_scratch_compute_as_owned_arrays():
    x = np.arange(1.0, 5.0)
    A = np.arange(16.0).reshape(4, 4)
    s = _with_frame(x, A)
    assert x[0] == 7.0
    want = ((A + 2.0 * x[:, None]) * np.arange(4)[None, :]).sum()
    assert s == want


def test_borrow_of_a_tuple_keeps_every_array():
    @njit(cache=False)
    def f(t):
        b = borrow(t)
        b[0][0] = 1.5
        b[1][1, 1] = 2.5
        return b[0].shape[0] + b[1].shape[1]

    a, B = np.zeros(3), np.zeros((2, 4))
    assert f((a, B)) == 7 and a[0] == 1.5 and B[1, 1] == 2.5


@pytest.mark.parametrize("src, msg", [
    ('@njit(inline="always")\ndef f(n):\n    a = scratch(n)\n', "in an inline function"),
    ("def f(n):\n    for i in range(3):\n        a = scratch(n)\n", "inside a loop"),
    ("def f(n):\n    while n:\n        if n > 1:\n            a = scratch2(n, n)\n", "inside a loop"),
    ("def f(n):\n    a = scratch_i(n)\n    return 1, a\n", "returns the stack array a"),
])
def test_check_frame_refuses_what_would_break_the_stack(src, msg):
    with pytest.raises(units.ContractError, match=msg):
        units.check_frame(src)


def test_every_unit_keeps_the_stack_rules():
    for u in units.UNITS:
        units.check_frame(u.text, u.path)


_COUNT = textwrap.dedent("""
    import json, sys, warnings
    import vcirun
    from numba.core.runtime import rtsys
    warnings.simplefilter("ignore")
    out = {}
    for method, scene, kw, Ts in json.loads(sys.argv[1]):
        vcirun.simulate(scene, method, h=0.01, T=0.05, **kw)      # compile / load, and warm
        counts = []
        for T in Ts:
            a0 = rtsys.get_allocation_stats().alloc
            tr = vcirun.simulate(scene, method, h=0.01, T=T, **kw)
            counts.append((rtsys.get_allocation_stats().alloc - a0, int(tr.impacts.size)))
        out[method + ":" + scene] = counts
    print(json.dumps(out))
""")


def test_the_loop_allocates_nothing_per_step():
    """numba's allocation counter (NUMBA_NRT_STATS) over a run of 10 and one of 60 smooth steps: the
    same count, so no step allocates (heap scratch would cost 5 allocations per CVA step in the
    step's Newton scratch, 2 more per step for H). Energies on (the default)."""
    cases = [["CVA", "cart_pendulum", {"beta": 3.2}, [0.1, 0.6]],
             ["VCI", "cart_pendulum", {"beta": 3.2}, [0.1, 0.6]]]
    env = dict(os.environ, NUMBA_NRT_STATS="1")
    r = subprocess.run([sys.executable, "-c", _COUNT, json.dumps(cases)], capture_output=True, text=True, env=env,
                       timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    for key, ((short, imp_short), (long, imp_long)) in out.items():
        assert imp_short == imp_long == 0, key       # smooth steps only (the first impact is at t = 0.73)
        assert long == short, f"{key}: {short} allocations for 10 steps, {long} for 60"
