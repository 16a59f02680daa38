"""`make bench` section `friction`: the frictional impact law (vcirun/collision/friction_law.py,
docs/derivations/friction.md "Frictional impacts"), printed, never asserted.

Rows:
  energy  the kinetic energy change of 10^4 random frictional impacts (planar rigid bodies: one or two
          bodies, masses 0.05-20, inertias, one to six contacts at random points with random normal
          angles, half of the sets on one floor (collinear, dependent rows), a duplicated contact in
          a quarter of them, restitution equal or mixed, mu in [0, 3] with zeros and 1e3 among them,
          every contact approaching or at rest): the largest Delta T / T-, how many Delta T > 0 beyond
          round-off (1e-12 T-), the case codes, and, on the one-contact impacts, how many Newton's law
          with Coulomb on the final slip (tangential restitution 0: Kane's law) would have gained
  cost    microseconds per impact, friction_impact_law against impact_law on the same normal rows, for
          k = 1, 2, 8, 50 contacts: coupled (a random mechanism of 2k + 3 degrees of freedom, every row
          coupled: one Lemke problem of up to 6k unknowns) and uncoupled (k spinning balls landing on a
          floor); both called from a compiled loop (no Python overhead), medians of repeats

Run alone: python bench/friction_bench.py [--quick] [--out results/friction_bench.json]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def log(msg=""):
    print(msg, flush=True)


def compiled_unit():
    """The compiled unit, as the exact reference loads it (vcirun.reference_solution.friction_law)."""
    from vcirun.reference_solution.friction_law import friction_law_module

    return friction_law_module()


# --- random impacts ------------------------------------------------------------------------------------

def _rows(ang, r, body, nb):
    n = np.array([np.cos(ang), np.sin(ang)])
    t = np.array([-n[1], n[0]])
    gn, gt = np.zeros(3 * nb), np.zeros(3 * nb)
    for g, d in ((gn, n), (gt, t)):
        g[3 * body: 3 * body + 2] = d
        g[3 * body + 2] = r[0] * d[1] - r[1] * d[0]
    return gn, gt


def random_impact(rng):
    """(W, u, e, mu, T-) of a random impact of planar rigid bodies (see the module docstring), or None."""
    nb = int(rng.integers(1, 3))
    masses = rng.uniform(0.05, 20.0, nb)
    inertias = rng.uniform(0.01, 3.0, nb)
    k = int(rng.integers(1, 7))
    floor = rng.random() < 0.5
    contacts = [(int(rng.integers(0, nb)), rng.uniform(-1, 1, 2), np.pi / 2 if floor else rng.uniform(0, 2 * np.pi))
                for _ in range(k)]
    if rng.random() < 0.25:
        contacts.append(contacts[int(rng.integers(0, k))])
    Mdiag = np.concatenate([[m, m, m * j] for m, j in zip(masses, inertias)])
    G_n, G_t = zip(*(_rows(a, r, b, nb) for b, r, a in contacts))
    G = np.array(G_n + G_t)
    qdot = rng.uniform(-3, 3, 3 * nb)
    u = G @ qdot
    kk = len(contacts)
    keep = [i for i in range(kk) if u[i] <= 0.0]
    if not keep or np.min(u[:kk]) > -1e-3:
        return None
    rows = keep + [kk + i for i in keep]
    W = G @ np.diag(1 / Mdiag) @ G.T
    W = 0.5 * (W + W.T)
    W, u = np.ascontiguousarray(W[np.ix_(rows, rows)]), u[rows]
    k = len(keep)
    e = np.full(k, rng.uniform(0, 1)) if rng.random() < 0.5 else rng.uniform(0, 1, k)
    mu = np.where(rng.random(k) < 0.5, rng.uniform(0, 3, k), rng.choice([0.0, 0.1, 0.5, 1.0, 2.0, 3.0, 1e3], k))
    return W, u, e, mu, 0.5 * float(qdot @ (Mdiag * qdot))


def kane_gain(W, u, e, mu):
    """Delta T of Newton's law with Coulomb on the final slip (one contact): stick if the impulse to
    u+ = (e |u-_n|, 0) is in the cone, else slide with lam_t = -s mu lam_n and u+_n = -e u-_n; None if
    neither is consistent (a jam)."""
    lam = np.linalg.solve(W, np.array([-e * u[0], 0.0]) - u)
    if lam[0] >= 0 and abs(lam[1]) <= mu * lam[0]:
        return float(lam @ u + 0.5 * lam @ W @ lam)
    for s in (1.0, -1.0):
        den = W[0, 0] - s * mu * W[0, 1]
        if den <= 0:
            continue
        P = -(1 + e) * u[0] / den
        lam = np.array([P, -s * mu * P])
        if s * (u + W @ lam)[1] >= 0:
            return float(lam @ u + 0.5 * lam @ W @ lam)
    return None


def row_energy(law, count, seed=20240601):
    rng = np.random.default_rng(seed)
    worst, gains, fails, codes = -np.inf, 0, 0, {}
    one, kane_gains = 0, 0
    n = 0
    t0 = time.perf_counter()
    while n < count:
        case = random_impact(rng)
        if case is None:
            continue
        W, u, e, mu, T = case
        lam = np.empty(len(u))
        code = int(law.friction_impact_law(W, u, e, mu, lam))
        codes[code] = codes.get(code, 0) + 1
        n += 1
        if code < 0:
            fails += 1
            continue
        dT = float(lam @ u + 0.5 * lam @ W @ lam)
        worst = max(worst, dT / T)
        gains += dT > 1e-12 * T
        if len(e) == 1 and mu[0] > 0 and W[1, 1] > 0:
            one += 1
            g = kane_gain(W, u, e[0], mu[0])
            kane_gains += g is not None and g > 1e-12 * T
    out = {"impacts": n, "max_dT_over_T": worst, "gains_beyond_roundoff": gains, "failures": fails,
           "codes": {str(c): v for c, v in sorted(codes.items())}, "one_contact_impacts": one,
           "kane_law_gains_on_those": kane_gains, "seconds": time.perf_counter() - t0}
    log(f"  energy: {n} random frictional impacts: max Delta T / T- = {worst:.3g}, "
        f"{gains} with Delta T > 1e-12 T- (target 0), {fails} failures, codes {out['codes']}")
    log(f"          Newton's law with Coulomb on the final slip on the {one} one-contact impacts: "
        f"{kane_gains} gain energy")
    return out


# --- cost ----------------------------------------------------------------------------------------------

def coupled(k, rng):
    """A random mechanism: G (2k x n) Gaussian, n = 2k + 3, M = B B^T + n I, so W = G M^-1 G^T is positive
    definite and every u- is a velocity of the system; every contact approaching (u-_n <= -0.1)."""
    n = 2 * k + 3
    G = rng.normal(size=(2 * k, n))
    B = rng.normal(size=(n, n))
    W = G @ np.linalg.inv(B @ B.T + n * np.eye(n)) @ G.T
    W = 0.5 * (W + W.T)
    u = G @ rng.normal(size=n)
    u[:k] = -np.abs(u[:k]) - 0.1
    return np.ascontiguousarray(W), u


def balls(k, rng):
    """k spinning balls landing on a floor: W diagonal, k groups of one contact."""
    R, m = 0.05, 0.2
    Iz = 0.4 * m * R * R
    W = np.diag(np.concatenate([np.full(k, 1 / m), np.full(k, 1 / m + R * R / Iz)]))
    u = np.concatenate([-rng.uniform(0.5, 2.0, k), rng.uniform(-2.0, 2.0, k)])
    return W, u


def _drivers(law):
    from numba import njit

    fil = law.friction_impact_law
    il = law.impact_law

    @njit(cache=False)
    def run_friction(W, u, e, mu, lam, reps):
        c = 0
        for _ in range(reps):
            c = fil(W, u, e, mu, lam)
        return c

    @njit(cache=False)
    def run_impact(Wn, un, e, lam, reps):
        c = 0
        for _ in range(reps):
            c = il(Wn, un, e, lam)
        return c

    return run_friction, run_impact


def _time(fn, args, reps, repeats):
    fn(*args, 1)
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn(*args, reps)
        ts.append((time.perf_counter() - t) / reps)
    return statistics.median(ts)


def row_cost(law, ks=(1, 2, 8, 50), quick=False):
    rng = np.random.default_rng(7)
    run_friction, run_impact = _drivers(law)
    out = []
    log("  cost: microseconds per impact (median of repeats, compiled loop); e = 0.5, mu = 0.6")
    log(f"    {'k':>4} {'layout':>9} {'friction law':>13} {'impact_law':>11} {'ratio':>7}  code")
    for k in ks:
        for layout, make in (("coupled", coupled), ("uncoupled", balls)):
            W, u = make(k, rng)
            e, mu = np.full(k, 0.5), np.full(k, 0.6)
            lam = np.empty(2 * k)
            Wn, un, lam1 = np.ascontiguousarray(W[:k, :k]), u[:k].copy(), np.empty(k)
            reps = max(1, int(2e4 / (k * k))) if not quick else 3
            repeats = 3 if quick else 7
            tf = _time(run_friction, (W, u, e, mu, lam), reps, repeats)
            ti = _time(run_impact, (Wn, un, e, lam1), reps, repeats)
            code = int(law.friction_impact_law(W, u, e, mu, lam))
            dT = float(lam @ u + 0.5 * lam @ W @ lam)
            out.append({"k": k, "layout": layout, "friction_us": tf * 1e6, "impact_law_us": ti * 1e6,
                        "ratio": tf / ti, "code": code, "dT": dT})
            log(f"    {k:>4} {layout:>9} {tf * 1e6:>13.2f} {ti * 1e6:>11.2f} {tf / ti:>7.1f}  {code}")
    return out


def section_friction(res, quick=False):
    log("== friction: the frictional impact law ==")
    log(f"  load average at start: {os.getloadavg()}")
    law = compiled_unit()
    out = {"energy": row_energy(law, 500 if quick else 10_000), "cost": row_cost(law, quick=quick)}
    out["loadavg_end"] = os.getloadavg()
    log(f"  load average at end: {out['loadavg_end']}")
    res["friction"] = out
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(ROOT / "results" / "friction_bench.json"))
    a = ap.parse_args(argv)
    res = {}
    section_friction(res, quick=a.quick)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=1, default=float))
    log(f"  written {a.out}")


if __name__ == "__main__":
    main()
