"""The layer map (README, "Layers"): no import cycle among vcirun modules and no import against the
data flow, function-level imports included; the numeric layers load no sympy.

Layers, top to bottom; a module may import from its own layer and the layers above it only. The
package facade vcirun/__init__ (lazy names) and the CLI sit outside: they may import anything.
"""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[2] / "vcirun"

LAYERS = (
    ("core", ("core",)),
    ("symbolic model", ("mechanics",)),
    ("scenes", ("scenes",)),
    ("discrete mechanics", ("discrete",)),
    ("backward error", ("modified",)),
    ("code generation", ("codegen",)),
    ("numba units", ("maps", "collision")),
    ("methods", ("methods",)),
    ("run", ("run",)),
    ("reference", ("reference_solution",)),
    ("files", ("io",)),
    ("experiments", ("experiments",)),
    ("verification", ("verification",)),
    ("interface", ("cli",)),
)
OUTSIDE = ("__init__", "__main__")


def _layer_of(mod: str) -> int | None:
    top = mod.split(".")[1] if mod.count(".") else ""
    for k, (_, names) in enumerate(LAYERS):
        if top in names:
            return k
    return None


def _modules():
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        yield ".".join(parts), path


def _imports(mod: str, path: Path) -> set:
    """Every vcirun module `mod` imports, at module level or inside functions."""
    tree = ast.parse(path.read_text())
    pkg = mod if path.name == "__init__.py" else mod.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("vcirun")}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.startswith("vcirun"):
                out.add(target)
                for a in node.names:  # `from . import record` imports a module
                    out.add(f"{target}.{a.name}")
    return out


def _graph():
    mods = dict(_modules())
    g = {}
    for m, p in mods.items():
        g[m] = {t for t in _imports(m, p) if t in mods and t != m}
    return g


def test_every_module_has_a_layer():
    missing = [m for m, _ in _modules() if m != "vcirun" and m.split(".")[1] not in OUTSIDE and _layer_of(m) is None]
    assert not missing, f"modules outside the layer map (tests/unit/test_layers.py LAYERS): {missing}"


def test_no_import_against_the_layers():
    bad = []
    for m, targets in _graph().items():
        lm = _layer_of(m)
        if lm is None:
            continue
        for t in targets:
            lt = _layer_of(t)
            if lt is not None and lt > lm:
                bad.append(f"{m} ({LAYERS[lm][0]}) imports {t} ({LAYERS[lt][0]})")
    assert not bad, "imports against the data flow:\n" + "\n".join(sorted(bad))


def test_no_import_cycle():
    g = _graph()
    # packages import their own submodules; an edge to a package's __init__ from inside it is not a cycle
    color, stack, cycles = {}, [], []

    def visit(u):
        color[u] = 1
        stack.append(u)
        for v in sorted(g.get(u, ())):
            if v == "vcirun" or u.startswith(v + "."):
                continue
            if color.get(v) == 1:
                cycles.append(" -> ".join(stack[stack.index(v):] + [v]))
            elif not color.get(v):
                visit(v)
        stack.pop()
        color[u] = 2

    for u in sorted(g):
        if not color.get(u):
            visit(u)
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


@pytest.mark.parametrize("module", ["vcirun.maps", "vcirun.collision", "vcirun.experiments", "vcirun.reference_solution",
                                    "vcirun.experiments.sweep", "vcirun.io.writer", "vcirun.io.reader",
                                    "vcirun.experiments.config", "vcirun.run.api", "vcirun.core.record"])
def test_numeric_layers_load_no_sympy_and_compile_nothing(module):
    code = (f"import sys, importlib; importlib.import_module({module!r}); "
            "bad = [m for m in sys.modules if m == 'sympy' or m.startswith('vcirun_kernels_')]; "
            "print(','.join(bad))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "", f"importing {module} loaded {r.stdout.strip()}"


# Imports of other distributions vcirun may make: its declared dependencies (pyproject.toml), what
# they install with them (llvmlite with numba, pandas with xarray, Pillow with matplotlib), and the optional extras that
# say so when missing (dask: `vcirun sweep --scheduler`). `make run` installs only the dependencies.
PROVIDED_BY = {"yaml": "pyyaml", "llvmlite": "numba", "pandas": "xarray", "PIL": "matplotlib"}
OPTIONAL = {"dask": "dask", "distributed": "dask", "h5netcdf": "netcdf"}


def test_every_third_party_import_is_a_declared_dependency():
    """A module vcirun imports that none of its dependencies installs works in the test environment
    (which has the test tools and Dask) and fails for a user of `make run` (the CLI once imported
    click, which only Dask's dependencies install)."""
    import ast
    import re

    tomllib = pytest.importorskip("tomllib")   # (Python >= 3.11)
    root = Path(__file__).resolve().parents[2]
    meta = tomllib.loads((root / "pyproject.toml").read_text())["project"]
    declared = {re.split(r"[<>=\[ ;]", d, maxsplit=1)[0].lower() for d in meta["dependencies"]}
    extras = set(meta.get("optional-dependencies", {}))
    names = set()
    for p in (root / "vcirun").rglob("*.py"):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.Import):
                names |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    third = {n for n in names if n not in sys.stdlib_module_names and n != "vcirun"}
    undeclared = sorted(n for n in third if PROVIDED_BY.get(n, n) not in declared
                        and OPTIONAL.get(n) not in extras)
    assert not undeclared, f"imported but installed by no dependency of vcirun: {undeclared}"
    assert {"numpy", "numba", "h5py", "typer"} <= third   # (the scan sees the imports)


def test_the_installed_numba_is_within_the_pinned_range():
    """numba is pinned to the versions the suite ran on (vcirun.codegen.kcall uses its internals): the
    environment the tests run in must be one of them, else the pin says nothing."""
    import re

    import numba

    tomllib = pytest.importorskip("tomllib")
    root = Path(__file__).resolve().parents[2]
    spec = next(d for d in tomllib.loads((root / "pyproject.toml").read_text())["project"]["dependencies"]
                if d.startswith("numba"))
    lo, hi = re.fullmatch(r"numba>=([\d.]+),<([\d.]+)", spec).groups()
    as_tuple = lambda v: tuple(int(x) for x in re.findall(r"\d+", v)[:2])  # noqa: E731
    assert as_tuple(lo) <= as_tuple(numba.__version__) < as_tuple(hi), (numba.__version__, spec)
