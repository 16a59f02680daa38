"""What a run needs besides its initial state and parameters, resolved once: the `Plan` of a
(system, method, grid, options), and the loop's buffers.

`vcirun.simulate` and `vcirun.ensemble` validate their arguments, resolve the system and the method,
size the memory check, build the settings vector and load the module through `plan`; for
a built-in scene named by a string the result is kept per (system, method, h, T, t0, options), so a
repeated call validates only its initial state and parameters. Each value of the key is kept with
its type, so that a value the checks reject (``constrained=1``, ``h=True``) never matches an
accepted one that compares equal. The kept plans belong to the kernel cache that loaded their modules
(vcirun.codegen.kernel_cache); a YAML file or a MechanicalSystem instance is resolved on every call (a
file may change, an instance may be mutated), and so is every call with a substitute loader (a
function passed as `loader=`).

`Buffers` holds one run's output tuple for reuse by the next run of the same plan in the same
thread: every buffer with a fill value is refilled before a run, so a reused buffer starts exactly
as a newly allocated one (the loop then computes the same bits). The impact record's capacity
grows as `run_loop` grows it; a run always sees the capacity sequence of a fresh allocation (views
of the first rows of a larger buffer).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..core import record
from ..core.bounds import check_simulate_args, check_start_args
from ..core.environ import jit_disabled, snapshot
from ..core.grid import grid_note
from ..core.sizes import check_run_memory, memory_limit, run_bytes
from ..core.system_data import (
    SystemData,
    check_mass_matrix,
    requested_start,
    start_tolerance,
)
from ..codegen.kernel_cache import KernelCache, default
from ..codegen.specialize import module_build, upgrade
from ..codegen.tiers import requested
from ..core.tolerances import DEFAULT_TOLERANCES, split_options
from ..methods.table import resolve_method
from ..scenes.registry import scene_args
from .resolve import _warmable, resolve_numeric, resolve_system, warm_memo


@dataclass(eq=False)
class Plan:
    """A resolved (system, method, grid, options): everything a run takes except its start and
    parameters. `module()` loads the module on the tier asked for (`tier`: auto, interpreted or compiled,
    vcirun.codegen.tiers; `tier_used` says which one it returned) and, in the auto tier, moves to the
    compiled one as soon as it is there (`first_call` makes numba's first call of a compiled loop)."""

    system: object
    sysd: SystemData
    sysm: object            # the symbolic system when it was built (cold path), else None
    meth: object
    load: object
    h: float
    T: float
    N: int
    t0: float
    tol: dict
    mopts: dict
    constrained: bool
    energies: bool
    resting_contact: bool
    settings: np.ndarray
    note: str
    need: int               # bytes of one run's buffers (validation.run_bytes)
    ks: object = None       # the method's KernelSet
    hit: tuple = None       # what resolve_numeric returned (a kept plan is valid while its warm memo holds it)
    kc: KernelCache = None  # the kernel cache that loads its module
    tier: str = "auto"
    tier_used: str = None
    memo: tuple = None      # resolve_numeric's warm memo of a built-in scene (what `_still_warm` looks up)
    _mod: object = None
    _prm: np.ndarray = None  # the default parameter vector
    _up: object = None      # the specialized build of its shared module (vcirun.codegen.specialize)
    hold: bool = False      # keep the module it has (an ensemble: one build for all its runs)
    # memos of values that follow from the fields above (init=False: `dataclasses.replace`, which makes
    # a plan of another grid from a kept one, starts them afresh)
    _t: tuple = field(default=None, init=False, repr=False, compare=False)   # (t0, h, N, t0 + h k for k = 0..N)
    _build: tuple = field(default=(None, None), init=False, repr=False, compare=False)   # (module, its build)
    _tolerances: dict = field(default=None, init=False, repr=False, compare=False)
    _called: object = field(default=None, init=False, repr=False, compare=False)   # the module first_call made ready
    _rows: tuple = field(default=None, init=False, repr=False, compare=False)     # (module, `rows`)
    _fields: dict = field(default=None, init=False, repr=False, compare=False)

    @property
    def max_impacts_step(self) -> int:
        return int(self.tol["max_impacts_step"])

    def module(self):
        """The module a run takes now: the kernels on the tier asked for; in the auto build, the specialized
        module of the same kernels once it is there (vcirun.codegen.specialize), unless the plan holds
        the module it has (`hold`) or its kernel cache holds the shared build (`specialize` False)."""
        up = self._up
        if self._mod is None or (self.tier_used == "interpreted" and self.tier == "auto" and self.load.poll()):
            if self._mod is None:
                up = self._up = upgrade(self.kc or default(), self.load, self.tier)
            if up is not None and self._specialized(up):
                self._mod, self.tier_used = up.mod, "compiled"
            else:
                self._mod = self.load(self.tier)
                self.tier_used = self.load.tier
        elif (up is not None and not self.hold and self.tier_used == "compiled" and self._mod is not up.mod
              and up.kc.specialize and self._specialized(up)):
            self._mod = up.mod   # (loaded here, or by another plan of the same module)
        return self._mod

    @staticmethod
    def _specialized(up) -> bool:
        """Is the specialized module there (loaded by any plan of the module, or found now)?"""
        return up.mod is not None or (up.due() and up.poll() is not None)

    @property
    def build_used(self) -> str | None:
        """The build of the compiled module last returned ("shared" or "specialized"; None on the
        interpreted tier, and where numba compiles nothing: NUMBA_DISABLE_JIT=1)."""
        mod, build = self._build
        if mod is not self._mod:   # (the tier and the environment that chooses the build are the plan's)
            build = None if self.tier_used != "compiled" or jit_disabled() else module_build(self._mod)
            self._build = (self._mod, build)
        return build

    def ran(self, seconds: float) -> None:
        """A run of its module took `seconds` in the compiled loop (what makes a module hot)."""
        if self._up is not None and self.tier_used == "compiled":
            self._up.seconds += seconds

    def grid(self, steps: int) -> np.ndarray:
        """t0 + h k, k = 0..steps (a new array per call; the whole grid's values computed once per plan)."""
        memo = self._t
        if memo is None or memo[:3] != (self.t0, self.h, self.N):
            memo = self._t = (self.t0, self.h, self.N, self.t0 + self.h * np.arange(self.N + 1))
        t = memo[3]
        return t.copy() if steps == self.N else t[: steps + 1].copy()

    def rows(self, mod) -> tuple:
        """(silent, own, records) of its runs on module `mod`. silent: the indices of the grid and step rows
        a run does not return and whose values the loop never reads (Buffers.get); own: the grid and
        step rows `take` hands over; records: the record rows `take` copies by count. Left out: the
        modified energy of a method without one (the loop writes it, a run returns None) and, in a
        module without friction, the friction rows and the tangential impulses (never written, or
        written 0: the Trajectory makes their zeros on first read)."""
        r = self._rows
        if r is None or r[0] is not mod:
            friction = bool(getattr(mod, "FRICTION", False))
            silent = (() if self.ks.modified is not None else (_HMOD,)) + (() if friction else _FRICTION_ROWS)
            records = _RECORDS if friction else tuple(
                (axis, counter, tuple(x for x in fields if x[1] != _IMPULSE_T)) for axis, counter, fields in _RECORDS)
            r = self._rows = (mod, (silent, tuple(x for x in _OWN if x[1] not in silent), records))
        return r[1]

    def fields(self, defaults) -> dict:
        """A new dict of what every Trajectory of its runs holds before its run's own values: the
        defaults of Trajectory.of_run (`defaults()`: vcirun.run.trajectory.run_defaults), the method,
        system, h, T, coordinates and source (made once per plan)."""
        f = self._fields
        if f is None:
            f = self._fields = defaults()
            f.update(method=self.meth.name, system=self.sysd.name, h=self.h, T=self.N * self.h,
                     coordinates=getattr(self.sysd, "coordinates", None), source=self.system)
        return dict(f)

    def tolerances(self) -> dict:
        """The run's solver tolerances by name (a new dict per call)."""
        t = self._tolerances
        if t is None:
            t = self._tolerances = {k: self.tol[k] for k in DEFAULT_TOLERANCES}
        return dict(t)

    def check_memory(self) -> None:
        """The memory check of one run against the limit in force now (a sweep scopes its own)."""
        if self.need > memory_limit():
            check_run_memory(self.N, self.sysd.n)

    def params(self, params) -> np.ndarray:
        """The run's parameter vector (a new array per call; the defaults' checks run once per plan)."""
        if params is not None:
            return self.sysd.param_values(params)
        if self._prm is None:
            self._prm = self.sysd.param_values(None)
        return self._prm.copy()


def build_of(mod, tier: str | None) -> str | None:
    """The build of a module loaded on `tier`: "shared" or "specialized" for a compiled module, None on
    the interpreted tier and where numba compiles nothing (NUMBA_DISABLE_JIT=1)."""
    if tier != "compiled" or jit_disabled():
        return None
    return module_build(mod)


def first_call(mod, plan: Plan, q0, p0, prm) -> None:
    """numba's first call of a module's loop (load from its cache, or compile) is not integration:
    one untimed step from the run's start, so a run's wall_time measures the integration only (once per
    module and kernel cache)."""
    if plan._called is mod:
        return
    kc = plan.kc or default()
    if mod.__name__ in kc.first_calls or getattr(mod, "TIER", "") == "interpreted":
        plan._called = mod
        return
    from ..codegen.cache import first_call_lock, note_first_call

    kc.first_calls.add(mod.__name__)
    t_first = time.perf_counter()
    with first_call_lock(mod, kc=kc):  # one compile per module across processes (sweep and test workers)
        run_loop(mod, q0, p0, plan.t0, plan.h, 1, prm, plan.settings, plan.sysd.n, plan.max_impacts_step)
    note_first_call(mod, plan.meth.kernel_set(), time.perf_counter() - t_first, kc=kc)
    plan._called = mod


_PLANS_MAX = 64   # plans kept per kernel cache
# the environment that chooses a module (vcirun.codegen.modules.build_id and the kernel path)
_BUILD_ENV = ("VCIRUN_BUILD", "NUMBA_DISABLE_JIT", "VCIRUN_CORE_NDOF", "VCIRUN_KERNEL_PATH")


def _key(system, method, h, T, t0, constrained, energies, resting_contact, options, tier):
    """The key of a plan kept for reuse (None: resolve per call): a built-in scene's name (checked
    when the plan is stored), the method's name, every value with its type, the build mode, the tier."""
    if type(system) is not str or type(method) is not str:
        return None
    # the settings that choose the module, as set (a finer key than the build id they make)
    key = (system, method, snapshot(_BUILD_ENV), tier, type(h), h, type(T), T,
           type(t0), t0, type(constrained), constrained, type(energies), energies, type(resting_contact),
           resting_contact)
    if options:
        key += tuple(sorted((k, type(v), v) for k, v in options.items()))
    try:
        hash(key)
    except TypeError:   # an option value that is not hashable (a list): resolved per call
        return None
    return key


def plan(system, method, *, h, T, t0=0.0, constrained=None, energies=True, resting_contact=True,
         options: dict | None = None, start: dict | None = None, kc: KernelCache | None = None,
         tier=None) -> Plan:
    """The Plan of a run; `start` holds the per-run arguments (beta, q0, p0, params) of a call,
    validated here with the rest (same checks, order and messages as one call of simulate). `kc`: the
    kernel cache (default: the API's), which keeps the plan when the run names a built-in scene; `tier`:
    vcirun.codegen.tiers.requested (None: $VCIRUN_TIER, else auto)."""
    start = start or {}
    kc = default() if kc is None else kc
    tier = requested(tier)
    key = _key(system, method, h, T, t0, constrained, energies, resting_contact, options, tier) if kc.warm else None
    if key is not None:
        with kc.lock:
            p = kc.plans.get(key)
            if p is not None:
                kc.plans.move_to_end(key)
        if p is not None and _still_warm(p, key):
            check_start_args(**start)
            return p
    mopts, tol = split_options(options or {})
    h, T, N = check_simulate_args(h=h, T=T, t0=t0, constrained=constrained, energies=energies, tolerances=tol,
                                  system=system, resting_contact=resting_contact, **start)
    if not _warmable(system):
        system = resolve_system(system)  # bad names and files raise here, before a bad method does
    meth = resolve_method(method, **mopts)
    ks = meth.kernel_set()
    hit = resolve_numeric(system, ks, kc)
    sysd, load, sysm = hit
    if constrained is None:
        constrained = meth.constrained
    settings = record.settings_vector(constrained=bool(constrained), energies=bool(energies),
                                      resting_contact=bool(resting_contact), **tol)
    p = Plan(system=system, sysd=sysd, sysm=sysm, meth=meth, load=load, h=h, T=T, N=N, t0=float(t0), tol=tol,
             mopts=mopts, constrained=bool(constrained), energies=bool(energies),
             resting_contact=bool(resting_contact), settings=settings, note=grid_note(h, T),
             need=run_bytes(N, sysd.n), ks=ks, hit=hit, kc=kc, tier=tier)
    if key is not None and sysm is None and scene_args(system) is not None:   # warm: nothing symbolic held
        p.memo = warm_memo(("scene", system), ks)   # (read only for a kept plan)
        with kc.lock:
            kc.plans[key] = p
            while len(kc.plans) > _PLANS_MAX:
                kc.plans.popitem(last=False)
    return p


def _still_warm(p: Plan, key) -> bool:
    """The warm-start memo that served plan `p` still holds its entry."""
    return p.kc.warm_hits.get(p.memo) is p.hit




# --- the initial state ------------------------------------------------------------------------------

def start_state(d: SystemData, beta, q0, p0, prm, sysm=None):
    """Validate the requested initial state before any kernel is loaded: ("state", q0, p0) or
    ("legendre", q0, qdot0) (p0 = M(q0) qdot0 is computed by `initial_state` with the compiled M).
    Same rules and messages as MechanicalSystem.initial_state; with the symbolic system at hand
    (cold path) the hyperregularity check runs here, before anything is generated or compiled."""
    kind, q0, p0 = requested_start(d, beta, q0, p0, prm)
    if sysm is not None:
        sysm.check_hyperregular(q0, prm)
    return kind, q0, p0, sysm is not None


def initial_state(d: SystemData, mod, start, prm, Mq=None):
    """(q0, p0) from `start_state`. The Legendre transform uses the module's compiled M(q) on every
    path, so warm and cold starts compute the same bits; on the warm path the hyperregularity check
    uses it too (compiled: mass_matrix_ok; numpy's check then only words the error). Mq: an n x n
    array to hold M(q0) (`Buffers.scratch`), else a new one."""
    kind, q0, p0, checked = start
    q0 = np.ascontiguousarray(q0, dtype=float)
    if Mq is None:
        Mq = np.empty((q0.shape[0], q0.shape[0]))
    ok = mod.mass_matrix_ok(q0, prm, Mq)   # M(q0) once, for the check and the Legendre transform
    if not checked and not ok:
        check_mass_matrix(d.name, q0, Mq)
    if kind == "legendre":
        p0 = Mq.dot(p0)   # (numpy's gemv, as @, in a third of its time)
    return q0, p0


def check_admissible(d: SystemData, mod, q0, prm, phi_text, phis=None) -> None:
    """A start inside the constraint is bad input (ValueError naming phi(q0), its value and the
    constraint phi_text() -- called only then: on the warm path it builds the symbolic system), not a
    run that ends later as `reset_failed` or `accumulation`; a start on the surface (to round-off)
    is allowed. phis: an array of the module's contacts to hold phi(q0) (`Buffers.scratch`)."""
    m = int(mod.NCON)
    if phis is None:
        phis = np.empty(m)
    G = None
    mod.sys_phis(q0, prm, phis)
    for i in range(m):
        if 0.0 <= phis[i] < math.inf:   # outside or on the surface: no tolerance to compute
            continue
        if G is None:
            G = np.empty((m, d.n))
            mod.sys_dphis(q0, prm, G)
        if not math.isfinite(phis[i]) or phis[i] < -start_tolerance(q0, G[i]):
            raise ValueError(f"initial state: q0={q0.tolist()} lies inside the constraint of system {d.name}: "
                             f"phi(q0) = {phis[i]:.6g} < 0 for {phi_text(i)}; start where phi(q0) >= 0 "
                             "(or pass constrained=False)")


def constraint_text(sysm, i: int) -> str:
    c = sysm.constraints[i]
    return f"phi = {c.phi}" if sysm.m == 1 else f"constraint {c.name} (phi = {c.phi})"


def ready_start(p: Plan, mod, start, prm, buffers: Buffers | None = None):
    """(q0, p0) of one run of plan `p` from its `start_state` (ValueError for a start the run refuses,
    or for friction coefficients the run's parameters make invalid: mu < 0, mu_s < mu); buffers: this
    thread's (their scratch holds M(q0) and phi(q0))."""
    if getattr(mod, "FRICTION", False):
        from ..core.system_data import friction_at

        friction_at(mod, prm, p.sysd.name)
    Mq, phis = (None, None) if buffers is None else buffers.scratch(p.sysd.n, int(mod.NCON))
    q0, p0 = initial_state(p.sysd, mod, start, prm, Mq)
    if p.constrained:
        check_admissible(p.sysd, mod, q0, prm, lambda i: constraint_text(p.sysm or resolve_system(p.system), i),
                         phis)
    return q0, p0


# --- the loop ---------------------------------------------------------------------------------------

class Buffers:
    """One run's output tuple, kept for the next run of the same size in this thread.

    keep_grid=True (an ensemble, which reads its results out of the buffers): every buffer is kept, and
    those with a fill value are refilled before each run. keep_grid=False (simulate, which hands its
    grid and step rows to the Trajectory: `take`): the grid and step rows are new arrays per run,
    allocated with their fills, and only the impact, partial-step, release and mode-change records
    are kept; those have no fill (the loop writes each entry it counts) and `take` copies what a run
    counted. The rows a run does not return and its loop never reads (`get`'s silent: `Plan.rows`) are
    this object's own, made once per size. Either way every row a run reads or returns starts exactly
    as in newly allocated buffers."""

    def __init__(self, keep_grid: bool):
        self.keep_grid = keep_grid
        self.dims, self.cap, self.big, self.views, self.views_cap = None, -1, None, None, -1
        fresh = () if keep_grid else ("grid", "step")
        self._fresh = tuple(i for i, f in enumerate(record.FIELDS) if f.axis in fresh)
        self._refill = tuple((i, f.fill) for i, f in enumerate(record.FIELDS)
                             if f.fill is not None and i not in self._fresh)   # reused, refilled per run
        self._specs = {}   # silent -> (index, shape, dtype, fill) of each fresh row at the current dims
        self._own = {}     # index -> a silent row's array at the current dims (never handed over)
        self._scratch = (None, None, None)   # ((n, m), M(q0), phi(q0)) of a run's start (`scratch`)

    def scratch(self, n: int, m: int) -> tuple:
        """(an n x n array, an array of m): room for a start's M(q0) and phi(q0) (ready_start), which
        never leave it."""
        s = self._scratch
        if s[0] != (n, m):
            s = self._scratch = ((n, m), np.empty((n, n)), np.empty(m))
        return s[1], s[2]

    def get(self, N: int, n: int, m: int, cap_imp: int, silent: tuple = ()) -> tuple:
        if self.big is None or self.dims != (N, n, m) or self.cap < cap_imp:
            self.big = record.allocate(N, n, m=m, cap_impacts=cap_imp)   # as a fresh run's: no refill
            self.dims, self.cap, self.views, self.views_cap = (N, n, m), cap_imp, list(self.big), cap_imp
            self._specs, self._own = {}, {}
            return self.big   # (its silent rows stay with it: a run never returns them)
        if self.views_cap != cap_imp:   # a run that starts again with the smaller first capacity
            rows = record.axis_rows(N, cap_imp)
            self.views = [b if b.shape[0] == rows[f.axis] else b[: rows[f.axis]]
                          for f, b in zip(record.FIELDS, self.big)]
            self.views_cap = cap_imp
        out = list(self.views)
        if self.keep_grid:
            silent = ()
        spec = self._specs.get(silent)
        if spec is None:
            spec = self._specs[silent] = tuple((i, self.big[i].shape, self.big[i].dtype, record.FIELDS[i].fill)
                                               for i in self._fresh if i not in silent)
        empty, zeros = np.empty, np.zeros
        for i, shape, dt, fill in spec:   # the rows the previous run left with its Trajectory
            if fill is None:
                out[i] = empty(shape, dt)
            elif fill == 0:
                out[i] = zeros(shape, dt)   # (0, 0.0 and False: all-zero bytes)
            else:
                a = out[i] = empty(shape, dt)
                a.fill(fill)
        for i in silent:   # (not big's: big's row may be with the Trajectory of a run that returned it)
            a = self._own.get(i)
            if a is None:
                a = self._own[i] = np.empty(self.big[i].shape, self.big[i].dtype)
                a.fill(0 if record.FIELDS[i].fill is None else record.FIELDS[i].fill)
            out[i] = a
        for i, fill in self._refill:
            out[i].fill(fill)
        return tuple(out)


# what `take` reads: every field's name in table order; the grid and step rows (name, index, axis),
# handed over; the records by axis (axis, counter of its entries, ((name, index), ...)), copied
_NAMES = tuple(f.name for f in record.FIELDS)
_OWN = tuple((f.name, i, f.axis) for i, f in enumerate(record.FIELDS) if f.axis in ("grid", "step"))
_RECORDS = tuple((axis, counter, tuple((f.name, i) for i, f in enumerate(record.FIELDS) if f.axis == axis))
                 for axis, counter in (("impact", "n_impacts"), ("partial", "n_partial"), ("release", "n_releases"),
                                       ("mode", "n_mode_changes")))
_Q = _NAMES.index("q")
# rows a run may not return (Plan.rows): the modified energy (methods without one), the friction rows
# and the tangential impulses (a module without friction never writes the first two and writes 0 in
# the third)
_HMOD = _NAMES.index("Hmod")
_FRICTION_ROWS = (_NAMES.index("contact_mode"), _NAMES.index("friction_work"))
_IMPULSE_T = _NAMES.index("impact_impulse_t")


def take(out: tuple, counters: dict, modified: bool, own: tuple = _OWN, records: tuple = _RECORDS,
         into: dict | None = None) -> dict:
    """{name: array} of a finished loop whose grid and step rows are its own (`Buffers(keep_grid=False)`,
    or buffers allocated for the run): the grid and step rows of `own` ((name, index, axis)) as they are
    (views up to the states and steps reached where the run stopped early), the record rows of
    `records` ((axis, counter, ((name, index), ...))) copied up to their counts. The defaults take
    every row; `Plan.rows` leaves out those a run does not return. A row left out and a record with
    no entries are not in the dict (Trajectory.of_run's derive makes them on first read); Hmod is None
    without `modified`. The values of `vcirun.core.record.trim`; `into`: the dict to add them to."""
    steps = counters["steps"]
    arrays = {} if into is None else into
    if steps + 1 != out[_Q].shape[0]:   # a run that stopped before t_N
        for name, i, axis in own:
            arrays[name] = out[i][: steps + 1 if axis == "grid" else steps]
    else:
        for name, i, _ in own:
            arrays[name] = out[i]
    for axis, counter, fields in records:
        k = counters[counter]
        if k:
            for name, i in fields:
                arrays[name] = out[i][:k].copy()
    if not modified:
        arrays["Hmod"] = None
    return arrays


def run_loop(mod, q0, p0, t0, h, N, prm, settings, n, max_impacts_step, buffers: Buffers | None = None,
             silent: tuple = ()):
    """(output buffers, counters, seconds in the compiled loop) of a run. The impact record starts at
    N / 4 + 16 entries; the loop reports ST_ACCUMULATION also when it is full, which is a buffer size,
    not impacts accumulating: then it reruns with room for every impact the caps allow. The seconds
    are those of the compiled calls alone (a Trajectory's `wall_time`); preparing the buffers is the
    caller's time."""
    cap_imp, most = record.impact_capacity(N), N * max_impacts_step + 16
    m = int(mod.NCON)
    wall = 0.0
    while True:
        if buffers is None:
            out = record.allocate(N, n, m=m, cap_impacts=cap_imp)
        else:
            out = buffers.get(N, n, m, cap_imp, silent)
        info = np.zeros(len(record.COUNTERS), dtype=np.int64)
        # no np.errstate here: the compiled loop never touches numpy's error state, and with
        # NUMBA_DISABLE_JIT=1 the caller's np.errstate(all="raise") must reach the numerics
        t_start = time.perf_counter()
        mod.integrate(q0, p0, t0, h, N, prm, settings, out, info)
        wall += time.perf_counter() - t_start
        counters = dict(zip(record.COUNTERS, info.tolist()))
        full_record = counters["n_impacts"] + m > cap_imp  # (an impact adds up to NCON entries)
        if not (counters["status"] == record.STATUS_OF["accumulation"] and full_record) or cap_imp >= most:
            return out, counters, wall
        cap_imp = min(4 * cap_imp, most)
