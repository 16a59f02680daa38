"""Test helper (and a script): the module-level mutable containers of a package.

A module-level mutable container is a name bound at module level to a dict, list or set (literal or
constructor, empty or not), an OrderedDict, defaultdict, deque, weak mapping, threading.local or a
ctypes array, that some code in the package mutates (a mutating method call, an item or attribute
assignment, a `del` of an item), through the bare name in its own module or as `module.name`
anywhere. Tables filled once and only read (`__all__`, constant lists) are not counted.

    python tests/module_state.py [PACKAGE_DIR]     # default: vcirun/ beside this file's parent
"""
from __future__ import annotations

import ast
import sys
from pathlib import Path

CONSTRUCTORS = {"dict", "list", "set", "OrderedDict", "defaultdict", "deque", "WeakValueDictionary",
                "WeakKeyDictionary", "WeakSet", "local"}
MUTATORS = {"append", "add", "update", "clear", "pop", "setdefault", "extend", "insert", "discard", "remove",
            "popitem", "move_to_end", "appendleft"}


def _container(v: ast.expr) -> bool:
    if isinstance(v, (ast.Dict, ast.List, ast.Set)):
        return True
    if isinstance(v, ast.Call):
        f = v.func
        name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None
        if name in CONSTRUCTORS:
            return True
        return isinstance(f, ast.BinOp) and isinstance(f.op, ast.Mult)   # (ctypes.c_int64 * N)()
    return False


def mutable_containers(root: Path) -> list[tuple[Path, str]]:
    """[(file, name)] of the module-level mutable containers below `root`, sorted."""
    trees = {p: ast.parse(p.read_text(), str(p)) for p in sorted(Path(root).rglob("*.py"))}
    candidates = set()
    for p, t in trees.items():
        for node in t.body:
            if isinstance(node, (ast.Assign, ast.AnnAssign)) and node.value is not None and _container(node.value):
                for tg in (node.targets if isinstance(node, ast.Assign) else [node.target]):
                    if isinstance(tg, ast.Name) and tg.id != "__all__":
                        candidates.add((p, tg.id))

    def owners(e: ast.expr, p: Path) -> list:
        if isinstance(e, ast.Name):
            return [(p, e.id)]
        if isinstance(e, ast.Attribute):
            return [(q, e.attr) for q in trees if (q, e.attr) in candidates]
        return []

    mutated = set()
    for p, t in trees.items():
        for node in ast.walk(t):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in MUTATORS:
                mutated.update(owners(node.func.value, p))
            targets = []
            if isinstance(node, ast.Assign):
                targets = node.targets
            elif isinstance(node, (ast.AugAssign, ast.AnnAssign)):
                targets = [node.target]
            elif isinstance(node, ast.Delete):
                targets = node.targets
            for tg in targets:
                if isinstance(tg, (ast.Subscript, ast.Attribute)):
                    mutated.update(owners(tg.value, p))
    return sorted(c for c in candidates if c in mutated)


def main(argv: list[str]) -> int:
    root = Path(argv[0]) if argv else Path(__file__).resolve().parents[1] / "vcirun"
    found = mutable_containers(root)
    for p, name in found:
        print(f"{p.relative_to(root.parent)}  {name}")
    print(f"{len(found)} module-level mutable containers in {root}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
