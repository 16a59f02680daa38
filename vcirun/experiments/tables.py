"""Tables: Table I (method properties, from the methods' declared data) and Table II (computation
time per method and h with 95% confidence intervals). Printed with rich, saved as CSV and Markdown."""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

from . import metrics
from ..io.reader import Results

__all__ = ["Table", "table1", "table2", "runs_table", "summary_table", "write_table", "print_table", "to_markdown"]

PAPER_METHODS = ("CVA", "VCI", "MCVAA", "MCVAC")
PROPERTY_COLUMNS = (("conserves_mh", "Conserves associated MH"),
                    ("symplectic", "Symplectic (to specified accuracy)"),
                    ("explicit_ld", "Explicit discrete Lagrangian"),
                    # beyond the paper's table: measured L2 order through impacts on forced
                    # scenes against the forced exact reference (tests/scenes/test_forced.py)
                    ("forcing", "Forcing (measured order)"))


@dataclass
class Table:
    title: str
    columns: list[str]          # display header (Markdown, rich)
    rows: list[list[str]]       # display cells
    csv_columns: list[str]      # machine-readable long format
    csv_rows: list[list]
    caption: str = ""
    left_columns: int = 1       # leading text columns; the rest (numbers) are right-aligned


def _mark(value) -> str:
    if value is True:
        return "✓"
    if value is False or value is None:
        return ""
    return f"✓ ({value})"


def table1(names=None) -> Table:
    """Table I of the paper, generated from `vcirun.methods.table.METHODS[name].properties`."""
    from vcirun.methods.table import METHODS

    names = list(names or [n for n in PAPER_METHODS if n in METHODS] + [n for n in METHODS if n not in PAPER_METHODS])
    rows, csv_rows = [], []
    for name in names:
        props = METHODS[name].properties
        rows.append([name] + [_mark(props.get(k)) for k, _ in PROPERTY_COLUMNS])
        csv_rows.append([name, METHODS[name].ld] + [props.get(k) for k, _ in PROPERTY_COLUMNS])
    missing = [n for n in PAPER_METHODS if n not in METHODS]
    return Table("Table I: properties of the impact integration methods",
                 ["Method"] + [title for _, title in PROPERTY_COLUMNS], rows,
                 ["method", "ld"] + [k for k, _ in PROPERTY_COLUMNS], csv_rows,
                 caption="Generated from vcirun.methods.table.METHODS" + (
                     f"; not available in this build: {', '.join(missing)}" if missing else ""))


def _unit(stats) -> tuple[str, float]:
    top = max((s.mean for s in stats if math.isfinite(s.mean)), default=0.0)
    return ("s", 1.0) if top >= 1.0 else ("ms", 1e3)


def _pm(mean: float, half: float, scale: float) -> str:
    if not math.isfinite(mean):
        return "n/a"
    if not math.isfinite(half):
        return f"{mean * scale:.3g}"
    # two significant digits of the half-width fix the decimals of both numbers
    digits = max(0, 1 - int(math.floor(math.log10(half * scale)))) if half > 0 else 3
    return f"{mean * scale:.{digits}f} ± {half * scale:.{digits}f}"


def table2(results: Results, level: float = 0.95) -> Table:
    """Table II: mean computation time per method (rows) and h (columns), with t-intervals."""
    stats = metrics.timing_stats(results.runs, level)
    if not stats:
        raise ValueError("no runs to time")
    unit, scale = _unit(stats)
    labels = []
    for s in stats:
        if s.label not in labels:
            labels.append(s.label)
    hs = sorted({s.h for s in stats}, reverse=True)
    by = {(s.label, s.h): s for s in stats}
    rows = []
    for label in labels:
        row = [label]
        for h in hs:
            s = by.get((label, h))
            cell = _pm(s.mean, s.halfwidth, scale) if s else ""
            if s and s.n_failed:
                cell += f" ({s.n_failed} failed)"
            row.append(cell)
        rows.append(row)
    csv_rows = [[s.label, s.h, s.n, s.mean, s.halfwidth, s.std, s.n_failed, level] for s in stats]
    ns = sorted({s.n for s in stats})
    return Table(f"Table II: computation time [{unit}], mean ± {int(level * 100)}% confidence interval",
                 ["Method"] + [f"h = {h:g}" for h in hs], rows,
                 ["method", "h", "n", "mean_s", "ci_halfwidth_s", "std_s", "n_failed", "level"], csv_rows,
                 caption=f"{results.name}: wall time of the integration per run ({_repeats(results)}kernel "
                         f"loading excluded), over n = {', '.join(map(str, ns))} initial conditions per cell; runs "
                         "that failed are excluded from the statistics.")


def _repeats(results) -> str:
    k = results.attrs.get("timing_repeats")
    return f"fastest of {k} identical integrations, " if isinstance(k, int) and k > 1 else ""


def to_markdown(table: Table) -> str:
    def esc(c):
        return str(c).replace("|", "\\|")

    lines = [f"**{table.title}**", "", "| " + " | ".join(map(esc, table.columns)) + " |",
             "|" + "|".join(["---"] * len(table.columns)) + "|"]
    lines += ["| " + " | ".join(map(esc, r)) + " |" for r in table.rows]
    if table.caption:
        lines += ["", table.caption]
    return "\n".join(lines) + "\n"


def write_table(table: Table, outdir: Path, stem: str) -> list[Path]:
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    csv_path, md_path = outdir / f"{stem}.csv", outdir / f"{stem}.md"
    with open(csv_path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(table.csv_columns)
        w.writerows(table.csv_rows)
    md_path.write_text(to_markdown(table), encoding="utf-8")
    return [csv_path, md_path]


def print_table(table: Table, console, compact: bool = False) -> None:
    """The table on a rich console; compact: no outer box, one space between columns, no cell ever
    wrapped or cut (for tables sized to fit 80 columns)."""
    from rich import box
    from rich.markup import escape
    from rich.table import Table as RichTable

    t = RichTable(title=escape(table.title), caption=escape(table.caption) if table.caption else None,
                  title_justify="left", caption_justify="left",
                  **(dict(box=box.SIMPLE_HEAD, pad_edge=False, padding=(0, 1), collapse_padding=True)
                     if compact else {}))
    for i, c in enumerate(table.columns):
        t.add_column(escape(c), justify="left" if i < table.left_columns else "right", no_wrap=i == 0 or compact,
                     overflow="ignore" if compact else "ellipsis")
    for r in table.rows:
        t.add_row(*(escape(str(c)) for c in r))
    console.print(t)


def _g(x, fmt) -> str:
    return format(x, fmt) if x is not None and math.isfinite(x) else "-"


def summary_table(results: Results) -> Table:
    """One row per (method, h): runs, how many ok, the impact counts (range), the L2 error (median and
    largest over the initial conditions) and the median wall time; sized to fit 80 columns."""
    import numpy as np

    groups: dict = {}
    for r in results.runs:
        a = r.attrs
        groups.setdefault((str(a.get("label", "")), float(a.get("h", float("nan")))), []).append(a)
    order = [m.get("label") for m in (results.attrs.get("methods") or []) if isinstance(m, dict)]
    rank = {lab: i for i, lab in enumerate(order)}
    rows, csv_rows = [], []
    for (label, h), runs in sorted(groups.items(), key=lambda kv: (rank.get(kv[0][0], len(rank)), kv[0][0], -kv[0][1])):
        ok = [a for a in runs if a.get("status") == "ok"]
        imp = [int(a["n_impacts"]) if isinstance(a.get("n_impacts"), (int, float)) else 0 for a in runs]
        l2 = np.array([a["l2_error"] for a in ok if isinstance(a.get("l2_error"), float)
                       and math.isfinite(a["l2_error"])])
        wt = np.array([a["wall_time"] for a in ok if isinstance(a.get("wall_time"), float)
                       and math.isfinite(a["wall_time"])])
        med, top = (float(np.median(l2)), float(np.max(l2))) if l2.size else (None, None)
        wmed = float(np.median(wt)) if wt.size else None
        rows.append([label, f"{h:g}", str(len(runs)), str(len(ok)),
                     f"{min(imp)}" if min(imp) == max(imp) else f"{min(imp)}-{max(imp)}",
                     _g(med, ".2e"), _g(top, ".2e"), _g(None if wmed is None else 1e3 * wmed, ".3g")])
        csv_rows.append([label, h, len(runs), len(ok), min(imp), max(imp), med, top, wmed])
    return Table(f"{results.name}: {len(results.runs)} runs, by method and h",
                 ["method", "h", "runs", "ok", "impacts", "L2 median", "L2 max", "ms"], rows,
                 ["label", "h", "runs", "ok", "impacts_min", "impacts_max", "l2_median", "l2_max", "wall_time_median_s"],
                 csv_rows, caption="L2 over the ok runs' initial conditions; ms: median wall time of the "
                                   "integration; every run: --runs", left_columns=1)


def run_status(a: dict) -> str:
    """A stored run's status for tables: its trajectory's status, or "tol <status>" for a run of tol=
    that finished without reaching its tolerance (its choice's status: not_reached, below_floor,
    over_budget)."""
    status, tol = str(a.get("status", "")), a.get("tol_status")
    return f"tol {tol}" if status == "ok" and tol not in (None, "", "ok") else status


def runs_table(results: Results, only_failed: bool = False) -> Table:
    """One row per stored run: id, method, h (the step a run of tol= chose), initial condition, status,
    impacts, L2 error, wall time."""
    rows, csv_rows = [], []
    for r in results.runs:
        a = r.attrs
        if only_failed and run_status(a) == "ok":
            continue
        h = a.get("h_chosen", a.get("h", float("nan")))
        beta = r.beta_or_none
        ic = f"{beta:g}" if beta is not None else str(a.get("ic_key", ""))
        l2 = a.get("l2_error")
        wt = a.get("wall_time")
        rows.append([r.run_id, str(a.get("label", "")), f"{h:g}", ic,
                     run_status(a), str(a.get("n_impacts", "")),
                     f"{l2:.3e}" if l2 is not None and math.isfinite(l2) else "-",
                     f"{1e3 * wt:.3g}" if wt is not None and math.isfinite(wt) else "-"])
        if len(rows[-1][3]) > 12:   # an initial-condition key (state=...): its index fits the column
            rows[-1][3] = rows[-1][3][:12]
        csv_rows.append([r.run_id, a.get("label"), a.get("h"), beta, a.get("ic_key"), a.get("status"),
                         a.get("n_impacts"), l2, wt])
    title = f"{results.name}: {len(rows)} run{'s' * (len(rows) != 1)}" + (" not ok" if only_failed else "")
    return Table(title, ["run", "method", "h", "beta", "status", "impacts", "L2 error", "ms"], rows,
                 ["run_id", "label", "h", "beta", "ic_key", "status", "n_impacts", "l2_error", "wall_time_s"],
                 csv_rows, left_columns=2)
