"""`vcirun.verify`: the test suite's numerical checks, run on the user's own system and methods."""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from . import checks as ck
from .fd import Probe, check_kernels, map_jacobian, symplecticity_defect
from .harness import StepFailed, exact_smooth, smooth_until_failure, step

DEFAULT_METHODS = ("CVA", "MCVAC")
DEFAULT_H_MAX = 0.04
DEFAULT_LEVELS = 7         # h = 0.04, 0.02, ..., 0.000625
N_PROBES = 3               # states along the motion (besides the start) for kernel and map checks
NEWTON_TOL = 1e-14         # the maps' Newton tolerance inside the FD Jacobians (noise / FD step << 1e-8)
IMPACT_ORDER_MCVA = 2      # the MCVA family is second order overall through impacts (the brief, Section 4.3)


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
        from .report import markdown

        return markdown(self, figure)

    def figure(self, path):
        from .report import figure

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
    from ..methods import resolve_method

    if methods is None:
        methods = DEFAULT_METHODS
    if isinstance(methods, str):
        methods = [m.strip() for m in methods.split(",") if m.strip()]
    out = [resolve_method(m) for m in methods]
    if not out:
        raise ValueError("methods: give at least one method (e.g. CVA,MCVAC)")
    return out


def _impact_order(meth):
    from ..discrete.lagrangians import LIBRARY

    return IMPACT_ORDER_MCVA if meth.reset == "mcva" else LIBRARY[meth.ld].order


def _forcing(sysm):
    """numpy f(q, qdot, t) of a forced system (sympy.lambdify of the declaration), or None."""
    if not sysm.is_forced:
        return None
    import sympy as sp

    fn = sp.lambdify([sysm.q, sysm.qd, sysm.t, sysm.param_symbols], list(sysm.forcing), "numpy")
    return fn


def verify(system, methods=None, *, q0=None, p0=None, beta=None, T=5.0, h=None, params=None,
           progress=None) -> VerifyResult:
    """Run the numerical checks of vcirun's test suite on `system` with `methods`.

    system : built-in name, YAML path or MechanicalSystem; methods: names (list or "CVA,MCVAC"; default
             CVA and MCVAC) or Method objects; q0, p0 or beta: the start state (as vcirun.simulate);
    T      : final time of every run; h: the step ladder (default 0.04 / 2^k, k = 0..6);
    params : parameter overrides; progress: callable(str) told what is being computed.

    Checks (each a verdict pass / warn / fail / skip with its number and threshold; see
    vcirun.verification.checks): derivatives of every generated kernel the methods' modules define
    against finite differences at the start and N_PROBES states along the motion; hyperregularity of
    M(q) along the motion; smooth observed orders (constraint ignored) against the exact smooth
    solution; the symplecticity defect of each one-step map; the MCVA family's modified-Hamiltonian
    conservation order; through impacts, the L2 order and the impact-time error against the exact
    reference (vcirun.reference) and the energy change across impact steps.

    Returns a VerifyResult (`.ok`, `.checks`, `.save(path)` writes the Markdown report and figure).
    Bad input raises ValueError naming the field."""
    from ..api import resolve_system, simulate
    from ..codegen.build import load_module
    from ..reference import l2_error, reference

    say = progress or (lambda msg: None)
    t_start = time.perf_counter()
    T = float(T)
    if not (T > 0 and np.isfinite(T)):
        raise ValueError(f"T: must be a positive finite time (got {T})")
    hs = _ladder(h, T)
    meths = _methods(methods)
    sysm = resolve_system(system)
    prm = sysm.param_values(params)
    q0, p0 = sysm.initial_state(beta=beta, q0=q0, p0=p0, params=prm)
    n = sysm.n
    force_np = _forcing(sysm)
    force = None if force_np is None else (lambda q, v, t: np.asarray(force_np(q, v, t, prm), float).ravel())
    res = VerifyResult(system=sysm.name, n=n, methods=[m.name for m in meths], q0=q0, p0=p0, T=T, h=hs,
                       params=dict(zip(sysm.params, prm.tolist())))
    add = res.checks.append
    Mq0 = sysm.mass_matrix(q0, prm)
    lam0 = float(np.linalg.eigvalsh(0.5 * (Mq0 + Mq0.T))[0])

    # --- references ---------------------------------------------------------------------------
    say("exact smooth solution (DOP853, constraint ignored)")
    from ..methods import METHODS

    base_mod = load_module(sysm, METHODS["CVA"].kernel_set())   # system kernels + Hamilton's equations
    H0 = float(base_mod.hamiltonian(q0, p0, prm))
    N0 = int(round(T / hs[0]))
    nested = all(abs(T / x - round(T / x)) < 1e-9 * T / x and int(round(T / x)) % N0 == 0 for x in hs)
    t_smooth = np.linspace(0.0, N0 * hs[0], N0 + 1) if nested else np.unique(np.concatenate(
        [x * np.arange(int(round(T / x)) + 1) for x in hs]))
    try:
        qs_ref, ps_ref = exact_smooth(base_mod, prm, q0, p0, t_smooth, force=force)
        smooth_ok = True
    except RuntimeError as e:
        smooth_ok = False
        add(ck.Check("smooth reference", None, ck.FAIL, float("nan"), "DOP853 succeeds", "a smooth solution on [0, T]",
                     str(e)))
        partial = smooth_until_failure(base_mod, prm, q0, p0, T, force=force)
    say("exact nonsmooth reference (vcirun.reference: events + elastic reset)")
    ref, ref_ok, ref_reason = None, False, "no exact nonsmooth reference (vcirun.reference failed)"
    try:
        ref = reference(sysm, T=T, q0=q0, p0=p0, params=params)
        ref_ok = True
    except (RuntimeError, ValueError) as e:
        add(ck.Check("reference", None, ck.FAIL, float("nan"), "vcirun.reference succeeds",
                     "the exact nonsmooth solution on [0, T]", " ".join(str(e).split())))
    qscale = float(np.max(np.abs(qs_ref))) if smooth_ok else 1.0
    qscale = max(qscale, 1e-300)
    if ref_ok:
        tt = np.linspace(0.0, T, 2001)
        ref_scale = float(np.max(np.abs(ref(tt))))
        acc = float(ref.accuracy)
        rows = [{"impacts": len(ref.impacts), "first impacts": ", ".join(f"{t:.6g}" for t in ref.impacts[:6]),
                 "accuracy (vs a 10x tighter solve)": ck._num(acc)}]
        v = ck.PASS if acc <= 1e-8 * max(1.0, ref_scale) else ck.WARN
        note = f"{len(ref.impacts)} impacts on [0, {T:g}]; self-reported accuracy {acc:.2e}"
        # (issue 15) until vcirun.reference integrates the generalized force, a forced system's exact
        # reference is the unforced motion: detect it against the forced smooth solve before the first impact
        if force is not None and smooth_ok:
            t1 = ref.impacts[0] if len(ref.impacts) else T
            m = t_smooth < 0.9 * t1
            if m.sum() >= 2:
                dev = float(np.max(np.abs(ref(t_smooth[m]) - qs_ref[m])))
                if dev > 1e-7 * max(1.0, qscale):
                    ref_ok = False
                    ref_reason = "vcirun.reference ignores this system's forcing (issue 15)"
                    v = ck.WARN
                    note = (f"vcirun.reference ignores the forcing of this system (differs from the forced smooth "
                            f"solution by {dev:.2e} before the first impact; issue 15): impact checks skipped")
        add(ck.Check("reference", None, v, acc, "accuracy <= 1e-8 (relative to max |q|)",
                     "an exact reference far more accurate than the methods", note, rows))

    # --- probes: the start and states along the motion ---------------------------------------------
    probe_src = ref if ref_ok else None
    t_probe = [T * (k + 1) / (N_PROBES + 1) for k in range(N_PROBES)]
    probes = [Probe(q0, p0, 0.0, hs[0])]
    fallback = None
    if probe_src is None and not smooth_ok:   # no exact solution: states of a run of the first method
        try:
            fallback = simulate(sysm, meths[0], h=hs[-1], T=T, q0=q0, p0=p0, params=params)
        except ValueError:
            fallback = None
    for t in t_probe:
        if probe_src is not None:
            y = probe_src.state([t])[0]
            probes.append(Probe(y[:n], y[n:], t, hs[0]))
        elif smooth_ok:
            j = int(np.argmin(np.abs(t_smooth - t)))
            probes.append(Probe(qs_ref[j], ps_ref[j], float(t_smooth[j]), hs[0]))
        elif fallback is not None and len(fallback.t) > N_PROBES + 1:   # spread over the part it reached
            j = int(np.argmin(np.abs(fallback.t - t * fallback.t[-1] / T)))
            probes.append(Probe(fallback.q[j], fallback.p[j], float(fallback.t[j]), hs[0]))
    hyper = []   # (source, t, q, eigenvalues or None)

    def sample_M(src, ts, Q, h=None):
        for t, q in zip(ts, Q):
            A = sysm_M(q)
            ev = np.linalg.eigvalsh(0.5 * (A + A.T)) if np.all(np.isfinite(A)) else None
            hyper.append((src, float(t), np.array(q), ev, h))

    def sysm_M(q):
        A = np.empty((n, n))
        base_mod.sys_M(np.ascontiguousarray(q, float), prm, A)
        return A

    if ref is not None:
        tt = np.linspace(0.0, T, 2001)
        sample_M("exact reference", tt, ref(tt))
    if smooth_ok:
        sample_M("smooth solution (constraint ignored)", t_smooth, qs_ref)
    else:   # as far as DOP853 got: where it stopped, and in what state of M
        t_part, q_part, _ = partial
        sample_M(f"smooth solution up to its failure at t = {t_part[-1]:.6g}", t_part, q_part)

    # --- per method -------------------------------------------------------------------------------
    for meth in meths:
        from ..discrete.lagrangians import LIBRARY

        name = meth.name
        ks = meth.kernel_set()
        say(f"{name}: loading its compiled module")
        p_smooth = LIBRARY[meth.ld].order
        mcva = meth.reset == "mcva"
        try:
            mod = load_module(sysm, ks)
        except ValueError as e:   # e.g. the MCVA family on a forced system (until issue 15)
            add(ck.skip("every check", name, f"{name} does not run on this system: {' '.join(str(e).split())}"))
            continue

        say(f"{name}: derivative checks of the generated kernels at {len(probes)} states")
        rows = check_kernels(mod, prm, probes, force=force, full_stages=ks.full_stages)
        add(ck.derivative_check(name, rows, len(probes)))

        say(f"{name}: symplecticity defect of its one-step maps")
        add(ck.symplecticity_check(name, _symplecticity_rows(mod, prm, probes, hs, mcva, n), force is not None))

        say(f"{name}: smooth runs (constraint ignored) over h = {hs[0]:g} .. {hs[-1]:g}")
        sm_h, sm_err, sm_excl = [], [], []
        for x in hs:
            tr = simulate(sysm, meth, h=x, T=T, q0=q0, p0=p0, params=params, constrained=False)
            sample_M(f"{name} smooth run h = {x:g}", *_thin(tr), h=x)
            if tr.status != "ok":
                sm_excl.append((x, f"status {tr.status}"))
            elif smooth_ok:
                sm_h.append(x)
                sm_err.append(_smooth_error(tr, x, T, N0, nested, t_smooth, qs_ref))
        if smooth_ok:
            c = ck.order_check("smooth order", name, sm_h, sm_err, p_smooth, scale=qscale, quantity="max |q - q_exact|",
                               excluded=sm_excl)
            c.note += f" (Ld {meth.ld}, constraint ignored)"
            c.expected += f" (Ld {meth.ld})"
        else:
            c = ck.skip("smooth order", name, "no smooth reference")
        add(c)

        if meth.reset is None:    # a bare discrete Lagrangian: smooth integration only
            for nm in ("L2 order through impacts", "impact times", "energy across impacts"):
                add(ck.skip(nm, name, f"{name} integrates the smooth system (no reset): no impacts to check"))
            continue
        say(f"{name}: runs through impacts over h = {hs[0]:g} .. {hs[-1]:g}")
        p_imp = _impact_order(meth)
        l2_h, l2, excl, ev_rows, en_rows, hm_h, hm_var, hm_scale, hm_excl = [], [], [], [], [], [], [], [], []
        for x in hs:
            tr = simulate(sysm, meth, h=x, T=T, q0=q0, p0=p0, params=params)
            sample_M(f"{name} run h = {x:g}", *_thin(tr), h=x)
            if mcva:
                if tr.status == "ok" and np.all(np.isfinite(tr.Hmod)):
                    hm_h.append(x)
                    hm_var.append(float(np.ptp(tr.Hmod)))
                    hm_scale.append(float(np.mean(np.abs(tr.Hmod))))
                else:
                    hm_excl.append((x, f"status {tr.status}"))
            if ref_ok:
                nimp = len(tr.impacts)
                same = tr.status == "ok" and nimp == len(ref.impacts)
                terr = float(np.max(np.abs(tr.impacts - ref.impacts))) if same and nimp else float("nan")
                ev_rows.append({"h": x, "n_impacts": nimp, "n_ref": len(ref.impacts), "time_error": terr,
                                "status": tr.status})
                if tr.status != "ok":
                    excl.append((x, f"status {tr.status}"))
                elif nimp != len(ref.impacts):
                    excl.append((x, f"{nimp} impacts, reference {len(ref.impacts)}"))
                else:
                    l2_h.append(x)
                    l2.append(l2_error(tr, ref))
            if tr.status != "ok":
                continue
            dE = _energy_changes(tr, base_mod, prm, force, mcva)
            imp = np.asarray(tr.impact_step, bool)[: dE.size]
            en_rows.append({"h": x, "jump": float(dE[imp].max()) if imp.any() else float("nan"),
                            "smooth": float(dE[~imp].max()) if (~imp).any() else float("nan")})
        if mcva:
            if force is not None:
                add(ck.skip("modified Hamiltonian", name, "forced system: H~ is not conserved"))
            else:
                sc = float(np.mean(hm_scale)) if hm_scale else 1.0
                c = ck.order_check("modified Hamiltonian", name, hm_h, hm_var, meth.mh_order, scale=sc, tol=ck.MH_TOL,
                                   quantity="max - min of H~ over [0, T]", excluded=hm_excl)
                c.expected = f"variation ~ h^{meth.mh_order} (mh_order {meth.mh_order})"
                c.note += " (along the runs through impacts: R^MCVA conserves H~, the smooth steps vary it)"
                add(c)
        e_scale = float(np.mean(hm_scale)) if (mcva and hm_scale) else abs(float(H0)) or 1.0
        if ref_ok:
            c = ck.order_check("L2 order through impacts", name, l2_h, l2, p_imp, scale=qscale * np.sqrt(T),
                               quantity="L2 error", excluded=excl)
            if excl and c.verdict == ck.PASS:
                c.verdict = ck.WARN
                c.note = f"runs excluded: {'; '.join(f'h = {x:g}: {why}' for x, why in excl)}; " + c.note
            add(c)
            add(ck.impact_events_check(name, ev_rows, p_imp, T))
        else:
            for nm in ("L2 order through impacts", "impact times"):
                add(ck.skip(nm, name, ref_reason))
        add(ck.impact_energy_check(name, en_rows, "H~" if mcva else ("H - W" if force is not None else "H"), p_imp,
                                   e_scale))

    c = ck.hyperregularity_check(hyper, lam0)
    if not smooth_ok:
        # the exact solution stopped: if M(q) is singular there, that is why (a motion that runs into a
        # singular mass matrix cannot be integrated, by any method)
        t_part, q_part, _ = partial
        A = sysm_M(q_part[-1])
        ev = np.linalg.eigvalsh(0.5 * (A + A.T)) if np.all(np.isfinite(A)) else None
        if ev is None or ev[0] <= 0 or ev[-1] / ev[0] > ck.COND_WARN or ev[0] < ck.LAMBDA_RATIO_WARN * lam0:
            c.verdict = ck.FAIL
            what = ("not finite" if ev is None else f"smallest eigenvalue {ev[0]:.3g} ({ev[0] / lam0:.2e} x its value at "
                    f"q0), cond(M) = {ev[-1] / ev[0]:.3g}" if ev[0] > 0 else f"smallest eigenvalue {ev[0]:.3g}")
            c.value = float("nan") if ev is None else float(ev[0])
            c.note = (f"the exact motion runs into a singular mass matrix: DOP853 stops at t = {t_part[-1]:.6g}, "
                      f"q = {ck._vec(q_part[-1])}, where M(q) has {what}; " + c.note)
    add(c)
    # system-level checks first in the report
    res.checks.sort(key=lambda c: c.method is not None)
    res.seconds = time.perf_counter() - t_start
    if force is not None:
        res.notes.append("forced system: the exact smooth solution adds the declared generalized force to "
                         "Hamilton's equations (sympy.lambdify of the declaration)")
    return res


def _energy_changes(tr, mod, prm, force, mcva):
    """|E(t_k+1) - E(t_k)| per step, E = H~ (MCVA family) or H; for a forced system |dH - W| with W the
    work of the forces over the step (trapezoidal on each side of every impact in it, so the velocity
    jump is never straddled: O(h^3) per step)."""
    E = tr.Hmod if mcva else tr.H
    dE = np.diff(E)
    if force is None or mcva:
        return np.abs(dE)
    n = tr.q.shape[1]
    A = np.empty((n, n))

    def power(q, p, t):
        mod.sys_M(np.ascontiguousarray(q, float), prm, A)
        v = np.linalg.solve(A, p)
        return float(force(q, v, t) @ v)

    P = np.array([power(q, p, t) for q, p, t in zip(tr.q, tr.p, tr.t)])
    W = 0.5 * tr.h * (P[:-1] + P[1:])
    t0 = float(tr.t[0])
    steps = np.minimum(np.floor((np.asarray(tr.impacts) - t0) / tr.h).astype(int), len(dE) - 1)
    for k in np.unique(steps):
        idx = np.flatnonzero(steps == k)
        pts = [(tr.t[k], tr.q[k], tr.p[k], None)]
        for i in idx:
            pts.append((tr.impacts[i], tr.impact_q[i], tr.impact_p_minus[i], tr.impact_p_plus[i]))
        pts.append((tr.t[k + 1], tr.q[k + 1], tr.p[k + 1], None))
        w = 0.0
        for (ta, qa, pa_m, pa_p), (tb, qb, pb, _) in zip(pts[:-1], pts[1:]):
            pa = pa_p if pa_p is not None else pa_m      # leave an impact with its post-impact momentum
            w += 0.5 * (tb - ta) * (power(qa, pa, ta) + power(qb, pb, tb))
        W[k] = w
    return np.abs(dE - W)


def _thin(tr, k=400):
    """(t, q) of a run at about k grid points (for sampling M along it)."""
    stride = max(1, len(tr.t) // k)
    return tr.t[::stride], tr.q[::stride]


def _smooth_error(tr, h, T, N0, nested, t_smooth, qs_ref):
    """max |q_k - q_exact(t_k)| over the coarsest grid (nested ladders: the test suite's measure) or
    over the run's own grid."""
    if nested:
        stride = int(round(T / h)) // N0
        return float(np.max(np.abs(tr.q[::stride] - qs_ref)))
    idx = np.clip(np.searchsorted(t_smooth, tr.t - 1e-12 * T), 0, len(t_smooth) - 1)
    return float(np.max(np.abs(tr.q - qs_ref[idx])))


def _symplecticity_rows(mod, prm, probes, hs, mcva, n):
    rows = []
    h_list = [hs[0], hs[len(hs) // 2]]
    for k, s in enumerate(probes):
        label = "start" if k == 0 else f"t = {s.t:.4g}"
        y = np.concatenate([s.q, s.p])
        for x in h_list:
            def full(yy, x=x, t=s.t):
                return np.concatenate(step(mod, yy[:n], yy[n:], x, t, prm, newton_tol=NEWTON_TOL))
            try:
                rows.append({"map": "full Phi_h", "h": x, "state": label, "defect": symplecticity_defect(map_jacobian(full, y))})
            except StepFailed:
                rows.append({"map": "full Phi_h", "h": x, "state": label, "defect": float("inf")})
            if mcva and hasattr(mod, "gauss_partial"):
                def part(yy, x=x, t=s.t):
                    q1, p1, v = np.empty(n), np.empty(n), np.empty(n)
                    it, _ = mod.gauss_partial(np.ascontiguousarray(yy[:n]), np.ascontiguousarray(yy[n:]), 0.5 * x, x, t,
                                              prm, NEWTON_TOL, 50, q1, p1, v)
                    if it < 0:
                        raise StepFailed("gauss_partial did not converge")
                    return np.concatenate([q1, p1])
                try:
                    d = symplecticity_defect(map_jacobian(part, y))
                except StepFailed:
                    d = float("inf")
                rows.append({"map": "partial flow of H~ (tau = h/2)", "h": x, "state": label, "defect": d})
    return rows
