"""What a newcomer types first: --version, systems, cache info|clear, simulate --q0/--p0/--output,
sweep --strict, plot without an argument, grid and compile notes."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import vcirun
from vcirun.cli.main import app
from vcirun.core.grid import GridWarning, grid_steps

TINY = """\
name: {name}
system: cart_pendulum
methods: [CVA]
h: [3.2e-2]
beta: [3.2, 4.2]
T: 0.5
output: results/{name}.h5
timing_repeats: 1
{extra}"""


@pytest.fixture
def runner():
    return CliRunner()


def invoke(runner, *args):
    return runner.invoke(app, [str(a) for a in args], catch_exceptions=False)


def one_line_error(r, *words):
    assert r.exit_code == 1, (r.exit_code, r.output)
    lines = r.stderr.strip().splitlines()
    assert lines and lines[-1].startswith("error: ") and "Traceback" not in r.output, r.output
    for w in words:
        assert w in lines[-1], lines[-1]


def test_version(runner):
    r = invoke(runner, "--version")
    assert r.exit_code == 0 and r.stdout.strip() == f"vcirun {vcirun.__version__}"


def test_systems(runner):
    r = invoke(runner, "systems")
    assert r.exit_code == 0
    for name in ("cart_pendulum", "double_pendulum", "oscillator_wall", "bouncing_ball", "n_pendulum_3"):
        assert name in r.stdout
    assert "y [m] height of the cart" in r.stdout and "theta [rad]" in r.stdout
    assert "m2 = 0.2 kg (pendulum point mass)" in r.stdout
    r = invoke(runner, "systems", "double_pendulum")
    assert "w = 1.2 m" in r.stdout and "cart_pendulum" not in r.stdout
    one_line_error(invoke(runner, "systems", "cart_pendlum"), "unknown built-in system")


def test_systems_lists_every_builtin(runner):
    """Every scene `simulate` accepts is listed and described: its coordinates and every parameter
    with a unit and a meaning, so a new scene cannot be added without its description."""
    from vcirun.scenes.registry import listed_scenes, scene_info
    from vcirun.scenes.registry import BUILTIN_SCENES, scene_data

    listed = invoke(runner, "systems").stdout
    for name in listed_scenes():
        assert name.rsplit("_", 1)[0] in BUILTIN_SCENES or name in BUILTIN_SCENES
        assert f"\n{name}  " in "\n" + listed, name
        info, d = scene_info(name), scene_data(name)
        assert len(info.coordinates) == d.n, name
        assert set(d.params) <= set(info.params), (name, set(d.params) - set(info.params))
        r = invoke(runner, "systems", name)
        assert r.exit_code == 0 and "coordinates" in r.stdout and "example" in r.stdout, name
    assert set(BUILTIN_SCENES) <= {n if n in BUILTIN_SCENES else n.rsplit("_", 1)[0] for n in listed_scenes()}


def test_cache_info_and_clear(runner, tmp_path, monkeypatch):
    monkeypatch.setenv("VCIRUN_CACHE_DIR", str(tmp_path / "c"))
    k = tmp_path / "c" / "kernels"
    k.mkdir(parents=True)
    (k / "vk_00000000000000000000.py").write_text("x = 1\n" * 100)
    (k / "wi_1.json").write_text("{}")
    (k / "core_00000000000000000000.py").write_text("x = 1\n")
    r = invoke(runner, "cache", "info")
    assert r.exit_code == 0 and (f"{tmp_path / 'c'}: 1 compiled modules, 1 shared cores, 1 warm-start entries, 3 files"
                                 in r.stdout)
    r = invoke(runner, "cache", "clear")
    assert r.exit_code == 0 and "removed 1 compiled modules" in r.stdout
    assert not k.exists()


def test_one_default_cache_for_every_entry_point(monkeypatch, tmp_path):
    from vcirun.codegen import cache

    monkeypatch.delenv("VCIRUN_CACHE_DIR", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))
    assert cache.cache_root() == tmp_path / ".cache" / "vcirun"
    makefile = (Path(__file__).resolve().parents[2] / "Makefile").read_text()
    assert "VCIRUN_CACHE_DIR" not in "\n".join(l for l in makefile.splitlines() if not l.startswith("#"))


def test_compile_announcement(monkeypatch, tmp_path, capsys):
    """A module missing from the cache is announced before it is built (without building it here)."""
    from vcirun.codegen import cache, cache_store
    from vcirun.cli import app as cli
    from vcirun.scenes.registry import get_scene
    from vcirun.methods.table import resolve_method

    monkeypatch.setenv("VCIRUN_CACHE_DIR", str(tmp_path / "empty"))
    monkeypatch.setattr(cache_store, "LISTENERS", [])
    from vcirun.codegen.kernel_cache import default
    monkeypatch.setattr(default(), "loaded", {})  # (another test may have loaded it in this process)
    cli._announce_compiles()
    ks = resolve_method("MCVAC").kernel_set()
    assert cache.announce_if_cold(get_scene("cart_pendulum"), ks)
    err = capsys.readouterr().err
    # what is compiled and why: the scene's kernels and, on an empty cache, the lean shared core
    assert re.search(r"compiling kernels for cart_pendulum/MCVA\[SVC,s=3\] and their shared core \(one contact, "
                     r"unforced\) \(first time, about \d+ s", err), err


def test_simulate_q0_p0_output_and_energy_scale(runner, tmp_path):
    out = tmp_path / "run.h5"
    r = invoke(runner, "simulate", "--system", "double_pendulum", "--q0", "-1.5,-1.5", "--p0", "0,0", "--T", "2",
               "--output", out)
    assert r.exit_code == 0, r.output
    assert f"saved {out}" in r.stdout
    rel = float(re.search(r"relative ([0-9.e+-]+) to the energy scale", r.stdout).group(1))
    assert rel < 1e-2   # H0 ~ 0 here: relative to |H0| alone this was 1e13 .. 1e16
    assert "s integrating;" in r.stdout
    from vcirun.run.trajectory import read_trajectory

    tr = read_trajectory(out)
    np.testing.assert_array_equal(tr.q[0], [-1.5, -1.5])
    assert tr.coordinate_names == ["theta1", "theta2"] and tr.impacts.size >= 1
    assert tr(1.0).shape == (2,)              # dense output re-attached from the scene's name
    r = invoke(runner, "simulate", "--system", "double_pendulum", "--T", "0.1", "--output", tmp_path / "x.csv")
    assert r.exit_code == 0 and (tmp_path / "x.csv").read_text().startswith("t,theta1,theta2,p_theta1")
    one_line_error(invoke(runner, "simulate", "--q0", "1,0", "--T", "0.1"), "give both --q0 and --p0")
    one_line_error(invoke(runner, "simulate", "--q0", "1,x", "--p0", "0,0", "--T", "0.1"), "--q0", "comma-separated")
    one_line_error(invoke(runner, "simulate", "--q0", "1", "--p0", "0", "--T", "0.1"), "length 2")
    one_line_error(invoke(runner, "simulate", "--T", "0.1", "--output", tmp_path / "x.txt"), "--output", ".h5")


def test_grid_note_once(runner):
    r = invoke(runner, "simulate", "--h", "0.03", "--T", "1")
    assert r.exit_code == 0
    assert r.stderr.count("note: T = 1 is not a multiple of h = 0.03: the grid ends at N h = 0.99") == 1
    assert "T = 0.99" in r.stdout
    with pytest.warns(GridWarning, match="N = floor"):
        tr = vcirun.simulate("cart_pendulum", "CVA", h=0.03, T=1, beta=3.2)
    assert tr.T == pytest.approx(0.99) and tr.n_steps == 33
    assert grid_steps(1e-3, 5)[2] == 5000 and grid_steps(3.2e-2, 5)[2] == 156


def test_sweep_strict_and_plot_every_file(runner, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    Path("good.yaml").write_text(TINY.format(name="good", extra=""))
    Path("bad.yaml").write_text(TINY.format(name="bad", extra="tolerances: {max_iter: 1}\n"))
    r = invoke(runner, "sweep", "good.yaml", "--workers", "1", "--strict", "-q")
    assert r.exit_code == 0, r.output
    r = invoke(runner, "sweep", "bad.yaml", "--workers", "1", "-q")
    assert r.exit_code == 0 and "did not finish with status ok" in r.stdout
    one_line_error(invoke(runner, "sweep", "bad.yaml", "--workers", "1", "--strict", "-q"),
                   "--strict: 2 of 2 stored runs did not finish with status ok")
    r = invoke(runner, "plot")       # no argument: every results file under results/
    assert r.exit_code == 0, r.output
    assert "figures and tables for results/bad.h5" in r.stdout and "figures and tables for results/good.h5" in r.stdout
    assert Path("results/figures/good/table2_timing.md").exists() and Path("results/figures/bad/table2_timing.md").exists()
    one_line_error(invoke(runner, "plot", "--out", "x"), "would overwrite each other")


def test_default_start_is_one_rule(runner, tmp_path):
    """A scene's default start lives in its numeric data: the CLI (no --beta), the API (no beta),
    the symbolic system and a sweep config without initial conditions all start from it."""
    from vcirun.core.system_data import requested_start
    from vcirun.experiments.config import parse_config
    from vcirun.scenes.registry import BUILTIN_SCENES, scene_data
    from vcirun.scenes.registry import get_scene

    assert scene_data("cart_pendulum").default_beta == 3.2
    for name in BUILTIN_SCENES:
        name = name + "_3" if name in ("n_pendulum", "newton_cradle") else name
        d = scene_data(name)
        assert (d.default_q0 is not None) != (d.default_beta is not None), name  # exactly one default start
        kind, q0, p0 = requested_start(d)
        if kind == "legendre":  # the symbolic system applies the same rule
            q_sym, p_sym = get_scene(name).initial_state()
            assert np.array_equal(q_sym, q0) and np.allclose(p_sym, get_scene(name).legendre(q0, p0)[1])
    r = invoke(runner, "simulate", "--h", "0.05", "--T", "0.5", "--output", tmp_path / "x.npz")
    assert r.exit_code == 0 and "beta = 3.2" in r.stdout, r.output
    cli = np.load(tmp_path / "x.npz")
    api = vcirun.simulate("cart_pendulum", "CVA", h=0.05, T=0.5)
    explicit = vcirun.simulate("cart_pendulum", "CVA", h=0.05, T=0.5, beta=3.2)
    assert api.beta == 3.2 and np.array_equal(api.q, explicit.q) and np.array_equal(cli["q"], api.q)
    cfg = parse_config({"name": "d", "system": "cart_pendulum", "methods": ["CVA"], "h": [0.05], "T": 0.5,
                        "reference": {"kind": "none"}})
    ic = cfg.initial_conditions()
    assert [c.key for c in ic] == ["default"] and get_scene("cart_pendulum").initial_state(
        **ic[0].simulate_kwargs())[0].tolist() == api.q[0].tolist()


def test_cache_info_lists_each_scene_once_and_caps_the_list():
    from vcirun.cli.cache import SHOWN, ready_text

    names = [f"scene{i:03d}/CVA[SVC]" for i in range(SHOWN + 5)] + ["scene000/CVA[SVC]"] * 3
    text = ready_text(names)
    assert text.startswith(f"compiled tier ready for {len(names)} module(s) of {SHOWN + 5} scene/kernel set(s): ")
    assert "scene000/CVA[SVC] (x4)" in text and text.count("scene000/") == 1
    assert text.endswith(", ... and 5 more (--all lists them)") and f"scene{SHOWN - 1:03d}/" in text
    assert f"scene{SHOWN:03d}/" not in text
    full = ready_text(names, all_names=True)
    assert f"scene{SHOWN + 4:03d}/CVA[SVC]" in full and "more" not in full


@pytest.mark.parametrize("suffix", [".nc", ".csv", ".npz"])
def test_a_run_saved_for_other_tools_is_named_as_such(runner, tmp_path, suffix):
    """info, plot and animate read runs saved as .h5; the other save formats get one line saying so."""
    f = tmp_path / f"run{suffix}"
    f.write_bytes(b"\0" * 16)
    for args in (["info", str(f)], ["plot", str(f)], ["animate", str(f)]):
        r = invoke(runner, *args)
        assert r.exit_code == 1, (args, r.output)
        assert "is for other tools" in r.output and "saved as .h5" in r.output, (args, r.output)


def test_simulate_takes_the_system_as_an_argument_too(runner):
    r = invoke(runner, "simulate", "oscillator_wall", "--T", "0.5")
    assert r.exit_code == 0 and "oscillator_wall" in r.stdout, r.output
    r = invoke(runner, "simulate", "oscillator_wall", "--system", "cart_pendulum", "--T", "0.5")
    assert r.exit_code == 1 and "name two systems" in r.output


def test_a_sweep_written_as_nc_is_read_as_results(runner, tmp_path):
    out = tmp_path / "p.nc"
    r = invoke(runner, "sweep", str(Path(__file__).resolve().parents[2] / "configs" / "quick.yaml"), "--output",
               str(out), "--quiet")
    assert r.exit_code == 0, r.output
    r = invoke(runner, "info", str(out))
    assert r.exit_code == 0 and "is for other tools" not in r.output, r.output
    r = invoke(runner, "info", str(tmp_path / "missing.csv"))
    assert r.exit_code == 1 and "is for other tools" not in r.output
