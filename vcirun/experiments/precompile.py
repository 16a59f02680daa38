"""Cold kernels of a sweep compiled side by side, one process per core, before its first run.

numba compiles with the GIL held and one thread, so a sweep of CVA, VCI and the MCVA family on an
empty cache used to compile their three shared cores one after the other (about 35-50 s each). Here
every method whose kernels are not cached is grouped by what it must compile -- methods that share a
shared core (MCVAA and MCVAC) in one group, as the second of them then costs only its scene kernels
-- and the groups run in worker processes, at most one per core. Each worker compiles by a one-step
`vcirun.simulate` and leaves the machine code in the kernel cache; the parent's preflight then loads
it. Compilation of one module is locked across processes (vcirun.codegen.cache.first_call_lock), so
another process that starts on the same kernels waits instead of compiling them twice.

A worker that fails only costs the parallelism: the preflight that follows compiles what is still
missing in the parent and reports any error there, with its field.
"""
from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor

__all__ = ["compile_groups", "compile_side_by_side"]


def compile_groups(sysm, methods: list[tuple[str, dict, dict]]) -> list[list[tuple]]:
    """The cold entries of `methods` ([(method name, method options, simulate keywords)]) on symbolic
    system `sysm`, each with its kernel set, grouped by the shared core they compile (or by their module
    when the core is cached), in first-seen order."""
    from vcirun.codegen.build import module_key
    from vcirun.codegen.cache import cold_parts, core_key_for
    from vcirun.methods.table import resolve_method

    groups: dict[str, list] = {}
    for name, mopts, kw in methods:
        try:
            ks = resolve_method(name, **mopts).kernel_set()
            parts = cold_parts(sysm, ks)
        except (ValueError, TypeError, KeyError):   # the preflight reports it with its field
            continue
        if parts:
            key = "core " + core_key_for(sysm, ks) if "core" in parts else "module " + module_key(sysm, ks)
            groups.setdefault(key, []).append((name, kw, ks))
    return list(groups.values())


def _compile(system, group: list[tuple[str, dict]], reference: dict | None) -> None:
    import logging

    import vcirun

    logging.getLogger("vcirun").setLevel(logging.ERROR)   # the parent said what is compiled, once
    for name, kw in group:
        vcirun.simulate(system, name, **kw)
    if reference is not None:
        vcirun.reference(system, **reference)


def compile_side_by_side(system, sysm, methods: list[tuple[str, dict, dict]], cores: int,
                         reference: dict | None = None) -> int:
    """Compile the cold kernels of `methods` (as for compile_groups), and of the exact reference
    (`reference`: its keywords, or None) when its system kernels are cold, in up to `cores` worker
    processes, longest build first, each announced once (vcirun.codegen.cache.announce_if_cold);
    returns the number of kernel sets compiled there (0: fewer than two builds or one core, nothing
    done here)."""
    from vcirun.codegen.build import system_core_features
    from vcirun.codegen.cache import announce_if_cold, cold_parts, core_key_for, estimate_compile_s, tell
    from vcirun.codegen.kernel_set import SYSTEM_KERNELS

    # (a group shares one core: counted with its first kernel set only)
    jobs = [(sum(estimate_compile_s(ks, sysm.n, system_core_features(ks, sysm), with_core=(i == 0))
                 for i, (*_, ks) in enumerate(g)),
             [(n, kw) for n, kw, _ in g], None, [ks for *_, ks in g]) for g in compile_groups(sysm, methods)]
    if reference is not None and cold_parts(sysm, SYSTEM_KERNELS):
        jobs.append((estimate_compile_s(SYSTEM_KERNELS, sysm.n), [], reference, [SYSTEM_KERNELS]))
    workers = min(len(jobs), cores)
    if workers < 2:
        return 0
    jobs.sort(key=lambda j: -j[0])   # longest first: the pool hands the next one to the first free process
    covered, said = set(), 0
    for *_, kss in jobs:
        for ks in kss:
            said += announce_if_cold(sysm, ks, covered)
            covered.add(core_key_for(sysm, ks))
    if said:   # (names what was just said: a count of lines, not of process jobs)
        tell(f"(the {'compile' if said == 1 else f'{said} compiles'} above run{'s' * (said == 1)} in {workers} "
             f"processes side by side, one per core)")
    # spawn: a fresh interpreter per worker (numba's compiler state is not forked)
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = [pool.submit(_compile, system, g, ref) for _, g, ref, _ in jobs]
        for f in futures:
            try:
                f.result()
            except Exception:   # noqa: BLE001 - the parent's preflight compiles and reports it
                pass
    return sum(len(kss) for *_, kss in jobs)
