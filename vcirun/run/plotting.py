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
    """h as the paper writes it (1E-2, 3.2E-2), to three significant digits (1.25E-3)."""
    m, e = f"{h:.2e}".split("e")
    m = m.rstrip("0").rstrip(".")
    return f"{m}E{int(e)}"


MANY_COORDINATES = 6   # above this, trajectory_figure draws the coordinates together, not a panel each


@styled
def trajectory_figure(tr, dense: bool = True, samples_per_step: int = 8) -> "Figure":
    """One run: each coordinate against t (dense output as a line where the dynamics are available,
    grid states as dots), impacts as dashed lines, and the energies H (and Hmod). Above
    MANY_COORDINATES coordinates (a 20-ball cradle): one panel with every coordinate (coloured by
    index), one image of q_i(t) (coordinate against time), and the energy, in a figure of fixed size."""
    names = tr.coordinate_names
    qu, _, eu = tr._units()
    n = len(names)
    curve = None
    if dense and len(tr.t) > 1:
        try:
            tt = np.linspace(tr.t[0], tr.t[-1], min(200_000, samples_per_step * (len(tr.t) - 1) + 1))
            curve = (tt, tr(tt))
        except ValueError:  # no dynamics for this system: the grid states alone
            curve = None
    if n > MANY_COORDINATES:
        fig, axes = new_figure(3, 1, figsize=(7.0, 7.5), sharex=True, squeeze=False,
                               gridspec_kw={"height_ratios": [3, 3, 2]})
        axes = axes[:, 0]
        _many_coordinates(axes[0], axes[1], tr, curve, names, qu)
        energy_ax = axes[2]
    else:
        fig, axes = new_figure(n + 1, 1, figsize=(6.0, 1.7 * (n + 1) + 0.6), sharex=True, squeeze=False)
        axes = axes[:, 0]
        for i, ax in enumerate(axes[:n]):
            if curve is not None:
                ax.plot(curve[0], curve[1][:, i], color=COLORS[0], linewidth=1.0, label="dense output")
            ax.plot(tr.t, tr.q[:, i], linestyle="none", marker=".", markersize=2.5, color=COLORS[1],
                    label="grid states")
            ax.set_ylabel(f"{names[i]}" + (f" [{qu[i]}]" if qu[i] else ""))
            ax.grid(True, linewidth=0.3, alpha=0.5)
        axes[0].legend(frameon=False, fontsize=7)
        energy_ax = axes[n]
    ax = energy_ax
    ax.plot(tr.t, tr.H, color=COLORS[0], label=r"$H$")
    if tr.Hmod is not None:
        ax.plot(tr.t, tr.Hmod, color=COLORS[2], linestyle="-.", label="truncated MH")
    ax.set_ylabel("energy" + (f" [{eu}]" if eu else ""))
    ax.grid(True, linewidth=0.3, alpha=0.5)
    ax.legend(frameon=False, fontsize=7)
    for a in axes:
        for ti in tr.impacts:
            a.axvline(ti, color="0.4", linestyle=(0, (4, 3)), linewidth=0.7)
    axes[-1].set_xlabel(r"$t$ [s]")
    fig.suptitle(f"{tr.system}, {tr.method}, h = {fmt_h(tr.h)}" + (f", beta = {tr.beta:g}" if tr.beta is not None
                                                                     else "")
                 + ("" if tr.ok else f" [{tr.status}]") + "; dashed lines: impacts", fontsize=9)
    return fig


def _many_coordinates(lines_ax, image_ax, tr, curve, names, qu):
    """Every coordinate in one panel (colour: index) and as an image, coordinate against time."""
    import matplotlib

    n = len(names)
    cmap = matplotlib.colormaps["viridis"]
    t, Q = (curve if curve is not None else (tr.t, tr.q))
    for i in range(n):
        lines_ax.plot(t, Q[:, i], color=cmap(i / max(n - 1, 1)), linewidth=0.8)
    unit = qu[0] if len(set(qu)) == 1 and qu[0] else ""
    lines_ax.set_ylabel("coordinates" + (f" [{unit}]" if unit else ""))
    lines_ax.grid(True, linewidth=0.3, alpha=0.5)
    lines_ax.set_title(f"{n} coordinates, coloured from {names[0]} (dark) to {names[-1]} (light)", fontsize=8)
    step = max(1, len(t) // 2000)
    im = image_ax.imshow(Q[::step].T, aspect="auto", origin="lower", interpolation="nearest", cmap="RdBu_r",
                         extent=(t[0], t[-1], -0.5, n - 0.5), vmin=-np.max(np.abs(Q)), vmax=np.max(np.abs(Q)))
    ticks = sorted(set(np.linspace(0, n - 1, min(n, 8)).round().astype(int)))
    image_ax.set_yticks(ticks)
    image_ax.set_yticklabels([names[k] for k in ticks], fontsize=7)
    image_ax.figure.colorbar(im, ax=image_ax, pad=0.01, fraction=0.04, label=unit)
