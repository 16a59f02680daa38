"""Runs of one scene from one start at chosen (method, N), cheaply: what the error estimate's
companion runs and the tolerance-driven choice's pilot runs are.

A `Runner` holds a (system, start, parameters, horizon, options) and runs any method on the grid
t_k = t0 + k T / N. It resolves each method's plan once (`vcirun.run.plan.plan`, the checks and
messages of `vcirun.simulate`) and runs the compiled loop directly for every other N, without
building a Trajectory unless asked: a pilot keeps its grid q and p, its impact and release
record and its status, and costs the loop and little else. Every run is the run `vcirun.simulate`
makes with the same arguments (same plan, same start, same loop): bit for bit, so a pilot can be
returned as the final trajectory and a companion compares with the user's run exactly. A twin
(`Runner.run(perturb=...)`) is the same run with h or the start moved by a few ulps: how far it
ends from the run is the round-off floor the motion amplifies.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from ..core import record
from ..core.bounds import nonfinite_start
from ..core.sizes import check_run_memory, memory_limit, run_bytes
from ..core.system_data import start_beta

_STATUS = record.STATUS_CODES
_INDEX = {f.name: k for k, f in enumerate(record.FIELDS)}
_EPS = float(np.finfo(float).eps)
PERTURB_ULPS = 8.0   # the twin runs of `Runner.run(perturb=...)` differ from the run by this many eps
DEFER_BYTES = 64 << 20   # Runner.run(trajectory="later") keeps a run's buffers up to this size for its build


def _nudged(x: np.ndarray, sign: float) -> np.ndarray:
    """x moved by PERTURB_ULPS eps max|x| in alternating signs (a copy)."""
    scale = float(np.max(np.abs(x))) if x.size else 0.0
    signs = np.where(np.arange(x.size) % 2 == 0, sign, -sign).reshape(x.shape)
    return x + PERTURB_ULPS * _EPS * max(scale, 1e-300) * signs


@dataclass
class Run:
    """What a pilot or companion run keeps: method (the Method), N, h, t0, grid q and p (N+1, n),
    impacts (time, contact) and releases (time, contact), contact_active (grid x m) held contacts,
    status, the loop's wall time, the CPU time of the whole run, and the Trajectory if one was built."""

    method: object
    N: int
    h: float
    t0: float
    q: np.ndarray
    p: np.ndarray
    impacts: np.ndarray
    impact_contact: np.ndarray
    releases: np.ndarray
    release_contact: np.ndarray
    held: bool
    status: str
    wall: float
    cpu: float
    trajectory: object = None
    holds: tuple = ()    # (time, contact) where a contact not held at the start comes to rest
    # Runner.run(trajectory="later"): builds the Trajectory when `built()` first asks for it
    pending: object = dataclasses.field(default=None, repr=False)
    # what comparisons compute once per run: coarser N -> its Difference (the ladder); "phis", ("near", k),
    # "min_gap" (vcirun.run.estimate)
    diffs: dict = dataclasses.field(default_factory=dict, repr=False)

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def built(self):
        """The run's Trajectory (None for a run made without one), built now if its build was deferred."""
        if self.trajectory is None and self.pending is not None:
            tr, self.pending = self.pending(), None
            if tr.status != self.status:   # (Runner.run read the status as the Trajectory gives it)
                raise RuntimeError(f"a deferred Trajectory has status {tr.status}, its run {self.status}")
            self.trajectory = tr
        return self.trajectory

    @property
    def t(self) -> np.ndarray:
        return self.t0 + self.h * np.arange(self.q.shape[0])

    @classmethod
    def of_trajectory(cls, tr, method, mod=None, prm=None) -> "Run":
        """The Run view of a finished Trajectory (the user's run, compared with its companions); with
        its module and parameters, a hold the record starts with is checked against phi(q0)."""
        held = bool(np.any(tr.contact_active)) or len(tr.releases) > 0
        t0 = float(tr.t[0]) if len(tr.t) else 0.0
        impacts, contacts = np.asarray(tr.impacts, float), np.asarray(tr.impact_contact)
        holds = hold_onsets(np.asarray(tr.contact_active), t0, float(tr.h),
                            start_gaps(mod, tr.q[0], prm) if mod is not None and len(tr.q) else None)
        if mod is not None and holds:
            holds = accumulated_holds(holds, impacts, contacts, float(tr.h), restitutions(mod, prm))
        return cls(method=method, N=tr.n_steps, h=float(tr.h), t0=t0, q=tr.q,
                   p=tr.p, impacts=impacts, impact_contact=contacts,
                   releases=np.asarray(tr.releases, float), release_contact=np.asarray(tr.release_contact),
                   held=held, status=tr.status, wall=float(tr.wall_time), cpu=float("nan"), trajectory=tr,
                   holds=holds)


def hold_onsets(active: np.ndarray, t0: float, h: float, start_phis=None) -> tuple:
    """((time, contact), ...) of the grid points where a contact not held before comes to rest. A
    contact the record holds at t0 is an onset too unless it starts on its surface (start_phis: phi_i
    at q0 within 1e-9 of 0; without them every hold at t0 counts as a resting start)."""
    if active.ndim != 2 or not active.any():
        return ()
    out = []
    if start_phis is not None:
        out += [(t0, int(c)) for c in np.flatnonzero(active[0]) if abs(float(start_phis[c])) > 1e-9]
    if active.shape[0] > 1:
        on = active[1:] & ~active[:-1]
        ks, cs = np.nonzero(on)
        # t0 + (k + 1) h in float64, as Python computes it from the int k + 1 (exact below 2^53)
        out += zip((t0 + (ks + 1).astype(float) * h).tolist(), cs.tolist())
    return tuple(out)


def accumulated_holds(onsets: tuple, impacts, impact_contact, h: float, restitution) -> tuple:
    """The hold onsets that accumulating impacts may have made: all but those of a plastic contact
    (restitution 0) that begin in the step of one of its impacts. A plastic impact leaves its contact
    at rest at once, as the law says, at an impact time the runs locate to their order; after an impact
    with e > 0 a run holds the contact where the bounce left is below what its step resolves, and that
    depends on h (vcirun.run.estimate.difference reads these onsets as unresolved)."""
    if not onsets or restitution is None:
        return onsets
    out = []
    for t, c in onsets:
        if restitution[c] == 0.0:
            ti = impacts[impact_contact == c]
            # the onset is the grid point after the step of the impact: t - h < t_impact <= t
            if np.any((ti > t - h * (1.0 + 1e-9)) & (ti <= t + 1e-12 * max(1.0, abs(t)))):
                continue
        out.append((t, c))
    return tuple(out)


def restitutions(mod, prm) -> np.ndarray:
    """e of every contact at parameters prm."""
    out = np.empty(int(mod.NCON))
    mod.sys_restitution(np.ascontiguousarray(prm, dtype=float), out)
    return out


def start_gaps(mod, q0, prm) -> np.ndarray:
    """phi_i(q0) of every contact."""
    out = np.empty(int(mod.NCON))
    mod.sys_phis(np.ascontiguousarray(q0, dtype=float), prm, out)
    return out


def _zero_fill(fill, dt) -> bool:
    """A fill whose bytes are all zero (0, 0.0, False): np.zeros makes it (from zeroed pages: cheaper
    than np.full writing every entry of a large buffer), with the same bits."""
    return fill is not None and not np.full((), fill, dt).tobytes().strip(b"\0")


class _FreshBuffers:
    """Fresh output buffers for each run of the loop (`record.allocate`'s, bit for bit), with the trailing
    shapes, dtypes and fills of each (n, m) worked out once and the rows of each axis from
    `record.axis_rows` (the `buffers` that `vcirun.run.plan.run_loop` takes). One per process (`_FRESH`):
    a scene's (n, m) recurs from call to call of `simulate(tol=...)`, its N does not."""

    def __init__(self):
        self.specs: dict = {}

    def get(self, N: int, n: int, m: int, cap_imp: int, silent: tuple = ()) -> tuple:   # (all fresh, silent or not)
        spec = self.specs.get((n, m))
        if spec is None:
            if len(self.specs) > 256:
                self.specs.clear()
            spec = []
            for f in record.FIELDS:
                dt = np.bool_ if f.dtype == "bool" else np.dtype(f.dtype)
                # 0: np.empty; 1: np.zeros (a fill of all-zero bytes, from zeroed pages); 2: np.full's fill
                kind = 0 if f.fill is None else 1 if _zero_fill(f.fill, dt) else 2
                spec.append((f.axis, f.shape(0, n, m)[1:], dt, kind, f.fill))
            spec = self.specs[(n, m)] = tuple(spec)
        rows = record.axis_rows(N, cap_imp)
        empty, zeros = np.empty, np.zeros
        out = []
        add = out.append
        for axis, tail, dt, kind, fill in spec:
            if kind == 0:
                add(empty((rows[axis],) + tail, dt))
            elif kind == 1:
                add(zeros((rows[axis],) + tail, dt))
            else:   # (what np.full does: an empty array, then every entry set to the fill)
                a = empty((rows[axis],) + tail, dt)
                a.fill(fill)
                add(a)
        return tuple(out)


_FRESH = _FreshBuffers()


class _Lazy:
    """Names this module imports on first use (vcirun.run.plan and vcirun.methods.table load kernels'
    machinery), kept: an import statement in a function costs a microsecond or two per call."""

    def __getattr__(self, name):
        from ..methods.table import resolve_method
        from . import plan

        self.resolve_method, self.run_loop, self.build_of = resolve_method, plan.run_loop, plan.build_of
        self.plan, self.start_state, self.ready_start, self.first_call = (plan.plan, plan.start_state, plan.ready_start,
                                                                          plan.first_call)
        return getattr(self, name)


_LAZY = _Lazy()
_BYTES: dict = {}   # (N, n) -> run_bytes(N, n), a pure function of the sizes


class Runner:
    """Runs of `system` from one start on [t0, t0 + T] (T the horizon of every run: h = T / N).

    system, beta, q0, p0, params, t0, constrained, resting_contact, options: as `vcirun.simulate`'s
    (options: newton_tol, event_tol, max_iter, max_impacts_step). Method options (ld, mh_order,
    flow_order) go with the method: pass a `vcirun.methods.table.Method` or a name."""

    def __init__(self, system, *, T, t0=0.0, beta=None, q0=None, p0=None, params=None, constrained=None,
                 resting_contact=True, options=None, build=None, tier=None, kc=None):
        self.system, self.T, self.t0 = system, float(T), float(t0)
        self.tier, self.kc = tier, kc   # vcirun.codegen.tiers.requested's tier and the kernel cache of plan()
        self.build = build   # vcirun.run.api.trajectory_of, for runs that return their Trajectory
        self.start = dict(beta=beta, q0=q0, p0=p0, params=params)
        self.params = params
        self.constrained, self.resting_contact = constrained, resting_contact
        self.options = dict(options or {})
        self._plans: dict = {}    # (method, energies) -> (plan, module, q0, p0, prm, beta): see _base
        self._resolved: dict = {}  # (method, energies) -> (plan, module, prm, beta, start): see _resolve
        self._tiers: dict = {}    # id(module) -> the tier it was loaded on
        self._states: dict = {}   # (sysd, sysm) ids -> (prm, beta, start_state)
        self._ready: dict = {}    # (module, sysd, sysm, constrained) ids -> (q0, p0) as the runs take them
        self._checked = False     # plan() has checked the start's arguments (beta, q0, p0, params)

    # --- plans --------------------------------------------------------------------------------------
    def _resolve(self, method, energies: bool):
        """(plan, module, prm, beta, start) of `method` (resolved once per method and energies flag): the
        plan, the start validated (`start_state`: one per system, whatever the method), and the module
        its runs take, loaded after that validation, as simulate loads it."""
        fast = (method, energies) if isinstance(method, str) else None
        hit = self._resolved.get(fast) if fast is not None else None
        if hit is not None:
            return hit
        meth = _LAZY.resolve_method(method)
        key = (meth, energies)
        hit = self._resolved.get(key)
        if hit is None:
            # a name (not the Method) lets plan() keep the plan of a built-in scene across Runners; the start's
            # arguments are the same for every plan of this Runner: plan() checks them on the first
            p = _LAZY.plan(self.system, method if isinstance(method, str) else meth, h=self.T, T=self.T, t0=self.t0,
                           constrained=self.constrained,
                           energies=energies, resting_contact=self.resting_contact, options=self.options,
                           start=None if self._checked else self.start, kc=self.kc, tier=self.tier)
            self._checked = True
            sysd = p.sysd
            # (the objects keyed by id stay alive in self._resolved)
            st = self._states.get((id(sysd), id(p.sysm)))
            if st is None:
                prm = sysd.param_values(self.params)
                beta = start_beta(sysd, self.start["beta"], self.start["q0"], self.start["p0"])
                st = self._states[(id(sysd), id(p.sysm))] = (
                    prm, beta, _LAZY.start_state(sysd, beta, self.start["q0"], self.start["p0"], prm, p.sysm))
            mod = p.module()   # (after the start is validated, as simulate does)
            self._tiers[id(mod)] = p.tier_used   # (the tier of this module; the kept plan may move on later)
            hit = self._resolved[key] = (p, mod) + st
        if fast is not None:
            self._resolved[fast] = hit
        return hit

    def _base(self, method, energies: bool):
        """(plan, module, q0, p0, prm, beta) of `method` (resolved once per method and energies flag)."""
        fast = (method, energies) if isinstance(method, str) else None
        hit = self._plans.get(fast) if fast is not None else None
        if hit is not None:
            return hit
        p, mod, prm, beta, start = self._resolve(method, energies)
        key = (_LAZY.resolve_method(method), energies)
        hit = self._plans.get(key)
        if hit is None:
            # the start as the run takes it depends on the module, the system and the constraint flag, not
            # on the energies flag: a method's runs with and without energies share it (the same functions
            # of the same arguments, the same bits)
            rk = (id(mod), id(p.sysd), id(p.sysm), p.constrained)
            ready = self._ready.get(rk)
            if ready is None:
                ready = self._ready[rk] = _LAZY.ready_start(p, mod, start, prm)
            q0, p0 = ready
            _LAZY.first_call(mod, p, q0, p0, prm)
            hit = self._plans[key] = (p, mod, q0, p0, prm, beta)
        if fast is not None:
            self._plans[fast] = hit
        return hit

    def method(self, method):
        return _LAZY.resolve_method(method)

    def module(self, method):
        return self._base(method, False)[1]

    def tier_used(self, method) -> str | None:
        """The tier `method`'s runs take (vcirun.codegen.tiers: "compiled", "interpreted" or "substitute"):
        the module its runs take, without preparing the start for it (a method asked only for its tier
        may make no run)."""
        return self._tiers.get(id(self._resolve(method, False)[1]))

    def params_vector(self, method) -> np.ndarray:
        return self._base(method, False)[4]

    def forced(self, method) -> bool:
        if not hasattr(self, "_forced"):
            self._forced = bool(getattr(self.module(method), "FORCED", False))
        return self._forced

    def n_contacts(self, method) -> int:
        return int(self.module(method).NCON)

    # --- runs ---------------------------------------------------------------------------------------
    def run(self, method, N: int, *, trajectory: bool | str = False, energies: bool | None = None,
            perturb: str | None = None) -> Run:
        """The run of `method` on N steps of h = T / N. trajectory=True also builds the Trajectory
        `vcirun.simulate` returns (energies along the grid unless energies=False), with the Runner's
        `build` (vcirun.run.api.trajectory_of, handed in by the caller: this module does not import the API).
        trajectory="later": the same run, its Trajectory built when `Run.built()` asks for it (a choice
        makes several final runs and returns one); built at once where the run's buffers, which a
        deferred build keeps, are large (over DEFER_BYTES).

        perturb: a twin of that run that differs from it at the level of round-off only, for measuring
        how much the motion amplifies round-off (`vcirun.run.estimate.amplified_floor`): "h" runs with
        h (1 + PERTURB_ULPS eps) (every step rounds differently; the grid times move by at most
        PERTURB_ULPS eps T), "start" from q0 and p0 moved by PERTURB_ULPS eps times their largest entry,
        in alternating signs. Never with trajectory=True."""
        run_loop = _LAZY.run_loop
        if trajectory and self.build is None:
            raise ValueError("trajectory: this Runner was made without build= (vcirun.run.api.trajectory_of)")
        if perturb not in (None, "h", "start") or (perturb and trajectory):
            raise ValueError(f"perturb: None, 'h' or 'start', without trajectory=True (got {perturb!r})")

        energies = bool(trajectory) if energies is None else energies
        base, mod, q0, p0, prm, beta = self._base(method, energies)
        N = int(N)
        h = self.T / N
        if perturb == "h":
            h = h * (1.0 + PERTURB_ULPS * _EPS)
        elif perturb == "start":
            q0, p0 = _nudged(q0, 1.0), _nudged(p0, -1.0)
        n = base.sysd.n
        need = _BYTES.get((N, n))
        if need is None:
            if len(_BYTES) > 4096:
                _BYTES.clear()
            need = _BYTES[(N, n)] = run_bytes(N, n)
        if trajectory:
            p = dataclasses.replace(base, h=h, N=N, need=need, note="", _mod=mod)
            p.check_memory()
        else:   # (the plan's memory check, without a copy of the plan)
            p = base
            if need > memory_limit():
                check_run_memory(N, n)
        c0 = time.thread_time()
        out, counters, wall = run_loop(mod, q0, p0, self.t0, h, N, prm, p.settings, n, p.max_impacts_step,
                                       buffers=_FRESH)
        base.ran(wall)
        steps = counters["steps"]
        Q = out[_INDEX["q"]][: steps + 1]
        P = out[_INDEX["p"]][: steps + 1]
        k_imp, k_rel = counters["n_impacts"], counters["n_releases"]
        field = lambda name, k: out[_INDEX[name]][:k]  # noqa: E731
        active = field("contact_active", steps + 1)
        tr = None
        pending = None
        if trajectory == "later" and need <= DEFER_BYTES:
            status = _STATUS[counters["status"]]
            if status == "ok" and nonfinite_start(out[_INDEX["H"]][0], out[_INDEX["Ed"]][0] if p.energies else None,
                                                  out[_INDEX["Hmod"]][0] if p.energies and p.meth.has_modified_energy
                                                  else None):
                status = "nonfinite"   # (the status trajectory_of gives a start whose energy overflows)

            def pending():
                t = self.build(p, mod, out, counters, q0, p0, prm, beta, wall)
                t.run_args, t.tier = self.run_args(p.meth), self._tiers.get(id(mod), p.tier_used)
                t.build = _LAZY.build_of(mod, t.tier)
                return t
        elif trajectory:
            tr = self.build(p, mod, out, counters, q0, p0, prm, beta, wall)
            tr.run_args, tr.tier = self.run_args(p.meth), self._tiers.get(id(mod), p.tier_used)
            tr.build = _LAZY.build_of(mod, tr.tier)
            status = tr.status
        else:
            status = _STATUS[counters["status"]]
        any_active = bool(active.any())   # (hold_onsets is () without a held contact)
        impacts, contacts = field("impacts", k_imp).copy(), field("impact_contact", k_imp).copy()
        holds = ()
        if any_active:
            holds = hold_onsets(active, self.t0, h, start_gaps(mod, q0, prm) if active[:1].any() else None)
            holds = accumulated_holds(holds, impacts, contacts, h, restitutions(mod, prm))
        run = Run(method=p.meth, N=N, h=h, t0=self.t0, q=Q, p=P, impacts=impacts, impact_contact=contacts,
                  releases=field("releases", k_rel).copy(), release_contact=field("release_contact", k_rel).copy(),
                  held=any_active or k_rel > 0, status=status, wall=wall,
                  cpu=time.thread_time() - c0, trajectory=tr, holds=holds, pending=pending)
        return run

    def run_args(self, meth) -> "RunArgs":
        return RunArgs(system=self.system, method=meth, t0=self.t0, beta=self.start["beta"], q0=self.start["q0"],
                       p0=self.start["p0"], params=self.params, constrained=self.constrained,
                       resting_contact=self.resting_contact, options=dict(self.options), tier=self.tier, kc=self.kc)


@dataclass(slots=True)   # (one per simulate call: slots halve its construction)
class RunArgs:
    """The arguments of a `vcirun.simulate` call, kept on its Trajectory (`tr.run_args`) so that
    `tr.error_estimate()` can run companions of the same run: the system as given (a name, a file
    or a MechanicalSystem), the resolved Method, the start as given, params, constrained,
    resting_contact and the solver options."""

    system: object
    method: object
    t0: float = 0.0
    beta: float | None = None
    q0: object = None
    p0: object = None
    params: dict | None = None
    constrained: bool | None = None
    resting_contact: bool = True
    options: dict = dataclasses.field(default_factory=dict)
    tier: str | None = None   # the call's tier and kernel cache: the companions run as the run did
    kc: object = dataclasses.field(default=None, repr=False)

    def runner(self, T: float) -> Runner:
        return Runner(self.system, T=T, t0=self.t0, beta=self.beta, q0=self.q0, p0=self.p0, params=self.params,
                      constrained=self.constrained, resting_contact=self.resting_contact, options=self.options,
                      tier=self.tier, kc=self.kc)
