"""Plots of one run (`Trajectory.plot`) and the style every vcirun figure shares: matplotlib only, no
vcirun layer below, so the result object can plot itself without importing the experiment layer.
Figures are built without pyplot (no backend chosen, pyplot's registry untouched) inside a local
style context (never global rcParams): safe in a notebook."""
from __future__ import annotations

import functools

import numpy as np

# Colour per method (Okabe-Ito, colour-blind safe), line style per step size.
COLORS = ["#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#F0E442", "#000000"]
LINE_STYLES = ["-", "--", ":", "-."]
MARKERS = ["o", "s", "^", "D", "v", "P"]

STYLE = {
    "font.family": "serif", "font.size": 9, "axes.labelsize": 10, "legend.fontsize": 8,
    "axes.linewidth": 0.8, "lines.linewidth": 1.1, "lines.markersize": 3.0, "savefig.bbox": "tight",
    "pdf.fonttype": 42, "ps.fonttype": 42,  # embed TrueType, editable text in the PDF
}


def style():
    """The local style context of every figure (never global rcParams)."""
    import matplotlib

    return matplotlib.rc_context(STYLE)


def styled(fn):
    """Build the figure inside the style context and lay it out there (text created at draw time
    then keeps the style when a notebook draws it later, outside the context)."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with style():
            fig = fn(*args, **kwargs)
            fig.draw_without_rendering()
        return fig
    return wrapper


def new_figure(nrows=1, ncols=1, *, figsize, **kw):
    """(Figure, axes) without pyplot: no backend is selected and pyplot's figure registry is untouched."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout="constrained")
    axes = fig.subplots(nrows, ncols, **kw)
    return fig, axes

def fmt_h(h: float) -> str:
    m, e = f"{h:.1e}".split("e")
    m = m.rstrip("0").rstrip(".")
    return f"{m}E{int(e)}"


@styled
def trajectory_figure(tr, dense: bool = True, samples_per_step: int = 8) -> "Figure":
    """One run: each coordinate against t (dense output as a line where the dynamics are available,
    grid states as dots), impacts as dashed lines, and the energies H (and Hmod)."""
    names = tr.coordinate_names
    qu, _, eu = tr._units()
    n = len(names)
    fig, axes = new_figure(n + 1, 1, figsize=(6.0, 1.7 * (n + 1) + 0.6), sharex=True, squeeze=False)
    axes = axes[:, 0]
    curve = None
    if dense and len(tr.t) > 1:
        try:
            tt = np.linspace(tr.t[0], tr.t[-1], min(200_000, samples_per_step * (len(tr.t) - 1) + 1))
            curve = (tt, tr(tt))
        except ValueError:  # no dynamics for this system: the grid states alone
            curve = None
    for i, ax in enumerate(axes[:n]):
        if curve is not None:
            ax.plot(curve[0], curve[1][:, i], color=COLORS[0], linewidth=1.0, label="dense output")
        ax.plot(tr.t, tr.q[:, i], linestyle="none", marker=".", markersize=2.5, color=COLORS[1],
                label="grid states")
        ax.set_ylabel(f"{names[i]}" + (f" [{qu[i]}]" if qu[i] else ""))
        ax.grid(True, linewidth=0.3, alpha=0.5)
    ax = axes[n]
    ax.plot(tr.t, tr.H, color=COLORS[0], label=r"$H$")
    if tr.Hmod is not None:
        ax.plot(tr.t, tr.Hmod, color=COLORS[2], linestyle="-.", label="truncated MH")
    ax.set_ylabel("energy" + (f" [{eu}]" if eu else ""))
    ax.grid(True, linewidth=0.3, alpha=0.5)
    ax.legend(frameon=False, fontsize=7)
    axes[0].legend(frameon=False, fontsize=7)
    for a in axes:
        for ti in tr.impacts:
            a.axvline(ti, color="0.4", linestyle=(0, (4, 3)), linewidth=0.7)
    axes[-1].set_xlabel(r"$t$ [s]")
    fig.suptitle(f"{tr.system}, {tr.method}, h = {fmt_h(tr.h)}" + (f", beta = {tr.beta:g}" if tr.beta is not None
                                                                     else "")
                 + ("" if tr.ok else f" [{tr.status}]") + "; dashed lines: impacts", fontsize=9)
    return fig
