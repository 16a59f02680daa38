"""Plot functions are notebook-safe: they return Figures, select no backend, leave rcParams and pyplot's
figure registry alone, and write nothing; Figure 4 states its reference and shows failed runs."""
from __future__ import annotations

import matplotlib
import numpy as np
import pytest
from matplotlib.figure import Figure
from test_storage import make_traj, run_attrs, synthetic_results, write

from vcirun.experiments import figures
from vcirun.io.reader import read_results


def _snapshot():
    rc = {k: v for k, v in matplotlib.rcParams.items() if k != "backend"}
    return matplotlib.get_backend(), rc, matplotlib.rcParams["backend"]


def _same(before, after):
    assert before[0] == after[0] and before[2] == after[2]
    diff = [k for k in before[1] if before[1][k] != after[1].get(k)]
    assert not diff, diff


def test_plot_functions_leave_matplotlib_state_unchanged(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    res = read_results(synthetic_results(tmp_path))
    before = _snapshot()
    made = [figures.figure4(res), figures.figure3(res), figures.figure1(res), figures.work_precision(res.path)]
    tr = make_traj(with_hmod=True)
    made.append(tr.plot(dense=False))
    after = _snapshot()
    _same(before, after)
    assert all(isinstance(f, Figure) for f in made)
    assert list(tmp_path.iterdir()) == [tmp_path / "syn.h5"]      # nothing written
    import sys

    if "matplotlib.pyplot" in sys.modules:                       # not registered with pyplot
        assert sys.modules["matplotlib.pyplot"].get_fignums() == []
    # the style was applied locally: serif fonts inside the figure
    assert made[0].axes[0].xaxis.label.get_fontfamily() == ["serif"]


def test_cli_writer_keeps_state_too(tmp_path):
    res = read_results(synthetic_results(tmp_path))
    before = _snapshot()
    written, skipped = figures.make_figures(res, tmp_path / "fig")
    _same(before, _snapshot())
    assert len(written) == 8 and list(skipped) == ["contacts"]  # (one elastic constraint: no contacts figure)


def _legend_texts(fig):
    return [t.get_text() for lg in fig.legends + [a.get_legend() for a in fig.axes if a.get_legend()]
            for t in lg.get_texts()]


def test_figure4_marks_failures_and_names_reference(tmp_path):
    runs = {}
    betas = np.linspace(3.2, 5.2, 5)
    for mi, label in enumerate(["CVA", "MCVAC", "VCI"]):
        for bi, beta in enumerate(betas):
            status = "ok"
            if label == "MCVAC" and bi == 2:
                status = "newton_failed"
            if label == "VCI":
                status = "reset_failed"      # every run of this method failed
            tr = make_traj(with_hmod=False, beta=float(beta), seed=bi, status=status)
            attrs, arrays = run_attrs(tr, label, 1e-2, float(beta), index=mi)
            attrs["h"] = 1e-2
            attrs["l2_error"] = (1e-3 * (1 + bi)) if status == "ok" else None
            runs[f"{label}-{bi}"] = (attrs, arrays)
    path = write(tmp_path / "f4.h5", runs, root={"name": "f4", "system": "synthetic", "T": 0.4,
                                                   "config_canonical": {"reference": {"kind": "method", "method": "CVA",
                                                                                      "h": 1e-4}}})
    fig = figures.figure4(path)
    texts = _legend_texts(fig)
    assert any("MCVAC, h = 1E-2: 1 of 5 runs failed (newton_failed)" in t for t in texts), texts
    assert any("VCI, h = 1E-2: all 5 runs failed (reset_failed)" in t for t in texts), texts
    assert "reference: CVA at h = 1E-4" in fig.axes[0].get_title()
    # CVA and MCVAC share their errors here: the later one says it lies on the earlier one
    assert any("MCVAC, h = 1E-2 (on CVA, h = 1E-2)" in t for t in texts), texts


def test_work_precision_skipped_without_finite_errors(tmp_path):
    runs = {}
    for mi, label in enumerate(["CVA", "MCVAA"]):
        for h in (3.2e-2, 1e-2):
            tr = make_traj(with_hmod=False, beta=3.2)
            attrs, arrays = run_attrs(tr, label, h, 3.2, index=mi)
            attrs.update(h=h, l2_error=float("nan"))     # NaN, as a sweep without reference stores it
            runs[f"{label}-{h}"] = (attrs, arrays)
    path = write(tmp_path / "t2.h5", runs)
    with pytest.raises(figures.FigureSkipped, match="finite L2"):
        figures.work_precision(path)


def test_trajectory_plot_with_dense_output():
    import vcirun

    tr = vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=1.5, beta=3.2)
    before = _snapshot()
    fig = tr.plot()
    _same(before, _snapshot())
    assert [a.get_ylabel() for a in fig.axes] == ["y [m]", "theta [rad]", "energy [J]"]
    dense_line = fig.axes[0].lines[0]
    assert len(dense_line.get_xdata()) == 8 * (len(tr.t) - 1) + 1


def test_steps_are_written_as_the_paper_writes_them_without_losing_digits():
    from vcirun.run.plotting import fmt_h

    assert [fmt_h(h) for h in (1e-2, 3.2e-2, 2e-1, 1e-4, 1.25e-3)] == ["1E-2", "3.2E-2", "2E-1", "1E-4", "1.25E-3"]
