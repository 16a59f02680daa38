"""Discrete Lagrangians Ld(q0, q1, h) of Section 3 and their slot derivatives.

Explicit discrete Lagrangians (SE1, SE2, SVC of eq. 26, midpoint) are sympy expressions. SVA and
SVB are *compositions* of half steps of SE1 and SE2 (Section 3.3): their Ld is the stationary value
of Ld^SE1(q0, qh, h/2) + Ld^SE2(qh, q1, h/2) over the interior node qh (resp. SE2 then SE1). The
printed formulas for L_d^SVA / L_d^SVB in the paper drop the factor 2 in the half-step velocities
((q_{k+1/2} - q_k)/h should read /(h/2)) and call the stationary point a minimum; the composition
of the one-step maps is the definition we trust, and the tests check Phi^SVA = Phi^SE2_{h/2} o
Phi^SE1_{h/2} against it.

Slot kernels are generated in the velocity parametrisation q1 = q0 + h v (v the step's mean
velocity). The maps then solve for v, which stays well conditioned as the step length goes to 0
(partial steps just before or after an impact), where q1 - q0 loses all its digits.
"""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class ExplicitLd:
    """An explicit discrete Lagrangian: `build(L, q0, q1, h)` -> sympy expression, where L(q, v) is
    the continuous Lagrangian; `forcing_weights` = (a, b): trapezoidal discrete forces
    f^- = a h f(q0, v, t), f^+ = b h f(q1, v, t + h)."""

    name: str
    order: int
    symmetric: bool
    build: object
    forcing_weights: tuple = (0.5, 0.5)

    @property
    def stages(self):
        return ((self.name, 1.0),)

    @property
    def explicit(self) -> bool:
        return True


@dataclass(frozen=True)
class CompositeLd:
    """Ld of a composition of explicit half steps: stages = ((explicit name, fraction of h), ...)."""

    name: str
    order: int
    symmetric: bool
    stages: tuple = field(default=())

    @property
    def explicit(self) -> bool:
        return False


def _se1(L, q0, q1, h):
    return h * L(q0, [(b - a) / h for a, b in zip(q0, q1)])


def _se2(L, q0, q1, h):
    return h * L(q1, [(b - a) / h for a, b in zip(q0, q1)])


def _svc(L, q0, q1, h):  # eq. (26)
    v = [(b - a) / h for a, b in zip(q0, q1)]
    return h / 2 * (L(q0, v) + L(q1, v))


def _midpoint(L, q0, q1, h):
    v = [(b - a) / h for a, b in zip(q0, q1)]
    return h * L([(a + b) / 2 for a, b in zip(q0, q1)], v)


# Symmetric compositions of the symmetric, second-order SVC step (Hairer, Lubich & Wanner, Geometric
# Numerical Integration, Sec. V.3): Phi^SVCp_h = Phi^SVC_{g_s h} o ... o Phi^SVC_{g_1 h}. A composition
# of discrete Lagrangian maps is the map of the composed Ld (the sum of the stage Lds, stationary in
# the interior nodes), so these are variational integrators of order p; inside Algorithm 1 the
# partial map is the same composition over tau and R^CVA applies unchanged. The stages with negative
# g step backwards in time: the SVC kernels are regular for any sign of h.
_S4 = 1.0 / (4.0 - 4.0 ** (1.0 / 3.0))
# Suzuki's 5-stage order 4 (smaller error constant than the 3-stage triple jump at 5/3 the cost)
SVC4_WEIGHTS = (_S4, _S4, 1.0 - 4.0 * _S4, _S4, _S4)
# Kahan & Li s9odr6a (GNI eq. V.3.11)
_K6 = (0.39216144400731413927925056, 0.33259913678935943859974864, -0.70624617255763935980996482,
       0.08221359629355080023149045)
SVC6_WEIGHTS = _K6 + (1.0 - 2.0 * sum(_K6),) + _K6[::-1]
# Kahan & Li s17odr8a (GNI eq. V.3.11)
_K8 = (0.13020248308889008087881763, 0.56116298177510838456196441, -0.38947496264484728640807860,
       0.15884190655515560089621075, -0.39590389413323757733623154, 0.18453964097831570709183254,
       0.25837438768632204729397911, 0.29501172360931029887096624)
SVC8_WEIGHTS = _K8 + (1.0 - 2.0 * sum(_K8),) + _K8[::-1]


def _svc_composition(name, order, weights):
    return CompositeLd(name, order=order, symmetric=True, stages=tuple(("SVC", float(w)) for w in weights))


LIBRARY = {
    "SE1": ExplicitLd("SE1", order=1, symmetric=False, build=_se1, forcing_weights=(1.0, 0.0)),
    "SE2": ExplicitLd("SE2", order=1, symmetric=False, build=_se2, forcing_weights=(0.0, 1.0)),
    "SVC": ExplicitLd("SVC", order=2, symmetric=True, build=_svc),
    "midpoint": ExplicitLd("midpoint", order=2, symmetric=True, build=_midpoint),
    "SVA": CompositeLd("SVA", order=2, symmetric=True, stages=(("SE1", 0.5), ("SE2", 0.5))),
    "SVB": CompositeLd("SVB", order=2, symmetric=True, stages=(("SE2", 0.5), ("SE1", 0.5))),
    "SVC4": _svc_composition("SVC4", 4, SVC4_WEIGHTS),
    "SVC6": _svc_composition("SVC6", 6, SVC6_WEIGHTS),
    "SVC8": _svc_composition("SVC8", 8, SVC8_WEIGHTS),
}


def get_ld(name: str):
    if name not in LIBRARY:
        raise ValueError(f"ld: unknown discrete Lagrangian {name!r} (choose one of {', '.join(LIBRARY)})")
    return LIBRARY[name]


def ld_expression(system, ld: ExplicitLd, q0, q1, h):
    """Ld(q0, q1, h) of `system` as a sympy expression in the given symbols."""
    return ld.build(lambda q, v: system.lagrangian(q, v), list(q0), list(q1), h)


def slot_symbols(n: int):
    """Symbols used by generated step kernels: q0, v (step velocity), q1, h, t."""
    import sympy as sp  # imported here: the library of Lds is read on every warm start, sympy is not

    q0 = sp.symbols(f"qa0:{n}")
    v = sp.symbols(f"va0:{n}")
    q1 = sp.symbols(f"qb0:{n}")
    return list(q0), list(v), list(q1), sp.Symbol("hh"), sp.Symbol("tt")


def step_expressions(system, ld: ExplicitLd, need_jacobian=True, need_energy=True, need_energy_grad=False):
    """Slot expressions of one explicit step in the velocity parametrisation.

    Returns dict of sympy objects in (q0, v, h, t):
      Pm   = -D1 Ld - f^-             (p0 as a function of the step; solve Pm = p0 for v)
      Pm_v = dPm/dv                   (Newton Jacobian, = -h D2 D1 Ld - d f^-/dv)
      Pp   =  D2 Ld + f^+             (p1)
      Ed   = -D3 Ld                   (discrete energy of the step; unforced part)
      Ed_v = dEd/dv                   (for the VCI reset)
    Only what is asked for is derived (a scene compiles only the derivatives its methods need).
    """
    import sympy as sp

    n = system.n
    q0, v, q1, h, t = slot_symbols(n)
    Ld = ld_expression(system, ld, q0, q1, h)
    sub = {b: a + h * vv for a, b, vv in zip(q0, q1, v)}
    D1 = sp.Matrix([sp.diff(Ld, s) for s in q0])
    D2 = sp.Matrix([sp.diff(Ld, s) for s in q1])
    out = {}
    vel = [vv for vv in v]
    a, b = ld.forcing_weights
    if system.is_forced:
        fm = a * h * system.forcing_at(q0, vel, t)
        fp = b * h * system.forcing_at(q1, vel, t + h)
    else:
        fm = fp = sp.zeros(n, 1)
    # expand_mul distributes h * (a - b / h) so that h / h cancels: the kernels must stay finite
    # at step length 0 (a partial step to an impact at the very start or end of a step)
    Pm = (-D1 - fm).xreplace(sub).applyfunc(sp.expand_mul)
    Pp = (D2 + fp).xreplace(sub).applyfunc(sp.expand_mul)
    out["Pm"] = Pm
    out["Pp"] = Pp
    if need_jacobian:
        out["Pm_v"] = Pm.jacobian(v)
    if need_energy or need_energy_grad:
        Ed = sp.expand_mul(-sp.diff(Ld, h).xreplace(sub))
        out["Ed"] = Ed
        if need_energy_grad:
            out["Ed_v"] = sp.Matrix([[sp.diff(Ed, s) for s in v]])
    out["symbols"] = (q0, v, h, t)
    return out
