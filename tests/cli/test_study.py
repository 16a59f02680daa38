"""`vcirun study` and `vcirun validate` on study configs, end to end (typer's CliRunner): every shipped
config validates, a tiny extremes study writes its JSON and its report (and --only refreshes one
section, keeping the others), a tiny work-precision study prints its tables, bad input is one line."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from vcirun.cli.main import app

ROOT = Path(__file__).resolve().parents[2]
TEMPLATE = ROOT / "docs" / "templates" / "extremes.md"

EXTREMES = f"""\
study: extremes
name: tiny_extremes
methods: [CVA]
output: results/tiny_extremes.json
report: {{template: {TEMPLATE}, output: docs/tiny_extremes.md}}
dense:
  scenes:
    - {{system: bouncing_ball, q0: [1.0e-4], p0: [0.0], h: 0.02, T: 1}}
accumulation:
  h: [1.0e-2]
  T: 30
"""

WP = """\
study: work_precision
name: tiny_wp
system: cart_pendulum
beta: [3.2]
T: 0.5
methods: [CVA]
h: [1.0e-2, 5.0e-3]
baselines: {DOP853: [1.0e-6]}
repeats: 1
baseline_repeats: 1
output: results/tiny_wp.json
"""


@pytest.fixture
def runner():
    return CliRunner()


def invoke(runner, *args):
    return runner.invoke(app, [str(a) for a in args], catch_exceptions=False)


def assert_one_line_error(result, *words):
    assert result.exit_code == 1, (result.exit_code, result.output)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert "Traceback" not in result.output
    for w in words:
        assert w in lines[0], lines[0]


@pytest.mark.parametrize("path", sorted((ROOT / "configs").glob("*.yaml")), ids=lambda p: p.name)
def test_validate_accepts_every_shipped_config(runner, path):
    r = invoke(runner, "validate", path)
    assert r.exit_code == 0, r.output
    assert r.stdout.startswith(f"{path}: ok")
    is_study = "study:" in {line.split(" ")[0] for line in path.read_text().splitlines()}
    assert (f"run it with: vcirun study {path}" in r.stdout) == is_study


def test_extremes_study_writes_results_and_report_and_only_keeps_the_rest(runner, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = tmp_path / "tiny_extremes.yaml"
    cfg.write_text(EXTREMES)
    r = invoke(runner, "study", cfg)
    assert r.exit_code == 0, r.output
    res = json.loads(Path("results/tiny_extremes.json").read_text())
    assert res["methods"] == ["CVA"] and [x["status"] for x in res["dense"]] == ["ok"]
    # the damped ball settles: held contacts take over where impacts accumulate
    assert [x["status"] for x in res["accumulation"]] == ["ok"]
    assert res["accumulation"][0]["held_from"] >= 0.5 * res["accumulation"][0]["exact_onset"]
    report = Path("docs/tiny_extremes.md").read_text()
    assert "### Several impacts in one step" in report and "### Impact accumulation" in report
    assert "### Grazing contact" not in report and "## Step size" not in report   # absent sections
    assert "{{" not in report and "<!--" not in report
    assert f"Produced by `vcirun study {cfg}`" in report
    dense = res["dense"]
    res["accumulation"][0]["status"] = "marker"       # --only dense must keep this section as stored
    Path("results/tiny_extremes.json").write_text(json.dumps(res))
    r = invoke(runner, "study", cfg, "--only", "dense")
    assert r.exit_code == 0, r.output
    again = json.loads(Path("results/tiny_extremes.json").read_text())
    assert again["accumulation"][0]["status"] == "marker"
    assert again["dense"] == dense                     # recomputed, same numbers


def test_work_precision_study_prints_tables(runner, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = tmp_path / "tiny_wp.yaml"
    cfg.write_text(WP)
    r = invoke(runner, "study", cfg)
    assert r.exit_code == 0, r.output
    assert "== tiny_wp" in r.stdout and "speed ratio solve_ivp / vcirun" in r.stdout
    res = json.loads(Path("results/tiny_wp.json").read_text())
    assert {x["label"] for x in res["runs"]} == {"CVA", "DOP853"} and all(x["status"] == "ok" for x in res["runs"])


def test_bad_study_input_is_one_line(runner, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = tmp_path / "s.yaml"
    cfg.write_text(EXTREMES)
    assert_one_line_error(invoke(runner, "study", cfg, "--quick"), "--quick is for work-precision")
    assert_one_line_error(invoke(runner, "study", cfg, "--only", "grazing"), "--only: 'grazing' is not a section",
                          "dense, accumulation")
    assert_one_line_error(invoke(runner, "sweep", cfg), "s.yaml: study: a study config",
                          "run it with `vcirun study FILE`")
    assert_one_line_error(invoke(runner, "study", ROOT / "configs" / "quick.yaml"),
                          "quick.yaml: a study config needs the top-level key study:")
    cfg.write_text(EXTREMES.replace("  T: 30", "  T: 30\n  dept: 2"))
    for cmd in ("study", "validate"):
        assert_one_line_error(invoke(runner, cmd, cfg), "s.yaml: accumulation.dept: unknown key",
                              "allowed: h, T, y0, c")
    cfg.write_text(EXTREMES.replace("study: extremes", "study: extreme"))
    assert_one_line_error(invoke(runner, "validate", cfg), "study: unknown study 'extreme'; did you mean 'extremes'?")
    assert not Path("results").exists()


def test_study_help_has_examples(runner):
    r = invoke(runner, "study", "--help")
    assert r.exit_code == 0 and "vcirun study configs/extremes.yaml" in r.stdout and "--only" in r.stdout


def test_a_study_never_writes_over_a_tracked_file_and_says_warnings_as_notes(runner, tmp_path, monkeypatch):
    """A report (or results) path that is a file tracked by git is refused before anything runs (the
    shipped extremes config writes under results/; `make extremes` names docs/extremes.md itself); the
    runs' Python warnings (a grid note) are single `note:` lines, not warnings with source lines."""
    import subprocess

    monkeypatch.chdir(tmp_path)
    subprocess.run(["git", "init", "-q"], check=True)
    Path("docs").mkdir()
    Path("docs/page.md").write_text("tracked\n")
    subprocess.run(["git", "add", "docs/page.md"], check=True)
    cfg = tmp_path / "tracked.yaml"
    cfg.write_text(EXTREMES.replace("docs/tiny_extremes.md", "docs/page.md"))
    assert_one_line_error(invoke(runner, "study", cfg), "report.output", "docs/page.md", "tracked by git")
    assert Path("docs/page.md").read_text() == "tracked\n" and not Path("results").exists()
    cfg.write_text(EXTREMES.replace("h: 0.02, T: 1}", "h: 0.03, T: 1}"))   # T not a multiple of h: a grid note
    r = invoke(runner, "study", cfg)
    assert r.exit_code == 0, r.output
    notes = [line for line in r.stderr.splitlines() if "is not a multiple of h" in line]
    assert len(notes) == 1 and notes[0].startswith("note: T = 1 is not a multiple of h = 0.03"), r.stderr
    assert "GridWarning" not in r.stderr and ".py:" not in r.stderr
