"""The extremes study (`study: extremes`): every section of the config for every method.

Each section is one family of hard cases (`step_size`, `contact`, `parameters`, `hygiene`), run
through the public API; the result is plain data (dicts of floats and strings, JSON-ready) that
`report.render_extremes` turns into docs/extremes.md and that tests/extremes asserts on. Nothing
here changes how a run is computed.
"""
from __future__ import annotations

import time

import numpy as np

from . import contact, hygiene, parameters, step_size
from .schema import ExtremesStudy

__all__ = ["run_extremes"]


def _cases(cfg: ExtremesStudy, methods: list[str]) -> dict:
    """section name -> function of its (validated) config body that runs it for every method."""
    return {
        "step_limit": lambda c: [
            step_size.step_limit(sc.system, m, T=sc.T, beta=sc.beta, h_min=c.h_min, h_max=c.h_max,
                                 per_decade=c.per_decade, rel=c.rel)
            for sc in c.scenes for m in methods],
        "long_horizon": lambda c: [
            step_size.long_run(c.system, m, h=c.h, steps=c.steps, beta=c.beta) for m in methods],
        "grazing": lambda c: [
            contact.grazing_case(sc.system, m, d, h=c.h, beta=sc.beta, after=c.after)
            for sc in c.scenes for m in methods for d in c.depths],
        "boundary": lambda c: [
            contact.boundary_case(sc.system, m, h=c.h, k=sc.k, T=sc.T, beta=sc.beta)
            for sc in c.scenes for m in methods],
        "dense": lambda c: [
            contact.dense_case(sc.system, m, h=sc.h, T=sc.T, beta=sc.beta,
                               q0=np.array(sc.q0) if sc.q0 is not None else None,
                               p0=np.array(sc.p0) if sc.p0 is not None else None, params=sc.params)
            for sc in c.scenes for m in methods],
        "surface": lambda c: [
            contact.surface_case(sc.system, m, kind, h=c.h, T=c.T)
            for sc in c.scenes for kind in sc.kinds for m in methods],
        "accumulation": lambda c: [
            contact.accumulation_case(m, h=h, T=c.T, y0=c.y0, c=c.c) for m in methods for h in c.h],
        "energy": lambda c: [parameters.energy_case(m, b, hs=c.h, T=c.T) for b in c.betas for m in methods],
        "mass_ratio": lambda c: [parameters.mass_ratio_case(m, r, hs=c.h, T=c.T) for r in c.ratios
                                 for m in methods],
        "singular_mass": lambda c: [parameters.singular_mass_case(m, m1, hs=c.h, T=c.T) for m1 in c.m1
                                    for m in methods]
        + [parameters.singular_mass_case(m, 0.0, hs=c.h, T=c.T, q0=np.array(c.nonaligned_q0), p0=np.zeros(2))
           for m in methods],
        "hygiene": lambda c: hygiene.hygiene_case([
            {"system": sc.system, "method": m, "h": sc.h, "T": sc.T, "kw": sc.kw.model_dump(exclude_none=True),
             "reference": sc.reference} for sc in c.scenes for m in methods]),
    }


def run_extremes(cfg: ExtremesStudy, *, log=print, only=None) -> dict:
    """Run every section of the study present in the config (or those named in `only`); returns the
    results dict (JSON-ready): name, methods, started, one list (hygiene: a dict) per section, wall_time."""
    methods = list(cfg.methods)
    res = {"name": cfg.name, "methods": methods, "started": time.strftime("%Y-%m-%d %H:%M:%S")}
    t_all = time.perf_counter()
    cases = _cases(cfg, methods)
    for name in cfg.sections():
        if only is not None and name not in only:
            continue
        t0 = time.perf_counter()
        res[name] = cases[name](getattr(cfg, name))
        log(f"[{name}] {time.perf_counter() - t0:.1f} s")
    res["wall_time"] = time.perf_counter() - t_all
    return res
