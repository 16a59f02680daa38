"""`vcirun.simulate(system, T=..., tol=...)`: the method, its options and h predicted to reach an L2
trajectory error `tol` in the least time, chosen by pilot runs, and the run with its error estimate.

The error of a method of order p at N grid steps on [t0, t0 + T] is e(N) = C N^-p once the steps
resolve the motion (the same impacts, contact by contact). Pilot runs of a method at N and 2N from
the user's start differ by d = e(N) - e(2N), so e(2N) = d / (2^p - 1) and C follows with the
verified order p (vcirun.run.estimate.verified_order); a third run shows the observed order. The
cost of a run is a + b N CPU seconds (measured on this scene: a timing run of N_CAL steps with the
energies the final run computes). The N that reaches TARGET tol is N* = (C / (TARGET tol))^(1/p).

Candidates (`_candidates`). CVA, CVA4, CVA6, CVA8, MCVAC, MCVAA, and VCI where the scene has one
contact, no generalized force and no declared reset map (R^VCI balances a short pre-impact step
against the rest of the step: with impacts denser than the grid it fails or loses bounces,
docs/extremes.md); under a generalized force CVA6 and CVA8 (order not verified) and MCVAA and MCVAC
(refused) are left out. A method the user names is the only candidate; `h` is then the largest step
allowed and `max_time` (seconds) bounds the predicted cost of the final run.

The scene model (`SceneModel`, per process, keyed by system, parameters, horizon and options). The
first call on a scene runs a ladder N = N_FIRST, 2 N_FIRST, ... for every candidate until two pairs
agree in their impacts and show the order (at least p - 1), or its pilots cost SCAN_BUDGET, and
one timing run per candidate; it records each candidate's error constant on this start, the
coarsest N that resolved the impacts and the coarsest N that showed the order. Each accepted final
run adds its start's constant (at round-off, the bound C <= floor N^p) and the coarsest N of its
estimate's runs, so the model follows the starts seen, not only the first. Later calls rank the
candidates by the model's median constant, pilot the best at N*/8 and N*/4 (the next where those
pilots do not resolve the motion), and scale the others by what the pilots say about this start (a
start that needs k times the steps for one method is taken to need k times the steps for every
method). Where N*/8 is coarser than the order was ever seen, the best is run without pilots at the
N the model's median constant predicts (its companions check it).

The final run (`_pursue`). The pick runs at the least N that reaches TARGET tol and that a companion
can certify (at least twice the coarsest N that showed the order: `_certifiable`), nested with a run
made already where that is cheaper than new companions at N/2 and N/4 (`_final_N`). Its Richardson
estimate (`estimate_of`: the companion, the third run's observed order, the grazing check, the
round-off amplified by the motion) decides:
accepted when the third run showed the order, the estimate is at most ACCEPT tol and its bracket's
upper end at most BOUND tol, and the round-off floor of the motion is at most FLOOR_SHARE tol
(`_floor`: two twins of the estimate's coarsest run, perturbed in h and in the start by a few ulps,
differ from it by what the motion makes of round-off, `amplified_floor`; the estimate cannot show
it: it divides its runs' difference by r^p - 1, 255 for CVA8 at r = 2, round-off and all, so a floor
of 1e-8 hides under an estimate of 1e-10; twins are skipped where the estimate's runs themselves
differ by at most FLOOR_SHARE tol / CHAIN_MARGIN). A floor above FLOOR_SHARE tol is the status
below_floor.
Runs that agree to within NOISE_EXPLAINS times that floor, far below tol, without showing the order
are accepted with the bound (largest difference + floor). Otherwise N grows by the estimate, or
doubles where the impacts disagree, a contact grazes or the observed order is short of p, until
accepted or the refinement has cost PURSUIT_BUDGET times the pick's predicted run. No candidate
reaching tol gives the status not_reached (below_floor, over_budget) and the most accurate resolved
run made (`_fallback`). docs/tolerance.md says where this fails.

Later calls (a scene model; not in the paper, and resting on other starts of the scene): the final and
one companion at N/2 are run first, the third run only where the pair needs it (`_needs_third`): not
where the pair agrees to round-off, nor where the final's N is set by tol, the model saw the order at
the companion's N (`_order_from`) and the estimate is at most THIRD_FREE tol (an estimate that small is
over tol only where the pair is several orders short of p: docs/tolerance.md). No twins where
FLOOR_SAMPLES twin measurements on the scene, the largest scaled to N, are CHAIN_MARGIN times below
FLOOR_SHARE tol (`MethodModel.floor_at`: a sample of the starts seen, not a bound for this one).
"""
from __future__ import annotations

import dataclasses
import math
import sys
import time
from dataclasses import dataclass, field

from ..core.values import check_number
from .estimate import ErrorEstimate, amplified_floor, forced_order, verified_order
from .ladder import MAX_RATIO, Assessment, _companion, assess, estimate_of
from .pilot import Run, Runner
from .scene_model import _MODELS, MethodModel, SceneModel, scene_key, scene_model  # noqa: F401 (public here too)

TARGET = 0.5      # the final run aims at an estimated error of TARGET * tol
ACCEPT = 1.0      # ... and is accepted when its estimate is at most ACCEPT * tol
BOUND = 3.0       # ... and the upper end of its bracket at most BOUND * tol
FLOOR_SHARE = 0.5   # ... and the round-off floor its twin runs measure at most FLOOR_SHARE * tol
NOISE_EXPLAINS = 4.0  # runs not showing the order differ by round-off where they differ by at most this times it
CHAIN_MARGIN = 100.0  # no twin runs where the estimate's own runs differ by at most FLOOR_SHARE tol / CHAIN_MARGIN
# later calls (a scene model): no third run where the model saw the order at the companion's N and the
# estimate is at most THIRD_FREE tol; no twins where FLOOR_SAMPLES twin measurements on the scene, the
# largest scaled to N, are at most FLOOR_SHARE tol / CHAIN_MARGIN
THIRD_FREE = 0.125
FLOOR_SAMPLES = 5
N_FIRST = 16      # the first pilot of a ladder (or T / h for a largest step h)
MAX_STEPS = 1 << 22
MAX_ROUNDS = 12   # refinements of the final before the choice says not_reached
PURSUIT_BUDGET, PURSUIT_FLOOR = 20.0, 0.05   # ... or once they cost this (times the pick's predicted cost)
PILOT_SHARE = 0.125   # with a scene model: the pilots at N*/8 and N*/4
DEFAULT_CANDIDATES = ("CVA", "CVA4", "CVA6", "CVA8", "MCVAC", "MCVAA", "VCI")

# statuses of a choice
OK, NOT_REACHED, BELOW_FLOOR, OVER_BUDGET = "ok", "not_reached", "below_floor", "over_budget"


@dataclass
class Candidate:
    """One candidate method on this start: its order, error constant C (e = C N^-p at N steps on
    the horizon; h-form: e = C_h h^p with C_h = C T^-p), cost model (a + b N CPU seconds), the N
    predicted to reach TARGET * tol, the predicted error and cost there, status and a note."""

    method: str
    order: float | None = None
    C: float | None = None
    a: float | None = None
    b: float | None = None
    N: int | None = None
    predicted_error: float | None = None
    predicted_cost: float | None = None
    source: str = ""
    status: str = "pending"
    note: str = ""
    N_resolved: int | None = None     # the coarsest N from which its pilots agree in their impacts
    N_asymptotic: int | None = None   # the coarsest N at which its pilots showed the order
    h: float | None = None            # T / N
    C_h: float | None = None          # C T^-p: e = C_h h^p

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class Choice:
    """What `simulate(tol=...)` chose: the method and h, the status ("ok"; "not_reached": no step
    within the limits reaches tol, the run returned is the best one made; "below_floor": tol is below
    the round-off level of this scene's runs; "over_budget": max_time does not allow it), the reason,
    every candidate (predicted error and cost), the pilot runs, the CPU seconds spent, and the
    final run's error estimate."""

    tol: float
    method: str
    h: float
    N: int
    status: str
    reason: str
    candidates: list
    estimate: ErrorEstimate | None = None
    pilots: list = field(default_factory=list)
    seconds: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status == OK

    def as_dict(self) -> dict:
        return {"tol": self.tol, "method": self.method, "h": self.h, "N": self.N, "status": self.status,
                "reason": self.reason, "candidates": [c.as_dict() for c in self.candidates],
                "estimate": self.estimate.as_dict() if self.estimate is not None else None,
                "pilots": list(self.pilots), "seconds": dict(self.seconds)}

    def table(self) -> str:
        """The candidates as a text table, the pick marked."""
        return candidate_table(self.candidates, self.method, self.tol) + f"\n{self.reason}"

    def __str__(self) -> str:
        return (f"Choice(tol={self.tol:g}: {self.method} h={self.h:.6g} (N={self.N}), status={self.status}; "
                f"{self.reason})")


def candidate_table(cands, pick: str, tol: float) -> str:
    def g(x, f=".3g"):
        return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, f)

    lines = [f"{'method':8s} {'order':>5s} {'C_h (e = C_h h^p)':>18s} {'us/step':>8s} {'h for tol':>10s} "
             f"{'steps':>8s} {'pred. error':>11s} {'pred. ms':>9s}  status"]
    for c in cands:
        ch, h = c.C_h, c.h
        mark = "*" if c.method == pick else " "
        lines.append(f"{mark}{c.method:7s} {g(c.order, 'g'):>5s} {g(ch, '.3e'):>18s} "
                     f"{g(None if c.b is None else c.b * 1e6, '.3g'):>8s} {g(h, '.4g'):>10s} "
                     f"{(g(c.N, 'd') if c.N is None or c.N < 10**8 else format(float(c.N), '.1e')):>8s} "
                     f"{g(c.predicted_error, '.2e'):>11s} "
                     f"{g(None if c.predicted_cost is None else c.predicted_cost * 1e3, '.3g'):>9s}  "
                     f"{c.status}{(': ' + c.note) if c.note else ''}")
    return f"tol = {tol:g}\n" + "\n".join(lines)


# --- the choice ----------------------------------------------------------------------------------------
def _certifiable(c: Candidate) -> int:
    """The smallest N whose estimate a companion can certify: the final and its companion at N/2 at or
    above the coarsest N that showed the order on the starts piloted (2 N_asymptotic); for a method whose
    runs agree to round-off, at or above the coarsest resolved N."""
    if c.C == 0.0 and c.N_resolved:
        return 2 * c.N_resolved
    return 2 * c.N_asymptotic if c.N_asymptotic else 1   # (the third run at N/4 may be coarser: it checks)


SCAN_BUDGET = 0.05   # CPU seconds of pilots per candidate on a scene's first call
PROGRESS_S = 10.0    # a call that has run this long says on stderr what it has made (_Chooser._say)
# the interpreted tier's steps cost 100-1000 times the compiled tier's: its pilots get this many times
# SCAN_BUDGET, enough for the ladders to reach the steps a compiled scan resolves the motion at (the
# cart-pendulum at beta = 4.2: CVA8 resolves at N = 64, which 50 ms of interpreted pilots stop short of)
INTERPRETED_SCAN_FACTOR = 40
INTERPRETED_KEY = "interpreted tier"   # marks the scene model of costs measured on the interpreted tier
N_CAL = 1024         # the timing run of a candidate (cost per step)


def _candidates(method, n_contacts: int, forced: bool, mapped: bool) -> tuple[list, dict]:
    """(candidate names, {name: reason left out})."""
    if method is not None:
        return [method], {}
    out, left = [], {}
    for name in DEFAULT_CANDIDATES:
        if name == "VCI" and (n_contacts > 1 or forced or mapped):
            left[name] = ("a candidate only with one contact, no generalized force and no declared reset map "
                          "(R^VCI fails or loses bounces with impacts denser than the grid)")
            continue
        if forced and name in ("MCVAA", "MCVAC"):
            left[name] = ("under a generalized force its order is 2 (its modified energy is not conserved), as "
                          "CVA's, at several times CVA's cost per step")
            continue
        if forced and name in ("CVA6", "CVA8"):
            left[name] = "its order under a generalized force is not verified"
            continue
        out.append(name)
    return out, left


def simulate_to_tolerance(system, method=None, *, T, tol, h_max=None, max_time=None, beta=None, q0=None, p0=None,
                          params=None, constrained=None, t0=0.0, energies=True, resting_contact=True,
                          options=None, build=None, tier=None, loader=None):
    """`vcirun.simulate(..., tol=...)`; see the module docstring. build: vcirun.run.api.trajectory_of
    (the API hands it in: this module does not import the API); tier, loader: as simulate's, for every
    run of the choice."""
    from ..codegen import kernel_cache
    from ..codegen.tiers import requested

    options = dict(options or {})
    if tol is None:
        raise ValueError("max_time: only with tol= (a time budget constrains the choice of method and h)")
    requested(tier)   # a bad tier is refused before any run (ValueError naming the field)
    tol = check_number("tol", tol, gt=0)
    T = check_number("T", T, gt=0)
    if h_max is not None:
        h_max = check_number("h", h_max, gt=0)
        if h_max > T:
            raise ValueError(f"h: the largest step allowed must be <= T = {T:g} (got {h_max:g})")
        if T / h_max > MAX_STEPS:   # every run allowed would be longer than the choice's step limit
            raise ValueError(f"h: the largest step allowed, {h_max:g}, needs {T / h_max:.3g} steps over T = {T:g}, "
                             f"more than tol='s limit of {MAX_STEPS} per run; allow a larger h or leave it out")
    if max_time is not None:
        max_time = check_number("max_time", max_time, gt=0)
    if constrained is False:
        raise ValueError("constrained: tol= measures the error of the constrained motion; drop constrained=False")
    mopts = {k: options.pop(k) for k in ("ld", "mh_order", "flow_order") if k in options}
    if mopts:
        if method is None:
            raise ValueError(f"{sorted(mopts)[0]}: a method option needs method= (e.g. method='MCVA')")
        from ..methods.table import resolve_method

        method = resolve_method(method, **mopts)
    elif method is not None:
        from ..methods.table import resolve_method

        resolve_method(method)   # an unknown name raises here, naming the field
    runner = Runner(system, T=T, t0=t0, beta=beta, q0=q0, p0=p0, params=params, constrained=constrained,
                    resting_contact=resting_contact, options=options, build=build, tier=tier,
                    kc=kernel_cache.of(loader))
    if method is not None:
        _check_named_method(runner, method)
    key = scene_key(system, params, T, t0, constrained, resting_contact, options, energies)
    served = runner.tier_used(method if method is not None else "CVA")
    if served == "interpreted":
        key += (INTERPRETED_KEY,)   # a model of the interpreter's costs per step, apart from the compiled one's
    elif served != "compiled":
        key = None   # a substitute loader: its costs are its own, kept by no model
    chooser = _Chooser(runner, method, T=T, tol=tol, h_max=h_max, max_time=max_time, energies=energies, key=key)
    return chooser.choose()


def _check_named_method(runner: Runner, method) -> None:
    """A method the user names must be one whose runs tol= can certify (ValueError naming `method`)."""
    why = uncertifiable(runner.method(method), runner.n_contacts(method), runner.forced(method))
    if why:
        raise ValueError(f"method: {why}")


def uncertifiable(meth, n_contacts: int, forced: bool) -> str | None:
    """Why tol= cannot certify the runs of `meth` on a scene with n_contacts contacts and a generalized
    force or not (None: it can): a discrete Lagrangian alone ignores the constraint (it integrates
    through the surface), and an order under forcing that is not verified cannot be assumed."""
    if meth.constrained is False and n_contacts > 0:
        return (f"{meth.name} ignores the constraint, and tol= measures the error of the constrained motion; "
                "name a collision integrator (CVA, VCI, MCVAA, MCVAC, CVA4, ...) or leave the method out")
    if meth.constrained is not False and forced and forced_order(meth) is None:
        return (f"{meth.name}'s order under a generalized force is not verified, so tol= cannot certify its "
                "runs; name CVA or CVA4 (or leave the method out), or run it with h= and read "
                "tr.error_estimate() (the observed order)")
    return None


def _label(name) -> str:
    return name if isinstance(name, str) else getattr(name, "name", str(name))


class _Chooser:
    def __init__(self, runner: Runner, method, *, T, tol, h_max, max_time, energies, key):
        self.runner, self.method, self.T, self.tol = runner, method, T, tol
        self.h_max, self.max_time, self.energies, self.key = h_max, max_time, energies, key
        self.runs: dict = {}        # label -> {N: Run}
        self.names: dict = {}       # label -> what runner.run takes (a name or a Method)
        self.pilot_log: list = []
        self.cpu0 = time.thread_time()
        self.wall0 = self.said = time.monotonic()   # (a progress line on stderr once a call is long: _say)
        self.n_min = max(1, math.ceil(T / h_max * (1 - 1e-12))) if h_max else 1
        self.model = _MODELS.get(key)
        self.later = False          # the candidates come from the scene model (not this call's scan)
        self.disagrees = False      # ... and this start's pilots disagree with it (the third run is kept)

    # --- runs ----------------------------------------------------------------------------------------
    def run(self, name, N, final=False, timing=False, perturb=None) -> Run:
        N = int(N)
        label = _label(name)
        self.names[label] = name
        have = self.runs.setdefault(label, {})
        if perturb is None and not timing and N in have and (not final or have[N].trajectory is not None
                                                             or have[N].pending is not None):
            return have[N]
        # a final run's Trajectory is built when it is returned (`_result`): of the final runs a choice
        # makes, one is returned
        r = self.runner.run(name, N, trajectory="later" if final else False,
                            energies=self.energies if (final or timing) else False, perturb=perturb)
        if not timing and perturb is None:
            have[N] = r
        self.pilot_log.append({"method": label, "N": N, "h": r.h, "status": r.status, "cpu": r.cpu,
                               "role": "final" if final else "timing" if timing else
                               f"twin ({perturb})" if perturb else "pilot"})
        self._say(label, N, r)
        return r

    def _say(self, label, N, r) -> None:
        """One line on stderr per PROGRESS_S seconds (or a tenth of the time elapsed, if longer) once the
        call has run PROGRESS_S: the runs made and the last one (a long horizon's runs take seconds
        each, and the call says nothing else until it returns)."""
        now = time.monotonic()
        elapsed = now - self.wall0
        if elapsed < PROGRESS_S or now - self.said < max(PROGRESS_S, 0.1 * elapsed):
            return
        self.said = now
        print(f"tol = {self.tol:g}: {len(self.pilot_log)} runs in {elapsed:.0f} s; the last {label} at N = {N} "
              f"({r.cpu:.3g} s of CPU, {r.status})", file=sys.stderr, flush=True)

    def order(self, label, N: int | None = None) -> float | None:
        """The verified order of `label` for the estimate of its run N (default: its finest run): 2 where
        that run, its companion or its third run holds a contact. A coarser run that takes a bounce for
        resting does not lower the order of the finer runs that resolve it."""
        meth = self.runner.method(self.names.get(label, label))
        runs = self.runs.get(label, {})
        if N is None and runs:
            N = max(runs)
        nested = []
        r = runs.get(N)
        while r is not None and len(nested) < 3:
            nested.append(r)
            r = _companion(runs, r.N, MAX_RATIO if len(nested) == 1 else 4)
        held = any(r.held for r in nested)
        return verified_order(meth, self.runner, held)[0]

    def method_model(self, label) -> MethodModel | None:
        return self.model.methods.get(label) if self.model is not None else None

    # --- one method's ladder ---------------------------------------------------------------------------
    def ladder(self, name, N0, budget=math.inf, need_order=True) -> Assessment:
        """Runs at N0, 2 N0, ... until assessed resolved (with the order observed, if need_order) or
        saturated, failed beyond MAX_STEPS, or the pilots' CPU exceeds `budget`."""
        label = _label(name)
        spent = 0.0
        N = max(int(N0), self.n_min, 1)
        # a ladder that starts at the floor the largest step allowed sets (h_max) makes three runs
        # whatever they cost: the order shows on no fewer, and a coarser start is not allowed
        floor_runs = 3 if self.n_min > int(N0) else 0
        while True:
            r = self.run(name, N)
            spent += r.cpu
            floor_runs -= 1
            p = self.order(label, N)
            if p is None:
                return Assessment("failed", note="order not verified on this scene")
            a = assess(self.runs[label], p, need_order)
            if a.status in ("resolved", "saturated"):
                return a
            over = spent > budget and floor_runs <= 0
            if 2 * N > MAX_STEPS or over:
                a.note = (a.note + "; " if a.note else "") + (
                    f"pilots stopped at N = {N} ({spent * 1e3:.3g} ms spent)" if over
                    else f"no resolution up to N = {N}")
                return a
            N *= 2

    def timing(self, name) -> tuple[float, float]:
        """(a, b): CPU seconds per run and per step of `name` (energies as the final run's), the line
        through timing runs at N_CAL steps and at the N of the method's finest pilot below it (the faster
        of two, made after the large one). Not the pilots' own CPU: a method's first runs in a process
        meet cold caches, and the coarsest pilots spend their time in event searches whose cost does not
        scale with N (the ball in the box, CVA: 217 us at N = 16 and 67 us at 32 as pilots, 41 us warm at
        32), so a line through them ranks methods at equal N by the order they were piloted in."""
        label = _label(name)
        runs = self.runs.get(label, {})
        big = self.run(name, max(N_CAL, self.n_min), timing=True)
        below = [N for N in runs if N < big.N]
        if not below:
            return 0.0, big.cpu / big.N
        small = min((self.run(name, max(below), timing=True) for _ in range(2)), key=lambda r: r.cpu)
        b = max((big.cpu - small.cpu) / (big.N - small.N), big.cpu / big.N / 4)
        return max(small.cpu - b * small.N, 0.0), b

    def predict(self, label, a: Assessment, cost) -> Candidate:
        p = self.order(label)
        c = Candidate(label, order=p, source="pilots on this start")
        c.a, c.b = cost
        if a.status == "resolved":
            N = max(math.ceil((a.C / (TARGET * self.tol)) ** (1.0 / p)), a.N_resolved or 1, self.n_min)
        elif a.status == "saturated":
            c.C, c.N_resolved = 0.0, a.N_resolved
            if a.floor > ACCEPT * self.tol:
                c.status, c.note = BELOW_FLOOR, f"tol is below the round-off level {a.floor:.1e} of these runs"
                return c
            N = max(a.N_resolved or 1, self.n_min)
        else:
            c.status, c.note = ("unresolved" if a.status == "unresolved" else "failed"), a.note
            return c
        c.C, c.N_resolved, c.N_asymptotic = a.C, a.N_resolved, a.N_asymptotic
        self._fill(c, max(N, _certifiable(c)))
        if a.observed is not None:   # (after the reason _fill gives, which it must not hide)
            c.note = f"{c.note}; observed order {a.observed:.2f}" if c.note else f"observed order {a.observed:.2f}"
        return c

    def _fill(self, c: Candidate, N: int):
        """Set N (at least what the estimate can certify: `_certifiable`), the predicted error and cost."""
        N = max(int(N), _certifiable(c))
        c.N = int(N)
        c.predicted_error = c.C * N ** -c.order if c.C else 0.0
        c.predicted_cost = (c.a or 0.0) + c.b * N if c.b is not None else None
        c.status = "ok"
        if N > MAX_STEPS:
            c.status, c.note = NOT_REACHED, f"needs {N:.3g} steps (more than {MAX_STEPS})"
        elif self.max_time is not None and c.predicted_cost is not None and c.predicted_cost > self.max_time:
            c.status, c.note = OVER_BUDGET, f"predicted {c.predicted_cost:.3g} s > max_time {self.max_time:g} s"

    # --- the choice ------------------------------------------------------------------------------------
    def choose(self):
        if self.model is None:
            mod = self.runner.module(self.method if self.method is not None else "CVA")
            feats = dict(n_contacts=int(mod.NCON), forced=bool(getattr(mod, "FORCED", False)),
                         mapped=bool(getattr(mod, "RESET_MAP", False)))
        else:
            feats = dict(n_contacts=self.model.n_contacts, forced=self.model.forced, mapped=self.model.mapped)
        names, left = _candidates(self.method, **feats)
        labels = [_label(n) for n in names]
        for n in names:
            self.names[_label(n)] = n
        if self.model is not None and all(self.method_model(lb) is not None for lb in labels):
            self.later = True
            cands = self._with_model(labels)
            how = f"ranked by the scene model ({self.model.starts} start{'s' if self.model.starts != 1 else ''} " \
                  "piloted in this process), scaled to this start by its pilots"
        else:
            cands = self._scan(labels)
            self._record(cands, feats, scanned=True)
            how = "pilots of every candidate on this start"
        for n, why in left.items():
            cands.append(Candidate(n, status="excluded", note=why))
        return self._finish(cands, how)

    def _scan(self, labels) -> list:
        """A ladder and a timing run for every candidate, each ladder bounded by SCAN_BUDGET CPU seconds
        (INTERPRETED_SCAN_FACTOR times that on the interpreted tier; or twice the best predicted final
        run, if that is more)."""
        cands = []
        best = 0.0
        for label in labels:
            scan = SCAN_BUDGET * (INTERPRETED_SCAN_FACTOR if self.runner.tier_used(self.names[label]) == "interpreted"
                                  else 1.0)
            a = self.ladder(self.names[label], N_FIRST, budget=max(scan, 2 * best))
            cost = self.timing(self.names[label])
            c = self.predict(label, a, cost)
            cands.append(c)
            if c.status == "ok" and c.predicted_cost is not None:
                best = min(best, c.predicted_cost) if best else c.predicted_cost
        return cands

    def _record(self, cands, feats=None, scanned=False):
        """Add this start's error constants (and, from a scan, the costs) to the scene model."""
        if self.key is None:
            return
        if scanned and INTERPRETED_KEY not in self.key and any(
                self.runner.tier_used(self.names[c.method]) == "interpreted" for c in cands if c.method in self.names):
            # a candidate timed on the interpreted tier (its compiled module still being built): the
            # costs of this scan are filed with the interpreted tier's model, not the compiled one's
            if feats is None and self.model is not None:
                feats = dict(n_contacts=self.model.n_contacts, forced=self.model.forced, mapped=self.model.mapped)
            self.key = self.key + (INTERPRETED_KEY,)
            self.model = _MODELS.get(self.key)
        if self.model is None:
            self.model = _MODELS.setdefault(self.key, SceneModel(self.key, self.T, **(feats or {})))
        self.model.starts += 1
        for c in cands:
            if c.status == "excluded" or c.order is None:
                continue
            m = self.model.methods.setdefault(c.method, MethodModel(order=c.order))
            if c.C is not None:
                m.C.append(c.C)
            if c.C is not None or not scanned:   # (a scan's unresolved candidate has neither)
                if c.N_resolved:
                    m.N_resolved.append(c.N_resolved)
                if c.N_asymptotic:
                    m.N_asymptotic.append(c.N_asymptotic)
            if scanned and c.b is not None:
                m.a, m.b = c.a, c.b
            if scanned and c.C is None and not m.C:
                m.unresolved = c.note

    def _from_model(self, label) -> Candidate:
        """The model's prediction for `label`, from its median error constant."""
        mm = self.method_model(label)
        c = Candidate(label, order=mm.order, a=mm.a, b=mm.b, source="scene model")
        if not mm.C or mm.b is None:
            c.status, c.note = "unresolved", mm.unresolved or "not resolved on the starts piloted"
            return c
        C, c.N_asymptotic, c.N_resolved = mm.medians()
        c.C = C
        N = max(math.ceil((C / (TARGET * self.tol)) ** (1.0 / mm.order)) if C > 0 else 1,
                c.N_resolved or 1, self.n_min)
        self._fill(c, N)
        return c

    def _with_model(self, labels) -> list:
        """Rank by the model. The best is piloted at N*/8 and N*/4 when that is as fine as the coarsest
        N at which its pilots showed the order on the starts seen (the next is piloted where its pilots do
        not resolve the motion); the others are then scaled by what the pilots say about this start.
        Where N*/8 is coarser, the best is run directly at the N the model predicts (its pilots would
        not be in the asymptotic regime; the final run's companions check it)."""
        preds = {lb: self._from_model(lb) for lb in labels}
        if not any(c.status == "ok" for c in preds.values()):
            # no candidate resolved on the starts seen (e.g. impacts accumulated there): this start may differ
            self.later = False
            cands = self._scan(labels)
            self._record(cands, scanned=True)
            return cands
        piloted: dict = {}
        scale = None
        for _ in range(2):
            ranked = sorted([c for lb, c in preds.items() if lb not in piloted and c.status == "ok"],
                            key=lambda c: c.predicted_cost)
            if not ranked:
                break
            c = ranked[0]
            n_asym = c.N_asymptotic or N_FIRST
            if not piloted and c.N * PILOT_SHARE < n_asym:
                d = self._from_model(c.method)
                d.source = "scene model (no pilots: they would be coarser than the order was seen)"
                piloted[c.method] = d
                break
            a = self.ladder(self.names[c.method], max(int(c.N * PILOT_SHARE), n_asym), need_order=False)
            pc = self.predict(c.method, a, (c.a, c.b))
            pc.source = "pilots on this start, ranked by the scene model"
            piloted[c.method] = pc
            if pc.status == "ok" and scale is None and c.N:
                scale = pc.N / c.N
                # this start needs more than twice the model's steps, or its pilots show an order short of
                # p: it is unlike the starts the model saw, and its final run keeps its third run
                self.disagrees = scale > 2.0 or (a.observed is not None and a.observed < (pc.order or 0) - 0.5)
                for lb, x in preds.items():
                    if lb not in piloted and x.status == "ok":
                        self._fill(x, max(int(math.ceil(x.N * scale)), self.n_min))
                        x.source = f"scene model, scaled by this start's pilots (x{scale:.2g} steps)"
            if pc.status == "ok":
                break
        return list(piloted.values()) + [c for lb, c in preds.items() if lb not in piloted]

    def _finish(self, cands, how):
        usable = sorted([c for c in cands if c.status == "ok" and c.predicted_cost is not None
                         and not c.source.startswith("scene model,")], key=lambda c: c.predicted_cost)
        if not usable:
            return self._fallback(cands)
        pick = usable[0]
        reason = (f"{pick.method} is predicted to reach {TARGET:g} tol at h = {self.T / pick.N:.4g} ({pick.N} steps) "
                  f"in {pick.predicted_cost * 1e3:.3g} ms CPU")
        others = sorted([c for c in cands if c is not pick and c.status == "ok" and c.predicted_cost is not None],
                        key=lambda c: c.predicted_cost)
        if others:
            reason += (f", the least of the candidates (next: {others[0].method}, "
                       f"{others[0].predicted_cost * 1e3:.3g} ms)")
        reason += f"; {how}"
        return self._pursue(pick, cands, reason)

    def _pursue(self, pick: Candidate, cands, reason):
        """Run the pick at its N with a Richardson companion and a third run for the observed order
        (nested pilots where they fit, else companions at N/2 and N/4); accept, or refine."""
        label = pick.method
        name = self.names[label]
        runs = self.runs.setdefault(label, {})
        mod, prm = self.runner.module(name), self.runner.params_vector(name)
        N = pick.N
        last = None
        # refining stops once it has spent PURSUIT_BUDGET times the pick's predicted cost (at least
        # PURSUIT_FLOOR seconds): a motion no affordable step resolves is reported, not chased to MAX_STEPS
        budget = max(PURSUIT_FLOOR, PURSUIT_BUDGET * (pick.predicted_cost or 0.0))
        spent0 = self._spent(label)
        # later calls make the third run after the pair, where the pair needs it (`_needs_third`); where the
        # final's N is set by what a companion can certify (2 N_asymptotic), not by tol, the model's order
        # does not stand for the third run: that run, where its order shows, is what lowers the model's
        # coarsest asymptotic N (`_record`); without it the model keeps the first scan's, and every later
        # call runs at twice that
        lazy = self.later
        order_from = self._order_from(label) if lazy and pick.N > _certifiable(pick) else None
        for _ in range(MAX_ROUNDS):
            if self._spent(label) - spent0 > budget:
                break
            N = self._final_N(name, runs, N, pick.N_asymptotic or 1, third=not lazy)
            if N > MAX_STEPS:
                break
            if self.max_time is not None and pick.b is not None and (pick.a or 0) + pick.b * N > self.max_time:
                pick.status, pick.note = OVER_BUDGET, f"refining needs N = {N}, beyond max_time"
                break
            r = self.run(name, N, final=True)
            p = self.order(label, N)
            est = estimate_of(runs, N, p, mod, prm, order_from=order_from)
            if lazy and self._needs_third(est):
                comp = _companion(runs, N)
                k = next((k for k in (2, 3, 4) if comp.N % k == 0), None)
                if k is not None and _companion(runs, comp.N, 4) is None:
                    self.run(name, comp.N // k)
                    p = self.order(label, N)
                    est = estimate_of(runs, N, p, mod, prm)
            last = est
            if est.status == "ok" and est.extras.get("floor", 0.0) > BOUND * self.tol:
                pick.status, pick.note = BELOW_FLOOR, (f"tol is below the round-off level {est.extras['floor']:.1e} "
                                                       "of these runs")
                break
            if est.status == "ok" and est.extras.get("checked") and est.l2 <= ACCEPT * self.tol \
                    and est.l2_bounds[1] <= BOUND * self.tol:
                floor, why = self._floor(name, runs, est, N)
                if why:   # the impacts are decided at round-off level on the coarsest run: refine
                    last = ErrorEstimate("richardson", "unresolved", r.h, order=p, message=why, first_difference=why)
                    N = 2 * N
                    continue
                if floor > FLOOR_SHARE * self.tol:
                    pick.status, pick.note = BELOW_FLOOR, (
                        f"tol is below this motion's round-off floor: twin runs perturbed at round-off level "
                        f"differ by {floor:.1e} (at N = {N}), more than {FLOOR_SHARE:g} tol")
                    break
                est.extras["floor_measured"] = floor
                est.l2_bounds = (est.l2_bounds[0], est.l2_bounds[1] + floor)
                if floor > est.extras.get("floor", 0.0):
                    est.note = (est.note + "; " if est.note else "") + (
                        f"round-off as the motion amplifies it, up to {floor:.1e} ({est.extras['floor_from']}), "
                        "is in the bracket's upper end")
            if est.status == "unresolved" and est.extras.get("noise", math.inf) <= TARGET * self.tol:
                # runs that agree far below tol without showing the order: where twins show the motion's
                # round-off of their size, round-off is what they differ by, and the error is bounded by
                # their largest difference plus that floor
                noise = est.extras["noise"]
                floor, why = self._floor(name, runs, est, N, twins=True)
                if not why and noise <= NOISE_EXPLAINS * floor and noise + floor <= TARGET * self.tol:
                    d = runs[N].diffs[_companion(runs, N).N]   # (final state: the finest pair's difference)
                    est = dataclasses.replace(
                        est, status="ok", l2=noise + floor, l2_bounds=(0.0, noise + floor), final_q=d.final_q,
                        final_p=d.final_p, message="", note=(
                            f"the runs agree to {noise:.1e} without showing the order, and twin runs perturbed at "
                            f"round-off level differ by {floor:.1e}: round-off amplified by the motion sets their "
                            "differences; the error is bounded by their sum"),
                        extras=dict(est.extras, floor_measured=floor, bound_only=True))
                    if self.method is None:
                        self._record([Candidate(label, order=p, C=est.l2 * N ** p, N_resolved=est.extras["third"],
                                                N_asymptotic=est.extras["third"])])
                    return self._result(r, label, cands, OK, reason, est)
            if est.status == "ok" and est.extras.get("checked"):
                if est.l2 <= ACCEPT * self.tol and est.l2_bounds[1] <= BOUND * self.tol:
                    third = est.extras.get("third")
                    if self.method is None:
                        # what this start showed: the coarsest run of an accepted estimate (where its order
                        # showed, or its runs agreed to round-off) and its constant; an estimate near round-off
                        # does not scale as N^-p, and gives a bound: C <= (the round-off level) N^p (without
                        # it the model's constant would be that of the starts whose errors are above round-off)
                        floor = max(est.extras.get("floor", 0.0), est.extras.get("floor_measured", 0.0))
                        coarsest = third or _companion(runs, N).N
                        # (an estimate on the model's order alone says nothing new of where the order shows)
                        self._record([Candidate(label, order=p, C=max(est.l2, floor) * N ** p, N_resolved=coarsest,
                                                N_asymptotic=None if est.extras.get("order_from_model")
                                                else coarsest)])
                    return self._result(r, label, cands, OK, reason, est)
                if est.order is not None and est.order < p - 0.25:
                    N = 2 * N   # the companions are not yet asymptotic: shift the three runs up
                else:
                    grow = (max(est.l2, est.l2_bounds[1] / BOUND) / (TARGET * self.tol)) ** (1.0 / est.order)
                    N = max(int(math.ceil(N * max(grow, 1.1))), N + 1)
            else:   # unresolved, failed, or no order check yet: the run becomes the companion of 2N
                N = 2 * N
        if pick.status == "ok":
            pick.status = NOT_REACHED
            pick.note = last.message if last is not None and last.status != "ok" else "the estimate stays above tol"
        return self._fallback(cands)   # (BELOW_FLOOR and OVER_BUDGET picks set the status there)

    def _floor(self, name, runs: dict, est: ErrorEstimate, N: int, twins: bool = False) -> tuple[float, str]:
        """The round-off floor of run N as the motion amplifies it (`amplified_floor`): twins, perturbed in
        h and in the start at round-off level, of the coarsest run of the estimate (its third run, else its
        companion: the floor hardly depends on h, and these cost a quarter or half of the run). twins:
        run them even where the estimate's runs agree far below tol."""
        base = runs.get(est.extras.get("third")) or _companion(runs, N) or runs[N]
        # runs at different h round differently from their first step on, so their difference holds a sample
        # of the amplified round-off as a twin's does. Where both pairs of the estimate's runs differ by at
        # most FLOOR_SHARE tol / CHAIN_MARGIN (runs agreeing to round-off, far more accurate than tol), the
        # floor is taken to be below FLOOR_SHARE tol and no twin is run; likewise one twin suffices where
        # it is that far below. CHAIN_MARGIN covers the spread of one sample: on 40 starts of the double
        # pendulum between walls (bench/tolerance.py's), the "h" and "start" twins of one run differed by
        # up to 63 times
        comp = _companion(runs, N)
        pairs = [runs[N].diffs.get(comp.N) if comp is not None else None]
        if base is not comp and comp is not None:
            pairs.append(comp.diffs.get(base.N))
        if not twins and None not in pairs and max(d.l2 for d in pairs) <= FLOOR_SHARE * self.tol / CHAIN_MARGIN:
            est.extras["floor_from"] = "bounded by the estimate's runs"
            return max(d.l2 for d in pairs), ""
        # a later call: where the twins of FLOOR_SAMPLES earlier calls on the scene, the largest scaled to
        # this N, put the floor CHAIN_MARGIN times below FLOOR_SHARE tol, no twins (the model's floor is
        # a sample of the starts seen, not a bound for this one: docs/tolerance.md)
        mm = self.method_model(_label(name)) if self.later else None
        seen = mm.floor_at(N, FLOOR_SAMPLES) if mm is not None else None
        if not twins and seen is not None and seen <= FLOOR_SHARE * self.tol / CHAIN_MARGIN:
            est.extras["floor_from"] = f"the scene model (twins of {len(mm.floors)} calls, the largest scaled)"
            return seen, ""
        # the twin in h first; the twin in the start too unless the first is below FLOOR_SHARE tol / CHAIN_MARGIN
        twins = [self.run(name, base.N, perturb="h")]
        floor, why = amplified_floor(base, twins, N)
        if why or floor > FLOOR_SHARE * self.tol / CHAIN_MARGIN:
            twins.append(self.run(name, base.N, perturb="start"))
            floor, why = amplified_floor(base, twins, N)
        est.extras["floor_from"] = (f"{len(twins)} twin run{'s' if len(twins) > 1 else ''} perturbed at round-off "
                                    f"level, at N = {base.N}")
        mm = self.method_model(_label(name))
        if mm is not None and self.key is not None:
            mm.floors.append(floor / math.sqrt(max(N, base.N)))
        return floor, why

    def _spent(self, label) -> float:
        return sum(x["cpu"] for x in self.pilot_log if x["method"] == label)

    def _final_N(self, name, runs: dict, N: int, n_asym: int = 1, third: bool = True) -> int:
        """The final run's N >= N, with a companion at or above n_asym (the coarsest N that showed the
        order) and a third run below it for the observed order; the cheapest of: a run M >= N made
        already that has both (M is run again with its Trajectory); k M (2 <= k <= MAX_RATIO) for a run
        M >= n_asym made already that has a third run below it; or N rounded up to a multiple of 4 with
        companions at N/2 and N/4, run here. third=False (the scene model has the order at n_asym): no
        third run is needed, and a fresh final has one companion, at N/2."""
        N = max(int(N), self.n_min, 4, 2 * n_asym)
        options = []
        for M, r in runs.items():
            if not r.ok or M < n_asym:
                continue
            comp = _companion(runs, M)
            if (M >= N and comp is not None and comp.N >= n_asym
                    and (not third or _companion(runs, comp.N, 4) is not None)):
                options.append((M, M))
            k = max(2, math.ceil(N / M))
            if k <= MAX_RATIO and (not third or _companion(runs, M, 4) is not None):
                options.append((k * M, k * M))
        fresh = 4 * math.ceil(N / 4)
        options.append(((1.75 if third else 1.5) * fresh, fresh))
        cost, Nf = min(options)
        if Nf == fresh:
            for M in ((fresh // 2, fresh // 4) if third else (fresh // 2,)):
                if M not in runs:
                    self.run(name, M)
        return Nf

    def _needs_third(self, est: ErrorEstimate) -> bool:
        """A later call's pair (the final and its companion) needs a third run for the observed order: where
        its estimate is a number not checked (neither at round-off nor on the model's order), or checked on
        the model's order alone but above THIRD_FREE tol and acceptable (the model's order alone certifies
        only estimates far below tol; above tol N grows on it, and the run becomes the companion of the
        next). Not where the runs are unresolved: N doubles."""
        if est.status != "ok":
            return False
        if not est.extras.get("checked"):
            return True
        return bool(est.extras.get("order_from_model")) and THIRD_FREE * self.tol < est.l2 <= ACCEPT * self.tol \
            and est.l2_bounds[1] <= BOUND * self.tol

    def _order_from(self, label) -> int | None:
        """On a later call, the N at and above which the scene model saw `label`'s order (the median of
        its starts' coarsest asymptotic N, as `_certifiable`): a final whose companion is that fine needs no
        third run for an estimate far below tol. None on a first call, without that record, or where this
        start's pilots disagree with the model."""
        if not self.later or self.disagrees:
            return None
        mm = self.method_model(label)
        return mm.n_asymptotic() if mm is not None else None

    def _fallback(self, cands):
        """No candidate reaches tol within the limits: the most accurate resolved run made, with its
        estimate, and the status that says why."""
        status = NOT_REACHED
        if any(c.status == BELOW_FLOOR for c in cands):
            status = BELOW_FLOOR
        elif self.max_time is not None and any(c.status == OVER_BUDGET for c in cands):
            status = OVER_BUDGET
        best = None
        for label, runs in self.runs.items():
            p = self.order(label)
            if p is None:
                continue
            name = self.names[label]
            for N in sorted(runs, reverse=True):
                if not runs[N].ok or _companion(runs, N) is None:
                    continue
                p = self.order(label, N)
                est = estimate_of(runs, N, p, self.runner.module(name), self.runner.params_vector(name))
                if est.status == "ok":
                    if best is None or est.l2 < best[2].l2:
                        best = (label, N, est)
                    break
        notes = "; ".join(f"{c.method}: {c.status}{' (' + c.note + ')' if c.note else ''}" for c in cands
                          if c.status != "excluded")
        if best is not None:
            label, N, est = best
        else:
            fin = sorted((N, label) for label, runs in self.runs.items() for N, r in runs.items() if r.ok)
            if fin:
                N, label = fin[-1]
                est = ErrorEstimate("richardson", "unresolved", self.T / N,
                                    message="no candidate resolved the motion (the choice's reason says why for each)")
            else:
                label = cands[0].method
                N = max(N_FIRST, self.n_min)
                est = ErrorEstimate("richardson", "failed", self.T / N, message=f"every pilot failed; {notes}")
        r = self.run(self.names.get(label, label), N, final=True)
        live = [c for c in cands if c.status != "excluded"]
        budget_out = bool(live) and all("pilots stopped at N" in (c.note or "") for c in live)
        reason = {NOT_REACHED: (f"no candidate resolved the motion before its pilots' budget ran out "
                                f"({SCAN_BUDGET * 1e3:.0f} ms of CPU each, {INTERPRETED_SCAN_FACTOR} times that on the "
                                f"interpreted tier, on a scene's first call): tol = "
                                f"{self.tol:g} is not reached" if budget_out
                                else f"no step within the limits reaches tol = {self.tol:g}"),
                  BELOW_FLOOR: f"tol = {self.tol:g} is below the round-off level of this scene's runs",
                  OVER_BUDGET: f"max_time = {self.max_time} s does not allow a run that reaches tol"}[status]
        reason += f"; the run returned is the most accurate one made ({label}, N = {r.N}); {notes}"
        return self._result(r, label, cands, status, reason, est)

    def _result(self, r: Run, label, cands, status, reason, est):
        tr = r.built()
        total = time.thread_time() - self.cpu0
        for c in cands:
            if c.N is not None:
                c.h = self.T / c.N
            if c.C is not None and c.order:
                c.C_h = c.C * self.T ** (-c.order)
        choice = Choice(tol=self.tol, method=label, h=r.h, N=r.N, status=status, reason=reason, candidates=cands,
                        estimate=est, pilots=self.pilot_log,
                        seconds={"total_cpu": total, "final_cpu": r.cpu,
                                 "pilots_cpu": sum(x["cpu"] for x in self.pilot_log if x["role"] != "final")})
        tr.choice = choice
        return tr
