"""The contract between the generated kernels of a module and the numba source units (issue 16).

A compiled module is one file: generated kernels (vcirun.codegen.derive) + the numba source units
of vcirun/maps and vcirun/collision + the role bindings `full`, `partial`, `reset`,
`modified_energy`. The units call names only the generated part or other units define; this file
is where those names are written down:

- UNITS: each unit's file, the names it provides and the names it requires. `check_unit` holds
  each declaration against the unit's source (symtable: the functions and constants it defines, the
  global names its code reads), so a declaration cannot drift from the code.
- GENERATED: what the generator emits for each part of a kernel set (the system kernels always; the
  step kernels of the full map's discrete Lagrangians; R^VCI's energy gradient; the modified
  Hamiltonian's kernels; the record's index and status constants). `check_generated` holds it
  against the generated text.
- PARTIALS, RESETS, MODIFIED_ENERGY: the role bindings, chosen by the method's data
  (vcirun.methods.table.Method.partial / .reset / .mh_order), never by an `if` in a unit.
- ENTRY: the names Python calls on a module (vcirun.run.api, vcirun.reference, baselines, verify).

`select_units(ks)` includes every unit whose requirements the generated part, the bindings and the
other included units meet (so a CVA module has reset_cva but not reset_vci, which needs ld_Edv),
and raises ContractError naming the missing symbol when an entry point or a binding cannot be met.
No sympy here: the selection runs on the warm path too (the cache key hashes the selected units).
"""
from __future__ import annotations

import ast
import builtins
import functools
import symtable
from dataclasses import dataclass
from pathlib import Path

from ..core import record

PKG = Path(__file__).resolve().parent.parent


class ContractError(ValueError):
    """A module cannot be assembled: a unit requires a name nothing provides (or a declaration does
    not match its unit's code)."""


@dataclass(frozen=True)
class Unit:
    path: str          # relative to the vcirun package
    provides: tuple    # names other units and Python may call
    requires: tuple    # names it reads from the generated part or other units

    @property
    def text(self) -> str:
        return (PKG / self.path).read_text()


# the impact law of Moreau (collision/impact_law.py: pure, no generated names)
IMPACT_LAW_PROVIDES = ("impact_law", "LCP_MAX_CONTACTS", "LCP_UNIQUE", "LCP_SINGULAR_UNIQUE", "LCP_MIN_NORM",
                       "LCP_INFEASIBLE", "LCP_BAD_INPUT", "LCP_RANK_TOL", "LCP_FEAS_TOL", "LCP_SYM_TOL")

UNITS = (
    Unit("maps/linalg.py", provides=("solve_small", "norm_inf", "copy_into", "set_row"), requires=()),
    Unit("maps/dynamics.py",
         provides=("velocity_from", "velocity_guess", "hamiltonian", "hamilton_rhs", "dynamics_rhs", "force_power",
                   "gdot", "cva_lambda", "mass_matrix_ok"),
         requires=("NDOF", "FORCED", "sys_M", "sys_V", "sys_dHq", "sys_dphi", "sys_force", "solve_small",
                   "copy_into")),
    Unit("maps/steps.py", provides=("guess_from_node", "explicit_step", "ld_step", "ld_partial"),
         requires=("NDOF", "NODE_LEN", "FULL_STAGES", "FULL_FRACS", "ld_PmJc", "ld_Ppc", "ld_Ed", "sys_node",
                   "sys_node_M", "velocity_from", "solve_small", "copy_into")),
    Unit("maps/gauss.py",
         provides=("GAUSS_A", "GAUSS_B", "GAUSS_C", "GAUSS_D", "MH_U_TOL", "MH_U_MAXIT", "mh_guess", "mh_solve",
                   "mh_terms", "mh_energy", "mh_gradient", "mh_field", "gauss_partial"),
         requires=("NDOF", "FORCED", "MH_ORDER", "MH_M", "MH_NSTAGE", "MH_FLOW_S", "mh_FA", "mh_value", "mh_grad",
                   "mh_hess", "sys_force", "sys_force_jac", "velocity_guess", "solve_small")),
    Unit("maps/held.py",
         provides=("contact_forces", "project_momentum", "held_stage", "held_step", "normal_acceleration"),
         requires=("NDOF", "NCON", "NODE_LEN", "FULL_STAGES", "FULL_FRACS", "dynamics_rhs", "sys_Mdotv", "sys_ddphis",
                   "sys_dphis", "sys_phis", "sys_M", "sys_node", "ld_PmJc", "ld_Ppc", "ld_Ed", "velocity_guess",
                   "solve_small", "copy_into")),
    Unit("collision/events.py",
         provides=("N_SCAN", "N_MODEL", "step_admissible", "partial_map", "collision_time", "search_collision"),
         requires=("NCON", "partial", "held_step", "sys_phi", "sys_phis", "gap", "gap_slope", "touching_mask",
                   "unmask_penetrating")),
    Unit("collision/impact_law.py", provides=IMPACT_LAW_PROVIDES, requires=()),
    Unit("collision/impact.py",
         provides=("impact_direction", "touch_tolerance", "gap", "gap_slope", "normal_velocities", "touching_mask",
                   "unmask_penetrating"),
         requires=("NDOF", "NCON", "sys_restitution", "sys_phi", "sys_phis", "sys_dphis", "sys_M", "cva_lambda",
                   "impact_law", "solve_small", "gdot")),
    Unit("collision/reset_cva.py", provides=("reset_cva",), requires=("NDOF",)),
    Unit("collision/reset_vci.py", provides=("reset_vci",),
         requires=("NDOF", "NODE_LEN", "FORCED", "VCI_STAGE", "FORCE_A", "FORCE_B", "velocity_guess",
                   "sys_node", "ld_PmJc", "ld_Ed", "ld_Edv", "sys_force", "sys_force_jac", "force_power",
                   "solve_small")),
    Unit("collision/reset_mcva.py", provides=("MH_RESET_ETOL", "reset_mcva"),
         requires=("NDOF", "MH_M", "mh_guess", "mh_gradient")),
    Unit("collision/algorithm1.py", provides=("integrate", "no_modified_energy", "initially_held"),
         requires=("NDOF", "NCON", "PARTIAL_IS_FULL", "full", "reset", "modified_energy", "search_collision",
                   "step_admissible", "impact_direction", "hamiltonian", "copy_into", "set_row", "held_step",
                   "contact_forces", "project_momentum", "normal_acceleration", "normal_velocities",
                   "touch_tolerance", "sys_phi", "sys_phis", "sys_restitution", "FORCED", "force_power", "velocity_guess")
         + tuple(f.index_name for f in record.FIELDS) + tuple(f"I_{c.upper()}" for c in record.COUNTERS)
         + tuple(f"S_{s.upper()}" for s in record.SETTINGS) + tuple(f"ST_{n.upper()}" for n, _ in record.STATUSES)),
)
UNIT = {u.path: u for u in UNITS}

# what vcirun.codegen.derive emits, per part of a kernel set
GENERATED = {
    "system": ("NDOF", "NCON", "FORCED", "NODE_LEN", "sys_M", "sys_V", "sys_phi", "sys_dphi", "sys_phis",
               "sys_dphis", "sys_ddphis", "sys_Mdotv", "sys_restitution", "sys_dHq", "sys_node", "sys_node_M",
               "sys_force", "sys_force_jac"),
    "record": tuple(ln.split(" = ")[0] for ln in record.module_constants().splitlines()),
    "steps": ("FULL_STAGES", "FULL_FRACS", "FORCE_A", "FORCE_B", "VCI_STAGE", "PARTIAL_IS_FULL", "ld_PmJ", "ld_Pp",
              "ld_PmJc", "ld_Ppc", "ld_Ed"),
    "vci": ("ld_Edv",),
    "modified": ("MH_ORDER", "MH_M", "MH_NSTAGE", "MH_FLOW_S", "mh_FA", "mh_value", "mh_grad", "mh_hess"),
}

# role bindings: the method's data -> the unit function bound to the role
PARTIALS = {"ld": "ld_partial", "gauss": "gauss_partial"}
RESETS = {"cva": "reset_cva", "vci": "reset_vci", "mcva": "reset_mcva"}
MODIFIED_ENERGY = {False: "no_modified_energy", True: "mh_energy"}

# names Python calls on a module
SYSTEM_ENTRY = ("hamiltonian", "hamilton_rhs", "dynamics_rhs", "force_power", "gdot", "cva_lambda",
                "mass_matrix_ok", "sys_M", "sys_phi", "sys_dphi", "sys_phis", "sys_dphis", "sys_restitution",
                "impact_direction", "gap", "touching_mask", "sys_ddphis", "sys_Mdotv")
METHOD_ENTRY = SYSTEM_ENTRY + ("integrate", "collision_time", "ld_step")


def generated_parts(ks) -> tuple:
    """The GENERATED parts a kernel set's module holds."""
    parts = ["system", "record"]
    if ks.full_stages:
        parts.append("steps")
    if ks.vci_stage:
        parts.append("vci")
    if ks.modified is not None:
        parts.append("modified")
    return tuple(parts)


def bindings(ks) -> dict:
    """{role: bound name} of a kernel set (empty for the system-only kernel set)."""
    if not ks.full_stages:
        return {}
    return {"full": "ld_step", "partial": PARTIALS[ks.partial], "reset": RESETS[ks.reset],
            "modified_energy": MODIFIED_ENERGY[ks.modified is not None]}


def entry_points(ks) -> tuple:
    return METHOD_ENTRY if ks.full_stages else SYSTEM_ENTRY


def select_units(ks) -> list[Unit]:
    """The units of a kernel set's module, in table order (see the module docstring)."""
    return list(_select(ks))


@functools.lru_cache(maxsize=256)
def _select(ks) -> tuple:
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
        for u in UNITS:
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
            raise ContractError(_explain(name, binds, avail, ks))
    return tuple(u for u in UNITS if u in included)


def _explain(name, binds, avail, ks) -> str:
    """Why `name` is not available: the unit that would provide it and its first unmet requirement."""
    target = binds.get(name, name)
    what = f"role {name!r} -> {target}" if name in binds else f"{name}"
    for u in UNITS:
        if target in u.provides:
            missing = [r for r in u.requires if r not in avail and r not in u.provides]
            return (f"module for kernel set {ks.key_text()}: {what} is provided by {u.path}, which requires "
                    f"{missing[0]}: neither the generated kernels ({', '.join(generated_parts(ks))}) nor an "
                    f"included unit provide it")
    return f"module for kernel set {ks.key_text()}: nothing provides {what}"


# --- declarations held against the code ------------------------------------------------------------

_BUILTINS = set(dir(builtins))


def source_names(text: str, filename: str = "<unit>") -> tuple[set, set]:
    """(defined, read): the module-level names a source defines (functions, assignments, imports) and
    the global names its code reads (module level and inside every function), by symtable."""
    top = symtable.symtable(text, filename, "exec")
    defined, imported, read = set(), set(), set()
    for s in top.get_symbols():
        if s.is_imported():
            imported.add(s.get_name())
        elif s.is_assigned():
            defined.add(s.get_name())
        if s.is_referenced() and not s.is_assigned() and not s.is_imported():
            read.add(s.get_name())

    def walk(tab):
        for child in tab.get_children():
            for s in child.get_symbols():
                if s.is_referenced() and (s.is_global() or s.is_free()) and not s.is_local():
                    read.add(s.get_name())
            walk(child)

    walk(top)
    read -= defined | imported | _BUILTINS
    return defined, read


def check_unit(u: Unit) -> None:
    """The declaration of `u` against its source: it defines every name it provides, defines no
    public name it does not declare, and reads no global name it does not require."""
    defined, read = source_names(u.text, u.path)
    public = {n for n in defined if not n.startswith("_")}
    if set(u.provides) - defined:
        raise ContractError(f"{u.path}: declared to provide {sorted(set(u.provides) - defined)}, which it does not define")
    if public - set(u.provides):
        raise ContractError(f"{u.path}: defines {sorted(public - set(u.provides))}, not in its declaration "
                            "(vcirun.codegen.units.UNITS)")
    if read - set(u.requires):
        raise ContractError(f"{u.path}: uses {sorted(read - set(u.requires))} without declaring it "
                            "(vcirun.codegen.units.UNITS: requires)")
    if set(u.requires) - read:
        raise ContractError(f"{u.path}: declares {sorted(set(u.requires) - read)} as required but never uses it")
    check_frame(u.text, u.path)


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
                            "(vcirun.codegen.units.GENERATED)")


def assemble(generated: str, ks) -> str:
    """generated part + the selected units + the bindings, checked: the module text."""
    check_generated(generated, ks)
    units = select_units(ks)
    for u in units:
        check_unit(u)
    parts = [generated] + [u.text for u in units]
    parts += [f"{role} = {target}" for role, target in bindings(ks).items()]
    return "\n\n".join(parts) + "\n"
