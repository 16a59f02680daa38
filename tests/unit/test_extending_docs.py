"""docs/extending.md's worked examples run, and the reference pages list what the code defines.

The ```python test blocks of docs/extending.md run in order in one namespace, in a temporary working
directory into which the ```<lang> file=NAME blocks are written first. They run uncompiled
(vcirun.codegen.evaluate.python_module_for is the default kernel cache's loader here), so no numba compile is
needed; the registries the examples extend (the Ld library, the reset, kernel and part tables, the
record table) are restored afterwards.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
FENCE = re.compile(r"^```([^\n]*)\n(.*?)^```\s*$", re.M | re.S)


def blocks(text: str):
    """(info string, body) of every fenced block, in order."""
    return [(m.group(1).strip(), m.group(2)) for m in FENCE.finditer(text)]


def test_blocks_are_found():
    found = blocks((DOCS / "extending.md").read_text())
    tested = [b for info, b in found if info == "python test"]
    files = [info for info, _ in found if "file=" in info]
    assert len(tested) >= 5 and len(files) >= 2, (len(tested), files)


def test_extending_examples_run(tmp_path, monkeypatch):
    from vcirun.codegen import roles
    from vcirun.codegen.evaluate import python_module_for
    from vcirun.codegen.kernel_cache import default
    from vcirun.core import record
    from vcirun.discrete import lagrangians

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(default(), "loader", python_module_for)   # the docs' calls run uncompiled
    monkeypatch.setattr(roles, "RESETS", dict(roles.RESETS))
    monkeypatch.setattr(roles, "KERNELS", dict(roles.KERNELS))   # (a kernel the examples declare: theirs alone)
    monkeypatch.setattr(roles, "PARTS", dict(roles.PARTS))
    monkeypatch.setattr(record, "FIELDS", record.FIELDS)

    found = blocks((DOCS / "extending.md").read_text())
    for info, body in found:
        m = re.search(r"\bfile=(\S+)", info)
        if m:
            (tmp_path / m.group(1)).write_text(body)
    namespace: dict = {"__name__": "extending_md"}
    library = dict(lagrangians.LIBRARY)   # other modules hold this dict itself: restored in place
    names = set(vars(roles))               # (a declared kernel's name is bound in roles too)
    try:
        for k, (info, body) in enumerate(found):
            if info == "python test":
                try:
                    exec(compile(body, f"docs/extending.md block {k}", "exec"), namespace)
                except Exception as e:
                    pytest.fail(f"docs/extending.md block {k} ({body.splitlines()[0]!r}...): {type(e).__name__}: {e}")
    finally:
        lagrangians.LIBRARY.clear()
        lagrangians.LIBRARY.update(library)
        for k in set(vars(roles)) - names:
            delattr(roles, k)


def test_trajectory_fields_page_lists_every_record_row():
    from vcirun.core import record

    page = (DOCS / "reference" / "trajectory_fields.md").read_text()
    missing = [f.name for f in record.FIELDS if f"| `{f.name}` |" not in page]
    assert not missing, f"docs/reference/trajectory_fields.md: add rows for {missing}"
    statuses = [name for name, _ in record.STATUSES if f"| `{name}` |" not in page]
    assert not statuses, f"docs/reference/trajectory_fields.md: add statuses {statuses}"


def test_config_schema_page_lists_every_top_level_key():
    from vcirun.experiments.config.schema import SweepConfig

    page = (DOCS / "reference" / "config_schema.md").read_text()
    keys = [fi.alias or name for name, fi in SweepConfig.model_fields.items()]
    missing = [k for k in keys if f"| `{k}` |" not in page]
    assert not missing, f"docs/reference/config_schema.md: add rows for {missing}"


def test_doc_links_resolve():
    """Every relative Markdown link of README.md and docs/ names an existing file."""
    bad = []
    for page in [ROOT / "README.md", *DOCS.rglob("*.md")]:
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue
            path = (page.parent / target.split("#")[0]).resolve()
            if not path.exists():
                bad.append(f"{page.relative_to(ROOT)}: {target}")
    assert not bad, bad
