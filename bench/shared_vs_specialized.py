"""The shared build against the specialized build: same runs, both builds, one process.

    PYTHONPATH=. python bench/shared_vs_specialized.py [--repeats 101] [--systems ...] [--methods ...]

For each (system, method, h): the trajectory of each build (max |dq|, |dp| between them: the kernels
are the same compiled code, the loop the same source) and the loop time (`Trajectory.wall_time`,
builds interleaved, medians and the median of the paired ratios shared / specialized).
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np


def run(system, method, h, mode, T=5.0):
    os.environ["VCIRUN_BUILD"] = mode.split("+")[0]
    os.environ["VCIRUN_CORE_NDOF"] = "fixed" if mode.endswith("+n") else ""
    import vcirun

    kw = {"beta": 3.2} if system == "cart_pendulum" else {}
    return vcirun.simulate(system, method, h=h, T=T, energies=False, **kw)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--systems", default="cart_pendulum,double_pendulum")
    ap.add_argument("--methods", default="CVA,VCI,MCVAA,MCVAC,CVA6")
    ap.add_argument("--h", default="0.01,0.032")
    ap.add_argument("--repeats", type=int, default=101)
    ap.add_argument("--shared", default="shared", help="shared, or shared+n (VCIRUN_CORE_NDOF=fixed)")
    a = ap.parse_args(argv)
    print(f"{time.strftime('%Y-%m-%d %H:%M:%S')} load {os.getloadavg()[0]:.1f}")
    print("| system | method | h | specialized us | shared us | shared/specialized (median of pairs) | max dq, dp |")
    print("|---|---|---|---|---|---|---|")
    for system in a.systems.split(","):
        for method in a.methods.split(","):
            for h in map(float, a.h.split(",")):
                s, c = run(system, method, h, "specialized"), run(system, method, h, a.shared)
                dq = float(np.abs(s.q - c.q).max()) if s.q.shape == c.q.shape else float("inf")
                dp = float(np.abs(s.p - c.p).max()) if s.p.shape == c.p.shape else float("inf")
                ts, tc, r = [], [], []
                for i in range(a.repeats):
                    order = ("specialized", a.shared) if i % 2 else (a.shared, "specialized")
                    w = {m: run(system, method, h, m).wall_time for m in order}
                    ts.append(w["specialized"]); tc.append(w[a.shared]); r.append(w[a.shared] / w["specialized"])
                same = "bit for bit" if dq == 0 and dp == 0 else f"{dq:.1e}, {dp:.1e}"
                print(f"| {system} | {method} | {h:g} | {1e6 * np.median(ts):.0f} | {1e6 * np.median(tc):.0f} | "
                      f"{np.median(r):.3f} | {same} |", flush=True)
    print(f"load {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
