"""The animation of one run: `Trajectory.animate`, `vcirun animate`.

Each frame shows the mechanism at time t (drawn from the scene's geometry, vcirun.mechanics.drawing; without
one, the configuration itself: the point q in the plane of its two coordinates with the constraint
boundaries phi_i = 0, a point on a line for one coordinate, one bar per coordinate for more), a star
where an impact happened in the last 0.1 s of motion time, the energy beside it (H on the grid, and
H0 plus the energy account's terms: where H drops with the impact law's loss the two agree, and the
gap between them is the integration error), and a time bar with every impact as a tick.

States between grid points come from the dense output (`tr(t)`: cubic Hermite pieces split at the
impacts, so a frame just after an impact shows the post-impact state). Frames are taken every
speed / fps seconds of motion time (speed 1: real time) and capped at max_frames, with the speed raised
to fit. Figures are built without pyplot (no backend is chosen, no global state changes); `save`
writes MP4 through ffmpeg when it is on the PATH, else GIF through Pillow (matplotlib's dependency).
"""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from .plotting import COLORS, fmt_h, style

__all__ = ["Animation", "animate", "MAX_FRAMES", "FPS"]

FPS = 30
MAX_FRAMES = 600
IMPACT_MARK_S = 0.1   # how long (motion time) an impact star stays
FOLLOW = 3.0          # the motion spans more than this many times one frame's extent: the view follows


def animate(traj, path=None, *, system=None, fps=FPS, speed=None, max_frames=MAX_FRAMES, energy=True, dpi=100):
    """An Animation of `traj` (see the module docstring); written to `path` (.mp4 or .gif) when given.
    system: the scene to draw (built-in name, YAML path or MechanicalSystem; default: the run's system,
    which works for built-in scenes); energy: show the energy panel."""
    anim = Animation(traj, system=system, fps=fps, speed=speed, max_frames=max_frames, energy=energy, dpi=dpi)
    if path is not None:
        anim.save(path)
    return anim


def _resolve(traj, system):
    """(MechanicalSystem or None, note): the scene a run is drawn from."""
    from .resolve import resolve_system

    target = system if system is not None else (traj.source if traj.source is not None else traj.system)
    try:
        return resolve_system(target), ""
    except (ValueError, OSError) as e:
        if system is not None:
            raise
        return None, (f"system {traj.system!r} is not a built-in scene ({' '.join(str(e).split())[:80]}); "
                      "drawn in configuration space (give system= its YAML path to draw it)")


def check_args(fps, speed, max_frames, dpi):
    """The animation's options (ValueError naming the field)."""
    from ..core.values import check_number

    check_number("fps", fps, ge=0.01, le=240)   # (a GIF frame lasts at most 655 s)
    if speed is not None:
        check_number("speed", speed, gt=0)
    check_number("max_frames", max_frames, integer=True, ge=2, le=100_000)
    check_number("dpi", dpi, gt=10, le=1000)


class Animation:
    """Frames of one run (see the module docstring). times: the motion time of each frame; speed: motion
    seconds per second of animation; frame(i): frame i as an RGB array; save(path); in a notebook the
    object displays itself (HTML, every frame embedded)."""

    def __init__(self, traj, *, system=None, fps=FPS, speed=None, max_frames=MAX_FRAMES, energy=True, dpi=100):
        check_args(fps, speed, max_frames, dpi)
        if len(traj.t) < 2:
            if getattr(traj, "status", "ok") != "ok":   # a run that stopped in its first step: nothing moved
                raise ValueError(f"animate: the run ended at its start with status {traj.status}: "
                                 f"{getattr(traj, 'message', '')}")
            raise ValueError("animate: the trajectory holds fewer than two grid states (stored with "
                             "store_trajectories: false?)")
        self.traj, self.fps, self.dpi = traj, float(fps), float(dpi)
        self.system, self.note = _resolve(traj, system)
        if system is not None and traj.dynamics is None:
            traj.attach_dynamics(system)
        t0, t1 = float(traj.t[0]), float(traj.t[-1])
        span = t1 - t0
        self.speed = float(speed) if speed is not None else 1.0
        n = int(np.floor(span * self.fps / self.speed + 1e-9)) + 1
        if n > max_frames:
            n = int(max_frames)
            self.speed = span * self.fps / (n - 1)
        self.times = t0 + np.arange(n) * self.speed / self.fps
        self.times[-1] = min(self.times[-1], t1)
        self.Q = self._states()
        self.impacts = np.asarray(traj.impacts, float)
        self.impact_contact = np.asarray(traj.impact_contact, int)
        self._build(energy)

    # --- states ------------------------------------------------------------------------------------
    def _states(self):
        tr = self.traj
        try:
            return np.asarray(tr(self.times), float)
        except ValueError:   # no dynamics for dense output: linear between the grid states
            self.note = (self.note + "; " if self.note else "") + "states interpolated linearly between grid points"
            return np.column_stack([np.interp(self.times, tr.t, tr.q[:, j]) for j in range(tr.q.shape[1])])

    @property
    def n_frames(self) -> int:
        return len(self.times)

    # --- the figure --------------------------------------------------------------------------------
    def _build(self, energy):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        tr = self.traj
        with style():
            fig = Figure(figsize=(8.0, 4.0) if energy else (5.0, 4.0), dpi=self.dpi)
            FigureCanvasAgg(fig)
            gs = fig.add_gridspec(2, 2 if energy else 1, height_ratios=[12, 1], width_ratios=[1.15, 1] if energy else [1],
                                  left=0.07, right=0.97, top=0.86, bottom=0.08, hspace=0.35, wspace=0.25)
            self.scene_ax = fig.add_subplot(gs[0, 0])
            self.energy_ax = fig.add_subplot(gs[0, 1]) if energy else None
            self.bar_ax = fig.add_subplot(gs[1, :])
            self.figure = fig
            title = (f"{tr.system}, {tr.method}, h = {fmt_h(tr.h)}" + (f", beta = {tr.beta:g}" if tr.beta is not None
                                                                        else "")
                     + ("" if tr.ok else f" [{tr.status}]") + f"; {self.speed:.3g}x speed")
            fig.suptitle(title, fontsize=9)
            drawing = getattr(self.system, "drawing", None) if self.system is not None else None
            self.scene = (_BodyScene(self, drawing) if drawing is not None else _ConfigScene(self))
            self._time_bar()
            self.energy = _EnergyPanel(self) if energy else None
        self._drawn = -1

    def _time_bar(self):
        ax, tr = self.bar_ax, self.traj
        t0, t1 = float(tr.t[0]), float(tr.t[-1])
        ax.set_xlim(t0, t1)
        ax.set_ylim(0, 1)
        ax.set_yticks([])
        ax.tick_params(axis="x", labelsize=7, pad=1)
        ax.vlines(self.impacts, 0, 1, color="#D55E00", linewidth=0.6, alpha=0.8)
        self._bar = ax.barh([0.5], [0.0], left=t0, height=1.0, color=COLORS[0], alpha=0.35)[0]
        self._clock = ax.text(0.995, 1.25, "", transform=ax.transAxes, ha="right", va="bottom", fontsize=8)
        ax.set_xlabel(f"t [s]  (ticks: {len(self.impacts)} impacts)", fontsize=7, labelpad=1)

    def draw_frame(self, i: int):
        """Update every artist to frame i."""
        i = int(i)
        if not 0 <= i < self.n_frames:
            raise IndexError(f"frame {i} outside 0..{self.n_frames - 1}")
        t = float(self.times[i])
        self.scene.update(i, t)
        if self.energy is not None:
            self.energy.update(t)
        self._bar.set_width(t - float(self.traj.t[0]))
        self._clock.set_text(f"t = {t:.3f} s")
        self._drawn = i

    def _animated(self) -> list:
        """[(axes, artist)] of everything that changes from frame to frame."""
        out = [(self.scene_ax, a) for a in self.scene.artists]
        if self.energy is not None:
            out += [(self.energy_ax, a) for a in self.energy.artists]
        return out + [(self.bar_ax, self._bar), (self.bar_ax, self._clock)]

    def frame(self, i: int) -> np.ndarray:
        """Frame i rendered: an (height, width, 3) uint8 array. The static parts (axes, ticks, the energy
        curves, the time bar's impact ticks) are drawn once; each frame restores them and draws the
        artists that move."""
        canvas = self.figure.canvas
        with style():
            if getattr(self, "_background", None) is None:
                for _, a in self._animated():
                    a.set_animated(True)
                canvas.draw()
                self._background = canvas.copy_from_bbox(self.figure.bbox)
            canvas.restore_region(self._background)
            self.draw_frame(i)
            for ax, a in self._animated():
                ax.draw_artist(a)
            return np.asarray(canvas.buffer_rgba())[..., :3].copy()

    def to_pixels(self, ax, x, y):
        """(row, column) of the data point (x, y) of axes `ax` in `frame`'s array (after a frame is drawn)."""
        px, py = ax.transData.transform((x, y))
        h = self.figure.canvas.get_width_height()[1]
        return int(round(h - py)), int(round(px))

    def save(self, path) -> Path:
        """Write every frame to `path`: .gif (Pillow, a 64-colour palette per frame) or .mp4 (H.264
        through ffmpeg, which must be on the PATH). Returns the path."""
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix not in (".mp4", ".gif"):
            raise ValueError(f"output: unknown animation format {path.suffix or '(none)'!r} of {path}; use .gif or .mp4")
        if suffix == ".mp4" and shutil.which("ffmpeg") is None:
            raise ValueError(f"output: {path} needs ffmpeg on the PATH for MP4; write .gif instead (Pillow)")
        path.parent.mkdir(parents=True, exist_ok=True)
        frames = (self.frame(i) for i in range(self.n_frames))
        (_write_mp4 if suffix == ".mp4" else _write_gif)(frames, path, self.fps)
        self.path = path
        return path

    def to_html(self) -> str:
        """Every frame as an HTML/JavaScript player (matplotlib's to_jshtml)."""
        from matplotlib import animation as mpl_anim

        with style():
            anim = mpl_anim.FuncAnimation(self.figure, self.draw_frame, frames=self.n_frames,
                                          interval=1000.0 / self.fps, blit=False)
            return anim.to_jshtml(fps=self.fps, default_mode="once")

    def _repr_html_(self) -> str:
        return self.to_html()

    def __repr__(self) -> str:
        return (f"Animation({self.traj.system!r}, {self.traj.method}, frames={self.n_frames}, fps={self.fps:g}, "
                f"speed={self.speed:.3g}x)")


def _write_gif(frames, path, fps):
    from PIL import Image

    def palette(a):
        return Image.fromarray(a).convert("P", palette=Image.Palette.ADAPTIVE, colors=64)

    first = palette(next(frames))
    first.save(path, save_all=True, append_images=(palette(a) for a in frames), duration=1000.0 / fps, loop=0,
               optimize=False)


def _write_mp4(frames, path, fps):
    import subprocess

    first = next(frames)
    h, w = first.shape[:2]
    cmd = ["ffmpeg", "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}", "-r",
           f"{fps:g}", "-i", "-", "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-pix_fmt", "yuv420p", "-vcodec", "libx264",
           str(path)]
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        proc.stdin.write(first.tobytes())
        for a in frames:
            proc.stdin.write(a.tobytes())
        proc.stdin.close()
    except BrokenPipeError:
        pass
    err = proc.stderr.read().decode(errors="replace")
    if proc.wait() != 0:
        raise ValueError(f"output: ffmpeg could not write {path}: {' '.join(err.split())[:300]}")


def _recent(anim, t):
    """Indices of the impacts within IMPACT_MARK_S of motion time before t (at least the last frame step)."""
    window = max(IMPACT_MARK_S, anim.speed / anim.fps)
    return np.flatnonzero((anim.impacts <= t) & (anim.impacts > t - window))


class _BodyScene:
    """The mechanism drawn from its Drawing."""

    def __init__(self, anim, drawing):
        from matplotlib.collections import LineCollection
        from matplotlib.patches import Circle, Polygon

        from ..mechanics.drawing import numeric

        self.anim = anim
        sysm = anim.system
        prm = sysm.param_values((anim.traj.options or {}).get("params"))
        self.nd = nd = numeric(drawing, list(sysm.params), prm)
        self.P = nd.positions(anim.Q)                       # (frames, points, 2)
        self.offsets = self._advances(anim)
        self.P = self.P + self.offsets[:, None, :]
        ax = anim.scene_ax
        ax.set_aspect("equal")
        ax.set_xticks([]), ax.set_yticks([])
        for side in ("top", "right", "bottom", "left"):
            ax.spines[side].set_visible(False)
        self._limits(ax)
        ix = nd.index
        self.lines = []
        for p, nrm in nd.lines:
            tangent = np.array([-nrm[1], nrm[0]])
            self.lines.append(ax.axline(tuple(p), tuple(p + tangent), color="0.25", linewidth=1.4, zorder=1))
        d = drawing
        self.seg_idx = np.array([[ix[a], ix[b]] for a, b in d.segments], int).reshape(-1, 2)
        self.segs = LineCollection([], colors=COLORS[0], linewidths=2.0, zorder=3)
        ax.add_collection(self.segs)
        self.damp_idx = np.array([[ix[a], ix[b]] for a, b in d.dampers], int).reshape(-1, 2)
        self.damps = LineCollection([], colors="0.45", linewidths=1.2, linestyles="--", zorder=2)
        ax.add_collection(self.damps)
        self.spring_idx = [(ix[a], ix[b]) for a, b in d.springs]
        self.springs = [ax.plot([], [], color="0.35", linewidth=1.0, zorder=2)[0] for _ in self.spring_idx]
        self.polys = [(np.array([ix[a] for a in poly]), ax.add_patch(Polygon(np.zeros((len(poly), 2)), closed=True,
                                                                            facecolor=COLORS[5], edgecolor=COLORS[0],
                                                                            alpha=0.85, linewidth=1.4, zorder=3)))
                      for poly in d.polygons]
        self.circles = [(ix[a], ax.add_patch(Circle((0, 0), r, facecolor=COLORS[4], edgecolor="0.2", linewidth=0.8,
                                                    alpha=0.9, zorder=4))) for a, r in nd.radii]
        self.dot_idx = np.array([ix[a] for a in d.dots], int)
        (self.dots,) = ax.plot([], [], "o", color=COLORS[1], markersize=6, zorder=5)
        self.pivot_idx = np.array([ix[a] for a in d.pivots], int)
        (self.pivots,) = ax.plot([], [], "^", color="0.2", markersize=7, zorder=2)
        self.contact_idx = [ix.get(c) if c is not None else None for c in d.contacts]
        (self.marks,) = ax.plot([], [], "*", color="#D55E00", markersize=13, zorder=6)
        if anim.note:
            ax.text(0.0, -0.02, anim.note, transform=ax.transAxes, fontsize=6, va="top", wrap=True)
        self.artists = ([self.damps] + self.springs + [p for _, p in self.polys] + [self.segs]
                        + [p for _, p in self.circles] + [self.pivots, self.dots, self.marks])
        if self.follow:   # the view moves: the lines too
            self.artists = self.lines + self.artists

    def _advances(self, anim):
        """(frames, 2): the drawing's shift at each frame, the sum of the advances of the impacts up to
        its time (walkers); zero without an advance."""
        out = np.zeros((anim.n_frames, 2))
        if self.nd.source.advance is None or not len(anim.impacts):
            return out
        tr = anim.traj
        n = tr.q.shape[1]
        taus, first = np.unique(np.asarray(tr.impacts, float), return_index=True)
        shifts = np.array([self.nd.advance(np.asarray(tr.impact_q, float).reshape(-1, n)[k]) for k in first])
        cum = np.cumsum(shifts, axis=0)
        k = np.searchsorted(taus, anim.times, side="right")
        out[k > 0] = cum[k[k > 0] - 1]
        return out

    def _limits(self, ax):
        P = self.P
        lo, hi = P.min(axis=(0, 1)), P.max(axis=(0, 1))
        radius = max([r for _, r in self.nd.radii], default=0.0)
        frame_ext = float(np.max(P.max(axis=1) - P.min(axis=1))) + 2 * radius
        ext = max(float(np.max(hi - lo)) + 2 * radius, 1e-9)
        self.amp = 0.025 * max(frame_ext, 1e-9)
        self.follow = frame_ext > 0 and ext > FOLLOW * frame_ext
        if self.follow:
            self.half = 0.75 * max(frame_ext, 1e-9)
            c = P.mean(axis=1)
            k = max(1, len(c) // 50)
            self.centres = np.array([c[max(0, i - k):i + k + 1].mean(axis=0) for i in range(len(c))])
            # a window of constant size: the axes box, fixed by the equal aspect at the first full draw, fits
            # every frame's window
            ax.set_xlim(self.centres[0][0] - self.half, self.centres[0][0] + self.half)
            ax.set_ylim(self.centres[0][1] - self.half, self.centres[0][1] + self.half)
        else:
            pad = 0.08 * ext + radius
            ax.set_xlim(lo[0] - pad, hi[0] + pad)
            ax.set_ylim(lo[1] - pad, hi[1] + pad)

    def update(self, i, t):
        P = self.P[i]
        ax = self.anim.scene_ax
        if self.follow:
            c = self.centres[i]
            ax.set_xlim(c[0] - self.half, c[0] + self.half)
            ax.set_ylim(c[1] - self.half, c[1] + self.half)
        self.segs.set_segments(P[self.seg_idx] if len(self.seg_idx) else [])
        self.damps.set_segments(P[self.damp_idx] if len(self.damp_idx) else [])
        for (a, b), line in zip(self.spring_idx, self.springs):
            line.set_data(*_zigzag(P[a], P[b], self.amp))
        for idx, patch in self.polys:
            patch.set_xy(P[idx])
        for a, patch in self.circles:
            patch.set_center(tuple(P[a]))
        self.dots.set_data(P[self.dot_idx, 0], P[self.dot_idx, 1]) if len(self.dot_idx) else self.dots.set_data([], [])
        if len(self.pivot_idx):
            self.pivots.set_data(P[self.pivot_idx, 0], P[self.pivot_idx, 1])
        marks = [self.contact_idx[c] for c in self.anim.impact_contact[_recent(self.anim, t)]
                 if c < len(self.contact_idx) and self.contact_idx[c] is not None]
        self.marks.set_data(P[marks, 0] if marks else [], P[marks, 1] if marks else [])


def _zigzag(a, b, amp, turns=8):
    """A spring drawn between points a and b: `turns` teeth of half-width amp (a fixed coil width)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    d = b - a
    L = float(np.hypot(*d))
    if L == 0:
        return [a[0]], [a[1]]
    u, nrm = d / L, np.array([-d[1], d[0]]) / L
    s = np.linspace(0.0, 1.0, 2 * turns + 3)
    off = np.zeros_like(s)
    off[2:-2:2], off[3:-2:2] = amp, -amp
    pts = a + np.outer(s * L, u) + np.outer(off, nrm)
    return pts[:, 0], pts[:, 1]


class _ConfigScene:
    """No drawing: the configuration itself (two coordinates: the point q in their plane with the
    constraint boundaries; one: a point on a line; more: one bar per coordinate)."""

    def __init__(self, anim):
        self.anim = anim
        tr, ax, Q = anim.traj, anim.scene_ax, anim.Q
        names = tr.coordinate_names
        self.n = n = Q.shape[1]
        self.mod = getattr(tr.dynamics, "module", None)
        self.prm = getattr(tr.dynamics, "prm", None)
        if n == 2:
            lo, hi = Q.min(axis=0), Q.max(axis=0)
            pad = 0.1 * np.maximum(hi - lo, 1e-9)
            ax.set_xlim(lo[0] - pad[0], hi[0] + pad[0])
            ax.set_ylim(lo[1] - pad[1], hi[1] + pad[1])
            ax.set_xlabel(names[0]), ax.set_ylabel(names[1])
            self._boundaries(ax, lo - pad, hi + pad)
            (self.trail,) = ax.plot([], [], color=COLORS[0], linewidth=0.8, alpha=0.6)
            (self.point,) = ax.plot([], [], "o", color=COLORS[1], markersize=7)
        elif n == 1:
            lo, hi = float(Q.min()), float(Q.max())
            pad = 0.1 * max(hi - lo, 1e-9)
            ax.set_xlim(lo - pad, hi + pad)
            ax.set_ylim(-1, 1)
            ax.set_yticks([])
            ax.set_xlabel(names[0])
            ax.axhline(0, color="0.7", linewidth=0.8)
            self._boundaries(ax, np.array([lo - pad]), np.array([hi + pad]))
            (self.point,) = ax.plot([], [], "o", color=COLORS[1], markersize=9)
        else:
            lo, hi = Q.min(axis=0), Q.max(axis=0)
            self.lo, self.width = lo, np.maximum(hi - lo, 1e-12)
            ax.set_xlim(0, 1)
            ax.set_yticks(range(n))
            ax.set_yticklabels(names, fontsize=7)
            ax.set_xlabel("each coordinate between its smallest and largest value")
            self.bars = ax.barh(range(n), np.zeros(n), color=COLORS[0], alpha=0.7)
        (self.marks,) = ax.plot([], [], "*", color="#D55E00", markersize=13, zorder=6)
        self.artists = ([self.trail, self.point] if n == 2 else [self.point] if n == 1 else list(self.bars)) + [self.marks]
        ax.set_title("configuration space (no drawing declared)", fontsize=8)
        if anim.note:
            ax.text(0.0, -0.12, anim.note, transform=ax.transAxes, fontsize=6, va="top", wrap=True)

    def _boundaries(self, ax, lo, hi):
        """phi_i = 0 (dashed) from the compiled constraints, on a grid over the view."""
        if self.mod is None:
            return
        m = int(self.mod.NCON)
        out = np.empty(m)
        if self.n == 2:
            xs, ys = np.linspace(lo[0], hi[0], 121), np.linspace(lo[1], hi[1], 121)
            Z = np.empty((m, len(ys), len(xs)))
            for a, y in enumerate(ys):
                for b, x in enumerate(xs):
                    self.mod.sys_phis(np.array([x, y]), self.prm, out)
                    Z[:, a, b] = out
            for i in range(m):
                if Z[i].min() < 0 < Z[i].max():
                    ax.contour(xs, ys, Z[i], levels=[0.0], colors="0.25", linestyles="--", linewidths=1.0)
        else:
            xs = np.linspace(lo[0], hi[0], 2001)
            Z = np.empty((m, len(xs)))
            for b, x in enumerate(xs):
                self.mod.sys_phis(np.array([x]), self.prm, out)
                Z[:, b] = out
            for i in range(m):
                for k in np.flatnonzero(np.sign(Z[i][:-1]) != np.sign(Z[i][1:])):
                    ax.axvline(xs[k], color="0.25", linestyle="--", linewidth=1.0)

    def update(self, i, t):
        q = self.anim.Q[i]
        recent = len(_recent(self.anim, t)) > 0
        if self.n == 2:
            self.trail.set_data(self.anim.Q[: i + 1, 0], self.anim.Q[: i + 1, 1])
            self.point.set_data([q[0]], [q[1]])
            self.marks.set_data([q[0]] if recent else [], [q[1]] if recent else [])
        elif self.n == 1:
            self.point.set_data([q[0]], [0.0])
            self.marks.set_data([q[0]] if recent else [], [0.0] if recent else [])
        else:
            for bar, v in zip(self.bars, (q - self.lo) / self.width):
                bar.set_width(v)


class _EnergyPanel:
    """H - H(t0) on the grid, the energy account's terms (their sum: what the model removed or added),
    impacts as lines, a cursor at t. The gap between the two curves is the integration error."""

    def __init__(self, anim):
        tr, ax = anim.traj, anim.energy_ax
        eu = tr._units()[2]
        H = np.asarray(tr.H, float)
        self.H0 = H0 = float(H[0])
        self.tr = tr
        ax.plot(tr.t, H - H0, color=COLORS[0], linewidth=1.1, label=r"$H - H(0)$")
        try:
            acc = tr.energy_account()
        except (ValueError, TypeError):
            acc = None
        title = f"energy, H(0) = {H0:.5g}" + (f" {eu}" if eu else "")
        if acc is not None:
            shown = [x for x in acc.terms if np.any(x.series != 0)]
            if shown:
                ax.plot(acc.t, sum(x.series for x in shown), color=COLORS[1], linestyle="--", linewidth=1.0,
                        label=" + ".join(x.name for x in shown))
            title += f"; integration error {acc.error:.2e}"
        ax.set_title(title, fontsize=8)
        for ti in anim.impacts:
            ax.axvline(ti, color="0.6", linestyle=(0, (4, 3)), linewidth=0.5)
        self.cursor = ax.axvline(float(tr.t[0]), color="#D55E00", linewidth=1.0)
        (self.dot,) = ax.plot([], [], "o", color="#D55E00", markersize=4)
        self.artists = [self.cursor, self.dot]
        ax.set_xlabel("t [s]")
        ax.set_ylabel("H - H(0)" + (f" [{eu}]" if eu else ""))
        ax.grid(True, linewidth=0.3, alpha=0.5)
        ax.legend(frameon=False, fontsize=7, loc="best")

    def update(self, t):
        self.cursor.set_xdata([t, t])
        H = np.asarray(self.tr.H, float)
        if np.isfinite(H).any():
            self.dot.set_data([t], [float(np.interp(t, self.tr.t, H)) - self.H0])
