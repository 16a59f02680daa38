"""What one compiled module must contain (a KernelSet), without importing numba or sympy: the
method registry (vcirun.methods.table) and the config layer read it on every start."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class KernelSet:
    """What one compiled module must contain: the explicit stages of the full map, which partial map
    and reset to bind (names of the descriptors in vcirun.codegen.roles), and the generated parts
    their descriptors need. vcirun.codegen.roles.kernel_set builds it from a method's data."""

    full_stages: tuple                 # ((explicit Ld name, fraction of h), ...)
    partial: str = "ld"                # a key of roles.PARTIALS
    reset: str = "cva"                 # a key of roles.RESETS
    vci_stage: str | None = None       # explicit Ld of the part "energy_gradient" (its dEd/dv; R^VCI)
    modified: tuple | None = None      # (Ld name, mh_order, flow_order): the part "modified" (H~)

    def key_text(self) -> str:
        return repr(self)

    @property
    def explicit_names(self) -> tuple:
        names = [s for s, _ in self.full_stages]
        if self.vci_stage and self.vci_stage not in names:
            names.append(self.vci_stage)
        return tuple(dict.fromkeys(names))


# The system-only kernel set: the system kernels and the continuous dynamics (H, Hamilton's
# equations with the force, phi, grad phi, d phi/dt, the elastic multiplier; vcirun/maps/dynamics.py),
# no discrete Lagrangian and no loop. What the exact reference, the baselines, studies and verify
# need: they load it instead of compiling a method's module.
SYSTEM_KERNELS = KernelSet(full_stages=(), partial=None, reset=None)
