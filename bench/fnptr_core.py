"""Can the compiled core be shared by every scene?

    python bench/fnptr_core.py

After the C backend the per-scene cold build of a small scene is numba compiling the numeric units
(maps/, collision/) again for each scene, although with C kernels they differ between scenes only
in which kernels they call. This script measures the alternative on a toy loop: the kernels'
addresses passed as DATA (an int64 table, called through an intrinsic), so that the compiled loop
is scene-independent and numba's on-disk cache serves every scene; against the binding by
symbol name of vcirun.codegen.c_emit (numba.types.ExternalFunction, one compiled loop per scene). Fresh processes per variant
share a fresh cache directory: the second must compile nothing; with the table a third one, given
another "scene's" kernel, compiles nothing either. Prints the first call's CPU
seconds, the functions numba compiled, and ns per call of the kernel in a compiled loop.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

KERNEL_C = r"""
#include <math.h>
#include <stdint.h>
int64_t kern(double *q, double *prm, double *out) {
    out[0] = prm[0] * sin(q[0]); out[1] = prm[1] * cos(q[1]); return 0;
}
"""

CORE = r'''
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

F8P = types.CPointer(types.float64)


@intrinsic
def cptr(typingctx, arr):
    def codegen(context, builder, signature, args):
        return context.make_array(arr)(context, builder, args[0]).data
    return F8P(arr), codegen


@intrinsic
def call3(typingctx, fptr, a, b, c):
    """int64 f(double *, double *, double *) at the address fptr (an int64 value)."""
    def codegen(context, builder, signature, args):
        dp = ir.PointerType(ir.DoubleType())
        f = builder.inttoptr(args[0], ir.FunctionType(ir.IntType(64), [dp, dp, dp]).as_pointer())
        return builder.call(f, args[1:])
    return types.int64(types.int64, F8P, F8P, F8P), codegen


@njit(cache=True)
def loop_table(table, q, prm, out, N):
    acc = 0.0
    for i in range(N):
        q[0] = i * 1e-3
        call3(table[0], cptr(q), cptr(prm), cptr(out))
        acc += out[0] + out[1]
    return acc


KERN = types.ExternalFunction("kern", types.int64(F8P, F8P, F8P))


@njit(cache=True)
def loop_name(q, prm, out, N):
    acc = 0.0
    for i in range(N):
        q[0] = i * 1e-3
        KERN(cptr(q), cptr(prm), cptr(out))
        acc += out[0] + out[1]
    return acc
'''

RUN = r'''
import ctypes, json, sys, time
import numpy as np
from llvmlite import binding
from numba.core import event
compiled = set()
class L(event.Listener):
    def on_start(self, ev): compiled.add(ev.data["qualname"])
    def on_end(self, ev): pass
event.register("numba:run_pass", L())
d, variant, so = sys.argv[1], sys.argv[2], sys.argv[3]
binding.load_library_permanently(d + "/k.so")
sys.path.insert(0, d)
c0 = time.process_time()
import core
lib = ctypes.CDLL(d + "/" + so)
table = np.array([ctypes.cast(lib.kern, ctypes.c_void_p).value], dtype=np.int64)
q, prm, out = np.zeros(2), np.array([2.0, 3.0]), np.zeros(2)
f = (lambda N: core.loop_table(table, q, prm, out, N)) if variant == "table" else (lambda N: core.loop_name(q, prm, out, N))
f(10)
first = time.process_time() - c0
N = 2_000_000
c1 = time.process_time()
f(N)
per = (time.process_time() - c1) / N * 1e9
print(json.dumps({"first_call_cpu_s": first, "compiled": sorted(compiled), "ns_per_call": per, "out": out.tolist()}))
'''


def main():
    out = {}
    for variant in ("table", "name"):
        with tempfile.TemporaryDirectory(prefix="vcirun_fnptr_") as d:
            Path(d, "k.c").write_text(KERNEL_C)
            Path(d, "k2.c").write_text(KERNEL_C.replace("sin(q[0])", "tanh(q[0])"))   # "another scene"
            for k in ("k", "k2"):
                subprocess.run(["cc", "-O2", "-fPIC", "-shared", "-o", f"{d}/{k}.so", f"{d}/{k}.c", "-lm"], check=True)
            Path(d, "core.py").write_text(CORE)
            env = dict(os.environ, NUMBA_CACHE_DIR=f"{d}/nbcache")
            rows = []
            procs = [("first process", "k.so"), ("second process", "k.so")]
            if variant == "table":
                procs.append(("third process, another scene's kernel", "k2.so"))
            for proc, so in procs:
                r = subprocess.run([sys.executable, "-c", RUN, d, variant, so], capture_output=True, text=True, env=env)
                if r.returncode:
                    raise SystemExit(r.stderr[-2000:])
                rows.append(json.loads(r.stdout.strip().splitlines()[-1]))
                x = rows[-1]
                print(f"{variant:5s} {proc}: first call {x['first_call_cpu_s']:.2f} s CPU, numba compiled "
                      f"{x['compiled'] or 'nothing'}, {x['ns_per_call']:.1f} ns per loop iteration (sin + cos + call); "
                      f"last out {x['out']}")
            out[variant] = rows
    print(f"load average {os.getloadavg()[0]:.1f}")
    return out


if __name__ == "__main__":
    main()
