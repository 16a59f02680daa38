"""Names that are one thing and stay true: every dotted `vcirun.` name in a docstring, comment, string
or document resolves to a module or an object (a moved function or a removed module fails here);
Trajectory declares each row of the run record as a field of its own (what editors and type
checkers read), in the order of vcirun.core.record.FIELDS."""
from __future__ import annotations

import ast
import dataclasses
import importlib
import io
import re
import tokenize
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
_NAME = re.compile(r"(?<![\w./-])vcirun(?:\.[A-Za-z_]\w*)+")


def _texts():
    """(file, text) of every comment and string of the Python sources and every document."""
    for path in sorted([*ROOT.glob("vcirun/**/*.py"), *ROOT.glob("tests/**/*.py"), *ROOT.glob("bench/**/*.py")]):
        if path == Path(__file__).resolve():   # (its own examples of stale names)
            continue
        src = path.read_text()
        for tok in tokenize.generate_tokens(io.StringIO(src).readline):
            if tok.type in (tokenize.COMMENT, tokenize.STRING):
                yield path, tok.string
    for path in sorted([*ROOT.glob("docs/**/*.md"), ROOT / "README.md", ROOT / "Makefile", ROOT / "pyproject.toml"]):
        yield path, path.read_text()


def _resolves(name: str) -> bool:
    parts = name.split(".")
    obj = importlib.import_module("vcirun")   # attributes first (the package's lazy names): importing
    for attr in parts[1:]:                    # vcirun.reference as a module would shadow the function
        if not hasattr(obj, attr):
            break
        obj = getattr(obj, attr)
    else:
        return True
    for i in range(len(parts), 0, -1):
        mod = ".".join(parts[:i])
        try:
            obj = importlib.import_module(mod)
        except ModuleNotFoundError as e:
            if e.name and (mod == e.name or mod.startswith(e.name + ".")):
                continue
            raise
        for attr in parts[i:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


# names that are not Python objects: the kernel cache's logger
NOT_OBJECTS = {"vcirun.build"}


def test_every_dotted_vcirun_name_resolves():
    seen, bad = {}, {}
    for path, text in _texts():
        for m in _NAME.finditer(text):
            seen.setdefault(m.group(0), path)
    for name, path in seen.items():
        if name not in NOT_OBJECTS and not _resolves(name):
            bad[name] = str(path.relative_to(ROOT))
    assert len(seen) > 200, len(seen)   # (the scan finds the names: hundreds of them)
    assert not bad, "names that resolve to nothing (stale after a move or rename):\n" + "\n".join(
        f"  {n}  ({p})" for n, p in sorted(bad.items()))


def test_the_scan_finds_a_stale_name():
    assert _resolves("vcirun.run.trajectory.Trajectory.save") and _resolves("vcirun.reference")
    assert not _resolves("vcirun.stress.ball_exact") and not _resolves("vcirun.scenes.oracles.no_such_function")
    assert [m.group(0) for m in _NAME.finditer("see vcirun.io.batches.data_problems, vcirun/io/x.py and `vcirun.`")] \
        == ["vcirun.io.batches.data_problems"]


def test_trajectory_declares_every_record_row():
    from vcirun.core import record
    from vcirun.run.trajectory import Trajectory

    tree = ast.parse((ROOT / "vcirun/run/trajectory.py").read_text())
    cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "Trajectory")
    written = [n.target.id for n in cls.body if isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name)]
    rows = [f.name for f in record.FIELDS]
    assert written[-len(rows):] == rows, "Trajectory's last fields must be the run record's rows, in order"
    assert not [d for d in cls.decorator_list if not (isinstance(d, ast.Name) and d.id == "dataclass")]
    fields = {f.name: f for f in dataclasses.fields(Trajectory)}
    for name in rows:
        assert fields[name].default is None and "np.ndarray" in str(fields[name].type), name
    tr = Trajectory(method="CVA", system="x", h=0.1, T=0.1, t=np.zeros(2), q=np.zeros((2, 1)), p=np.zeros((2, 1)))
    for f in record.FIELDS:   # empty arrays of the row's dtype, except rows of some methods only
        v = getattr(tr, f.name)
        assert (v is None) == (f.only is not None), f.name
