"""Uncompiled access to a scene's generated module, for verification and exploration.

`python_module(system, ld, mh_order, flow_order)` executes the very source text that vcirun.codegen
compiles (generated kernels + numba units), with `njit` replaced by the identity, so every function
(mh_energy, mh_terms, mh_gradient, gauss_partial, reset_mcva, ld_step, integrate, ...) can be called
from Python without a numba compile (~10-20 s per module). About 1000x slower per call than the
compiled module: meant for tests that evaluate H~ at a few thousand points or run a few short
simulations, not for production runs. `python_module_for(system, kernel_set)` does the same for any
method's kernel set (e.g. to run `vcirun.simulate` uncompiled by substituting it for load_module).
"""
from __future__ import annotations

import re
import types
from functools import lru_cache

from . import frame


def _njit(*args, **kwargs):
    if args and callable(args[0]):
        return args[0]
    return lambda f: f


@lru_cache(maxsize=None)
def python_module_for(system, ks):
    """The generated module of (system, kernel set) executed as plain Python."""
    from .derive import module_source

    text = module_source(system, ks)
    text = text.replace("from numba import njit", "")
    text = re.sub(r"^from vcirun\.codegen\.frame import .*$", "", text, flags=re.M)
    mod = types.ModuleType(f"vcirun_python_{system.name}_{abs(hash(ks))}")
    mod.__dict__["njit"] = _njit
    mod.__dict__.update(frame.PYTHON)   # the stack / borrowed arrays as plain numpy
    exec(compile(text, mod.__name__, "exec"), mod.__dict__)
    return mod


def python_module(system, ld: str = "SVC", mh_order: int = 3, flow_order: int = 4):
    """The scene's MCVA module for (ld, mh_order, flow_order), executed as plain Python (the kernel set
    of vcirun.methods.table.generalized_mcva, from the same descriptors: codegen does not import
    methods)."""
    from ..discrete.lagrangians import get_ld
    from ..modified import check_mcva_options
    from .roles import MCVA_FAMILY, kernel_set

    if isinstance(system, str):
        from ..scenes.declarations import get_scene

        system = get_scene(system)
    ld, s, flow = check_mcva_options(ld, int(mh_order), int(flow_order))
    ks = kernel_set(ld, tuple(get_ld(ld).stages), MCVA_FAMILY["partial"], MCVA_FAMILY["reset"], s, flow)
    return python_module_for(system, ks)
