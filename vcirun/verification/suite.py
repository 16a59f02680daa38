"""`vcirun.verify`: the test suite's numerical checks, run on the user's own system and methods."""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..run.accounts import FRICTION, LAW
from . import checks as ck
from .fd import Probe, check_kernels, map_jacobian, smaller_steps, symplecticity_defect
from .harness import StepFailed, exact_smooth, smooth_until_failure, step
from .window import Window, settle_window

DEFAULT_METHODS = ("CVA", "MCVAC")
DEFAULT_H_MAX = 0.04
DEFAULT_LEVELS = 7         # h = 0.04, 0.02, ..., 0.000625
N_PROBES = 3               # states along the motion (besides the start) for kernel and map checks
NEWTON_TOL = 1e-14         # the maps' Newton tolerance inside the FD Jacobians (noise / FD step << 1e-8)


@dataclass
class VerifyResult:
    """What `vcirun.verify` found. checks: every verdict (vcirun.verification.checks.Check);
    ok: no check failed; warnings: the checks that warn; seconds: wall time of the verification."""

    system: str
    n: int
    methods: list
    q0: np.ndarray
    p0: np.ndarray
    T: float
    h: list
    params: dict
    checks: list = field(default_factory=list)
    seconds: float = 0.0
    notes: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not any(c.failed for c in self.checks)

    @property
    def failures(self) -> list:
        return [c for c in self.checks if c.verdict == ck.FAIL]

    @property
    def warnings(self) -> list:
        return [c for c in self.checks if c.verdict == ck.WARN]

    def check(self, name, method=None):
        """The check called `name` (of `method`), or None."""
        return next((c for c in self.checks if c.name == name and c.method == method), None)

    def to_markdown(self, figure=None) -> str:
        from .verdict import markdown

        return markdown(self, figure)

    def figure(self, path):
        from .verdict import figure

        return figure(self, path)

    def save(self, path, figure=True):
        """Write the Markdown report to `path` (and the figure next to it, same name .png). Returns the
        paths written."""
        from pathlib import Path

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        written = []
        fig = None
        if figure:
            fig = self.figure(path.with_suffix(".png"))
            if fig is not None:
                written.append(fig)
        path.write_text(self.to_markdown(fig.name if fig is not None else None))
        written.insert(0, path)
        return written


def _ladder(h, T):
    """Validated, descending list of steps; each a positive finite float with T / h >= 1."""
    if h is None:
        return [DEFAULT_H_MAX / 2 ** k for k in range(DEFAULT_LEVELS)]
    if isinstance(h, (int, float)):
        h = [h]
    try:
        hs = sorted({float(x) for x in h}, reverse=True)
    except (TypeError, ValueError):
        raise ValueError(f"h: expected a list of step sizes (got {h!r})") from None
    if len(hs) < 3:
        raise ValueError(f"h: an order needs at least 3 step sizes (got {len(hs)})")
    for x in hs:
        if not (x > 0 and np.isfinite(x)) or T / x < 1:
            raise ValueError(f"h: every step must be positive, finite and at most T = {T:g} (got {x:g})")
    return hs


def _methods(methods):
    from ..methods.table import resolve_method

    if methods is None:
        methods = DEFAULT_METHODS
    if isinstance(methods, str):
        methods = [m.strip() for m in methods.split(",") if m.strip()]
    out = [resolve_method(m) for m in methods]
    if not out:
        raise ValueError("methods: give at least one method (e.g. CVA,MCVAC)")
    return out


def _impact_order(meth):
    return meth.impact_order   # the reset's declared order (vcirun.codegen.roles.RESETS), else its Ld's


def _forcing(sysm):
    """numpy f(q, qdot, t) of a forced system (sympy.lambdify of the declaration), or None."""
    if not sysm.is_forced:
        return None
    import sympy as sp

    fn = sp.lambdify([sysm.q, sysm.qd, sysm.t, sysm.param_symbols], list(sysm.forcing), "numpy")
    return fn


def _force_vanishes(sysm, prm) -> bool:
    """The declared generalized force is identically zero at these parameter values (sympy, exactly)."""
    import sympy as sp

    values = dict(zip(sysm.param_symbols, [sp.nsimplify(float(x)) for x in prm]))
    return all(sp.simplify(sp.sympify(e).subs(values)) == 0 for e in sysm.forcing)


def verify(system, methods=None, *, q0=None, p0=None, beta=None, T=5.0, h=None, params=None,
           progress=None, tier=None, loader=None) -> VerifyResult:
    """Run the numerical checks of vcirun's test suite on `system` with `methods`.

    system : built-in name, YAML path or MechanicalSystem; methods: names (list or "CVA,MCVAC"; default
             CVA and MCVAC) or Method objects; q0, p0 or beta: the start state (as vcirun.simulate);
    T      : final time of every run; h: the step ladder (default 0.04 / 2^k, k = 0..6);
    params : parameter overrides; progress: callable(str) told what is being computed.
    tier   : the kernels' tier, as vcirun.simulate's (the same numbers on either).
    loader : where the methods' kernels come from, as vcirun.simulate's (default: the kernel cache).

    Checks (each a verdict pass / warn / fail / skip with its number and threshold; see
    vcirun.verification.checks): derivatives of every generated kernel the methods' modules define
    against finite differences at the start and N_PROBES states along the motion; hyperregularity of
    M(q) along the motion; smooth observed orders (constraint ignored) against the exact smooth
    solution; the symplecticity defect of each one-step map; the MCVA family's modified-Hamiltonian
    conservation order; through impacts, the L2 order and the impact-time error against the exact
    reference (vcirun.reference) and the energy change across impact steps less the impact law's loss
    (the energy account: restitution, plastic holds). A motion that comes to rest is checked through
    impacts on a window before it settles (vcirun.verification.window; the notes say so).

    Systems with Coulomb friction: the derivative table checks sys_slips and sys_friction against the
    declaration and sys_dslips against FD of sys_slips; "mode-change times" compares each run's
    stick/slip transitions (count, contacts, kinds, times at the method's order) with the exact
    reference's; "energy account" judges what the run's account leaves after the friction work and
    the impact law's loss (the integration error: order p); the MCVA family's H~ is taken less the
    friction work too (varying at order p: friction is a non-conservative force). A motion that
    comes to rest with every contact stuck is said to in the notes (the checks run through the rest).

    Forced systems: the exact smooth solution adds the declared force to Hamilton's equations;
    vcirun.reference is compared with it before the first impact (if they disagree, the impact checks
    are skipped with that reason); the energy check balances the forces' work too; symplecticity and
    H~ conservation are reported, not judged.

    Returns a VerifyResult (`.ok`, `.checks`, `.save(path)` writes the Markdown report and figure).
    Bad input raises ValueError naming the field."""
    from ..codegen.tiers import requested

    s = _Session(system, methods, q0, p0, beta, T, h, params, progress, requested(tier), loader)
    s.references()
    s.choose_probes()
    for meth in s.meths:
        s.method_checks(meth)
    s.add(s.hyperregularity())
    s.res.checks.sort(key=lambda c: c.method is not None)   # system-level checks first
    s.res.seconds = time.perf_counter() - s.t_start
    return s.res


class _Session:
    """The state of one verification: the system, start state, ladder, references, and the results."""

    def __init__(self, system, methods, q0, p0, beta, T, h, params, progress, tier="compiled", loader=None):
        from ..run.resolve import resolve_system
        from ..codegen.build import load_module
        from ..core.sizes import check_ladder_memory
        from ..methods.table import METHODS

        self.say = progress or (lambda msg: None)
        self.t_start = time.perf_counter()
        T = float(T)
        if not (T > 0 and np.isfinite(T)):
            raise ValueError(f"T: must be a positive finite time (got {T})")
        self.T, self.hs = T, _ladder(h, T)
        self.meths = _methods(methods)
        self.sysm = sysm = resolve_system(system)
        self.params = params
        self.prm = prm = sysm.param_values(params)
        self.q0, self.p0 = sysm.initial_state(beta=beta, q0=q0, p0=p0, params=prm)
        self.n = sysm.n
        check_ladder_memory(self.hs, T, self.n, len(sysm.constraints))   # before anything is compiled or run
        phi0 = sysm.phi_value(self.q0, prm)
        if not phi0 >= 0:   # checked before anything is compiled
            raise ValueError(f"q0: the start state is inside the constraint: phi(q0) = {phi0:.6g} < 0 for constraint "
                             f"{sysm.phi} (choose q0 with phi(q0) >= 0)")
        f = _forcing(sysm)
        vanishing = f is not None and _force_vanishes(sysm, prm)
        if vanishing:   # (e.g. the bouncing ball's drag at c = 0): the map is the unforced one, judged as such
            f = None
        self.force = None if f is None else (lambda q, v, t: np.asarray(f(q, v, t, prm), float).ravel())
        self.res = VerifyResult(system=sysm.name, n=self.n, methods=[m.name for m in self.meths], q0=self.q0,
                                p0=self.p0, T=T, h=self.hs, params=dict(zip(sysm.params, prm.tolist())))
        from ..core.grid import grid_count

        short = [x for x in self.hs if abs(grid_count(x, T) * x - T) > 1e-9 * T]
        if short:
            self.res.notes.append(f"T = {T:g} is not a multiple of h = {', '.join(f'{x:g}' for x in short)}: those "
                                  "grids end at floor(T / h) h < T (each run's error is measured on its own grid)")
        if self.force is not None:
            self.res.notes.append("forced system: the exact smooth solution adds the declared generalized force to "
                                  "Hamilton's equations (sympy.lambdify of the declaration)")
        elif vanishing:
            self.res.notes.append("the declared generalized force vanishes at these parameter values: the system is "
                                  "checked as an unforced one (symplecticity and H~ judged)")
        self.tier, self.loader = tier, loader
        self.friction = bool(sysm.has_friction)   # the mode-change and energy-account checks
        self.ref_modes = []
        # the runs' work in steps (a smooth and an impact run per step size and method), for the estimate
        self.steps_total = 2 * len(self.meths) * sum(grid_count(x, T) for x in self.hs)
        self.steps_done, self.run_seconds, self.said_at, self.runs = 0, 0.0, 0.0, 0
        self.base = load_module(sysm, METHODS["CVA"].kernel_set(), tier)   # system kernels + Hamilton's equations
        self.H0 = float(self.base.hamiltonian(self.q0, self.p0, prm))
        Mq0 = self.M(self.q0)
        self.lam0 = float(np.linalg.eigvalsh(0.5 * (Mq0 + Mq0.T))[0])
        self.hyper = []   # (source, t, q, eigenvalues of M or None, h of a run or None)

    def declared(self):
        """numpy M(q), V(q), phi(q) of the declaration (sympy.lambdify, independent of code generation);
        with friction also the slip rows W_t(q) and the coefficients (mu, mu_s) at the parameters."""
        if not hasattr(self, "_declared"):
            f, prm = self.sysm.numpy_functions(), list(self.prm)
            if "phis" in f:
                phis = lambda q: np.array(f["phis"](list(q), prm), float).ravel()  # noqa: E731
            else:   # one constraint (before several constraints were declared as a list)
                phis = lambda q: np.array([f["phi"](list(q), prm)], float)  # noqa: E731
            self._declared = {"M": lambda q: np.array(f["M"](list(q), prm), float),
                              "V": lambda q: float(f["V"](list(q), prm)), "phis": phis}
            if self.sysm.has_friction:   # the slip rows and the coefficients, for sys_slips and sys_friction
                self._declared["slips"] = lambda q: self.sysm.slip_matrix_value(q, self.prm)
                self._declared["friction"] = self.sysm.friction_values(self.prm)
        return self._declared

    @property
    def names(self):
        return [c.name for c in self.sysm.constraints]

    def add(self, check):
        self.res.checks.append(check)

    def M(self, q):
        A = np.empty((self.n, self.n))
        self.base.sys_M(np.ascontiguousarray(q, float), self.prm, A)
        return A

    def sample_M(self, src, ts, Q, h=None):
        for t, q in zip(ts, Q):
            A = self.M(q)
            ev = np.linalg.eigvalsh(0.5 * (A + A.T)) if np.all(np.isfinite(A)) else None
            self.hyper.append((src, float(t), np.array(q), ev, h))

    def simulate(self, meth, h, T=None, **kw):
        import warnings

        from ..core.grid import GridWarning
        from ..run.api import simulate

        from ..core.grid import grid_count
        from ..core.progress import format_seconds

        t = time.perf_counter()
        with warnings.catch_warnings():   # said once, in the report's notes (see __init__)
            warnings.simplefilter("ignore", GridWarning)
            tr = simulate(self.sysm, meth, h=h, T=self.T if T is None else T, q0=self.q0, p0=self.p0,
                          params=self.params, tier=self.tier, loader=self.loader, **kw)
        self.run_seconds += time.perf_counter() - t
        self.steps_done += grid_count(h, self.T if T is None else T)
        self.runs += 1
        left = self.run_seconds / self.steps_done * max(0, self.steps_total - self.steps_done)
        now = time.perf_counter()
        quiet = now - self.said_at < max(10.0, 0.1 * (now - self.t_start))
        if self.runs > 1 and self.run_seconds + left > 10.0 and not quiet:
            self.said_at = now   # a long ladder says how far its runs are, and what is left
            self.say(f"runs: {self.steps_done:,} of {self.steps_total:,} steps, about {format_seconds(left)} left")
        return tr

    # --- the exact solutions ------------------------------------------------------------------------
    def references(self):
        """The exact smooth solution on the coarsest grid (constraint ignored) and vcirun.reference."""
        from ..reference_solution.exact import reference

        T, hs = self.T, self.hs
        self.say("exact smooth solution (DOP853, constraint ignored)")
        from ..core.grid import grid_count

        self.N0 = N0 = grid_count(hs[0], T)
        # nested ladder (every grid contains the coarsest one, same end): the test suite's error measure
        self.nested = all(grid_count(x, T) % N0 == 0 and abs(grid_count(x, T) * x - N0 * hs[0]) <= 1e-9 * T for x in hs)
        self.t_smooth = np.linspace(0.0, N0 * hs[0], N0 + 1) if self.nested else np.unique(np.concatenate(
            [x * np.arange(grid_count(x, T) + 1) for x in hs]))
        self.partial = None
        try:
            self.qs_ref, self.ps_ref = exact_smooth(self.base, self.prm, self.q0, self.p0, self.t_smooth,
                                                    force=self.force)
            self.smooth_ok = True
            self.qscale = max(float(np.max(np.abs(self.qs_ref))), 1e-300)
            self.sample_M("smooth solution (constraint ignored)", self.t_smooth, self.qs_ref)
        except RuntimeError as e:
            self.smooth_ok, self.qscale = False, 1.0
            self.add(ck.Check("smooth reference", None, ck.FAIL, float("nan"), "DOP853 succeeds",
                              "a smooth solution on [0, T]", _message(e, "smooth reference")))
            self.partial = smooth_until_failure(self.base, self.prm, self.q0, self.p0, T, force=self.force)
            t_part, q_part, _ = self.partial   # as far as DOP853 got: where it stopped, and the state of M there
            self.sample_M(f"smooth solution up to its failure at t = {t_part[-1]:.6g}", t_part, q_part)
        self.say("exact nonsmooth reference (vcirun.reference: events + elastic reset)")
        self.ref, self.ref_ok = None, False
        self.window = Window(T)
        self.ref_reason = "no exact nonsmooth reference (vcirun.reference failed)"
        try:
            self.ref = reference(self.sysm, T=T, q0=self.q0, p0=self.p0, params=self.params, tier=self.tier)
        except (RuntimeError, ValueError) as e:
            self.add(ck.Check("reference", None, ck.FAIL, float("nan"), "vcirun.reference succeeds",
                              "the exact nonsmooth solution on [0, T]", _message(e, "reference")))
            return
        self.ref_ok = True
        ref = self.ref
        # a reference that ends early (Painleve's paradox: ref.status "painleve") is compared where it is
        self.ref_T = T_ref = min(T, float(ref.T))
        tt = np.linspace(0.0, T_ref, 2001)
        qt = ref(tt)
        self.ref_scale = max(float(np.max(np.abs(qt))), 1e-300)
        acc = float(ref.accuracy)
        rows = [{"impacts": len(ref.impacts), "first impacts": ", ".join(f"{t:.6g}" for t in ref.impacts[:6]),
                 "accuracy (vs a 10x tighter solve)": ck.fmt(acc)}]
        v = ck.PASS if acc <= 1e-8 * max(1.0, self.ref_scale) else ck.WARN
        note = f"{len(ref.impacts)} impacts on [0, {T:g}]; self-reported accuracy {acc:.2e}"
        # a forced system's exact reference must follow the forced smooth solve before the first impact;
        # where it does not (a force the reference does not integrate), the impact checks are skipped
        if self.force is not None and self.smooth_ok:
            # (before the first impact and the first held contact: the smooth solve ignores the constraint)
            holds = [a for a, _, _ in getattr(ref, "held_intervals", [])]
            free = min([T_ref] + list(ref.impacts[:1]) + holds[:1])
            m = self.t_smooth < 0.9 * free
            dev = float(np.max(np.abs(ref(self.t_smooth[m]) - self.qs_ref[m]))) if m.sum() >= 2 else 0.0
            if dev > 1e-7 * max(1.0, self.qscale):
                self.ref_ok = False
                self.ref_reason = "vcirun.reference ignores this system's forcing"
                v = ck.WARN
                note = (f"vcirun.reference ignores the forcing of this system (differs from the forced smooth "
                        f"solution by {dev:.2e} before the first impact): impact checks skipped")
        if self.ref_ok:
            self.sample_M("exact reference", tt, qt)
            self.window = settle_window(ref, T_ref, self.hs[0], [c.name for c in self.sysm.constraints])
            if T_ref < T:
                Tw = float(np.floor(min(self.window.T, T_ref) / self.hs[0] + 1e-9) * self.hs[0])
                self.window = Window(Tw, f"the exact reference ends at t = {T_ref:.6g} with status {ref.status} "
                                     f"({' '.join(str(ref.message).split())}): the impact checks use [0, {Tw:g}]",
                                     int(np.sum(np.asarray(ref.impacts) <= Tw)))
                v = ck.WARN
            if self.window.cut:
                self.res.notes.append("impact checks on a window: " + self.window.note)
                note += f"; impact checks on [0, {self.window.T:g}] (" + (
                    "the motion comes to rest" if T_ref == T else f"the reference ends at t = {T_ref:.6g}") + ": see the notes)"
            if self.friction:
                note += self.friction_reference(ref)
        self.add(ck.Check("reference", None, v, acc, "accuracy <= 1e-8 max |q|",
                          "an exact reference far more accurate than the methods", note, rows))

    def friction_reference(self, ref) -> str:
        """The reference's mode changes on the window (self.ref_modes), a note where its motion comes to
        rest with every contact stuck, or where it ends on Painleve's paradox; returns the reference
        check's addition to its note."""
        from .friction import reference_mode_changes, rest_time

        Tw = self.window.T
        self.ref_modes = reference_mode_changes(ref, Tw)
        add = f"; {len(self.ref_modes)} friction mode changes on [0, {Tw:g}]"
        t_rest = rest_time(ref, self.base, self.prm, self.n, self.T) if self.ref_T == self.T else None
        if t_rest is not None:
            who = ", ".join(self.sysm.constraints[j].name for j in ref.mode_intervals[-1][2])
            how = ("a run sticks at its own located mode change and stays at rest, so the checks run through the "
                   "rest (from there on a run's error is the error of the state it stopped in)" if t_rest < Tw else
                   f"after the window of the impact checks, [0, {Tw:g}]")
            self.res.notes.append(f"the exact motion comes to rest at t = {t_rest:.6g} ({who} stuck) and stays at "
                                  f"rest to T = {self.T:g}: {how}")
            add += f"; at rest from t = {t_rest:.6g}"
        return add

    def choose_probes(self):
        """The start state and N_PROBES states along the exact motion (or a run, if there is none)."""
        T, n, h0 = self.T, self.n, self.hs[0]
        self.probes = [Probe(self.q0, self.p0, 0.0, h0)]
        run = None
        if not self.ref_ok and not self.smooth_ok:
            try:
                run = self.simulate(self.meths[0], self.hs[-1])
            except ValueError:
                run = None
        for k in range(N_PROBES):
            t = T * (k + 1) / (N_PROBES + 1)
            if self.ref_ok:
                t = min(t, self.ref_T)
                y = self.ref.state([t])[0]
                self.probes.append(Probe(y[:n], y[n:], t, h0))
            elif self.smooth_ok:
                j = int(np.argmin(np.abs(self.t_smooth - t)))
                self.probes.append(Probe(self.qs_ref[j], self.ps_ref[j], float(self.t_smooth[j]), h0))
            elif run is not None and len(run.t) > N_PROBES + 1:   # spread over the part it reached
                j = int(np.argmin(np.abs(run.t - t * run.t[-1] / T)))
                self.probes.append(Probe(run.q[j], run.p[j], float(run.t[j]), h0))

    # --- one method --------------------------------------------------------------------------------
    def method_checks(self, meth):
        from ..codegen.build import load_module

        name = meth.name
        ks = meth.kernel_set()
        self.say(f"{name}: loading its compiled module")
        try:
            if self.loader is None:
                mod = load_module(self.sysm, ks, self.tier)
            else:
                from ..codegen.kernel_cache import of

                mod = of(self.loader).load_module(self.sysm, ks)
        except ValueError as e:   # a method the system's declaration does not support
            self.add(ck.skip("every check", name, f"{name} does not run on this system: {' '.join(str(e).split())}"))
            return
        mcva = meth.has_modified_energy
        self.say(f"{name}: derivative checks of the generated kernels at {len(self.probes)} states")
        rows = check_kernels(mod, self.prm, self.probes, force=self.force, full_stages=ks.full_stages,
                             declared=self.declared(), h_min=self.hs[-1])
        self.add(ck.derivative_check(name, rows, len(self.probes)))
        self.say(f"{name}: symplecticity defect of its one-step maps")
        rows = _symplecticity_rows(mod, self.prm, self.probes, self.hs, mcva, self.n)
        self.add(ck.symplecticity_check(name, rows, self.force is not None))
        self.smooth_order(meth)
        if meth.reset is None:    # a bare discrete Lagrangian: smooth integration only
            for nm in ("L2 order through impacts", "impact times", "energy across impacts") + (
                    ("mode-change times", "energy account") if self.friction else ()):
                self.add(ck.skip(nm, name, f"{name} integrates the smooth system (no reset): no impacts to check"))
            return
        self.impact_checks(meth)

    def smooth_order(self, meth):
        from ..discrete.lagrangians import LIBRARY

        name, hs = meth.name, self.hs
        self.say(f"{name}: smooth runs (constraint ignored) over h = {hs[0]:g} .. {hs[-1]:g}")
        used, errs, excl = [], [], []
        for x in hs:
            tr = self.simulate(meth, x, constrained=False)
            self.sample_M(f"{name} smooth run h = {x:g}", *_thin(tr), h=x)
            if tr.status != "ok":
                excl.append((x, f"status {tr.status}"))
            elif self.smooth_ok:
                used.append(x)
                errs.append(_smooth_error(tr, x, self.T, self.N0, self.nested, self.t_smooth, self.qs_ref))
        if not self.smooth_ok:
            self.add(ck.skip("smooth order", name, "no smooth reference"))
            return
        c = ck.order_check("smooth order", name, used, errs, LIBRARY[meth.ld].order, scale=self.qscale,
                           quantity="max |q - q_exact|", excluded=excl)
        c.note += f" (Ld {meth.ld}, constraint ignored)"
        c.expected += f" (Ld {meth.ld})"
        self.add(c)

    def impact_checks(self, meth):
        """Runs through impacts over the ladder (on the settle window, vcirun.verification.window): L2
        order, impact times, the energy change across impact steps less the impact law's loss and the
        forcing work (the energy account), and (MCVA family) the truncated modified Hamiltonian's
        conservation order; with friction also the mode-change times against the reference's and the
        rest of the energy account (vcirun.verification.friction)."""
        name, hs, ref = meth.name, self.hs, self.ref
        mcva = meth.has_modified_energy
        p_imp = _impact_order(meth)
        Tw = self.window.T
        short = self.ref_ok and self.window.T < self.hs[0]
        if short or (self.ref_ok and self.window.cut and self.window.impacts == 0 and len(ref.impacts)):
            why = (f"{self.window.note}: no step of the coarsest h = {self.hs[0]:g} fits in it" if short else
                   "no impact of the exact motion lies before the window in which the coarsest h resolves its "
                   f"bounces ({self.window.note}): use a smaller h ladder")
            for nm in ("L2 order through impacts", "impact times", "energy across impacts") + (
                    ("modified Hamiltonian",) if mcva else ()) + (
                    ("mode-change times", "energy account") if self.friction else ()):
                self.add(ck.skip(nm, name, why))
            return
        span = f"h = {hs[0]:g} .. {hs[-1]:g}" + (f" on [0, {Tw:g}]" if self.window.cut else "")
        self.say(f"{name}: runs through impacts over {span}")
        l2_h, l2, excl, ev_rows, en_rows, mode_rows, acc_rows, coarse = [], [], [], [], [], [], [], []
        hm_h, hm_var, hm_scale, hm_excl = [], [], [], []
        ref_imp = np.asarray(ref.impacts)[np.asarray(ref.impacts) <= Tw] if self.ref_ok else None
        for x in hs:
            tr = self.simulate(meth, x, T=Tw)
            self.sample_M(f"{name} run h = {x:g}", *_thin(tr), h=x)
            acc = tr.energy_account() if tr.status == "ok" else None
            if mcva:
                if tr.status == "ok" and np.all(np.isfinite(tr.Hmod)):
                    hm = tr.Hmod - acc.term(LAW).series   # H~ plus the law's losses so far
                    if acc.term(FRICTION) is not None:
                        hm = hm - acc.term(FRICTION).series   # ... and the friction work
                    hm_h.append(x)
                    hm_var.append(float(np.ptp(hm)))
                    hm_scale.append(float(np.mean(np.abs(tr.Hmod))))
                else:
                    hm_excl.append((x, f"status {tr.status}"))
            if self.ref_ok:
                nimp, nref = len(tr.impacts), len(ref_imp)
                same = tr.status == "ok" and nimp == nref
                terr = float(np.max(np.abs(tr.impacts - ref_imp))) if same and nimp else float("nan")
                ev_rows.append({"h": x, "n_impacts": nimp, "n_ref": nref, "time_error": terr, "status": tr.status})
                if tr.status != "ok":
                    excl.append((x, f"status {tr.status}"))
                elif nimp != nref:
                    excl.append((x, f"{nimp} impacts, reference {nref}"))
                else:
                    l2_h.append(x)
                    l2.append(_l2_error(tr, ref, ref_imp, self.sysm.reset_map is not None))
                    coarse.append(_on_coarsest(tr, x, Tw, self.hs[0]))
            if self.friction and self.ref_ok:
                from .friction import compare, run_mode_changes

                events, left = run_mode_changes(tr, Tw, self.ref_modes)
                terr, diff = compare(events, self.ref_modes, self.names)
                mode_rows.append({"h": x, "n_changes": len(events), "n_ref": len(self.ref_modes), "time_error": terr,
                                  "status": tr.status, "first_difference": diff, "at_start": left})
            if self.friction and acc is not None:
                rest = np.asarray(acc.rest_series, float)
                acc_rows.append({"h": x, "rest": float(np.max(np.abs(rest))) if rest.size else 0.0,
                                 "law": acc.total(LAW), "friction": acc.total(FRICTION), "scale": float(acc.scale)})
            if acc is not None:
                dE = _energy_changes(tr, acc, mcva and self.force is None)
                imp = np.asarray(tr.impact_step, bool)[: dE.size]
                en_rows.append({"h": x, "jump": float(dE[imp].max()) if imp.any() else float("nan"),
                                "smooth": float(dE[~imp].max()) if (~imp).any() else float("nan")})
        if mcva:
            if self.force is not None:
                self.add(ck.skip("modified Hamiltonian", name, "forced system: H~ is not conserved"))
            elif self.friction:
                # friction is a non-conservative force: H~ changes by the friction work, which the loop
                # sums at the method's order (docs/derivations/friction.md, "Energy")
                c = ck.order_check("modified Hamiltonian", name, hm_h, hm_var, p_imp,
                                   scale=float(np.mean(hm_scale)) if hm_scale else 1.0, tol=ck.MH_TOL,
                                   one_sided=True, quantity="max - min of H~ less the losses", excluded=hm_excl)
                c.expected = (f"variation ~ h^{p_imp:g} or smaller (friction: H~ less the friction work and the "
                              f"law's losses; h^{meth.mh_order} where friction does no work)")
                c.note += (" (along the runs through impacts, with the impact law's losses and the friction work "
                           "added back: friction is a non-conservative force, H~ changes by its work, which the "
                           f"held steps sum at order {p_imp:g})")
                self.add(c)
            else:
                c = ck.order_check("modified Hamiltonian", name, hm_h, hm_var, meth.mh_order,
                                   scale=float(np.mean(hm_scale)) if hm_scale else 1.0, tol=ck.MH_TOL,
                                   quantity="max - min of H~ over [0, T]", excluded=hm_excl)
                c.expected = f"variation ~ h^{meth.mh_order} (mh_order {meth.mh_order})"
                c.note += (" (along the runs through impacts, with the impact law's losses added back: R^MCVA "
                           "conserves H~ less the law's loss, the smooth steps vary it)")
                self.add(c)
        if self.ref_ok:
            c = ck.order_check("L2 order through impacts", name, l2_h, l2, p_imp,
                               scale=self.ref_scale * np.sqrt(Tw), quantity="L2 error", excluded=excl)
            if excl and c.verdict == ck.PASS:
                c.verdict = ck.WARN
                c.note = f"runs excluded: {'; '.join(f'h = {x:g}: {why}' for x, why in excl)}; " + c.note
            if c.verdict == ck.WARN:
                ck.converges_elsewhere(c, l2_h, l2, _successive_differences(coarse), self.ref_scale * np.sqrt(Tw))
            self.add(c)
            self.add(ck.impact_events_check(name, ev_rows, p_imp, Tw))
            if self.friction:
                self.add(ck.mode_events_check(name, mode_rows, p_imp, Tw))
        else:
            for nm in ("L2 order through impacts", "impact times") + (("mode-change times",) if self.friction else ()):
                self.add(ck.skip(nm, name, self.ref_reason))
        forced = self.force is not None
        e_scale = float(np.mean(hm_scale)) if (mcva and hm_scale and not forced) else abs(self.H0) or 1.0
        energy = "H - W" if forced else ("H~" if mcva else "H")
        c = ck.impact_energy_check(name, en_rows, energy, p_imp, e_scale)
        c.note += ("; the change is taken less the impact law's loss" + (" and the forcing work" if forced else "")
                   + (" and the friction work" if self.friction else "") + " of the step (the energy account)"
                   + ("; impact steps are the steps with an event: impacts and friction mode changes"
                      if self.friction else ""))
        self.add(c)
        if self.friction:
            a_scale = max([r["scale"] for r in acc_rows if np.isfinite(r["scale"])] + [abs(self.H0)]) or 1.0
            # (each account's scale: max(|H0|, the largest kinetic energy of the run))
            self.add(ck.energy_account_check(name, acc_rows, p_imp, a_scale))

    # --- hyperregularity ---------------------------------------------------------------------------
    def hyperregularity(self):
        c = ck.hyperregularity_check(self.hyper, self.lam0)
        if self.partial is None:
            return c
        # the exact solution stopped: if M(q) is singular there, that is why (a motion that runs into a
        # singular mass matrix cannot be integrated, by any method)
        t_part, q_part, _ = self.partial
        A = self.M(q_part[-1])
        ev = np.linalg.eigvalsh(0.5 * (A + A.T)) if np.all(np.isfinite(A)) else None
        if ev is None or ev[0] <= 0 or ev[-1] / ev[0] > ck.COND_WARN or ev[0] < ck.LAMBDA_RATIO_WARN * self.lam0:
            if ev is None:
                what = "entries that are not finite"
            elif ev[0] > 0:
                what = (f"smallest eigenvalue {ev[0]:.3g} ({ev[0] / self.lam0:.2e} x its value at q0), "
                        f"cond(M) = {ev[-1] / ev[0]:.3g}")
            else:
                what = f"smallest eigenvalue {ev[0]:.3g}"
            c.verdict = ck.FAIL
            c.value = float("nan") if ev is None else float(ev[0])
            c.note = (f"the exact motion runs into a singular mass matrix: DOP853 stops at t = {t_part[-1]:.6g}, "
                      f"q = {ck.fmt_vec(q_part[-1])}, where M(q) has {what}; " + c.note)
        return c


def _message(e, prefix) -> str:
    """An exception's text on one line, without a leading 'prefix: ' (the check already names it)."""
    text = " ".join(str(e).split())
    return text[len(prefix) + 2:] if text.startswith(prefix + ": ") else text


def _energy_changes(tr, acc, modified):
    """|change of R| per step, R = E - E0 less the impact law's term and the forcing work of the run's
    energy account (vcirun.run.accounts): what the method, not the model, changed in the step. E = H~
    (modified: the MCVA family, unforced) or H."""
    E = np.asarray(tr.Hmod if modified else tr.H, float)
    for term in acc.terms:
        E = E - term.series
    return np.abs(np.diff(E))


def _l2_error(tr, ref, ref_imp, jumps: bool) -> float:
    """`vcirun.l2_error` of a run whose impacts pair with the reference's (ref_imp, the same count); where
    the system's reset map moves q (`jumps`), without the grid points that lie between a run's impact and
    the reference's. There the run and the reference are on opposite sides of q's jump (a wheel's leg
    exchange), an O(1) difference at a point whose impact-time error the impact-time check judges. With
    those points kept, a grid point that falls in the gap at one h and not at the next gives the rimless
    wheel's MCVAC errors 0.03, 0.11, 0.11, 5e-4, 1e-4, 0.03, 0.03 down the ladder."""
    from ..reference_solution.exact import l2_error

    if not jumps or not len(ref_imp):
        return l2_error(tr, ref)
    t = tr.t
    keep = np.ones(t.shape[0], bool)
    for a, b in zip(np.asarray(tr.impacts, float), np.asarray(ref_imp, float)):
        keep &= ~((t >= min(a, b)) & (t < max(a, b)))
    d = tr.q[keep] - ref(t[keep])
    return float(np.sqrt(tr.h * np.sum(d * d)))


def _on_coarsest(tr, h, T, h0):
    """The run's q at the points of the coarsest grid on [0, T] (None where its grid does not hold
    them: a ladder that is not nested)."""
    from ..core.grid import grid_count

    N, N0 = grid_count(h, T), grid_count(h0, T)
    if N0 == 0 or N % N0 or len(tr.q) != N + 1:
        return None
    return np.asarray(tr.q[:: N // N0], float)


def _successive_differences(Q):
    """max |q_h - q_h'| over the coarsest grid between consecutive runs of the ladder (coarse to fine;
    nan where a run is not on that grid)."""
    out = []
    for a, b in zip(Q[:-1], Q[1:]):
        ok = a is not None and b is not None and a.shape == b.shape
        out.append(float(np.max(np.abs(a - b))) if ok else float("nan"))
    return out


def _thin(tr, k=400):
    """(t, q) of a run at about k grid points (for sampling M along it)."""
    stride = max(1, len(tr.t) // k)
    return tr.t[::stride], tr.q[::stride]


def _smooth_error(tr, h, T, N0, nested, t_smooth, qs_ref):
    """max |q_k - q_exact(t_k)| over the coarsest grid (nested ladders: the test suite's measure) or
    over the run's own grid."""
    if nested:
        from ..core.grid import grid_count

        stride = grid_count(h, T) // N0
        return float(np.max(np.abs(tr.q[::stride] - qs_ref)))
    idx = np.clip(np.searchsorted(t_smooth, tr.t - 1e-12 * T), 0, len(t_smooth) - 1)   # the union grid holds tr.t
    return float(np.max(np.abs(tr.q - qs_ref[idx])))


# stencil steps of the symplecticity Jacobians, coarse to fine: the stencil's truncation falls as d^4
# and its round-off grows as eps / d, so the defect of a symplectic map falls along these steps until
# round-off (an 8-link chain at h = 0.04: 7e-3 at 1e-3, 9e-7 at 1e-4, 8e-11 at 1e-5), while a map's own
# defect does not depend on d
DEFECT_STEPS = (1e-3, 3e-4, 1e-4, 3e-5, 1e-5, 3e-6)
# the rise from the smallest defect to the next finer step that marks it as the stencil's round-off floor
# (round-off grows as 1/d: 3.3x per step; a defect of the map's own stays within a few percent)
FLOOR_RISE = 1.5


def _defect(f, y) -> tuple[float, float]:
    """(defect, floor) of map f at y. The defect: J by the 4th-order stencil at the steps of
    DEFECT_STEPS in turn, until the defect is a hundredth of the pass threshold or stops falling (to
    less than a third of the previous step's), the smallest kept; where it stops on a slow fall above
    the threshold, one finer step says whether that is the bottom. floor: where the smallest lies at
    the bottom of a V (3x below the step before it, where truncation falls as d^4, and FLOOR_RISE x
    below the step after it, where round-off grows as 1/d), the defect the stencil's round-off makes
    there: J's entries err by about NEWTON_TOL / d (the maps solve to NEWTON_TOL) and J^T Omega J by
    2 max|J| times that; else 0. A V-bottom defect at or below its floor is the stencil's error, not the
    map's (the Gauss partial flow of a 12-link chain at h = 0.01, |J| = 108: 4.4e-6, 5.2e-8, 2.2e-7 at
    d = 3e-5, 1e-5, 3e-6, floor 2.2e-7; an 8th-order stencil bottoms out at 2e-8 there)."""
    thr = ck.SYMPLECTIC_THRESHOLDS[0]
    vals, jmax, last = [], [], False
    for k, d in enumerate(DEFECT_STEPS):
        J = map_jacobian(f, y, d)
        x = symplecticity_defect(J)
        vals.append(x)
        jmax.append(float(np.max(np.abs(J))))
        if last or x <= 0.01 * thr:
            break
        if k and not x < vals[-2] / 3:   # stopped falling
            if x >= vals[-2] or x <= thr:
                break
            last = True
    k = int(np.argmin(vals))
    if 0 < k < len(vals) - 1 and vals[k + 1] >= FLOOR_RISE * vals[k]:
        return vals[k], 2.0 * jmax[k] * NEWTON_TOL / DEFECT_STEPS[k]
    return vals[k], 0.0


def _defect_where_defined(make, y, x, h_min):
    """(defect, floor, the step it was measured at) of the map make(h) at y (`_defect`): at step x,
    else at the largest of x / 2, x / 4, ... >= h_min at which every Newton solve of the stencil
    converges (fd.smaller_steps: a step the map's equations cannot be solved at says nothing about its
    symplecticity); (inf, 0, x) where it converges at none."""
    for h in smaller_steps(x, h_min):
        try:
            return (*_defect(make(h), y), h)
        except StepFailed:
            continue
    return float("inf"), 0.0, x


def _symplecticity_rows(mod, prm, probes, hs, mcva, n):
    rows = []
    h_list = [hs[0], hs[len(hs) // 2]]
    for k, s in enumerate(probes):
        label = "start" if k == 0 else f"t = {s.t:.4g}"
        y = np.concatenate([s.q, s.p])
        for x in h_list:
            def full(x, t=s.t):
                return lambda yy: np.concatenate(step(mod, yy[:n], yy[n:], x, t, prm, newton_tol=NEWTON_TOL))
            d, floor, at = _defect_where_defined(full, y, x, hs[-1])
            rows.append({"map": "full Phi_h", "h": at, "state": label, "defect": d, "floor": floor})
            if mcva and hasattr(mod, "gauss_partial"):
                def part(x, t=s.t):
                    def f(yy):
                        q1, p1, v = np.empty(n), np.empty(n), np.empty(n)
                        it, _ = mod.gauss_partial(np.ascontiguousarray(yy[:n]), np.ascontiguousarray(yy[n:]), 0.5 * x,
                                                  x, t, prm, NEWTON_TOL, 50, q1, p1, v)
                        if it < 0:
                            raise StepFailed("gauss_partial did not converge")
                        return np.concatenate([q1, p1])
                    return f
                d, floor, at = _defect_where_defined(part, y, x, hs[-1])
                rows.append({"map": "partial flow of H~ (tau = h/2)", "h": at, "state": label, "defect": d,
                             "floor": floor})
    return rows
