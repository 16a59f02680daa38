"""The Markdown report and the figure of `vcirun verify`."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .checks import FAIL, PASS, SKIP, WARN

_ORDER_CHECKS = ("smooth order", "L2 order through impacts", "impact times", "mode-change times", "modified Hamiltonian")
_MARK = {PASS: "pass", WARN: "**warn**", FAIL: "**FAIL**", SKIP: "skip"}


def _cell(x) -> str:
    return str(x).replace("|", "\\|").replace("\n", " ")


def _table(rows) -> list[str]:
    if not rows:
        return []
    cols = list(dict.fromkeys(k for r in rows for k in r))
    out = ["| " + " | ".join(_cell(c) for c in cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        out.append("| " + " | ".join(_cell(r.get(c, "")) for c in cols) + " |")
    return out


def _value(c) -> str:
    from .checks import fmt

    if c.verdict == SKIP and not np.isfinite(c.value if c.value is not None else np.nan):
        return "-"
    return fmt(c.value)


def markdown(res, figure=None) -> str:
    """The report of a VerifyResult: verdict, summary table, then each check's measured data."""
    counts = {v: sum(c.verdict == v for c in res.checks) for v in (PASS, WARN, FAIL, SKIP)}
    verdict = "FAIL" if counts[FAIL] else ("pass with warnings" if counts[WARN] else "pass")
    q0 = ", ".join(f"{x:.6g}" for x in res.q0)
    p0 = ", ".join(f"{x:.6g}" for x in res.p0)
    L = [f"# vcirun verify: {res.system}", "",
         f"**Verdict: {verdict}** ({counts[PASS]} pass, {counts[WARN]} warn, {counts[FAIL]} fail, {counts[SKIP]} skip) "
         f"in {res.seconds:.1f} s.", "",
         f"- system: `{res.system}` ({res.n} degrees of freedom), parameters "
         + ", ".join(f"{k} = {v:g}" for k, v in res.params.items()),
         f"- methods: {', '.join(res.methods)}",
         f"- start state: q0 = [{q0}], p0 = [{p0}]; T = {res.T:g}",
         f"- step ladder: h = {', '.join(f'{h:g}' for h in res.h)}"]
    L += [f"- note: {n}" for n in res.notes]
    L += ["", "| check | method | verdict | value | threshold | expected | note |", "|---|---|---|---|---|---|---|"]
    for c in res.checks:
        L.append(f"| {_cell(c.name)} | {_cell(c.method or '-')} | {_MARK[c.verdict]} | {_value(c)} | {_cell(c.threshold)} "
                 f"| {_cell(c.expected)} | {_cell(c.note)} |")
    if figure is not None:
        L += ["", f"![error against h]({figure})", "",
              "Error against h per method (log-log); filled: points used in the fit, hollow: not used (round-off "
              "plateau or pre-asymptotic); dashed: the theoretical slope through the finest point used."]
    L += ["", "## Details", ""]
    for c in res.checks:
        if not c.rows:
            continue
        L += [f"### {c.name}" + (f" [{c.method}]" if c.method else "") + f": {c.verdict}", ""]
        L += _table(c.rows) + [""]
    L += ["## How the checks are judged", "",
          "- reference: vcirun.reference's self-reported accuracy (a second solve at a 10x tighter tolerance); "
          "for a forced system it is also compared with the forced smooth solution before the first impact.",
          "- hyperregularity: eigenvalues of M(q) at 2001 states of the exact nonsmooth reference, along the exact "
          "smooth solution and the methods' runs. Judged on the exact solutions (on the finest runs if there are "
          "none): fail where M is not finite or not positive definite, or where the exact solution stops at a "
          "singular M; warn where cond(M) > 1e4 or the smallest eigenvalue falls below 1e-4 of its value at q0, "
          "or where coarse runs leave the region the exact motion stays in.",
          "- derivatives: every generated kernel the method's compiled module defines, at the start state and "
          "3 states along the exact motion, against 4th-order central differences of the lower-level kernel "
          "named in the table (Pm, Pp, Ed against the discrete Lagrangian evaluated from sys_M and sys_V by the "
          "library's quadrature rule, plus the discrete forces of a forced system); relative error, pass below "
          "1e-6 for FD rows and 1e-10 for identities.",
          "- orders: least-squares slope of log error against log h over the points above the round-off plateau "
          "(vcirun.verification.orders.fit_order, the test suite's estimator; coarsest points whose error does not "
          "decrease are dropped as pre-asymptotic). Pass if the slope is within the tolerance of the theory, or if "
          "the asymptotic regime (consecutive local slopes within the tolerance, ignoring points within 100x of "
          "round-off) spans at least 3 steps; warn if it spans only the two finest steps, or if the errors are "
          "still large (> 1e-3 of the solution's size at the finest h: ladder too coarse), or if the errors sit "
          "at round-off (ladder too fine); fail otherwise.",
          "- smooth order: constraint ignored, max |q - q_exact| over the coarsest grid (the measure of "
          "tests/convergence/test_orders), q_exact by DOP853 at rtol 1e-13; theory: the order of the method's "
          "discrete Lagrangian; tolerance 0.15.",
          "- through impacts: L2 error (vcirun.l2_error) and the largest impact-time error against vcirun.reference; "
          "theory: the discrete Lagrangian's order (CVA, VCI, CVA4, ...), 2 for the MCVA family; tolerance 0.15 "
          "(impact times: one-sided); every h must find the reference's impacts (a different count warns on the "
          "coarser half of the ladder and fails on the finer half).",
          "- modified Hamiltonian (MCVA family): max - min of the truncated H~ along the runs through impacts, "
          "expected ~ h^mh_order (tolerance 0.3, as tests/convergence/test_modified_conservation).",
          "- symplecticity: max |J^T Omega J - Omega| of the full map Phi_h (and of the MCVA partial flow of H~ "
          "at tau = h/2), J by 4th-order FD at steps 1e-3, 3e-4, ..., 3e-6 until the defect stops falling "
          "(the stencil's truncation falls as the step's 4th power, a map's own defect does not), the smallest kept, "
          "at two steps and the four states; pass below 1e-8, or below 1e-6 where the smallest lies at the bottom "
          "of a V in the step (rising again as 1/d: round-off) within the floor that the maps' Newton tolerance "
          "makes in J, a defect the stencil does not resolve (the resets are "
          "not judged; a forced map is reported, not judged).",
          "- energy across impacts: the largest change of H (H~ for the MCVA family; H minus the work of the forces "
          "for a forced system) over one impact step, against h: slope at least p - 0.3 (O(h^p) per impact keeps "
          "the global order p), or every impact step changing it at most 10x as much as the largest smooth "
          "step, or every change at round-off; warn down to p - 0.6, fail below. With friction the impact "
          "steps are the steps with an event (impacts and friction mode changes) and the friction work is taken "
          "off too.",
          "- mode-change times (friction): the runs' stick/slip transitions against the exact reference's: the same "
          "count, contacts and kinds (slip -> stick, stick -> slip, slip reversed) at every h (a different sequence "
          "warns on the coarser half of the ladder, fails on the finer half), and the largest time error at the "
          "method's order or faster (one-sided, tolerance 0.15).",
          "- energy account (friction): the largest |rest| of each run's energy account (H - H0 less the friction "
          "work, the impact law's loss and the forcing work: the integration error) against h: order p or more "
          "(one-sided), or at round-off at every h; a rest that does not fall with h fails (the recorded work is "
          "not what the forces did).",
          "- an order checked against an exact solution whose errors stay large and flat while the runs converge "
          "among themselves (successive differences falling 4x and ending below a tenth of the error) fails: the "
          "method integrates another system. Points within 100x of round-off do not decide an order: where "
          "only they bend it, it warns (the ladder is too fine).", ""]
    return "\n".join(L)


def figure(res, path):
    """Log-log figure of the order checks' errors against h (one panel per check kind, one line per
    method, dashed theoretical slopes). Returns the path written, or None if there is nothing to plot."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    kinds = [k for k in _ORDER_CHECKS if any(c.name == k and c.data.get("h") for c in res.checks)]
    if not kinds:
        return None
    fig, axes = plt.subplots(1, len(kinds), figsize=(4.2 * len(kinds), 3.8), squeeze=False)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, kind in zip(axes[0], kinds):
        for i, c in enumerate(c for c in res.checks if c.name == kind and c.data.get("h")):
            col = colors[i % len(colors)]
            h, e, m = (np.asarray(c.data[k]) for k in ("h", "err", "mask"))
            ok = np.isfinite(e) & (e > 0)
            label = f"{c.method} (slope {c.value:.2f})" if np.isfinite(c.value) else c.method
            ax.loglog(h[ok], e[ok], "-", color=col, lw=1.2)
            ax.loglog(h[ok & m], e[ok & m], "o", color=col, label=label)
            if (ok & ~m).any():   # points the fit did not use (plateau, pre-asymptotic): hollow
                ax.loglog(h[ok & ~m], e[ok & ~m], "o", mfc="none", color=col)
            if m.any():
                hf = h[m].min()
                ef = e[m][np.argmin(h[m])]
                hh = np.array([h.max(), hf])
                ax.loglog(hh, ef * (hh / hf) ** c.data["theory"], "--", color=col, lw=1, alpha=0.8,
                          label=f"slope {c.data['theory']:g}")
        ax.set_title(kind)
        ax.set_xlabel("h")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    axes[0][0].set_ylabel("error")
    fig.suptitle(f"vcirun verify: {res.system}", fontsize=10)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
