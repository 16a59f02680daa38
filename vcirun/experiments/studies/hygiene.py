"""Floating-point hygiene: the whole loop run uncompiled (NUMBA_DISABLE_JIT=1) inside
np.errstate(all="raise"), so any overflow / invalid operation / division by zero raises.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time

__all__ = ["hygiene_case"]

_HYGIENE_SCRIPT = r"""
import json, sys, numpy as np, vcirun
cases = json.loads(sys.argv[1])
out = []
# positive control: the check is live (an overflow inside the uncompiled loop code raises)
from vcirun.run.resolve import resolve_system
from vcirun.codegen.build import load_module
from vcirun.codegen.kernel_set import SYSTEM_KERNELS
s = resolve_system("cart_pendulum"); mod = load_module(s, SYSTEM_KERNELS)
with np.errstate(all="raise"):
    try:
        mod.hamiltonian(np.array([0.0, 0.0]), np.array([1e200, 1e200]), s.param_values())
        control = "no exception"
    except FloatingPointError as e:
        control = "FloatingPointError: " + str(e)
for c in cases:
    rec = dict(c)
    try:
        with np.errstate(all="raise"):
            tr = vcirun.simulate(c["system"], c["method"], h=c["h"], T=c["T"], **c.get("kw", {}))
            rec["status"] = tr.status
            rec["impacts"] = int(len(tr.impacts))
            rec["finite"] = bool(np.all(np.isfinite(tr.q)) and np.all(np.isfinite(tr.p)) and np.all(np.isfinite(tr.H)))
        if c.get("reference"):
            # scipy's solve_ivp takes nextafter(0, inf), a subnormal, at t = 0: underflow there is by design
            with np.errstate(all="raise", under="ignore"):
                ref = vcirun.reference(c["system"], T=c["T"], **c.get("kw", {}))
                rec["l2"] = vcirun.l2_error(tr, ref)
    except Exception as e:
        rec["status"] = "raised " + type(e).__name__ + ": " + str(e)
    out.append(rec)
print(json.dumps({"control": control, "cases": out}))
"""


def hygiene_case(cases, *, timeout=600.0) -> dict:
    """Run each {'system', 'method', 'h', 'T', 'kw', 'reference'} with NUMBA_DISABLE_JIT=1 in a fresh
    interpreter inside np.errstate(all="raise"): every kernel, Newton iteration, event search and
    reset then executes as numpy scalar arithmetic, so a hidden overflow, invalid operation or
    division by zero raises FloatingPointError. Includes a positive control (an overflow that must
    raise). The compiled path uses the same source, so its arithmetic is what was checked."""
    # the numba kernel backend: C kernels are called through numba intrinsics, which do not run
    # uncompiled (the C backend's arithmetic is the same expressions, emitted as C)
    env = dict(os.environ, NUMBA_DISABLE_JIT="1", VCIRUN_KERNEL_BACKEND="numba")
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", _HYGIENE_SCRIPT, json.dumps(cases)], capture_output=True, text=True,
                       env=env, timeout=timeout)
    if p.returncode != 0:
        return {"error": p.stderr[-2000:], "cases": [], "control": ""}
    res = json.loads(p.stdout.strip().splitlines()[-1])
    res["wall_time"] = time.perf_counter() - t0
    return res
