"""The declared interface of a generated module, as one table: what the generator emits for the units
(kernels with their arguments, constants), the roles Algorithm 1 calls (full, partial, reset,
modified_energy) with their signatures, and the partial-map and reset descriptors.

Everything that depends on these declarations is derived from this module:

- vcirun.codegen.units: GENERATED (the names of each generated part), the role bindings of a kernel
  set, ENTRY (what Python calls on a module), and `check_unit`'s arity checks;
- vcirun.codegen.shared: the kernel ABI of the shared build (the slot table, the stubs that call a
  scene's kernels by address, the scene's pointer wrappers);
- vcirun.methods.table: each method's kernel set (`kernel_set`).

The numba source units of vcirun/maps and vcirun/collision import the generated names and the roles
they call from here, so that editors and linters see them with their signatures; the assembler drops
those import lines (vcirun.codegen.units.unit_body) and the generated part or the bindings define the
names in the module. Called from Python, a declaration raises: the numbers exist only in a module.

Adding a reset that uses existing kernels: one unit file defining a function with the signature of
the role `reset`, and one `ResetMap` row (in RESETS, or at run time through `register_reset`).
A reset that needs a new kernel of the system: one `@kernel(part, derive=...)` declaration (its
signature and its symbolic definition; a new part is declared with it), the unit, the row naming
the part in its needs (docs/extending.md, *Add a reset*, runs such an example). A kernel generated
per Ld or per modified Hamiltonian also needs its generator's emitter (vcirun.codegen.derive).

No numba, no sympy: the method table and the warm path import this. (No `from __future__ import
annotations`: the declarations are read from their evaluated annotations.)
"""
import functools
import inspect
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import record
from .kernel_set import KernelSet


class ContractError(ValueError):
    """A module cannot be assembled: a unit requires a name nothing provides, a declaration does not
    match its unit's code, or a role's implementation does not have the role's signature."""


# --- argument types of the kernel ABI ---------------------------------------------------------------

@dataclass(frozen=True)
class Spec:
    """One argument of a generated kernel: kind 'a' (1-d C-contiguous float64 array), 'b' (2-d), 'f'
    (float64), 'i' (int64); shape: the array's shape in the scene module's constants (NPRM: the
    parameter count), as the scene's pointer wrapper rebuilds it (vcirun.codegen.shared)."""

    kind: str
    shape: str | None = None


F8 = Spec("f")
I8 = Spec("i")


def vec(n: str) -> Spec:
    return Spec("a", f"({n},)")


def mat(r: str, c: str) -> Spec:
    return Spec("b", f"({r}, {c})")


@dataclass(frozen=True)
class KernelDecl:
    """A generated kernel as the units call it. part: the GENERATED part that defines it; per_stage:
    the units call it as name(sid, ...) and the scene defines <LD>_<suffix>(...) for each explicit Ld
    of the full map (suffix: the name after "ld_"); core: called through the shared core's slot table
    (False: a scene-module name only); returns "int" (0) or "float"; derive: None for the kernels
    vcirun.codegen.derive emits by their own generators, else the kernel's symbolic definition,
    derive(system) -> {output argument (or "return" for a float kernel): sympy expression or
    Matrix}, its inputs among q, qd, t (the system's coordinates, velocities and time)."""

    name: str
    part: str
    args: tuple          # ((name, Spec), ...), sid excluded
    returns: str
    per_stage: bool
    core: bool
    doc: str
    derive: object = None

    @property
    def arg_names(self) -> str:
        return ", ".join(a for a, _ in self.args)

    @property
    def spec(self) -> str:
        return "".join(s.kind for _, s in self.args)

    @property
    def ret_literal(self) -> str:
        """The value kcall's return type is read from (vcirun.codegen.kcall)."""
        return "0.0" if self.returns == "float" else "0"

    @property
    def suffix(self) -> str:
        return self.name[len("ld_"):]

    @property
    def arity(self) -> int:
        return len(self.args) + (1 if self.per_stage else 0)


KERNELS: dict[str, KernelDecl] = {}


@dataclass(frozen=True)
class PartDecl:
    """A generated part of a module. arg: what a kernel set gives the part (KernelSet.parts): "ld"
    (an explicit Ld name: its kernels are generated for that Ld), "mh" ((Ld, mh_order, flow_order)),
    "none" (True: the part depends on the system alone); per_scene: a shared core may hold the part
    while a scene's kernel set lacks it (its kernels' slots are then empty and the units do not call
    them), so resets whose needs differ only in such parts share one core (vcirun.codegen.shared)."""

    name: str
    arg: str
    per_scene: bool
    doc: str


PARTS: dict[str, PartDecl] = {p.name: p for p in (
    PartDecl("system", "none", False, "the system kernels and constants: every module"),
    PartDecl("record", "none", False, "the record's index and status constants (vcirun.core.record): every module"),
    PartDecl("steps", "none", False, "the step kernels of the full map's explicit Lds, by stage id"),
    PartDecl("energy_gradient", "ld", True, "dEd/dv of one explicit Ld (R^VCI's energy condition)"),
    PartDecl("modified", "mh", False, "the truncated modified Hamiltonian H~ and its Gauss flow (the MCVA family)"),
)}
BASE_PARTS = ("system", "record", "steps")   # every method's module; KernelSet.parts names the others


def _unavailable(name: str, what: str):
    def call(*args, **kwargs):
        raise ContractError(f"{name} is {what}: call it on a module from vcirun.codegen.build.load_module "
                            "(or vcirun.codegen.evaluate.python_module_for)")
    return call


DERIVED_INPUTS = ("q", "qd", "t")   # the inputs of a kernel declared with `derive`


def kernel(part: str, *, per_stage: bool = False, core: bool = True, derive=None):
    """Declare a generated kernel by its Python signature (annotations: Spec; return: int or float).
    derive: the kernel's symbolic definition (KernelDecl.derive), which vcirun.codegen.derive emits
    in every module whose kernel set has `part`; a part that is not in PARTS is declared with it
    (one that depends on the system alone: arg "none"). The declared name is also bound in this
    module, so that a unit's `from vcirun.codegen.roles import NAME` resolves."""
    def deco(fn):
        sig = inspect.signature(fn, eval_str=True)   # (annotations given as text: a module under `annotations`)
        params = list(sig.parameters.values())
        if per_stage:
            if not params or params[0].name != "sid":
                raise ContractError(f"{fn.__name__}: a per-stage kernel takes sid first")
            params = params[1:]
        decl = KernelDecl(fn.__name__, part, tuple((p.name, p.annotation) for p in params),
                          "float" if sig.return_annotation is float else "int", per_stage, core,
                          inspect.getdoc(fn) or "", derive)
        for a, s in decl.args:
            if not isinstance(s, Spec):
                raise ContractError(f"{fn.__name__}: argument {a} needs a Spec annotation (F8, I8, vec, mat)")
        if derive is not None:
            if per_stage:
                raise ContractError(f"{fn.__name__}: a kernel with `derive` depends on the system alone (not per_stage)")
            bad = [a for a, s in decl.args if s.kind in "fi" and a not in DERIVED_INPUTS]
            if bad:
                raise ContractError(f"{fn.__name__}: scalar argument {bad[0]!r}: a derived kernel's inputs are "
                                    f"{DERIVED_INPUTS} and prm")
        if decl.name in KERNELS and KERNELS[decl.name] != decl:
            raise ContractError(f"kernel {decl.name!r}: already declared (part {KERNELS[decl.name].part!r})")
        if part not in PARTS:
            if derive is None:
                raise ContractError(f"{fn.__name__}: part {part!r} is not declared (PARTS: {', '.join(PARTS)}); a "
                                    "kernel of a new part gives its symbolic definition (derive=...)")
            PARTS[part] = PartDecl(part, "none", False, f"{fn.__name__}: {decl.doc.splitlines()[0] if decl.doc else ''}")
        KERNELS[decl.name] = decl
        stub = functools.wraps(fn)(_unavailable(fn.__name__, f"a generated kernel (part {part!r})"))
        globals().setdefault(decl.name, stub)
        return stub
    return deco


# --- the system kernels (part "system": every module) -----------------------------------------------

@kernel("system")
def sys_M(q: vec("NDOF"), prm: vec("NPRM"), out: mat("NDOF", "NDOF")) -> int:
    """out = M(q), the mass matrix."""


@kernel("system")
def sys_V(q: vec("NDOF"), prm: vec("NPRM")) -> float:
    """V(q), the potential."""


@kernel("system")
def sys_phi(q: vec("NDOF"), prm: vec("NPRM")) -> float:
    """The gap min_i phi_i(q) (phi itself for one constraint): what the event search follows."""


@kernel("system")
def sys_dphi(q: vec("NDOF"), prm: vec("NPRM"), out: vec("NDOF")) -> int:
    """out = grad of sys_phi (several constraints: that of the smallest phi_i)."""


@kernel("system")
def sys_phis(q: vec("NDOF"), prm: vec("NPRM"), out: vec("NCON")) -> int:
    """out_i = phi_i(q), every constraint."""


@kernel("system")
def sys_dphis(q: vec("NDOF"), prm: vec("NPRM"), out: mat("NCON", "NDOF")) -> int:
    """out = G(q), the constraint Jacobian (row i: grad phi_i)."""


@kernel("system")
def sys_dphis_nz(q: vec("NDOF"), prm: vec("NPRM"), out: vec("DPHI_NNZ")) -> int:
    """out = the structural nonzeros of G(q) in row order: row i's are out[DPHI_ROW[i]:DPHI_ROW[i + 1]],
    in the columns DPHI_COL (the same numbers as sys_dphis there)."""


@kernel("system")
def sys_ddphis(q: vec("NDOF"), v: vec("NDOF"), prm: vec("NPRM"), out: vec("NCON")) -> int:
    """out_i = v^T Hess(phi_i)(q) v: the velocity term of d^2 phi_i / dt^2."""


@kernel("system")
def sys_Mdotv(q: vec("NDOF"), v: vec("NDOF"), prm: vec("NPRM"), out: vec("NDOF")) -> int:
    """out = (dM/dq . v) v: the velocity term of d/dt (M v)."""


@kernel("system")
def sys_restitution(prm: vec("NPRM"), out: vec("NCON")) -> int:
    """out_i = the restitution coefficient e_i of constraint i."""


@kernel("system")
def sys_slips(q: vec("NDOF"), prm: vec("NPRM"), out: mat("NCON", "NDOF")) -> int:
    """out = W_t(q), the slip rows: contact i slides at v_t,i = W_t,i(q) qdot, the friction force opposes
    it (vcirun.mechanics.friction); zero rows where contact i has no friction."""


@kernel("system")
def sys_dslips(q: vec("NDOF"), v: vec("NDOF"), prm: vec("NPRM"), out: vec("NCON")) -> int:
    """out_i = v^T (dW_t,i/dq) v: the velocity term of d(v_t,i)/dt = W_t,i(q) qddot + out_i along qdot = v."""


@kernel("system")
def sys_friction(prm: vec("NPRM"), mu: vec("NCON"), mu_s: vec("NCON")) -> int:
    """mu_i, mu_s,i = the kinetic and static friction coefficients of contact i (0 where frictionless)."""


@kernel("system")
def sys_dHq(q: vec("NDOF"), x: vec("NDOF"), prm: vec("NPRM"), out: vec("NDOF")) -> int:
    """out = dH/dq at fixed x = M(q)^-1 p."""


@kernel("system")
def sys_reset_map(q: vec("NDOF"), qd: vec("NDOF"), prm: vec("NPRM"), qo: vec("NDOF"), qdo: vec("NDOF")) -> int:
    """(qo, qdo) = the declared reset map of (q, qd), the state just before an impact (the identity
    when the system declares none: RESET_MAP false)."""


@kernel("system")
def sys_node(q: vec("NDOF"), prm: vec("NPRM"), c: vec("NODE_LEN")) -> int:
    """c = the node data of q: the tensors a step kernel needs at q (vcirun.codegen.tensor)."""


@kernel("system")
def sys_node_M(c: vec("NODE_LEN"), A: mat("NDOF", "NDOF")) -> int:
    """A = M(q) from the node data c of q."""


@kernel("system")
def sys_force(q: vec("NDOF"), qd: vec("NDOF"), t: F8, prm: vec("NPRM"), out: vec("NDOF")) -> int:
    """out = f(q, qdot, t), the generalized force (zero for an unforced system)."""


@kernel("system")
def sys_force_jac(q: vec("NDOF"), qd: vec("NDOF"), t: F8, prm: vec("NPRM"), fq: mat("NDOF", "NDOF"),
                  fv: mat("NDOF", "NDOF")) -> int:
    """fq = df/dq, fv = df/dqdot."""


# --- the step kernels of the full map's explicit Lds (part "steps"), by stage id -------------------

@kernel("steps", per_stage=True)
def ld_PmJc(sid: I8, q0: vec("NDOF"), v: vec("NDOF"), h: F8, t: F8, prm: vec("NPRM"), c: vec("NODE_LEN"),
            r: vec("NDOF"), J: mat("NDOF", "NDOF")) -> int:
    """r = Pm(q0, v, h) = -D1 Ld - f^- and J = dr/dv, given the node data c of q0."""


@kernel("steps", per_stage=True)
def ld_Ppc(sid: I8, q0: vec("NDOF"), v: vec("NDOF"), h: F8, t: F8, prm: vec("NPRM"), c: vec("NODE_LEN"),
           out: vec("NDOF"), cn: vec("NODE_LEN")) -> int:
    """out = Pp(q0, v, h) = D2 Ld + f^+, given the node data c of q0; cn = the node data of q0 + h v."""


@kernel("steps", per_stage=True)
def ld_Ed(sid: I8, q0: vec("NDOF"), v: vec("NDOF"), h: F8, prm: vec("NPRM")) -> float:
    """The discrete energy -D3 Ld(q0, q0 + h v, h)."""


@kernel("steps", per_stage=True, core=False)
def ld_PmJ(sid: I8, q0: vec("NDOF"), v: vec("NDOF"), h: F8, t: F8, prm: vec("NPRM"), r: vec("NDOF"),
           J: mat("NDOF", "NDOF")) -> int:
    """ld_PmJc without node data (a scene-module name: verification and tests)."""


@kernel("steps", per_stage=True, core=False)
def ld_Pp(sid: I8, q0: vec("NDOF"), v: vec("NDOF"), h: F8, t: F8, prm: vec("NPRM"), out: vec("NDOF")) -> int:
    """ld_Ppc without node data (a scene-module name)."""


# --- the energy gradient of one explicit Ld (part "energy_gradient": ks.part("energy_gradient")) ----

@kernel("energy_gradient", per_stage=True)
def ld_Edv(sid: I8, q0: vec("NDOF"), v: vec("NDOF"), h: F8, prm: vec("NPRM"), out: vec("NDOF")) -> int:
    """out = d(-D3 Ld)/dv of the energy gradient's Ld (sid: that Ld's stage id, EDV_STAGE)."""


# --- the truncated modified Hamiltonian (part "modified": vcirun/codegen/mh_kernels.py) -------------

@kernel("modified")
def mh_FA(q: vec("NDOF"), p: vec("NDOF"), u: vec("MH_M"), h: F8, prm: vec("NPRM"), F: vec("MH_M"),
          A: mat("MH_M", "MH_M")) -> int:
    """F = the stationarity residual of eta's stage velocities u, A = dF/du."""


@kernel("modified")
def mh_value(q: vec("NDOF"), p: vec("NDOF"), u: vec("MH_M"), W: mat("MH_M", "MH_M"), h: F8, prm: vec("NPRM"),
             terms: vec("MH_ORDER")) -> float:
    """H~^{O(h^s)} at the stationary u (W = A^-1 there); terms = (eta, H2, ..., H_s)."""


@kernel("modified")
def mh_grad(q: vec("NDOF"), p: vec("NDOF"), u: vec("MH_M"), W: mat("MH_M", "MH_M"), h: F8, prm: vec("NPRM"),
            grad: vec("2 * NDOF")) -> float:
    """H~ and grad = (dH~/dq, dH~/dp)."""


@kernel("modified")
def mh_hess(q: vec("NDOF"), p: vec("NDOF"), u: vec("MH_M"), W: mat("MH_M", "MH_M"), h: F8, prm: vec("NPRM"),
            hess: mat("2 * NDOF", "2 * NDOF")) -> int:
    """hess = the Hessian of eta in (q, p)."""


# --- generated constants ----------------------------------------------------------------------------

@dataclass(frozen=True)
class ConstantDecl:
    """A module constant of a generated part. slot: how the shared core reads it (vcirun.codegen.shared):
    "int" or "bool" from a scalar slot, "i8" / "f8" an array from (address, length) slots, None a
    compile-time constant of the core itself."""

    name: str
    part: str
    slot: str | None
    doc: str


CONSTANTS: dict[str, ConstantDecl] = {}


def _constant(name: str, part: str, slot: str | None, placeholder, doc: str):
    CONSTANTS[name] = ConstantDecl(name, part, slot, doc)
    return placeholder


# in the shared core's slot order
NDOF = _constant("NDOF", "system", "int", 1, "number of coordinates n")
NCON = _constant("NCON", "system", "int", 1, "number of constraints m")
NODE_LEN = _constant("NODE_LEN", "system", "int", 1, "length of a point's node data (sys_node)")
BAND = _constant("BAND", "system", "int", 0,
                 "half-bandwidth of M(q) and of the step Jacobians (MechanicalSystem.bandwidth)")
MH_M = _constant("MH_M", "modified", "int", 1, "number of eta's stage velocities (all stages)")
FORCED = _constant("FORCED", "system", "bool", False, "the system has a generalized force")
PARTIAL_IS_FULL = _constant("PARTIAL_IS_FULL", "steps", "bool", True,
                            "the partial map is the full map at step tau (PartialMap.is_full)")
EDV_STAGE = _constant("EDV_STAGE", "steps", "int", -1, "stage id of the energy gradient's Ld (-1: none)")
RESET_ID = _constant("RESET_ID", "steps", "int", 0,
                     "index of the kernel set's reset among the resets its shared core holds "
                     "(vcirun.codegen.shared.core_resets)")
MH_ORDER = _constant("MH_ORDER", "modified", "int", 3, "s of H~^{O(h^s)}")
MH_NSTAGE = _constant("MH_NSTAGE", "modified", "int", 1, "explicit stages of the modified Hamiltonian's Ld")
FULL_STAGES = _constant("FULL_STAGES", "steps", "i8", np.zeros(1, np.int64),
                        "stage id of each explicit stage of the full map")
FULL_FRACS = _constant("FULL_FRACS", "steps", "f8", np.ones(1), "fraction of h of each stage")
FORCE_A = _constant("FORCE_A", "steps", "f8", np.zeros(1), "discrete-force weight of f^- per stage id")
FORCE_B = _constant("FORCE_B", "steps", "f8", np.zeros(1), "discrete-force weight of f^+ per stage id")
RESET_MAP = _constant("RESET_MAP", "system", "bool", False,
                      "the system declares a reset map (sys_reset_map; vcirun.mechanics.hybrid)")
RESET_LAW_FIRST = _constant("RESET_LAW_FIRST", "system", "bool", False,
                            "the impact law acts before the declared map (plastic: true or a restitution)")
FRICTION = _constant("FRICTION", "system", "bool", False,
                     "some contact has friction: a coefficient that is a number > 0 or a parameter (sys_friction)")
# the structural nonzeros of G = grad phi in row order (CSR): the loops over every contact on every step
# (touching, normal velocities, touch tolerances) run over them, O(nnz) where G is m x n (the 100-ball
# cradle: 198 of 9900 entries)
DPHI_NNZ = _constant("DPHI_NNZ", "system", "int", 1, "structural nonzeros of G (at least 1: a padding zero)")
DPHI_ROW = _constant("DPHI_ROW", "system", "i8", np.zeros(2, np.int64),
                     "start of row i's nonzeros in sys_dphis_nz's output (NCON + 1 entries)")
DPHI_COL = _constant("DPHI_COL", "system", "i8", np.zeros(1, np.int64),
                     "column of each nonzero, ascending within a row (DPHI_NNZ entries)")
MH_FLOW_S = _constant("MH_FLOW_S", "modified", None, 2,
                      "stages of the Gauss flow (a module-level choice of maps/gauss.py)")

# the record's index and status constants (O_<FIELD>, I_<COUNTER>, S_<SETTING>, ST_<STATUS>)
for _line in record.module_constants().splitlines():
    _name, _value = _line.split(" = ")
    globals()[_name] = _constant(_name, "record", None, int(_value), "vcirun.core.record")
del _line, _name, _value


def generated_names(part: str) -> tuple:
    """The names a generated part defines (kernels and constants)."""
    return tuple(n for n, c in CONSTANTS.items() if c.part == part) + tuple(
        n for n, k in KERNELS.items() if k.part == part)


# --- the roles Algorithm 1 calls ---------------------------------------------------------------------

@dataclass(frozen=True)
class RoleDecl:
    name: str
    params: tuple        # names, in order
    optional: int        # trailing parameters with a default
    returns: tuple       # what the tuple it returns holds (one name: a scalar)
    doc: str


ROLES: dict[str, RoleDecl] = {}


def role(*returns: str):
    """Declare a role by its Python signature; returns: the names of what it returns (one: a scalar);
    the docstring says what holds on return."""
    def deco(fn):
        sig = inspect.signature(fn)
        optional = sum(1 for p in sig.parameters.values() if p.default is not inspect.Parameter.empty)
        ROLES[fn.__name__] = RoleDecl(fn.__name__, tuple(sig.parameters), optional, returns, inspect.getdoc(fn) or "")
        return functools.wraps(fn)(_unavailable(fn.__name__, "a role, bound per module (vcirun.codegen.units)"))
    return deco


@role('iterations', 'Ed')
def full(q0, p0, h, t, prm, ntol, maxit, q1, p1, vlast, want_E=True):
    """The full map Phi_h from (q0, p0) at t: (q1, p1) the state at t + h, vlast the last stage's step
    velocity. Returns (Newton iterations, < 0 on failure; the discrete energy -D3 Ld, NaN when
    want_E is false). ntol, maxit: Newton's tolerance and iteration cap."""


@role('iterations', 'Ed')
def partial(q0, p0, tau, h, t, prm, ntol, maxit, q1, p1, vlast):
    """Phi^partial_tau from (q0, p0) at t (h: the grid step, a parameter of some partial maps): (q1,
    p1) at t + tau, vlast the step velocity. Returns (Newton iterations, < 0 on failure; the discrete
    energy of the step, R^VCI's E_pre)."""


@role('iterations', 's')
def reset(q, pm, d, s0, dE, E_pre, vpre, dtau, tau_rem, h, t, prm, ntol, maxit, pp):
    """The reset at an impact: pp = p(t_i^+) = pm + s d. q is the impact configuration at the impact
    time t, pm = p(t_i^-); d, s0, dE: the impact law's direction, Newton multiplier and continuous
    energy loss (collision/impact.py: one elastic contact d = grad phi, s0 = R^CVA's lambda, dE = 0);
    E_pre, vpre, dtau: the discrete energy, step velocity and length of the partial step that
    reached the impact; tau_rem: the time left in the grid step; h: the grid step. Returns
    (iterations, < 0 on failure; s, the multiplier along d that the record scales the impulses by)."""


@role('value')
def modified_energy(q, p, h, prm):
    """The method's modified energy at (q, p) (the record's Hmod row), NaN for methods without one."""


# --- descriptors: which unit function plays a role, and what it needs --------------------------------

@dataclass(frozen=True)
class PartialMap:
    """name: Method.partial; function: the unit function bound to `partial`, defined in unit; needs:
    generated parts beyond the full map's; is_full: the same map as `full` at step tau (Algorithm 1
    then reuses the full step as the collision search's first partial step: PARTIAL_IS_FULL)."""

    name: str
    unit: str
    function: str
    needs: tuple = ()
    is_full: bool = False


@dataclass(frozen=True)
class ResetMap:
    """name: Method.reset; function: the unit function bound to `reset`, defined in unit (relative to
    the vcirun package, or an absolute path); needs: generated parts beyond the full map's
    ("energy_gradient": dEd/dv of the full map's explicit Ld, "modified": the truncated modified
    Hamiltonian H~, which the method then carries: the role modified_energy and the record's Hmod
    row); conserves: what the reset keeps across an impact ("H", "Ed", "H~", or "" for none);
    impact_order: the method's order through impacts (None: the order of its full map's Ld)."""

    name: str
    unit: str
    function: str
    needs: tuple = ()
    conserves: str = ""
    impact_order: int | None = None

    @property
    def modified_hamiltonian(self) -> bool:
        return "modified" in self.needs

    @property
    def fills(self) -> tuple:
        """The record fields a run of a method with this reset fills (vcirun.core.record.FIELDS)."""
        return tuple(f.name for f in record.FIELDS if f.only is None or (f.only == "modified"
                                                                       and self.modified_hamiltonian))


FULL_MAP = ("maps/steps.py", "ld_step")     # the role full: Phi_h of the scene's discrete Lagrangian
MODIFIED_ENERGY = {False: ("collision/algorithm1.py", "no_modified_energy"), True: ("maps/gauss.py", "mh_energy")}

PARTIALS: dict[str, PartialMap] = {p.name: p for p in (
    PartialMap("ld", "maps/steps.py", "ld_partial", is_full=True),
    PartialMap("gauss", "maps/gauss.py", "gauss_partial", needs=("modified",)),
)}

RESETS: dict[str, ResetMap] = {r.name: r for r in (
    ResetMap("cva", "collision/reset_cva.py", "reset_cva", conserves="H"),
    ResetMap("vci", "collision/reset_vci.py", "reset_vci", needs=("energy_gradient",), conserves="Ed"),
    # the MCVA family is second order overall through impacts (Section 4.3)
    ResetMap("mcva", "collision/reset_mcva.py", "reset_mcva", needs=("modified",), conserves="H~", impact_order=2),
)}
DEFAULT_RESET = "cva"   # bound in the modules of smooth methods (reset None: the loop never calls it)
# the generalized MCVA (Section 4.4): the partial map and the reset of a method on its modified Hamiltonian
MCVA_FAMILY = {"partial": "gauss", "reset": "mcva"}


def register_reset(r: ResetMap) -> ResetMap:
    """Add a reset descriptor (the extension point: a unit file and this row). Raises on a name that
    is taken by another descriptor, a unit file that does not exist, or needs that name no generated
    part; the unit itself is checked when a module is assembled (vcirun.codegen.units.check_unit)."""
    if r.name in RESETS and RESETS[r.name] != r:
        raise ContractError(f"reset {r.name!r}: already declared as {RESETS[r.name]}")
    if not (Path(__file__).resolve().parent.parent / r.unit).is_file():
        raise ContractError(f"reset {r.name!r}: unit {r.unit} is not a file (give a path relative to the vcirun "
                            "package, or an absolute one)")
    bad = [p for p in r.needs if p not in PARTS or p in BASE_PARTS]
    if bad:
        raise ContractError(f"reset {r.name!r}: needs {bad[0]!r}, not a generated part beyond every module's "
                            f"(choose from {', '.join(p for p in PARTS if p not in BASE_PARTS)}, or declare its "
                            "kernel with @kernel(part, derive=...))")
    RESETS[r.name] = r
    return r


def reset_map(name: str | None) -> ResetMap:
    key = DEFAULT_RESET if name is None else name
    if key not in RESETS:
        raise ValueError(f"reset: unknown reset {name!r} (declared: {', '.join(RESETS)}; add one with "
                         "vcirun.codegen.roles.register_reset)")
    return RESETS[key]


def partial_map(name: str) -> PartialMap:
    if name not in PARTIALS:
        raise ValueError(f"partial: unknown partial map {name!r} (declared: {', '.join(PARTIALS)})")
    return PARTIALS[name]


def kernel_set(ld: str, stages: tuple, partial: str, reset: str | None, mh_order=None, flow_order=None) -> KernelSet:
    """The kernel set of a method: the full map's stages, the partial map and reset it binds, and the
    generated parts their descriptors need, each with its argument (PartDecl.arg): the Ld `ld` (the
    energy gradient), (ld, mh_order, flow_order) (the modified Hamiltonian), or True."""
    r, pm = reset_map(reset), partial_map(partial)
    needs = set(r.needs) | set(pm.needs)
    return KernelSet(full_stages=tuple(stages), partial=pm.name, reset=r.name,
                     parts=tuple((p, part_argument(p, ld, mh_order, flow_order)) for p in PARTS if p in needs))


def part_argument(part: str, ld: str, mh_order=None, flow_order=None):
    """What a kernel set gives `part` (PartDecl.arg) for a method on the explicit Ld `ld`."""
    return {"ld": ld, "mh": (ld, mh_order, flow_order), "none": True}[PARTS[part].arg]


# --- names Python calls on a module (vcirun.run, reference/, experiments/, verification/) -----------

ENTRY = {
    # every module, the system-only one included: the continuous dynamics and the contact geometry
    "system": ("hamiltonian", "hamilton_rhs", "dynamics_rhs", "force_power", "gdot", "cva_lambda",
               "mass_matrix_ok", "impact_direction", "gap", "gap_slope", "touching_mask",
               "sys_M", "sys_V", "sys_phi", "sys_dphi", "sys_phis", "sys_dphis", "sys_dphis_nz", "sys_ddphis",
               "sys_Mdotv", "sys_restitution", "sys_dHq", "sys_node", "sys_force", "sys_force_jac", "sys_reset_map",
               "declared_reset", "sys_slips", "sys_dslips", "sys_friction", "friction_impact_direction"),
    # a method's module: the loop, the collision-time search, its full map
    "steps": ("integrate", "collision_time", "ld_step", "full"),
    # the MCVA family's module: the modified Hamiltonian and its Gauss flow
    "modified": ("mh_energy", "mh_terms", "mh_guess", "mh_gradient", "gauss_partial"),
}
# the per-Ld kernels a scene module defines for each explicit Ld of its full map: <LD>_<suffix>
LD_ENTRY = ("PmJ", "Pp", "Ed", "Edv", "PmJc", "Ppc")
