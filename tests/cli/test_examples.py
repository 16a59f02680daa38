"""Examples that show what they claim: every `vcirun simulate` line of `vcirun systems`, of the README
and of docs/guide.md, docs/bodies.md, docs/walkers.md runs, ends ok and records impacts, or with
friction impacts or stick/slip mode changes (every scene has contacts; a line with --unconstrained is
the exception it says it is, a line that says it ends with status painleve ends so); `--help`
examples too."""
from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
from typer.testing import CliRunner

from vcirun.cli.main import app
from vcirun.scenes.registry import example_command, listed_scenes

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md"] + [ROOT / "docs" / f for f in ("guide.md", "bodies.md", "walkers.md")]


def _fenced_lines(prefix):
    """(document, line) for every line starting with `prefix` inside a fenced code block of the user's
    documents, its comment cut."""
    out = []
    for path in DOCS:
        fenced = False
        for line in path.read_text().splitlines():
            if line.startswith("```"):
                fenced = not fenced
                continue
            if fenced and line.strip().startswith(prefix):
                out.append((path.name, line.split("#")[0].strip(), line.partition("#")[2].strip()))
    return out


def _doc_commands():
    """Every `vcirun simulate ...` line inside a fenced code block of the user's documents."""
    return _fenced_lines("vcirun simulate")


def _catalog_commands():
    return [(f"vcirun systems: {name}", *example_command(name).split("   (")) for name in listed_scenes()]


def _claimed_status(claim):
    """The status an example says its run ends with ("status painleve" in what it says it shows), else ok."""
    m = re.search(r"status (\w+)", claim)
    return m.group(1) if m else "ok"


CASES = _catalog_commands() + _doc_commands()


@pytest.mark.parametrize("where, command, claim", CASES, ids=[f"{w}: {c[15:60]}" for w, c, _ in CASES])
def test_example_runs_and_records_impacts(where, command, claim, tmp_path, monkeypatch):
    monkeypatch.chdir(ROOT)
    args = shlex.split(command)[2:]
    if "--output" in args:
        args[args.index("--output") + 1] = str(tmp_path / Path(args[args.index("--output") + 1]).name)
    r = CliRunner().invoke(app, ["simulate", *args], catch_exceptions=False)
    status = _claimed_status(claim)
    if status != "ok":   # a run that ends with a failure status exits 1 and says why
        assert r.exit_code == 1, (where, command, r.output)
        assert re.search(rf"status\s+{status}\b", r.stdout), r.stdout
        assert f"run ended with status {status}" in r.output, r.output
        return
    assert r.exit_code == 0, (where, command, r.output)
    assert re.search(r"status\s+ok", r.stdout), r.stdout
    impacts = int(re.search(r"impacts\s+(\d+)", r.stdout).group(1))
    m = re.search(r"mode changes\s+(\d+)", r.stdout)   # printed for a run with stick/slip transitions
    changes = int(m.group(1)) if m else 0
    if "--unconstrained" in args:
        assert impacts == 0
    else:
        assert impacts + changes > 0, f"{where}: `{command}` records no impact and no mode change"


def test_every_scene_has_an_example_and_the_docs_have_commands():
    assert len(_catalog_commands()) == len(listed_scenes()) >= 21
    assert any("cradle_gap" in c for _, c, _ in _catalog_commands())
    friction = ("rocking_block_friction", "spinning_ball", "incline", "coulomb_oscillator", "painleve_rod",
                "link_chain_friction_3")
    assert set(friction) <= set(listed_scenes())
    claims = {c.split()[3]: claim for _, c, claim in _catalog_commands()}
    assert _claimed_status(claims["painleve_rod"]) == "painleve"
    assert len(_doc_commands()) >= 4


def _doc_animations():
    return [(w, c) for w, c, _ in _fenced_lines("vcirun animate --system")]


@pytest.mark.slow
@pytest.mark.parametrize("where, command", _doc_animations(), ids=[c[15:70] for _, c in _doc_animations()])
def test_documented_animations_run(where, command, tmp_path, monkeypatch):
    """Every `vcirun animate --system ...` line of the docs writes its GIF (here into a scratch folder)."""
    from PIL import Image

    monkeypatch.chdir(ROOT)
    args = shlex.split(command)[2:]
    out = tmp_path / "a.gif"
    if "--output" in args:
        args[args.index("--output") + 1] = str(out)
    else:
        args += ["--output", str(out)]
    r = CliRunner().invoke(app, ["animate", *args], catch_exceptions=False)
    assert r.exit_code == 0, (where, command, r.output)
    with Image.open(out) as im:
        assert im.n_frames >= 30
