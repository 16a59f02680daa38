"""`vcirun.ensemble`: many runs of one (system, method, h, T, options), from k initial conditions or
parameter sets, on every core, as one labelled xarray Dataset over the dimension `run`.

Each run is exactly `vcirun.simulate`'s run of the same arguments: the same plan (vcirun.run.plan:
validation and resolution once), the same initial-state rules and compiled Legendre transform,
the same loop with the same buffer sizes, so its final state, status and counters are bit for bit
those of simulate. What differs is around the loop:

- Threads. The compiled loop releases the GIL; `workers` threads (default: every core) take
  chunks of runs. A shared-build module's scene table is installed once and its lock held for the
  ensemble (vcirun.codegen.shared.exclusive), so the runs of one scene are not serialised by it.
- Memory. Each thread reuses one set of loop buffers; a run is reduced to its final state,
  status and counters as soon as it ends, so the result is O(k n) whatever N is, plus
  O(workers N n) of buffers. Full trajectories (outputs="trajectory") are O(k N n) and are
  checked against the memory limit first; `iter_ensemble` yields one Dataset per batch of runs
  instead, for any k at the memory of one batch.
- Failures. A run that fails numerically keeps its status (and the state where it stopped); a
  run whose start or parameters are refused (simulate raises ValueError for them) gets the
  status `invalid_input` and its message in the Dataset's attrs; the other runs go on.
"""
from __future__ import annotations

import dataclasses
import math
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..core import record
from ..core.bounds import check_one_start, check_start_args, nonfinite_start
from ..core.limits import check_count
from ..core.progress import Progress, check_report
from ..core.sizes import check_run_memory, format_bytes, memory_limit
from ..core.system_data import start_beta
from ..core.values import check_number, describe
from .plan import (
    Buffers,
    first_call,
    plan,
    ready_start,
    run_loop,
    start_state,
)

INVALID = "invalid_input"
STATUS_NAMES = tuple(name for name, _ in record.STATUSES) + (INVALID,)
OUTPUTS = ("final", "trajectory")
_O_Q, _O_P, _O_H, _O_ED, _O_HMOD = (record.FIELDS.index(record.FIELD[k]) for k in ("q", "p", "H", "Ed", "Hmod"))
MAX_MESSAGES = 100


def _runs_of(name: str, value, inner: int) -> int | None:
    """How many runs `value` gives (its leading length when it has one more axis than one run's
    value, `inner` being one run's number of axes), None for one value shared by every run."""
    try:
        a = np.asarray(value)
    except (TypeError, ValueError):   # ragged lists
        raise ValueError(f"{name}: must be numbers, one value or one row per run (got {describe(value)})") from None
    if a.dtype == object:
        raise ValueError(f"{name}: must be numbers (got {describe(value)})")
    if a.ndim == inner:
        return None
    if a.ndim == inner + 1:
        return a.shape[0]
    raise ValueError(f"{name}: must have {inner} axes for one value shared by every run, or {inner + 1} "
                     f"(runs first); got shape {a.shape}")


def _inputs(beta, q0, p0, params) -> tuple[int, dict]:
    """k and the per-run inputs: beta (k,) or None, q0/p0 (k, n) or None, params {name: (k,)}."""
    check_one_start(beta, q0, p0)
    if (q0 is None) != (p0 is None):
        raise ValueError("initial state: give both q0 and p0 (or beta)")
    if isinstance(params, (list, tuple)):
        if not params or not all(isinstance(d, dict) for d in params):
            raise ValueError("params: a sequence of parameter sets must hold mappings of names to numbers")
        names = list(dict.fromkeys(k for d in params for k in d))
        missing = [(i, k) for i, d in enumerate(params) for k in names if k not in d]
        if missing:
            raise ValueError(f"params[{missing[0][0]}]: lacks {missing[0][1]!r}, which other parameter sets give")
        params = {k: [d[k] for d in params] for k in names}
    elif params is not None and not isinstance(params, dict):
        raise ValueError(f"params: must be a mapping of names to numbers or arrays (got {describe(params)})")
    sizes = {}
    if beta is not None:
        sizes["beta"] = _runs_of("beta", beta, 0)
    if q0 is not None:
        sizes["q0"], sizes["p0"] = _runs_of("q0", q0, 1), _runs_of("p0", p0, 1)
    for k, v in (params or {}).items():
        sizes[f"params.{k}"] = _runs_of(f"params.{k}", v, 0)
    lengths = {k: s for k, s in sizes.items() if s is not None}
    k = next(iter(lengths.values()), 1)
    for name, s in lengths.items():
        if s != k:
            first = next(iter(lengths))
            raise ValueError(f"{name}: has {s} runs, {first} has {k}; give every per-run input the same length")
    if k < 1:
        raise ValueError(f"{next(iter(lengths))}: no runs (an empty array)")
    per = {"beta": None if beta is None else np.broadcast_to(_floats("beta", beta), (k,)),
           "q0": None if q0 is None else _rows("q0", q0, k), "p0": None if p0 is None else _rows("p0", p0, k),
           "params": None if params is None else {n: np.broadcast_to(_floats(f"params.{n}", v), (k,))
                                                  for n, v in params.items()}}
    return k, per


def _floats(name: str, v) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: must be numbers (got {describe(v)})") from None
    if np.asarray(v).dtype.kind == "b":
        raise ValueError(f"{name}: must be numbers, not booleans (got {describe(v)})")
    return a


def _rows(name: str, v, k):
    a = _floats(name, v)
    return np.broadcast_to(a, (k,) + a.shape[-1:]) if a.ndim == 1 else a


class _Context:
    """One ensemble's plan, module, per-run inputs and requested outputs."""

    def __init__(self, p, per, k, outputs):
        self.plan, self.per, self.k, self.outputs = p, per, k, outputs
        self.shared_prm = p.sysd.param_values(None) if per["params"] is None else None
        self.local = threading.local()

    def run_args(self, i: int):
        per = self.per
        beta = None if per["beta"] is None else float(per["beta"][i])
        q0 = None if per["q0"] is None else per["q0"][i]
        p0 = None if per["p0"] is None else per["p0"][i]
        params = None if per["params"] is None else {n: float(v[i]) for n, v in per["params"].items()}
        return beta, q0, p0, params


def _allocate(ctx: _Context, k: int) -> dict:
    n, N = ctx.plan.sysd.n, ctx.plan.N
    res = {"q_final": np.full((k, n), np.nan), "p_final": np.full((k, n), np.nan),
           "status": np.full(k, INVALID, dtype=f"<U{max(map(len, STATUS_NAMES))}"),
           "fail_step": np.full(k, -1, dtype=np.int64), "n_steps": np.zeros(k, dtype=np.int64),
           "n_impacts": np.zeros(k, dtype=np.int64), "H0": np.full(k, np.nan), "energy_error": np.full(k, np.nan),
           "messages": {}}
    if ctx.outputs == "trajectory":
        res |= {"q": np.full((k, N + 1, n), np.nan), "p": np.full((k, N + 1, n), np.nan),
                "H": np.full((k, N + 1), np.nan)}
    return res


def _one(ctx: _Context, mod, i: int, j: int, res: dict) -> None:
    """Run i of the ensemble into row j of `res` (in a worker thread)."""
    p = ctx.plan
    beta, q0, p0, params = ctx.run_args(i)
    try:
        check_start_args(beta, q0, p0, params)
        prm = ctx.shared_prm if params is None else p.sysd.param_values(params)
        start = start_state(p.sysd, start_beta(p.sysd, beta, q0, p0), q0, p0, prm, p.sysm)
        q0, p0 = ready_start(p, mod, start, prm)
    except ValueError as e:
        if len(res["messages"]) < MAX_MESSAGES:
            res["messages"][i] = str(e)
        return
    buffers = getattr(ctx.local, "buffers", None)
    if buffers is None:
        buffers = ctx.local.buffers = Buffers(keep_grid=True)
    out, c, wall = run_loop(mod, q0, p0, p.t0, p.h, p.N, prm, p.settings, p.sysd.n, p.max_impacts_step, buffers)
    p.ran(wall)
    steps, status, fail = c["steps"], record.STATUS_CODES[c["status"]], c["fail_step"]
    H = out[_O_H][: steps + 1]
    H0 = float(H[0])
    bad = nonfinite_start(H0, out[_O_ED][0] if p.energies else None,
                                     out[_O_HMOD][0] if p.energies and p.meth.has_modified_energy else None, q0, p0)
    if bad and status == "ok":
        status, fail = "nonfinite", 0
    res["q_final"][j] = out[_O_Q][steps]
    res["p_final"][j] = out[_O_P][steps]
    res["status"][j] = status
    res["fail_step"][j] = fail
    res["n_steps"][j] = steps
    res["n_impacts"][j] = c["n_impacts"]
    res["H0"][j] = H0
    if p.energies and math.isfinite(H0):
        res["energy_error"][j] = float(np.nanmax(np.abs(H - H0)))   # max |H - H(0)| over the run
    if "q" in res:
        res["q"][j, : steps + 1] = out[_O_Q][: steps + 1]
        res["p"][j, : steps + 1] = out[_O_P][: steps + 1]
        res["H"][j, : steps + 1] = H


def _compute(ctx: _Context, lo: int, hi: int, workers: int, progress: Progress | None = None) -> dict:
    """Runs lo..hi-1 on `workers` threads, as result arrays of hi - lo rows; `progress` counts the runs
    done (chunks of at most 256 runs, so a long ensemble reports within seconds)."""
    from ..codegen.shared import exclusive

    res = _allocate(ctx, hi - lo)
    mod = ctx.plan.module()
    size = max(1, min(256, math.ceil((hi - lo) / (8 * workers))))
    chunks = (range(a, min(hi, a + size)) for a in range(lo, hi, size))
    with exclusive(mod) as fast:
        def work(chunk):
            for i in chunk:
                _one(ctx, fast, i, i - lo, res)
            if progress is not None:
                progress.update(len(chunk))

        if workers == 1 or hi - lo <= size:
            for ch in chunks:
                work(ch)
        else:
            with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="vcirun-ensemble") as ex:
                for _ in ex.map(work, chunks):
                    pass
    return res


def _dataset(ctx: _Context, res: dict, lo: int, wall: float):
    import xarray as xr

    from ..scenes.registry import coordinate_names

    p = ctx.plan
    k = res["status"].shape[0]
    names = coordinate_names(p.sysd.name, p.sysd.n, getattr(p.sysd, "coordinates", None))
    rc, rs = ("run", "coordinate"), ("run",)
    data = {"q_final": (rc, res["q_final"], {"long_name": "q at the last grid state reached"}),
            "p_final": (rc, res["p_final"], {"long_name": "p at the last grid state reached"}),
            "status": (rs, res["status"], {"values": ", ".join(STATUS_NAMES)}),
            "fail_step": (rs, res["fail_step"], {"long_name": "step where the run stopped (-1: reached T)"}),
            "n_steps": (rs, res["n_steps"], {"long_name": "grid steps taken"}),
            "n_impacts": (rs, res["n_impacts"], {"long_name": "impacts"}),
            "H0": (rs, res["H0"], {"long_name": "H(q0, p0)"}),
            "energy_error": (rs, res["energy_error"], {"long_name": "max |H - H(0)| over the run"})}
    coords = {"run": np.arange(lo, lo + k), "coordinate": names}
    if "q" in res:
        coords["t"] = p.t0 + p.h * np.arange(p.N + 1)
        data |= {"q": (("run", "t", "coordinate"), res["q"]), "p": (("run", "t", "coordinate"), res["p"]),
                 "H": (("run", "t"), res["H"])}
    per = ctx.per
    if per["beta"] is not None:
        coords["beta"] = ("run", np.array(per["beta"][lo: lo + k]))
    for n, v in (per["params"] or {}).items():
        coords[n] = ("run", np.array(v[lo: lo + k]))
    if per["q0"] is not None:
        coords["q0"] = (rc, np.array(per["q0"][lo: lo + k]))
        coords["p0"] = (rc, np.array(per["p0"][lo: lo + k]))
    attrs = {"system": p.sysd.name, "method": p.meth.name, "h": p.h, "T": p.N * p.h, "t0": p.t0, "N": p.N,
             "constrained": int(p.constrained), "energies": int(p.energies), "wall_time": wall,
             "tier": str(p.tier_used), "build": str(p.build_used or ""),
             "messages": [f"run {i}: {m}" for i, m in sorted(res["messages"].items())]}
    return xr.Dataset(data, coords=coords, attrs=attrs)


def results_bytes(k: int, n: int, N: int, outputs: str) -> int:
    """Bytes of the result arrays of k runs (`_allocate`; "trajectory" adds q, p and H per grid point)
    with the per-run inputs kept beside them."""
    per_run = 8 * (2 * n) + 4 * max(map(len, STATUS_NAMES)) + 8 * 5 + 8 * (2 * n + 1)
    if outputs == "trajectory":
        per_run += 8 * (N + 1) * (2 * n + 1)
    return int(k) * per_run


def check_results_memory(k: int, n: int, N: int, outputs: str) -> None:
    """Refuse k runs whose result arrays would exceed the memory limit (vcirun.core.sizes), before any
    is allocated."""
    need, lim = results_bytes(k, n, N, outputs), memory_limit()
    if need > lim:
        fix = ("use outputs='final', or vcirun.run.ensemble.iter_ensemble for one batch of runs at a time"
               if outputs == "trajectory" else "use vcirun.run.ensemble.iter_ensemble for one batch of runs at a time")
        raise ValueError(f"{'outputs' if outputs == 'trajectory' else 'runs'}: the results of {k:,} runs need about "
                         f"{format_bytes(need)} (limit {format_bytes(lim)}); {fix}")


def _prepare(system, method, h, T, beta, q0, p0, params, outputs, constrained, t0, energies, resting_contact,
             workers, options, tier=None, batch=None):
    if outputs not in OUTPUTS:
        raise ValueError(f"outputs: must be one of {', '.join(OUTPUTS)} (got {describe(outputs)})")
    k, per = _inputs(beta, q0, p0, params)
    p = plan(system, method, h=h, T=T, t0=t0, constrained=constrained, energies=energies,
             resting_contact=resting_contact, options=options, tier=tier)
    n = p.sysd.n
    for name in ("q0", "p0"):
        if per[name] is not None and per[name].shape != (k, n):
            raise ValueError(f"{name}: must have shape ({k}, {n}) or ({n},) (got {per[name].shape})")
    if per["params"]:
        p.sysd.param_values({name: 0.0 for name in per["params"]})   # unknown names: one error for the batch
    if workers is None:
        try:
            workers = len(os.sched_getaffinity(0))
        except (AttributeError, OSError):
            workers = os.cpu_count() or 1
    workers = int(check_number("workers", workers, ge=1, le=1024, integer=True))
    check_run_memory(p.N, n, copies=workers, field="h")
    check_results_memory(k if batch is None else min(k, batch), n, p.N, outputs)
    p.module()
    if p.tier_used in ("compiled", "interpreted"):   # one tier and build for the whole ensemble (a copy: p may be kept)
        p = dataclasses.replace(p, tier=p.tier_used, hold=True)
    ctx = _Context(p, per, k, outputs)
    mod = p.module()
    for i in range(k):   # numba's first call of the loop, untimed, from the first start it accepts
        b, q, pp, prm_over = ctx.run_args(i)
        try:
            check_start_args(b, q, pp, prm_over)
            prm = p.sysd.param_values(prm_over)
            q, pp = ready_start(p, mod, start_state(p.sysd, start_beta(p.sysd, b, q, pp), q, pp, prm, p.sysm), prm)
        except ValueError:
            continue
        first_call(mod, p, q, pp, prm)
        break
    return ctx, workers


def ensemble(system, method, *, h, T, beta=None, q0=None, p0=None, params=None, outputs="final",
             constrained=None, t0=0.0, energies=True, resting_contact=True, workers=None, tier=None, progress=None,
             **options):
    """Run k initial conditions or parameter sets of `system` with `method` on the grid of h and T;
    an xarray Dataset over `run` (and `coordinate`).

    beta: an array of k values of the scene's initial-condition map; or q0 and p0 of shape (k, n);
    params: {name: scalar or array of k values} or a sequence of k mappings. A value without the run
    axis is shared by every run (e.g. one beta with k parameter sets). The other arguments are
    simulate's, for every run. outputs: "final" (q_final, p_final over (run, coordinate), status,
    fail_step, n_steps, n_impacts, H0, energy_error = max |H - H(0)|) or "trajectory" (also q, p
    over (run, t, coordinate) and H over (run, t), NaN after a run's last state). workers: threads
    (default: every core). tier: simulate's, one for the whole ensemble (attrs["tier"] says which).
    progress: None (a line on stderr every 10 s with the runs done and an
    estimate of the time left, once the ensemble is estimated to take over 10 s), False (silent) or
    a callable f(done, total, elapsed seconds, remaining seconds or None) called as runs finish.
    At most 1e12 member steps (runs x T / h) per call (vcirun.core.limits), and the result arrays
    within the memory limit (vcirun.core.sizes), both checked before any run starts.

    Each run equals `vcirun.simulate` with the same arguments, bit for bit; a failed run is its
    status, a refused start `invalid_input` (message in attrs["messages"]). Bad arguments of the
    whole ensemble (shapes, lengths, names, h, T, tolerances) raise ValueError naming the field.
    """
    report = check_report(progress)
    ctx, workers = _prepare(system, method, h, T, beta, q0, p0, params, outputs, constrained, t0, energies,
                            resting_contact, workers, options, tier)
    check_count("ensemble_steps", "runs", ctx.k * ctx.plan.N,
                fix="split the ensemble (vcirun.run.ensemble.iter_ensemble runs it in batches), raise h or lower T")
    t = time.perf_counter()
    res = _compute(ctx, 0, ctx.k, workers, Progress(ctx.k, f"ensemble of {ctx.k:,} runs", report))
    return _dataset(ctx, res, 0, time.perf_counter() - t)


def iter_ensemble(system, method, *, h, T, batch=4096, beta=None, q0=None, p0=None, params=None,
                  outputs="final", constrained=None, t0=0.0, energies=True, resting_contact=True, workers=None,
                  tier=None, progress=None, **options):
    """`ensemble` one batch of runs at a time: yields a Dataset per `batch` runs (its `run` coordinate
    the runs' indices), so that any k, with full trajectories too, needs the memory of one batch.
    The module's lock is held while a batch computes, not between batches. The caps hold per batch;
    `progress` counts the runs of every batch (see `ensemble`)."""
    batch = int(check_number("batch", batch, ge=1, integer=True))
    report = check_report(progress)
    ctx, workers = _prepare(system, method, h, T, beta, q0, p0, params, outputs, constrained, t0, energies,
                            resting_contact, workers, options, tier, batch=batch)
    check_count("ensemble_steps", "batch", min(batch, ctx.k) * ctx.plan.N,
                fix="use a smaller batch, raise h or lower T")
    prog = Progress(ctx.k, f"ensemble of {ctx.k:,} runs", report)
    for lo in range(0, ctx.k, batch):
        t = time.perf_counter()
        hi = min(ctx.k, lo + batch)
        res = _compute(ctx, lo, hi, workers, prog)
        yield _dataset(ctx, res, lo, time.perf_counter() - t)
