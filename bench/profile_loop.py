"""Where a compiled loop spends its time: perf samples of one module's `integrate`, by function.

    python bench/profile_loop.py MODULE.py --system cart_pendulum --method CVA --h 0.032 --T 50
                                 [--beta 3.2 | none] [--seconds 10] [--top 30]

MODULE.py is a generated kernel module (a specialized-build module, or a shared-build scene module,
which is then linked to this tree's core). It is compiled afresh into a temporary numba cache, so its
LLVM module (every function that was not inlined, with its symbol) is at hand; `integrate` is called
with the arguments `vcirun.simulate` gives it, over and over for --seconds while `perf record` samples
this process (user space; needs perf). Each sample's instruction pointer is attributed to the JIT
function whose entry is the nearest below it (numba's symbols, demangled to the Python name); samples
outside the JIT code keep perf's own symbol (malloc, NRT_incref in numba's helper library, ...).

It answers "which callee got slower" where bench/compare_trees.py only gives the total, e.g. run it on
two modules (this tree's and an old tree's) and compare the shares.
"""
from __future__ import annotations

import argparse
import bisect
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _demangle(name: str) -> str:
    """numba's Itanium-style mangled name (_ZN<len><part>...<len><name>B<abi tags>E<arg types>) -> name."""
    if not name.startswith("_ZN"):
        return name
    i, parts = 3, []
    while i < len(name) and name[i].isdigit():
        j = i
        while name[j].isdigit():
            j += 1
        n = int(name[i:j])
        parts.append(name[j:j + n])
        i = j + n
    return parts[-1] if parts else name


def jit_symbols(library) -> list[tuple[int, str]]:
    mod = library._final_module
    syms = []
    for f in mod.functions:
        if f.is_declaration:
            continue
        try:
            addr = library.get_pointer_to_function(f.name)
        except Exception:
            continue
        if addr:
            syms.append((addr, _demangle(f.name)))
    syms.sort()
    return syms


def all_jit_symbols() -> list[tuple[int, str]]:
    """The symbols of every function numba compiled in this process (the shared core's loop, the scene
    module's kernels and their wrappers live in different libraries)."""
    import gc

    from numba.core.registry import CPUDispatcher

    syms = {}
    for obj in gc.get_objects():
        if isinstance(obj, CPUDispatcher):
            for cres in obj.overloads.values():
                try:
                    syms.update(jit_symbols(cres.library))
                except Exception:
                    continue
    return sorted(syms.items())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("module")
    ap.add_argument("--system", default="cart_pendulum")
    ap.add_argument("--method", default="CVA")
    ap.add_argument("--h", type=float, default=0.032)
    ap.add_argument("--T", type=float, default=50.0)
    ap.add_argument("--beta", type=lambda v: None if v.lower() == "none" else float(v), default=3.2,
                    help="the scene's beta (none: its default start)")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--top", type=int, default=30)
    ap.add_argument("--resting-contact", choices=("on", "off"), default="on")
    a = ap.parse_args(argv)
    if not os.environ.get("_PROFILE_LOOP_CHILD"):
        if shutil.which("perf") is None:
            raise SystemExit("profile_loop: needs `perf` (linux-tools) on PATH")
        # fresh numba cache: the function symbols exist only for a module compiled in this process
        cache = tempfile.mkdtemp(prefix="profile_loop_numba_")
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, VCIRUN_CACHE_DIR=cache + "/vcirun", _PROFILE_LOOP_CHILD="1",
                   PYTHONPATH=str(ROOT), VCIRUN_TIER="compiled")
        try:
            rc = subprocess.call([sys.executable, __file__] + (argv or sys.argv[1:]), env=env)
        finally:
            shutil.rmtree(cache, ignore_errors=True)
        raise SystemExit(rc)

    import warnings

    sys.path.insert(0, str(ROOT / "bench"))
    from compare_trees import capture_loop, load

    warnings.simplefilter("ignore")
    raw, args, tr = capture_loop(load(a.module, a.method), a.system, a.method, a.h, a.T, a.beta,
                                 a.resting_contact == "on")
    syms = all_jit_symbols()
    entries = [s[0] for s in syms]
    t0 = time.perf_counter()
    raw(*args)
    one = time.perf_counter() - t0
    data = tempfile.mktemp(prefix="profile_loop_", suffix=".data")
    perf = subprocess.Popen(["perf", "record", "-q", "-F", "4999", "-o", data, "-p", str(os.getpid())],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(0.5)
    n = 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < a.seconds:
        raw(*args)
        n += 1
    perf.send_signal(signal.SIGINT)
    perf.wait()
    script = subprocess.run(["perf", "script", "-i", data, "-F", "ip,sym"], capture_output=True, text=True).stdout
    os.unlink(data)
    counts = Counter()
    for line in script.splitlines():
        parts = line.split(None, 1)
        if not parts:
            continue
        try:
            ip = int(parts[0], 16)
        except ValueError:
            continue
        sym = parts[1].strip() if len(parts) > 1 else "[unknown]"
        if sym in ("[unknown]", "") or sym.startswith("[unknown"):
            k = bisect.bisect_right(entries, ip) - 1
            sym = f"jit:{syms[k][1]}" if k >= 0 and ip - entries[k] < 1 << 20 else "[unknown]"
        counts[sym] += 1
    total = sum(counts.values())
    print(f"{a.module}: {a.system} {a.method} h={a.h} T={a.T}: {tr.q.shape[0] - 1} steps, "
          f"{tr.impacts.size} impacts; one call {one * 1e3:.3f} ms; {n} calls sampled, {total} samples")
    for sym, c in counts.most_common(a.top):
        print(f"  {100 * c / total:6.2f} %  {sym}")


if __name__ == "__main__":
    main()
