"""Figures and tables of a work-precision or long-horizon study (vcirun.experiments.workprecision).

`plot_study(path, outdir=None)` (for `vcirun plot`) reads the study's JSON (results/work_precision.json,
...) and writes, to `outdir` (default <results dir>/figures/<study name>/); `work_precision_figure(res)`
and `long_horizon_figure(res)` return the Figures without writing (no pyplot, no global style):

- work_precision: `work_precision_<name>.png/.pdf`, three panels: median L2 error against the median
  compiled-loop wall time per simulation, the median wall time of the whole call, and its median CPU
  time (thread_time; immune to preemption on a loaded machine);
  one line per vcirun method over h (labelled by h), one per solve_ivp solver over rtol, on the
  output grid h = 1e-2 (the solver's cost depends on the grid only through t_eval);
- long_horizon: `long_horizon_<name>.png/.pdf`, one panel per horizon T: max |H - H0| against the
  median CPU time of the whole call (filled markers, solid), and for the MCVA family the truncated modified
  Hamiltonian's max |Hmod - Hmod0| (open markers, dotted); solve_ivp over rtol;
- `<name>_summary.md` and `<name>_ratios.md`: the printed tables, as Markdown.

Hooking it into `vcirun plot` (the lead's call, cli.py / figures.py are not ours): a results path
ending in `.json` whose top level has `"study"` in ("work_precision", "long_horizon") goes to
`wp_figures.plot_study(path, outdir)`, which returns the written paths; `print_study_tables(path)`
prints the tables. Everything else goes to `figures.plot_results` as today.
"""
from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np

from ..run.plotting import COLORS, MARKERS, fmt_h, new_figure, styled
from .figures import save_figure

__all__ = ["plot_study", "work_precision_figure", "long_horizon_figure", "print_study_tables", "is_study_file"]

_BASE_STYLE = {"DOP853": ("#000000", "x", "--"), "Radau": ("#777777", "+", ":"),
               "DOP853/numpy": ("#8c564b", "1", "-.")}  # numpy rhs: what a user writes


def is_study_file(path) -> bool:
    p = Path(path)
    if p.suffix != ".json" or not p.is_file():
        return False
    try:
        import json

        return json.loads(p.read_text()).get("study") in ("work_precision", "long_horizon")
    except (ValueError, OSError):
        return False


def _vcirun_labels(res):
    seen = []
    for r in res["runs"]:
        if r["kind"] == "vcirun" and r["label"] not in seen:
            seen.append(r["label"])
    return seen


def _baseline_grid(res, prefer=1e-2) -> float | None:
    hs = sorted({p["h"] for p in res["summary"] if p["kind"] == "baseline"})
    return min(hs, key=lambda h: abs(math.log(h / prefer))) if hs else None


@styled
def work_precision_figure(res: dict):
    """The work-precision Figure of a loaded study (not registered with pyplot; see figures)."""
    labels = _vcirun_labels(res)
    T = sorted({p["T"] for p in res["summary"]})[0]
    pts = [p for p in res["summary"] if p["T"] == T]
    hb = _baseline_grid(res)
    fig, axes = new_figure(1, 3, figsize=(14.0, 4.4), sharey=True)
    for ax, timing, xlabel in ((axes[0], "wall", "median compiled-loop wall time per simulation [s]"),
                               (axes[1], "call", "median wall time per call\n(simulate() / solve_ivp_run()) [s]"),
                               (axes[2], "cpu", "median CPU time per call (thread_time) [s]")):
        for i, label in enumerate(labels):
            mine = sorted([p for p in pts if p["kind"] == "vcirun" and p["label"] == label and np.isfinite(p["err"])],
                          key=lambda p: -p["h"])
            if not mine:
                continue
            x = [p.get(timing, math.nan) for p in mine]
            y = [p["err"] for p in mine]
            ax.loglog(x, y, color=COLORS[i % len(COLORS)], marker=MARKERS[i % len(MARKERS)], markersize=4,
                      label=label)
            if i == 0:
                for p in mine:
                    ax.annotate(f"h={fmt_h(p['h'])}", (p.get(timing, math.nan), p["err"]), fontsize=6, color="0.35",
                                xytext=(3, 3), textcoords="offset points")
        for s, (col, mk, ls) in _BASE_STYLE.items():
            theirs = sorted([p for p in pts if p["kind"] == "baseline" and p["label"] == s and p["h"] == hb
                             and np.isfinite(p["err"])], key=lambda p: -p["rtol"])
            if not theirs:
                continue
            ax.loglog([p.get(timing, math.nan) for p in theirs], [p["err"] for p in theirs], color=col, marker=mk, linestyle=ls,
                      markersize=5, label=f"solve_ivp {s} (rtol {theirs[0]['rtol']:.0e}..{theirs[-1]['rtol']:.0e})")
            for p in (theirs[0], theirs[-1]):
                ax.annotate(f"{p['rtol']:.0e}", (p.get(timing, math.nan), p["err"]), fontsize=6, color=col, xytext=(3, -8),
                            textcoords="offset points")
        ax.set_xlabel(xlabel)
        ax.grid(True, which="both", linewidth=0.3, alpha=0.5)
    axes[0].set_ylabel(r"median $L^2$ error against the exact solution")
    axes[0].legend(frameon=False, fontsize=7, loc="lower left")
    nb = len({r["beta"] for r in res["runs"]})
    grid = f"; solve_ivp output on the h = {fmt_h(hb)} grid" if hb else ""
    fig.suptitle(f"{res['config']['system']}, T = {T:g}, medians over {nb} initial conditions{grid}", fontsize=9)
    return fig


@styled
def long_horizon_figure(res: dict, timing: str = "cpu"):
    """The long-horizon Figure. x axis: CPU time of the whole call (default; runs of seconds are
    preempted on a loaded machine, so their wall time is inflated more than that of short runs) or
    "wall" (compiled-loop time)."""
    tkey = lambda p: p.get(timing, math.nan)  # noqa: E731
    labels = _vcirun_labels(res)
    Ts = sorted({p["T"] for p in res["summary"]})
    fig, axes = new_figure(1, len(Ts), figsize=(5.0 * len(Ts), 4.2), squeeze=False)
    for ax, T in zip(axes[0], Ts):
        pts = [p for p in res["summary"] if p["T"] == T]
        for i, label in enumerate(labels):
            col, mk = COLORS[i % len(COLORS)], MARKERS[i % len(MARKERS)]
            mine = sorted([p for p in pts if p["kind"] == "vcirun" and p["label"] == label], key=lambda p: -p["h"])
            ok = [p for p in mine if np.isfinite(p["err"])]
            if ok:
                ax.loglog([tkey(p) for p in ok], [p["err"] for p in ok], color=col, marker=mk, markersize=4,
                          label=f"{label} max|H-H0|")
                if i == 0:
                    for p in ok:
                        ax.annotate(f"h={fmt_h(p['h'])}", (tkey(p), p["err"]), fontsize=6, color="0.35",
                                    xytext=(3, 3), textcoords="offset points")
            hm = [p for p in ok if np.isfinite(p.get("dHmod", math.nan))]
            if hm:
                ax.loglog([tkey(p) for p in hm], [p["dHmod"] for p in hm], color=col, marker=mk, markersize=4,
                          markerfacecolor="none", linestyle=":", label=f"{label} max|Hmod-Hmod0|")
        mine_err = [p["err"] for p in pts if p["kind"] == "vcirun" and np.isfinite(p["err"])]
        ytop = 100.0 * max(mine_err) if mine_err else math.inf
        for s, (col, mk, ls) in _BASE_STYLE.items():
            theirs = sorted([p for p in pts if p["kind"] == "baseline" and p["label"] == s and np.isfinite(p["err"])],
                            key=lambda p: -p["rtol"])
            if theirs:
                ys = [min(p["err"], ytop) for p in theirs]
                ax.loglog([tkey(p) for p in theirs], ys, color=col, marker=mk, linestyle=ls,
                          markersize=5, label=f"solve_ivp {s} max|H-H0| (at the top: lost the motion)")
                for p, y in zip(theirs, ys):
                    lost = p["err"] > ytop
                    ax.annotate(f"{p['rtol']:.0e}" + (f": {p['err']:.0e}" if lost else ""), (tkey(p), y), fontsize=5,
                                color=col, xytext=(3, -7), textcoords="offset points")
            timed_out = [p for p in pts if p["kind"] == "baseline" and p["label"] == s and "time_limit" in p["statuses"]]
            if timed_out:
                ax.annotate(f"{s}: rtol " + ", ".join(f"{p['rtol']:.0e}" for p in sorted(timed_out, key=lambda p: -p["rtol"]))
                            + " stopped at the time limit", (0.01, 0.01), xycoords="axes fraction", fontsize=6, color=col)
        ax.set_title(f"T = {T:g}", fontsize=9)
        ax.set_xlabel("median CPU time per call [s]" if timing == "cpu" else "median compiled-loop time [s]")
        ax.grid(True, which="both", linewidth=0.3, alpha=0.5)
    axes[0][0].set_ylabel("energy error (median over initial conditions)")
    axes[0][0].legend(frameon=False, fontsize=6, loc="best")
    fig.suptitle(f"{res['config']['system']}: energy error over long horizons (failed runs omitted)", fontsize=9)
    return fig


def _tables_markdown(res: dict) -> tuple[str, str]:
    from . import workprecision as wp   # (here: it imports the reference and numba, which a plot never needs)

    buf = io.StringIO()
    wp.print_tables(res, file=buf)
    text = buf.getvalue()
    head, _, ratios = text.partition("-- speed ratio")
    return "```\n" + head + "```\n", ("```\n-- speed ratio" + ratios + "```\n") if ratios else ""


def print_study_tables(path, file=None) -> None:
    import sys

    from . import workprecision as wp

    wp.print_tables(wp.load(path), file=file or sys.stdout)


def plot_study(path, outdir=None) -> list[Path]:
    """Every figure and table of a saved study; returns the written paths."""
    path = Path(path)
    from . import workprecision as wp

    res = wp.load(path)
    outdir = Path(outdir) if outdir is not None else path.parent / "figures" / res["name"]
    outdir.mkdir(parents=True, exist_ok=True)
    if res["study"] == "work_precision":
        paths = save_figure(work_precision_figure(res), outdir, f"work_precision_{res['name']}")
    else:
        paths = save_figure(long_horizon_figure(res), outdir, f"long_horizon_{res['name']}")
    summ, rat = _tables_markdown(res)
    p = outdir / f"{res['name']}_summary.md"
    p.write_text(summ)
    paths.append(p)
    if rat:
        p = outdir / f"{res['name']}_ratios.md"
        p.write_text(rat)
        paths.append(p)
    return paths
