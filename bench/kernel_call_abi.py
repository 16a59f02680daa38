"""What one call of a kernel costs from the shared core, by how it is called.

    python bench/kernel_call_abi.py

A kernel of the PmJc shape (8 arrays, 2 scalars; a 2-DOF body) called 5e6 times from a compiled loop:
- by address with numba's array ABI (vcirun.codegen.kcall before the pointer wrappers: seven
  words per array),
- by address with the arrays' data pointers (a wrapper rebuilding them with numba.carray: what
  vcirun.codegen.shared does),
- called directly (inlined by LLVM: the specialized build).
Prints the best of 5 in ns per call.
"""
from __future__ import annotations

import time

import numpy as np
from llvmlite import ir
from numba import carray, njit, types
from numba.core import cgutils
from numba.core.callconv import excinfo_t
from numba.extending import intrinsic

P = types.CPointer(types.float64)
A1, A2 = types.Array(types.float64, 1, "C"), types.Array(types.float64, 2, "C")


@njit
def kern(q0, v, h, t, prm, c, r, J):
    r[0] = prm[0] * q0[0] + h * v[0] + c[0]
    r[1] = prm[1] * q0[1] + t * v[1]
    J[0, 0] = h
    J[0, 1] = 0.0
    J[1, 0] = 0.0
    J[1, 1] = h
    return 0


@njit
def kern_p(q0, v, h, t, prm, c, r, J):
    return kern(carray(q0, (2,)), carray(v, (2,)), h, t, carray(prm, (2,)), carray(c, (4,)), carray(r, (2,)),
                carray(J, (2, 2)))


def _address(disp, sig):
    disp.compile(sig)
    cres = disp.overloads[sig]
    return cres.library.get_pointer_to_function(cres.fndesc.llvm_func_name)


@intrinsic
def dptr(typingctx, arr):
    def codegen(context, builder, signature, args):
        return context.make_array(arr)(context, builder, args[0]).data
    return P(arr), codegen


@intrinsic
def call_at(typingctx, addr, args):
    argtys = tuple(args.types)

    def codegen(context, builder, signature, llargs):
        cc = context.call_conv
        f = builder.inttoptr(llargs[0], cc.get_function_type(types.int64, argtys).as_pointer())
        vals = [builder.extract_value(llargs[1], i) for i in range(len(argtys))]
        rv = cgutils.alloca_once(builder, cc.get_return_type(types.int64).pointee)
        ex = cgutils.alloca_once(builder, ir.PointerType(excinfo_t))
        builder.call(f, [rv, ex] + list(cc._get_arg_packer(argtys).as_arguments(builder, vals)))
        return builder.load(rv)
    return types.int64(addr, args), codegen


@njit
def loop_array_abi(addr, n, q0, v, prm, c, r, J):
    s = 0.0
    for i in range(n):
        call_at(addr, (q0, v, 0.01, 0.0, prm, c, r, J))
        s += r[0]
    return s


@njit
def loop_pointers(addr, n, q0, v, prm, c, r, J):
    s = 0.0
    for i in range(n):
        call_at(addr, (dptr(q0), dptr(v), 0.01, 0.0, dptr(prm), dptr(c), dptr(r), dptr(J)))
        s += r[0]
    return s


@njit
def loop_inlined(addr, n, q0, v, prm, c, r, J):
    s = 0.0
    for i in range(n):
        kern(q0, v, 0.01, 0.0, prm, c, r, J)
        s += r[0]
    return s


def main():
    a_arr = _address(kern, (A1, A1, types.float64, types.float64, A1, A1, A1, A2))
    a_ptr = _address(kern_p, (P, P, types.float64, types.float64, P, P, P, P))
    arrays = (np.ones(2), np.ones(2), np.ones(2), np.ones(4), np.zeros(2), np.zeros((2, 2)))
    N = 5_000_000
    for f, addr in ((loop_array_abi, a_arr), (loop_pointers, a_ptr), (loop_inlined, 0)):
        f(addr, 10, *arrays)
        best = min(_timed(f, addr, N, arrays) for _ in range(5))
        print(f"{f.__name__:16s} {best / N * 1e9:6.2f} ns per call")


def _timed(f, addr, N, arrays):
    t = time.perf_counter()
    f(addr, N, *arrays)
    return time.perf_counter() - t


if __name__ == "__main__":
    main()
