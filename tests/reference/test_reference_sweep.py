"""The reference in a sweep: per initial condition its status, integration path and accuracy are stored;
the runs of an initial condition whose reference failed (it raised, or its accuracy is not finite) get a
NaN L2 error and a note that says why, never a number."""
from __future__ import annotations

import math

import numpy as np
import pytest

import vcirun
from vcirun.experiments.config import load_config
from vcirun.experiments.sweep import run_sweep
from vcirun.reference_solution import exact as rx

CONFIG = """\
name: refs
system: cart_pendulum
methods: [CVA]
h: [2.0e-2]
beta: [3.2, 4.2]
T: {T}
timing_repeats: 1
workers: 1
reference: {kind: exact, rtol: 1.0e-13}
"""


def _sweep(tmp_path, T=1.0):
    """The sweep's results (T differs per test: a worker keeps the references of an identical config)."""
    p = tmp_path / "refs.yaml"
    p.write_text(CONFIG.replace("{T}", str(T)))
    run_sweep(load_config(p), config_path=p, output=tmp_path / "refs.h5", workers=1, progress=False)
    return vcirun.open_results(tmp_path / "refs.h5")


def test_reference_kind_accuracy_and_status_are_stored(tmp_path):
    ds = _sweep(tmp_path)
    assert list(ds.reference_status.values) == ["ok", "ok"]
    assert list(ds.reference_path.values) == ["taylor", "taylor"]
    acc = ds.reference_accuracy.values
    assert np.all(np.isfinite(acc)) and np.all(acc <= 1e-12)
    assert np.all(np.isfinite(ds.l2_error.values))
    assert "Taylor (heyoka)" in ds.attrs["reference"]


@pytest.mark.parametrize("how", ["raises", "nan accuracy"])
def test_runs_against_a_failed_reference_have_nan_errors_and_say_why(tmp_path, monkeypatch, how):
    real = rx.solve_exact

    def flaky(sysm, q0, p0, prm, T, **kw):
        ref = real(sysm, q0, p0, prm, T, **kw)
        if abs(q0[0] - 4.2) < 1e-12 and T > 0.5:   # beta = 4.2 (the preflight's short solve passes)
            if how == "raises":
                raise RuntimeError("reference: a solve that fails for this test")
            ref.accuracy = math.nan
        return ref

    monkeypatch.setattr(rx, "solve_exact", flaky)
    ds = _sweep(tmp_path, T=0.9 if how == "raises" else 0.8)
    assert list(ds.reference_status.values) == ["ok", "failed"]
    assert list(ds.reference_path.values) == ["taylor", ""]
    l2 = ds.l2_error.values.ravel()
    note = [str(x) for x in ds.l2_note.values.ravel()]
    assert np.isfinite(l2[0]) and math.isnan(l2[1])
    assert note[0] == "" and note[1].startswith("reference failed: ")
    assert ("fails for this test" if how == "raises" else "accuracy is nan") in note[1]
    assert list(ds.status.values.ravel()) == ["ok", "ok"]       # the runs themselves are fine
    assert "1 failed" in ds.attrs["reference"]
