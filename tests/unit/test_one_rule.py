"""One rule per concept, used everywhere: the step count N from (T, h), the tolerances, and the
stored size of a run (summed over the record table, so a new stored field is counted)."""
from __future__ import annotations

import ast
import warnings
from pathlib import Path

import pytest

import vcirun
from vcirun.core import record, sizes
from vcirun.core.grid import GridWarning, grid_count, grid_end, grid_steps
from vcirun.core.tolerances import DEFAULT_TOLERANCES, TOLERANCES
from vcirun.experiments.config import ConfigError, parse_config
from vcirun.experiments.sweep import reference_horizon

PKG = Path(vcirun.__file__).resolve().parent

# (h, T, N): T / h just below a multiple (5 / 1e-3 = 4999.999...), a fraction below and above 1/2
GRIDS = [(1e-3, 5.0, 5000), (3.2e-2, 5.0, 156), (0.03, 5.0, 166), (0.03, 1.0, 33), (0.1, 0.3, 3), (0.25, 1.0, 4)]


def _config(h, T, **extra):
    return {"name": "g", "system": "cart_pendulum", "methods": ["CVA"], "h": [h], "beta": [3.2], "T": T,
            "reference": {"kind": "none"}, **extra}


@pytest.mark.parametrize("h, T, N", GRIDS)
def test_step_count_is_the_floor_rule(h, T, N):
    assert grid_count(h, T) == N and grid_steps(h, T) == (h, T, N)
    assert grid_end(h, T) == N * h <= T * (1 + 1e-9)


@pytest.mark.parametrize("h, T, N", [g for g in GRIDS if g[2] <= 200])
def test_api_config_and_sweep_agree_on_the_step_count(h, T, N):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GridWarning)
        tr = vcirun.simulate("cart_pendulum", "CVA", h=h, T=T, beta=3.2)
    assert tr.n_steps == N and tr.T == pytest.approx(N * h, rel=1e-12)
    # the config's memory check counts N steps: a limit of exactly one N-step run passes, one byte less
    # fails (N + 1 steps, the rounded count where T / h has a fraction >= 1/2, would need more)
    need = sizes.run_bytes(N, 2)
    assert sizes.run_bytes(N + 1, 2) > need
    parse_config(_config(h, T, max_memory=need))
    with pytest.raises(ConfigError, match=r"h\[0\]: .* steps of 2 coordinates"):
        parse_config(_config(h, T, max_memory=need - 1))
    # the sweep's reference covers exactly the runs' grids
    cfg = parse_config(_config(h, T), check_semantics=False)
    assert reference_horizon(cfg) == max(T, N * h)


def test_step_count_is_computed_in_one_place():
    """No module outside vcirun.core.grid rounds or floors a ratio of T and h."""
    offenders = []
    for path in PKG.rglob("*.py"):
        if path == PKG / "core" / "grid.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", "")) in
                    ("round", "floor", "ceil") and node.args and isinstance(node.args[0], ast.BinOp)
                    and isinstance(node.args[0].op, ast.Div)):
                words = {getattr(x, "id", getattr(x, "attr", "")) for x in ast.walk(node.args[0])}
                if any(w == "T" or w.startswith("T_") for w in words) and \
                        any(w in ("h", "hg") or w.startswith("h_") for w in words):
                    offenders.append(f"{path.relative_to(PKG)}:{node.lineno}: {ast.unparse(node)}")
    assert not offenders, offenders


def test_tolerances_are_one_table():
    from vcirun.experiments.config import SweepConfig

    model = SweepConfig.model_fields["tolerances"].annotation
    assert list(model.model_fields) == list(TOLERANCES)
    for name, t in TOLERANCES.items():
        assert record.SETTINGS.count(name) == 1
        bad = {"gt": t.gt, "ge": (t.ge or 0) - 1, "le": (t.le or 0) + 1}
        for kind, value in bad.items():
            if getattr(t, kind) is None:
                continue
            with pytest.raises(ConfigError, match=f"tolerances.{name}: must be"):
                parse_config(_config(0.1, 0.3, tolerances={name: value}), check_semantics=False)
            with pytest.raises(ValueError, match=f"^{name}: must be"):
                vcirun.simulate("cart_pendulum", "CVA", h=0.1, T=0.3, beta=3.2, **{name: value})
    tr = vcirun.simulate("cart_pendulum", "CVA", h=0.1, T=0.3, beta=3.2)
    assert tr.tolerances == DEFAULT_TOLERANCES


def test_stored_bytes_counts_every_stored_field(monkeypatch):
    N, n, m = 100, 3, 2
    base = sizes.stored_bytes(N, n, m, impacts=5, releases=2)
    extra = record.Field("extra_force", "grid", True, "float64", 0.0, "trajectory", "a new stored row", contacts=True)
    monkeypatch.setattr(record, "FIELDS", record.FIELDS + (extra,))
    assert sizes.stored_bytes(N, n, m, impacts=5, releases=2) - base == (N + 1) * n * m * 8
    monkeypatch.setattr(record, "FIELDS", record.FIELDS[:-1] + (record.Field(
        "impact_extra", "impact", False, "int64", None, "impacts", "a new impact row"),))
    assert sizes.stored_bytes(N, n, m, impacts=5, releases=2) - base == 5 * 8
    assert sizes.stored_bytes(N, n, m, store_trajectories=False, impacts=5) - \
        sizes.stored_bytes(N, n, m, store_trajectories=False, impacts=4) == 8 * (1 + 3 * n) + 16 + 8 + 2 * 8 + 8  # + impact_impulse_t


@pytest.mark.parametrize("system, method, kw", [("cart_pendulum", "MCVAA", {"beta": 3.2}),
                                                ("ball_in_box", "CVA", {})])
def test_stored_bytes_is_the_size_of_a_runs_stored_arrays(system, method, kw):
    from vcirun.run.trajectory_files import trajectory_payload

    tr = vcirun.simulate(system, method, h=0.01, T=1.0, **kw)
    m = tr.contact_active.shape[1]
    data = 8 * (tr.n_steps + 1)  # t
    friction = 0
    for f in record.FIELDS:
        if f.stored != "no":
            a = getattr(tr, f.name)  # None: a row of other methods (Hmod), counted all the same
            b = a.nbytes if a is not None else (tr.n_steps + 1) * f.itemsize
            if f.name in record.FRICTION_ROWS:
                friction += b
            else:
                data += b
    _, arrays = trajectory_payload(tr)   # a frictionless system: its friction rows are not stored
    assert not set(arrays) & set(record.FRICTION_ROWS) and friction > 0
    kw = dict(impacts=len(tr.impacts), partial_steps=len(tr.partial_steps), releases=len(tr.releases))
    est = sizes.stored_bytes(tr.n_steps, len(tr.q[0]), m, friction=False, **kw)
    assert est - sizes.STORED_OVERHEAD == data
    assert sizes.stored_bytes(tr.n_steps, len(tr.q[0]), m, **kw) - est == friction   # with friction: counted
    assert len(tr.impacts) > 0
