"""Sweep config validation: every bad config gives one line naming the file and the field; good
configs expand into a stable run grid."""
from __future__ import annotations

from pathlib import Path

import pytest

from vcirun.core.yaml_loader import yaml_load
from vcirun.experiments.config import COLLISION_METHODS, DISCRETE_LAGRANGIANS, ConfigError, load_config, parse_config
from vcirun.experiments.sweep import expand, run_id_for, run_identity
from vcirun.experiments.worker import make_tasks

ROOT = Path(__file__).resolve().parents[2]

GOOD = """\
name: t
system: cart_pendulum
methods: [CVA, VCI]
h: [3.2e-2, 1e-2]
beta: {start: 3.2, stop: 4.2, num: 3}
T: 0.5
"""

INLINE = """\
name: t
system:
  coordinates: [x]
  parameters: {m: 1.0, k: 4.0}
  mass_matrix: [["m"]]
  potential: "0.5*k*x**2"
  constraint: "x + 1"
  q0: [0.5]
  p0: [0.0]
methods: [CVA]
h: [0.01]
T: 0.5
"""


def edit(base: str, **changes) -> str:
    """`base` with top-level keys replaced (value None deletes the key); values are YAML text."""
    lines = base.splitlines()
    out, skip = [], False
    for line in lines:
        key = line.split(":", 1)[0] if line and not line.startswith(" ") else None
        if key is not None:
            skip = key in changes
            if skip and changes[key] is not None:
                out.append(f"{key}: {changes[key]}")
        if not skip:
            out.append(line)
    for key, value in changes.items():
        if value is not None and not any(l.startswith(f"{key}:") for l in lines):
            out.append(f"{key}: {value}")
    return "\n".join(out) + "\n"


# (id, config text, field named in the message, words the message must contain)
BAD = [
    ("unknown-method", edit(GOOD, methods="[CVA, FOO]"), "methods[1].name", "must be one of"),
    ("h-negative", edit(GOOD, h="[0.01, -0.01]"), "h[1]", "must be > 0 (got -0.01)"),
    ("h-zero", edit(GOOD, h="[0]"), "h[0]", "must be > 0"),
    ("h-above-T", edit(GOOD, h="[1.0]"), "h[0]", "must be <= T"),
    ("h-duplicate", edit(GOOD, h="[0.01, 1.0e-2]"), "h[1]", "duplicate"),
    ("beta-start-after-stop", edit(GOOD, beta="{start: 5.2, stop: 3.2, num: 3}"), "beta", "must be <= stop"),
    ("beta-num-zero", edit(GOOD, beta="{start: 3.2, stop: 5.2, num: 0}"), "beta.num", "must be >= 1"),
    ("beta-num-one-span", edit(GOOD, beta="{start: 3.2, stop: 5.2, num: 1}"), "beta", "num = 1"),
    ("beta-missing-num", edit(GOOD, beta="{start: 3.2, stop: 5.2}"), "beta.num", "required"),
    ("beta-bad-element", edit(GOOD, beta="[3.2, abc]"), "beta[1]", "finite number"),
    ("beta-and-states", edit(GOOD, initial_states="[{q0: [1, 0], p0: [0, 0]}]"), "initial_states", "not both"),
    ("unknown-system", edit(GOOD, system="cart_pendulm"), "system", "did you mean 'cart_pendulum'"),
    ("unknown-system-param", edit(GOOD, system="{name: cart_pendulum, params: {m3: 1.0}}"), "system.params.m3",
     "unknown parameter"),
    ("unknown-top-key", edit(GOOD, metods="[CVA]"), "metods", "did you mean 'methods'"),
    ("unknown-method-key", edit(GOOD, methods="[{name: CVA, lable: x}]"), "methods[0].lable", "did you mean 'label'"),
    ("unknown-option", edit(GOOD, methods="[{name: CVA, options: {constrainted: false}}]"),
     "methods[0].options.constrainted", "did you mean 'constrained'"),
    ("unknown-reference-key", edit(GOOD, reference="{kind: exact, h: 1.0e-4}"), "reference.h", "allowed: kind, rtol"),
    ("reference-kind", edit(GOOD, reference="{kind: exakt}"), "reference", "kind must be exact, method or none"),
    ("reference-method-needs-h", edit(GOOD, reference="{kind: method, method: CVA}"), "reference.h", "required"),
    ("T-zero", edit(GOOD, T="0"), "T", "must be > 0 (got 0)"),
    ("T-negative", edit(GOOD, T="-5"), "T", "must be > 0"),
    ("T-nan", edit(GOOD, T=".nan"), "T", "finite number"),
    ("mh-order-5", edit(GOOD, methods="[{name: MCVA, ld: SVC, mh_order: 5}]"), "methods[0].mh_order", "must be <= 4"),
    ("mh-order-0", edit(GOOD, methods="[{name: MCVA, ld: SVC, mh_order: 0}]"), "methods[0].mh_order", "must be >= 1"),
    ("mh-order-on-MCVAA", edit(GOOD, methods="[{name: MCVAA, mh_order: 3}]"), "methods[0]", "only for the generalized"),
    ("MCVA-without-ld", edit(GOOD, methods="[{name: MCVA, mh_order: 3}]"), "methods[0]", "needs ld"),
    ("flow-order-5", edit(GOOD, methods="[{name: MCVA, ld: SVC, mh_order: 3, flow_order: 5}]"),
     "methods[0].flow_order", "must be one of 4 or 6"),
    ("unknown-ld", edit(GOOD, methods="[{name: MCVA, ld: RK4, mh_order: 3}]"), "methods[0].ld", "must be one of"),
    ("duplicate-method", edit(GOOD, methods="[CVA, VCI, CVA]"), "methods[2]", "duplicate label"),
    ("empty-methods", edit(GOOD, methods="[]"), "methods", "must not be empty"),
    ("methods-not-list", edit(GOOD, methods="CVA"), "methods", "must be a list"),
    ("h-not-list", edit(GOOD, h="0.01"), "h", "must be a list"),
    ("h-not-number", edit(GOOD, h="[fast]"), "h[0]", "finite number"),
    ("T-wrong-type", edit(GOOD, T="five"), "T", "finite number (got 'five')"),
    ("workers-zero", edit(GOOD, workers="0"), "workers", "must be >= 1"),
    ("workers-float", edit(GOOD, workers="1.5"), "workers", "integer"),
    ("store-not-bool", edit(GOOD, store_trajectories="maybe"), "store_trajectories", "true or false"),
    ("bad-name", edit(GOOD, name='"my sweep"'), "name", "letters, digits"),
    ("tolerance-negative", edit(GOOD, tolerances="{newton_tol: -1.0e-12}"), "tolerances.newton_tol", "must be > 0"),
    ("system-not-mapping", edit(GOOD, system="3"), "system", "built-in name"),
    ("missing-T", edit(GOOD, T=None), "T", "required key is missing"),
    ("missing-methods", edit(GOOD, methods=None), "methods", "required key is missing"),
    ("expression-unknown-name", INLINE.replace('"0.5*k*x**2"', '"0.5*k*y**2"'), "system.potential", "unknown name 'y'"),
    ("expression-attribute", INLINE.replace('"x + 1"', '"x.__class__"'), "system.constraint", "not allowed"),
    ("expression-import", INLINE.replace('"0.5*k*x**2"', "\"__import__('os')\""), "system.potential", "not allowed"),
    ("expression-unbalanced", INLINE.replace('"0.5*k*x**2"', '"0.5*(k*x**2"'), "system.potential", "never closed"),
    ("inline-unknown-key", INLINE.replace("  q0: [0.5]", "  q00: [0.5]"), "system.q00", "unknown key"),
    ("inline-mass-shape", INLINE.replace('[["m"]]', '[["m", "0"]]'), "system.mass_matrix[0]", "must be square"),
    ("inline-state-length", INLINE + "initial_states: [{q0: [0.5, 1.0], p0: [0.0, 0.0]}]\n", "initial_states[0]",
     "length 1"),
    ("inline-beta-without-map", INLINE + "beta: [1.0]\n", "beta", "no initial-condition map"),
    ("state-violates-constraint", edit(GOOD, beta=None, initial_states="[{q0: [-0.5, 0.0], p0: [0.0, 0.0]}]"),
     "initial_states[0]", "violates the constraint"),
    ("system-file-missing", edit(GOOD, system="nowhere/system.yaml"), "system", "not found"),
]


def write(tmp_path, text, name="c.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def assert_one_line(err: ConfigError, path, field: str, words: str):
    msg = str(err)
    assert "\n" not in msg, msg
    assert msg.startswith(f"{path}: {field}: "), msg
    assert words in msg, msg
    assert "Traceback" not in msg and "pydantic" not in msg.lower(), msg


@pytest.mark.parametrize("case", BAD, ids=[c[0] for c in BAD])
def test_bad_config_one_line_naming_the_field(tmp_path, case):
    _, text, field, words = case
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as ei:
        load_config(path)
    assert_one_line(ei.value, path, field, words)


def test_at_least_fifteen_distinct_bad_cases():
    assert len({c[2] for c in BAD}) >= 15 and len(BAD) >= 15


@pytest.mark.parametrize("text,words", [
    ("name: t\nh: [0.01\nT: 5\n", "invalid YAML at line 3"),
    ("name: t\nT: 5\nT: 6\n", "duplicate key 'T'"),
    ("- a\n- b\n", "top level must be a mapping"),
    ("", "empty config"),
    ("name: t\n\tT: 5\n", "invalid YAML"),
])
def test_file_level_errors(tmp_path, text, words):
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as ei:
        load_config(path)
    msg = str(ei.value)
    assert "\n" not in msg and msg.startswith(f"{path}: ") and words in msg, msg


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(ConfigError, match=r"nope\.yaml: file not found$"):
        load_config(tmp_path / "nope.yaml")
    with pytest.raises(ConfigError, match="is a directory"):
        load_config(tmp_path)


def test_many_problems_are_all_reported_on_the_one_line(tmp_path):
    path = write(tmp_path, edit(GOOD, T="0", h="[-1]"))
    with pytest.raises(ConfigError) as ei:
        load_config(path)
    msg = str(ei.value)
    assert "\n" not in msg and "(2 problems)" in msg
    assert "h[0]: must be > 0 (got -1)" in msg and "T: must be > 0 (got 0)" in msg


def test_a_typo_is_named_not_reported_as_missing(tmp_path):
    """`methdos:` instead of `methods:`: the typo and the key it probably means, once; and the other
    problems of the file in the same line."""
    path = write(tmp_path, GOOD.replace("methods:", "methdos:").replace("T: 0.5", "T: -1"))
    with pytest.raises(ConfigError) as ei:
        load_config(path)
    msg = str(ei.value)
    assert msg.startswith(f"{path}: methdos: unknown key; did you mean 'methods'?"), msg
    assert "('methods' is required and missing)" in msg and "required key is missing" not in msg
    assert "allowed:" not in msg and len(msg) < len(str(path)) + 130   # the hint, not the whole key list
    assert "T: must be > 0 (got -1)" in msg and "(2 problems)" in msg and "\n" not in msg


def test_good_config_defaults_and_yaml_floats(tmp_path):
    cfg = load_config(write(tmp_path, GOOD))
    assert cfg.h == [0.032, 0.01]  # 1e-2 without a dot is a float here (YAML 1.1 would say string)
    assert cfg.reference.kind == "exact" and cfg.reference.rtol == 1e-13
    assert cfg.store_trajectories is True and cfg.workers is None
    assert str(cfg.output_path()) == "results/t.h5"
    assert [ic.key for ic in cfg.initial_conditions()] == ["beta=3.2", "beta=3.7", "beta=4.2"]
    assert yaml_load("x: [1e3, 1.0e-4, -2E-1, 7]")["x"] == [1000.0, 1e-4, -0.2, 7]


def test_name_defaults_to_the_file_stem(tmp_path):
    cfg = load_config(write(tmp_path, edit(GOOD, name=None), name="my_sweep.yaml"))
    assert cfg.name == "my_sweep"


def test_inline_system_and_generalized_method(tmp_path):
    text = INLINE.replace("methods: [CVA]", "methods: [CVA, {name: MCVA, ld: SVC, mh_order: 3, flow_order: 4}]")
    cfg = load_config(write(tmp_path, text))
    assert cfg.system_label() == "user_system"
    m = cfg.methods[1]
    assert m.display == "MCVA[SVC,s=3,p=4]"
    assert m.simulate_kwargs() == {"ld": "SVC", "mh_order": 3, "flow_order": 4}
    assert [ic.key for ic in cfg.initial_conditions()] == ["default"]


def test_system_file_relative_to_config(tmp_path):
    (tmp_path / "sys").mkdir()
    body = "\n".join(l[2:] for l in INLINE.split("methods:")[0].splitlines()[2:])
    (tmp_path / "sys" / "osc.yaml").write_text("name: osc\n" + body + "\n")
    cfg = load_config(write(tmp_path, edit(INLINE.split("system:")[0] + "system: sys/osc.yaml\nmethods: [CVA]\n"
                                           "h: [0.01]\nT: 0.5\n")))
    assert cfg.system.file == str(tmp_path / "sys" / "osc.yaml")
    assert cfg.system_label() == "osc"


def test_method_names_match_the_core():
    """Every name the config accepts is one `vcirun.simulate` accepts (and MCVA needs options)."""
    from vcirun.methods.table import resolve_method

    for name in COLLISION_METHODS + DISCRETE_LAGRANGIANS:
        if name == "MCVA":
            resolve_method(name, ld="SVC", mh_order=3, flow_order=4)
        else:
            assert resolve_method(name) is not None


# The sweep configs the README and `make reproduce` use (other YAML files in configs/ may feed other
# tools, e.g. the stress study's extremes.yaml).
SWEEP_CONFIGS = {"quick": 40, "fig1": 4, "fig3": 2, "fig4": 408, "table2": 204}


@pytest.mark.parametrize("name", sorted(SWEEP_CONFIGS))
def test_shipped_configs_validate(name):
    cfg = load_config(ROOT / "configs" / f"{name}.yaml")
    assert cfg.name == name and str(cfg.output_path()) == f"results/{name}.h5"
    assert len(expand(cfg)) == SWEEP_CONFIGS[name]


def test_paper_settings_in_the_shipped_configs():
    """Section 5.2: h = 3.2e-2 and 1e-2, 51 betas on [3.2, 5.2], T = 5; Figure 3 at beta 3.2, h 1e-2."""
    fig4 = load_config(ROOT / "configs" / "fig4.yaml")
    assert fig4.h == [3.2e-2, 1e-2] and fig4.T == 5 and [m.name for m in fig4.methods] == ["CVA", "VCI", "MCVAA",
                                                                                            "MCVAC"]
    betas = fig4.beta.values()
    assert len(betas) == 51 and betas[0] == 3.2 and betas[-1] == 5.2
    fig3 = load_config(ROOT / "configs" / "fig3.yaml")
    assert fig3.h == [1e-2] and fig3.beta.values() == [3.2] and fig3.store_trajectories
    fig1 = load_config(ROOT / "configs" / "fig1.yaml")
    assert [m.options.constrained for m in fig1.methods] == [None, False]


# --- the run grid -------------------------------------------------------------------------------------
def test_run_ids_are_stable_unique_and_ignore_cosmetics(tmp_path):
    a = expand(load_config(write(tmp_path, GOOD)))
    b = expand(load_config(write(tmp_path, edit(GOOD, output="elsewhere.h5", workers="3", name="other"))))
    assert len(a) == 2 * 2 * 3 and len({s.run_id for s in a}) == len(a)
    assert [s.run_id for s in a] == [s.run_id for s in b]  # output, workers, name: not part of a run
    labelled = expand(load_config(write(tmp_path, edit(GOOD, methods="[{name: CVA, label: C}, VCI]"))))
    assert [s.run_id for s in labelled] == [s.run_id for s in a]
    assert labelled[0].label == "C"
    longer = expand(load_config(write(tmp_path, edit(GOOD, T="0.6"))))
    assert not {s.run_id for s in longer} & {s.run_id for s in a}
    tol = expand(load_config(write(tmp_path, edit(GOOD, tolerances="{newton_tol: 1.0e-10}"))))
    assert not {s.run_id for s in tol} & {s.run_id for s in a}
    # grid order: method, then h, then beta
    assert [(s.method.name, s.h, s.ic.beta) for s in a[:4]] == [("CVA", 0.032, 3.2), ("CVA", 0.032, 3.7),
                                                                ("CVA", 0.032, 4.2), ("CVA", 0.01, 3.2)]


def test_run_id_is_a_hash_of_the_identity(tmp_path):
    cfg = load_config(write(tmp_path, GOOD))
    s = expand(cfg)[5]
    ident = run_identity(cfg, s.method, s.h, s.ic)
    assert run_id_for(ident) == s.run_id and len(s.run_id) == 12
    assert ident["h"] == s.h and ident["method"] == {"name": s.method.name}


def test_config_key_ignores_where_and_how_many_workers(tmp_path):
    a = load_config(write(tmp_path, GOOD))
    b = load_config(write(tmp_path, edit(GOOD, output="x/y.h5", workers="2", description='"a note"')))
    c = load_config(write(tmp_path, edit(GOOD, store_trajectories="false")))
    assert a.canonical_sha256() == b.canonical_sha256() != c.canonical_sha256()


def test_tasks_group_runs_by_initial_condition(tmp_path):
    cfg = load_config(write(tmp_path, edit(GOOD, beta="{start: 3.2, stop: 5.2, num: 6}")))
    specs = expand(cfg)
    tasks = make_tasks(specs, workers=2, stored_refs=set(), needs_reference=True)
    assert len(tasks) == 6  # enough initial conditions: one task each, the reference computed once
    assert all(len({r.ic.key for r in t.runs}) == 1 and len(t.runs) == 4 and t.want_reference for t in tasks)
    few = make_tasks([s for s in specs if s.ic.beta == 3.2], workers=2, stored_refs=set(), needs_reference=True)
    assert len(few) == 4 and sum(t.want_reference for t in few) == 1  # split for parallelism, stored once
    stored = make_tasks(specs, workers=2, stored_refs={"beta=3.2"}, needs_reference=True)
    assert [t.want_reference for t in stored] == [False] + [True] * 5
    assert sorted(r.run_id for t in few for r in t.runs) == sorted(s.run_id for s in specs if s.ic.beta == 3.2)


def test_parse_config_from_a_mapping():
    """The Python API takes a mapping; errors then name the field without a file."""
    data = yaml_load(GOOD)
    cfg = parse_config(data)
    assert cfg.name == "t" and len(expand(cfg)) == 12
    with pytest.raises(ConfigError) as ei:
        parse_config({**data, "h": [0.01, 0]})
    assert str(ei.value) == "<config>: h[1]: must be > 0 (got 0)"


def test_experiments_and_cli_never_import_sympy():
    """Layering (DESIGN.md): the runner talks to the core through its API, never to sympy."""
    import ast

    files = sorted((ROOT / "vcirun" / "experiments").glob("*.py")) + sorted((ROOT / "vcirun" / "cli").glob("*.py"))
    for f in files:
        for node in ast.walk(ast.parse(f.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            assert not any(n == "sympy" or n.startswith("sympy.") for n in names), f
