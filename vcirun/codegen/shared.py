"""The shared core: the numeric units compiled once per kernel-set family, not once per scene.

A *specialized* module (vcirun.codegen.units.assemble) is one scene's generated kernels + every unit
of vcirun/maps and vcirun/collision, compiled together: numba types, lowers and optimises the
scene-independent loop again for every scene, 90 % of a cold build (docs/performance.md, *Cold
builds*). The shared build splits it in two:

- the **scene module**: the generated part alone (the kernels and their constants), each kernel
  compiled for the one signature its declaration gives (vcirun.codegen.roles.KERNELS: argument
  kinds and shapes, return type; a few seconds);
- the **core**: the units of the kernel set with a stub for every kernel the units call, which calls
  the scene's compiled kernel by address (vcirun.codegen.kcall), and every other name the units read
  from the generated part (`SCALARS`: the scene's sizes and flags; `ARRAYS`: the kernel set's stage
  data) read from the same slot table at run time. Its text depends only on which units and role
  bindings the kernel set has (and MH_FLOW_S, a module-level choice of maps/gauss.py), not on the
  scene or the Ld: numba caches it once on disk and every scene of the family loads it.

`link` joins the two into one module object with the names of a specialized module (the contract of
vcirun.codegen.roles: ENTRY points, constants, kernels), whose core functions install the scene's
slot table before they run. The table is process-global: calls into the core from several threads
at once are serialised by a lock, except inside `exclusive`, which installs one scene's table and
holds the lock for a block of calls that then run in parallel (vcirun.ensemble's threads).

What the core loses against the specialized build: the kernels are not inlined into the loop (an
indirect call each), and NDOF is not a compile-time constant (`core_source(ks, ndof=n)` makes it
one, VCIRUN_CORE_NDOF=fixed); measured in docs/performance.md, *The shared build*.
"""
from __future__ import annotations

import contextlib
import dataclasses
import functools
import re
import threading
import types as pytypes
from pathlib import Path

import numpy as np

from ..core import record
from . import roles, units
from .kernel_set import KernelSet
from .roles import ContractError

# What the units read from the generated part besides kernels, as run-time slot values (the
# constants of vcirun.codegen.roles with a slot): the scene's sizes, and the kernel set's stage data
# (so that every kernel set with the same units and bindings shares one core: CVA on SVC, on SE1 +
# SE2, or a composition of 17 stages). Booleans are 0/1.
SCALARS = tuple(n for n, c in roles.CONSTANTS.items() if c.slot in ("int", "bool"))
BOOLEANS = tuple(n for n, c in roles.CONSTANTS.items() if c.slot == "bool")
ARRAYS = tuple((n, c.slot) for n, c in roles.CONSTANTS.items() if c.slot in ("i8", "f8"))  # (address, length)
MAX_STAGE_KERNELS = 4   # distinct explicit Lds of one full map (SE1 + SE2 is 2; compositions repeat one)

# The kernels the core calls by address: the declarations of vcirun.codegen.roles with core=True
# (`core_kernels()`: a kernel declared at run time joins at the end). A kernel is called with the
# arrays' data pointers only (numba's array ABI passes seven words per array: 8.2 ns against 3.4 ns
# per 8-array call, measured); the scene's wrapper `_p_<name>` rebuilds the arrays with their
# declared shapes (carray) and calls the kernel, inlined into it.
def core_kernels() -> tuple:
    return tuple(k for k in roles.KERNELS.values() if k.core)


def _stage_slots(k: roles.KernelDecl) -> int:
    """Slots of a per-stage kernel: one per distinct explicit Ld of the full map (part "steps"), or
    one for the single stage the energy gradient is generated for."""
    return MAX_STAGE_KERNELS if k.part == "steps" else 1


def _slot_name(k: roles.KernelDecl, sid: int) -> str:
    if not k.per_stage:
        return k.name
    return f"{k.suffix}_{sid}" if _stage_slots(k) > 1 else k.suffix


def _wrapper(k: roles.KernelDecl, attr: str) -> list[str]:
    call = ", ".join(f"carray({a}, {s.shape})" if s.kind in "ab" else a for a, s in k.args)
    # called by address only: no Python or C entry wrapper is compiled for it
    return ['@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)',
            f"def _p_{attr}({k.arg_names}):",
            f"    return {attr}({call})", ""]


def pointer_wrappers(ks: KernelSet) -> str:
    """The scene module's `_p_<kernel>` wrappers of a kernel set (vcirun.codegen.derive.scene_source)."""
    lines = ["from numba import carray", ""]
    for _, kind, k, sid in layout():
        if kind != "kernel":
            continue
        attr = kernel_attr(k, sid, ks)
        if attr is not None:
            lines += _wrapper(k, attr)
    return "\n".join(lines)


SCENE_MARK = "# vcirun scene module"   # first line of a scene module's file (vcirun.codegen.build)

_DECO = '@njit(cache=True, nogil=True, error_model="numpy", inline="always")'


def layout() -> tuple:
    """The slot table, the same for every kernel set: ((slot name, kind, kernel declaration, stage
    id), ...); kind "scalar", "array" (two slots: address, length) or "kernel". A kernel declared at
    run time takes the next slots (the others keep theirs, so no core's text changes)."""
    return _layout(core_kernels())


@functools.lru_cache(maxsize=8)
def _layout(kernels: tuple) -> tuple:
    from .kcall import NSLOTS

    out = [(s, "scalar", None, None) for s in SCALARS]
    for name, _ in ARRAYS:
        out += [(name, "array", None, None), (name + ".len", "array_len", None, None)]
    for k in kernels:
        out += [(_slot_name(k, sid), "kernel", k, sid) for sid in range(_stage_slots(k) if k.per_stage else 1)]
    if len(out) > NSLOTS:
        raise ContractError(f"the shared core's slot table holds {NSLOTS} slots, the declarations need {len(out)} "
                            "(vcirun.codegen.kcall.NSLOTS)")
    return tuple(out)


def slots() -> dict:
    """{slot name: index} of `layout()`."""
    return {name: i for i, (name, *_) in enumerate(layout())}


def __getattr__(name):   # LAYOUT, SLOT, CORE_KERNELS: the current tables
    if name == "LAYOUT":
        return layout()
    if name == "SLOT":
        return slots()
    if name == "CORE_KERNELS":
        return core_kernels()
    raise AttributeError(name)


def kernel_attr(k: roles.KernelDecl, sid: int, ks: KernelSet) -> str | None:
    """The scene module's name for a kernel slot (None: the kernel set has no such kernel)."""
    if k.part not in units.generated_parts(ks):
        return None
    if not k.per_stage:
        return k.name
    if k.part == "steps":
        names = ks.explicit_names
        return f"{names[sid]}_{k.suffix}" if sid < len(names) else None
    return f"{ks.part(k.part)}_{k.suffix}"   # a per-Ld part (the energy gradient): its Ld's kernel


def _stubs(ks: KernelSet) -> str:
    lines = []
    parts = units.generated_parts(ks)
    slot_of = slots()
    for k in core_kernels():
        if k.part not in parts:
            continue
        a, call = k.arg_names, f"{k.ret_literal}, {k.spec!r}, ({k.arg_names},))"
        if not k.per_stage:
            lines += [_DECO, f"def {k.name}({a}):", f"    return kcall(slot({slot_of[k.name]}), {call}", ""]
        elif _stage_slots(k) > 1:
            lines += [_DECO, f"def {k.name}(sid, {a}):", f"    return kcall(slot({slot_of[_slot_name(k, 0)]} + sid), {call}",
                      ""]
        else:
            lines += [_DECO, f"def {k.name}(sid, {a}):", f"    return kcall(slot({slot_of[_slot_name(k, 0)]}), {call}", ""]
    for name, kind in (("_slot_i8s", "i8"), ("_slot_f8s", "f8")):   # a run-time array: carray over (address, length)
        lines += [_DECO, f"def {name}(k):", f"    return carray({kind}ptr(slot(k)), (slot(k + 1),))", ""]
    return "\n".join(lines)


def _runtime_names(fixed: dict) -> dict:
    slot_of = slots()
    sub = {s: (f"(slot({slot_of[s]}) != 0)" if s in BOOLEANS else f"slot({slot_of[s]})") for s in SCALARS}
    sub |= {a: f"_slot_{kind}s({slot_of[a]})" for a, kind in ARRAYS}
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


# The scene features a core may be compiled for. The *lean* core serves the common scene -- one
# constraint, no generalized force, no declared reset map, no friction -- with these names module
# constants, so numba prunes the branches they decide (the several-contact impact with its Delassus
# matrix and LCP, the forced, mapped and frictional paths) before typing them: the CVA core compiles
# in about 60 % of the time of the general one (docs/performance.md, *Builds*). A frictionless scene
# that is not lean takes the frictionless core (FRICTION compiled in as False: the held steps with
# friction modes, the frictional impact law and the mode events pruned). A lean scene with friction (a
# block on a ramp, a ball on the floor) takes the lean core with FRICTION compiled in as True: its held
# step with friction costs 1.36x the frictionless one's on the lean core, against 1.56x on the general
# core (docs/performance.md, *Friction*). Any other scene with friction takes the general core, which
# reads every flag at run time. Four variants, not one per combination.
LEAN = (("NCON", 1), ("FORCED", False), ("RESET_MAP", False), ("RESET_LAW_FIRST", False), ("FRICTION", False))
LEAN_FRICTION = LEAN[:-1] + (("FRICTION", True),)
FRICTIONLESS = (("FRICTION", False),)
FEATURE_NAMES = {LEAN: "one contact, unforced", LEAN_FRICTION: "one contact with friction, unforced",
                 FRICTIONLESS: "any contacts and forcing, no friction",
                 (): "any contacts, forcing and friction"}


def core_features(ks: KernelSet, ncon: int, forced: bool, reset_map: bool, law_first: bool,
                  friction: bool = False) -> tuple:
    """The features of the core that serves a scene with these constants: LEAN, LEAN_FRICTION,
    FRICTIONLESS or () (general). The system-only set (the exact reference's kernels) too: its impact
    law prunes the same branches (cart-pendulum reference, empty cache: 14.3 s general, 5.0 s lean;
    the same bits)."""
    have = {"NCON": int(ncon), "FORCED": bool(forced), "RESET_MAP": bool(reset_map),
            "RESET_LAW_FIRST": bool(law_first), "FRICTION": bool(friction)}
    for lean in (LEAN, LEAN_FRICTION):
        if dict(lean) == have:
            return lean
    return () if friction else FRICTIONLESS


def scene_features(ks: KernelSet, scene_mod) -> tuple:
    """core_features of a scene module (its generated constants)."""
    return core_features(ks, int(getattr(scene_mod, "NCON", 1)), bool(getattr(scene_mod, "FORCED", False)),
                         bool(getattr(scene_mod, "RESET_MAP", False)), bool(getattr(scene_mod, "RESET_LAW_FIRST", False)),
                         bool(getattr(scene_mod, "FRICTION", False)))


# Resets whose needs differ only in parts a scene may lack (roles.PartDecl.per_scene: R^CVA and R^VCI,
# which differs by the energy gradient) share one core: it holds every such reset of the package's
# table and calls the one of its scene's kernel set, chosen at run time by the scene's RESET_ID (a
# branch per impact costs nothing measurable). CVA and VCI then compile one core between them (the
# quick sweep's cold build: three cores of ~36, 37 and 48 s on two processes made 73 s; two made
# ~50 s). A reset registered from outside the package (its unit an absolute path) gets a core of its
# own, so that registering one changes no other core.


def core_resets(ks: KernelSet) -> tuple:
    """The ResetMap rows one shared core holds for a kernel set, in table order (RESET_ID indexes
    them): its own reset, and the package's resets whose needs differ from it only in parts a scene
    may lack."""
    own = roles.reset_map(ks.reset)
    if Path(own.unit).is_absolute():
        return (own,)

    def fixed(r):
        return {p for p in r.needs if not roles.PARTS[p].per_scene}

    return tuple(r for r in roles.RESETS.values()
                 if r is own or (not Path(r.unit).is_absolute() and fixed(r) == fixed(own)))


def core_kernel_set(ks: KernelSet) -> KernelSet:
    """The kernel set a core is built from: ks with the parts the resets it shares its core with
    need (core_resets; such a part takes the full map's first Ld as its argument, which the core's
    text does not depend on)."""
    if not ks.full_stages:
        return ks
    have = {p for p, _ in ks.parts}
    need = {p for r in core_resets(ks) for p in r.needs} - have
    if not need:
        return ks
    ld = ks.full_stages[0][0]
    add = tuple((p, roles.part_argument(p, ld)) for p in need)
    return dataclasses.replace(ks, parts=tuple(sorted(ks.parts + add, key=lambda pa: list(roles.PARTS).index(pa[0]))))


def _reset_dispatch(resets: tuple) -> str:
    """The role `reset` of a core holding several resets: the scene's (RESET_ID), by its index."""
    sig = ", ".join(roles.ROLES["reset"].params)
    lines = ['@njit(cache=True, nogil=True, error_model="numpy", inline="always")', f"def reset_of_scene({sig}):",
             "    # the scene kernel set's reset, by its index among the core's (core_resets)"]
    for i, r in enumerate(resets[:-1]):
        lines += [f"    if RESET_ID == {i}:", f"        return {r.function}({sig})"]
    lines.append(f"    return {resets[-1].function}({sig})")
    return "\n".join(lines) + "\n"


def core_source(ks: KernelSet, ndof: int | None = None, features: tuple = ()) -> str:
    """The core's module text for a kernel set: its units and bindings, with stubs for the kernels and
    the slot reads for the rest; checked against the unit contract like a specialized module.
    It depends on the kernel set only through which units and bindings it has (and the Gauss flow's
    stage count, a module-level choice of maps/gauss.py): one core serves CVA on every Ld and
    composition. ndof None: NDOF is read at run time (one core for every scene); an int: a
    compile-time constant (one core per n; measured in docs/performance.md). features: LEAN,
    LEAN_FRICTION, FRICTIONLESS or () (core_features): the scene constants compiled in."""
    resets = core_resets(ks) if ks.full_stages else None
    ks = core_kernel_set(ks)
    fixed = dict(features) | ({} if ndof is None else {"NDOF": int(ndof)})
    consts = "".join(f"{k} = {v}\n" for k, v in fixed.items())
    if ks.part("modified") is not None:
        consts += f"MH_FLOW_S = {ks.part('modified')[2] // 2}\n"
    stub_text = "\n\n".join([consts, record.module_constants(), _stubs(ks)])
    # the contract check only: the slot-read names and the scene-only kernels
    declared = [f"{s} = 0" for s in list(SCALARS) + [a for a, _ in ARRAYS]]
    declared += [f"{k.name} = 0" for k in roles.KERNELS.values() if not k.core]
    units.check_generated("\n".join(declared) + "\n" + stub_text + "\n", ks)
    parts = [HEADER, stub_text]
    for u in units.select_units(ks, resets):
        units.check_unit(u)
        parts.append(_read_at_run_time(u.body, fixed))
    binds = units.bindings(ks)
    if resets is not None and len(resets) > 1:   # the role `reset` bound to the scene's choice among them
        parts.append(_read_at_run_time(_reset_dispatch(resets), fixed))
        binds["reset"] = "reset_of_scene"
    parts += [f"{role} = {target}" for role, target in binds.items()]
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
            raise ContractError(f"{ks.key_text()}: {len(ks.explicit_names)} distinct explicit Lds, the shared "
                                      f"core has slots for {MAX_STAGE_KERNELS} (vcirun.codegen.shared)")
        self.arrays = {}
        self.values = []
        for name, kind, k, sid in layout():
            if kind == "scalar":
                self.values.append(int(getattr(scene_mod, name, 0)))
            elif kind == "array":
                dtype = np.int64 if dict(ARRAYS)[name] == "i8" else np.float64
                a = np.ascontiguousarray(getattr(scene_mod, name, np.zeros(0)), dtype=dtype)
                self.arrays[name] = a   # kept alive with the table
                self.values += [a.ctypes.data, a.shape[0]]
            elif kind == "kernel":
                attr = kernel_attr(k, sid, ks)
                self.values.append(0 if attr is None else _address(getattr(scene_mod, "_p_" + attr), attr, k, nbtypes))

    def install(self):
        from .kcall import install

        install(self.values)
        _CURRENT[0] = self


def _address(disp, attr, k: roles.KernelDecl, nbtypes) -> int:
    """The machine address of the wrapper `disp` of kernel `attr`, compiled for the ABI's signature
    (data pointers for arrays; numba's calling convention)."""
    from .kcall import POINTER_TYPES

    sig = tuple(POINTER_TYPES[c] for c in k.spec)
    disp.compile(sig)
    cres = disp.overloads[sig]
    want = nbtypes.float64 if k.returns == "float" else nbtypes.int64
    if nbtypes.unliteral(cres.signature.return_type) != want:
        raise ContractError(f"{attr}: returns {cres.signature.return_type}, the kernel ABI "
                                  f"(vcirun.codegen.shared) says {want}")
    return cres.library.get_pointer_to_function(cres.fndesc.llvm_func_name)


def link(name: str, scene_mod, core_mod, ks: KernelSet):
    """One module object with a specialized module's names: the scene's kernels and constants, the
    core's functions bound to this scene's slot table."""
    for k, v in getattr(core_mod, "FEATURES", ()):
        if getattr(scene_mod, k, None) != v:   # a core compiled for other scene constants
            raise ContractError(f"{name}: the scene has {k} = {getattr(scene_mod, k, None)}, its core "
                                f"{getattr(core_mod, 'CORE_KEY', core_mod.__name__)} was compiled for {k} = {v}")
    scene = SceneSlots(scene_mod, ks)
    mod = pytypes.ModuleType(name)
    mod.__file__ = getattr(scene_mod, "__file__", None)
    for k, v in vars(core_mod).items():
        if k.startswith("__") or getattr(v, "targetoptions", {}).get("no_cpython_wrapper"):
            continue   # (a function without numba's Python wrapper is called from compiled code only)
        mod.__dict__[k] = _Entry(v, scene) if hasattr(v, "py_func") else v
    for k, v in vars(scene_mod).items():
        if not k.startswith("__"):
            mod.__dict__[k] = v   # the scene's own kernels and sizes (NDOF, NCON, ...) as compiled there
    mod.__dict__["SHARED_CORE"] = core_mod.__name__
    mod.__dict__["LOCK_KEY"] = "core_" + getattr(core_mod, "CORE_KEY", core_mod.__name__)
    mod.__dict__["SCENE_SLOTS"] = scene
    return mod


class _Unlocked:
    """A linked module's names with its core functions called directly (no lock, no table install):
    valid only inside `exclusive`, which holds the lock with this scene's table installed."""

    def __init__(self, mod):
        self._mod = mod

    def __getattr__(self, name):
        v = getattr(self._mod, name)
        v = v._fn if isinstance(v, _Entry) else v
        self.__dict__[name] = v
        return v


@contextlib.contextmanager
def exclusive(mod):
    """The module's functions for calls from several threads at once: a linked module's scene table
    is installed once and the lock held for the block, so the calls inside run in parallel (each
    core function releases the GIL) instead of taking the lock one call at a time. Calls into
    another scene's module from other threads wait for the block to end. A specialized module
    (no slot table) is yielded as it is."""
    scene = getattr(mod, "SCENE_SLOTS", None)
    if scene is None:
        yield mod
        return
    with _LOCK:
        scene.install()
        yield _Unlocked(mod)
