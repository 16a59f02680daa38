"""The floor of a `vcirun.simulate` call in its present design, against the hand-written loop of
bench/handwritten_cva.py (cart-pendulum CVA, T = 5, h = 1e-2, beta = 3.2, the scene's generated
kernels), medians of interleaved calls; printed, never asserted:

    python bench/call_floor.py [calls]

"floor": only what a kept plan's run cannot skip -- a copy of the start, its two compiled calls
(M(q0) for the Legendre transform, phi(q0) for admissibility), the loop buffers, the loop, the
records taken by count and `Trajectory.of_run` with the fields that follow from the call left to
their first read (vcirun.run.api._Derive); "simulate": the whole call. The difference is what the
call's checks, messages and dicts cost (the argument checks of the kept plan, the start's
validation, the status and message, the energies' finiteness)."""
from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import handwritten_cva as hw  # noqa: E402
import vcirun  # noqa: E402
from vcirun.codegen.kernel_cache import default  # noqa: E402
from vcirun.core import record  # noqa: E402
from vcirun.run.api import _Derive  # noqa: E402
from vcirun.run.plan import Buffers, take  # noqa: E402
from vcirun.run.trajectory import Trajectory  # noqa: E402


def main(calls: int = 1000) -> dict:
    def call():
        return vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=5.0, beta=3.2)

    tr = call()
    p = next(iter(default().plans.values()))
    mod = p.module()
    prm0, q0s, p0s = p.params(None), tr.q[0].copy(), tr.p[0].copy()
    n, m = q0s.shape[0], int(mod.NCON)
    buf, names = Buffers(keep_grid=False), record.COUNTERS

    def floor():
        prm, q0, p0 = prm0.copy(), q0s.copy(), p0s.copy()
        mod.mass_matrix_ok(q0, prm, np.empty((n, n)))
        mod.sys_phis(q0, prm, np.empty(m))
        silent, own, records = p.rows(mod)
        out = buf.get(p.N, n, m, record.impact_capacity(p.N), silent)
        info = np.zeros(len(names), np.int64)
        t = time.perf_counter()
        mod.integrate(q0, p0, 0.0, p.h, p.N, prm, p.settings, out, info)
        wall = time.perf_counter() - t
        counters = dict(zip(names, info.tolist()))
        arrays = take(out, counters, False, own, records)
        arrays.update(method="CVA", wall_time=wall, status="ok")
        return Trajectory.of_run(arrays, _Derive((p, mod, prm, counters, m, None)))

    args = hw.setup()
    hand_loop = hw.kernel_integrate(hw.vcirun_module())
    hand_loop(*args)
    res = {}
    for name, f in (("floor", floor), ("simulate", call)):
        hand, wall, whole, _ = hw.interleaved(f, hand_loop, args, calls, warm=100)
        h, c, w = (statistics.median(x) * 1e6 for x in (hand, whole, wall))
        res[name] = {"hand_us": h, "call_us": c, "ratio": c / h, "outside_us": c - w}
        print(f"{name:8s}: hand-written loop {h:.1f} us, call {c:.1f} us = x{c / h:.2f}, outside the compiled loop "
              f"{c - w:.1f} us")
    return res


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 1000)
