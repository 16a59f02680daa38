"""The yardstick of vcirun's loop: CVA on the cart-pendulum written by hand in numba, allocation-free.

The same method as vcirun's CVA (SVC full step in the velocity parametrisation, Newton with the
analytic Jacobian and vcirun's stopping rule, the first collision time by secant/Illinois on the
partial step to event_tol h, R^CVA p+ = p- + lam grad phi conserving H, the rest of the step after
the impact), the same record per grid step (q, p, H, the discrete energy Ed, Newton iterations),
with the cart-pendulum's M, V and their derivatives written out (2 x 2: closed-form solves). One
function call runs the whole loop into preallocated buffers; nothing is allocated per step.

`python bench/handwritten_cva.py` prints its loop time against vcirun's compiled loop and whole
`simulate()` call (the `handwritten` rows of bench/bench_all.py's `loop` section) and checks that it
follows vcirun's trajectory (the impact times agree to ~1e-12; the states to the Newton tolerance).
"""
from __future__ import annotations

import math
import statistics
import sys
import time

import numpy as np
from numba import njit

NTOL, ETOL, MAXIT = 1e-12, 1e-13, 50


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _mass(th, prm):
    m1, m2, L = prm[0], prm[1], prm[2]
    return m1 + m2, m2 * L * math.sin(th), m2 * L * L          # M = [[a, b], [b, c]]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _solve2(a, b, c, r0, r1):
    det = a * c - b * b
    return (c * r0 - b * r1) / det, (a * r1 - b * r0) / det


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _H(y, th, py, pt, prm):
    a, b, c = _mass(th, prm)
    vy, vt = _solve2(a, b, c, py, pt)
    m1, m2, L, g = prm[0], prm[1], prm[2], prm[3]
    return 0.5 * (py * vy + pt * vt) + (m1 + m2) * g * y - m2 * g * L * math.cos(th)


@njit(cache=True, nogil=True, error_model="numpy")
def svc_step(y0, th0, py, pt, h, prm, out):
    """SVC (trapezoidal Ld) step of length h from (q0, p0): Newton on Pm(q0, v, h) = p0 for the step
    velocity v; out = (y1, th1, py1, pt1, vy, vt, Ed, iterations (< 0: no convergence))."""
    m1, m2, L, g = prm[0], prm[1], prm[2], prm[3]
    b0 = m2 * L
    a, bs0, c = _mass(th0, prm)
    vy, vt = _solve2(a, bs0, c, py, pt)
    it = 0
    conv = False
    dprev = np.inf
    while it < MAXIT:
        it += 1
        th1 = th0 + h * vt
        bs1 = b0 * math.sin(th1)
        bc0 = b0 * math.cos(th0)
        bc1 = b0 * math.cos(th1)
        # Pm = (M0 + M1)/2 v - h/2 (1/2 v^T dM(q0) v - dV(q0)); dM/dth = [[0, b cos], [b cos, 0]]
        ry = a * vy + 0.5 * (bs0 + bs1) * vt + 0.5 * h * (m1 + m2) * g - py
        rt = 0.5 * (bs0 + bs1) * vy + c * vt - 0.5 * h * (bc0 * vy * vt - m2 * g * L * math.sin(th0)) - pt
        # Jacobian d Pm / d v
        j00 = a
        j01 = 0.5 * (bs0 + bs1) + 0.5 * h * bc1 * vt
        j10 = 0.5 * (bs0 + bs1) - 0.5 * h * bc0 * vt
        j11 = c + 0.5 * h * bc1 * vy - 0.5 * h * bc0 * vy
        det = j00 * j11 - j01 * j10
        dy = (j11 * ry - j01 * rt) / det
        dt = (j00 * rt - j10 * ry) / det
        vy -= dy
        vt -= dt
        dn = max(abs(dy), abs(dt))
        vn = max(abs(vy), abs(vt))
        if not math.isfinite(dn):
            break
        if dn <= NTOL * (1.0 + vn):
            conv = True
            break
        theta = dn / dprev
        if it >= 2 and theta < 0.1 and theta / (1.0 - theta) * dn <= NTOL * (1.0 + vn):
            conv = True
            break
        if it >= 3 and dn >= dprev and dn <= math.sqrt(NTOL) * (1.0 + vn):
            conv = True
            break
        dprev = dn
    y1 = y0 + h * vy
    th1 = th0 + h * vt
    bs1 = b0 * math.sin(th1)
    bc1 = b0 * math.cos(th1)
    # Pp = (M0 + M1)/2 v + h/2 (1/2 v^T dM(q1) v - dV(q1))
    out[0] = y1
    out[1] = th1
    out[2] = a * vy + 0.5 * (bs0 + bs1) * vt - 0.5 * h * (m1 + m2) * g
    out[3] = 0.5 * (bs0 + bs1) * vy + c * vt + 0.5 * h * (bc1 * vy * vt - m2 * g * L * math.sin(th1))
    out[4] = vy
    out[5] = vt
    # Ed = -D3 Ld: the discrete energy, (v^T (M0 + M1) v) / 4 + (V0 + V1) / 2
    ke = 0.25 * (a * vy * vy + (bs0 + bs1) * vy * vt + c * vt * vt) * 2.0
    out[6] = ke + 0.5 * ((m1 + m2) * g * (y0 + y1) - m2 * g * L * (math.cos(th0) + math.cos(th1)))
    out[7] = it if conv else -it


@njit(cache=True, nogil=True, error_model="numpy")
def integrate(q0, p0, h, N, prm, Q, P, Hs, Eds, iters, impacts):
    """N grid steps of CVA from (q0, p0); returns (steps taken, impacts, status 0 ok / 1 failed)."""
    w = np.empty(8)   # (one allocation per run: the step's output)
    y, th, py, pt = q0[0], q0[1], p0[0], p0[1]
    Q[0, 0], Q[0, 1], P[0, 0], P[0, 1] = y, th, py, pt
    nimp = 0
    for k in range(N):
        svc_step(y, th, py, pt, h, prm, w)
        Hs[k] = _H(y, th, py, pt, prm)
        Eds[k] = w[6]
        if w[7] < 0:
            return k, nimp, 1
        its = int(w[7])
        if w[0] > 0.0:
            y, th, py, pt = w[0], w[1], w[2], w[3]
        else:
            tau_max = h
            tc = k * h
            while tau_max > 0.0:
                # first root of y(tau) in (0, tau_max]: secant / Illinois on the partial step
                a, ga = 0.0, y
                if ga <= 0.0:      # on the surface after an impact: step off it first
                    a = tau_max
                    while a > 1e-3 * ETOL * h:
                        a *= 0.5
                        svc_step(y, th, py, pt, a, prm, w)
                        if w[0] > 0.0:
                            break
                    ga = w[0]
                svc_step(y, th, py, pt, tau_max, prm, w)
                its += abs(int(w[7]))
                if w[0] > 0.0:
                    y, th, py, pt = w[0], w[1], w[2], w[3]
                    break
                b, gb = tau_max, w[0]
                side = 0
                c = 0.5 * (a + b)
                for _ in range(200):
                    c = (a * gb - b * ga) / (gb - ga)
                    if not (c > a and c < b):
                        c = 0.5 * (a + b)
                    svc_step(y, th, py, pt, c, prm, w)
                    its += abs(int(w[7]))
                    gc = w[0]
                    if gc > 0.0:
                        a, ga = c, gc
                        if side == 1:
                            gb *= 0.5
                        side = 1
                    elif gc < 0.0:
                        b, gb = c, gc
                        if side == -1:
                            ga *= 0.5
                        side = -1
                    else:
                        break
                    if b - a <= ETOL * h:
                        break
                # R^CVA at the impact state (w: the partial step to c): p+ = p- - 2 (g.M^-1 p)/(g.M^-1 g) g, g = (1, 0)
                qy, qt_, pmy, pmt = w[0], w[1], w[2], w[3]
                A, B, C = _mass(qt_, prm)
                xy, xt = _solve2(A, B, C, 1.0, 0.0)
                lam = -2.0 * (xy * pmy + xt * pmt) / xy
                impacts[nimp] = tc + c
                nimp += 1
                y, th, py, pt = qy, qt_, pmy + lam, pmt
                tc += c
                tau_max -= c
        iters[k] = its
        Q[k + 1, 0], Q[k + 1, 1], P[k + 1, 0], P[k + 1, 1] = y, th, py, pt
    return N, nimp, 0


def setup(h=1e-2, T=5.0, beta=3.2):
    """(arguments of integrate) for the cart-pendulum's Xi(beta) and its default parameters."""
    import vcirun

    try:
        from vcirun.scenes.registry import scene_data
    except ImportError:   # a tree before the scene registry (the base of bench/loop_targets.py)
        from vcirun.scenes.data import cart_pendulum as _cart

        def scene_data(name):
            return _cart()

    d = scene_data("cart_pendulum")
    tr = vcirun.simulate("cart_pendulum", "CVA", h=h, T=h, beta=beta)   # (vcirun's start state for Xi(beta))
    q0, p0 = tr.q[0], tr.p[0]
    prm = np.array([d.params[k] for k in ("m1", "m2", "L", "g")], dtype=np.float64)
    N = int(round(T / h))
    return (np.asarray(q0, float), np.asarray(p0, float), h, N, prm, np.empty((N + 1, 2)), np.empty((N + 1, 2)),
            np.empty(N), np.empty(N), np.zeros(N, np.int64), np.empty(64))


def measure(repeats: int = 201) -> dict:
    """Medians of interleaved calls: the hand-written loop, vcirun's compiled loop (Trajectory.wall_time)
    and vcirun's whole simulate() call, cart-pendulum CVA, T = 5, h = 1e-2, beta = 3.2."""
    import vcirun

    args = setup()
    integrate(*args)
    f = lambda: vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=5.0, beta=3.2)  # noqa: E731
    for _ in range(20):
        f()
        integrate(*args)
    hand, loop, call = [], [], []
    for _ in range(repeats):
        t = time.perf_counter()
        integrate(*args)
        hand.append(time.perf_counter() - t)
        t = time.perf_counter()
        tr = f()
        call.append(time.perf_counter() - t)
        loop.append(tr.wall_time)
    steps, nimp, status = integrate(*args)
    imp = args[-1][:nimp]
    ref = np.asarray(tr.impacts)
    hm, lm, cm = (statistics.median(x) * 1e3 for x in (hand, loop, call))
    return {"hand_ms": hm, "loop_ms": lm, "call_ms": cm, "loop_ratio": lm / hm, "call_ratio": cm / hm,
            "hand_min_ms": min(hand) * 1e3, "loop_min_ms": min(loop) * 1e3, "call_min_ms": min(call) * 1e3,
            "status": int(status), "impacts": int(nimp), "vcirun_impacts": int(len(ref)),
            "impact_time_diff": float(np.max(np.abs(imp - ref))) if len(ref) == nimp else float("nan"),
            "q_diff": float(np.max(np.abs(args[5][:steps + 1] - tr.q))) if len(tr.q) == steps + 1 else float("nan")}


if __name__ == "__main__":
    r = measure(int(sys.argv[1]) if len(sys.argv) > 1 else 201)
    print(f"hand-written numba CVA {r['hand_ms']:.4f} ms, vcirun loop {r['loop_ms']:.4f} ms (x{r['loop_ratio']:.2f}), "
          f"simulate() {r['call_ms']:.4f} ms (x{r['call_ratio']:.2f}); impacts {r['impacts']} / {r['vcirun_impacts']}, "
          f"max |dt_impact| {r['impact_time_diff']:.1e}, max |dq| {r['q_diff']:.1e}")
