"""What one compiled module must contain (a KernelSet), without importing numba or sympy: the
method registry (vcirun.methods.table) and the config layer read it on every start."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class KernelSet:
    """What one compiled module must contain: the explicit stages of the full map, which partial map
    and reset to bind (names of the descriptors in vcirun.codegen.roles), and the generated parts
    their descriptors need beyond the system's and the full map's, each with its argument:
    ((part, argument), ...) in the order of vcirun.codegen.roles.PARTS, e.g.
    ("energy_gradient", "SVC") for dEd/dv of that explicit Ld, ("modified", ("SVC", 3, 4)) for the
    truncated modified Hamiltonian of (Ld, mh_order, flow_order). vcirun.codegen.roles.kernel_set
    builds it from a method's data."""

    full_stages: tuple                 # ((explicit Ld name, fraction of h), ...)
    partial: str = "ld"                # a key of roles.PARTIALS
    reset: str = "cva"                 # a key of roles.RESETS
    parts: tuple = ()                  # ((part name, its argument), ...): a key of roles.PARTS each

    def key_text(self) -> str:
        return repr(self)

    def part(self, name: str):
        """The argument of the generated part `name`, None when the kernel set has no such part."""
        for p, arg in self.parts:
            if p == name:
                return arg
        return None

    @property
    def modified(self):
        """part("modified"): the (Ld, mh_order, flow_order) of the truncated modified Hamiltonian the
        module carries (the MCVA family), or None."""
        return self.part("modified")

    @property
    def explicit_names(self) -> tuple:
        """The explicit Lds the module's step kernels are generated for, in stage-id order: the full
        map's, then the Ld of a part whose argument names one (the energy gradient's)."""
        names = [s for s, _ in self.full_stages]
        for _, arg in self.parts:
            if isinstance(arg, str) and arg not in names:
                names.append(arg)
        return tuple(dict.fromkeys(names))


# The system-only kernel set: the system kernels and the continuous dynamics (H, Hamilton's
# equations with the force, phi, grad phi, d phi/dt, the elastic multiplier; vcirun/maps/dynamics.py),
# no discrete Lagrangian and no loop. What the exact reference, the baselines, studies and verify
# need: they load it instead of compiling a method's module.
SYSTEM_KERNELS = KernelSet(full_stages=(), partial=None, reset=None)
