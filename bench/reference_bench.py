"""The exact reference's benchmark (`make bench` section `reference`, or `python bench/reference_bench.py
[--quick]`): printed tables and a dict for bench_all's JSON; never asserted.

1. Cost per built-in scene: one warm `vcirun.reference` (default options: the accuracy check included) on
   the Taylor path and on the DOP853 path (rtol 1e-13), beside one `simulate()` call of each method at
   h = 1e-2 on the same start and T. Medians over repeats.
2. The targets of the reference's issue, in this one process:
   - random states of the unit box (uniform position, velocity components in [-5, 5], e = 1 for half of
     them, else uniform in [0.2, 0.98]; T = 5) whose reference has another event sequence than the closed
     form (vcirun.scenes.oracles.ball_in_box_exact, the floor's Zeno tail aside) -- target 0;
   - the default cart-pendulum reference (beta = 4.2, T = 5), warm, against one MCVAA `simulate()` at
     h = 1e-2 (interleaved calls, medians) -- target <= 4x;
   - the reference's error against an independent solve -- target <= 1e-12: the cart-pendulum solved here
     with heyoka in long double (tolerance 1e-19, equations and elastic reset written out below, no vcirun
     code), max |q_ref - q| on a 2001-point grid over T = 5 for several beta; and the box and the
     oscillator against their closed forms.
   - the 51 references of configs/fig4.yaml (beta in [3.2, 5.2], T = 5) against its 408 runs, serially.
"""
from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import vcirun  # noqa: E402
from vcirun.reference_solution.exact import solve_exact  # noqa: E402
from vcirun.run.resolve import resolve_system  # noqa: E402

METHODS = ["CVA", "VCI", "MCVAA", "MCVAC"]
SCENES = [("cart_pendulum", {"beta": 4.2}, {}, 5.0), ("double_pendulum", {}, {}, 5.0),
          ("oscillator_wall", {}, {}, 10.0), ("bouncing_ball", {}, {"c": 0.5}, 3.0), ("ball_in_box", {}, {"e": 0.8}, 8.0),
          ("newton_cradle_3", {}, {}, 1.0), ("double_pendulum_walls", {}, {"e": 0.9}, 3.0), ("n_pendulum_3", {}, {}, 3.0),
          ("n_pendulum_4", {}, {}, 3.0)]


def log(msg=""):
    print(msg, flush=True)


def median_s(fn, repeats):
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return statistics.median(out)


def cost_per_scene(quick=False) -> dict:
    reps = 3 if quick else 9
    log("== the exact reference per scene (warm, median ms; default options, accuracy check included)")
    log(f"  {'scene':22s} {'T':>5s} {'impacts':>7s} {'Taylor':>9s} {'DOP853':>9s}   "
        + "  ".join(f"{m:>7s}" for m in METHODS) + "   (one simulate() at h = 1e-2)")
    out = {}
    for name, start, params, T in SCENES:
        s = resolve_system(name)
        prm = s.param_values(params)
        q0, p0 = s.initial_state(params=prm, **start)
        row = {"T": T}
        ref = solve_exact(s, q0, p0, prm, T)   # warm: kernels, heyoka integrators
        row["impacts"], row["kind"] = len(ref.impacts), ref.kind
        if ref.kind == "taylor":
            row["taylor_ms"] = 1e3 * median_s(lambda: solve_exact(s, q0, p0, prm, T), reps)
        solve_exact(s, q0, p0, prm, T, path="dop853")
        row["dop853_ms"] = 1e3 * median_s(lambda: solve_exact(s, q0, p0, prm, T, path="dop853"), max(3, reps // 3))
        for m in METHODS:
            kw = dict(h=1e-2, T=T, q0=q0, p0=p0, params=params)
            vcirun.simulate(s, m, **kw)
            row[m] = 1e3 * median_s(lambda: vcirun.simulate(s, m, **kw), reps)
        out[name] = row
        tay = f"{row['taylor_ms']:9.2f}" if "taylor_ms" in row else f"{'-':>9s}"
        log(f"  {name:22s} {T:5g} {row['impacts']:7d} {tay} {row['dop853_ms']:9.2f}   "
            + "  ".join(f"{row[m]:7.2f}" for m in METHODS))
    return out


def _box_wrong(n, seed=2929) -> dict:
    from vcirun.scenes.oracles import ball_in_box_exact

    box = resolve_system("ball_in_box")
    rng = np.random.default_rng(seed)
    wrong, worst, failed, secs = 0, 0.0, 0, 0.0
    for k in range(n):
        x0, y0 = rng.uniform(0.0, 1.0, 2)
        vx, vy = rng.uniform(-5.0, 5.0, 2)
        e = 1.0 if k % 2 == 0 else float(rng.uniform(0.2, 0.98))
        t0 = time.perf_counter()
        try:
            ref = solve_exact(box, [x0, y0], [vx, vy], box.param_values({"e": e}), 5.0)
        except Exception:  # noqa: BLE001 - counted: a refused reference is a failure too
            failed += 1
            continue
        secs += time.perf_counter() - t0
        tt = np.linspace(0.0, 5.0, 1001)
        ex = ball_in_box_exact(tt, x0, y0, vx, vy, width=1.0, height=1.0, g=9.81, e=e)
        it, ic = ex.impact_times, ex.impact_contact
        floor = ref.impacts[ref.impact_contact == 0]
        if any(0 in iv[2] for iv in ref.held_intervals) and len(floor):
            keep = ~((ic == 0) & (it > floor[-1] + 1e-12))
            it, ic = it[keep], ic[keep]
        if list(ic) != list(ref.impact_contact) or not np.isfinite(ref.accuracy):
            wrong += 1
            continue
        worst = max(worst, float(np.max(np.abs(ref(tt) - np.column_stack([ex.x, ex.y])))))
    return {"states": n, "wrong": wrong, "failed": failed, "worst_q_error": worst, "mean_ms": 1e3 * secs / max(1, n)}


def _cart_longdouble(beta, T, ts):
    """The cart-pendulum (m1 = 1, m2 = 0.2, L = 2, g = 10), Xi(beta), elastic impacts on y = 0, solved by
    heyoka in long double: q(ts) (len(ts), 2) and the impact times. Written from the equations: with
    det = m2 L^2 (m1 + m2 - m2 sin^2 th), M^-1 = [[m2 L^2, -m2 L s], [-m2 L s, m1 + m2]] / det, v = M^-1 p,
    dH/dy = (m1 + m2) g, dH/dth = -m2 L cos(th) v_y v_th + m2 g L sin(th); the reset p_y += -2 v_y / (M^-1)_yy."""
    import heyoka as hy

    ld = np.longdouble
    m1, m2, L, g = ld(1), ld("0.2"), ld(2), ld(10)
    y, th, py, pth = hy.make_vars("y", "th", "py", "pth")
    s, c = hy.sin(th), hy.cos(th)
    det = m2 * L * L * (m1 + m2 - m2 * s * s)
    vy = (m2 * L * L * py - m2 * L * s * pth) / det
    vth = (-m2 * L * s * py + (m1 + m2) * pth) / det
    sys_ = [(y, vy), (th, vth), (py, hy.expression(float(-(m1 + m2) * g))),   # -12 exactly
            (pth, m2 * L * c * vy * vth - m2 * g * L * s)]
    ta = hy.taylor_adaptive(sys_, np.zeros(4, dtype=ld), fp_type=ld, tol=ld("1e-19"),
                            t_events=[hy.t_event(y, direction=hy.event_direction.negative, fp_type=ld)])
    q0 = np.array([beta, 0.0], dtype=ld)
    qd0 = np.array([0.0, 3.5 - 0.18 * beta], dtype=ld)
    Mq = np.array([[m1 + m2, m2 * L * np.sin(q0[1])], [m2 * L * np.sin(q0[1]), m2 * L * L]], dtype=ld)
    ta.state[:] = np.concatenate([q0, Mq @ qd0])
    ta.time = ld(0)
    out = np.empty((len(ts), 2), dtype=ld)
    impacts, k = [], 0
    while True:
        r = ta.propagate_until(ld(T), c_output=True)
        oc, co = r[0], r[4]
        tend = ta.time
        while k < len(ts) and ld(ts[k]) < tend:
            out[k] = co(ld(ts[k]))[:2]
            k += 1
        if oc != hy.taylor_outcome.time_limit:
            st = ta.state.copy()
            sn = np.sin(st[1])
            dt = m2 * L * L * (m1 + m2 - m2 * sn * sn)
            miyy = m2 * L * L / dt
            vy_ = (m2 * L * L * st[2] - m2 * L * sn * st[3]) / dt
            st[2] += -2 * vy_ / miyy
            ta.state[:] = st
            impacts.append(float(tend))
            continue
        while k < len(ts):
            out[k] = ta.state[:2]
            k += 1
        return out.astype(float), impacts


def targets(quick=False) -> dict:
    res = {}
    n = 200 if quick else 1000
    log(f"== targets of the exact reference (this one process; {n} random box states)")
    box = _box_wrong(n)
    res["box"] = box
    log(f"  random box states with a wrong event sequence: {box['wrong']} of {box['states']} "
        f"(refused: {box['failed']}; worst q error {box['worst_q_error']:.1e}; {box['mean_ms']:.1f} ms each)  target 0")
    reps = 9 if quick else 41
    vcirun.reference("cart_pendulum", T=5, beta=4.2)
    vcirun.simulate("cart_pendulum", "MCVAA", h=1e-2, T=5, beta=4.2)
    refs, sims = [], []
    for _ in range(reps):   # interleaved: a slow spell of the shared machine hits both
        refs.append(median_s(lambda: vcirun.reference("cart_pendulum", T=5, beta=4.2), 1))
        sims.append(median_s(lambda: vcirun.simulate("cart_pendulum", "MCVAA", h=1e-2, T=5, beta=4.2), 1))
    ref_s, sim_s = statistics.median(refs), statistics.median(sims)
    res["cart_ratio"] = {"reference_ms": 1e3 * ref_s, "mcvaa_ms": 1e3 * sim_s, "ratio": ref_s / sim_s}
    log(f"  cart-pendulum reference (default options), warm: {1e3 * ref_s:.2f} ms against one MCVAA simulate() "
        f"{1e3 * sim_s:.2f} ms: {ref_s / sim_s:.1f}x  target <= 4x")
    tt = np.linspace(0.0, 5.0, 2001)
    errs, dop = [], []
    for beta in (3.2, 3.7, 4.2, 4.7, 5.2):
        q, imps = _cart_longdouble(beta, 5.0, tt)
        ref = vcirun.reference("cart_pendulum", T=5.0, beta=beta)
        errs.append(float(np.max(np.abs(ref(tt) - q))))
        assert len(imps) == len(ref.impacts)
        s = resolve_system("cart_pendulum")
        prm = s.param_values()
        q0, p0 = s.initial_state(beta=beta, params=prm)
        dop.append(float(np.max(np.abs(solve_exact(s, q0, p0, prm, 5.0, path="dop853", check_accuracy=False)(tt) - q))))
    res["independent"] = {"cart_taylor_max": max(errs), "cart_taylor": errs, "cart_dop853": dop}
    log(f"  reference error against an independent solve (cart-pendulum, heyoka in long double, 5 beta): "
        f"{min(errs):.1e} .. {max(errs):.1e} (the DOP853 path: {min(dop):.1e} .. {max(dop):.1e})  target <= 1e-12")
    log(f"  (box against its closed form: worst {box['worst_q_error']:.1e} over the states above)")
    betas = np.linspace(3.2, 5.2, 51)
    t0 = time.perf_counter()
    for b in betas:
        vcirun.reference("cart_pendulum", T=5, beta=float(b))
    refs_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    for b in betas:
        for m in METHODS:
            for h in (3.2e-2, 1e-2):
                vcirun.simulate("cart_pendulum", m, h=h, T=5, beta=float(b))
    runs_s = time.perf_counter() - t0
    res["fig4"] = {"references_s": refs_s, "runs_s": runs_s}
    log(f"  configs/fig4.yaml's work, serial: 51 references {refs_s:.2f} s, 408 runs {runs_s:.2f} s")
    return res


def main(argv=None):
    import warnings

    from vcirun.run.api import GridWarning

    warnings.simplefilter("ignore", GridWarning)
    quick = "--quick" in (argv if argv is not None else sys.argv[1:])
    out = {"per_scene": cost_per_scene(quick)}
    out.update(targets(quick))
    return out


if __name__ == "__main__":
    main()
