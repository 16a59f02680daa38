"""Named methods as data: a choice of (full, partial, reset) for Algorithm 1 (Section 4, Table I)."""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

from ..codegen import roles
from ..codegen.kernel_set import KernelSet
from ..discrete.lagrangians import LIBRARY, get_ld
from ..modified import check_mcva_options


@dataclass(frozen=True)
class Method:
    """name; ld: discrete Lagrangian of the full step; partial: a partial map of
    vcirun.codegen.roles.PARTIALS ('ld': Phi^Ld_tau, 'gauss': Gauss collocation of the truncated
    modified Hamiltonian's flow); reset: a reset of vcirun.codegen.roles.RESETS ('cva', 'vci',
    'mcva', or one registered there), or None (smooth integration, constraint ignored);
    mh_order, flow_order: methods whose descriptors need the modified Hamiltonian only."""

    name: str
    ld: str
    partial: str = "ld"
    reset: str | None = None
    mh_order: int | None = None
    flow_order: int | None = None
    properties: dict = field(default_factory=dict, compare=False)

    def kernel_set(self) -> KernelSet:
        return _kernel_set(self)

    @property
    def constrained(self) -> bool:
        return self.reset is not None

    @property
    def reset_map(self) -> roles.ResetMap:
        """The descriptor of the reset (that of the default reset for smooth methods)."""
        return roles.reset_map(self.reset)

    @property
    def has_modified_energy(self) -> bool:
        """The method carries a truncated modified Hamiltonian (the record's Hmod row is filled)."""
        return self.kernel_set().modified is not None

    @property
    def impact_order(self) -> int:
        """The method's order through impacts: its reset's, else its full map's Ld's."""
        order = self.reset_map.impact_order if self.constrained else None
        return LIBRARY[self.ld].order if order is None else order


@lru_cache(maxsize=256)
def _kernel_set(method: Method) -> KernelSet:
    """The kernel set of a method, from its descriptors (memoised: simulate asks for it on every call)."""
    return roles.kernel_set(method.ld, tuple(get_ld(method.ld).stages), method.partial, method.reset,
                            method.mh_order, method.flow_order)


def properties(*, conserves_mh=False, symplectic=False, explicit_ld=False, forcing=None) -> dict:
    """Table I's columns of a method: conserves its associated modified Hamiltonian; symplectic
    (True, or "exact"); explicit discrete Lagrangian (the simplifying discrete Lagrange-d'Alembert
    principle); forcing: the L2 order measured through impacts on forced scenes (docs/derivations/forcing.md),
    None where none was measured."""
    return {"conserves_mh": conserves_mh, "symplectic": symplectic, "explicit_ld": explicit_ld, "forcing": forcing}


METHODS = {
    # Table I of the paper: CVA and VCI use SVC (explicit Ld); VCI is exactly symplectic.
    "CVA": Method("CVA", ld="SVC", reset="cva", properties=properties(explicit_ld=True, forcing="order 2")),
    "VCI": Method("VCI", ld="SVC", reset="vci",
                  properties=properties(symplectic="exact", explicit_ld=True, forcing="order 2")),
    # Section 5.2: MCVA on SVA with H~^{O(h^4)} (H4 kept: it does not vanish, see vcirun/modified) and
    # MCVAC, the generalized MCVA on SVC with H~^{O(h^3)}; both with the order-4 Gauss partial flow.
    "MCVAA": Method("MCVAA", ld="SVA", partial="gauss", reset="mcva", mh_order=4, flow_order=4,
                    properties=properties(conserves_mh=True, symplectic=True, forcing="order 2")),
    "MCVAC": Method("MCVAC", ld="SVC", partial="gauss", reset="mcva", mh_order=3, flow_order=4,
                    properties=properties(conserves_mh=True, symplectic=True, explicit_ld=True, forcing="order 2")),
    # Beyond the paper: CVA on higher-order symmetric compositions of SVC (Suzuki s5 order 4,
    # Kahan & Li s9 order 6 and s17 order 8; vcirun.discrete.lagrangians). Same partial map (the
    # composition over tau) and R^CVA: the collision time and the state at impact inherit the order.
    "CVA4": Method("CVA4", ld="SVC4", reset="cva", properties=properties(forcing="order 4")),
    "CVA6": Method("CVA6", ld="SVC6", reset="cva", properties=properties()),
    "CVA8": Method("CVA8", ld="SVC8", reset="cva", properties=properties()),
}


def resolve_method(method, **options) -> Method:
    """A Method from a name (CVA, VCI, MCVAA, MCVAC, MCVA with ld/mh_order/flow_order, or a bare
    discrete Lagrangian name for smooth integration) or a Method instance."""
    if isinstance(method, Method):
        return method
    if not isinstance(method, str):
        raise ValueError(f"method: expected a method name, got {type(method).__name__}")
    if method in METHODS:
        base = METHODS[method]
        if not options:
            return base
        if method in ("CVA", "VCI") and set(options) == {"ld"}:
            ld = get_ld(options["ld"])  # raises naming the field
            if method == "VCI" and not ld.explicit:
                raise ValueError(f"ld: VCI needs an explicit discrete Lagrangian (its reset conserves the "
                                 f"energy of one explicit step); {ld.name} is a composition - use CVA, or "
                                 f"one of {', '.join(k for k, v in LIBRARY.items() if v.explicit)}")
            return Method(f"{method}[{ld.name}]", ld=ld.name, reset=base.reset,
                          properties=properties(symplectic=base.properties["symplectic"], explicit_ld=ld.explicit))
        bad = sorted(options)[0]
        hint = "ld (CVA, VCI)" if method in ("CVA", "VCI") else "none: use method 'MCVA' for ld/mh_order/flow_order"
        raise ValueError(f"{bad}: option not accepted by method {method} (accepted: {hint})")
    if method in LIBRARY:
        return Method(method, ld=method, reset=None,
                      properties=properties(symplectic="exact", explicit_ld=LIBRARY[method].explicit))
    if method == "MCVA":
        return generalized_mcva(**options)
    names = list(METHODS) + ["MCVA"] + list(LIBRARY)
    upper = {n.upper(): n for n in names}
    import difflib

    near = ([upper[method.upper()]] if method.upper() in upper
            else [upper[m] for m in difflib.get_close_matches(method.upper(), list(upper), n=1)])
    raise ValueError(f"method: unknown method {method!r}" + (f"; did you mean {near[0]!r}?" if near else "")
                     + f" (choose one of {', '.join(names)})")


def generalized_mcva(ld: str = "SVC", mh_order: int = 3, flow_order: int = 4, **unknown) -> Method:
    """Generalized MCVA (Section 4.4): full steps of discrete Lagrangian `ld`, partial steps by the
    `flow_order` Gauss collocation flow of the truncated modified Hamiltonian H~^{O(h^mh_order)},
    reset R^MCVA conserving that truncation. Raises ValueError naming the offending field."""
    ld, mh_order, flow_order = check_mcva_options(ld, mh_order, flow_order, **unknown)
    return Method(f"MCVA[{ld},s={mh_order},g{flow_order}]", ld=ld, **roles.MCVA_FAMILY,
                  mh_order=mh_order, flow_order=flow_order,
                  properties=properties(conserves_mh=True, symplectic=True, explicit_ld=LIBRARY[ld].explicit))
