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

Each kernel is its own translation unit, compiled in parallel (one job per core), then linked into
one shared object, written atomically (parallel sweep workers never load a half-written file).
"""
from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

BACKEND_ENV = "VCIRUN_KERNEL_BACKEND"
BACKENDS = ("c", "numba")
BASE_FLAGS = ("-fPIC", "-ffp-contract=off", "-fno-math-errno")
# statements of one kernel -> optimisation level (measured: docs/performance.md, Cold builds)
OPT_LEVELS = ((1500, "-O2"), (6000, "-O1"), (None, "-O1"))
CC_TIMEOUT = 3600.0


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
    return f"c|{cc}|{stamp}|{' '.join(BASE_FLAGS)}|{OPT_LEVELS}"


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


def compile_shared(units: list, out: Path, jobs: int | None = None) -> Path:
    """Compile C translation units [(name, source, opt flag)] into the shared object `out`
    (atomically replaced). Returns out. Raises CompileError."""
    cc = compiler()
    if cc is None:
        raise CompileError("no C compiler")
    out = Path(out)
    with tempfile.TemporaryDirectory(prefix="vkc_", dir=out.parent) as d:
        objs = []
        cmds = []
        for name, src, opt in units:
            c = Path(d) / f"{name}.c"
            c.write_text(src)
            o = Path(d) / f"{name}.o"
            objs.append(str(o))
            cmds.append([cc, opt, *BASE_FLAGS, "-c", "-o", str(o), str(c)])
        jobs = jobs or max(1, min(len(cmds), os.cpu_count() or 1))
        # largest first, so that the long one starts at once
        order = sorted(range(len(cmds)), key=lambda i: -len(units[i][1]))
        with ThreadPoolExecutor(max_workers=jobs) as ex:
            list(ex.map(lambda i: _run(cmds[i], d), order))
        tmp = Path(d) / out.name
        _run([cc, "-shared", "-o", str(tmp), *objs, "-lm"], d)
        os.replace(tmp, out)
    return out
