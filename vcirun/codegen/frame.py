"""Arrays without reference counting for the numba units: stack scratch and borrowed views.

numba reference-counts every array it passes: a callee increfs each array argument on entry and
decrefs it on exit, an `np.empty` is a heap allocation freed by the last decref, and both are atomic
operations on the array's meminfo. In the units' hot loop (a smooth step is a handful of calls with
6-10 arrays each, and allocates its Newton scratch) that bookkeeping measured about half of the loop
time (bench/profile_loop.py: NRT_incref + NRT_decref 49 %, allocation 12 % of a cart-pendulum CVA
run). An array whose meminfo is NULL is not counted (NRT_incref/decref return at the null test), so:

- `borrow(x)`: the same array (or tuple of arrays) with meminfo and parent NULL: a view that does not
  own its memory. `integrate` borrows its buffers once; everything it passes down is then free of
  atomics. The owner must outlive the view: keep it named until the end (`keep(owner)`).
- `scratch(n)`, `scratch2(m, n)`, `scratch_i(n)`: a float64 (n), float64 (m, n) or int64 (n) array
  on the calling function's stack (alloca, NULL meminfo, uninitialised like np.empty). Its memory
  ends with the function's frame, so it must not escape: not returned, not stored, and (a dynamic
  alloca grows the frame each time it runs) not allocated inside a loop or in an inline="always"
  function, which numba pastes into its caller's loops. vcirun.codegen.units checks these three
  rules on every unit (`check_unit`). Sizes follow NDOF, NCON, NODE_LEN: mostly n or n x n doubles
  (8 DOF: 512 bytes); the largest are the Gauss flow's two Newton matrices, (2 s n)^2 doubles each
  (s stages: 32 KB at 8 DOF and s = 4), far inside a thread's stack (8 MB by default on Linux).
  The alloca is where the call is, also for sizes known when compiled: an entry-block (static)
  alloca for those measured the same loop time (CVA, MCVAA: 0.97-1.04), so there is one code path.

The arithmetic is untouched (the same operations in the same order): the trajectories are those of
np.empty and owned arrays, bit for bit (docs/performance.md, *The loop without reference counting*).
"""
from __future__ import annotations

import numpy as np
from numba import config, types
from numba.core import cgutils
from numba.extending import intrinsic

SCRATCH = ("scratch", "scratch2", "scratch_i")   # the names the unit check knows as stack arrays
NAMES = ("borrow", "keep") + SCRATCH


def _borrowed(context, builder, ty, val):
    a = context.make_array(ty)(context, builder, val)
    a.meminfo = cgutils.get_null_value(a.meminfo.type)
    a.parent = cgutils.get_null_value(a.parent.type)
    return a._getvalue()


@intrinsic
def borrow(typingctx, x):
    if isinstance(x, types.Array):
        def codegen(context, builder, sig, args):
            return _borrowed(context, builder, sig.args[0], args[0])

        return x(x), codegen
    if isinstance(x, types.BaseTuple) and all(isinstance(t, types.Array) for t in x.types):
        def codegen(context, builder, sig, args):
            vals = [_borrowed(context, builder, t, builder.extract_value(args[0], i))
                    for i, t in enumerate(sig.args[0].types)]
            return context.make_tuple(builder, sig.return_type, vals)

        return x(x), codegen
    return None


@intrinsic
def keep(typingctx, x):
    """A use of x (nothing is emitted): the owner of borrowed views stays alive up to here."""
    def codegen(context, builder, sig, args):
        return context.get_dummy_value()

    return types.none(x), codegen


def _stack_array(context, builder, aryty, dims):
    elt = context.get_data_type(aryty.dtype)
    count = dims[0]
    for d in dims[1:]:
        count = builder.mul(count, d)
    data = builder.alloca(elt, size=count)
    ary = context.make_array(aryty)(context, builder)
    itemsize = context.get_constant(types.intp, context.get_abi_sizeof(elt))
    strides = []
    acc = itemsize
    for d in reversed(dims):   # C order
        strides.insert(0, acc)
        acc = builder.mul(acc, d)
    context.populate_array(ary, data=data, shape=dims, strides=strides, itemsize=itemsize, meminfo=None)
    return ary._getvalue()


def _scratch(dtype, ndim):
    aryty = types.Array(dtype, ndim, "C")

    def typer(typingctx, *dims):
        if len(dims) != ndim or not all(isinstance(d, types.Integer) for d in dims):
            return None

        def codegen(context, builder, sig, args):
            ds = [context.cast(builder, a, t, types.intp) for a, t in zip(args, sig.args)]
            return _stack_array(context, builder, aryty, ds)

        return aryty(*dims), codegen

    return typer


@intrinsic
def scratch(typingctx, n):
    return _scratch(types.float64, 1)(typingctx, n)


@intrinsic
def scratch2(typingctx, m, n):
    return _scratch(types.float64, 2)(typingctx, m, n)


@intrinsic
def scratch_i(typingctx, n):
    return _scratch(types.int64, 1)(typingctx, n)


# --- plain Python equivalents: the uncompiled loop (NUMBA_DISABLE_JIT=1, the hygiene study) and
# vcirun.codegen.evaluate's uncompiled modules

def _py_borrow(x):
    return x


def _py_keep(x):
    return None


def _py_scratch(n):
    return np.empty(n)


def _py_scratch2(m, n):
    return np.empty((m, n))


def _py_scratch_i(n):
    return np.empty(n, dtype=np.int64)


PYTHON = {"borrow": _py_borrow, "keep": _py_keep, "scratch": _py_scratch, "scratch2": _py_scratch2,
          "scratch_i": _py_scratch_i}

if config.DISABLE_JIT:
    borrow, keep, scratch, scratch2, scratch_i = (PYTHON[k] for k in NAMES)
