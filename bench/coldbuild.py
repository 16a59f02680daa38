"""Cold builds: where the first `vcirun.simulate` of a new scene spends its time.

    python bench/coldbuild.py [--cases cart_pendulum:CVA,n_pendulum_8:MCVAA,...] [--out results/coldbuild.json]
    python bench/coldbuild.py profile SYSTEM METHOD          (one measurement, in this process)

Each case runs in a fresh process with a FRESH kernel cache (VCIRUN_CACHE_DIR = a new temporary
directory), one at a time; the load average is recorded before and after. Inside the process the
first simulation (h = 1e-2, T = 5, beta = 3.2 on the cart-pendulum; h = 1e-3, T = 0.01 on the
n-link pendulum, as `make bench`'s scaling section) is timed from outside (wall of the call) and
broken down by an exclusive-time stack (a stage's time excludes the stages nested in it):

  sympy     the symbolic system and the derivation of the kernels (module_source minus printing)
  emit      sympy's printer (vcirun.codegen.printer.pycode): expression -> source text
  cc        the C compiler (C backend only)
  frontend  numba's passes before type inference (bytecode, IR, inlining of inline="always")
  typing    numba's type inference (NopythonTypeInference)
  typed     numba's other typed passes (rewrites, legalisation, ...)
  lowering  numba IR -> LLVM IR (NativeLowering without the LLVM stages below)
  llvm_fn   LLVM function-level optimisation of each new function
  llvm_mod  LLVM module-level optimisation of each library, which LINKS IN every callee's library
            and optimises it again (numba's design: one library per compiled function)
  llvm_obj  LLVM machine-code generation (MCJIT finalize_object) of each library
  link      linking the callees' modules in, verification
  cache     writing numba's on-disk cache (index + object code)
  other     the rest of numba's compile (dispatcher bookkeeping) and of the simulation call

Per kernel (compiled function): the same stages, summed over its compilations. Printed as tables,
saved as JSON.
"""
from __future__ import annotations

import time

T_START = time.perf_counter()

import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
STAGES = ["sympy", "emit", "cc", "frontend", "typing", "typed", "lowering", "llvm_fn", "llvm_mod", "llvm_obj",
          "link", "cache", "other"]
DEFAULT_CASES = ([f"cart_pendulum:{m}{c}" for m in ("CVA", "MCVAC", "MCVAA") for c in ("", "+core")]
                 + [f"n_pendulum_{n}:{m}+core" for n in (2, 4, 8) for m in ("CVA", "MCVAC", "MCVAA")])
# (the figure of the specialized build, the target) in s per case: fresh cache, this machine
TARGETS = {"cart_pendulum:CVA": (9.0, 5.0), "cart_pendulum:MCVAC": (17.0, 8.0), "n_pendulum_8:CVA": (20.7, 15.0),
           "n_pendulum_8:MCVAC": (71.0, 30.0), "n_pendulum_8:MCVAA": (499.0, 60.0)}


# --- the exclusive-time stack ---------------------------------------------------------------------
class Stack:
    """Exclusive time per (stage, kernel), wall and CPU (this process's CPU plus that of finished
    child processes: the C compiler): entering a frame pauses the one below it."""

    def __init__(self):
        self.frames = []          # [stage, kernel, wall resumed, cpu resumed, own wall, own cpu]
        self.excl: dict = {}      # (stage, kernel) -> wall seconds
        self.cpu: dict = {}       # (stage, kernel) -> CPU seconds
        self.count: dict = {}
        self.by_pass: dict = {}   # numba pass name -> CPU seconds (exclusive)

    @staticmethod
    def clocks():
        ch = resource.getrusage(resource.RUSAGE_CHILDREN)
        return time.perf_counter(), time.process_time() + ch.ru_utime + ch.ru_stime

    def push(self, stage, kernel):
        w, c = self.clocks()
        if self.frames:
            top = self.frames[-1]
            top[4] += w - top[2]
            top[5] += c - top[3]
        self.frames.append([stage, kernel, w, c, 0.0, 0.0])
        self.count[stage, kernel] = self.count.get((stage, kernel), 0) + 1

    def pop(self) -> float:
        """Close the top frame; returns its exclusive CPU seconds."""
        w, c = self.clocks()
        st, k, w0, c0, ow, oc = self.frames.pop()
        ow += w - w0
        oc += c - c0
        self.excl[st, k] = self.excl.get((st, k), 0.0) + ow
        self.cpu[st, k] = self.cpu.get((st, k), 0.0) + oc
        if self.frames:
            self.frames[-1][2:4] = [w, c]
        return oc

    def relabel(self, stage):
        """The top frame's time so far stays with its stage; from now on it counts as `stage`."""
        w, c = self.clocks()
        fr = self.frames[-1]
        fr[4] += w - fr[2]
        fr[5] += c - fr[3]
        self.excl[fr[0], fr[1]] = self.excl.get((fr[0], fr[1]), 0.0) + fr[4]
        self.cpu[fr[0], fr[1]] = self.cpu.get((fr[0], fr[1]), 0.0) + fr[5]
        fr[0], fr[2:6] = stage, [w, c, 0.0, 0.0]

    def wrap(self, obj, attr, stage, kernel_of=None):
        orig = getattr(obj, attr)
        stack = self

        def wrapped(*a, **kw):
            stack.push(stage, kernel_of(*a, **kw) if kernel_of else "")
            try:
                return orig(*a, **kw)
            finally:
                stack.pop()

        setattr(obj, attr, wrapped)


_TYPING = {"nopython_type_inference"}
_LOWERING = {"native_lowering"}


def _pass_stage(name: str, seen_typing: dict, qual: str) -> str:
    if name in _TYPING:
        seen_typing[qual] = True
        return "typing"
    if name in _LOWERING:
        return "lowering"
    return "typed" if seen_typing.get(qual) else "frontend"


def instrument(stack: Stack):
    """Hook numba's events and codegen and vcirun's generator into `stack`."""
    from numba.core import caching, codegen, event

    seen_typing: dict = {}

    class Compile(event.Listener):
        def on_start(self, ev):
            stack.push("other", ev.data["dispatcher"].py_func.__name__)

        def on_end(self, ev):
            stack.pop()

    class Pass(event.Listener):
        def on_start(self, ev):
            qual = ev.data["qualname"]
            name = ev.data["name"].split(" [")[0]
            stack.push(_pass_stage(name, seen_typing, qual), qual.split(".")[-1])

        def on_end(self, ev):
            name = ev.data["name"].split(" [")[0]
            stack.by_pass[name] = stack.by_pass.get(name, 0.0) + stack.pop()

    event.register("numba:compile", Compile())
    event.register("numba:run_pass", Pass())
    lib = lambda self, *a, **k: self.name.split(".")[-1]  # noqa: E731
    stack.wrap(codegen.CPUCodeLibrary, "_optimize_functions", "llvm_fn", lib)
    stack.wrap(codegen.CPUCodeLibrary, "_optimize_final_module", "llvm_mod", lib)
    stack.wrap(codegen.CPUCodeLibrary, "finalize", "link", lib)
    stack.wrap(codegen.JITCodeLibrary, "_finalize_specific", "llvm_obj", lib)
    stack.wrap(caching.Cache, "save_overload", "cache", lambda self, *a, **k: self._py_func.__name__)
    stack.push("sympy", "import sympy")  # (generation imports it; done here to hook the printer)
    import vcirun.codegen.kernels as K

    stack.pop()
    stack.wrap(K, "pycode", "emit", lambda *a, **k: "")
    try:
        import vcirun.codegen.cc as cc  # the C backend (when present)

        stack.wrap(cc, "compile_shared", "cc", lambda *a, **k: "")
    except ImportError:
        pass


def profile(system: str, method: str, extra: dict | None = None) -> dict:
    """One cold build in this process (the caller gives it a fresh VCIRUN_CACHE_DIR)."""
    extra = extra or {}
    load0 = os.getloadavg()
    import numba  # noqa: F401

    import vcirun
    from vcirun.codegen import build
    from vcirun.codegen.kernel_cache import default

    t_import = time.perf_counter() - T_START
    stack = Stack()
    stack.push("sympy", "")   # everything of the call not claimed by a nested stage
    instrument(stack)
    kw = dict(h=1e-2, T=5.0, beta=3.2) if system == "cart_pendulum" else dict(h=1e-3, T=0.01)
    kw.update(extra)
    t0 = time.perf_counter() - stack.excl.get(("sympy", "import sympy"), 0.0)
    c0 = Stack.clocks()[1] - stack.cpu.get(("sympy", "import sympy"), 0.0)
    # the symbolic part: resolve_system + module_source; afterwards the stack's base is "other"
    kc = default()
    orig_exec = kc._exec_module

    def exec_module(*a, **k):
        stack.push("other", "module exec")
        try:
            return orig_exec(*a, **k)
        finally:
            stack.pop()
            stack.relabel("other")   # numba's compile from here on

    kc._exec_module = exec_module   # (an instance attribute: this cache's loads go through it)
    with kc.report() as built:
        tr = vcirun.simulate(system, method, **kw)
    wall = time.perf_counter() - t0
    cpu = Stack.clocks()[1] - c0
    stack.pop()
    del kc._exec_module
    log = built.entries[-1]
    path = build.cache_dir() / f"vk_{log['key']}.py"
    by_stage = {s: 0.0 for s in STAGES}
    by_stage_cpu = {s: 0.0 for s in STAGES}
    by_kernel: dict = {}
    for (st, k), dt in stack.excl.items():
        by_stage[st] = by_stage.get(st, 0.0) + dt
        by_stage_cpu[st] = by_stage_cpu.get(st, 0.0) + stack.cpu[st, k]
        if st not in ("sympy", "emit") and k:
            by_kernel.setdefault(k, {})[st] = by_kernel.get(k, {}).get(st, 0.0) + stack.cpu[st, k]
    srcs = sorted(Path(build.cache_dir()).glob("*"))
    return {"system": system, "method": method, "first_sim_s": wall, "first_sim_cpu_s": cpu, "import_s": t_import, "status": tr.status,
            "generate_s": log["generate_s"], "cached": log["cached"], "stages": by_stage, "stages_cpu": by_stage_cpu, "kernels": by_kernel,
            "passes_cpu": dict(sorted(stack.by_pass.items(), key=lambda kv: -kv[1])),
            "compiles": {k: c for (st, k), c in stack.count.items() if st == "other" and k != "module exec"},
            "source_kB": path.stat().st_size / 1e3 if path.exists() else None,
            "cache_files": len(srcs), "loadavg_before": load0, "loadavg_after": os.getloadavg(),
            "backend": os.environ.get("VCIRUN_MH_BACKEND", "default"), "extra": extra, "vcirun_file": vcirun.__file__}


# --- the driver ------------------------------------------------------------------------------------
# "SCENE:METHOD+core": the kernel set's shared core (vcirun.codegen.shared) is compiled first, by
# another scene of the same method in the same fresh cache; then the case's scene is built cold
WARMUP = {"cart_pendulum": "double_pendulum", "double_pendulum": "cart_pendulum"}


def _warmup_scene(system: str) -> str:
    if system.startswith("n_pendulum_"):
        return "n_pendulum_3" if system != "n_pendulum_3" else "n_pendulum_2"
    return WARMUP.get(system, "cart_pendulum")


def run_case(case: str, timeout: float = 3600, env_extra: dict | None = None) -> dict:
    system, method = case.split(":")
    warm_core = method.endswith("+core")
    method = method.removesuffix("+core")
    with tempfile.TemporaryDirectory(prefix="vcirun_cold_") as d:
        env = dict(os.environ, VCIRUN_CACHE_DIR=d, **(env_extra or {}))
        core_s = None
        if warm_core:
            other = _warmup_scene(system)
            c0 = time.perf_counter()
            w = subprocess.run([sys.executable, "-c", "import sys, vcirun; vcirun.simulate(sys.argv[1], sys.argv[2], "
                                "h=1e-2, T=0.05)", other, method], env=env, cwd=ROOT, capture_output=True, text=True,
                               timeout=timeout)
            if w.returncode != 0:
                return {"case": case, "error": "core warm-up: " + (w.stderr.strip().splitlines() or ["?"])[-1]}
            core_s = time.perf_counter() - c0
        t0 = time.perf_counter()
        try:
            r = subprocess.run([sys.executable, str(Path(__file__).resolve()), "profile", system, method], env=env,
                               cwd=ROOT, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return {"case": case, "error": f"timed out after {timeout} s"}
        wall = time.perf_counter() - t0
    if r.returncode != 0:
        return {"case": case, "error": (r.stderr.strip().splitlines() or [f"exit {r.returncode}"])[-1]}
    out = json.loads(r.stdout.strip().splitlines()[-1])
    out["case"] = case
    out["process_wall_s"] = wall
    out["core_warmup_s"] = core_s
    out["env"] = env_extra or {}
    return out


def print_row(r: dict, log=print):
    if "error" in r:
        log(f"  {r['case']:22s} {r['error']}")
        return
    st = r["stages_cpu"]
    tgt = TARGETS.get(r["case"].replace("+core", ""))
    mark = ""
    if tgt is not None:
        verdict = ("met" if r["first_sim_s"] <= tgt[1] else "met in CPU time" if r["first_sim_cpu_s"] <= tgt[1]
                   else "NOT met")
        mark = f"  target {tgt[1]:g} s: {verdict}"
    log(f"  {r['case']:22s} {r['first_sim_s']:7.1f} {r['first_sim_cpu_s']:7.1f} |" + "".join(f"{st.get(s, 0.0):9.2f}" for s in STAGES)
        + f" | {r['source_kB']:7.0f} kB  load {r['loadavg_before'][0]:.1f}/{r['loadavg_after'][0]:.1f}{mark}")


def header(log=print):
    log(f"  {'case':22s} {'wall s':>7s} {'CPU s':>7s} |" + "".join(f"{s:>9s}" for s in STAGES)
        + " | source     load before/after  (first simulation; stages in CPU s)")


def print_kernels(r: dict, top: int = 8, log=print):
    if "error" in r:
        return
    ks = sorted(r["kernels"].items(), key=lambda kv: -sum(kv[1].values()))[:top]
    log(f"    {r['case']}: most expensive kernels (CPU s; compilations)")
    for k, st in ks:
        parts = ", ".join(f"{s} {st[s]:.2f}" for s in STAGES if st.get(s, 0) >= 0.05)
        log(f"      {k:24s} {sum(st.values()):7.2f}  ({r['compiles'].get(k, 0)}x)  {parts}")


GROUPS = [("sympy", ("sympy",)), ("emit", ("emit",)), ("cc", ("cc",)), ("numba: front+typing", ("frontend", "typing", "typed")),
          ("numba: lowering", ("lowering",)), ("LLVM", ("llvm_fn", "llvm_mod", "llvm_obj", "link")),
          ("cache+other", ("cache", "other"))]


def markdown(rows, generated=None) -> str:
    """The per-stage table of `rows` (results of run_case) as Markdown, CPU seconds."""
    head = "| case | wall s | CPU s | " + " | ".join(g for g, _ in GROUPS) + " | generated kernels (numba CPU s) | load |"
    out = [head, "|" + "---|" * (head.count("|") - 1)]
    gen = generated or ()
    for r in rows:
        if "error" in r:
            out.append(f"| {r['case']} | {r['error']} |" + " |" * (len(GROUPS) + 3))
            continue
        st = r["stages_cpu"]
        g = sum(sum(v.values()) for k, v in r["kernels"].items() if k in gen)
        out.append(f"| {r['case']} | {r['first_sim_s']:.1f} | {r['first_sim_cpu_s']:.1f} | "
                   + " | ".join(f"{sum(st.get(x, 0.0) for x in xs):.1f}" for _, xs in GROUPS)
                   + f" | {g:.1f} | {r['loadavg_before'][0]:.1f} |")
    return "\n".join(out)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "profile":
        print(json.dumps(profile(argv[1], argv[2])))
        return
    if argv and argv[0] == "markdown":   # python bench/coldbuild.py markdown results/coldbuild.json
        rows = json.loads(Path(argv[1]).read_text())
        rows = rows["coldbuild"]["rows"].values() if isinstance(rows, dict) else rows
        kernels = {"sys_M", "sys_V", "sys_phi", "sys_dphi", "sys_dHq", "sys_node", "sys_node_M", "sys_force",
                   "sys_force_jac", "mh_FA", "mh_value", "mh_grad", "mh_hess"}
        kernels |= {k for r in rows if "kernels" in r for k in r["kernels"]
                    if k.split("_")[-1] in ("PmJc", "Ppc", "Ed", "Edv", "PmJ", "Pp")}
        print(markdown(list(rows), kernels))
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(DEFAULT_CASES))
    ap.add_argument("--out", default=str(ROOT / "results" / "coldbuild.json"))
    ap.add_argument("--kernels", type=int, default=6, help="kernels listed per case")
    ap.add_argument("--numba", action="store_true", help="the numba kernel backend (VCIRUN_KERNEL_BACKEND=numba)")
    a = ap.parse_args(argv)
    env = {"VCIRUN_KERNEL_BACKEND": "numba"} if a.numba else {}
    rows = []
    header()
    for case in a.cases.split(","):
        r = run_case(case, env_extra=env)
        rows.append(r)
        print_row(r)
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(json.dumps(rows, indent=1))
        sys.stdout.flush()
    for r in rows:
        print_kernels(r, a.kernels)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(rows, indent=1))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
