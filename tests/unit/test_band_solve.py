"""The band solve of the step Jacobians and of M(q): the bits of the dense solve on every band matrix,
and a bandwidth that never understates the coupling of a scene's coordinates."""
import numpy as np
import pytest
import sympy as sp
from hypothesis import given, settings, strategies as st

from vcirun.maps.linalg import _eliminate, solve_band, solve_small
from vcirun.mechanics.system import MechanicalSystem
from vcirun.scenes.registry import get_scene


def _dense_elimination(A, b):
    """Textbook Gaussian elimination with partial pivoting (first largest pivot, rows below updated
    from column k + 1, back substitution), in plain Python: the reference the compiled solve is
    checked against, written apart from it. None if a pivot is zero."""
    A, b = [list(map(float, r)) for r in A], list(map(float, b))
    n = len(b)
    for k in range(n):
        piv = max(range(k, n), key=lambda i: (abs(A[i][k]), -i))
        if not abs(A[piv][k]) > 0.0:
            return None
        A[k], A[piv], b[k], b[piv] = A[piv], A[k], b[piv], b[k]
        inv = 1.0 / A[k][k]
        for i in range(k + 1, n):
            f = A[i][k] * inv
            if f != 0.0:
                for j in range(k + 1, n):
                    A[i][j] -= f * A[k][j]
                b[i] -= f * b[k]
    x = [0.0] * n
    for k in range(n - 1, -1, -1):
        s = b[k]
        for j in range(k + 1, n):
            s -= A[k][j] * x[j]
        x[k] = s / A[k][k]
    return np.array(x)


@settings(max_examples=300, deadline=None)
@given(n=st.integers(1, 12), data=st.data())
def test_band_solve_has_the_bits_of_the_dense_elimination(n, data):
    bw = data.draw(st.integers(0, n - 1))
    seed = data.draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n)) * np.exp(rng.normal(size=(n, 1)) * 3)  # rows of very different scales
    A[np.abs(np.subtract.outer(np.arange(n), np.arange(n))) > bw] = 0.0
    b = rng.normal(size=n)
    A1, b1, A2, b2 = A.copy(), b.copy(), A.copy(), b.copy()
    ok1, ok2 = solve_small(A1, b1, n), solve_band(A2, b2, n, bw)
    x = _dense_elimination(A, b)
    assert ok1 == ok2 == (x is not None)
    if ok1:
        assert np.array_equal(b1, x) and np.array_equal(b2, x)
        assert np.allclose(A @ b2, b, rtol=0, atol=1e-8 * np.abs(A).sum(axis=1).max() * np.abs(b2).max() + 1e-300)


_EDGE = st.one_of(st.sampled_from([0.0, -0.0, 1.0, -1.0, 2.0, 1e-300, -1e300, np.inf, -np.inf, np.nan]),
                  st.floats(-1e6, 1e6, allow_nan=False))


@settings(max_examples=400, deadline=None)
@given(n=st.integers(1, 2), data=st.data())
def test_small_solves_leave_what_the_elimination_leaves(n, data):
    """n <= 2 runs straight-line code: the same return value and the same bits in b and A as the
    general elimination, also at ties of the pivots, zero multipliers, singular and non-finite matrices
    and a rank tolerance."""
    bw = data.draw(st.integers(0, n - 1))
    A = np.array(data.draw(st.lists(_EDGE, min_size=n * n, max_size=n * n))).reshape(n, n)
    if data.draw(st.booleans()) and n == 2:
        A[1, 0] = -A[0, 0]   # |a10| = |a00|: the first largest pivot stays
    A[np.abs(np.subtract.outer(np.arange(n), np.arange(n))) > bw] = 0.0
    b = np.array(data.draw(st.lists(_EDGE, min_size=n, max_size=n)))
    tiny = data.draw(st.sampled_from([0.0, 1e-12, 1.5]))
    A1, b1, A2, b2 = A.copy(), b.copy(), A.copy(), b.copy()
    ok1, ok2 = solve_band(A1, b1, n, bw, tiny), _eliminate(A2, b2, n, bw, tiny)
    assert ok1 == ok2
    assert np.array_equal(b1, b2, equal_nan=True) and np.array_equal(A1, A2, equal_nan=True)
    assert np.array_equal(np.signbit(b1), np.signbit(b2))


def test_singular_band_matrix_is_refused():
    A = np.diag([1.0, 0.0, 2.0])
    assert not solve_band(A, np.ones(3), 3, 0)


def _numeric_band(system, rng, k=5):
    """The widest |i - j| of a numerically nonzero entry of M, of the Hessian of L in (q, qdot) and of
    the force's Jacobian, at k random states."""
    q, qd = list(system.q), list(system.qd)
    L = system.lagrangian()
    z = q + qd
    H = sp.hessian(L, z)
    blocks = [system.M, H[:len(q), :len(q)], H[:len(q), len(q):], H[len(q):, :len(q)]]
    if system.forcing is not None:
        blocks += [system.forcing.jacobian(q), system.forcing.jacobian(qd)]
    prm = dict(zip(system.param_symbols, system.param_values()))
    b = 0
    for _ in range(k):
        vals = prm | dict(zip(z, rng.uniform(-1, 1, len(z)))) | {system.t: rng.uniform(0, 1)}
        for B in blocks:
            Bn = np.array(B.subs(vals).evalf(), dtype=float)
            for i, j in zip(*np.nonzero(np.abs(Bn) > 1e-14)):
                b = max(b, abs(int(i) - int(j)))
    return b


@pytest.mark.parametrize("make, expected", [
    (lambda: get_scene("newton_cradle_12"), 0),
    (lambda: get_scene("n_pendulum_4"), 3),
    (lambda: get_scene("double_pendulum_walls"), 1),
    (lambda: get_scene("ball_in_box"), 0),
    (lambda: get_scene("cart_pendulum"), 1),
    (lambda: get_scene("damped_oscillator"), 0),
])
def test_bandwidth_of_the_built_in_scenes(make, expected):
    system = make()
    assert system.bandwidth == expected
    assert _numeric_band(system, np.random.default_rng(3)) <= system.bandwidth


def test_bandwidth_counts_potential_and_force_coupling():
    x = sp.symbols("x1:6")
    xd = sp.symbols("x1_dot x2_dot x3_dot x4_dot x5_dot")
    k, c = sp.symbols("k c")
    # springs between neighbours (V couples i, i + 1) and a damper from ball 1 to ball 4
    V = sum(k * (x[i + 1] - x[i]) ** 2 / 2 for i in range(4))
    f = sp.Matrix([c * (xd[3] - xd[0]), 0, 0, -c * (xd[3] - xd[0]), 0])
    s = MechanicalSystem("springs", list(x), {"k": 1.0, "c": 0.1}, sp.eye(5), V, phi=x[1] - x[0],
                         qd=list(xd), forcing=f)
    assert s.bandwidth == 3
    s2 = MechanicalSystem("springs2", list(x), {"k": 1.0}, sp.eye(5), V, phi=x[1] - x[0])
    assert s2.bandwidth == 1
    assert _numeric_band(s2, np.random.default_rng(0)) == 1
