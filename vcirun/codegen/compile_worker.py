"""The background compile process (vcirun.codegen.background starts it and says what it does):
`python -m vcirun.codegen.compile_worker JOB` builds the compiled tier of one module into the cache."""
from __future__ import annotations

import contextlib
import os
import sys
import time
import traceback

from . import background, cache_lock, cache_store


def run(job: background.Job) -> int:
    """0 when the compiled tier is there (built now or by another process), 1 when the compile failed
    (recorded in bg_<key>.failed for the callers, who stay interpreted)."""
    d = cache_store.kernels_dir()
    with cache_lock.try_held(background.lock_path(d, job.key), f"the compiled tier of {job.label}") as mine, \
            contextlib.ExitStack() as held:
        if not mine or background.marker(d, job.key) is not None:
            return 0
        held.enter_context(background.slot(d))
        try:
            from .kernel_cache import KernelCache   # (numba: imported once a compile slot is ours)

            kc = KernelCache(background=True)
            mod = kc.compiled(job.key, job.system, job.ks)
            kc.finish(mod, job.key, job.system, job.ks, job.nprm)   # numba's first calls, then the marker
        except BaseException as e:   # noqa: BLE001 - recorded for the callers, who stay interpreted
            reason = " ".join(f"{type(e).__name__}: {e}".split())[:500]
            traceback.print_exc()
            sys.stderr.flush()
            try:
                cache_store.write_atomic(background.failure_path(d, job.key), cache_store.seal_json(
                    {"key": job.key, "system": job.label, "reason": reason, "time": time.time(),
                     "log": str(background.log_path(d, job.key))}))
            except cache_store.CacheError:
                pass
            return 1
    return 0


def _nice_session(nice: int) -> None:
    """The worker runs in a session of its own, and where Linux groups the scheduling by session
    (autogroup, /proc/sys/kernel/sched_autogroup_enabled) a process's nice value only ranks it within
    its session: the sessions share the cores equally, and a niced compile took half of a two-core
    machine from the sweep's interpreted runs. The session's own nice value ranks it among sessions;
    it is set only when the session is the worker's own (background.start makes one), never a
    caller's."""
    if os.getsid(0) != os.getpid():
        return
    try:
        with open("/proc/self/autogroup", "w") as f:
            f.write(str(nice))
    except OSError:   # (no autogroup: the process's nice value is the whole story)
        pass


def main(argv: list[str]) -> int:
    import logging

    try:
        os.nice(background.NICE)
    except OSError:
        pass
    _nice_session(background.NICE)
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    return run(background.Job.decode(argv[0]))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
