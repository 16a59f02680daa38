"""Warm start: a built-in scene or a YAML system whose kernel module is cached starts from
the warm index -- no sympy, no scipy.integrate, no generated module -- and gives the same bits as
the symbolic (cold) path. The index goes stale with the files it hashes and falls back cleanly.

Subprocesses use the suite's kernel cache ($VCIRUN_CACHE_DIR), so their modules are compiled at most
once per cache; a cold path is forced by deleting the index entry. No timing assertions here (the
timings are bench/warm_start.py's).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

# every test here deletes or damages entries of the kernel cache's warm index that the others read:
# they hold the suite's warm-index lock (tests/conftest.py), so two workers never run them at once
pytestmark = pytest.mark.usefixtures("warm_index_lock")

import vcirun
import vcirun.run.resolve as resolve
from vcirun.codegen import build
from vcirun.codegen.kernel_cache import KernelCache, default
from vcirun.methods.table import METHODS

YAML = """name: warm_cart_yaml
description: the cart-pendulum as a YAML system (warm-start test)
coordinates: [y, theta]
parameters: {m1: 1.0, m2: 0.2, L: 2.0, g: 10.0}
mass_matrix:
  - ["m1 + m2", "m2*L*sin(theta)"]
  - ["m2*L*sin(theta)", "m2*L**2"]
potential: "(m1 + m2)*g*y - m2*g*L*cos(theta)"
constraint: "y"
q0: [0.3, 0.2]
qdot0: [-1.0, 1.0]
"""

FIELDS = ("t", "q", "p", "H", "Ed", "impacts", "impact_q", "impact_p_minus", "impact_p_plus", "impact_step",
          "partial_steps", "newton_iters")

CHILD = r"""
import json, os, sys, traceback
args = json.loads(sys.argv[1])
first_sympy = []   # where sympy was first imported from (the failure message of a warm run that built it)
class _Watch:
    def find_spec(self, name, path=None, target=None):
        if name == "sympy" and not first_sympy:
            first_sympy.append("".join(traceback.format_stack(limit=25)[:-1]))
        return None
sys.meta_path.insert(0, _Watch())
import vcirun
from vcirun.run import api, resolve
from vcirun.codegen import build
from vcirun.codegen.kernel_cache import default
from vcirun.methods.table import resolve_method
out, log = [], []
for system, method, kw, force_cold, instance in args["runs"]:
    if force_cold:  # delete the index entry: the symbolic path must run (and write it again)
        ident = resolve._warm_ident(system)[0]
        default().index_path(ident, resolve_method(method).kernel_set()).unlink(missing_ok=True)
    ident = resolve._warm_ident(system)[0]
    indexed = ident is not None and default().index_path(ident, resolve_method(method).kernel_set()).is_file()
    if instance:
        system = resolve.resolve_system(system)
    with default().report() as built:
        tr = vcirun.simulate(system, method, **kw)
    log += built.entries
    fields = {f: getattr(tr, f) for f in args["fields"]}
    out.append({"fields": {f: [v.dtype.str, list(v.shape), v.tobytes().hex()] for f, v in fields.items()},
                "status": tr.status, "system": tr.system, "options": tr.options,
                "log": built.entries, "indexed_before": indexed})
print(json.dumps({"runs": out, "log": log, "sympy": "sympy" in sys.modules, "scipy_integrate": "scipy.integrate" in sys.modules,
                  "vcirun.mechanics": "vcirun.mechanics" in sys.modules,
                  "derive": "vcirun.codegen.derive" in sys.modules, "first_sympy": first_sympy[:1],
                  "cache_dir": os.environ.get("VCIRUN_CACHE_DIR"), "tier": os.environ.get("VCIRUN_TIER")}))
"""


def child(runs) -> dict:
    arg = json.dumps({"runs": runs, "fields": FIELDS})
    r = subprocess.run([sys.executable, "-c", CHILD, arg], capture_output=True, text=True, env=dict(os.environ),
                       timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.fixture
def yaml_file(tmp_path):
    p = tmp_path / "warm_cart.yaml"
    p.write_text(YAML)
    return p


def _cases(yaml_file):
    return [["cart_pendulum", "CVA", {"h": 1e-2, "T": 5.0, "beta": 3.2}],
            ["cart_pendulum", "CVA", {"h": 2e-2, "T": 3.0, "beta": 2.5, "params": {"m2": 0.3, "L": 1.5}}],
            [str(yaml_file), "CVA", {"h": 2e-2, "T": 2.0}],                          # the YAML's default state
            [str(yaml_file), "CVA", {"h": 2e-2, "T": 2.0, "q0": [0.5, 0.1], "p0": [0.2, -0.4]}]]


def test_warm_start_is_sympy_free_and_bit_identical_to_the_cold_path(yaml_file):
    cases = _cases(yaml_file)
    cold = child([c + [True, False] for c in cases])              # by name, index entry deleted first
    warm = child([c + [False, False] for c in cases])             # by name, from the index
    inst = child([c[:2] + [c[2], False, True] for c in cases[:2]])  # MechanicalSystem instances: symbolic path
    why = {k: warm[k] for k in ("first_sympy", "cache_dir", "tier")} | {
        "indexed_before": [r["indexed_before"] for r in warm["runs"]], "log": warm["log"]}
    assert warm["sympy"] is False and warm["scipy_integrate"] is False, why
    assert warm["vcirun.mechanics"] is False and warm["derive"] is False
    assert cold["sympy"] is True  # the cold path did build the symbolic systems
    # two modules (cart-pendulum, YAML system), both from the disk cache through the index
    assert len(warm["log"]) == 2 and all(e["cached"] and e["warm_index"] for e in warm["log"]), warm["log"]
    assert cold["log"] and not any(e["warm_index"] for e in cold["log"]), cold["log"]
    for c, w, case in zip(cold["runs"], warm["runs"], cases):
        assert c["status"] == w["status"] == "ok"
        assert (c["system"], c["options"]) == (w["system"], w["options"])
        assert c["fields"] == w["fields"], f"warm and cold trajectories differ: {case}"
    for c, i in zip(cold["runs"], inst["runs"]):
        assert c["fields"] == i["fields"]
    assert warm["runs"][2]["system"] == "warm_cart_yaml"
    assert warm["runs"][1]["options"]["params"] == {"m1": 1.0, "m2": 0.3, "L": 1.5, "g": 10.0}


def test_changed_yaml_parameters_are_a_new_index_entry_with_new_numbers(yaml_file):
    case = [str(yaml_file), "CVA", {"h": 2e-2, "T": 2.0}]
    first = child([case + [False, False], case + [False, False]])  # second run: in-process memo
    yaml_file.write_text(YAML.replace("m2: 0.2", "m2: 0.25"))
    changed = child([case + [False, False]])
    again = child([case + [False, False]])
    assert again["sympy"] is False and again["runs"][0]["log"][0]["warm_index"]
    assert changed["runs"][0]["fields"] == again["runs"][0]["fields"]
    assert changed["runs"][0]["fields"]["q"] != first["runs"][0]["fields"]["q"]  # not the stale entry's numbers
    assert changed["runs"][0]["options"]["params"]["m2"] == 0.25
    # parameters are runtime inputs: same module; an expression change is a different module
    from vcirun.mechanics import load_system_yaml

    import yaml

    ks = METHODS["CVA"].kernel_set()
    data = yaml.safe_load(YAML)
    k1 = build.module_key(load_system_yaml(yaml_file), ks)
    assert k1 == build.module_key(load_system_yaml(data), ks)
    assert k1 != build.module_key(load_system_yaml(data | {"constraint": "y + 0.1"}), ks)


def test_no_index_entry_where_the_files_changed_since_the_module_key(tmp_path, monkeypatch):
    """A process whose package files are edited (or upgraded) while it compiles does not index its
    module under the new files' key: the next process, on the new files, would load the old module."""
    import shutil

    from vcirun.codegen import modules as build   # (where the keys are computed: the names to patch)
    from vcirun.scenes.registry import get_scene

    pkg = tmp_path / "vcirun"
    shutil.copytree(build._PKG, pkg, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(build, "_PKG", pkg)
    monkeypatch.setenv("VCIRUN_CACHE_DIR", str(tmp_path / "cache"))
    kc = KernelCache()
    sysm, ks, ident = get_scene("cart_pendulum"), METHODS["CVA"].kernel_set(), ("scene", "cart_pendulum")
    key = kc.module_key(sysm, ks)
    f = pkg / "collision" / "impact.py"
    f.write_text(f.read_text() + "\n# edited\n")
    kc.warm_record(ident, ks, key, {"name": sysm.name}, system=sysm)
    assert not kc.index_path(ident, ks).exists()
    new = build.module_key_of(sysm, ks, kc.backend_id())
    assert new != key
    kc.warm_record(ident, ks, new, {"name": sysm.name}, system=sysm)
    assert kc.index_path(ident, ks).exists()


def test_warm_key_follows_the_hashed_files(tmp_path, monkeypatch):
    """The index key changes with every file the module key hashes and with the system-defining files."""
    import shutil

    from vcirun.codegen import modules as build   # (where the keys are computed: the names to patch)

    pkg = tmp_path / "vcirun"
    shutil.copytree(build._PKG, pkg, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(build, "_PKG", pkg)
    ks = METHODS["CVA"].kernel_set()
    ident = ("scene", "cart_pendulum")
    k0 = build.warm_key_of(ident, ks)
    assert k0 == build.warm_key_of(ident, ks)
    assert build.warm_key_of(("scene", "double_pendulum"), ks) != k0
    assert build.warm_key_of(ident, METHODS["VCI"].kernel_set()) != k0
    for rel in ["scenes/scene.py", "scenes/registry.py", "scenes/paper.py", "scenes/friction.py", "core/system_data.py",
                "mechanics/loader.py",
                "collision/reset_cva.py",
                "codegen/derive.py", "mechanics/system.py"]:
        f = pkg / rel
        text = f.read_text()
        f.write_text(text + "\n# edited\n")
        assert build.warm_key_of(ident, ks) != k0, rel
        f.write_text(text)
        assert build.warm_key_of(ident, ks) == k0
    # sympy (its srepr makes the fingerprint) and PyYAML versions
    stamp = build._dependency_stamp()
    assert b"no sympy" not in stamp and b"no yaml" not in stamp
    monkeypatch.setattr(build, "_dependency_stamp", lambda: stamp + b"|other sympy")
    assert build.warm_key_of(ident, ks) != k0
    monkeypatch.setattr(build, "_dependency_stamp", lambda: stamp)
    # the kernel module of the MCVA family also hashes vcirun/modified: so does its index key
    mk = METHODS["MCVAC"].kernel_set()
    m0 = build.warm_key_of(ident, mk)
    (pkg / "modified" / "series.py").write_text((pkg / "modified" / "series.py").read_text() + "\n#\n")
    assert build.warm_key_of(ident, mk) != m0 and build.warm_key_of(ident, ks) == k0


def test_corrupt_or_stale_index_entries_fall_back_to_the_symbolic_path():
    ks = METHODS["CVA"].kernel_set()
    ident = ("scene", "cart_pendulum")
    kc = KernelCache()   # a new process: nothing read from the index yet
    d, load, sysm = resolve.resolve_numeric("cart_pendulum", ks, kc)
    load()
    path = kc.index_path(ident, ks)
    assert path.is_file()
    assert resolve.resolve_numeric("cart_pendulum", ks, kc)[2] is None  # indexed: no symbolic system
    ref = vcirun.simulate("cart_pendulum", "CVA", h=2e-2, T=2.0, beta=3.2)
    good = path.read_text()
    entry = json.loads(good)
    bad_entries = ["", "{not json", "[]", json.dumps(entry | {"module": "0" * 20}),   # module file missing
                   json.dumps(entry | {"module": "../../etc/passwd"}), json.dumps(entry | {"format": -1}),
                   json.dumps(entry | {"n": 3}), json.dumps(entry | {"params": [["m1", 1.0]]}),
                   json.dumps({k: v for k, v in entry.items() if k != "module"})]
    for bad in bad_entries:
        path.write_text(bad)
        kc = KernelCache()  # a new process: the memo of index hits is empty
        d, load, sysm = resolve.resolve_numeric("cart_pendulum", ks, kc)
        assert sysm is not None, bad  # the symbolic path
        tr = vcirun.simulate("cart_pendulum", "CVA", h=2e-2, T=2.0, beta=3.2, loader=kc)
        assert np.array_equal(tr.q, ref.q) and np.array_equal(tr.p, ref.p)
        assert json.loads(path.read_text())["module"] == entry["module"]  # rewritten by the fallback
    path.unlink()
    tr = vcirun.simulate("cart_pendulum", "CVA", h=2e-2, T=2.0, beta=3.2, loader=KernelCache())
    assert np.array_equal(tr.q, ref.q) and path.is_file()


def test_yaml_index_entry_fields(yaml_file):
    ks = METHODS["CVA"].kernel_set()
    ident, raw = resolve._warm_ident(str(yaml_file))
    assert ident[0] == "yaml" and raw == yaml_file.read_bytes()
    default().index_path(ident, ks).unlink(missing_ok=True)
    d, load, sysm = resolve.resolve_numeric(str(yaml_file), ks)
    assert sysm is not None
    load()
    d2, _, sysm2 = resolve.resolve_numeric(str(yaml_file), ks)
    assert sysm2 is None
    assert (d2.name, d2.n, d2.params, d2.description, d2.ic_map) == (d.name, d.n, d.params, d.description, None)
    assert np.array_equal(d2.default_q0, d.default_q0) and np.array_equal(d2.default_p0, d.default_p0)
    assert d2.default_p0.tobytes() == sysm.default_p0.tobytes()


def test_a_substitute_loader_disables_the_warm_index():
    """A loader passed to simulate (e.g. to run modules uncompiled) is used, whatever the index holds."""
    calls = []

    def fake(system, ks):
        calls.append(system.name)
        return build.load_module(system, ks)

    ks = METHODS["CVA"].kernel_set()
    resolve.resolve_numeric("cart_pendulum", ks)[1]()  # indexed
    a = vcirun.simulate("cart_pendulum", "CVA", h=2e-2, T=1.0, beta=3.2, loader=fake)
    assert calls == ["cart_pendulum"]
    b = vcirun.simulate("cart_pendulum", "CVA", h=2e-2, T=1.0, beta=3.2, loader=fake)
    assert calls == ["cart_pendulum"] * 2   # a function: no plan kept between calls
    assert np.array_equal(a.q, b.q)
    with pytest.raises(ValueError, match="loader: expected a KernelCache or a function"):
        vcirun.simulate("cart_pendulum", "CVA", h=2e-2, T=1.0, beta=3.2, loader="compiled")


def test_import_vcirun_is_light_and_names_resolve():
    code = ("import sys, vcirun; light = 'vcirun.run.api' not in sys.modules and 'numpy' not in sys.modules; "
            "from vcirun.reference_solution.exact import l2_error as _l2; "  # the package has a name of its own...
            "import vcirun.run.api, vcirun.run.trajectory, vcirun.reference_solution as R; "
            "from vcirun import simulate, reference, l2_error, Trajectory; "
            "ok = (simulate is vcirun.run.api.simulate and reference is vcirun.reference is R.reference "
            "and callable(reference) and l2_error is R.l2_error is _l2 and Trajectory is vcirun.run.trajectory.Trajectory "
            "and 'vcirun.reference' not in sys.modules and type(vcirun) is type(sys)); "  # ...no module class of its own
            "print(light, ok, sorted(vcirun.__all__), 'scipy.integrate' in sys.modules, 'sympy' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split(maxsplit=2)[:2] == ["True", "True"], r.stdout
    assert "['Trajectory', '__version__', 'ensemble', 'l2_error', 'open_results', 'periodic_orbit', 'reference', 'simulate'] False False" in r.stdout
    with pytest.raises(AttributeError):
        vcirun.no_such_name  # noqa: B018
    assert isinstance(vcirun.__version__, str) and "simulate" in dir(vcirun)


def test_methods_and_lagrangians_import_without_sympy():
    code = "import sys, vcirun.methods.table, vcirun.discrete.lagrangians; print('sympy' in sys.modules)"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.strip() == "False", r.stderr
