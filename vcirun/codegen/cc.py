"""The system C compiler for the C kernels (vcirun.codegen.c_emit): discovery, flags, compilation.

`compiler()` is the compiler the C backend uses: $CC, else the first of cc, gcc, clang on PATH, or
None (then every kernel stays in numba). `backend()` is the kernel backend a new module gets:
"c" when a compiler exists, "numba" otherwise or when VCIRUN_KERNEL_BACKEND=numba asks for it.
`identity()` is what the module cache key records about it (the backend, the compiler's path, size
and mtime, the flags: cheap, no subprocess, so the warm path stays as it is).

Flags keep the numbers numba computes: -ffp-contract=off (no fused multiply-add), no -ffast-math,
no -march (the generic x86-64 / aarch64 instruction set); -fno-math-errno only drops the errno
write of sqrt and friends. The optimisation level depends on the kernel's size (`opt_level`): the
register allocators of gcc and LLVM are superlinear in the live values of one straight-line
function, which is what a modified-Hamiltonian kernel at n = 8 is (docs/performance.md).

Kernels of one optimisation level are packed into translation units (a long kernel is one of its
own), compiled in parallel (one job per core), then linked into one shared object, written
atomically (parallel sweep workers never load a half-written file); vcirun.codegen.c_link records its
digest and checks it before every load.
"""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

BACKEND_ENV = "VCIRUN_KERNEL_BACKEND"
BACKENDS = ("c", "numba")
BASE_FLAGS = ("-fPIC", "-ffp-contract=off", "-fno-math-errno")
# statements of one kernel -> optimisation level (measured: docs/performance.md, Cold builds): -O2
# where it is cheap; -O1 for the long (segmented) kernels, where -O2 costs twice the compile time
# and did not run faster
OPT_LEVELS = ((1500, "-O2"), (None, "-O1"))
CC_TIMEOUT = 3600.0
# Kernels lighter than this (statements + 2-D element stores) stay numba source: LLVM inlines them
# into the compiled Newton loops (a C call cannot be inlined: ~10 % more loop time for the
# cart-pendulum's 20-45-statement step kernels, bench/compare_trees.py), and numba compiles them in
# well under a second.
C_MIN_STATEMENTS = 100
C_MIN_ENV = "VCIRUN_C_MIN_STATEMENTS"
SEGMENT_LINES = 400  # a kernel longer than twice this is split into functions of about this many statements


def min_statements() -> int:
    """C_MIN_STATEMENTS, or $VCIRUN_C_MIN_STATEMENTS (0: every leaf kernel in C)."""
    v = os.environ.get(C_MIN_ENV, "").strip()
    if not v:
        return C_MIN_STATEMENTS
    try:
        return max(0, int(v))
    except ValueError:
        raise ValueError(f"{C_MIN_ENV}: expected a number of statements, got {v!r}") from None


def compiler() -> str | None:
    """Path of the C compiler, or None."""
    env = os.environ.get("CC")
    if env:
        return shutil.which(env) or (env if Path(env).is_file() else None)
    for name in ("cc", "gcc", "clang"):
        p = shutil.which(name)
        if p:
            return p
    return None


def backend() -> str:
    """The kernel backend of new modules: $VCIRUN_KERNEL_BACKEND, else "c" if a compiler exists."""
    b = os.environ.get(BACKEND_ENV, "").strip().lower()
    if b and b not in BACKENDS:
        raise ValueError(f"{BACKEND_ENV}: unknown kernel backend {b!r} (choose one of {', '.join(BACKENDS)})")
    if b == "numba":
        return "numba"
    if compiler() is None:
        if b == "c":
            raise ValueError(f"{BACKEND_ENV}=c but no C compiler was found (set CC, or install cc/gcc/clang, "
                             f"or use {BACKEND_ENV}=numba)")
        return "numba"
    return "c"


def identity() -> str:
    """Backend + compiler (path, size, mtime) + flags, for cache keys (no subprocess)."""
    b = backend()
    if b != "c":
        return "numba"
    cc = compiler()
    try:
        st = os.stat(os.path.realpath(cc))
        stamp = f"{st.st_size}:{int(st.st_mtime)}"
    except OSError:
        stamp = "?"
    return f"c|{cc}|{stamp}|{' '.join(BASE_FLAGS)}|{OPT_LEVELS}|min={min_statements()}|seg={SEGMENT_LINES}"


def opt_level(statements: int) -> str:
    for limit, flag in OPT_LEVELS:
        if limit is None or statements <= limit:
            return flag
    return OPT_LEVELS[-1][1]


class CompileError(RuntimeError):
    pass


def _run(cmd: list, cwd: str):
    r = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=CC_TIMEOUT)
    if r.returncode != 0:
        raise CompileError(f"{' '.join(cmd[:3])} ...: {r.stderr.strip()[-2000:]}")


def compile_shared(units: list, out: Path, jobs: int | None = None, check=None) -> Path:
    """Compile C translation units [(name, source, opt flag)] into the shared object `out`. Returns out.
    Raises CompileError (or OSError).

    The work happens in a directory `.vkc_build.<pid>.<host>.<random>` beside `out` (removed after; one
    that a killed process left is removed by vcirun.codegen.cache_store.sweep_stale). File names are
    relative to it, so the object code does not depend on the directory's name. `check(path)` runs on
    the linked file before it is fsynced and renamed over `out` (atomically: parallel workers never
    load a half-written file)."""
    import shutil
    from concurrent.futures import ThreadPoolExecutor

    from ..core.fsync import fsync_path
    from .cache_store import BUILD_DIR_MARK, owner_tag

    cc = compiler()
    if cc is None:
        raise CompileError("no C compiler")
    out = Path(out)
    d = out.parent / f"{BUILD_DIR_MARK}{owner_tag()}"
    d.mkdir()
    try:
        objs = []
        cmds = []
        for i, (name, src, opt) in enumerate(units):
            c = f"u{i}_{name}.c"
            (d / c).write_text(src)
            o = c[:-2] + ".o"
            objs.append(o)
            cmds.append([cc, opt, *BASE_FLAGS, "-c", "-o", o, c])
        jobs = jobs or max(1, min(len(cmds), os.cpu_count() or 1))
        # largest first, so that the long one starts at once
        order = sorted(range(len(cmds)), key=lambda i: -len(units[i][1]))
        with ThreadPoolExecutor(max_workers=jobs) as ex:
            list(ex.map(lambda i: _run(cmds[i], str(d)), order))
        _run([cc, "-shared", "-o", out.name, *objs, "-lm"], str(d))
        tmp = d / out.name
        if check is not None:
            check(tmp)
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, out)
        fsync_path(out.parent, directory=True)
    finally:
        shutil.rmtree(d, ignore_errors=True)
    return out
