"""The shared build (vcirun.codegen.shared): a scene module holds only its kernels and calls
into its kernel set's core, compiled once and loaded by every scene.

- the shared build gives the specialized build's trajectory bit for bit (several contacts with
  restitution; the forced MCVA family in the slow set);
- a NEW scene in a fresh process compiles its kernels and nothing of the core (the point of the
  design: the loop is not compiled again per scene);
- the kernel ABI is enforced at compile time (a non-contiguous array cannot reach a kernel);
- threads running different scenes at once get their own scene's kernels (the slot table is
  process-global; calls are serialised).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import uuid

import numpy as np
import pytest

import vcirun
from vcirun.codegen import build
from vcirun.codegen.kernel_cache import default
from vcirun.codegen.roles import mat, vec   # (annotations of a kernel declared in a test)


def _both(monkeypatch, system, method, **kw):
    out = {}
    for mode in ("specialized", "shared"):
        monkeypatch.setenv("VCIRUN_BUILD", mode)
        out[mode] = vcirun.simulate(system, method, **kw)
    return out["specialized"], out["shared"]


def _same(a, b):
    assert a.status == b.status
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.p, b.p)
    np.testing.assert_array_equal(a.impacts, b.impacts)
    np.testing.assert_array_equal(a.impact_contact, b.impact_contact)
    np.testing.assert_array_equal(a.impact_impulse, b.impact_impulse)
    np.testing.assert_array_equal(a.H, b.H)


def test_shared_build_equals_specialized_several_contacts(monkeypatch):
    spec, shar = _both(monkeypatch, "ball_in_box", "CVA", h=0.01, T=3.0, params={"e": 0.9})
    assert len(shar.impacts) > 3
    _same(spec, shar)
    assert any(hasattr(m, "SHARED_CORE") for m in default().loaded.values())
    assert any(not hasattr(m, "SHARED_CORE") for m in default().loaded.values())


@pytest.mark.slow
@pytest.mark.parametrize("method", ["MCVAC", "VCI"])
def test_shared_build_equals_specialized_forced(monkeypatch, method):
    spec, shar = _both(monkeypatch, "bouncing_ball", method, h=0.01, T=3.0, params={"c": 0.3})
    _same(spec, shar)


_YAML = """\
name: shared_core_probe_{tag}
coordinates: [x, y]
parameters: {{m: 1.0, g: 9.81, c: {c}}}
mass_matrix: [[m, 0], [0, m]]
potential: "m*g*y + c*x**2"
constraint: "y"
"""

_PROBE = r"""
import json, sys
from numba.core import event
compiled = []
class L(event.Listener):
    def on_start(self, ev): compiled.append(ev.data["dispatcher"].py_func.__module__)
    def on_end(self, ev): pass
event.register("numba:compile", L())
import vcirun
tr = vcirun.simulate(sys.argv[1], "CVA", h=0.01, T=1.0, q0=[0.0, 1.0], p0=[0.3, 0.0])
print(json.dumps({"status": tr.status, "impacts": len(tr.impacts), "modules": sorted(set(compiled))}))
"""


def test_new_scene_compiles_no_core_in_a_fresh_process(tmp_path, monkeypatch):
    monkeypatch.delenv("VCIRUN_BUILD", raising=False)
    first = tmp_path / "first.yaml"
    first.write_text(_YAML.format(tag="a", c=0.25))
    vcirun.simulate(str(first), "CVA", h=0.01, T=0.1, q0=[0.0, 1.0], p0=[0.3, 0.0])  # the core of CVA exists now
    new = tmp_path / "new.yaml"  # a scene no cache has seen: its own kernels must be compiled
    new.write_text(_YAML.format(tag=uuid.uuid4().hex[:8], c=0.5 + int(uuid.uuid4().int % 1000) / 1e4))
    env = {k: v for k, v in os.environ.items() if k != "VCIRUN_BUILD"}
    r = subprocess.run([sys.executable, "-c", _PROBE, str(new)], capture_output=True, text=True, env=env,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    got = json.loads(r.stdout.strip().splitlines()[-1])
    assert got["status"] == "ok" and got["impacts"] >= 1
    assert any(m.startswith("vcirun_scene_") for m in got["modules"]), got  # its kernels were compiled
    assert not [m for m in got["modules"] if m.startswith("vcirun_core_")], got  # the loop was not


def test_kernel_abi_refuses_a_strided_array():
    from numba import njit
    from numba.core.errors import TypingError

    from vcirun.codegen.kcall import kcall

    @njit
    def bad(x):
        return kcall(0, 0, "a", (x[::2],))

    with pytest.raises(TypingError, match="kernel ABI"):
        bad(np.zeros(4))


def test_threads_running_different_scenes_get_their_own_kernels(monkeypatch):
    monkeypatch.delenv("VCIRUN_BUILD", raising=False)
    runs = [("cart_pendulum", {"beta": 3.2}), ("double_pendulum", {})]
    want = [vcirun.simulate(s, "CVA", h=0.01, T=2.0, **kw) for s, kw in runs]
    got, errors = {}, []

    def work(i):
        try:
            s, kw = runs[i % 2]
            got[i] = vcirun.simulate(s, "CVA", h=0.01, T=2.0, **kw)
        except Exception as e:  # noqa: BLE001 (reported below)
            errors.append(e)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert not errors and len(got) == 8
    for i, tr in got.items():
        np.testing.assert_array_equal(tr.q, want[i % 2].q)


def test_core_text_reads_the_scene_sizes_at_run_time():
    """In the core, the scene's sizes and the kernel set's stage data are slot reads (NDOF -> slot(0));
    with a fixed n, NDOF is a constant again; every CVA-family kernel set has the same core."""
    import io
    import tokenize

    from vcirun.codegen import shared
    from vcirun.methods.table import METHODS

    def names(text):
        return {t.string for t in tokenize.generate_tokens(io.StringIO(text).readline) if t.type == tokenize.NAME}

    from vcirun.codegen.kcall import NSLOTS

    assert len(shared.LAYOUT) <= NSLOTS
    read = set(shared.SCALARS) | {a for a, _ in shared.ARRAYS}
    ks = METHODS["MCVAC"].kernel_set()
    text = shared.core_source(ks)
    assert not names(text) & read
    slot = shared.SLOT
    assert slot["NDOF"] == 0 and "slot(0)" in text and f"(slot({slot['FORCED']}) != 0)" in text
    assert f"_slot_i8s({slot['FULL_STAGES']})" in text and "MH_FLOW_S = 2" in text
    fixed = shared.core_source(ks, ndof=3)
    assert "NDOF = 3" in fixed and names(fixed) & read == {"NDOF"}
    # CVA on SVC and its compositions CVA4, CVA6, CVA8 (5, 9, 17 stages) share one core
    cva = [m for m in METHODS.values() if m.kernel_set().reset == "cva" and m.kernel_set().modified is None]
    assert len({m.kernel_set() for m in cva}) >= 3
    assert len({shared.core_source(m.kernel_set()) for m in cva}) == 1


@pytest.mark.slow
def test_fixed_ndof_core_equals_run_time_ndof_core(monkeypatch):
    """VCIRUN_CORE_NDOF=fixed (one core per n, NDOF a compile-time constant) gives the same bits."""
    monkeypatch.delenv("VCIRUN_BUILD", raising=False)
    monkeypatch.delenv("VCIRUN_CORE_NDOF", raising=False)
    a = vcirun.simulate("double_pendulum", "CVA", h=0.01, T=2.0)
    monkeypatch.setenv("VCIRUN_CORE_NDOF", "fixed")
    b = vcirun.simulate("double_pendulum", "CVA", h=0.01, T=2.0)
    _same(a, b)


@pytest.mark.parametrize("var, value", [("VCIRUN_BUILD", "fast"), ("VCIRUN_CORE_NDOF", "3")])
def test_bad_build_choice_is_one_line_naming_the_variable(monkeypatch, var, value):
    monkeypatch.setenv(var, value)
    with pytest.raises(ValueError, match=var):
        vcirun.simulate("cart_pendulum", "CVA", h=0.01, T=0.1, beta=3.2)


def test_cold_build_estimate_counts_the_core_only_until_it_is_compiled(tmp_path, monkeypatch):
    """Shared build: scene kernels from this cache's record (scaled in n), plus the core's recorded
    time while numba has not cached it."""
    from vcirun.codegen import cache
    from vcirun.methods.table import METHODS

    monkeypatch.setenv("VCIRUN_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("VCIRUN_BUILD", raising=False)
    ks = METHODS["CVA"].kernel_set()
    key = default().core_key_of(ks, 2)
    (tmp_path / "build_times.json").write_text(json.dumps({"scene|CVA[SVC]|2": 3.0, f"core|{key}": 50.0}))
    assert cache.estimate_compile_s(ks, 2) == pytest.approx(53.0)
    assert cache.estimate_compile_s(ks, 4) == pytest.approx(56.0)   # the scene part linear in n
    pyc = build.cache_dir() / "__pycache__"
    pyc.mkdir(parents=True, exist_ok=True)
    (pyc / f"core_{key}.integrate-21.py311.nbi").write_bytes(b"")
    assert cache.estimate_compile_s(ks, 2) == pytest.approx(3.0)


def test_cold_build_estimate_of_an_empty_cache_needs_no_core_key(tmp_path, monkeypatch):
    """A cache with no core compiled or timed (a first run's): the first estimate of the core, without
    assembling the core's text for its key; once a core is timed, the key is asked for again."""
    from vcirun.codegen import cache, compile_notes
    from vcirun.methods.table import METHODS

    monkeypatch.setenv("VCIRUN_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("VCIRUN_BUILD", raising=False)
    ks = METHODS["CVA"].kernel_set()
    kc = default()
    key = kc.core_key_of(ks, 2)
    want = compile_notes._DEFAULT_SCENE_S["CVA"] + compile_notes._DEFAULT_CORE_S["general"]
    asked = []
    monkeypatch.setattr(kc, "core_key_of", lambda *a, **k: asked.append(a) or key)
    assert cache.estimate_compile_s(ks, 2) == pytest.approx(want) and not asked
    (tmp_path / "build_times.json").write_text(json.dumps({f"core|{key}": 50.0}))
    assert cache.estimate_compile_s(ks, 2) == pytest.approx(compile_notes._DEFAULT_SCENE_S["CVA"] + 50.0) and asked


def test_a_scene_takes_the_lean_core_only_when_it_has_one_unforced_contact():
    """One constraint, no force, no declared reset: the lean core (those constants compiled in, the
    several-contact impact pruned), for a method's kernel set and the system-only one (the exact
    reference's) alike; any other scene: the general core, which reads them at run time."""
    from vcirun.codegen import shared
    from vcirun.codegen.kernel_set import SYSTEM_KERNELS
    from vcirun.methods.table import METHODS
    from vcirun.scenes.registry import get_scene

    ks = METHODS["CVA"].kernel_set()
    feats = {name: build.system_core_features(ks, get_scene(name))
             for name in ("cart_pendulum", "ball_in_box", "damped_oscillator", "rimless_wheel")}
    F = shared.FRICTIONLESS   # several contacts or a force, no friction: the general core without friction code
    assert feats == {"cart_pendulum": shared.LEAN, "ball_in_box": F, "damped_oscillator": F, "rimless_wheel": F}
    assert build.system_core_features(SYSTEM_KERNELS, get_scene("cart_pendulum")) == shared.LEAN
    assert build.system_core_features(SYSTEM_KERNELS, get_scene("ball_in_box")) == F
    from vcirun.scenes.friction import incline, rocking_block_friction

    assert build.system_core_features(ks, rocking_block_friction()) == ()   # friction: the general core
    # one contact with friction: the lean core with FRICTION compiled in as True, reference included
    assert build.system_core_features(ks, incline(0.3, mu=0.2)) == shared.LEAN_FRICTION
    assert build.system_core_features(SYSTEM_KERNELS, incline(0.3, mu=0.2)) == shared.LEAN_FRICTION
    assert "NCON = 1\nFORCED = False\n" in shared.core_source(ks, features=shared.LEAN_FRICTION)
    assert len({default().core_key_of(ks, 2, f) for f in (shared.LEAN, shared.LEAN_FRICTION, ())}) == 3
    lean, general = shared.core_source(ks, features=shared.LEAN), shared.core_source(ks)
    assert "NCON = 1\nFORCED = False\n" in lean and "NCON = 1\n" not in general
    assert default().core_key_of(ks, 2, shared.LEAN) != default().core_key_of(ks, 2)


def test_linking_a_scene_to_a_core_compiled_for_other_constants_is_refused():
    import types

    from vcirun.codegen import shared
    from vcirun.codegen.roles import ContractError
    from vcirun.methods.table import METHODS

    core = types.SimpleNamespace(FEATURES=shared.LEAN, CORE_KEY="k", __name__="core_k")
    scene = types.SimpleNamespace(NCON=4, FORCED=False, RESET_MAP=False, RESET_LAW_FIRST=False)
    with pytest.raises(ContractError, match="NCON = 4.*NCON = 1"):
        shared.link("m", scene, core, METHODS["CVA"].kernel_set())


def test_the_lean_core_gives_the_specialized_build_bit_for_bit(monkeypatch):
    """The lean core against the specialized module of the same scene and method (one contact)."""
    a, b = _both(monkeypatch, "cart_pendulum", "VCI", h=0.01, T=5.0, beta=3.2)
    assert len(a.impacts) >= 3
    _same(a, b)


def test_cva_and_vci_share_one_core_that_binds_each_its_reset():
    """R^CVA and R^VCI in one core (their needs differ only in the energy gradient, a part a scene may
    lack): every CVA composition and VCI map to the same core text, which holds both resets and calls
    the one its scene's kernel set binds (RESET_ID, the index in core_resets); MCVA's core stays its
    own. No reset is named in the rule: it follows from the descriptors."""
    from vcirun.codegen import shared
    from vcirun.methods.table import METHODS, resolve_method

    sets = [METHODS[m].kernel_set() for m in ("CVA", "VCI", "CVA4", "CVA8")] + [resolve_method("VCI", ld="midpoint").kernel_set()]
    texts = {shared.core_source(ks, features=shared.LEAN) for ks in sets}
    assert len(texts) == 1
    text = texts.pop()
    assert "def reset_cva(" in text and "def reset_vci(" in text and "reset = reset_of_scene" in text
    assert "    if slot(%d) == 0:\n        return reset_cva(" % shared.SLOT["RESET_ID"] in text
    assert [r.name for r in shared.core_resets(METHODS["CVA"].kernel_set())] == ["cva", "vci"]
    assert METHODS["CVA"].kernel_set().part("energy_gradient") is None
    assert METHODS["VCI"].kernel_set().part("energy_gradient") == "SVC"
    mcva = shared.core_source(METHODS["MCVAC"].kernel_set(), features=shared.LEAN)
    assert "reset_of_scene" not in mcva and "reset = reset_mcva" in mcva


def test_cold_method_families_are_grouped_by_the_core_they_compile(tmp_path, monkeypatch):
    """A sweep's preflight compiles cold kernel sets side by side, one group per shared core (CVA and
    VCI share theirs, MCVAA and MCVAC theirs); nothing is cold in a cache that holds them."""
    from vcirun.experiments.precompile import compile_groups
    from vcirun.scenes.registry import get_scene

    monkeypatch.delenv("VCIRUN_BUILD", raising=False)
    methods = [(m, {}, {}) for m in ("CVA", "MCVAA", "VCI", "MCVAC")]
    sysm = get_scene("cart_pendulum")
    monkeypatch.setenv("VCIRUN_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(default(), "loaded", {})   # (modules this process loaded count as built)
    groups = compile_groups(sysm, methods)
    assert [[n for n, *_ in g] for g in groups] == [["CVA", "VCI"], ["MCVAA", "MCVAC"]]
    monkeypatch.undo()
    for m in ("CVA", "MCVAA", "VCI", "MCVAC"):
        vcirun.simulate("cart_pendulum", m, h=0.01, T=0.01, beta=3.2)
    assert compile_groups(sysm, methods) == []


def test_cold_scene_kernels_compile_side_by_side_in_worker_processes(tmp_path, monkeypatch):
    """compile_side_by_side on a cache that holds the CVA and VCI cores but not the scene's kernels:
    two spawn processes compile one kernel set each, and the parent then finds both cached."""
    import shutil

    from vcirun.codegen.cache import cold_parts, core_key_for
    from vcirun.experiments.precompile import compile_side_by_side
    from vcirun.methods.table import METHODS
    from vcirun.scenes.registry import get_scene

    monkeypatch.delenv("VCIRUN_BUILD", raising=False)
    sysm = get_scene("cart_pendulum")
    methods = [(m, {}, dict(h=0.01, T=0.01, beta=3.2)) for m in ("CVA", "VCI")]
    src = build.cache_dir()
    for m, _, kw in methods:
        vcirun.simulate("cart_pendulum", m, **kw)   # the suite's cache holds both cores (compiled now if not)
    dest = tmp_path / "kernels"
    (dest / "__pycache__").mkdir(parents=True)
    for m, *_ in methods:
        key = core_key_for(sysm, METHODS[m].kernel_set())
        for f in [src / f"core_{key}.py", *(src / "__pycache__").glob(f"core_{key}.*")]:
            shutil.copy2(f, dest / f.relative_to(src))
    monkeypatch.setenv("VCIRUN_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(default(), "loaded", {})
    assert [cold_parts(sysm, METHODS[m].kernel_set()) for m, *_ in methods] == [("scene",), ("scene",)]
    assert compile_side_by_side("cart_pendulum", sysm, methods, cores=2) == 2
    assert [cold_parts(sysm, METHODS[m].kernel_set()) for m, *_ in methods] == [(), ()]
    assert compile_side_by_side("cart_pendulum", sysm, methods, cores=2) == 0   # nothing cold: nothing done


def test_a_kernel_declared_at_run_time_takes_the_next_slot_and_its_reset_a_core_of_its_own(monkeypatch, tmp_path):
    """A reset that needs a new kernel (docs/extending.md): the kernel's declaration adds its part and
    a slot after the others (no other core's text changes), the reset's core calls it through that
    slot, and the scene module defines it from its symbolic definition with the ABI wrapper."""
    import sympy as sp

    from vcirun.codegen import roles, shared
    from vcirun.codegen.derive import scene_source
    from vcirun.methods.table import METHODS, Method
    from vcirun.scenes.registry import get_scene

    monkeypatch.setattr(roles, "KERNELS", dict(roles.KERNELS))
    monkeypatch.setattr(roles, "PARTS", dict(roles.PARTS))
    monkeypatch.setattr(roles, "RESETS", dict(roles.RESETS))
    cva_core = shared.core_source(METHODS["CVA"].kernel_set(), features=shared.LEAN)
    before = len(shared.layout())

    @roles.kernel("test_hessian", derive=lambda s: {"out": sp.hessian(s.V, list(s.q))})
    def sys_test_hessV(q: vec("NDOF"), prm: vec("NPRM"), out: mat("NDOF", "NDOF")) -> int:
        """out = V''(q)."""

    monkeypatch.delattr(roles, "sys_test_hessV")
    unit = tmp_path / "reset_test.py"
    unit.write_text("from numba import njit\n\nfrom vcirun.codegen.frame import scratch2\n"
                    "from vcirun.codegen.roles import NDOF, sys_test_hessV\n\n\n"
                    '@njit(cache=True, nogil=True, error_model="numpy")\n'
                    "def reset_test(q, pm, d, s0, dE, E_pre, vpre, dtau, tau_rem, h, t, prm, ntol, maxit, pp):\n"
                    "    K = scratch2(NDOF, NDOF)\n    sys_test_hessV(q, prm, K)\n"
                    "    for i in range(NDOF):\n        pp[i] = pm[i] + (s0 + 0.0 * K[0, 0]) * d[i]\n    return 1, s0\n")
    roles.register_reset(roles.ResetMap("test_h", str(unit), "reset_test", needs=("test_hessian",)))
    ks = Method("CVA_test_h", ld="SVC", reset="test_h").kernel_set()
    assert ks.parts == (("test_hessian", True),)
    assert [r.name for r in shared.core_resets(ks)] == ["test_h"]          # registered from outside: its own core
    slot = shared.slots()["sys_test_hessV"]
    assert slot == before and len(shared.layout()) == before + 1         # the next slot; the others keep theirs
    assert shared.core_source(METHODS["CVA"].kernel_set(), features=shared.LEAN) == cva_core
    core = shared.core_source(ks, features=shared.LEAN)
    assert f"def sys_test_hessV(q, prm, out):\n    return kcall(slot({slot}), 0, 'aab'" in core
    assert "def reset_test(" in core and "reset = reset_test" in core and "def reset_cva(" not in core
    scene = scene_source(get_scene("oscillator_wall"), ks)
    assert "def sys_test_hessV(q, prm, out):" in scene and "def _p_sys_test_hessV(q, prm, out):" in scene
