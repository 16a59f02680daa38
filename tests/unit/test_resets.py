"""Reset maps R^CVA (eq. 32) and R^VCI (eq. 33), checked through the compiled kernels.

Impact data (q, p-, E_pre, tau_rem) come from two sources:
  * random: a random state, a random partial step of length dtau in (0.02 h, 0.98 h) taken with the
    scene's own partial map (so E_pre = -D3 Ld of that step, as Algorithm 1 hands it over), the
    momentum flipped if needed so that the normal velocity grad phi . M^-1 p- is negative;
    tau_rem = h - dtau. (The reset equations are algebraic in q: phi(q) = 0 is not needed.)
  * recorded: every impact of CVA/VCI runs of the paper's scenes, with (dtau, E_pre) recomputed by
    `collision_time` from the grid state before the impact step.

Checks (tolerances relative, as stated in each assertion):
  R^CVA: |H(q, p+) - H(q, p-)| <= 1e-13 max(|H|, kinetic energy) (H = T + V with q fixed, so the
         kinetic energy is the natural scale; H itself can be ~0, e.g. the double pendulum).
  R^VCI: with w recovered by an independent Newton solve of Pm(q, w, tau_rem) = p+ (own iteration,
         kernel residual), -D3 Ld(q, w, tau_rem) = E_pre to 1e-12 max(1, |E_pre|).
  both:  p+ - p- = lam grad phi (no component orthogonal to grad phi, to 1e-13 |p|), lam > 0 and
         p+ != p-, normal velocity negative before and positive after (reflection); R^CVA exactly
         reverses it.
"""
from __future__ import annotations

import numpy as np
import pytest

import vcirun

from vcirun.codegen import roles, units
from vcirun.codegen.build import load_module
from vcirun.methods.table import METHODS, Method
from vcirun.run.resolve import resolve_system

NO_HELD = np.zeros(1, dtype=np.int64)  # collision_time's held contacts: none
SCENES = ["cart_pendulum", "double_pendulum", "oscillator_wall"]
NTOL, MAXIT, ETOL = 1e-12, 50, 1e-13



def _law(mod, q, pm, prm):
    """(d, s0, dE) of the impact law at (q, p-) (collision/impact.py: impact_direction), the arguments
    every reset takes (the role `reset` of vcirun.codegen.roles)."""
    n, m = len(q), int(mod.NCON)
    d, lam, active = np.empty(n), np.empty(m), np.empty(m, dtype=np.int64)
    _, s0, dE = mod.impact_direction(np.ascontiguousarray(q, float), np.ascontiguousarray(pm, float), 1.0, 1e-13,
                                     prm, d, lam, active)
    return d, s0, dE

def _mods(scene):
    s = resolve_system(scene)
    return s, s.param_values(None), load_module(s, METHODS["CVA"].kernel_set()), load_module(s, METHODS["VCI"].kernel_set())


def _Minv(mod, q, prm):
    n = q.shape[0]
    A = np.empty((n, n))
    mod.sys_M(q, prm, A)
    return np.linalg.inv(A)


def _grad(mod, q, prm):
    g = np.empty(q.shape[0])
    mod.sys_dphi(q, prm, g)
    return g


def _random_impacts(scene, count, seed):
    """[(q, pm, E_pre, dtau, tau_rem, h)] with negative normal velocity."""
    s, prm, _, mv = _mods(scene)
    n = s.n
    rng = np.random.default_rng(seed)
    out = []
    qt, pt, vt = np.empty(n), np.empty(n), np.empty(n)
    while len(out) < count:
        h = 10 ** rng.uniform(-3, -1.5)
        q0 = rng.normal(size=n)
        p0 = 3.0 * rng.normal(size=n)
        dtau = h * rng.uniform(0.02, 0.98)
        for sign in (1.0, -1.0):
            it, E = mv.partial(q0, sign * p0, dtau, h, 0.0, prm, NTOL, MAXIT, qt, pt, vt)
            assert it > 0
            g = _grad(mv, qt, prm)
            vn = g @ _Minv(mv, qt, prm) @ pt
            if vn < -1e-3 * np.sqrt(g @ g) * np.linalg.norm(pt):  # not tangential
                out.append((qt.copy(), pt.copy(), E, dtau, h - dtau, h))
                break
    return out


def _recorded_impacts(scene, method):
    """Impacts of real runs: (q, pm, E_pre, dtau, tau_rem, h, recorded pp), first impact of each step."""
    s, prm, mc, mv = _mods(scene)
    mod = mc if method == "CVA" else mv
    n = s.n
    runs = [dict(beta=b) for b in (3.2, 4.2, 5.2)] if scene == "cart_pendulum" else [dict()]
    out = []
    qt, pt, vt = np.empty(n), np.empty(n), np.empty(n)
    for kw in runs:
        for h in (3.2e-2, 1e-2):
            tr = vcirun.simulate(scene, method, h=h, T=10.0 if scene != "cart_pendulum" else 5.0, **kw)
            assert tr.status == "ok", tr.message
            j = 0
            for i in np.flatnonzero(tr.impact_step):
                code, dtau, Epre, _ = mod.collision_time(tr.q[i], tr.p[i], h, h, tr.t[i], prm, NTOL, MAXIT, ETOL, qt, pt, vt, NO_HELD)
                assert code == 1
                # the recorded impact is the first of this step (impacts are ascending)
                while tr.impacts[j] < tr.t[i] - 1e-12:
                    j += 1
                assert abs(tr.impacts[j] - (tr.t[i] + dtau)) <= 1e-12 * max(1.0, tr.t[i])
                np.testing.assert_allclose(qt, tr.impact_q[j], rtol=0, atol=1e-13)
                np.testing.assert_allclose(pt, tr.impact_p_minus[j], rtol=0, atol=1e-12)
                out.append((qt.copy(), pt.copy(), Epre, dtau, h - dtau, h, tr.impact_p_plus[j].copy()))
    assert out
    return out


def _check_along_grad_and_reflecting(mod, prm, q, pm, pp, lam):
    g = _grad(mod, q, prm)
    W = _Minv(mod, q, prm)
    dp = pp - pm
    scale = np.linalg.norm(pm) + np.linalg.norm(pp)
    # p+ = p- + lam grad phi, and nothing orthogonal to grad phi
    assert np.linalg.norm(dp - lam * g) <= 1e-13 * scale
    perp = dp - (dp @ g) / (g @ g) * g
    assert np.linalg.norm(perp) <= 1e-13 * scale
    # never p+ = p-; lam reflects: normal velocity negative before, positive after
    assert lam != 0.0 and np.any(pp != pm)
    vn_m, vn_p = g @ W @ pm, g @ W @ pp
    assert vn_m < 0.0 < vn_p, (vn_m, vn_p)
    assert lam > 0.0  # phi >= 0 admissible: the impulse pushes along +grad phi
    return vn_m, vn_p


def _cva_check(mc, prm, q, pm):
    pp = np.empty_like(pm)
    it, lam = mc.reset_cva(q, pm, *_law(mc, q, pm, prm), 0.0, pm, 0.0, 0.0, 0.0, 0.0, prm, NTOL, MAXIT, pp)
    assert it > 0
    H_m, H_p = mc.hamiltonian(q, pm, prm), mc.hamiltonian(q, pp, prm)
    kin = 0.5 * pm @ _Minv(mc, q, prm) @ pm
    rel = abs(H_p - H_m) / max(abs(H_m), kin)
    assert rel <= 1e-13, rel
    vn_m, vn_p = _check_along_grad_and_reflecting(mc, prm, q, pm, pp, lam)
    assert abs(vn_p + vn_m) <= 1e-12 * abs(vn_m)  # elastic: the normal velocity is reversed
    return pp, rel


def _solve_w(mv, q, pp, tau, prm):
    """Independent Newton solve of Pm(q, w, tau) = pp (own iteration, own stopping rule)."""
    n = q.shape[0]
    w = np.empty(n)
    mv.velocity_guess(q, pp, prm, w)
    r, J = np.empty(n), np.empty((n, n))
    for _ in range(50):
        mv.SVC_PmJ(q, w, tau, 0.0, prm, r, J)
        dw = np.linalg.solve(J, r - pp)
        w -= dw
        if np.max(np.abs(dw)) <= 1e-15 * (1.0 + np.max(np.abs(w))):
            break
    mv.SVC_PmJ(q, w, tau, 0.0, prm, r, J)
    return w, r


def _vci_check(mv, prm, q, pm, Epre, tau_rem, h):
    pp = np.empty_like(pm)
    it, lam = mv.reset_vci(q, pm, *_law(mv, q, pm, prm), Epre, pm, 0.0, tau_rem, h, 0.0, prm, NTOL, MAXIT, pp)
    assert it > 0, (q, pm, Epre, tau_rem)
    w, r = _solve_w(mv, q, pp, tau_rem, prm)
    res_p = np.max(np.abs(r - pp)) / max(1.0, np.max(np.abs(pp)))
    res_E = abs(mv.SVC_Ed(q, w, tau_rem, prm) - Epre) / max(1.0, abs(Epre))
    assert res_p <= 1e-12, res_p
    assert res_E <= 1e-12, res_E
    _check_along_grad_and_reflecting(mv, prm, q, pm, pp, lam)
    return pp, res_E


@pytest.mark.parametrize("scene", SCENES)
def test_cva_reset_random_states(scene):
    _, prm, mc, _ = _mods(scene)
    worst = max(_cva_check(mc, prm, q, pm)[1] for q, pm, *_ in _random_impacts(scene, 150, 1))
    assert worst <= 1e-13


def _vci_has_reflecting_root(mv, mc, prm, q, pm, Epre, tau_rem):
    """Does eq. (33) have a root with lam > 0? Scan F(lam) = -D3 Ld(q, w(lam), tau_rem) - E_pre,
    w(lam) solving Pm(q, w, tau_rem) = pm + lam grad phi, for sign changes on lam in (0, 20 lam_CVA]."""
    g = _grad(mv, q, prm)
    lam_c = mc.cva_lambda(q, pm, prm, np.empty_like(q))
    F = []
    for lam in np.linspace(0.0, 20.0 * lam_c, 4001)[1:]:
        w, _ = _solve_w(mv, q, pm + lam * g, tau_rem, prm)
        F.append(mv.SVC_Ed(q, w, tau_rem, prm) - Epre)
    F = np.array(F)
    return bool(np.any(np.sign(F[1:]) != np.sign(F[:-1]))), float(F.min())


@pytest.mark.parametrize("scene", SCENES)
def test_vci_reset_random_states(scene):
    """Every random impact where eq. (33) has a reflecting root is solved to 1e-12. R^VCI has no
    solution when the discrete energies of the two partial steps differ (O(h^2), sign depending
    on dtau vs tau_rem) by more than the normal kinetic energy can absorb; such samples (1 of 150
    for the cart-pendulum and the double pendulum with this seed) must come back as a failure,
    and the scan confirms that no root exists."""
    _, prm, mc, mv = _mods(scene)
    worst, failed = 0.0, 0
    for q, pm, E, _, tr, h in _random_impacts(scene, 150, 2):
        pp = np.empty_like(pm)
        it, _ = mv.reset_vci(q.copy(), pm.copy(), *_law(mv, q, pm, prm), E, pm.copy(), 0.0, tr, h, 0.0, prm, NTOL, MAXIT, pp)
        if it < 0:
            failed += 1
            exists, Fmin = _vci_has_reflecting_root(mv, mc, prm, q, pm, E, tr)
            assert not exists, (q, pm, E, tr)
            continue
        worst = max(worst, _vci_check(mv, prm, q, pm, E, tr, h)[1])
    assert failed <= 3
    assert worst <= 1e-12


@pytest.mark.parametrize("scene", ["cart_pendulum", "double_pendulum"])
@pytest.mark.parametrize("method", ["CVA", "VCI"])
def test_resets_at_recorded_impacts(scene, method):
    """Impacts of real runs: the reset recomputed from the recorded pre-impact data reproduces the
    recorded p+, and satisfies its equations."""
    _, prm, mc, mv = _mods(scene)
    for q, pm, Epre, dtau, tau_rem, h, pp_rec in _recorded_impacts(scene, method):
        if method == "CVA":
            pp, _ = _cva_check(mc, prm, q, pm)
        else:
            pp, _ = _vci_check(mv, prm, q, pm, Epre, tau_rem, h)
        np.testing.assert_allclose(pp, pp_rec, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("method", ["CVA", "VCI"])
def test_trajectory_impact_records_change_p_along_grad_phi(method):
    """The Trajectory's own impact records (all impacts, not only the first of a step)."""
    s, prm, mc, _ = _mods("cart_pendulum")
    for beta in (3.2, 4.2, 5.2):
        tr = vcirun.simulate("cart_pendulum", method, h=1e-2, T=5.0, beta=beta)
        assert tr.status == "ok" and len(tr.impacts) == 3
        for q, pm, pp in zip(tr.impact_q, tr.impact_p_minus, tr.impact_p_plus):
            assert abs(q[0]) <= 1e-12  # on the surface phi = y = 0
            g = _grad(mc, q, prm)
            lam = (pp - pm) @ g / (g @ g)
            _check_along_grad_and_reflecting(mc, prm, q, pm, pp, lam)
            if method == "CVA":
                H_m, H_p = mc.hamiltonian(q, pm, prm), mc.hamiltonian(q, pp, prm)
                assert abs(H_p - H_m) <= 1e-13 * abs(H_m)


def test_vci_reset_reports_failure_when_eq33_has_no_solution():
    """R^VCI needs E_pre >= min_w -D3 Ld(q, w, tau_rem). For the oscillator -D3 Ld^SVC =
    m w^2 / 2 + k (q^2 + (q + tau w)^2) / 4 is a quadratic in w with an explicit minimum; below it
    there is no root and the reset must say so (negative iteration count), not return p+ = p-."""
    _, prm, _, mv = _mods("oscillator_wall")
    m, k, d = prm
    q, pm, tau = np.array([-d]), np.array([-1e-3]), 0.05
    a, b, c = m / 2 + k * tau**2 / 4, k * tau * q[0] / 2, k * q[0] ** 2 / 2
    Emin = c - b * b / (4 * a)
    for dE in (1e-4, 1e-2, 1.0):
        pp = np.zeros(1)
        it, _ = mv.reset_vci(q, pm, *_law(mv, q, pm, prm), Emin - dE, pm, 0.0, tau, 0.1, 0.0, prm, NTOL, MAXIT, pp)
        assert it < 0


def test_vci_reset_finds_reflecting_root_when_one_exists():
    _, prm, _, mv = _mods("oscillator_wall")
    m, k, d = prm
    q, pm, tau = np.array([-d]), np.array([-1e-3]), 0.05
    a, b, c = m / 2 + k * tau**2 / 4, k * tau * q[0] / 2, k * q[0] ** 2 / 2
    Emin = c - b * b / (4 * a)
    for dE in (1e-4, 1e-2, 1e-1):
        E = Emin + dE
        w = np.roots([a, b, c - E])
        lam_ref = np.max(m * w + tau * k * q[0] / 2) - pm[0]   # the reflecting root (p+ > 0)
        pp = np.zeros(1)
        it, lam = mv.reset_vci(q, pm, *_law(mv, q, pm, prm), E, pm, 0.0, tau, 0.1, 0.0, prm, NTOL, MAXIT, pp)
        assert it > 0 and abs(lam - lam_ref) <= 1e-10 * abs(lam_ref), (dE, it, lam, lam_ref)


# --- a reset added as one unit file and one descriptor row --------------------------------------

PLASTIC_UNIT = """# numba source unit: a perfectly plastic reset, p+ = p- + s grad phi with zero normal velocity after.
from numba import njit

from vcirun.codegen.frame import scratch, scratch2
from vcirun.codegen.roles import NDOF, sys_M
from vcirun.maps.linalg import solve_small


@njit(cache=True, nogil=True, error_model="numpy")
def reset_plastic(q, pm, d, s0, dE, E_pre, vpre, dtau, tau_rem, h, t, prm, ntol, maxit, pp):
    \"\"\"s = -(d . M^-1 pm) / (d . M^-1 d): d . M^-1 pp = 0.\"\"\"
    A = scratch2(NDOF, NDOF)
    sys_M(q, prm, A)
    x = scratch(NDOF)
    for i in range(NDOF):
        x[i] = d[i]
    if not solve_small(A, x, NDOF):
        return -1, s0
    dWd = 0.0
    dWp = 0.0
    for i in range(NDOF):
        dWd += d[i] * x[i]
        dWp += x[i] * pm[i]
    s = -dWp / dWd
    for i in range(NDOF):
        pp[i] = pm[i] + s * d[i]
    return 1, s
"""


@pytest.fixture
def plastic(tmp_path, monkeypatch):
    """The plastic reset as one unit file and one descriptor row (registered for this test only)."""
    path = tmp_path / "reset_plastic.py"
    path.write_text(PLASTIC_UNIT)
    monkeypatch.setattr(roles, "RESETS", dict(roles.RESETS))
    row = roles.register_reset(roles.ResetMap("plastic", str(path), "reset_plastic", conserves=""))
    return Method("PLASTIC", ld="SVC", reset="plastic"), row


def _check_plastic_run(method, h, tol, loader=None):
    """The oscillator x'' = -x from x = 1 at rest hits the wall x = -1/2 at t* = 2 pi / 3 with
    velocity -sqrt(3)/2 and stops there; the spring then pulls it back: x = -cos(t - t*) / 2, energy
    1/8 (from 1/2), no further impact before T = 5 (it grazes the wall again at t* + 2 pi)."""
    tr = vcirun.simulate("oscillator_wall", method, h=h, T=5.0, loader=loader)
    assert tr.ok and tr.impacts.shape == (1,), tr.message
    t_star = 2 * np.pi / 3
    assert abs(tr.impacts[0] - t_star) < tol
    assert tr.impact_q[0, 0] == pytest.approx(-0.5, abs=1e-12)
    assert tr.impact_p_minus[0, 0] == pytest.approx(-np.sqrt(3) / 2, abs=tol)
    assert abs(tr.impact_p_plus[0, 0]) < 1e-13          # plastic: nothing left of the normal velocity
    exact = np.where(tr.t < t_star, np.cos(tr.t), -0.5 * np.cos(tr.t - t_star))
    assert np.max(np.abs(tr.q[:, 0] - exact)) < tol     # second order
    after = tr.t > t_star + h
    assert np.allclose(tr.H[after], 0.125, atol=tol) and tr.H[0] == pytest.approx(0.5)


def test_a_reset_is_one_unit_file_and_one_descriptor_row(plastic):
    """A plastic reset p+ = p- + s grad phi with zero normal velocity, from an existing kernel (sys_M)
    and unit (solve_small): its unit file and its row, then a method with it through vcirun.simulate
    (the assembled module run uncompiled, vcirun.codegen.evaluate.python_module_for)."""
    from vcirun.codegen.evaluate import python_module_for

    method, row = plastic
    units.check_unit(units.Unit(row.unit))
    assert [u.path for u in units.select_units(method.kernel_set())][-2] == row.unit   # before the loop
    assert not method.has_modified_energy and method.impact_order == 2
    _check_plastic_run(method, 1e-2, 2e-4, loader=python_module_for)
    with pytest.raises(units.ContractError, match="already declared"):
        roles.register_reset(roles.ResetMap("plastic", row.unit, "reset_other"))
    with pytest.raises(units.ContractError, match="is not a file"):
        roles.register_reset(roles.ResetMap("sticky", row.unit + ".missing", "reset_sticky"))
    with pytest.raises(units.ContractError, match="needs 'lcp', not a generated part"):
        roles.register_reset(roles.ResetMap("sticky", row.unit, "reset_sticky", needs=("lcp",)))


@pytest.mark.slow
def test_a_registered_reset_compiles(plastic):
    """The same method compiled (the shared core of its family, ~1 min once per machine)."""
    _check_plastic_run(plastic[0], 1e-3, 2e-6)
