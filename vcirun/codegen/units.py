"""The contract between the generated kernels of a module and the numba source units.

A compiled module is one file: generated kernels (vcirun.codegen.derive) + the numba source units
of vcirun/maps and vcirun/collision + the role bindings `full`, `partial`, `reset`,
`modified_energy`. What the generated part defines, the roles and their signatures, and the
descriptors that choose a role's unit function are declared once, in vcirun.codegen.roles; this
module holds the units against them and assembles a module:

- A unit declares what it requires by its imports: the generated names and roles it calls from
  vcirun.codegen.roles, the functions of other units from those units' modules (so editors and
  linters resolve every name). `unit_body` drops those import lines when the unit is assembled;
  what a unit provides is what it defines at module level without a leading underscore.
- UNITS: the units every module may hold, in module order; a reset's unit (roles.RESETS) joins the
  module that binds it. `check_unit` holds a unit against the declarations: every name it reads
  is defined or imported, every import is used and declared (a generated name of
  roles.KERNELS / roles.CONSTANTS, a role, or a name its sibling unit defines), every call passes
  as many arguments as the callee takes, and every role implementation it defines has the role's
  parameters in the role's order.
- GENERATED: the names of each generated part (roles.generated_names); `check_generated` holds it
  against the generated text.
- `bindings(ks)`: the role bindings of a kernel set, from its descriptors (never an `if` in a unit).
- `entry_points(ks)`: roles.ENTRY, the names Python calls on a module of that kernel set.

`select_units(ks)` includes every unit whose requirements the generated part, the bindings and the
other included units meet (so a module without the modified Hamiltonian has no maps/gauss.py), and
raises ContractError naming the missing symbol when an entry point or a binding cannot be met.
No sympy here: the selection runs on the warm path too (the cache key hashes the selected units).
"""
from __future__ import annotations

import ast
import builtins
import functools
import re
import symtable
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from . import roles
from .roles import ContractError

PKG = Path(__file__).resolve().parent.parent
_SOURCE = PKG   # where sibling units are read from (PKG may point elsewhere for a unit under test)

ROLES_MODULE = "vcirun.codegen.roles"
# an import of a unit's requirements: from the declarations, or from another unit
_CONTRACT_IMPORT = re.compile(r"^from (vcirun\.(?:codegen\.roles|maps\.\w+|collision\.\w+)) import "
                              r"(\([^)]*\)|[^\n]*)\n", re.M)


@dataclass(frozen=True)
class Unit:
    path: str          # relative to the vcirun package, or absolute (a unit outside the package)

    @property
    def file(self) -> Path:
        return PKG / self.path   # (an absolute path stays itself)

    @property
    def text(self) -> str:
        return self.file.read_text()

    @property
    def module(self) -> str:
        """The unit's module name within the package (the form sibling units import it by)."""
        p = Path(self.path)
        return "vcirun." + ".".join(p.with_suffix("").parts) if not p.is_absolute() else p.stem

    @property
    def body(self) -> str:
        """The text a module holds: the unit without its contract imports."""
        return unit_body(self.text)

    @property
    def imports(self) -> dict:
        """{module: names} the unit imports from the declarations and other units."""
        return _imports(self.text)

    @property
    def requires(self) -> tuple:
        return tuple(n for names in self.imports.values() for n in names)

    @property
    def provides(self) -> tuple:
        return _provides(self.text, self.path)


def unit_body(text: str) -> str:
    return _CONTRACT_IMPORT.sub("", text)


@functools.lru_cache(maxsize=128)
def _imports(text: str) -> dict:
    out = {}
    for m in _CONTRACT_IMPORT.finditer(text):
        names = [n.strip() for n in m.group(2).strip("()").replace("\n", " ").split(",")]
        out.setdefault(m.group(1), []).extend(n for n in names if n)
    return {k: tuple(v) for k, v in out.items()}


@functools.lru_cache(maxsize=128)
def _provides(text: str, filename: str) -> tuple:
    defined, _, _ = _names(text, filename)
    return tuple(sorted(n for n in defined if not n.startswith("_")))


UNITS = tuple(Unit(p) for p in (
    "maps/linalg.py", "maps/newton.py", "maps/dynamics.py", "maps/steps.py", "maps/gauss.py", "maps/held.py",
    "maps/friction.py", "collision/state.py", "collision/events.py", "collision/impact_law.py",
    "collision/friction_law.py", "collision/impact.py", "collision/impact_friction.py", "collision/declared.py",
    "collision/algorithm1.py"))
UNIT = {u.path: u for u in UNITS}
_RESET_SLOT = UNITS.index(UNIT["collision/algorithm1.py"])   # a bound reset's unit: before the loop

class _Generated(Mapping):
    """{part: the names it defines}, read from the declarations when asked (a kernel declared at run
    time, e.g. with a part of its own, is in it from then on)."""

    def __getitem__(self, part):
        if part not in roles.PARTS:
            raise KeyError(part)
        return roles.generated_names(part)

    def __iter__(self):
        return iter(roles.PARTS)

    def __len__(self):
        return len(roles.PARTS)


GENERATED = _Generated()


def generated_parts(ks) -> tuple:
    """The GENERATED parts a kernel set's module holds, in roles.PARTS order."""
    have = {"system", "record"} | ({"steps"} if ks.full_stages else set()) | {p for p, _ in ks.parts}
    return tuple(p for p in roles.PARTS if p in have)


def bindings(ks) -> dict:
    """{role: bound name} of a kernel set, from its descriptors (empty for the system-only set)."""
    if not ks.full_stages:
        return {}
    return {"full": roles.FULL_MAP[1], "partial": roles.partial_map(ks.partial).function,
            "reset": roles.reset_map(ks.reset).function,
            "modified_energy": roles.MODIFIED_ENERGY["modified" in generated_parts(ks)][1]}


def implementations() -> dict:
    """{function name: role} of every declared role implementation (a name may play one role only)."""
    out = {roles.FULL_MAP[1]: "full"}
    out |= {p.function: "partial" for p in roles.PARTIALS.values()}
    out |= {r.function: "reset" for r in roles.RESETS.values()}
    out |= {fn: "modified_energy" for _, fn in roles.MODIFIED_ENERGY.values()}
    return out


def entry_points(ks) -> tuple:
    return tuple(n for p in generated_parts(ks) for n in roles.ENTRY.get(p, ()))


def candidate_units(ks, resets=None) -> tuple:
    """UNITS, with the units of the kernel set's reset (or of the resets given: ResetMap rows) when it
    binds one, before the loop's."""
    if not ks.full_stages:
        return UNITS
    rows = (roles.reset_map(ks.reset),) if resets is None else tuple(resets)
    return UNITS[:_RESET_SLOT] + tuple(dict.fromkeys(Unit(r.unit) for r in rows)) + UNITS[_RESET_SLOT:]


def select_units(ks, resets=None) -> list[Unit]:
    """The units of a kernel set's module, in module order (see the module docstring); resets: the
    ResetMap rows whose units the module holds (a shared core's several: vcirun.codegen.shared),
    by default the kernel set's own."""
    return list(_select(ks, None if resets is None else tuple(resets), _descriptor_state()))


def _descriptor_state() -> tuple:
    # registered resets and declared kernels change what a kernel set's names mean: part of the memo key
    return tuple(roles.RESETS.items()), tuple(roles.KERNELS)


@functools.lru_cache(maxsize=256)
def _select(ks, resets, _state) -> tuple:
    candidates = candidate_units(ks, resets)
    avail = {n for part in generated_parts(ks) for n in GENERATED[part]}
    binds = bindings(ks)
    included: list[Unit] = []
    changed = True
    while changed:
        changed = False
        for role, target in binds.items():
            if role not in avail and target in avail:
                avail.add(role)
                changed = True
        for u in candidates:
            if u in included:
                continue
            own = avail | set(u.provides)
            own |= {role for role, target in binds.items() if target in own}  # e.g. a default it binds itself
            if set(u.requires) <= own:
                included.append(u)
                avail |= set(u.provides)
                changed = True
    for name in list(binds) + list(entry_points(ks)):
        if name not in avail:
            raise ContractError(_explain(name, binds, avail, ks, candidates))
    return tuple(u for u in candidates if u in included)


def _explain(name, binds, avail, ks, candidates) -> str:
    """Why `name` is not available: the unit that would provide it and its first unmet requirement."""
    target = binds.get(name, name)
    what = f"role {name!r} -> {target}" if name in binds else f"{name}"
    for u in candidates:
        if target in u.provides:
            missing = [r for r in u.requires if r not in avail and r not in u.provides]
            return (f"module for kernel set {ks.key_text()}: {what} is provided by {u.path}, which requires "
                    f"{missing[0]}: neither the generated kernels ({', '.join(generated_parts(ks))}) nor an "
                    f"included unit provide it")
    return f"module for kernel set {ks.key_text()}: nothing provides {what}"


# --- declarations held against the code ------------------------------------------------------------

_BUILTINS = set(dir(builtins))


@functools.lru_cache(maxsize=128)
def _names(text: str, filename: str) -> tuple[set, set, set]:
    """(defined, imported, read): the module-level names a source defines and imports, and the global
    names its code reads (module level and inside every function) that it neither defines nor
    imports, by symtable."""
    top = symtable.symtable(text, filename, "exec")
    defined, imported, used = set(), set(), set()
    for s in top.get_symbols():
        if s.is_imported():
            imported.add(s.get_name())
        elif s.is_assigned():
            defined.add(s.get_name())
        if s.is_referenced():
            used.add(s.get_name())

    def walk(tab):
        for child in tab.get_children():
            for s in child.get_symbols():
                if s.is_referenced() and (s.is_global() or s.is_free()) and not s.is_local():
                    used.add(s.get_name())
            walk(child)

    walk(top)
    return defined, imported, used


def source_names(text: str, filename: str = "<unit>") -> tuple[set, set]:
    """(defined, read): the module-level names a source defines (functions, assignments, imports) and
    the global names its code reads that it neither defines nor imports (builtins aside)."""
    defined, imported, used = _names(text, filename)
    return defined | imported, used - defined - imported - _BUILTINS


def _declared(name: str) -> bool:
    return name in roles.KERNELS or name in roles.CONSTANTS or name in roles.ROLES


def _signatures(tree: ast.Module) -> dict:
    """{function: (parameter names, number with a default)} of a module's top-level functions."""
    return {f.name: (tuple(a.arg for a in f.args.args), len(f.args.defaults))
            for f in tree.body if isinstance(f, ast.FunctionDef)}


def _unit_of_module(module: str) -> Unit | None:
    if not module.startswith("vcirun."):
        return None
    rel = module[len("vcirun."):].replace(".", "/") + ".py"
    if (PKG / rel).is_file():
        return Unit(rel)
    return Unit(str(_SOURCE / rel)) if (_SOURCE / rel).is_file() else None


def check_unit(u: Unit) -> None:
    """The unit against the declarations (see the module docstring); raises ContractError naming the
    unit, the name and the fix. A unit that passed leaves a stamp in the kernel cache named by the
    hash of everything the check reads (the unit, the units it imports from, the declarations, this
    checker), so a new process does not parse and walk the units again: 1-2 s of a first call."""
    stamp = _stamp(u)
    if stamp is not None and stamp.exists():
        return
    _check(u.path, u.text)
    if stamp is not None:
        try:
            stamp.parent.mkdir(exist_ok=True)
            stamp.touch()
        except OSError:   # (a read-only or full cache: checked again next time)
            pass


def _stamp(u: Unit) -> Path | None:
    """The stamp of u's passed check: root()/units_checked/<hash>; None if the cache is unusable."""
    import hashlib

    from .cache_store import CacheError, kernels_dir

    try:
        d = kernels_dir().parent / "units_checked"
    except CacheError:
        return None
    h = hashlib.sha256(_checker_digest().encode())
    for text in (u.path, u.text, *(sib.text for sib in _siblings(u.text))):
        h.update(b"\0" + text.encode())
    h.update(b"\0" + _declarations_digest().encode())
    return d / h.hexdigest()[:32]


@functools.lru_cache(maxsize=1)
def _checker_digest() -> str:
    """The checker's own sources (this module, the scratch rules of frame.py)."""
    here = Path(__file__).resolve().parent
    return "\0".join((here / f).read_text() for f in ("units.py", "frame.py"))


def _siblings(text: str) -> list:
    return [sib for sib in map(_unit_of_module, _imports(text)) if sib is not None]


def _declarations_digest() -> str:
    """What the check reads of the declarations (they grow when a reset is registered from outside)."""
    k = sorted((n, d.per_stage, tuple(a for a, _ in d.args)) for n, d in roles.KERNELS.items())
    r = sorted((n, d.params, d.optional) for n, d in roles.ROLES.items())
    return repr((k, r, sorted(roles.CONSTANTS), sorted(implementations().items())))


@functools.lru_cache(maxsize=128)
def _check(path: str, text: str) -> None:
    defined, imported, used = _names(text, path)
    read = used - defined - imported - _BUILTINS
    if read:
        raise ContractError(f"{path}: uses {sorted(read)} without defining or importing it (import a generated "
                            f"name or a role from {ROLES_MODULE}, another unit's name from its module)")
    sigs = {}
    for module, names in _imports(text).items():
        unused = [n for n in names if n not in used]
        if unused:
            raise ContractError(f"{path}: imports {unused} from {module} but never uses it")
        if module == ROLES_MODULE:
            bad = [n for n in names if not _declared(n)]
            if bad:
                raise ContractError(f"{path}: imports {bad} from {ROLES_MODULE}, which declares no such generated "
                                    "name or role (vcirun.codegen.roles: KERNELS, CONSTANTS, ROLES)")
            for n in names:
                if n in roles.KERNELS:
                    sigs[n] = (("sid",) if roles.KERNELS[n].per_stage else ()) + tuple(a for a, _ in roles.KERNELS[n].args), 0
                elif n in roles.ROLES:
                    sigs[n] = roles.ROLES[n].params, roles.ROLES[n].optional
        else:
            sib = _unit_of_module(module)
            if sib is None:
                raise ContractError(f"{path}: imports from {module}, which is not a unit")
            missing = [n for n in names if n not in sib.provides]
            if missing:
                raise ContractError(f"{path}: imports {missing} from {module}, which does not define it")
            sib_sigs = _signatures(ast.parse(sib.text, sib.path))
            sigs |= {n: sib_sigs[n] for n in names if n in sib_sigs}
    tree = ast.parse(text, path)
    own = _signatures(tree)
    sigs |= own
    _check_calls(path, tree, sigs)
    impl = implementations()
    for fn, (params, optional) in own.items():
        if fn in impl:
            r = roles.ROLES[impl[fn]]
            if params != r.params or optional != r.optional:
                raise ContractError(f"{path}: {fn} implements the role {r.name!r}, whose signature is "
                                    f"({_sig_text(r.params, r.optional)}); {fn} takes ({_sig_text(params, optional)})"
                                    " (vcirun.codegen.roles)")
    check_frame(text, path)
    check_wrappers(tree, path, set(impl))


def check_wrappers(tree: ast.Module, path: str, implementations=()) -> None:
    """A function compiled without numba's Python and C entry wrappers (`no_cpython_wrapper=True,
    no_cfunc_wrapper=True`: a cold build compiles less) is called from compiled code only: a name
    Python calls on a module (roles.ENTRY) or a role's implementation keeps its wrappers."""
    entry = {n for names in roles.ENTRY.values() for n in names} | set(implementations)
    for fn in tree.body:
        if not isinstance(fn, ast.FunctionDef) or fn.name not in entry:
            continue
        for d in fn.decorator_list:
            if isinstance(d, ast.Call) and any(k.arg == "no_cpython_wrapper" for k in d.keywords):
                raise ContractError(f"{path}:{fn.lineno}: {fn.name} is compiled without numba's Python wrapper, "
                                    "but Python calls it (vcirun.codegen.roles ENTRY, or a role's implementation): "
                                    "drop no_cpython_wrapper and no_cfunc_wrapper")


def _sig_text(params, optional) -> str:
    return ", ".join(p + ("=..." if i >= len(params) - optional else "") for i, p in enumerate(params))


def _check_calls(path: str, tree: ast.Module, sigs: dict) -> None:
    """Every call of a declared or unit function passes between its required and its total number
    of arguments (by position or by a parameter's name)."""
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in sigs):
            continue
        params, optional = sigs[node.func.id]
        if any(isinstance(a, ast.Starred) for a in node.args) or any(k.arg is None for k in node.keywords):
            raise ContractError(f"{path}:{node.lineno}: {node.func.id} called with * or **: pass its arguments "
                                "by name or position (the arity check needs them)")
        n = len(node.args) + len(node.keywords)
        unknown = [k.arg for k in node.keywords if k.arg not in params]
        if unknown or not len(params) - optional <= n <= len(params):
            raise ContractError(f"{path}:{node.lineno}: {node.func.id} called with {n} arguments"
                                + (f" (unknown {unknown})" if unknown else "")
                                + f"; it takes ({_sig_text(params, optional)})")


def check_units(units=UNITS) -> None:
    """Every unit, and no name provided by two units (a requirement names one provider)."""
    seen = {}
    for u in tuple(units) + tuple(Unit(r.unit) for r in roles.RESETS.values()):
        check_unit(u)
        for n in u.provides:
            if seen.setdefault(n, u.path) != u.path:
                raise ContractError(f"{n}: defined by both {seen[n]} and {u.path}; rename one")


def check_frame(text: str, filename: str = "<unit>") -> None:
    """The stack-scratch rules of vcirun.codegen.frame on a unit's source: a `scratch*` array is not
    allocated inside a loop (a dynamic alloca grows the frame each pass) or in an inline="always"
    function (numba pastes it into its caller's loops), and is not returned (its memory ends with
    the frame)."""
    from .frame import SCRATCH

    def is_scratch(node):
        return isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in SCRATCH

    for fn in ast.walk(ast.parse(text, filename)):
        if not isinstance(fn, ast.FunctionDef):
            continue
        inline = any(isinstance(k, ast.keyword) and k.arg == "inline" for d in fn.decorator_list
                     if isinstance(d, ast.Call) for k in d.keywords)
        local = set()

        def visit(node, in_loop):
            for child in ast.iter_child_nodes(node):
                if isinstance(child, (ast.FunctionDef, ast.Lambda)):
                    continue
                if is_scratch(child):
                    where = f"{filename}:{child.lineno} ({fn.name})"
                    if inline:
                        raise ContractError(f"{where}: {child.func.id} in an inline function (vcirun.codegen.frame)")
                    if in_loop:
                        raise ContractError(f"{where}: {child.func.id} inside a loop (vcirun.codegen.frame): "
                                            "allocate it before the loop")
                if isinstance(child, ast.Assign) and is_scratch(child.value):
                    local.update(t.id for t in child.targets if isinstance(t, ast.Name))
                if isinstance(child, ast.Return) and child.value is not None:
                    vals = child.value.elts if isinstance(child.value, ast.Tuple) else [child.value]
                    for v in vals:
                        if isinstance(v, ast.Name) and v.id in local:
                            raise ContractError(f"{filename}:{child.lineno} ({fn.name}): returns the stack array "
                                                f"{v.id} (vcirun.codegen.frame): its memory ends with the frame")
                visit(child, in_loop or isinstance(child, (ast.For, ast.While)))

        visit(fn, False)


def check_generated(text: str, ks) -> None:
    """The generated part of a module defines every GENERATED name of its kernel set's parts."""
    defined, _ = source_names(text, "<generated>")
    want = {n for part in generated_parts(ks) for n in GENERATED[part]}
    if want - defined:
        raise ContractError(f"generated kernels for {ks.key_text()} lack {sorted(want - defined)} "
                            "(vcirun.codegen.roles)")


def standalone_source(paths) -> str:
    """The bodies of units that need no generated name (e.g. collision/impact_law.py with the
    linear algebra it calls), with the units they import, in dependency order: a module of its own."""
    order: list[Unit] = []

    def add(u: Unit):
        if u in order:
            return
        for module, names in u.imports.items():
            if module == ROLES_MODULE:
                raise ContractError(f"{u.path}: imports {list(names)} from {ROLES_MODULE}: not standalone")
            add(_unit_of_module(module))
        order.append(u)

    for p in paths:
        add(Unit(p))
    for u in order:
        check_unit(u)
    return "\n\n".join(u.body for u in order) + "\n"


def assemble(generated: str, ks, check_package: bool = True) -> str:
    """generated part + the selected units + the bindings, checked: the module text. check_package
    False checks only the units outside the package (a reset registered from outside): the
    interpreted tier runs the units as Python, where a breach of the contract raises by itself, and
    the package's units are checked by every compiled build and the test suite."""
    check_generated(generated, ks)
    selected = select_units(ks)
    for u in selected:
        if check_package or Path(u.path).is_absolute():
            check_unit(u)
    parts = [generated] + [u.body for u in selected]
    parts += [f"{role} = {target}" for role, target in bindings(ks).items()]
    return "\n\n".join(parts) + "\n"
