"""Figures from a results file (or a Trajectory), in the paper's style.

- Figure 4: L2 trajectory error against beta, one curve per method and h, log axis; the reference
  used is stated, failed runs are marked at the bottom of the axes and listed in the legend.
- Figure 3: time evolution of H, -D3 Ld (impact steps masked) and the truncated modified
  Hamiltonian (its truncation order mh_order in the legend), impact times as dashed vertical lines,
  one panel per method, one shared y axis.
- Figure 1: energy H(t) of the same run with and without the impact constraint.
- Work-precision: mean computation time against median L2 error per method, one point per h.
- Contacts: energy H(t) against time, one panel per method (several constraints or restitution < 1),
  the run at the smallest h, impacts as vertical lines coloured by contact (the results
  file's constraint names), held phases (resting contact) shaded.
(`Trajectory.plot()` draws one run: `vcirun.run.plotting.trajectory_figure`.)

Notebook safety: every builder returns a `matplotlib.figure.Figure` that is not registered with
pyplot, built inside a local `matplotlib.rc_context`; nothing here selects a backend or changes
global rcParams, so Jupyter's inline plots are unaffected (shown by displaying the returned Figure;
in a script call `fig.savefig(...)`). Files are written only for the CLI (`vcirun plot`), by
`save_figure` / `make_figures` / `plot_results`. A builder raises `FigureSkipped` with the reason the
results do not support its figure.
"""
from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..run.plotting import COLORS, LINE_STYLES, MARKERS, fmt_h, new_figure, style, styled
from ..io.results import reference_note
from ..run.trajectory_files import masked_discrete_energy
from . import metrics
from ..io.errors import StorageError
from ..io.reader import Results, find_newest_results, load_trajectory, read_results

__all__ = ["FigureSkipped", "figure4", "figure3", "figure1", "work_precision", "contacts_energy", "make_figures",
           "plot_results", "PlotReport", "save_figure"]


class FigureSkipped(Exception):
    """The results hold nothing this figure can show; str() says why."""


def save_figure(fig, outdir: Path, stem: str) -> list[Path]:
    """Write `fig` as <outdir>/<stem>.png and .pdf (for the CLI)."""
    import matplotlib

    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    paths = []
    with style():
        # the tight box once for both files (in inches, the same at every dpi): savefig would draw the
        # whole figure once more per file to find it
        fig.draw_without_rendering()
        box = fig.get_tightbbox().padded(matplotlib.rcParams["savefig.pad_inches"])
        for ext in ("png", "pdf"):
            p = outdir / f"{stem}.{ext}"
            fig.savefig(p, dpi=200 if ext == "png" else None, bbox_inches=box,
                        metadata=None if ext == "png" else {"Creator": "vcirun"})
            paths.append(p)
    return paths


def _as_results(results) -> Results:
    if isinstance(results, Results):
        return results
    if isinstance(results, (str, Path)):
        return read_results(results)
    raise TypeError(f"results: expected vcirun results (a path or Results), got {type(results).__name__}")


def _method_order(runs) -> list[str]:
    seen = {}
    for r in runs:
        seen.setdefault(r.attrs["label"], int(r.attrs.get("method_index", 0)))
    return sorted(seen, key=lambda k: seen[k])



def _runs_by_series(runs):
    """{(label, h): [(beta, l2 or nan, status, l2_note)]} sorted by beta, runs with a finite beta."""
    acc = defaultdict(list)
    for r in runs:
        beta = r.attrs.get("beta")
        if beta is None or not np.isfinite(beta):
            continue
        l2 = r.attrs.get("l2_error")
        l2 = math.nan if l2 is None or not np.isfinite(l2) else float(l2)
        acc[(r.attrs["label"], float(r.attrs["h"]))].append((float(beta), l2, str(r.attrs.get("status", "?")),
                                                              str(r.attrs.get("l2_note", ""))))
    return {k: sorted(v) for k, v in acc.items()}


def _coincident(series: dict, tol: float = 0.02) -> dict:
    """{key: other key} for curves within a relative `tol` of an earlier one at every common beta."""
    out, keys = {}, list(series)
    for i, a in enumerate(keys):
        for b in keys[:i]:
            (ba, ea), (bb, eb) = series[a], series[b]
            common, ia, ib = np.intersect1d(ba, bb, return_indices=True)
            x, y = ea[ia], eb[ib]
            m = np.isfinite(x) & np.isfinite(y)
            if m.sum() >= 2 and np.max(np.abs(x[m] - y[m]) / np.maximum(np.abs(x[m]), np.abs(y[m]))) < tol:
                out[a] = b
                break
    return out


@styled
def figure4(results) -> "Figure":
    """L2 error against beta for each method and h (the paper's Figure 4)."""
    from matplotlib.lines import Line2D

    results = _as_results(results)
    raw = _runs_by_series(results.runs)
    drawable = {k: v for k, v in raw.items() if any(np.isfinite(p[1]) or p[2] != "ok" for p in v)}
    if not any(np.isfinite(p[1]) for v in drawable.values() for p in v):
        raise FigureSkipped("no run has both a beta and an L2 error (needs beta in the config and a reference)")
    if max(len(v) for v in drawable.values()) < 2:
        raise FigureSkipped("L2 error against beta needs at least two betas")
    labels = _method_order(results.runs)
    hs = sorted({h for _, h in drawable}, reverse=True)
    keys = sorted(drawable, key=lambda k: (labels.index(k[0]), -k[1]))
    curves = {k: (np.array([p[0] for p in drawable[k]]), np.array([p[1] for p in drawable[k]])) for k in keys}
    same = _coincident(curves)
    fig, ax = new_figure(figsize=(6.4, 4.8))
    handles, failed_handles = [], []
    for idx, key in enumerate(keys):
        label, h = key
        b, e = curves[key]
        i, j = labels.index(label), hs.index(h)
        color = COLORS[i % len(COLORS)]
        every = max(1, len(b) // 12)
        # markers of different series at different betas, wider lines drawn first: a curve lying on
        # another stays visible (Figure 4's CVA and MCVAC at h = 1e-2 nearly coincide)
        base = text = f"{label}, h = {fmt_h(h)}"
        if key in same:
            text += f" (on {same[key][0]}, h = {fmt_h(same[key][1])})"
        if np.isfinite(e).any():
            (ln,) = ax.semilogy(b, e, color=color, linestyle=LINE_STYLES[j % len(LINE_STYLES)],
                                linewidth=max(0.8, 2.4 - 0.35 * idx), zorder=2 + idx,
                                marker=MARKERS[i % len(MARKERS)], markevery=((idx * max(1, every // len(keys))) % every, every),
                                markersize=4, markerfacecolor="white" if j else color, label=text)
            handles.append(ln)
        status = [p[2] for p in drawable[key]]
        bad = np.array([s != "ok" for s in status])
        if bad.any():  # failed runs: a mark on the beta axis, and in the legend
            kinds = sorted({s for s in status if s != "ok"})
            ax.plot(b[bad], np.full(bad.sum(), 0.02 + 0.03 * (idx % 4)), linestyle="none", marker="x",
                    color=color, markersize=5, transform=ax.get_xaxis_transform(), clip_on=False, zorder=10)
            what = "all" if bad.all() else f"{bad.sum()} of"
            failed_handles.append(Line2D([], [], linestyle="none", marker="x", color=color, markersize=5,
                                         label=f"{base}: {what} {len(b)} runs failed ({', '.join(kinds)})"))
    ax.set_xlabel(r"$\beta$")
    ax.set_ylabel(r"$L^2$ error")
    ax.grid(True, which="both", linewidth=0.3, alpha=0.5)
    allh = handles + failed_handles
    # below the axes: the curves fill the whole plot, so any inside position hides some of them
    fig.legend(handles=allh, loc="outside lower center", ncol=min(4, max(1, len(handles))) if not failed_handles
               else 2, frameon=False)
    ax.set_title(f"{results.attrs.get('system', '')}, T = {results.attrs.get('T', '')}\n{reference_note(results)}",
                 fontsize=8)
    return fig


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


def _mh_order(r) -> int | None:
    """The truncation order of a run's modified Hamiltonian (resolved_method, else the method data)."""
    m = r.attrs.get("resolved_method") or {}
    if isinstance(m, dict) and m.get("mh_order"):
        return int(m["mh_order"])
    try:
        from vcirun.methods.table import resolve_method

        spec = r.attrs.get("method_spec") or {"name": r.attrs.get("method")}
        mm = resolve_method(spec["name"], **{k: v for k, v in spec.items() if k in ("ld", "mh_order", "flow_order")})
        return int(mm.mh_order) if getattr(mm, "mh_order", None) else None
    except Exception:  # noqa: BLE001 - a label detail, never a reason to lose the figure
        return None


@styled
def figure3(results) -> "Figure":
    """H, -D3 Ld and the truncated modified Hamiltonian over time, one panel per MH method."""
    results = _as_results(results)

    def want(r):
        return r.attrs.get("has_trajectory") and r.attrs.get("has_Hmod") and r.attrs.get("n_steps", 0) > 0

    h, ic = _pick_case(results.runs, want)
    if h is None:
        raise FigureSkipped("needs stored trajectories of an MCVA-family run (store_trajectories: true; "
                            "methods MCVAA, MCVAC or MCVA)")
    runs = [r for r in results.runs if want(r) and float(r.attrs["h"]) == h and r.attrs["ic_key"] == ic]
    fig, axes = new_figure(1, len(runs), figsize=(3.4 * len(runs), 3.2), squeeze=False, sharey=True)
    for ax, r in zip(axes[0], runs):
        tr = load_trajectory(results.path, r.run_id)
        s = _mh_order(r)
        ax.plot(tr.t, tr.H, color=COLORS[0], label=r"$H$")
        ax.plot(tr.t, masked_discrete_energy(tr), color=COLORS[1], linestyle="--",
                label=r"$-D_3L_d$ (impact steps masked)")
        ax.plot(tr.t, tr.Hmod, color=COLORS[2], linestyle="-.",
                label="truncated MH" + (f", mh_order = {s}" if s else ""))
        for ti in tr.impacts:
            ax.axvline(ti, color="0.4", linestyle=(0, (4, 3)), linewidth=0.7)
        ax.set_title(f"{r.attrs['label']}" + ("" if r.attrs.get("status") == "ok" else f" [{r.attrs['status']}]"),
                     fontsize=9)
        ax.set_xlabel(r"$t$ [s]")
        ax.grid(True, linewidth=0.3, alpha=0.5)
        ax.legend(frameon=False, fontsize=7)
    axes[0][0].set_ylabel("energy [J]")
    b = runs[0].attrs.get("beta")
    where = f"beta = {b:g}" if b is not None and np.isfinite(b) else ic
    fig.suptitle(f"{results.attrs.get('system', '')}: {where}, h = {fmt_h(h)}; dashed lines: impacts", fontsize=9)
    return fig


@styled
def figure1(results) -> "Figure":
    """H(t) of a run with impacts against the same method without the constraint (Figure 1)."""
    results = _as_results(results)

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
    fig, axes = new_figure(len(pairs), 1, figsize=(6.0, 2.9 * len(pairs)), squeeze=False)
    for ax, (rc, rf) in zip(axes[:, 0], pairs):
        tc = load_trajectory(results.path, rc.run_id)
        tf = load_trajectory(results.path, rf.run_id)
        ax.plot(tf.t, tf.H, color=COLORS[0], label="without impacts")
        ax.plot(tc.t, tc.H, color=COLORS[1], label="with impacts")
        for ti in tc.impacts:
            ax.axvline(ti, color="0.4", linestyle=(0, (4, 3)), linewidth=0.7)
        # |H0| can be 0 (it depends on the zero of V), so the jump is compared with the range of H's
        # smooth oscillation in the run without impacts, the scale Figure 1 sets it against.
        jump = _largest_impact_jump(tc)
        smooth = float(np.nanmax(tf.H) - np.nanmin(tf.H)) if len(tf.H) else float("nan")
        txt = f"largest change of H over an impact step: {jump:.2g}"
        if smooth > 0:
            txt += f" = {jump / smooth:.2g} x the range of H without impacts ({smooth:.2g})"
        # in the title, not over the data: an annotation box inside the axes covered the legend
        ax.set_title(f"{rc.attrs['label']}, h = {fmt_h(float(rc.attrs['h']))}\n{txt}", fontsize=8)
        ax.set_ylabel(r"$H$ [J]")
        ax.grid(True, linewidth=0.3, alpha=0.5)
    axes[-1, 0].set_xlabel(r"$t$ [s]; dashed lines: impacts")
    fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="outside upper center", ncol=2, frameon=False)
    return fig


def _largest_impact_jump(tr) -> float:
    """max over impact steps k -> k+1 of |H_{k+1} - H_k| (0 without impacts)."""
    steps = np.flatnonzero(np.asarray(tr.impact_step, bool))
    steps = steps[steps + 1 < len(tr.H)]
    return float(np.max(np.abs(tr.H[steps + 1] - tr.H[steps]))) if steps.size else 0.0


@styled
def work_precision(results) -> "Figure":
    """Median L2 error against mean computation time, one marker per h, one line per method."""
    results = _as_results(results)
    l2 = defaultdict(list)
    for r in results.runs:
        e = r.attrs.get("l2_error")
        if r.attrs.get("status") == "ok" and e is not None and np.isfinite(e):  # NaN: no reference
            l2[(r.attrs["label"], float(r.attrs["h"]))].append(float(e))
    stats = {(s.label, s.h): s for s in metrics.timing_stats(results.runs)}
    points = defaultdict(list)
    for (label, h), errs in l2.items():
        s = stats.get((label, h))
        if s and s.n and np.isfinite(s.mean):
            points[label].append((s.mean, float(np.median(errs)), h))
    if not points or max(len(v) for v in points.values()) < 2:
        raise FigureSkipped("work-precision needs finite L2 errors (a reference) and timings at two or more h")
    labels = _method_order(results.runs)
    fig, ax = new_figure(figsize=(5.0, 3.8))
    for label in labels:
        pts = sorted(points.get(label, []))
        if not pts:
            continue
        i = labels.index(label)
        ax.loglog([p[0] for p in pts], [p[1] for p in pts], color=COLORS[i % len(COLORS)],
                  marker=MARKERS[i % len(MARKERS)], markersize=4, label=label)
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    # a log axis spanning less than a decade: label 1, 2, 5 x 10^k instead of colliding minor labels
    ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())
    hs = sorted({p[2] for v in points.values() for p in v}, reverse=True)
    ax.set_title("one point per h: " + ", ".join(fmt_h(h) for h in hs) + " (larger h: less time)\n"
                 + reference_note(results), fontsize=7)
    ax.set_xlabel("mean computation time per run [s]")
    ax.set_ylabel(r"median $L^2$ error")
    ax.grid(True, which="both", linewidth=0.3, alpha=0.5)
    ax.legend(frameon=False)
    return fig


@styled
def contacts_energy(results) -> "Figure":
    """H(t) per method at the smallest stored h (first initial state), impacts marked by contact."""
    results = _as_results(results)
    cons = results.attrs.get("constraints") or []
    if len(cons) < 2 and all(str(c.get("restitution", "1")) in ("1", "1.0") for c in cons):
        raise FigureSkipped("for scenes with several constraints or restitution < 1; this results "
                            "file declares one elastic constraint (or predates the constraints record)")
    runs = [r for r in results.runs if r.attrs.get("has_trajectory") and r.attrs.get("n_steps", 0) > 0]
    if not runs:
        raise FigureSkipped("needs stored trajectories (store_trajectories: true)")
    h = min(float(r.attrs["h"]) for r in runs)
    ic = sorted({r.attrs["ic_key"] for r in runs})[0]
    runs = [r for r in runs if float(r.attrs["h"]) == h and r.attrs["ic_key"] == ic]
    names = [c.get("name", f"c{i}") for i, c in enumerate(cons)]
    fig, axes = new_figure(1, len(runs), figsize=(3.4 * len(runs), 3.2), squeeze=False, sharey=True)
    seen = set()
    for ax, r in zip(axes[0], runs):
        tr = load_trajectory(results.path, r.run_id)
        ax.plot(tr.t, tr.H, color="k", linewidth=1.0, label=r"$H$")
        for ti, c in zip(tr.impacts, tr.impact_contact):
            lab = None if c in seen else f"impact: {names[c] if c < len(names) else c}"
            seen.add(int(c))
            ax.axvline(ti, color=COLORS[int(c) % len(COLORS)], linestyle=(0, (4, 3)), linewidth=0.7, label=lab)
        held = np.asarray(tr.contact_active).any(axis=1) if np.size(tr.contact_active) else np.zeros(0, bool)
        if held.any():
            ax.fill_between(tr.t, 0, 1, where=held, transform=ax.get_xaxis_transform(), color="0.85",
                            label="held contact" if "held" not in seen else None)
            seen.add("held")
        ax.set_title(f"{r.attrs['label']}" + ("" if r.attrs.get("status") == "ok" else f" [{r.attrs['status']}]"),
                     fontsize=9)
        ax.set_xlabel(r"$t$ [s]")
        ax.grid(True, linewidth=0.3, alpha=0.5)
    axes[0][0].set_ylabel("energy H [J]")
    handles, labels = [], []
    for ax in axes[0]:
        for hd, lb in zip(*ax.get_legend_handles_labels()):
            if lb not in labels:
                handles.append(hd)
                labels.append(lb)
    axes[0][-1].legend(handles, labels, frameon=False, fontsize=7)
    prm = _parameter_values(results.attrs.get("system_spec"))
    rest = [f"{prm[r]:g}" if (r := str(c.get("restitution"))) in prm else r for c in cons]  # parameter -> value
    e = ("e = " + rest[0]) if len(set(rest)) == 1 else ", ".join(f"{n}: e = {v}" for n, v in zip(names, rest))
    fig.suptitle(f"{results.attrs.get('system', '')}, {len(cons)} contacts, {e}; {ic}, h = {fmt_h(h)}", fontsize=8)
    return fig



def _parameter_values(spec) -> dict:
    """{name: value} of a results file's system: the scene's (or file's) defaults with the config's
    overrides ({} where the system cannot be read back)."""
    if not isinstance(spec, dict):
        return {}
    out = {}
    try:
        if spec.get("name") and not spec.get("file"):
            from ..scenes.registry import scene_data

            out = dict(scene_data(spec["name"]).params)
        elif spec.get("file"):
            from ..mechanics.loader import load_system_yaml

            out = dict(load_system_yaml(spec["file"]).params)
    except (ValueError, OSError):
        out = {}
    out.update({str(k): float(v) for k, v in (spec.get("params") or {}).items()})
    return out


FIGURES = {"fig4": figure4, "fig3": figure3, "fig1": figure1, "work_precision": work_precision,
           "contacts": contacts_energy}
_STEMS = {"fig4": "fig4_l2_error_vs_beta", "fig3": "fig3_energy_evolution", "fig1": "fig1_energy_with_without_impacts",
          "work_precision": "work_precision", "contacts": "contacts_energy"}


def figures(results, which=None) -> tuple[dict, dict[str, str]]:
    """Every figure the results support, as Figures: ({name: Figure}, {name: reason skipped})."""
    results = _as_results(results)
    made, skipped = {}, {}
    for name, fn in FIGURES.items():
        if which and name not in which:
            continue
        try:
            made[name] = fn(results)
        except FigureSkipped as e:
            skipped[name] = str(e)
    return made, skipped


def make_figures(results, outdir: Path, which=None) -> tuple[list[Path], dict[str, str]]:
    """For `vcirun plot`: write every figure the results support (PNG and PDF) into `outdir`:
    (written paths, {figure: reason skipped})."""
    made, skipped = figures(results, which)
    written = []
    for name, fig in made.items():
        written += save_figure(fig, Path(outdir), _STEMS[name])
    return written, skipped


@dataclass
class PlotReport:
    results_path: Path
    outdir: Path
    paths: list          # figures and table files written
    skipped: dict        # figure -> reason
    tables: list         # tables.Table objects (for printing)


def plot_results(results=None, outdir=None, results_dir="results") -> PlotReport:
    """`vcirun plot FILE`: every figure and table a results file supports, written to
    <results dir>/figures/<sweep name>/ unless `outdir` is given. With no file, the newest *.h5 under
    `results_dir` (the CLI itself plots every results file when given none)."""
    from . import tables

    path = Path(results) if results is not None else find_newest_results(results_dir)
    res = read_results(path)
    if not res.runs:
        raise StorageError(f"{path}: no complete runs to plot yet")
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


def plot_single(path, outdir=None) -> list:
    """`vcirun plot run.h5` (a file of one run): the run's figure (`Trajectory.plot`, PNG and PDF) and
    its energy account along the grid (CSV: t, H, each term, the rest) into <file's folder>/figures/<stem>/
    unless `outdir` is given. Returns the paths written."""
    import csv

    from ..io.single import read_single

    path = Path(path)
    traj = read_single(path)
    outdir = Path(outdir) if outdir is not None else path.parent / "figures" / path.stem
    outdir.mkdir(parents=True, exist_ok=True)
    fig = traj.plot()
    written = []
    for ext in ("png", "pdf"):
        p = outdir / f"trajectory.{ext}"
        fig.savefig(p, dpi=150)
        written.append(p)
    try:
        acc = traj.energy_account()
    except (ValueError, OSError, RuntimeError):   # a YAML system the file does not carry: no account
        return written
    p = outdir / "energy_account.csv"
    with open(p, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["t", "H"] + [x.name.replace(" ", "_") for x in acc.terms] + ["rest"])
        rest = acc.rest_series
        for k in range(len(acc.t)):
            w.writerow([repr(float(acc.t[k])), repr(float(acc.H[k]))] + [repr(float(x.series[k])) for x in acc.terms]
                       + [repr(float(rest[k]))])
    written.append(p)
    return written
