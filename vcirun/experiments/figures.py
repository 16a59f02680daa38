"""Figures from a results file, in the paper's style (matplotlib, Agg backend, PNG and PDF).

- Figure 4: L2 trajectory error against beta, one curve per method and h, log axis.
- Figure 3: time evolution of H, -D3 Ld (impact steps masked) and the truncated modified
  Hamiltonian, impact times as dashed vertical lines, one panel per method.
- Figure 1: energy H(t) of the same run with and without the impact constraint.
- Work-precision: mean computation time against median L2 error per method, one point per h.

Each builder returns the paths it wrote, or raises `FigureSkipped` with the reason the results do
not support that figure (the `plot` command reports it and carries on).
"""
from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import metrics, storage

__all__ = ["FigureSkipped", "figure4", "figure3", "figure1", "work_precision", "make_figures", "plot_results",
           "PlotReport"]

# Colour per method (Okabe-Ito, colour-blind safe), line style per step size.
_COLORS = ["#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#F0E442", "#000000"]
_STYLES = ["-", "--", ":", "-."]
_MARKERS = ["o", "s", "^", "D", "v", "P"]


class FigureSkipped(Exception):
    """The results hold nothing this figure can show; str() says why."""


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    plt.rcParams.update({
        "font.family": "serif", "font.size": 9, "axes.labelsize": 10, "legend.fontsize": 8,
        "axes.linewidth": 0.8, "lines.linewidth": 1.1, "lines.markersize": 3.0, "savefig.bbox": "tight",
        "pdf.fonttype": 42, "ps.fonttype": 42,  # embed TrueType, editable text in the PDF
    })
    return plt


def _save(fig, outdir: Path, stem: str) -> list[Path]:
    outdir.mkdir(parents=True, exist_ok=True)
    paths = []
    for ext in ("png", "pdf"):
        p = outdir / f"{stem}.{ext}"
        fig.savefig(p, dpi=200 if ext == "png" else None, metadata=None if ext == "png" else {"Creator": "vcirun"})
        paths.append(p)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return paths


def _method_order(runs) -> list[str]:
    seen = {}
    for r in runs:
        seen.setdefault(r.attrs["label"], int(r.attrs.get("method_index", 0)))
    return sorted(seen, key=lambda k: seen[k])


def _fmt_h(h: float) -> str:
    m, e = f"{h:.1e}".split("e")
    m = m.rstrip("0").rstrip(".")
    return f"{m}E{int(e)}"


def figure4(results: storage.Results, outdir: Path) -> list[Path]:
    """L2 error against beta for each method and h (the paper's Figure 4)."""
    series = metrics.l2_series(results.runs)
    series = {k: v for k, v in series.items() if np.isfinite(v[1]).any()}
    if not series:
        raise FigureSkipped("no run has both a beta and an L2 error (needs beta in the config and a reference)")
    if max(len(b) for b, _ in series.values()) < 2:
        raise FigureSkipped("L2 error against beta needs at least two betas")
    plt = _pyplot()
    labels = _method_order(results.runs)
    hs = sorted({h for _, h in series}, reverse=True)
    fig, ax = plt.subplots(figsize=(6.4, 4.6), layout="constrained")
    for (label, h), (b, e) in sorted(series.items(), key=lambda kv: (labels.index(kv[0][0]), -kv[0][1])):
        i, j = labels.index(label), hs.index(h)
        ax.semilogy(b, e, color=_COLORS[i % len(_COLORS)], linestyle=_STYLES[j % len(_STYLES)],
                    marker=_MARKERS[i % len(_MARKERS)], markevery=max(1, len(b) // 12),
                    label=f"{label}, h = {_fmt_h(h)}")
        bad = ~np.isfinite(e)
        if bad.any():  # failed runs: marked on the axis rather than silently dropped
            ax.plot(b[bad], np.full(bad.sum(), np.nanmin(e[np.isfinite(e)]) if np.isfinite(e).any() else 1.0),
                    "x", color=_COLORS[i % len(_COLORS)], markersize=5)
    ax.set_xlabel(r"$\beta$")
    ax.set_ylabel(r"$L^2$ error")
    ax.grid(True, which="both", linewidth=0.3, alpha=0.5)
    # below the axes: the curves fill the whole plot, so any inside position hides some of them
    fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=min(4, len(series)),
               frameon=False)
    ax.set_title(f"{results.attrs.get('system', '')}, T = {results.attrs.get('T', '')}", fontsize=9)
    return _save(fig, outdir, "fig4_l2_error_vs_beta")


def _pick_case(runs, want) -> tuple[float, str]:
    """(h, ic_key) for single-run figures: the smallest h, the first initial condition."""
    cands = [r for r in runs if want(r)]
    if not cands:
        return None, None
    h = min(float(r.attrs["h"]) for r in cands)
    order = {}
    for r in cands:
        if float(r.attrs["h"]) == h:
            order.setdefault(r.attrs["ic_key"], int(r.attrs.get("ic_index", 0)))
    return h, min(order, key=order.get)


def figure3(results: storage.Results, outdir: Path) -> list[Path]:
    """H, -D3 Ld and the truncated modified Hamiltonian over time, one panel per MH method."""
    def want(r):
        return r.attrs.get("has_trajectory") and r.attrs.get("has_Hmod") and r.attrs.get("n_steps", 0) > 0

    h, ic = _pick_case(results.runs, want)
    if h is None:
        raise FigureSkipped("needs stored trajectories of an MCVA-family run (store_trajectories: true; "
                            "methods MCVAA, MCVAC or MCVA)")
    runs = [r for r in results.runs if want(r) and float(r.attrs["h"]) == h and r.attrs["ic_key"] == ic]
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(runs), figsize=(3.4 * len(runs), 3.0), squeeze=False, layout="constrained")
    for ax, r in zip(axes[0], runs):
        tr = storage.load_trajectory(results.path, r.run_id)
        ax.plot(tr.t, tr.H, color=_COLORS[0], label=r"$H$")
        ax.plot(tr.t, metrics.masked_discrete_energy(tr), color=_COLORS[1], linestyle="--",
                label=r"$-D_3L_d$")
        ax.plot(tr.t, tr.Hmod, color=_COLORS[2], linestyle="-.", label=r"truncated MH")
        for ti in tr.impacts:
            ax.axvline(ti, color="0.4", linestyle=(0, (4, 3)), linewidth=0.7)
        ax.set_title(f"{r.attrs['label']}" + ("" if r.attrs.get("status") == "ok" else f" [{r.attrs['status']}]"),
                     fontsize=9)
        ax.set_xlabel(r"$t$ [s]")
        ax.grid(True, linewidth=0.3, alpha=0.5)
    axes[0][0].set_ylabel("energy [J]")
    axes[0][0].legend(frameon=False)
    b = runs[0].attrs.get("beta")
    where = f"beta = {b:g}" if b is not None and np.isfinite(b) else ic
    fig.suptitle(f"{results.attrs.get('system', '')}: {where}, h = {_fmt_h(h)}", fontsize=9)
    return _save(fig, outdir, "fig3_energy_evolution")


def figure1(results: storage.Results, outdir: Path) -> list[Path]:
    """H(t) of a run with impacts against the same method without the constraint (Figure 1)."""
    def unconstrained(r):
        return (r.attrs.get("method_spec") or {}).get("constrained") is False

    def key(r):
        spec = dict(r.attrs.get("method_spec") or {})
        spec.pop("constrained", None)
        return (tuple(sorted(spec.items())), float(r.attrs["h"]), r.attrs["ic_key"])

    stored = [r for r in results.runs if r.attrs.get("has_trajectory") and r.attrs.get("n_steps", 0) > 0]
    free = {key(r): r for r in stored if unconstrained(r)}
    pairs = [(r, free[key(r)]) for r in stored if not unconstrained(r) and key(r) in free]
    if not pairs:
        raise FigureSkipped("needs stored trajectories of one method with and without its constraint "
                            "(a second method entry with options: {constrained: false})")
    pairs.sort(key=lambda p: (-float(p[0].attrs["h"]), p[0].attrs.get("method_index", 0)))
    pairs = pairs[:4]
    plt = _pyplot()
    fig, axes = plt.subplots(len(pairs), 1, figsize=(6.0, 2.6 * len(pairs)), squeeze=False, layout="constrained")
    for ax, (rc, rf) in zip(axes[:, 0], pairs):
        tc = storage.load_trajectory(results.path, rc.run_id)
        tf = storage.load_trajectory(results.path, rf.run_id)
        ax.plot(tf.t, tf.H, color=_COLORS[0], label="without impacts")
        ax.plot(tc.t, tc.H, color=_COLORS[1], label="with impacts")
        for ti in tc.impacts:
            ax.axvline(ti, color="0.4", linestyle=(0, (4, 3)), linewidth=0.7)
        # |H0| can be 0 (it depends on the zero of V), so the jump is compared with the range of H's
        # smooth oscillation in the run without impacts, the scale Figure 1 sets it against.
        jump = _largest_impact_jump(tc)
        smooth = float(np.nanmax(tf.H) - np.nanmin(tf.H)) if len(tf.H) else float("nan")
        txt = f"largest change of H over an impact step: {jump:.2g}"
        if smooth > 0:
            txt += f" = {jump / smooth:.2g} x the range of H without impacts ({smooth:.2g})"
        ax.text(0.01, 0.97, txt, transform=ax.transAxes, fontsize=7, color="0.3", va="top",
                bbox={"facecolor": "white", "edgecolor": "none", "alpha": 0.8, "pad": 1})
        ax.set_ylabel(r"$H$ [J]")
        ax.set_title(f"{rc.attrs['label']}, h = {_fmt_h(float(rc.attrs['h']))}", fontsize=9)
        ax.grid(True, linewidth=0.3, alpha=0.5)
    axes[-1, 0].set_xlabel(r"$t$ [s]")
    axes[0, 0].legend(frameon=False, loc="upper right")
    return _save(fig, outdir, "fig1_energy_with_without_impacts")


def _largest_impact_jump(tr) -> float:
    """max over impact steps k -> k+1 of |H_{k+1} - H_k| (0 without impacts)."""
    steps = np.flatnonzero(np.asarray(tr.impact_step, bool))
    steps = steps[steps + 1 < len(tr.H)]
    return float(np.max(np.abs(tr.H[steps + 1] - tr.H[steps]))) if steps.size else 0.0


def work_precision(results: storage.Results, outdir: Path) -> list[Path]:
    """Median L2 error against mean computation time, one marker per h, one line per method."""
    l2 = defaultdict(list)
    for r in results.runs:
        if r.attrs.get("status") == "ok" and r.attrs.get("l2_error") is not None:
            l2[(r.attrs["label"], float(r.attrs["h"]))].append(float(r.attrs["l2_error"]))
    stats = {(s.label, s.h): s for s in metrics.timing_stats(results.runs)}
    points = defaultdict(list)
    for (label, h), errs in l2.items():
        s = stats.get((label, h))
        if s and s.n and np.isfinite(s.mean):
            points[label].append((s.mean, float(np.median(errs)), h))
    if not points or max(len(v) for v in points.values()) < 2:
        raise FigureSkipped("work-precision needs L2 errors and timings at two or more h")
    plt = _pyplot()
    labels = _method_order(results.runs)
    fig, ax = plt.subplots(figsize=(5.0, 3.8), layout="constrained")
    for label in labels:
        pts = sorted(points.get(label, []))
        if not pts:
            continue
        i = labels.index(label)
        ax.loglog([p[0] for p in pts], [p[1] for p in pts], color=_COLORS[i % len(_COLORS)],
                  marker=_MARKERS[i % len(_MARKERS)], markersize=4, label=label)
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    # a log axis spanning less than a decade: label 1, 2, 5 x 10^k instead of colliding minor labels
    ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())
    hs = sorted({p[2] for v in points.values() for p in v}, reverse=True)
    ax.set_title("one point per h: " + ", ".join(_fmt_h(h) for h in hs) + " (larger h: less time)", fontsize=8)
    ax.set_xlabel("mean computation time per run [s]")
    ax.set_ylabel(r"median $L^2$ error")
    ax.grid(True, which="both", linewidth=0.3, alpha=0.5)
    ax.legend(frameon=False)
    return _save(fig, outdir, "work_precision")


FIGURES = {"fig4": figure4, "fig3": figure3, "fig1": figure1, "work_precision": work_precision}


def make_figures(results: storage.Results, outdir: Path, which=None) -> tuple[list[Path], dict[str, str]]:
    """Every figure the results support: (written paths, {figure: reason skipped})."""
    written, skipped = [], {}
    for name, fn in FIGURES.items():
        if which and name not in which:
            continue
        try:
            written += fn(results, Path(outdir))
        except FigureSkipped as e:
            skipped[name] = str(e)
    return written, skipped


@dataclass
class PlotReport:
    results_path: Path
    outdir: Path
    paths: list          # figures and table files written
    skipped: dict        # figure -> reason
    tables: list         # tables.Table objects (for printing)


def plot_results(results=None, outdir=None, results_dir="results") -> PlotReport:
    """`vcirun plot`: every figure and table a results file supports, written to
    <results dir>/figures/<sweep name>/ unless `outdir` is given. With no file, the newest *.h5 under
    `results_dir`."""
    from . import tables

    path = Path(results) if results is not None else storage.find_newest_results(results_dir)
    res = storage.read_results(path)
    if not res.runs:
        raise storage.StorageError(f"{path}: no complete runs to plot yet")
    outdir = Path(outdir) if outdir is not None else path.parent / "figures" / res.name
    paths, skipped = make_figures(res, outdir)
    made = []
    t1 = tables.table1()
    paths += tables.write_table(t1, outdir, "table1_methods")
    made.append(t1)
    t2 = tables.table2(res)
    paths += tables.write_table(t2, outdir, "table2_timing")
    made.append(t2)
    return PlotReport(path, outdir, paths, skipped, made)
