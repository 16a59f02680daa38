"""What `vcirun verify` compares on systems with Coulomb friction: the mode changes of the exact
reference and of a run as one sequence of located events (time, contact, kind), and whether the exact
motion comes to rest.

The kinds are the trajectory's (`mode_change_kind`, vcirun.core.record): 1 slip -> stick, 2 stick
-> slip, 3 slip reversed (the slip stopped and the stick test failed). The reference records each
transition as (t, contact, the contact's new mode: +1 / -1 sliding, 0 stuck; vcirun.reference_solution
.coulomb) with the mode it left in its held intervals; the kind follows from the pair.
"""
from __future__ import annotations

import numpy as np

from .checks import MODE_KIND

STICK = 0          # vcirun.reference_solution.coulomb.STICK
REST_TOL = 1e-12   # |qdot| below this (relative to the largest speed of the motion): at rest
START_TOL = 1e-12  # a run's mode change this close to t = 0 (relative to T) is its start's choice of mode


def _mode_before(ref, t, i):
    """The mode of held contact i on the held interval of the reference that ends at t."""
    best = None
    for t0, t1, A, S in ref.mode_intervals:
        if i in A and t0 < t and abs(t1 - t) <= 1e-12 * max(1.0, abs(t)):
            best = S[list(A).index(i)]
    return best


def reference_mode_changes(ref, T):
    """[(t, contact, kind)] of the reference's friction mode changes on [0, T], in time order."""
    out = []
    for t, i, new in sorted(ref.transitions):
        if t > T:
            break
        if new == STICK:
            kind = 1
        else:
            before = _mode_before(ref, t, i)
            kind = 2 if before == STICK else 3
        out.append((float(t), int(i), kind))
    return out


def run_mode_changes(tr, T, ref_modes=()):
    """([(t, contact, kind)] of a run's recorded mode changes on [0, T], [those left out]). Left out:
    changes within START_TOL of t = 0 where the reference has none there. A contact that starts held
    at rest and slides takes its slip direction in the run from the sign of its slip velocity at the
    start, which can be round-off (4e-15 on the compass gait's stance foot); the run then records a
    reversal at t ~ 1e-16, where the reference starts in the mode the held problem gives. That is the
    start's choice of mode, not a transition of the motion."""
    t = np.asarray(tr.mode_changes, float)
    c = np.asarray(tr.mode_change_contact, np.int64)
    k = np.asarray(tr.mode_change_kind, np.int64)
    tol = START_TOL * max(1.0, float(T))
    ref_at_start = any(e[0] <= tol for e in ref_modes)
    out, left = [], []
    for a, b, d in zip(t, c, k):
        if a > T:
            continue
        (left if a <= tol and not ref_at_start else out).append((float(a), int(b), int(d)))
    return out, left


def _event(e, names):
    t, i, kind = e
    who = names[i] if names is not None and i < len(names) else f"contact {i}"
    return f"{who} {MODE_KIND.get(kind, f'kind {kind}')} at t = {t:.6g}"


def compare(run, ref, names=None):
    """(max |t - t_ref| over the pairs, the first difference as text or "") of two mode-change
    sequences: the same count, and in order the same contact and kind."""
    for k, (a, b) in enumerate(zip(run, ref)):
        if a[1:] != b[1:]:
            return float("nan"), f"mode change {k + 1}: the run's {_event(a, names)}, the reference's {_event(b, names)}"
    if len(run) != len(ref):
        extra = run[len(ref)] if len(run) > len(ref) else None
        miss = ref[len(run)] if len(ref) > len(run) else None
        what = f"an extra {_event(extra, names)}" if extra else f"no {_event(miss, names)}"
        return float("nan"), f"{len(run)} mode changes, reference {len(ref)} ({what})"
    if not run:
        return 0.0, ""
    return float(max(abs(a[0] - b[0]) for a, b in zip(run, ref))), ""


def rest_time(ref, mod, prm, n, T):
    """The time from which the exact motion is at rest with every held contact stuck to T (its last
    held interval: every contact stuck, the velocity zero at its start and at T), or None."""
    if not ref.mode_intervals:
        return None
    t0, t1, A, S = ref.mode_intervals[-1]
    if t1 < T * (1 - 1e-12) or not A or any(s != STICK for s in S):
        return None
    tt = np.linspace(0.0, T, 401)
    Y = ref.state(np.append(tt, [t0, T]))
    V = np.empty((len(Y), n))
    A_ = np.empty((n, n))
    for k, y in enumerate(Y):
        mod.sys_M(np.ascontiguousarray(y[:n]), prm, A_)
        V[k] = np.linalg.solve(A_, y[n:])
    vmax = max(float(np.max(np.abs(V))), 1e-300)
    if float(np.max(np.abs(V[-2:]))) <= REST_TOL * vmax:
        return float(t0)
    return None
