"""The frictional impact law, Python-callable: `friction_impact(W, u, e, mu) -> (code, lam)` (the exact
reference's impacts with friction, vcirun.reference_solution.coulomb, and the tests).

It calls the standalone numba unit vcirun/collision/friction_law.py (docs/derivations/friction.md,
"Frictional impacts"), so the reference applies the integrators' law, compiled from the same text.
The unit's source (with impact_law's and the linear algebra it calls, vcirun.codegen.units.
standalone_source) is written once into the kernel cache directory under a key of its text and
imported from there, so numba's on-disk cache serves later processes; in a process it is compiled
at the first call and kept.

Arguments as the unit's: rows ordered [normal_1 .. normal_k, tangent_1 .. tangent_k], W (2k, 2k) the
Delassus matrix, u (2k,) the velocities before the impact, e (k,) restitution, mu (k,) friction.
Returns the case code (CODES names them; < 0 is a failure with lam = 0) and lam (2k,), the impulses:
p+ = p- + Gn^T lam[:k] + Gt^T lam[k:].
"""
from __future__ import annotations

import functools
import hashlib
import importlib.util
import sys

import numpy as np

__all__ = ["friction_impact", "friction_law_module", "code_name", "CODES"]

UNIT = "collision/friction_law.py"
CODES = ("LCP_UNIQUE", "LCP_SINGULAR_UNIQUE", "LCP_MIN_NORM", "FRIC_SOLVED", "LCP_INFEASIBLE", "LCP_BAD_INPUT",
         "LCP_DEGENERATE")


@functools.lru_cache(maxsize=1)
def friction_law_module():
    """The compiled unit (a module with friction_impact_law, impact_law and the case codes)."""
    from ..codegen import cache_store, units
    from ..codegen.build import cache_dir

    text = units.standalone_source([UNIT])
    key = hashlib.sha256(text.encode()).hexdigest()[:16]
    path = cache_dir() / f"unit_friction_law_{key}.py"
    if not path.exists() or path.read_text() != text:
        cache_store.write_atomic(path, text, what=path.name)
    name = f"vcirun_unit_friction_law_{key}"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, path)
        law = importlib.util.module_from_spec(spec)
        sys.modules[name] = law
        try:
            spec.loader.exec_module(law)
        except BaseException:
            sys.modules.pop(name, None)
            raise
    return sys.modules[name]


def friction_impact(W, u, e, mu) -> tuple[int, np.ndarray]:
    """(case code, impulses) of the frictional impact law for k contacts (see the module docstring)."""
    law = friction_law_module()
    W = np.ascontiguousarray(W, dtype=np.float64)
    u = np.ascontiguousarray(u, dtype=np.float64).reshape(-1)
    e = np.ascontiguousarray(e, dtype=np.float64).reshape(-1)
    mu = np.ascontiguousarray(mu, dtype=np.float64).reshape(-1)
    if W.ndim != 2:
        raise ValueError(f"friction_impact: W must be a (2k, 2k) matrix, got shape {W.shape}")
    lam = np.zeros(u.shape[0])
    code = int(law.friction_impact_law(W, u, e, mu, lam))
    return code, lam


def code_name(code: int) -> str:
    """The name of a case code (e.g. 'FRIC_SOLVED')."""
    law = friction_law_module()
    for n in CODES:
        if getattr(law, n) == code:
            return n
    return f"code {code}"
