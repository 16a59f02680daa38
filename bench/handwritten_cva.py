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


# --- the same loop on the scene's generated kernels ------------------------------------------------
# The yardstick of the engine alone: the loop above, by hand and allocation-free, with the mechanics
# from the cart-pendulum's generated kernels (SVC_PmJ, SVC_Pp, SVC_Ed, sys_M, sys_V, sys_phi,
# sys_dphi of the module vcirun runs) in place of the closed forms; what vcirun's loop costs beyond it
# is the generic engine's (the loop state, the records, the event search, node data), not the
# derivation's. Its event search is integrate's, written again over arrays: the closed-form loop stays
# one standalone cached function, so the yardstick's own time does not depend on this variant.

def kernel_integrate(mod):
    """integrate(q0, p0, h, N, prm, Q, P, Hs, Eds, iters, impacts) of `mod`'s kernels (compiled once per
    process: a closure over the module's dispatchers)."""
    PmJ, Pp, Ed_k, sys_M, sys_V = mod.SVC_PmJ, mod.SVC_Pp, mod.SVC_Ed, mod.sys_M, mod.sys_V
    sys_phi, sys_dphi = mod.sys_phi, mod.sys_dphi

    @njit(nogil=True, error_model="numpy")
    def solve2(A, r0, r1):
        det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
        return (A[1, 1] * r0 - A[0, 1] * r1) / det, (A[0, 0] * r1 - A[1, 0] * r0) / det

    @njit(nogil=True, error_model="numpy")
    def step(q0, p0, h, prm, v, r, J, A, q1, p1):
        """SVC step from (q0, p0): (q1, p1) written; returns (Ed, iterations (< 0: no convergence))."""
        sys_M(q0, prm, A)
        v[0], v[1] = solve2(A, p0[0], p0[1])
        it = 0
        conv = False
        dprev = np.inf
        while it < MAXIT:
            it += 1
            PmJ(q0, v, h, 0.0, prm, r, J)
            dy, dt = solve2(J, r[0] - p0[0], r[1] - p0[1])
            v[0] -= dy
            v[1] -= dt
            dn = max(abs(dy), abs(dt))
            vn = max(abs(v[0]), abs(v[1]))
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
        q1[0] = q0[0] + h * v[0]
        q1[1] = q0[1] + h * v[1]
        Pp(q0, v, h, 0.0, prm, p1)
        return Ed_k(q0, v, h, prm), (it if conv else -it)

    @njit(nogil=True, error_model="numpy")
    def hamiltonian(q, p, prm, A):
        sys_M(q, prm, A)
        x0, x1 = solve2(A, p[0], p[1])
        return 0.5 * (p[0] * x0 + p[1] * x1) + sys_V(q, prm)

    @njit(nogil=True, error_model="numpy")
    def integrate_k(q0, p0, h, N, prm, Q, P, Hs, Eds, iters, impacts):
        v, r, g = np.empty(2), np.empty(2), np.empty(2)   # (one allocation per run, as integrate's w)
        J, A = np.empty((2, 2)), np.empty((2, 2))
        q, p, q1, p1 = q0.copy(), p0.copy(), np.empty(2), np.empty(2)
        Q[0], P[0] = q, p
        nimp = 0
        for k in range(N):
            E, it = step(q, p, h, prm, v, r, J, A, q1, p1)
            Hs[k] = hamiltonian(q, p, prm, A)
            Eds[k] = E
            if it < 0:
                return k, nimp, 1
            its = it
            if sys_phi(q1, prm) > 0.0:
                q[:] = q1
                p[:] = p1
            else:
                tau_max = h
                tc = k * h
                while tau_max > 0.0:
                    a, ga = 0.0, sys_phi(q, prm)
                    if ga <= 0.0:      # on the surface after an impact: step off it first
                        a = tau_max
                        while a > 1e-3 * ETOL * h:
                            a *= 0.5
                            step(q, p, a, prm, v, r, J, A, q1, p1)
                            if sys_phi(q1, prm) > 0.0:
                                break
                        ga = sys_phi(q1, prm)
                    E, it = step(q, p, tau_max, prm, v, r, J, A, q1, p1)
                    its += abs(it)
                    gb = sys_phi(q1, prm)
                    if gb > 0.0:
                        q[:] = q1
                        p[:] = p1
                        break
                    b = tau_max
                    side = 0
                    c = 0.5 * (a + b)
                    for _ in range(200):
                        c = (a * gb - b * ga) / (gb - ga)
                        if not (c > a and c < b):
                            c = 0.5 * (a + b)
                        E, it = step(q, p, c, prm, v, r, J, A, q1, p1)
                        its += abs(it)
                        gc = sys_phi(q1, prm)
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
                    # R^CVA at the impact state: p+ = p- - 2 (g.M^-1 p-)/(g.M^-1 g) g, g = grad phi
                    sys_dphi(q1, prm, g)
                    sys_M(q1, prm, A)
                    x0, x1 = solve2(A, g[0], g[1])
                    lam = -2.0 * (x0 * p1[0] + x1 * p1[1]) / (x0 * g[0] + x1 * g[1])
                    impacts[nimp] = tc + c
                    nimp += 1
                    q[:] = q1
                    p[0] = p1[0] + lam * g[0]
                    p[1] = p1[1] + lam * g[1]
                    tc += c
                    tau_max -= c
            iters[k] = its
            Q[k + 1] = q
            P[k + 1] = p
        return N, nimp, 0

    return integrate_k


def vcirun_module():
    """The compiled module vcirun runs for cart-pendulum CVA (this tree's, in its default build)."""
    from vcirun.codegen.build import load_module
    from vcirun.methods.table import resolve_method

    try:
        from vcirun.scenes.registry import get_scene
    except ImportError:   # a tree before the scene registry (the base of bench/loop_targets.py)
        from vcirun.scenes.declarations import get_scene
    s = get_scene("cart_pendulum")
    return load_module(s, resolve_method("CVA").kernel_set())


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


def interleaved(f, hand_loop, args, repeats: int, warm: int = 20):
    """(hand, loop, call, the last Trajectory): seconds of `repeats` calls of hand_loop(*args) and of f(),
    alternating (as a sweep alternates runs), after `warm` rounds of both; loop: each Trajectory's
    wall_time (its compiled loop alone)."""
    for _ in range(warm):
        f()
        hand_loop(*args)
    hand, loop, call = [], [], []
    for _ in range(repeats):
        t = time.perf_counter()
        hand_loop(*args)
        hand.append(time.perf_counter() - t)
        t = time.perf_counter()
        tr = f()
        call.append(time.perf_counter() - t)
        loop.append(tr.wall_time)
    return hand, loop, call, tr


def measure(repeats: int = 201, kernels: bool = False) -> dict:
    """Medians of interleaved calls: the hand-written loop, vcirun's compiled loop (Trajectory.wall_time)
    and vcirun's whole simulate() call, cart-pendulum CVA, T = 5, h = 1e-2, beta = 3.2. kernels: the
    hand-written loop on the scene's generated kernels (`kernel_integrate`), else on the closed forms."""
    import vcirun

    args = setup()
    hand_loop = kernel_integrate(vcirun_module()) if kernels else integrate
    hand_loop(*args)
    f = lambda: vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=5.0, beta=3.2)  # noqa: E731
    hand, loop, call, tr = interleaved(f, hand_loop, args, repeats)
    steps, nimp, status = hand_loop(*args)
    imp = args[-1][:nimp]
    ref = np.asarray(tr.impacts)
    hm, lm, cm = (statistics.median(x) * 1e3 for x in (hand, loop, call))
    try:   # which build ran (the auto build runs the specialized module once it is in the cache)
        from vcirun.codegen.kernel_cache import default

        mod = next(iter(default().plans.values())).module()
        ran = "shared" if hasattr(mod, "SHARED_CORE") else "specialized"
    except (ImportError, AttributeError, StopIteration):
        ran = "?"
    return {"module_build": ran, "hand_ms": hm, "loop_ms": lm, "call_ms": cm, "loop_ratio": lm / hm, "call_ratio": cm / hm,
            "hand_min_ms": min(hand) * 1e3, "loop_min_ms": min(loop) * 1e3, "call_min_ms": min(call) * 1e3,
            "status": int(status), "impacts": int(nimp), "vcirun_impacts": int(len(ref)),
            "impact_time_diff": float(np.max(np.abs(imp - ref))) if len(ref) == nimp else float("nan"),
            "q_diff": float(np.max(np.abs(args[5][:steps + 1] - tr.q))) if len(tr.q) == steps + 1 else float("nan")}


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--kernels"]
    r = measure(int(args[0]) if args else 201, kernels="--kernels" in sys.argv)
    print(f"hand-written numba CVA{' (generated kernels)' if '--kernels' in sys.argv else ''} {r['hand_ms']:.4f} ms, vcirun loop {r['loop_ms']:.4f} ms (x{r['loop_ratio']:.2f}), "
          f"simulate() {r['call_ms']:.4f} ms (x{r['call_ratio']:.2f}); impacts {r['impacts']} / {r['vcirun_impacts']}, "
          f"max |dt_impact| {r['impact_time_diff']:.1e}, max |dq| {r['q_diff']:.1e}")
