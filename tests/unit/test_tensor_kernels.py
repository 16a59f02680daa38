"""Step kernels from per-slot tensors (vcirun.codegen.tensor, the default kernel path) against the
expanded slot expressions (vcirun.discrete.lagrangians.step_expressions).

1. Kernel by kernel (Pm, J = dPm/dv, Pp, Ed, dEd/dv), executed as plain Python (no numba compile):
   the two paths agree to ~1e-12 relative at random (q0, v, t) and step lengths h including 0 and
   negative h (stages of compositions with negative fractions), for every explicit Ld and four
   scenes (one of them forced).
2. J and dEd/dv of the tensor path against central differences of its own Pm and Ed.
3. Whole compiled simulations (CVA, VCI, SVA, midpoint) agree with the expanded path to round-off.
"""
from __future__ import annotations

import importlib.util
import sys
import types

import numpy as np
import pytest

from vcirun.codegen import derive, frame
from vcirun.discrete.quadrature import quadrature_nodes
from vcirun.discrete.lagrangians import LIBRARY, ExplicitLd
from vcirun.scenes.registry import get_scene

SYSTEMS = ("cart_pendulum", "double_pendulum", "n_pendulum_3", "damped_oscillator", "forced_2dof")
LDS = ("SE1", "SE2", "SVC", "midpoint")
STEPS = (0.0, 0.013, 0.2, -0.07, -0.31)  # h = 0 (partial step at an impact) and negative stages
RTOL_PATHS = 1e-12
RTOL_FD = 1e-6


def _forced_2dof():
    """A 2-DOF system whose mass matrix depends on both coordinates and whose force depends on q,
    qdot and t (the built-in forced scenes are 1-DOF with f = -c qdot)."""
    import sympy as sp

    from vcirun.mechanics.system import MechanicalSystem

    x, y, xd, yd, t = sp.symbols("x y x_dot y_dot t")
    a, b, c, k = sp.symbols("a b c k")
    M = sp.Matrix([[2 + a * sp.cos(y), b * sp.sin(x) * y], [b * sp.sin(x) * y, 1 + x ** 2]])
    return MechanicalSystem(
        name="forced_2dof", q=[x, y], qd=[xd, yd], t=t, params={"a": 0.5, "b": 0.3, "c": 0.2, "k": 1.5},
        M=M, V=k * (x ** 2 + y ** 4) / 2 + x * y, phi=x + 3,
        forcing=sp.Matrix([-c * xd + sp.sin(t) * y, -c * x * yd ** 2 + sp.cos(t + xd)]))


def _system(name):
    return _forced_2dof() if name == "forced_2dof" else get_scene(name)


def _njit(*args, **kwargs):
    if args and callable(args[0]):
        return args[0]
    return lambda f: f


def _python_kernels(system, ld: str, path: str):
    """The step kernels of `ld` (with <ld>_Edv) on `path`, executed as plain Python, with the system
    kernels they call (the node data sys_node of the cached kernels <ld>_PmJc, <ld>_Ppc)."""
    text = (f"import math\nimport numpy as np\n\nNDOF = {system.n}\n\n" + derive.system_kernels_source(system, path)
            + "\n\n" + derive.ld_kernels_source(system, [ld], ld, path))
    mod = types.ModuleType(f"tensor_test_{system.name}_{ld}_{path}")
    mod.__dict__["njit"] = _njit
    mod.__dict__.update(frame.PYTHON)   # the header's stack arrays, as numpy
    exec(compile(text, mod.__name__, "exec"), mod.__dict__)
    return mod


def _evaluate(mod, ld, n, q0, v, h, t, prm):
    r, J, pp, ev = np.empty(n), np.empty((n, n)), np.empty(n), np.empty(n)
    getattr(mod, f"{ld}_PmJ")(q0, v, h, t, prm, r, J)
    getattr(mod, f"{ld}_Pp")(q0, v, h, t, prm, pp)
    E = getattr(mod, f"{ld}_Ed")(q0, v, h, prm)
    getattr(mod, f"{ld}_Edv")(q0, v, h, prm, ev)
    return {"Pm": r, "J": J, "Pp": pp, "Ed": np.array([E]), "Edv": ev}


def rel_err(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


@pytest.fixture(scope="module")
def kernel_pairs():
    cache = {}

    def get(system_name, ld):
        if (system_name, ld) not in cache:
            s = _system(system_name)
            cache[system_name, ld] = (s, _python_kernels(s, ld, "tensor"), _python_kernels(s, ld, "expanded"))
        return cache[system_name, ld]

    return get


def test_quadrature_nodes_of_the_library():
    assert quadrature_nodes(LIBRARY["SE1"]) == ((0.0, 1.0),)
    assert quadrature_nodes(LIBRARY["SE2"]) == ((1.0, 1.0),)
    assert quadrature_nodes(LIBRARY["SVC"]) == ((0.0, 0.5), (1.0, 0.5))
    assert quadrature_nodes(LIBRARY["midpoint"]) == ((0.5, 1.0),)
    assert quadrature_nodes(LIBRARY["SVA"]) is None  # a composition: its stages are the explicit Lds

    def not_a_rule(L, q0, q1, h):  # h L(q0, v)^2 / h: no quadrature rule -> expanded fallback
        v = [(b - a) / h for a, b in zip(q0, q1)]
        return L(q0, v) ** 2

    assert quadrature_nodes(ExplicitLd("sq", 1, False, not_a_rule)) is None


def test_kernel_path_selection(monkeypatch):
    monkeypatch.delenv(derive.KERNEL_PATH_ENV, raising=False)
    assert derive.kernel_path() == derive.DEFAULT_KERNEL_PATH == "tensor"
    monkeypatch.setenv(derive.KERNEL_PATH_ENV, "expanded")
    assert derive.kernel_path() == "expanded"
    assert derive.kernel_path("tensor") == "tensor"
    s = get_scene("cart_pendulum")
    assert "vcirun.codegen.tensor" not in derive.ld_kernels_source(s, ["SVC"])
    monkeypatch.setenv(derive.KERNEL_PATH_ENV, "fancy")
    with pytest.raises(ValueError, match="VCIRUN_KERNEL_PATH"):
        derive.kernel_path()


@pytest.mark.parametrize("system_name", SYSTEMS)
@pytest.mark.parametrize("ld", LDS)
def test_tensor_kernels_equal_expanded_kernels(system_name, ld, kernel_pairs, rng):
    system, tens, expd = kernel_pairs(system_name, ld)
    n = system.n
    prm = system.param_values()
    worst = {}
    for h in STEPS:
        for _ in range(3):
            q0, v, t = rng.uniform(-1.2, 1.2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(0.0, 2.0)
            a = _evaluate(tens, ld, n, q0, v, h, t, prm)
            b = _evaluate(expd, ld, n, q0, v, h, t, prm)
            for k in a:
                assert np.all(np.isfinite(a[k])), (k, h)
                worst[k] = max(worst.get(k, 0.0), rel_err(a[k], b[k]))
    bad = {k: e for k, e in worst.items() if not e < RTOL_PATHS}
    assert not bad, f"{system_name}/{ld}: tensor vs expanded relative differences above {RTOL_PATHS}: {bad}"


@pytest.mark.parametrize("system_name", SYSTEMS)
@pytest.mark.parametrize("ld", LDS)
def test_tensor_jacobians_match_finite_differences(system_name, ld, kernel_pairs, rng):
    system, tens, _ = kernel_pairs(system_name, ld)
    n = system.n
    prm = system.param_values()
    worst = {"J": 0.0, "Edv": 0.0}
    for h in (0.0, 0.2, -0.07):
        q0, v, t = rng.uniform(-1.2, 1.2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(0.0, 2.0)
        a = _evaluate(tens, ld, n, q0, v, h, t, prm)
        steps = 1e-6 * np.maximum(1.0, np.abs(v))
        Jfd, Efd = np.empty((n, n)), np.empty(n)
        for j in range(n):
            e = np.zeros(n)
            e[j] = steps[j]
            up, dn = _evaluate(tens, ld, n, q0, v + e, h, t, prm), _evaluate(tens, ld, n, q0, v - e, h, t, prm)
            Jfd[:, j] = (up["Pm"] - dn["Pm"]) / (2 * steps[j])
            Efd[j] = (up["Ed"][0] - dn["Ed"][0]) / (2 * steps[j])
        worst["J"] = max(worst["J"], rel_err(a["J"], Jfd))
        worst["Edv"] = max(worst["Edv"], rel_err(a["Edv"], Efd))
    bad = {k: e for k, e in worst.items() if not e < RTOL_FD}
    assert not bad, f"{system_name}/{ld}: analytic vs finite-difference relative errors above {RTOL_FD}: {bad}"


@pytest.mark.parametrize("system_name", SYSTEMS)
@pytest.mark.parametrize("ld", LDS)
@pytest.mark.parametrize("path", ["tensor", "expanded"])
def test_node_data_handoff(system_name, ld, path, kernel_pairs, rng):
    """The full step keeps node data (vcirun.maps.steps): <ld>_Ppc must hand over exactly (bit for bit)
    sys_node at q1 = q0 + h v, the start of the next stage, and the cached kernels with c =
    sys_node(q0) must give exactly what the plain ones give; sys_node_M must rebuild M(q)."""
    system, tens, expd = kernel_pairs(system_name, ld)
    mod = tens if path == "tensor" else expd
    n = system.n
    prm = system.param_values()
    for h in STEPS:
        q0, v, t = rng.uniform(-1.2, 1.2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(0.0, 2.0)
        c, cn, want = np.full(mod.NODE_LEN, np.nan), np.full(mod.NODE_LEN, np.nan), np.full(mod.NODE_LEN, np.nan)
        mod.sys_node(q0, prm, c)
        pp, pp_plain = np.empty(n), np.empty(n)
        getattr(mod, f"{ld}_Ppc")(q0, v, h, t, prm, c, pp, cn)
        getattr(mod, f"{ld}_Pp")(q0, v, h, t, prm, pp_plain)
        q1 = np.array([q0[a] + h * v[a] for a in range(n)])
        mod.sys_node(q1, prm, want)
        written = ~np.isnan(want)  # structural zeros of the tensors are never written nor read
        assert written.any() and np.array_equal(cn[written], want[written]), (h, cn, want)
        assert np.array_equal(pp, pp_plain)
        r, J, r2, J2 = np.empty(n), np.empty((n, n)), np.empty(n), np.empty((n, n))
        getattr(mod, f"{ld}_PmJc")(q0, v, h, t, prm, c, r, J)
        getattr(mod, f"{ld}_PmJ")(q0, v, h, t, prm, r2, J2)
        assert np.array_equal(r, r2) and np.array_equal(J, J2)
        A, M = np.empty((n, n)), np.empty((n, n))
        mod.sys_node_M(c, A)
        mod.sys_M(q0, prm, M)
        assert rel_err(A, M) < RTOL_PATHS


@pytest.mark.parametrize("system_name", SYSTEMS)
def test_tensor_dhq_equals_expanded(system_name, rng):
    """sys_dHq (dH/dq at fixed x = M^-1 p) from the tensors equals system.dH_dq_at, expanded."""
    system = _system(system_name)
    n = system.n
    mods = {}
    for path in ("tensor", "expanded"):
        text = "import math\nimport numpy as np\n\n" + derive.system_kernels_source(system, path)
        mods[path] = types.ModuleType(f"dhq_test_{system_name}_{path}")
        mods[path].__dict__["njit"] = _njit
        mods[path].__dict__.update(frame.PYTHON)
        exec(compile(text, mods[path].__name__, "exec"), mods[path].__dict__)
    prm = system.param_values()
    for _ in range(5):
        q, x = rng.uniform(-1.2, 1.2, n), rng.uniform(-1.5, 1.5, n)
        a, b = np.empty(n), np.empty(n)
        mods["tensor"].sys_dHq(q, x, prm, a)
        mods["expanded"].sys_dHq(q, x, prm, b)
        assert rel_err(a, b) < RTOL_PATHS, (a, b)


# --- whole simulations, compiled --------------------------------------------------------------
SIMS = [  # (system, method, method options, simulate keywords): impacts with SVC (CVA, VCI) and SVA
    # (SE1 and SE2 stages); a forced smooth run with the midpoint rule (second derivatives)
    ("cart_pendulum", "CVA", {}, {"beta": 3.2, "h": 1e-2, "T": 3.0}),
    ("double_pendulum", "VCI", {}, {"h": 1e-2, "T": 2.0}),
    ("n_pendulum_3", "CVA", {"ld": "SVA"}, {"h": 1e-2, "T": 2.0}),
    ("damped_oscillator", "midpoint", {}, {"h": 5e-2, "T": 5.0}),
]


def _compiled_expanded(system, ks, directory):
    """The module of (system, ks) on the expanded path, compiled from its own file (the kernel cache
    key does not know the kernel path, so the cache is bypassed)."""
    text = derive.module_source(system, ks, kernel_path="expanded")
    name = f"vcirun_expanded_{system.name}_{abs(hash(ks.key_text()))}"
    path = directory / f"{name}.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow  # each case builds the expanded-path module too (40-90 s cold); `make test-all`
@pytest.mark.parametrize("system_name, method, mopts, kw", SIMS,
                         ids=[f"{s}-{m}" + "".join(f"-{v}" for v in o.values()) for s, m, o, _ in SIMS])
def test_simulation_agrees_with_expanded_path(system_name, method, mopts, kw, tmp_path, monkeypatch):
    import vcirun
    from vcirun.codegen.build import load_module
    from vcirun.methods.table import resolve_method

    monkeypatch.delenv(derive.KERNEL_PATH_ENV, raising=False)
    system = get_scene(system_name)
    ks = resolve_method(method, **mopts).kernel_set()
    tens_mod = load_module(system, ks)
    for stage, _ in ks.full_stages:  # the default path is the tensor path
        kernel = getattr(tens_mod, f"{stage}_PmJ")
        assert "vcirun.codegen.tensor" in getattr(kernel, "py_func", kernel).__doc__
    a = vcirun.simulate(system, method, **mopts, **kw)
    exp_mod = _compiled_expanded(system, ks, tmp_path)
    b = vcirun.simulate(system, method, **mopts, **kw, loader=lambda s, k: exp_mod)
    assert a.status == b.status == "ok"
    assert len(a.impacts) == len(b.impacts)
    if method != "midpoint":
        assert len(a.impacts) > 0  # the comparison covers resets and partial steps
    scale = max(1.0, float(np.max(np.abs(b.p))), float(np.max(np.abs(b.q))))
    assert np.max(np.abs(a.q - b.q)) <= 1e-11 * scale
    assert np.max(np.abs(a.p - b.p)) <= 1e-11 * scale
    assert np.nanmax(np.abs(a.Ed - b.Ed)) <= 1e-11 * max(1.0, float(np.nanmax(np.abs(b.Ed))))
    assert np.max(np.abs(a.impacts - b.impacts), initial=0.0) <= 1e-11
