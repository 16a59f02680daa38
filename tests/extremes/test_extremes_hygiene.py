"""Floating-point hygiene: the normal scenes raise no hidden floating-point error.

Two levels:
  * the Python side (simulate's bookkeeping, the exact reference with DOP853, the L2 error) inside
    np.errstate(all="raise") with the compiled loop, every method, both paper scenes;
  * the whole loop *uncompiled* (NUMBA_DISABLE_JIT=1, a fresh interpreter) inside
    np.errstate(all="raise"): every kernel, Newton iteration, collision-time search and reset then
    runs as numpy scalar arithmetic, so an overflow, invalid operation or division by zero
    anywhere raises FloatingPointError. A positive control (H at p = 1e200 must overflow) shows the
    check is live. The compiled path runs the same source.
"""
from __future__ import annotations

import numpy as np
import pytest

import vcirun
from vcirun.experiments.studies.hygiene import hygiene_case

METHODS = ["CVA", "VCI", "MCVAA", "MCVAC"]


@pytest.mark.parametrize("method", METHODS)
def test_python_side_raises_nothing(method):
    for scene, kw, T in (("cart_pendulum", dict(beta=3.2), 1.5), ("double_pendulum", {}, 2.5)):
        with np.errstate(all="raise"):
            tr = vcirun.simulate(scene, method, h=1e-2, T=T, **kw)
        assert tr.status == "ok" and len(tr.impacts) >= 1
        assert np.all(np.isfinite(tr.q)) and np.all(np.isfinite(tr.p)) and np.all(np.isfinite(tr.H))
        assert np.all(np.isfinite(tr.Ed))
        if tr.Hmod is not None:
            assert np.all(np.isfinite(tr.Hmod))
        # scipy's solve_ivp takes nextafter(0, inf), a subnormal, at t = 0: that underflow is by design
        with np.errstate(all="raise", under="ignore"):
            ref = vcirun.reference(scene, T=T, **kw)
            assert vcirun.l2_error(tr, ref) < 0.05


def _assert_clean(res, n):
    assert "error" not in res, res.get("error")
    assert res["control"].startswith("FloatingPointError"), res["control"]   # the check is live
    assert len(res["cases"]) == n
    for c in res["cases"]:
        assert c["status"] == "ok", c
        assert c["finite"] and c["impacts"] >= 1, c


def test_uncompiled_loop_raises_nothing_cva_vci():
    cases = [{"system": s, "method": m, "h": h, "T": T, "kw": kw, "reference": s == "cart_pendulum"}
             for s, h, T, kw in (("cart_pendulum", 0.02, 1.5, {"beta": 3.2}), ("double_pendulum", 0.02, 2.5, {}),
                                 ("oscillator_wall", 0.1, 5.0, {}))
             for m in ("CVA", "VCI")]
    res = hygiene_case(cases)
    _assert_clean(res, len(cases))
    for c in res["cases"]:
        if "l2" in c:
            assert c["l2"] < 0.05


def test_uncompiled_loop_raises_nothing_mcva():
    cases = [{"system": s, "method": m, "h": 0.02, "T": T, "kw": kw}
             for s, T, kw in (("cart_pendulum", 1.5, {"beta": 3.2}), ("double_pendulum", 2.5, {}))
             for m in ("MCVAA", "MCVAC")]
    _assert_clean(hygiene_case(cases), len(cases))
