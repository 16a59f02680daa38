"""Mass matrix of an N-link chain with a free base (vcirun.scenes.contacts.LINK_CHAIN) derived two
ways: vcirun.mechanics.bodies (phasor sums, collected by angle difference) and
sympy.physics.mechanics (LagrangesMethod on the same kinematics), with and without trigsimp of its
entries: sympy.count_ops of M and the derivation time.  Usage: python bench/bodies_derivation.py [N ...]
"""
from __future__ import annotations

import sys
import time

import sympy as sp
from sympy.physics import mechanics as me


def ours(n):
    from vcirun.scenes.contacts import LINK_CHAIN

    t = time.perf_counter()
    s = LINK_CHAIN.system(n)
    return s.M, time.perf_counter() - t


def physics_mechanics(n, trig):
    t = time.perf_counter()
    x, y = me.dynamicsymbols("x y")
    th = me.dynamicsymbols(f"theta1:{n + 1}")
    m, l = sp.symbols("m l")
    N = me.ReferenceFrame("N")
    O = me.Point("O")
    O.set_vel(N, 0)
    P = O.locatenew("P0", x * N.x + y * N.y)
    P.set_vel(N, x.diff() * N.x + y.diff() * N.y)
    bodies = []
    for i in range(n):
        A = N.orientnew(f"A{i}", "Axis", [th[i], N.z])
        A.set_ang_vel(N, th[i].diff() * N.z)
        C = P.locatenew(f"C{i}", l / 2 * A.x)
        C.v2pt_theory(P, N, A)
        I = me.inertia(A, 0, 0, m * l**2 / 12)
        bodies.append(me.RigidBody(f"B{i}", C, A, m, (I, C)))
        P = P.locatenew(f"P{i + 1}", l * A.x)
        P.set_vel(N, P.pos_from(O).dt(N))
    L = me.Lagrangian(N, *bodies)
    lm = me.LagrangesMethod(L, [x, y] + list(th))
    lm.form_lagranges_equations()
    M = lm.mass_matrix
    if trig:
        M = M.applyfunc(sp.trigsimp)
    return M, time.perf_counter() - t


def main(sizes):
    for n in sizes:
        Mo, to = ours(n)
        Mp, tp = physics_mechanics(n, False)
        print(f"N = {n}: vcirun.mechanics.bodies: count_ops(M) = {sp.count_ops(Mo)}, {to:.2f} s; "
              f"sympy.physics.mechanics: {sp.count_ops(Mp)}, {tp:.2f} s", flush=True)
        if n <= 5:
            Mt, tt = physics_mechanics(n, True)
            print(f"        sympy.physics.mechanics + trigsimp: {sp.count_ops(Mt)}, {tt:.2f} s", flush=True)


if __name__ == "__main__":
    main([int(a) for a in sys.argv[1:]] or [3, 5])
