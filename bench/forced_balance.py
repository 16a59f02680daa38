"""Forced systems: observed orders and the modified energy balance of the MCVA family.

    python bench/forced_balance.py [--T 5]

For a forced system the truncated modified Hamiltonian H~ of the conservative discrete Lagrangian is
not conserved; along the modified flow with the force (the MCVA family's partial steps) it obeys
dH~/dt = f(q, dH~/dp, t) . dH~/dp. The balance B(t) = H~(t) - H~(0) - int_0^t f . dH~/dp measures
how far the discrete motion (full steps by the forced DEL, partial steps by the forced Gauss flow,
resets conserving H~) is from that law. Printed per scene, method, mh_order and h: max |B| over the
grid, the impact count, and the fitted slope of max |B| against h. The integral is computed on the
grid by composite Simpson between impact steps (fourth order) and by the trapezoid on the two
pieces of an impact step, split at the recorded impact states (f . dH~/dp jumps there): the
quadrature error is then O(h^4) + O(h^3) per impact, below the balance itself.

Printed only, never asserted; docs/derivations/forcing.md quotes one run.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import vcirun  # noqa: E402
from vcirun.run import resolve  # noqa: E402
from vcirun.methods.table import resolve_method  # noqa: E402

CART_DRAG = {
    "name": "cart_drag", "coordinates": ["y", "theta"],
    "parameters": {"m1": 1.0, "m2": 0.2, "L": 2.0, "g": 10.0, "c": 0.3, "b": 0.05},
    "mass_matrix": [["m1 + m2", "m2*L*sin(theta)"], ["m2*L*sin(theta)", "m2*L**2"]],
    "potential": "(m1 + m2)*g*y - m2*g*L*cos(theta)", "constraint": "y",
    "forcing": ["-c*y_dot", "-b*theta_dot + 0.1*sin(2*t)"]}


def _power_and_energy(mod, prm, h, q, p, t):
    """(f . dH~/dp, H~) at one state."""
    n = q.shape[0]
    u = np.empty(mod.MH_M)
    W = np.empty((mod.MH_M, mod.MH_M))
    grad = np.empty(2 * n)
    mod.mh_guess(q, p, prm, u)
    it, E = mod.mh_gradient(q, p, h, prm, u, W, grad, np.empty((0, 0)))
    v = grad[n:].copy()
    return mod.force_power(q, v, t, prm), E


def _simpson(y, h):
    """Composite Simpson on equally spaced samples (3/8 rule for the last three intervals of an odd
    count; trapezoid for one interval)."""
    m = len(y) - 1
    if m <= 0:
        return 0.0
    if m == 1:
        return 0.5 * h * (y[0] + y[1])
    s = 0.0
    end = m if m % 2 == 0 else m - 3
    if end > 0:
        s += h / 3 * (y[0] + 4 * y[1:end:2].sum() + 2 * y[2:end - 1:2].sum() + y[end])
    if m % 2 == 1:
        a = end
        s += 3 * h / 8 * (y[a] + 3 * y[a + 1] + 3 * y[a + 2] + y[a + 3])
    return s


def balance(system, method, h, T, q0, p0, **mopts):
    """(max |B|, impacts, status) of one run."""
    tr = vcirun.simulate(system, method, h=h, T=T, q0=q0, p0=p0, **mopts)
    if not tr.ok:
        return np.nan, len(tr.impacts), tr.status
    meth = resolve_method(method, **mopts)
    d, load, _ = resolve.resolve_numeric(system, meth.kernel_set())
    mod = load()
    prm = d.param_values()
    P = np.empty(len(tr.t))
    E = np.empty(len(tr.t))
    for k in range(len(tr.t)):
        P[k], E[k] = _power_and_energy(mod, prm, h, tr.q[k], tr.p[k], tr.t[k])
    # work on each grid interval: Simpson over runs of smooth steps, split trapezoid on impact steps
    work = np.zeros(len(tr.t))
    imp_steps = np.flatnonzero(tr.impact_step)
    j = 0  # next impact record
    a = 0
    for k in list(imp_steps) + [len(tr.t) - 1]:
        # smooth stretch a..k (grid indices), Simpson on each prefix would be O(N^2): accumulate
        # Simpson on the stretch end and trapezoid for the intermediate values
        if k > a:
            tot = _simpson(P[a:k + 1], h)
            trap = np.concatenate([[0.0], np.cumsum(0.5 * h * (P[a:k] + P[a + 1:k + 1]))])
            work[a:k + 1] = work[a] + trap * (tot / trap[-1] if trap[-1] != 0 else 1.0)
        if k == len(tr.t) - 1 and k not in imp_steps:
            break
        # impact step k -> k+1: pieces between the grid points and the recorded impact states
        t_prev, P_prev, w = tr.t[k], P[k], work[k]
        while j < len(tr.impacts) and tr.impacts[j] < tr.t[k + 1] + 1e-15:
            ti = tr.impacts[j]
            Pm, _ = _power_and_energy(mod, prm, h, tr.impact_q[j], tr.impact_p_minus[j], ti)
            Pp, _ = _power_and_energy(mod, prm, h, tr.impact_q[j], tr.impact_p_plus[j], ti)
            w += 0.5 * (ti - t_prev) * (P_prev + Pm)
            t_prev, P_prev = ti, Pp
            j += 1
        work[k + 1] = w + 0.5 * (tr.t[k + 1] - t_prev) * (P_prev + P[k + 1])
        a = k + 1
    B = E - E[0] - work
    return float(np.max(np.abs(B))), len(tr.impacts), tr.status


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--T", type=float, default=5.0)
    a = ap.parse_args(argv)
    from vcirun.mechanics.loader import load_system_yaml

    scenes = [("damped_oscillator (c = 0.5, wall d = 0.5)",
               vcirun.run.resolve.resolve_system("damped_oscillator"), dict(c=0.5, d=0.5), [1.5], [0.0]),
              ("cart_drag (2-DOF, drag + drive)", load_system_yaml(CART_DRAG), {}, [1.5, 0.0], [0.0, 0.6])]
    hs = [2e-2, 1e-2, 5e-3, 2.5e-3]
    cases = [("MCVA", dict(ld="SVC", mh_order=s)) for s in (2, 3, 4)] + [("MCVA", dict(ld="SVA", mh_order=4))]
    print(f"# modified energy balance max|B| over [0, {a.T}] (load {os.getloadavg()[0]:.2f})")
    for label, sysm, params, q0, p0 in scenes:
        for k, v in params.items():
            sysm.params[k] = v
        print(f"\n## {label}")
        print("| method | " + " | ".join(f"h = {h:g}" for h in hs) + " | slope | impacts |")
        print("|---|" + "---|" * (len(hs) + 2))
        for m, kw in cases:
            vals, imps = [], []
            for h in hs:
                b, ni, st = balance(sysm, m, h, a.T, q0, p0, **kw)
                vals.append(b)
                imps.append(ni)
            v = np.array(vals)
            slope = np.polyfit(np.log(hs), np.log(v), 1)[0] if np.all(np.isfinite(v)) else np.nan
            name = f"MCVA[{kw['ld']}, s={kw['mh_order']}]"
            print(f"| {name} | " + " | ".join(f"{x:.2e}" for x in vals) + f" | {slope:.2f} | {imps} |", flush=True)


if __name__ == "__main__":
    main()
