"""Structure of the one-step maps.

- symplecticity defect max|J^T Omega J - Omega| < 1e-8 for every map (J by a 4th-order FD stencil);
- SE1/SE2 adjoint (Phi^SE1_h o Phi^SE2_{-h} = I), symmetric methods self-adjoint;
- SVA = SVC on a separable system, not on the cart-pendulum;
- Phi^SVA_{Nh} = Phi^SE2_{h/2} o Phi^SVB_{(N-1)h} o Phi^SE1_{h/2};
- SVC energy error over 1e5 steps has no drift.
"""
from __future__ import annotations

import numpy as np
import pytest

import vcirun
from convergence.helpers import drift_slope, map_jacobian, run_map, step, symplecticity_defect
from vcirun.discrete.lagrangians import LIBRARY
from vcirun.mechanics import load_system_yaml

METHODS = ("SE1", "SE2", "SVA", "SVB", "SVC", "midpoint")
NONSEPARABLE = ("cart_pendulum", "double_pendulum")


def _states(n, rng, k=3):
    return [(rng.uniform(-1.0, 1.0, n), rng.uniform(-1.0, 1.0, n)) for _ in range(k)]


# --- acceptance 3: symplecticity -----------------------------------------------------------
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("system_name", NONSEPARABLE)
def test_symplecticity_defect(system_name, method, compiled, rng):
    system, mod, prm = compiled(system_name, method)
    n = system.n
    worst = 0.0
    for q, p in _states(n, rng):
        for h in (0.1, 0.02):
            f = lambda y: np.concatenate(step(mod, y[:n], y[n:], h, 0.0, prm))  # noqa: E731
            J = map_jacobian(f, np.concatenate([q, p]), d=1e-3)
            worst = max(worst, symplecticity_defect(J))
    assert worst < 1e-8, f"{system_name}/{method}: symplecticity defect {worst:.2e}"


def test_symplecticity_defect_detects_a_dissipative_map(compiled):
    """Control: the forced (damped) SVC map contracts phase volume, det J ~ exp(-c h), and the
    same defect measure sees it."""
    system, mod, prm = compiled("damped_oscillator", "SVC")
    f = lambda y: np.concatenate(step(mod, y[:1], y[1:], 0.1, 0.0, prm))  # noqa: E731
    J = map_jacobian(f, np.array([0.4, -0.3]), d=1e-3)
    assert abs(np.linalg.det(J) - np.exp(-0.1 * 0.1)) < 1e-3
    assert symplecticity_defect(J) > 5e-3


# --- acceptance 4: adjoints, symmetry, SVA vs SVC, composition identity --------------------
@pytest.mark.parametrize("system_name", NONSEPARABLE)
def test_se1_and_se2_are_adjoint(system_name, compiled, rng):
    """Phi^SE1_h o Phi^SE2_{-h} = I (and Phi^SE2_h o Phi^SE1_{-h} = I): negative steps are allowed."""
    system, se1, prm = compiled(system_name, "SE1")
    _, se2, _ = compiled(system_name, "SE2")
    worst = 0.0
    for q, p in _states(system.n, rng, 5):
        for h in (0.1, 0.01):
            for first, second in ((se2, se1), (se1, se2)):
                qa, pa = step(first, q, p, -h, 0.0, prm)
                qb, pb = step(second, qa, pa, h, 0.0, prm)
                worst = max(worst, float(np.max(np.abs(np.r_[qb - q, pb - p]))))
    assert worst < 1e-12, worst


@pytest.mark.parametrize("method", METHODS)
def test_declared_symmetry_is_self_adjointness(method, compiled, rng):
    """symmetric=True <=> Phi_h o Phi_{-h} = I (to 1e-12); SE1/SE2 miss it by O(h^2)."""
    system, mod, prm = compiled("cart_pendulum", method)
    worst = 0.0
    for q, p in _states(system.n, rng):
        qa, pa = step(mod, q, p, 0.05, 0.0, prm)
        qb, pb = step(mod, qa, pa, -0.05, 0.0, prm)
        worst = max(worst, float(np.max(np.abs(np.r_[qb - q, pb - p]))))
    if LIBRARY[method].symmetric:
        assert worst < 1e-12, worst
    else:
        assert worst > 1e-5, worst


HENON_HEILES = """
name: henon_heiles_wall
coordinates: [x, y]
parameters: {m: 1.3, lam: 1.0}
mass_matrix: [["m", "0"], ["0", "m"]]
potential: "0.5*(x**2 + y**2) + lam*(x**2*y - y**3/3)"
constraint: "y + 10"
q0: [0.1, -0.2]
qdot0: [0.35, 0.2]
"""


def test_sva_equals_svc_on_a_separable_system(compiled, tmp_path):
    """Constant M (separable, nonlinear V): SVC (eq. 26) generates Stoermer-Verlet = SVA exactly."""
    path = tmp_path / "hh.yaml"
    path.write_text(HENON_HEILES)
    system = load_system_yaml(path)
    q0, p0 = system.initial_state()
    out = {}
    for m in ("SVA", "SVC"):
        _, mod, prm = compiled(system, m)
        out[m] = run_map(mod, prm, q0, p0, 0.05, 400)
    dq = np.max(np.abs(out["SVA"][0] - out["SVC"][0]))
    dp = np.max(np.abs(out["SVA"][1] - out["SVC"][1]))
    assert dq < 1e-12 and dp < 1e-12, (dq, dp)
    assert np.ptp(out["SVC"][0][:, 0]) > 0.2  # a non-trivial trajectory


def test_sva_differs_from_svc_on_the_cart_pendulum(compiled):
    system, sva, prm = compiled("cart_pendulum", "SVA")
    _, svc, _ = compiled("cart_pendulum", "SVC")
    q0, p0 = system.initial_state(beta=1.0)
    Qa, _ = run_map(sva, prm, q0, p0, 0.05, 40)
    Qc, _ = run_map(svc, prm, q0, p0, 0.05, 40)
    assert np.max(np.abs(Qa - Qc)) > 1e-3


@pytest.mark.parametrize("h, N", [(0.01, 50), (0.1, 20)])
@pytest.mark.parametrize("system_name", NONSEPARABLE)
def test_sva_svb_composition_identity(system_name, h, N, compiled):
    """Phi^SVA_{Nh} = Phi^SE2_{h/2} o Phi^SVB_{(N-1)h} o Phi^SE1_{h/2} (to 1e-11)."""
    system, sva, prm = compiled(system_name, "SVA")
    q0, p0 = system.initial_state(beta=1.0) if system_name == "cart_pendulum" else system.initial_state()
    Qa, Pa = run_map(sva, prm, q0, p0, h, N)
    q, p = step(compiled(system_name, "SE1")[1], q0, p0, h / 2, 0.0, prm)
    Qb, Pb = run_map(compiled(system_name, "SVB")[1], prm, q, p, h, N - 1, t0=h / 2)
    q, p = step(compiled(system_name, "SE2")[1], Qb[-1], Pb[-1], h / 2, (N - 0.5) * h, prm)
    err = float(np.max(np.abs(np.r_[q - Qa[-1], p - Pa[-1]])))
    assert err < 1e-11, err
    # ... and the interior SVB nodes are the SVA half-step nodes: not a trivially short run
    assert np.max(np.abs(Qa[-1] - q0)) > 0.05


# --- acceptance 5: no energy drift over 1e5 SVC steps ------------------------------------------
def no_drift(t, dH, n_windows=100, rel=0.05):
    """(ok, description): windowed max|H - H0| has a slope whose 95% CI contains 0, or whose
    growth over the whole run is below `rel` times the median window amplitude; and the second
    half never exceeds 1.5 times the first half's maximum."""
    slope, (lo, hi), wmax = drift_slope(t, dH, n_windows)
    amp = float(np.median(wmax))
    growth = abs(slope) * (t[-1] - t[0])
    half = n_windows // 2
    ok = (lo <= 0.0 <= hi or growth < rel * amp) and wmax[half:].max() <= 1.5 * wmax[:half].max()
    return ok, f"slope {slope:.3e} CI [{lo:.3e}, {hi:.3e}], growth {growth:.3e} vs amplitude {amp:.3e}"


@pytest.mark.parametrize(
    "system_name, kwargs",
    [
        # chaotic, nonseparable, bounded: the Figure-1 state, wall ignored
        ("double_pendulum", dict()),
        # the cart-pendulum without gravity (unconstrained, the cart free-falls with g = 10 and
        # |p| grows without bound, so there the energy error is not a bounded quantity)
        ("cart_pendulum", dict(beta=1.0, params={"g": 0.0})),
    ],
)
def test_svc_energy_error_has_no_drift(system_name, kwargs):
    tr = vcirun.simulate(system_name, "SVC", h=1e-2, T=1000.0, constrained=False, **kwargs)
    assert tr.ok and tr.n_steps == 100_000
    dH = tr.H - tr.H[0]
    ok, desc = no_drift(tr.t, dH)
    assert ok, f"{system_name}: energy drift: {desc}"


def test_drift_detector_sees_a_small_linear_drift():
    """Control: an SVC energy record plus a drift worth 10% of its amplitude over the run fails."""
    tr = vcirun.simulate("cart_pendulum", "SVC", h=1e-2, T=1000.0, beta=1.0, params={"g": 0.0})
    dH = tr.H - tr.H[0]
    amp = np.median(drift_slope(tr.t, dH)[2])
    assert no_drift(tr.t, dH)[0]
    assert not no_drift(tr.t, np.abs(dH) + 0.1 * amp * tr.t / tr.t[-1])[0]


def test_free_falling_cart_pendulum_ends_with_a_status_not_nan():
    """With gravity and the constraint ignored the cart falls forever; |p_y| ~ (m1+m2) g t makes the
    implicit SVC step ever harder. Whatever happens, the run reports a status and finite states."""
    tr = vcirun.simulate("cart_pendulum", "SVC", h=1e-2, T=1000.0, beta=1.0)
    assert tr.status in ("ok", "newton_failed")
    assert np.all(np.isfinite(tr.q)) and np.all(np.isfinite(tr.p))
    if tr.status == "newton_failed":
        assert len(tr.t) == tr.fail_step + 1 and "newton_failed in step" in tr.message
