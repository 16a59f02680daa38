"""The compiled tier built beside the interpreted one: one background process per machine and module.

When a call in the `auto` tier (vcirun.codegen.tiers) needs a module whose compiled code is not in the
cache, it runs on the interpreted tier at once and `start`s this module as a separate process
(`python -m vcirun.codegen.compile_worker JOB`) that builds the compiled tier into the cache:

1. it takes the lock `kernels/bg_<key>.lock` without waiting (vcirun.codegen.cache_lock: the holder is
   named in the file and kept alive by a heartbeat); a process that finds it held leaves at once, so
   one process per machine compiles a module, however many callers asked;
2. it waits for a free background-compile slot (one per core; it runs at nice NICE: see below), then
   makes the module's text from the generated kernels the caller wrote (`vg_<key>.py`, sealed:
   no sympy here), with the C kernels compiled (vcirun.codegen.c_link), and writes `vk_<key>.py`;
3. it loads it as any process does (vcirun.codegen.kernel_cache: every file checked, numba's code
   sealed) and calls the module's entry points once, so that numba compiles and caches them;
4. it writes the marker `vk_<key>.ready` (sealed JSON: key, system, kernel set, seconds): the compiled
   tier is there. Callers of this and other processes look for the marker on each call and switch.

A compile that fails writes `bg_<key>.failed` (sealed JSON with the reason and the log's last
lines; the log is `bg_<key>.log`): callers say it once and stay interpreted. Every file is written
atomically and checked on load, so a kill of the caller or of this process at any moment leaves the
cache usable; the lock dies with its holder, and the next call that needs the module starts the
compile again. The process runs in its own session (a Ctrl-C in the caller's terminal does not
reach it), with its standard streams on /dev/null and the log; the caller reaps it when it ends
(a thread waits on it), and when the caller ends first, init does.
"""
from __future__ import annotations

import base64
import contextlib
import os
import pickle
import subprocess
import sys
import threading
import time
from pathlib import Path

from . import cache_lock, cache_store   # (light: numba is imported once a compile slot is ours)

__all__ = ["start", "state", "marker", "failure", "in_progress", "Job"]

# How the cores are shared: the caller computes at its own priority, a background compile at nice
# NICE, its session too (Linux's autogroup ranks sessions by the session's nice value:
# compile_worker._nice_session; the scheduler then gives a busy caller ~10 times its CPU share) and at most one background
# compile per core at a time (the others wait for a slot: `slot`), so a sweep's interpreted runs are
# not slowed by the compiles it started, and the compiles use the cores as soon as the runs leave them
# idle. Measured in docs/performance.md (tiers).
NICE = 10


def marker_path(d: Path, key: str) -> Path:
    return d / f"vk_{key}.ready"


def lock_path(d: Path, key: str) -> Path:
    return d / f"bg_{key}.lock"


def failure_path(d: Path, key: str) -> Path:
    return d / f"bg_{key}.failed"


def log_path(d: Path, key: str) -> Path:
    return d / f"bg_{key}.log"


def _read_sealed(path: Path) -> dict | None:
    try:
        data = cache_store.read(path)
        return None if data is None else cache_store.unseal_json(data)
    except (cache_store.CacheError, ValueError):
        return None


def marker(d: Path, key: str) -> dict | None:
    """The marker of a compiled module (None: absent or not one of ours; advisory, so an unreadable
    marker only means the module is taken as not compiled)."""
    m = _read_sealed(marker_path(d, key))
    return m if m is not None and m.get("key") == key else None


def write_marker(d: Path, key: str, data: dict) -> None:
    """Mark module `key` compiled (best effort: a read-only cache keeps no marker)."""
    try:
        cache_store.write_atomic(marker_path(d, key), cache_store.seal_json({"key": key, **data}),
                                 what=marker_path(d, key).name)
    except cache_store.CacheError:
        pass


def failure(d: Path, key: str) -> dict | None:
    f = _read_sealed(failure_path(d, key))
    return f if f is not None and f.get("key") == key else None


def forget_failure(d: Path, key: str) -> None:
    """The compiled tier of `key` is there: its failure record and compile log go."""
    for p in (failure_path(d, key), log_path(d, key)):
        try:
            p.unlink()
        except OSError:
            pass


def in_progress(d: Path, key: str) -> dict | None:
    """The holder of the compile lock of `key` ({pid, host, what, since, ...}), or None when no process
    holds it."""
    return cache_lock.holder(lock_path(d, key))


def state(d: Path, key: str) -> str:
    """"compiled", "compiling", "failed" or "none"."""
    if marker(d, key) is not None:
        return "compiled"
    if in_progress(d, key) is not None:
        return "compiling"
    return "failed" if failure(d, key) is not None else "none"


class Job:
    """What the background process builds: the module key, its kernel set, the system's name, its
    number of parameters, the cache it writes (the caller's: VCIRUN_CACHE_DIR is passed on resolved)
    and the build (vcirun.codegen.modules.build_mode; None: the caller's environment decides)."""

    def __init__(self, key: str, ks, system: str, nprm: int, root: Path, family: str = "",
                 build: str | None = None):
        self.key, self.ks, self.system, self.nprm, self.root = key, ks, system, int(nprm), Path(root)
        self.family, self.build = family, build

    @property
    def label(self) -> str:
        return f"{self.system}/{self.family}" + (f" ({self.build} build)" if self.build else "")

    def encode(self) -> str:
        return base64.b64encode(pickle.dumps({"key": self.key, "ks": self.ks, "system": self.system,
                                              "nprm": self.nprm, "root": str(self.root),
                                              "family": self.family, "build": self.build})).decode()

    @classmethod
    def decode(cls, text: str) -> "Job":
        d = pickle.loads(base64.b64decode(text.encode()))   # noqa: S301 - written by our own caller
        return cls(d["key"], d["ks"], d["system"], d["nprm"], Path(d["root"]), d.get("family", ""),
                   d.get("build"))


def start(job: Job, d: Path):
    """Start the background compile of `job` (a process of its own session; reaped by a daemon thread
    of this process). Returns the Popen, or None when the process cannot be started (then the caller
    stays interpreted; the reason is the exception's)."""
    env = dict(os.environ)
    env[cache_store.ENV] = str(job.root)
    if job.build is not None:
        env["VCIRUN_BUILD"] = job.build
    pkg_parent = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = pkg_parent + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    log = open(log_path(d, job.key), "ab")   # noqa: SIM115 - handed to the child
    try:
        proc = subprocess.Popen([sys.executable, "-m", "vcirun.codegen.compile_worker", job.encode()],
                                stdin=subprocess.DEVNULL, stdout=log, stderr=log, env=env, cwd=str(d),
                                start_new_session=True, close_fds=True)
    finally:
        log.close()
    threading.Thread(target=proc.wait, name=f"vcirun-reap-{proc.pid}", daemon=True).start()
    return proc


def exercise(mod, ks, nprm: int) -> None:
    """Call the module's entry points once, so numba compiles (or loads) them: the loop (a method's
    module), the checks of a run's start, Hamilton's equations, the contacts and the energy (every
    module, the system-only one of the exact reference included). The values are zeros: what numba
    compiles depends on the types only."""
    import numpy as np

    from ..core import record

    n, m = int(mod.NDOF), int(mod.NCON)
    prm = np.ones(nprm)
    q, p, v = np.zeros(n), np.zeros(n), np.zeros(n)
    A = np.empty((n, n))
    mod.mass_matrix_ok(q, prm, A)
    mod.sys_phis(q, prm, np.empty(m))
    mod.sys_dphis(q, prm, np.empty((m, n)))
    if ks.reset is not None:   # one step of the loop (vcirun.run.plan.run_loop's call)
        from ..core.tolerances import DEFAULT_TOLERANCES

        settings = record.settings_vector(constrained=True, energies=True, resting_contact=True,
                                          **DEFAULT_TOLERANCES)
        out = record.allocate(1, n, m=m, cap_impacts=record.impact_capacity(1))
        mod.integrate(q, p, 0.0, 1e-2, 1, prm, settings, out, np.zeros(len(record.COUNTERS), dtype=np.int64))
    # what Python calls on every module after a run (the energy account, dense output, the start's checks):
    # compiled here too, or the first process to call them would compile them in the foreground
    mod.hamiltonian(q, p, prm)
    mod.dynamics_rhs(0.0, np.zeros(2 * n), prm, np.empty(2 * n))
    mod.force_power(q, v, 0.0, prm)
    mod.sys_M(q, prm, A)
    mod.sys_ddphis(q, v, prm, np.empty(m))
    mod.sys_Mdotv(q, v, prm, np.empty(n))


@contextlib.contextmanager
def slot(d: Path, poll_s: float = 0.5):
    """One of the machine's background-compile slots (a lock `bg_slot<i>.lock` per core), waited for."""
    n = max(1, os.cpu_count() or 1)
    while True:
        for i in range(n):
            with cache_lock.try_held(d / f"bg_slot{i}.lock", "a background compile slot") as got:
                if got:
                    yield i
                    return
        time.sleep(poll_s)
