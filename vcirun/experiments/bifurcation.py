"""Continuation of a periodic orbit along a parameter, period doubling and the bifurcation diagram.

`continuation` steps the parameter through `values`, each fixed point the guess of the next
(vcirun.experiments.periodic.periodic_orbit). A period doubling is detected where a multiplier
crosses -1 between two values; the crossing is located by the secant method on the most negative
real multiplier (`doubling_point`), and from the next value on the period-two orbit (a fixed point
of the two-impact return map, started from the period-one point displaced along the eigenvector of
the multiplier near -1) is followed instead, its two section points both in the diagram.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from .periodic import PeriodicOrbit, ReturnMap, periodic_orbit


@dataclass
class Branch:
    """One continuation: per parameter value the orbit (k = 1 or 2) and its section points (rows of
    (q, p) just after each impact of one period); `doubling`: the located parameter value where the
    period-one orbit's multiplier crosses -1 (None if it does not in the range)."""

    param: str
    values: list = field(default_factory=list)
    orbits: list = field(default_factory=list)
    points: list = field(default_factory=list)
    doubling: float | None = None

    def to_dict(self) -> dict:
        return {"param": self.param, "values": list(self.values), "doubling": self.doubling,
                "orbits": [o.to_dict() for o in self.orbits], "points": [np.asarray(p).tolist() for p in self.points]}

    def save(self, path) -> None:
        with open(path, "w") as f:
            json.dump(self.to_dict(), f, indent=1)


def _min_real(orbit: PeriodicOrbit) -> float:
    real = [z.real for z in orbit.eigenvalues if abs(z.imag) <= 1e-9 * max(1.0, abs(z))]
    return min(real) if real else np.inf


def doubling_point(system, method, *, h, param, lo, hi, orbit_lo, params=None, tol=1e-7, maxit=30, **kw):
    """The parameter value in [lo, hi] where the period-one orbit's most negative real multiplier is
    -1 (orbit_lo: the orbit at lo, its multiplier > -1; the one at hi below), by the secant method
    safeguarded by the bracket (Illinois). Returns (value, orbit there)."""
    base = dict(params or {})
    x = np.concatenate(orbit_lo.fixed_point)

    def f(v, guess):
        o = periodic_orbit(system, method, h=h, guess=guess, params={**base, param: v}, **kw)
        return _min_real(o) + 1.0, o

    a, fa = lo, _min_real(orbit_lo) + 1.0
    b, (fb, ob) = hi, f(hi, x)
    o = ob
    side = 0
    for _ in range(maxit):
        c = (a * fb - b * fa) / (fb - fa)
        fc, o = f(c, x)
        x = np.concatenate(o.fixed_point)
        if abs(fc) < 1e-12 or abs(b - a) < tol:
            return c, o
        if fc * fa > 0:
            a, fa = c, fc
            if side == 1:
                fb *= 0.5
            side = 1
        else:
            b, fb = c, fc
            if side == -1:
                fa *= 0.5
            side = -1
    return c, o


def continuation(system, method, *, h, param, values, guess, params=None, progress=None, **kw) -> Branch:
    """Follow the orbit from `guess` through the parameter `values` (ascending or descending); at a
    period doubling switch to the period-two orbit (module docstring). progress: see
    vcirun.core.progress (default: a line on stderr with the values done and an estimate of the time
    left, every 10 s once the continuation is estimated to take over 10 s)."""
    from ..core.progress import Progress

    base = dict(params or {})
    br = Branch(param)
    prog = Progress(len(values), f"continuation along {param}", progress)
    x = x1 = guess
    k = 1
    prev = None
    for v in values:
        prm = {**base, param: float(v)}
        if k == 1:
            o = periodic_orbit(system, method, h=h, guess=x, params=prm, **kw)
            if prev is not None and _min_real(prev) > -1.0 >= _min_real(o):
                br.doubling, _ = doubling_point(system, method, h=h, param=param, lo=br.values[-1], hi=float(v),
                                                orbit_lo=prev, params=base, **kw)
                two = _period_two(system, method, h, prm, o, **kw)
                if two is not None:
                    o, k = two, 2
        else:
            # the period-one orbit (unstable now) too: the period-two orbit's seed if Newton on the
            # two-impact map slides onto it from the previous point
            one = periodic_orbit(system, method, h=h, guess=x1, params=prm, **kw)
            o = periodic_orbit(system, method, h=h, guess=x, params=prm, k=2, **kw)
            if _collapsed(_section_points(system, method, h, prm, o)):
                o = _period_two(system, method, h, prm, one, **kw) or o
            x1 = np.concatenate(one.fixed_point)
        pts = _section_points(system, method, h, prm, o)
        br.values.append(float(v))
        br.orbits.append(o)
        br.points.append(pts)
        x = np.concatenate(o.fixed_point)
        if k == 1:
            prev, x1 = o, x
        prog.update(1)
    return br


def _collapsed(pts) -> bool:
    """The section points of a period-two orbit coincide (it is the period-one orbit)."""
    return bool(np.max(np.abs(pts[0] - pts[-1])) <= 1e-6 * (1.0 + np.max(np.abs(pts[0]))))


def _period_two(system, method, h, prm, o1: PeriodicOrbit, displacement=(1e-2, 3e-2, 1e-1), **kw):
    """The period-two orbit next to the period-one orbit o1 whose multiplier has crossed -1: a fixed
    point of the two-impact map from o1's point displaced along that multiplier's eigenvector, accepted
    when its two section points differ (None if no displacement finds one)."""
    x1 = np.concatenate(o1.fixed_point)
    w, V = np.linalg.eig(o1.jacobian)
    v = np.real(V[:, int(np.argmin(w.real))])
    v /= np.max(np.abs(v))
    for eps in displacement:
        try:
            o2 = periodic_orbit(system, method, h=h, guess=x1 + eps * np.max(np.abs(x1)) * v, params=prm, k=2, **kw)
        except RuntimeError:
            continue
        if not _collapsed(_section_points(system, method, h, prm, o2)):
            return o2
    return None


def _section_points(system, method, h, prm, o: PeriodicOrbit) -> np.ndarray:
    """The k section points of an orbit: its fixed point and its images under the one-impact map."""
    x = np.concatenate(o.fixed_point)
    pts = [x]
    if o.k > 1:
        P = ReturnMap(system, method, h=h, params=prm)
        for _ in range(o.k - 1):
            x, _ = P(x)
            pts.append(x)
    return np.array(pts)


def bifurcation_figure(branch: Branch, path, coordinate: int = 0, label: str | None = None) -> None:
    """The bifurcation diagram: coordinate `coordinate` of each section point against the parameter
    (the period-two orbit's two points), the located period doubling marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(6.4, 6.0), sharex=True)
    for v, o, pts in zip(branch.values, branch.orbits, branch.points):
        ax.plot([v] * len(pts), pts[:, coordinate], "o", ms=3, color="C0" if o.k == 1 else "C3")
        ax2.plot([v] * len(o.eigenvalues), o.eigenvalues.real, ".", ms=3, color="C0" if o.k == 1 else "C3")
    if branch.doubling is not None:
        for a in (ax, ax2):
            a.axvline(branch.doubling, color="0.5", lw=0.8, ls="--")
        ax.set_title(f"period doubling at {branch.param} = {branch.doubling:.6g}")
    ax.set_ylabel(label or f"q[{coordinate}] just after the impact")
    ax2.axhline(-1.0, color="0.7", lw=0.6)
    ax2.set_ylabel("multipliers (real part)")
    ax2.set_xlabel(branch.param)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
