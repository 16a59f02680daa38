"""Calls from the shared core into a scene's kernels by address (vcirun.codegen.shared).

The shared core is numba code compiled once per kernel set and reused by every scene, so it cannot
name a scene's kernels: it reads them, and the scene's sizes, from a slot table, a process-global
int64 array that Python fills for the scene before each call into the core (`install`). Two
intrinsics do it:

- `slot(k)`: the int64 in slot k (a size such as NDOF, or a kernel's address). The table is an
  external LLVM global, bound to a ctypes buffer by `llvmlite.binding.add_symbol`, so code loaded
  from numba's on-disk cache in another process binds to that process's buffer.
- `kcall(addr, ret, spec, args)`: call the numba-compiled function at `addr` (numba's calling
  convention) returning the type of `ret` (0 -> int64, 0.0 -> float64). `spec` is a literal string,
  one letter per argument ('a' 1-d / 'b' 2-d C-contiguous float64 array, 'f' float64, 'i' int64):
  scalars are cast to it, an array of another type is a typing error, and an array is passed as
  its data pointer (`POINTER_TYPES`): the callee is the scene's `_p_<kernel>` wrapper, which
  rebuilds the arrays with the scene's shapes and calls the kernel, the same compiled code as in
  the specialized build.
"""
from __future__ import annotations

import ctypes

from llvmlite import binding, ir
from numba import types
from numba.core import cgutils, errors
from numba.core.callconv import excinfo_t
from numba.extending import intrinsic

SYMBOL = "vcirun_scene_slots"
NSLOTS = 64

SPEC_TYPES = {"a": types.Array(types.float64, 1, "C"), "b": types.Array(types.float64, 2, "C"),
              "f": types.float64, "i": types.int64}
# what the callee (the scene's `_p_<kernel>` wrapper, vcirun.codegen.shared) takes: arrays as data pointers
POINTER_TYPES = {"a": types.CPointer(types.float64), "b": types.CPointer(types.float64),
                 "f": types.float64, "i": types.int64}

_TABLE = (ctypes.c_int64 * NSLOTS)()
binding.add_symbol(SYMBOL, ctypes.addressof(_TABLE))


def install(values) -> None:
    """Fill the slot table (a sequence of at most NSLOTS ints); the rest keeps its old values."""
    for i, v in enumerate(values):
        _TABLE[i] = v


def _table_ptr(builder):
    mod = builder.module
    try:
        gv = mod.get_global(SYMBOL)
    except KeyError:
        gv = ir.GlobalVariable(mod, ir.ArrayType(ir.IntType(64), NSLOTS), name=SYMBOL)
        gv.linkage = "external"
    return gv


@intrinsic
def slot(typingctx, k):
    if not isinstance(k, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        idx = context.cast(builder, args[0], signature.args[0], types.int64)
        ptr = builder.gep(_table_ptr(builder), [ir.Constant(ir.IntType(32), 0), idx])
        return builder.load(ptr)

    return types.int64(k), codegen


@intrinsic
def kcall(typingctx, addr, ret, spec, args):
    if not isinstance(spec, types.StringLiteral) or not isinstance(args, types.BaseTuple):
        return None
    code = spec.literal_value
    if len(code) != len(args.types):
        raise errors.TypingError(f"kcall: spec {code!r} has {len(code)} letters for {len(args.types)} arguments")
    want = tuple(SPEC_TYPES[c] for c in code)
    for i, (c, got) in enumerate(zip(code, args.types)):
        if c in "ab" and types.unliteral(got) != want[i]:
            raise errors.TypingError(f"kcall: argument {i} is {got}, the kernel ABI wants {want[i]}")
    resty = types.unliteral(ret)

    callee = tuple(POINTER_TYPES[c] for c in code)

    def codegen(context, builder, signature, llargs):
        vals = []
        for i, c in enumerate(code):
            v = builder.extract_value(llargs[3], i)
            if c in "ab":   # the array's data pointer (its shape is the scene's, rebuilt by the wrapper)
                vals.append(context.make_array(want[i])(context, builder, v).data)
            else:
                vals.append(context.cast(builder, v, args.types[i], want[i]))
        call_conv = context.call_conv
        fnty = call_conv.get_function_type(resty, callee)
        fptr = builder.inttoptr(llargs[0], fnty.as_pointer())
        retty = call_conv.get_return_type(resty).pointee
        retvaltmp = cgutils.alloca_once(builder, retty)
        builder.store(cgutils.get_null_value(retty), retvaltmp)
        excinfoptr = cgutils.alloca_once(builder, ir.PointerType(excinfo_t), name="excinfo")
        realargs = [retvaltmp, excinfoptr] + list(call_conv._get_arg_packer(callee).as_arguments(builder, vals))
        builder.call(fptr, realargs)
        return context.get_returned_value(builder, resty, builder.load(retvaltmp))

    return resty(addr, ret, spec, args), codegen


def _ptr_intrinsic(dtype):
    @intrinsic
    def ptr(typingctx, addr):
        if not isinstance(addr, types.Integer):
            return None

        def codegen(context, builder, signature, args):
            return builder.inttoptr(args[0], context.get_value_type(dtype).as_pointer())

        return types.CPointer(dtype)(addr), codegen

    return ptr


f8ptr = _ptr_intrinsic(types.float64)   # int64 address -> double *, for numba.carray
i8ptr = _ptr_intrinsic(types.int64)
