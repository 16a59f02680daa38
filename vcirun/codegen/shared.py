"""The shared core: the numeric units compiled once per kernel-set family, not once per scene (issue 21).

A *specialized* module (vcirun.codegen.units.assemble) is one scene's generated kernels + every unit
of vcirun/maps and vcirun/collision, compiled together: numba types, lowers and optimises the
scene-independent loop again for every scene, 90 % of a cold build (docs/performance.md, *Cold
builds*). The shared build splits it in two:

- the **scene module**: the generated part alone (the kernels and their constants), each kernel
  compiled for the one signature of the ABI tables below (`SYSTEM_ABI`, `STAGE_ABI`, `VCI_ABI`,
  `MODIFIED_ABI`; a few seconds);
- the **core**: the units of the kernel set with a stub for every kernel the units call, which calls
  the scene's compiled kernel by address (vcirun.codegen.kcall), and every other name the units read
  from the generated part (`SCALARS`: the scene's sizes and flags; `ARRAYS`: the kernel set's stage
  data) read from the same slot table at run time. Its text depends only on which units and role
  bindings the kernel set has (and MH_FLOW_S, a module-level choice of maps/gauss.py), not on the
  scene or the Ld: numba caches it once on disk and every scene of the family loads it.

`link` joins the two into one module object with the names of a specialized module (the contract of
vcirun.codegen.units: ENTRY points, constants, kernels), whose core functions install the scene's
slot table before they run. The table is process-global: calls into the core from several threads
at once are serialised by a lock.

What the core loses against the specialized build: the kernels are not inlined into the loop (an
indirect call each), and NDOF is not a compile-time constant (`core_source(ks, ndof=n)` makes it
one, VCIRUN_CORE_NDOF=fixed); measured in docs/performance.md, *The shared build*.
"""
from __future__ import annotations

import re
import threading
import types as pytypes

import numpy as np

from ..core import record
from . import units
from .kernel_set import KernelSet

# What the units read from the generated part besides kernels, as run-time slot values: the scene's
# sizes, and the kernel set's stage data (so that every kernel set with the same units and bindings
# shares one core: CVA on SVC, on SE1 + SE2, or a composition of 17 stages). Booleans are 0/1.
SCALARS = ("NDOF", "NCON", "NODE_LEN", "MH_M", "FORCED", "PARTIAL_IS_FULL", "VCI_STAGE", "MH_ORDER", "MH_NSTAGE")
BOOLEANS = ("FORCED", "PARTIAL_IS_FULL")
ARRAYS = (("FULL_STAGES", "i8"), ("FULL_FRACS", "f8"), ("FORCE_A", "f8"), ("FORCE_B", "f8"))  # (address, length)
MAX_STAGE_KERNELS = 4   # distinct explicit Lds of one full map (SE1 + SE2 is 2; compositions repeat one)

# kernel name -> (return value giving the type, argument spec of vcirun.codegen.kcall)
SYSTEM_ABI = {
    "sys_M": ("0", "aab"), "sys_V": ("0.0", "aa"), "sys_phi": ("0.0", "aa"), "sys_dphi": ("0", "aaa"),
    "sys_phis": ("0", "aaa"), "sys_dphis": ("0", "aab"), "sys_ddphis": ("0", "aaaa"), "sys_Mdotv": ("0", "aaaa"),
    "sys_restitution": ("0", "aa"), "sys_dHq": ("0", "aaaa"), "sys_node": ("0", "aaa"), "sys_node_M": ("0", "ab"),
    "sys_force": ("0", "aafaa"), "sys_force_jac": ("0", "aafabb"),
}
# per explicit stage (the units call ld_X(sid, ...), the scene defines <LD>_X(...))
STAGE_ABI = {"PmJc": ("0", "aaffaaab"), "Ppc": ("0", "aaffaaaa"), "Ed": ("0.0", "aafa")}
STAGE_ARGS = {"PmJc": "q0, v, h, t, prm, c, r, J", "Ppc": "q0, v, h, t, prm, c, out, cn", "Ed": "q0, v, h, prm"}
VCI_ABI = ("0", "aafaa")   # <LD>_Edv(q0, v, h, prm, out), called as ld_Edv(sid, q0, v, h, prm, out)
MODIFIED_ABI = {"mh_FA": ("0", "aaafaab"), "mh_value": ("0.0", "aaabfaa"), "mh_grad": ("0.0", "aaabfaa"),
                "mh_hess": ("0", "aaabfab")}
_ARGS = {"sys_M": "q, prm, out", "sys_V": "q, prm", "sys_phi": "q, prm", "sys_dphi": "q, prm, out",
         "sys_phis": "q, prm, out", "sys_dphis": "q, prm, out", "sys_ddphis": "q, v, prm, out",
         "sys_Mdotv": "q, v, prm, out", "sys_restitution": "prm, out", "sys_dHq": "q, x, prm, out",
         "sys_node": "q, prm, c", "sys_node_M": "c, A", "sys_force": "q, qd, t, prm, out",
         "sys_force_jac": "q, qd, t, prm, fq, fv", "mh_FA": "q, p, u, h, prm, F, A",
         "mh_value": "q, p, u, W, h, prm, terms", "mh_grad": "q, p, u, W, h, prm, grad",
         "mh_hess": "q, p, u, W, h, prm, hess"}

# The shape of each array argument, in the scene module's constants (NPRM: the parameter count).
# A kernel is called by address with the arrays' data pointers only (numba's array ABI passes seven
# words per array: 8.2 ns against 3.4 ns per 8-array call, measured); the scene's wrapper `_p_<name>`
# rebuilds the arrays with these shapes (carray) and calls the kernel, inlined into it.
_SHAPES = {"q": "(NDOF,)", "v": "(NDOF,)", "q0": "(NDOF,)", "x": "(NDOF,)", "qd": "(NDOF,)", "p": "(NDOF,)",
           "r": "(NDOF,)", "prm": "(NPRM,)", "c": "(NODE_LEN,)", "cn": "(NODE_LEN,)", "J": "(NDOF, NDOF)",
           "fq": "(NDOF, NDOF)", "fv": "(NDOF, NDOF)", "u": "(MH_M,)", "W": "(MH_M, MH_M)", "F": "(MH_M,)",
           "terms": "(MH_ORDER,)", "grad": "(2 * NDOF,)", "hess": "(2 * NDOF, 2 * NDOF)"}
_OUT_SHAPES = {"sys_M": "(NDOF, NDOF)", "sys_dphi": "(NDOF,)", "sys_phis": "(NCON,)", "sys_dphis": "(NCON, NDOF)",
               "sys_ddphis": "(NCON,)", "sys_Mdotv": "(NDOF,)", "sys_restitution": "(NCON,)", "sys_dHq": "(NDOF,)",
               "sys_force": "(NDOF,)", "Ppc": "(NDOF,)", "Edv": "(NDOF,)"}
_A_SHAPES = {"sys_node_M": "(NDOF, NDOF)", "mh_FA": "(MH_M, MH_M)"}


def _shape(kernel: str, arg: str) -> str:
    if arg == "out":
        return _OUT_SHAPES[kernel]
    if arg == "A":
        return _A_SHAPES[kernel]
    return _SHAPES[arg]


def _wrapper(kernel: str, attr: str, args: str, spec: str) -> list[str]:
    names = [a.strip() for a in args.split(",")]
    call = ", ".join(f"carray({a}, {_shape(kernel, a)})" if c in "ab" else a for a, c in zip(names, spec))
    return ['@njit(cache=True, nogil=True, error_model="numpy")', f"def _p_{attr}({args}):",
            f"    return {attr}({call})", ""]


def pointer_wrappers(ks: KernelSet) -> str:
    """The scene module's `_p_<kernel>` wrappers of a kernel set (vcirun.codegen.derive.scene_source)."""
    lines = ["from numba import carray", ""]
    for name, kind, ret, spec in LAYOUT:
        if kind != "kernel":
            continue
        attr = kernel_attr(name, ks)
        if attr is None:
            continue
        base = name.rsplit("_", 1)[0] if name not in SYSTEM_ABI and name not in MODIFIED_ABI else name
        args = _ARGS.get(base) or (STAGE_ARGS.get(base) if base in STAGE_ABI else "q0, v, h, prm, out")
        lines += _wrapper(base, attr, args, spec)
    return "\n".join(lines)


SCENE_MARK = "# vcirun scene module"   # first line of a scene module's file (vcirun.codegen.build)

_DECO = '@njit(cache=True, nogil=True, error_model="numpy", inline="always")'


def _layout() -> list[tuple]:
    """The slot table, the same for every kernel set: [(slot name, kind, ret, spec)]; kind "scalar",
    "array" (two slots: address, length) or "kernel"."""
    out = [(s, "scalar", None, None) for s in SCALARS]
    for name, _ in ARRAYS:
        out += [(name, "array", None, None), (name + ".len", "array_len", None, None)]
    out += [(k, "kernel", r, sp) for k, (r, sp) in SYSTEM_ABI.items()]
    for kind, (r, sp) in STAGE_ABI.items():
        out += [(f"{kind}_{sid}", "kernel", r, sp) for sid in range(MAX_STAGE_KERNELS)]
    out.append(("Edv", "kernel", *VCI_ABI))
    out += [(k, "kernel", r, sp) for k, (r, sp) in MODIFIED_ABI.items()]
    return out


LAYOUT = _layout()
SLOT = {name: i for i, (name, *_) in enumerate(LAYOUT)}


def kernel_attr(slot_name: str, ks: KernelSet) -> str | None:
    """The scene module's name for a kernel slot (None: the kernel set has no such kernel)."""
    kind, _, sid = slot_name.rpartition("_")
    if slot_name in SYSTEM_ABI or slot_name in MODIFIED_ABI:
        return slot_name if (slot_name in SYSTEM_ABI or ks.modified is not None) else None
    if slot_name == "Edv":
        return f"{ks.vci_stage}_Edv" if ks.vci_stage else None
    names = ks.explicit_names if ks.full_stages else ()
    return f"{names[int(sid)]}_{kind}" if int(sid) < len(names) else None


def _stubs(ks: KernelSet) -> str:
    lines = []
    for k, (r, sp) in SYSTEM_ABI.items():
        lines += [_DECO, f"def {k}({_ARGS[k]}):", f"    return kcall(slot({SLOT[k]}), {r}, {sp!r}, ({_ARGS[k]},))", ""]
    if ks.full_stages:
        for kind, (r, sp) in STAGE_ABI.items():
            a = STAGE_ARGS[kind]
            lines += [_DECO, f"def ld_{kind}(sid, {a}):",
                      f"    return kcall(slot({SLOT[kind + '_0']} + sid), {r}, {sp!r}, ({a},))", ""]
    if ks.vci_stage:
        a = "q0, v, h, prm, out"
        lines += [_DECO, f"def ld_Edv(sid, {a}):",
                  f"    return kcall(slot({SLOT['Edv']}), {VCI_ABI[0]}, {VCI_ABI[1]!r}, ({a},))", ""]
    if ks.modified is not None:
        for k, (r, sp) in MODIFIED_ABI.items():
            lines += [_DECO, f"def {k}({_ARGS[k]}):", f"    return kcall(slot({SLOT[k]}), {r}, {sp!r}, ({_ARGS[k]},))", ""]
    for name, kind in (("_slot_i8s", "i8"), ("_slot_f8s", "f8")):   # a run-time array: carray over (address, length)
        lines += [_DECO, f"def {name}(k):", f"    return carray({kind}ptr(slot(k)), (slot(k + 1),))", ""]
    return "\n".join(lines)


def _runtime_names(fixed: dict) -> dict:
    sub = {s: (f"(slot({SLOT[s]}) != 0)" if s in BOOLEANS else f"slot({SLOT[s]})") for s in SCALARS}
    sub |= {a: f"_slot_{kind}s({SLOT[a]})" for a, kind in ARRAYS}
    return {k: v for k, v in sub.items() if k not in fixed}


_NAME_RE = re.compile(r"(?<![\w.])(" + "|".join(list(SCALARS) + [a for a, _ in ARRAYS]) + r")\b")


def _read_at_run_time(text: str, fixed: dict) -> str:
    """The unit's source with each name of SCALARS and ARRAYS read from the slot table (NDOF -> slot(0),
    FORCED -> (slot(4) != 0), FULL_FRACS -> _slot_f8s(11)); a name in `fixed` stays a module constant."""
    sub = _runtime_names(fixed)
    return _NAME_RE.sub(lambda m: sub.get(m.group(0), m.group(0)), text)


HEADER = """# Generated by vcirun.codegen.shared: do not edit. The shared core of one kernel set: the numeric
# units with stubs that call a scene's kernels by address (vcirun.codegen.kcall).
import math
import numpy as np
from numba import carray, njit
from vcirun.codegen.kcall import f8ptr, i8ptr, kcall, slot
"""


def core_source(ks: KernelSet, ndof: int | None = None) -> str:
    """The core's module text for a kernel set: its units and bindings, with stubs for the kernels and
    the slot reads for the rest; checked against the unit contract like a specialized module.
    It depends on the kernel set only through which units and bindings it has (and the Gauss flow's
    stage count, a module-level choice of maps/gauss.py): one core serves CVA on every Ld and
    composition. ndof None: NDOF is read at run time (one core for every scene); an int: a
    compile-time constant (one core per n; measured in docs/performance.md)."""
    fixed = {} if ndof is None else {"NDOF": int(ndof)}
    consts = "".join(f"{k} = {v}\n" for k, v in fixed.items())
    if ks.modified is not None:
        consts += f"MH_FLOW_S = {ks.modified[2] // 2}\n"
    stub_text = "\n\n".join([consts, record.module_constants(), _stubs(ks)])
    declared = "\n".join(f"{s} = 0" for s in list(SCALARS) + [a for a, _ in ARRAYS])  # the contract check only
    units.check_generated(declared + "\n" + stub_text + "\nld_PmJ = ld_Pp = 0\n", ks)
    parts = [HEADER, stub_text]
    for u in units.select_units(ks):
        units.check_unit(u)
        parts.append(_read_at_run_time(u.text, fixed))
    parts += [f"{role} = {target}" for role, target in units.bindings(ks).items()]
    return "\n\n".join(parts) + "\n"


# --- linking a scene module to a core ---------------------------------------------------------------

_LOCK = threading.RLock()
_CURRENT = [None]


class _Entry:
    """A core function as the linked module exposes it: installs the scene's slot table, then calls."""

    __slots__ = ("_fn", "_scene")

    def __init__(self, fn, scene):
        self._fn, self._scene = fn, scene

    def __call__(self, *args):
        # the kernel ABI takes C-contiguous arrays: a strided argument from Python (e.g. a column of
        # scipy's finite-difference Jacobian) goes through a contiguous copy, written back after
        back = []
        for i, a in enumerate(args):
            if isinstance(a, np.ndarray) and not a.flags.c_contiguous:
                back.append((a, np.ascontiguousarray(a)))
                args = args[:i] + (back[-1][1],) + args[i + 1:]
        with _LOCK:
            if _CURRENT[0] is not self._scene:
                self._scene.install()
            out = self._fn(*args)
        for a, c in back:
            if a.flags.writeable:
                a[...] = c
        return out

    def __getattr__(self, name):
        return getattr(self._fn, name)


class SceneSlots:
    """The slot values of one scene's module: its sizes and stage data, and the addresses of its
    compiled kernels (each compiled here for the one signature of the ABI tables)."""

    def __init__(self, scene_mod, ks: KernelSet):
        from numba import types as nbtypes

        if len(ks.explicit_names) > MAX_STAGE_KERNELS:
            raise units.ContractError(f"{ks.key_text()}: {len(ks.explicit_names)} distinct explicit Lds, the shared "
                                      f"core has slots for {MAX_STAGE_KERNELS} (vcirun.codegen.shared)")
        self.arrays = {}
        self.values = []
        for name, kind, ret, spec in LAYOUT:
            if kind == "scalar":
                self.values.append(int(getattr(scene_mod, name, 0)))
            elif kind == "array":
                dtype = np.int64 if dict(ARRAYS)[name] == "i8" else np.float64
                a = np.ascontiguousarray(getattr(scene_mod, name, np.zeros(0)), dtype=dtype)
                self.arrays[name] = a   # kept alive with the table
                self.values += [a.ctypes.data, a.shape[0]]
            elif kind == "kernel":
                attr = kernel_attr(name, ks)
                self.values.append(0 if attr is None else _address(getattr(scene_mod, "_p_" + attr), attr, ret,
                                                                  spec, nbtypes))

    def install(self):
        from .kcall import install

        install(self.values)
        _CURRENT[0] = self


def _address(disp, attr, ret, spec, nbtypes) -> int:
    """The machine address of the wrapper `disp` of kernel `attr`, compiled for the ABI's signature
    (data pointers for arrays; numba's calling convention)."""
    from .kcall import POINTER_TYPES

    sig = tuple(POINTER_TYPES[c] for c in spec)
    disp.compile(sig)
    cres = disp.overloads[sig]
    want = nbtypes.float64 if ret == "0.0" else nbtypes.int64
    if nbtypes.unliteral(cres.signature.return_type) != want:
        raise units.ContractError(f"{attr}: returns {cres.signature.return_type}, the kernel ABI "
                                  f"(vcirun.codegen.shared) says {want}")
    return cres.library.get_pointer_to_function(cres.fndesc.llvm_func_name)


def link(name: str, scene_mod, core_mod, ks: KernelSet):
    """One module object with a specialized module's names: the scene's kernels and constants, the
    core's functions bound to this scene's slot table."""
    scene = SceneSlots(scene_mod, ks)
    mod = pytypes.ModuleType(name)
    mod.__file__ = getattr(scene_mod, "__file__", None)
    for k, v in vars(core_mod).items():
        if k.startswith("__"):
            continue
        mod.__dict__[k] = _Entry(v, scene) if hasattr(v, "py_func") else v
    for k, v in vars(scene_mod).items():
        if not k.startswith("__"):
            mod.__dict__[k] = v   # the scene's own kernels and sizes (NDOF, NCON, ...) as compiled there
    mod.__dict__["SHARED_CORE"] = core_mod.__name__
    mod.__dict__["LOCK_KEY"] = "core_" + getattr(core_mod, "CORE_KEY", core_mod.__name__)
    mod.__dict__["SCENE_SLOTS"] = scene
    return mod
