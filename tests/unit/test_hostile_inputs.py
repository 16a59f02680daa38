"""Hostile input: every case is refused before work starts with one line naming the field,
or (non-finite energies) ends with a failure status, never `ok`. YAML alias bombs, sizes, grid and
memory bounds, booleans where numbers belong, identifiers that collide after NFKC, and the Python API's
argument checks (same messages as the config layer)."""
from __future__ import annotations

import math
import time
import tracemalloc

import numpy as np
import pytest
import yaml

import vcirun
from vcirun.core import names, sizes, values, yaml_loader
from vcirun.experiments.config import ConfigError, load_config
from vcirun.mechanics import load_system_yaml

SYSTEM = """\
name: spring
coordinates: [x]
parameters: {k: 4.0}
mass_matrix: [["1"]]
potential: "0.5*k*x**2"
constraint: "x + 0.5"
q0: [0.2]
p0: [1.0]
"""

CONFIG = """\
name: c
system: cart_pendulum
methods: [CVA]
h: [1.0e-2]
beta: [3.2]
T: 0.5
reference: {kind: none}
"""


def bomb(levels: int) -> str:
    lines = ["  a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    lines += [f"  a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]" for i in range(1, levels)]
    return "x-anchors:\n" + "\n".join(lines) + "\n"


def one_line_config_error(tmp_path, text, *words, name="c.yaml"):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as ei:
        load_config(p)
    msg = str(ei.value)
    assert "\n" not in msg and msg.startswith(str(p)), msg
    for w in words:
        assert w in msg, msg
    return msg


# --- YAML ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("where", ["T", "description"])
def test_alias_bomb_is_refused_in_milliseconds(tmp_path, where):
    text = bomb(9) + (CONFIG.replace("T: 0.5", "T: *a8") if where == "T" else CONFIG + "description: *a8\n")
    t0 = time.perf_counter()
    one_line_config_error(tmp_path, text, "alias bomb")
    assert time.perf_counter() - t0 < 5.0  # 9**9 = 387 million values: never expanded


def test_alias_bomb_in_a_system_file(tmp_path):
    (tmp_path / "s.yaml").write_text(bomb(8) + SYSTEM + "description: *a7\n")
    one_line_config_error(tmp_path, CONFIG.replace("system: cart_pendulum", "system: s.yaml"), "s.yaml", "alias bomb")
    with pytest.raises(ValueError, match="alias bomb"):
        load_system_yaml(tmp_path / "s.yaml")


def test_yaml_limits_and_rules():
    with pytest.raises(yaml.YAMLError, match="recursive alias"):
        yaml_loader.yaml_load("a: &r [*r]\n")
    with pytest.raises(yaml.YAMLError, match="duplicate key 'a'"):
        yaml_loader.yaml_load("a: 1\na: 2\n")
    with pytest.raises(yaml.YAMLError, match="characters long"):
        yaml_loader.yaml_load("x: '" + "y" * (yaml_loader.MAX_YAML_CHARS + 1) + "'\n")
    # shared aliases within the caps are fine; YAML 1.2 numbers
    assert yaml_loader.yaml_load("a: &a [1e-3, 2]\nb: [*a, *a]\n") == {"a": [1e-3, 2], "b": [[1e-3, 2], [1e-3, 2]]}


def test_deeply_nested_yaml_is_refused_before_pyyaml_recurses():
    t0 = time.perf_counter()
    with pytest.raises(yaml.YAMLError, match="more than 100 levels deep"):
        yaml_loader.yaml_load("x: " + "[" * 5000 + "]" * 5000 + "\n")
    assert time.perf_counter() - t0 < 2.0
    # brackets inside quotes or comments are text
    assert yaml_loader.yaml_load("a: '" + "[" * 300 + "'\n# " + "{" * 300 + "\n") == {"a": "[" * 300}


def test_system_files_are_parsed_like_configs(tmp_path):
    p = tmp_path / "s.yaml"
    p.write_text(SYSTEM.replace("{k: 4.0}", "{k: 1e-3}"))
    assert load_system_yaml(p).params == {"k": 1e-3}  # a float (YAML 1.1 would give the string '1e-3')
    p.write_text(SYSTEM.replace("{k: 4.0}", "{k: 4.0, k: 400.0}"))
    with pytest.raises(ValueError, match=r"line 3.*duplicate key 'k'"):
        load_system_yaml(p)
    p.write_text(SYSTEM.replace('potential: "0.5*k*x**2"', "potential: true"))
    with pytest.raises(ValueError, match="system.potential: boolean true"):
        load_system_yaml(p)
    p.write_text(SYSTEM.replace('potential: "0.5*k*x**2"', "potential: [[1, 2], [3, 4]]"))
    with pytest.raises(ValueError, match="system.potential: must be an expression string or a number"):
        load_system_yaml(p)


def test_special_config_files(tmp_path):
    fifo = tmp_path / "fifo.yaml"
    os_mkfifo = getattr(__import__("os"), "mkfifo", None)
    if os_mkfifo is not None:
        os_mkfifo(fifo)
        with pytest.raises(ConfigError, match="not a regular file"):
            load_config(fifo)  # never blocks on the pipe
    big = tmp_path / "big.yaml"
    big.write_text(CONFIG + "description: '" + "x" * 4_100_000 + "'\n")
    with pytest.raises(ConfigError, match="a config is a few kB"):
        load_config(big)


def test_a_system_file_that_is_not_a_file_says_what_it_is(tmp_path):
    """A FIFO, a directory or a dangling link named as the system file was reported as 'not found'."""
    import os

    cfg = CONFIG.replace("system: cart_pendulum", "system: sys.yaml")
    (tmp_path / "sys.yaml").mkdir()
    one_line_config_error(tmp_path, cfg, "system: system file ", "sys.yaml is a directory")
    (tmp_path / "sys.yaml").rmdir()
    (tmp_path / "sys.yaml").symlink_to(tmp_path / "nowhere.yaml")
    one_line_config_error(tmp_path, cfg, "sys.yaml is a symbolic link loop or points nowhere")
    (tmp_path / "sys.yaml").unlink()
    if hasattr(os, "mkfifo"):
        os.mkfifo(tmp_path / "sys.yaml")
        one_line_config_error(tmp_path, cfg, "sys.yaml is not a regular file")  # never blocks
        (tmp_path / "sys.yaml").unlink()
    one_line_config_error(tmp_path, cfg, "system file not found: ", "sys.yaml")


# --- grid, memory, sizes ------------------------------------------------------------------------------------
@pytest.mark.parametrize("h,T,words", [
    ("1.0e-320", "5", ["h[0]", "must be >= 1e-50"]),
    ("1.0e-300", "5", ["h[0]", "must be >= 1e-50"]),
    ("1.0e-6", "1.0e9", ["h[0]", "T / h = 1e+15 steps is too many"]),
    ("1.0e-6", "1.0e4", ["h[0]", "1e+10 steps of 2 coordinates need about", "GiB"]),
])
def test_grid_and_memory_bounds(tmp_path, h, T, words):
    one_line_config_error(tmp_path, CONFIG.replace("h: [1.0e-2]", f"h: [{h}]").replace("T: 0.5", f"T: {T}"), *words)


def test_a_method_reference_is_a_run_whose_memory_is_checked_by_validate(tmp_path):
    """reference: {kind: method, h: 1e-12}: `validate` said ok and the sweep stopped at its preflight with
    `reference: T: 1e+10 steps ...` (the field named wrongly)."""
    text = CONFIG.replace("reference: {kind: none}", "reference: {kind: method, method: CVA, h: 1.0e-12}")
    one_line_config_error(tmp_path, text, "reference.h: ", "steps of 2 coordinates need about", "raise reference.h")
    ok = CONFIG.replace("reference: {kind: none}", "reference: {kind: method, method: CVA, h: 1.0e-4}")
    (tmp_path / "ok.yaml").write_text(ok)
    load_config(tmp_path / "ok.yaml")


def test_max_memory_is_configurable_and_not_part_of_the_results(tmp_path):
    text = CONFIG.replace("h: [1.0e-2]", "h: [1.0e-5]").replace("T: 0.5", "T: 100")  # 1e7 steps, ~0.9 GiB
    one_line_config_error(tmp_path, text + "max_memory: 100MB\n", "h[0]", "limit 95.4 MiB", "max_memory")
    p = tmp_path / "ok.yaml"
    p.write_text(text + "max_memory: 4GB\n")
    cfg = load_config(p)
    assert "max_memory" not in cfg.canonical()  # resuming with another limit keeps the file
    one_line_config_error(tmp_path, CONFIG + "max_memory: lots\n", "max_memory: must be a positive size")


def test_run_bytes_estimates_what_simulate_allocates():
    """The memory estimate against the allocations numpy reports to tracemalloc for a real run."""
    N = 20_000
    vcirun.simulate("cart_pendulum", "CVA", h=1e-3, T=1e-3, beta=3.2)  # kernels loaded outside the trace
    tracemalloc.start()
    tr = vcirun.simulate("cart_pendulum", "CVA", h=1e-3, T=N * 1e-3, beta=3.2, energies=False)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert tr.n_steps == N
    est = sizes.run_bytes(N, 2)
    assert 0.8 * peak <= est <= 3 * peak, (est, peak)


def test_sizes_are_capped(tmp_path):
    s = tmp_path / "s.yaml"
    s.write_text(SYSTEM.replace("coordinates: [x]", "coordinates: [" + ", ".join(f"x{i}" for i in range(100)) + "]"))
    with pytest.raises(ValueError, match="system.coordinates: 100 coordinates; the limit is 32"):
        load_system_yaml(s)
    one_line_config_error(tmp_path, CONFIG.replace("system: cart_pendulum", "system: n_pendulum_100000")
                          .replace("beta: [3.2]\n", ""), "system: n_pendulum_100000 has 100,000 coordinates",
                          "n_pendulum_K takes K from 1 to 32")
    with pytest.raises(ValueError, match="system: n_pendulum_100000 has 100,000 coordinates"):
        vcirun.simulate("n_pendulum_100000", "CVA", h=0.01, T=0.1)
    with pytest.raises(ValueError, match="system: newton_cradle_5000 has 5,000 coordinates and 4,999 contacts"):
        vcirun.reference("newton_cradle_5000", T=0.1)
    chunk = "(" + "-".join(["-x"] * 80) + ")"  # 7199 nodes in 7259 characters (under the length cap)
    s.write_text(SYSTEM.replace('"0.5*k*x**2"', '"' + "*".join([chunk] * 30) + '"'))
    with pytest.raises(ValueError, match="system.potential: .*has 7199 numbers, names and operations; the limit is 5000"):
        load_system_yaml(s)
    one_line_config_error(tmp_path, CONFIG.replace("h: [1.0e-2]", "h: [" + ", ".join(
        f"{1e-3 * (1 + i * 1e-5):.10g}" for i in range(10_001)) + "]"), "h:", "at most 10000")


# --- booleans where numbers belong ------------------------------------------------------------------------------
@pytest.mark.parametrize("old,new,field", [
    ("T: 0.5", "T: true", "T: must be a number, not true/false"),
    ("system: cart_pendulum", "system: {name: cart_pendulum, params: {m1: true}}", "system.params.m1: must be a number"),
    ("h: [1.0e-2]", "h: [true]", "h[0]: must be a number"),
])
def test_true_is_not_a_number(tmp_path, old, new, field):
    one_line_config_error(tmp_path, CONFIG.replace(old, new), field)


def inline(potential='"0.5*k*x**2"', params="{k: 4.0}", coords="[x]") -> str:
    return CONFIG.replace("system: cart_pendulum\n", f"""system:
  coordinates: {coords}
  parameters: {params}
  mass_matrix: [["1"]]
  potential: {potential}
  constraint: "x + 0.5"
  q0: [0.2]
  p0: [1.0]
""").replace("beta: [3.2]\n", "")


def test_inline_potential_true_is_refused(tmp_path):
    one_line_config_error(tmp_path, inline(potential="true"), "system.potential: must be an expression or a number")


# --- identifiers (NFKC) --------------------------------------------------------------------------------------
@pytest.mark.parametrize("params,potential,coords,words", [
    ("{k: 4.0, ｋ: 400.0}", '"0.5*k*x**2"', "[x]", ["system.parameters.ｋ", "collides with system.parameters.k",
                                                    "NFKC"]),
    ("{k: 4.0}", '"0.5*ｋ*x**2"', "[x]", ["system.potential: non-ASCII character 'ｋ'", "write 'k'"]),
    ("{k: 4.0}", '"0.5*𝑘*x**2"', "[x]", ["system.potential: non-ASCII character", "MATHEMATICAL ITALIC SMALL K"]),
    ("{k: 4.0}", '"0.5*k*ｘ**2"', "[ｘ]", ["system.coordinates[0]", "'ｘ' is not ASCII", "write 'x'"]),
    ("{κ: 4.0}", '"0.5*x**2"', "[x]", ["system.parameters.κ", "GREEK SMALL LETTER KAPPA"]),
    ("{x_dot: 4.0}", '"0.5*x**2"', "[x]", ["x_dot", "collides"]),
    ("{lambda: 4.0}", '"0.5*x**2"', "[x]", ["'lambda' is a Python keyword"]),
])
def test_identifiers_must_be_ascii_and_distinct_after_nfkc(tmp_path, params, potential, coords, words):
    one_line_config_error(tmp_path, inline(potential=potential, params=params, coords=coords), *words)


def test_full_width_parameter_in_a_system_file_and_a_python_system(tmp_path):
    s = tmp_path / "s.yaml"
    s.write_text(SYSTEM.replace("{k: 4.0}", "{k: 4.0, ｋ: 400.0}"), encoding="utf-8")
    with pytest.raises(ValueError, match="collides with system.parameters.k"):
        load_system_yaml(s)
    s.write_text(SYSTEM.replace("name: spring", "name: ｓpring"), encoding="utf-8")
    with pytest.raises(ValueError, match="system.name: 'ｓpring' is not ASCII"):
        load_system_yaml(s)
    import sympy as sp

    from vcirun.mechanics.system import MechanicalSystem

    x, k = sp.Symbol("x"), sp.Symbol("ｋ")
    m = MechanicalSystem(name="u", q=[x], params={"ｋ": 4.0}, M=sp.Matrix([[1]]), V=k * x**2 / 2, phi=x + 1,
                         default_q0=np.array([0.2]), default_p0=np.array([0.0]))
    with pytest.raises(ValueError, match="system.parameters.ｋ: 'ｋ' is not ASCII"):
        vcirun.simulate(m, "CVA", h=0.01, T=0.1)



@pytest.mark.parametrize("params,potential,coords,field", [
    ("{k: 4.0, vcTQ0: 400.0}", '"0.5*vcTQ0*x**2"', "[x]", "system.parameters.vcTQ0"),  # read as x by the kernels
    ("{hh: 4.0}", '"0.5*hh*x**2"', "[x]", "system.parameters.hh"),
    ("{k: 4.0, mh_p0: 1.0}", '"0.5*k*mh_p0*x**2"', "[x]", "system.parameters.mh_p0"),
    ("{k: 4.0}", '"0.5*k*qa0**2"', "[qa0]", "system.coordinates[0]"),
    ("{k: 4.0}", '"0.5*k*cse2**2"', "[cse2]", "system.coordinates[0]"),
])
def test_names_of_the_generated_code_are_reserved(tmp_path, params, potential, coords, field):
    """A parameter named vcTQ0 (the tensor kernels' placeholder of coordinate 0) ran with status ok and
    q(T) 0.682 instead of 0.529: the kernels read the coordinate for it. Such names are refused."""
    text = inline(potential=potential, params=params, coords=coords).replace('"x + 0.5"', f'"{coords[1:-1]} + 0.5"')
    one_line_config_error(tmp_path, text, f"{field}: ", "is reserved", "choose another name")


def test_reserved_names_in_a_python_system_and_names_that_are_not_reserved():
    import sympy as sp

    from vcirun.mechanics.system import MechanicalSystem

    x, k = sp.Symbol("x"), sp.Symbol("vcTQ0")
    m = MechanicalSystem(name="u", q=[x], params={"vcTQ0": 4.0}, M=sp.Matrix([[1]]), V=k * x**2 / 2, phi=x + 1,
                         default_q0=np.array([0.2]), default_p0=np.array([0.0]))
    with pytest.raises(ValueError, match="system.parameters.vcTQ0: 'vcTQ0' is reserved"):
        vcirun.simulate(m, "CVA", h=0.01, T=0.1)
    for name in ("th", "qa", "hhh", "t1", "cse", "theta1", "m1", "x1", "vc", "mh"):
        assert names.reserved_name_problem(name) is None, name
    for name in ("hh", "tt", "qa12", "va0", "qb3", "cse0", "xm1", "vcTT", "vcTC7", "mh_u0"):
        assert "is reserved" in names.reserved_name_problem(name), name
# --- the Python API ----------------------------------------------------------------------------------------------
BASE = dict(h=0.01, T=1.0, beta=3.2)


@pytest.mark.parametrize("kw,message", [
    ({"max_iter": 0}, "max_iter: must be >= 1 (got 0)"),
    ({"max_iter": -1}, "max_iter: must be >= 1 (got -1)"),
    ({"max_iter": 2.5}, "max_iter: must be an integer (got 2.5)"),
    ({"t0": math.nan}, "t0: must be a finite number (got nan)"),
    ({"t0": math.inf}, "t0: must be a finite number (got inf)"),
    ({"newton_tol": 0}, "newton_tol: must be > 0 (got 0)"),
    ({"newton_tol": math.nan}, "newton_tol: must be a finite number (got nan)"),
    ({"newton_tol": -1}, "newton_tol: must be > 0 (got -1)"),
    ({"event_tol": 0}, "event_tol: must be > 0 (got 0)"),
    ({"max_impacts_step": 0}, "max_impacts_step: must be >= 1 (got 0)"),
    ({"constrained": "no"}, "constrained: must be true or false (got 'no')"),
    ({"h": "fast"}, "h: must be a finite number (got 'fast')"),   # (h=None: the default step, docs/guide.md)
    ({"h": 1j}, "h: must be a finite number (got 1j)"),
    ({"h": np.array([0.01, 0.02])}, "h: must be a finite number (got array("),
    ({"h": 1e-320}, "h: must be >= 1e-50"),
    ({"T": 1e9, "h": 1e-6}, "h: T / h = 1e+15 steps is too many"),
    ({"T": 1e4, "h": 1e-6}, "T: 1e+10 steps of 2 coordinates need about"),
    ({"beta": math.inf}, "beta: must be a finite number (got inf)"),
    ({"params": {"m1": math.nan}}, "params.m1: must be a finite number (got nan)"),
    ({"beta": None, "q0": [math.nan, 0.0], "p0": [0.0, 0.0]}, "q0: must be a list of finite numbers"),
    # 'no' is truthy: resting contacts were held (status ok) where the caller asked for them not to be
    ({"resting_contact": "no"}, "resting_contact: must be true or false (got 'no')"),
    # both: q0/p0 won and beta was silently ignored
    ({"q0": [0.1, 0.2], "p0": [0.0, 0.0]}, "beta: give either beta or q0 and p0, not both"),
])
def test_simulate_validates_like_the_config_layer(kw, message):
    with pytest.raises(ValueError) as ei:
        vcirun.simulate("cart_pendulum", "CVA", **{**BASE, **kw})
    assert message in str(ei.value) and "\n" not in str(ei.value)


def test_same_message_as_the_config_layer(tmp_path):
    with pytest.raises(ValueError) as api:
        vcirun.simulate("cart_pendulum", "CVA", **{**BASE, "max_iter": 0})
    cfg = one_line_config_error(tmp_path, CONFIG + "tolerances: {max_iter: 0}\n")
    assert cfg.endswith("tolerances." + str(api.value))


@pytest.mark.parametrize("kw,message", [
    ({"T": 0}, "T: must be > 0 (got 0)"),
    ({"T": math.inf}, "T: must be a finite number (got inf)"),
    ({"rtol": 0}, "rtol: must be >= 2.3e-14 (got 0)"),
    ({"rtol": math.nan}, "rtol: must be a finite number (got nan)"),
    ({"method": "CVA", "h": 0}, "h: must be > 0 (got 0)"),
    ({"resting_contact": "no"}, "resting_contact: must be true or false (got 'no')"),
    ({"check_accuracy": "no"}, "check_accuracy: must be true or false (got 'no')"),
    ({"q0": [0.1, 0.2], "p0": [0.0, 0.0]}, "beta: give either beta or q0 and p0, not both"),
])
def test_reference_validates_before_solving(kw, message):
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)").replace("+", r"\+")):
        vcirun.reference("cart_pendulum", **{"T": 1.0, "beta": 3.2, **kw})
    assert time.perf_counter() - t0 < 5.0  # rtol=0 is refused, not left to hang inside solve_ivp


@pytest.mark.parametrize("kw", [{"T": 1.0, "beta": 1e20}, {"T": 1e6, "beta": 3.2}])
def test_an_exact_reference_beyond_its_budget_is_refused(monkeypatch, kw):
    """beta = 1e20 (velocities ~1e19) collapses the steps (the Taylor coefficients overflow; DOP853's
    steps shrink), so the solve would run for hours. The work (Taylor steps, DOP853's right-hand-side
    evaluations) is projected to T and refused above its bound (checked here from 2,000 units instead
    of 20,000 and 200,000, to keep the test short)."""
    import importlib

    ref_mod = importlib.import_module("vcirun.reference_solution.exact")
    monkeypatch.setattr(ref_mod, "MIN_RHS_EVALS_FOR_PROJECTION", 2_000)
    monkeypatch.setattr(ref_mod, "MIN_TAYLOR_STEPS_FOR_PROJECTION", 2_000)
    with pytest.raises(ValueError, match=r"^T: the exact reference would need about .* (right-hand-side evaluations|Taylor "
                                         r"steps)"):
        vcirun.reference("cart_pendulum", rtol=1e-10, check_accuracy=False, **kw)
    vcirun.reference("cart_pendulum", T=0.5, beta=3.2, rtol=1e-10)  # a normal solve stays under it


@pytest.mark.parametrize("system,kw", [("oscillator_wall", {"q0": [1e300], "p0": [0.0]}),
                                       ("oscillator_wall", {"q0": [0.1], "p0": [1e200]})])
def test_non_finite_initial_energy_is_a_failure_with_a_cause(system, kw):
    tr = vcirun.simulate(system, "CVA", h=0.01, T=0.1, **kw)
    assert tr.status == "nonfinite" and tr.fail_step == 0
    assert "non-finite initial energy" in tr.message and "H(0) = inf" in tr.message


def test_a_normal_run_is_untouched():
    tr = vcirun.simulate("oscillator_wall", "CVA", h=0.01, T=0.1)
    assert tr.status == "ok" and np.all(np.isfinite(tr.H))


def test_validation_helpers():
    assert sizes.parse_bytes("16GB") == 16_000_000_000 and sizes.parse_bytes("512MiB") == 512 * 2**20
    with pytest.raises(ValueError):
        sizes.parse_bytes("-1")
    assert names.ascii_name_problem("k") is None
    assert "reads as 'k'" in names.ascii_name_problem("ｋ")
    assert values.describe(list(range(10**6))).startswith("[0, 1, 2, 3, ...")  # bounded repr
