"""Fault-injection and hostile-input probe of vcirun: the counts of docs/reliability.md.

    .venv/bin/python bench/reliability_probe.py [--only SECTION ...] [--quick]

Sections (each case is a real command or call; nothing is mocked except where a case says so):
  config    hostile sweep configs and system files through `vcirun validate` and `vcirun sweep`
  api       hostile arguments to vcirun.simulate / vcirun.reference (one subprocess, a watchdog per call)
  output    unusable output paths (read-only, parent is a file, a directory, symlinks, a second writer)
  corrupt   damaged results files given to `vcirun info`, `vcirun plot` and a resuming `vcirun sweep`
  disk      a full disk: tmpfs of 1, 2, 6 MB and 12 kB (needs `unshare --mount`; skipped otherwise)
  kill      SIGKILL of `vcirun sweep` at random moments: file readable by plain h5py, no committed run
            lost, resume completes bit-identical to an uninterrupted sweep
  loss      the loss bound: SIGKILL during a 2000-run sweep, runs lost against the sweep's own rate

Every case is classified: `ok` (the expected outcome: a one-line `error:` and a non-zero exit, no
traceback, no new file left behind; or a correct result), `segfault`, `traceback`, `hang` (timeout),
`wrong_ok` (a run or command reported ok with a wrong or non-finite result), `lost` (committed runs
missing after a fault), `bad_message` (non-zero exit but not a single `error:` line, or files left).
Writes results/reliability.json and docs/reliability.md.
"""
from __future__ import annotations

import argparse
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PY = sys.executable
ENV = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
ENV.setdefault("VCIRUN_CACHE_DIR", str(ROOT / ".vcirun_cache"))


@dataclass
class Case:
    section: str
    name: str
    outcome: str           # ok | segfault | traceback | hang | wrong_ok | lost | bad_message | skipped
    detail: str = ""
    seconds: float = 0.0
    numbers: dict = field(default_factory=dict)


CASES: list[Case] = []


def record(section, name, outcome, detail="", seconds=0.0, **numbers):
    c = Case(section, name, outcome, " ".join(str(detail).split())[:300], round(seconds, 2), numbers)
    CASES.append(c)
    print(f"  [{outcome:>11}] {section}/{name}: {c.detail[:150]}", flush=True)
    return c


# --- running commands ---------------------------------------------------------------------------------
def vcirun(*args, cwd=None, timeout=300, script=None, wrap=None):
    """(rc, stdout, stderr, seconds) of `vcirun ARGS` in a subprocess; rc None on timeout. `script`
    runs a Python file instead of the CLI module (fault injection); `wrap` prefixes the command."""
    cmd = [PY, script] if script else [PY, "-m", "vcirun.cli.main"]
    cmd = cmd + [str(a) for a in args]
    if wrap:
        cmd = wrap + [" ".join(_q(c) for c in cmd)]
    t0 = time.monotonic()
    try:
        p = subprocess.run(cmd, cwd=cwd, env=ENV, capture_output=True, text=True, timeout=timeout)
        return p.returncode, p.stdout, p.stderr, time.monotonic() - t0
    except subprocess.TimeoutExpired as e:
        return None, e.stdout or "", e.stderr or "", time.monotonic() - t0


def _q(s: str) -> str:
    return "'" + str(s).replace("'", "'\"'\"'") + "'"


def classify_error(rc, out, err, *, left=()) -> tuple[str, str]:
    """An expected failure: one `error:` line on stderr, exit 1 (or 130/143), nothing left behind."""
    if rc is None:
        return "hang", "timed out"
    if rc < 0 or rc in (134, 139):
        return "segfault", f"killed by signal {-rc if rc < 0 else rc - 128}"
    if "Traceback" in err or "Traceback" in out:
        return "traceback", err.strip().splitlines()[-1] if err.strip() else out.strip().splitlines()[-1]
    if rc == 0:
        return "wrong_ok", "exit 0 where an error was expected: " + (out.strip().splitlines() or [""])[0]
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("error:")]
    if len(errors) != 1:
        return "bad_message", f"{len(errors)} error lines: {' | '.join(lines[-3:])}"
    if left:
        return "bad_message", f"left behind: {', '.join(map(str, left))}; {errors[0]}"
    return "ok", errors[0]


def listing(d: Path) -> set:
    return {p.relative_to(d) for p in d.rglob("*")} if d.exists() else set()


# --- configs ----------------------------------------------------------------------------------------
TINY = """\
name: tiny
system: cart_pendulum
methods: [CVA, VCI]
h: [3.2e-2, 1.0e-2]
beta: {start: 3.2, stop: 5.2, num: 3}
T: 0.5
reference: {kind: exact, rtol: 1.0e-10}
timing_repeats: 1
"""

SYSTEM = """\
name: spring
coordinates: [x]
parameters: {k: 4.0}
mass_matrix: [["1"]]
potential: "0.5*k*x**2"
constraint: "x + 0.5"
q0: [0.2]
p0: [1.0]
"""


def bomb(levels: int, anchor_value: str = '"lol"') -> tuple[str, str]:
    """(anchor lines, the top alias) of a billion-laughs structure: 9**levels copies."""
    lines = [f"  a0: &a0 [{', '.join([anchor_value] * 9)}]"]
    for i in range(1, levels):
        lines.append(f"  a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]")
    return "\n".join(lines), f"*a{levels - 1}"


def inline(potential='"0.5*k*x**2"', params="{k: 4.0}", coords="[x]", extra=""):
    return f"""\
name: inl
system:
  name: inl
  coordinates: {coords}
  parameters: {params}
  mass_matrix: [["1"]]
  potential: {potential}
  constraint: "x + 0.5"
  q0: [0.2]
  p0: [1.0]
{extra}methods: [CVA]
h: [1.0e-2]
T: 0.5
reference: {{kind: none}}
"""


def config_cases() -> list[tuple[str, str, dict]]:
    """(name, config text, {file name: text} of extra files) of hostile configs: each must be refused."""
    b9, top9 = bomb(9)
    b8, top8 = bomb(8, '"x"')
    cases = [
        ("alias bomb in T", f"anchors:\n{b9}\n" + TINY.replace("T: 0.5", f"T: {top9}"), {}),
        ("alias bomb in description", f"x-anchors: &x\n{b9}\n" + TINY + f"description: {top9}\n", {}),
        ("alias bomb in a system file's description", TINY.replace("system: cart_pendulum", "system: sys.yaml"),
         {"sys.yaml": f"x: &x\n{b9}\n" + SYSTEM + f"description: {top9}\n"}),
        ("alias bomb (8 levels) in potential", inline(potential=top8).replace("name: inl\nsystem:", f"z:\n{b8}\nname: inl\nsystem:", 1), {}),
        ("recursive alias", TINY + "description: &r [*r]\n", {}),
        ("h = 1e-320", TINY.replace("h: [3.2e-2, 1.0e-2]", "h: [1.0e-320]"), {}),
        ("h = 1e-300", TINY.replace("h: [3.2e-2, 1.0e-2]", "h: [1.0e-300]"), {}),
        ("T = 1e9 with h = 1e-6", TINY.replace("h: [3.2e-2, 1.0e-2]", "h: [1.0e-6]").replace("T: 0.5", "T: 1.0e9"), {}),
        ("T = 1e4 with h = 1e-6", TINY.replace("h: [3.2e-2, 1.0e-2]", "h: [1.0e-6]").replace("T: 0.5", "T: 1.0e4"), {}),
        ("method reference at h = 1e-12", TINY.replace("reference: {kind: exact, rtol: 1.0e-10}",
                                                        "reference: {kind: method, method: CVA, h: 1.0e-12}"), {}),
        ("memory above max_memory", TINY.replace("h: [3.2e-2, 1.0e-2]", "h: [1.0e-5]").replace("T: 0.5", "T: 1000")
         + "max_memory: 1GB\n", {}),
        ("full-width parameter beside its ASCII twin", inline(params="{k: 4.0, ｋ: 400.0}"), {}),
        ("full-width letter in an expression", inline(potential='"0.5*ｋ*x**2"'), {}),
        ("mathematical letter in an expression", inline(potential='"0.5*𝑘*x**2"'), {}),
        ("coordinate declared full-width", inline(coords="[ｘ]", potential='"0.5*k*ｘ**2"'), {}),
        ("Greek parameter name", inline(params="{κ: 4.0}", potential='"0.5*x**2"'), {}),
        ("system file: full-width parameter", TINY.replace("system: cart_pendulum", "system: sys.yaml"),
         {"sys.yaml": SYSTEM.replace("{k: 4.0}", "{k: 4.0, ｋ: 400.0}")}),
        ("system file: duplicate key", TINY.replace("system: cart_pendulum", "system: sys.yaml"),
         {"sys.yaml": SYSTEM.replace("{k: 4.0}", "{k: 4.0, k: 400.0}")}),
        ("system file: potential: true", TINY.replace("system: cart_pendulum", "system: sys.yaml"),
         {"sys.yaml": SYSTEM.replace('potential: "0.5*k*x**2"', "potential: true")}),
        ("system file: non-ASCII system name", TINY.replace("system: cart_pendulum", "system: sys.yaml"),
         {"sys.yaml": SYSTEM.replace("name: spring", "name: ｓpring")}),
        ("system file: parameter named lambda", TINY.replace("system: cart_pendulum", "system: sys.yaml"),
         {"sys.yaml": SYSTEM.replace("{k: 4.0}", "{k: 4.0, lambda: 1.0}")}),
        ("system file: parameter x_dot beside coordinate x", TINY.replace("system: cart_pendulum", "system: sys.yaml"),
         {"sys.yaml": SYSTEM.replace("{k: 4.0}", "{k: 4.0, x_dot: 1.0}")}),
        ("system file: a list as potential", TINY.replace("system: cart_pendulum", "system: sys.yaml"),
         {"sys.yaml": SYSTEM.replace('potential: "0.5*k*x**2"', "potential: [[1, 2], [3, 4]]")}),
        ("parameter named like a kernel placeholder (vcTQ0)", inline(params="{k: 4.0, vcTQ0: 400.0}",
                                                                     potential='"0.5*vcTQ0*x**2"'), {}),
        ("system file: parameter named like a step slot (hh)", TINY.replace("system: cart_pendulum", "system: sys.yaml"),
         {"sys.yaml": SYSTEM.replace("{k: 4.0}", "{k: 4.0, hh: 1.0}")}),
        ("inline potential: true", inline(potential="true"), {}),
        ("parameter override true", TINY.replace("system: cart_pendulum", "system: {name: cart_pendulum, params: {m1: true}}"), {}),
        ("T: true", TINY.replace("T: 0.5", "T: true"), {}),
        ("expression of 20000 characters", inline(potential='"' + "+".join(["x"] * 10000) + '"'), {}),
        ("expression of 7199 nodes in 7259 characters",
         inline(potential='"' + "*".join(["(" + "-".join(["-x"] * 80) + ")"] * 30) + '"'), {}),
        ("expression of 4000 terms", inline(potential='"' + "+".join(["x"] * 4000) + '"'), {}),
        ("lone surrogate in the description", TINY + 'description: "bad \\ud800 text"\n', {}),
        ("expression nested 500 deep", inline(potential='"' + "(" * 500 + "x" + ")" * 500 + '"'), {}),
        ("100 coordinates", TINY.replace("system: cart_pendulum", "system: sys.yaml"),
         {"sys.yaml": SYSTEM.replace("coordinates: [x]", "coordinates: [" + ", ".join(f"x{i}" for i in range(100)) + "]")}),
        ("20000 step sizes", TINY.replace("h: [3.2e-2, 1.0e-2]", "h: [" + ", ".join(f"{1e-3 * (1 + i * 1e-5):.10g}" for i in range(20000)) + "]"), {}),
        ("max_iter: 0", TINY + "tolerances: {max_iter: 0}\n", {}),
        ("duplicate key in the config", TINY + "T: 1.0\n", {}),
        ("binary (non-UTF-8) config", None, {}),
        ("config of 5 MB", TINY + "description: '" + "x" * 5_000_000 + "'\n", {}),
    ]
    return cases


def run_config_section(tmp: Path) -> None:
    print("config: hostile sweep configs and system files", flush=True)
    for i, (name, text, files) in enumerate(config_cases()):
        d = tmp / f"cfg{i}"
        d.mkdir()
        cfg = d / "c.yaml"
        if text is None:
            cfg.write_bytes(b"\xff\xfe\x00name: x\n\x80\x81")
        else:
            cfg.write_text(text, encoding="utf-8")
        for fn, body in files.items():
            (d / fn).write_text(body, encoding="utf-8")
        before = listing(d)
        for cmd in ("validate", "sweep"):
            args = [cmd, cfg] + (["--output", d / "out" / "r.h5", "--workers", "1", "-q"] if cmd == "sweep" else [])
            rc, out, err, sec = vcirun(*args, cwd=d, timeout=240)
            left = sorted(listing(d) - before)
            outcome, detail = classify_error(rc, out, err, left=left)
            record("config", f"{name} [{cmd}]", outcome, detail, sec)
    # special files
    d = tmp / "cfg_special"
    d.mkdir()
    fifo = d / "fifo.yaml"
    with_fifo = hasattr(os, "mkfifo")
    if with_fifo:
        os.mkfifo(fifo)
        rc, out, err, sec = vcirun("validate", fifo, cwd=d, timeout=60)
        record("config", "config is a FIFO [validate]", *classify_error(rc, out, err), sec)
    rc, out, err, sec = vcirun("validate", d, cwd=d, timeout=60)
    record("config", "config is a directory [validate]", *classify_error(rc, out, err), sec)
    # the system file named by a config is a FIFO or a directory (never blocks, says what it is)
    (d / "uses_sys.yaml").write_text(TINY.replace("system: cart_pendulum", "system: special_sys.yaml"))
    kinds = ([("FIFO", lambda p: os.mkfifo(p))] if with_fifo else []) + [("directory", lambda p: p.mkdir())]
    for kind, make in kinds:
        sp_ = d / "special_sys.yaml"
        make(sp_)
        for cmd in ("validate", "sweep"):
            args = [cmd, d / "uses_sys.yaml"] + (["--output", d / "sp_out.h5", "--workers", "1", "-q"] if cmd == "sweep" else [])
            rc, out, err, sec = vcirun(*args, cwd=d, timeout=60)
            outcome, detail = classify_error(rc, out, err, left=[p for p in [d / "sp_out.h5"] if p.exists()])
            if outcome == "ok" and "not found" in detail:
                outcome, detail = "bad_message", "says 'not found' for a " + kind + ": " + detail
            record("config", f"system file is a {kind} [{cmd}]", outcome, detail, sec)
        sp_.rmdir() if sp_.is_dir() else sp_.unlink()
    # positive controls: parsed like configs, so these must work
    (d / "sys.yaml").write_text(SYSTEM.replace("{k: 4.0}", "{k: 4.0, c: 1e-3}"))
    (d / "ok.yaml").write_text(TINY.replace("system: cart_pendulum", "system: sys.yaml").replace("beta: {start: 3.2, stop: 5.2, num: 3}\n", "")
                               + 'description: "a NUL \\0 inside"\n')
    rc, out, err, sec = vcirun("sweep", d / "ok.yaml", "--output", d / "ok.h5", "--workers", "1", "-q", cwd=d, timeout=300)
    ok = rc == 0 and "Traceback" not in err
    if ok:
        import h5py

        with h5py.File(d / "ok.h5", "r") as f:
            ok = len(f["runs"]) == 4
    record("config", "control: system file with 1e-3, description with a NUL [sweep]",
           "ok" if ok else ("traceback" if "Traceback" in err else "bad_message"), err.strip()[-200:] or "4 runs stored", sec)


# --- API ----------------------------------------------------------------------------------------------------
API_SCRIPT = r'''
import json, math, signal, sys, time
import numpy as np
import vcirun

class Hang(Exception):
    pass

def on_alarm(signum, frame):
    raise Hang()

signal.signal(signal.SIGALRM, on_alarm)
nan, inf = float("nan"), float("inf")
base = dict(h=0.01, T=1.0, beta=3.2)
cases = []
def sim(name, expect="error", system="cart_pendulum", method="CVA", **kw):
    cases.append(("simulate", name, expect, system, method, kw))
def ref(name, expect="error", system="cart_pendulum", **kw):
    cases.append(("reference", name, expect, system, None, kw))

for k, v in [("max_iter", 0), ("max_iter", -1), ("max_iter", 2.5), ("t0", nan), ("t0", inf), ("newton_tol", 0),
             ("newton_tol", nan), ("newton_tol", -1), ("event_tol", 0), ("max_impacts_step", 0), ("max_impacts_step", -1),
             ("constrained", "no"), ("h", None), ("h", 1j), ("h", np.array([0.01, 0.02])), ("h", "0.01"), ("h", 1e-320),
             ("h", 1e-300), ("h", -0.01), ("T", nan), ("T", 0), ("beta", inf), ("energies", "yes"),
             ("params", {"m1": nan}), ("params", {"m1": True}), ("params", "m1=2")]:
    sim(f"{k}={v!r}", **{**base, k: v})
sim("q0=[nan, 0]", h=0.01, T=1.0, q0=[nan, 0.0], p0=[0.0, 0.0])
sim("resting_contact='no'", h=0.01, T=1.0, beta=3.2, resting_contact="no")
sim("beta and q0/p0 both", h=0.01, T=1.0, beta=3.2, q0=[0.1, 0.2], p0=[0.0, 0.0])
ref("resting_contact='no'", T=1.0, beta=3.2, resting_contact="no")
ref("beta and q0/p0 both", T=1.0, beta=3.2, q0=[0.1, 0.2], p0=[0.0, 0.0])
sim("q0 2-D", h=0.01, T=1.0, q0=[[0.1, 0.2]], p0=[0.0, 0.0])
sim("p0 of strings", h=0.01, T=1.0, q0=[0.1, 0.2], p0=["a", "b"])
sim("T=1e9, h=1e-6", h=1e-6, T=1e9, beta=3.2)
sim("T=1e4, h=1e-6", h=1e-6, T=1e4, beta=3.2)
sim("q0=1e300 (oscillator_wall)", expect="not_ok", system="oscillator_wall", h=0.01, T=1.0, q0=[1e300], p0=[0.0])
sim("beta=1e300", expect="not_ok", method="MCVAC", h=0.01, T=1.0, beta=1e300)
sim("p0=1e200 (oscillator_wall)", expect="not_ok", system="oscillator_wall", h=0.01, T=1.0, q0=[0.1], p0=[1e200])
sim("control: a normal run", expect="ok", h=0.01, T=1.0, beta=3.2)
ref("T=0", T=0, beta=3.2)
ref("T=inf", T=inf, beta=3.2)
ref("T=nan", T=nan, beta=3.2)
ref("rtol=0", T=1.0, beta=3.2, rtol=0)
ref("rtol=nan", T=1.0, beta=3.2, rtol=nan)
ref("rtol=-1", T=1.0, beta=3.2, rtol=-1)
ref("rtol=0.5", T=1.0, beta=3.2, rtol=0.5)
ref("method reference h=0", T=1.0, beta=3.2, method="CVA", h=0)
ref("beta=1e20 (steps collapse)", T=1.0, beta=1e20)
ref("T=1e6", T=1e6, beta=3.2)
ref("control: exact reference", expect="ok", T=0.5, beta=3.2, rtol=1e-10)

def user_system(pname):
    import sympy as sp
    from vcirun.mechanics.system import MechanicalSystem
    x = sp.Symbol("x"); k = sp.Symbol(pname)
    return MechanicalSystem(name="u", q=[x], params={pname: 4.0}, M=sp.Matrix([[1]]), V=k * x**2 / 2, phi=x + 1,
                            default_q0=np.array([0.2]), default_p0=np.array([0.0]))

out = []
for kind, name, expect, system, method, kw in cases:
    t0 = time.time()
    signal.alarm(60)
    try:
        if kind == "simulate":
            tr = vcirun.simulate(system, method, **kw)
            finite = bool(np.all(np.isfinite(tr.q)) and np.all(np.isfinite(tr.H)))
            res = ("status", tr.status, finite, tr.message[:200])
        else:
            r = vcirun.reference(system, **kw)
            res = ("status", "ok", bool(np.all(np.isfinite(r(np.linspace(0, kw["T"], 11))))), "")
    except Hang:
        res = ("hang", "", False, "")
    except ValueError as e:
        res = ("ValueError", "", False, str(e))
    except BaseException as e:
        res = ("exception", type(e).__name__, False, str(e)[:200])
    finally:
        signal.alarm(0)
    out.append({"kind": kind, "name": name, "expect": expect, "result": res, "seconds": time.time() - t0})
    print(json.dumps(out[-1]), flush=True)
# a MechanicalSystem built in Python with a full-width parameter
for pname in ("ｋ", "vcTQ0"):
    t0 = time.time()
    try:
        tr = vcirun.simulate(user_system(pname), "CVA", h=0.01, T=0.1)
        res = ("status", tr.status, True, "")
    except ValueError as e:
        res = ("ValueError", "", False, str(e))
    except BaseException as e:
        res = ("exception", type(e).__name__, False, str(e)[:200])
    print(json.dumps({"kind": "simulate", "name": f"MechanicalSystem with parameter {pname!r}", "expect": "error",
                      "result": res, "seconds": time.time() - t0}), flush=True)
'''


def run_api_section(tmp: Path) -> None:
    print("api: hostile arguments to simulate and reference", flush=True)
    script = tmp / "api_probe.py"
    script.write_text(API_SCRIPT)
    t0 = time.monotonic()
    p = subprocess.run([PY, str(script)], env=ENV, capture_output=True, text=True, timeout=1800)
    if p.returncode != 0:
        record("api", "probe process", "segfault" if p.returncode < 0 else "traceback", p.stderr[-300:],
               time.monotonic() - t0)
    for line in p.stdout.splitlines():
        try:
            r = json.loads(line)
        except ValueError:
            continue
        kind, status, finite, msg = r["result"]
        name = f"{r['kind']}({r['name']})"
        if kind == "hang":
            outcome, detail = "hang", "no answer within 60 s"
        elif kind == "exception":
            outcome, detail = "traceback", f"{status}: {msg}"
        elif r["expect"] == "error":
            if kind == "ValueError":
                outcome, detail = ("ok", msg) if "\n" not in msg and ":" in msg else ("bad_message", msg)
            else:
                outcome, detail = "wrong_ok", f"returned status {status} (finite: {finite})"
        elif r["expect"] == "not_ok":
            outcome, detail = (("ok", f"status {status}: {msg}") if kind == "status" and status != "ok"
                               else ("ok", msg) if kind == "ValueError" else ("wrong_ok", f"status {status}"))
        else:  # a control that must work
            outcome = "ok" if kind == "status" and status == "ok" and finite else "bad_message"
            detail = f"status {status}" if kind == "status" else msg
        record("api", name, outcome, detail, r["seconds"])


# --- output paths ----------------------------------------------------------------------------------------------
def run_output_section(tmp: Path) -> None:
    print("output: unusable output paths", flush=True)
    d = tmp / "out"
    d.mkdir()
    cfg = d / "tiny.yaml"
    cfg.write_text(TINY)
    sweep = lambda out, *extra, wrap=None: vcirun("sweep", cfg, "--output", out, "--workers", "1", "-q", *extra,  # noqa: E731
                                                   cwd=d, wrap=wrap)
    (d / "afile").write_text("x")
    (d / "adir").mkdir()
    before = listing(d)
    for name, out in [("parent is a file", d / "afile" / "r.h5"), ("output is a directory", d / "adir"),
                      ("output is /dev/null", Path("/dev/null"))]:
        rc, o, e, s = sweep(out)
        record("output", name, *classify_error(rc, o, e, left=sorted(listing(d) - before)), s)
    # read-only directory (a read-only bind mount; chmod does not stop root)
    ro = d / "ro"
    ro.mkdir()
    wrap = _mount_wrap(f"mount --bind {ro} {ro} && mount -o remount,bind,ro {ro}")
    if wrap:
        for name, out in [("read-only directory", ro / "r.h5"), ("read-only parent of a new directory", ro / "sub" / "r.h5")]:
            rc, o, e, s = vcirun("sweep", cfg, "--output", out, "--workers", "1", "-q", cwd=d, wrap=wrap)
            record("output", name, *classify_error(rc, o, e), s)
    else:
        record("output", "read-only directory", "skipped", "unshare --mount not available")
    # symlinks: written through (the link keeps pointing at the results)
    (d / "real").mkdir()
    link = d / "link.h5"
    link.symlink_to(d / "real" / "target.h5")
    rc, o, e, s = sweep(link)
    rc2, o2, e2, s2 = sweep(link, "--force")
    import h5py

    good = (rc == 0 and rc2 == 0 and link.is_symlink() and (d / "real" / "target.h5").is_file()
            and len(h5py.File(link, "r")["runs"]) == 12)
    record("output", "output is a symlink (written through, twice)", "ok" if good else "bad_message",
           f"rc {rc}/{rc2}; link kept: {link.is_symlink()}", s + s2)
    dangling = d / "dangling.h5"
    dangling.symlink_to("/nonexistent-vcirun-probe/x.h5")
    rc, o, e, s = sweep(dangling)
    record("output", "dangling symlink into a missing directory", *classify_error(rc, o, e), s)
    (d / "loop1").symlink_to(d / "loop2")
    (d / "loop2").symlink_to(d / "loop1")
    rc, o, e, s = sweep(d / "loop1")
    record("output", "symlink loop", *classify_error(rc, o, e), s)
    # a second writer on the same file
    slow = d / "slow.yaml"
    slow.write_text(TINY.replace("num: 3", "num: 40").replace("T: 0.5", "T: 5"))
    p = subprocess.Popen([PY, "-m", "vcirun.cli.main", "sweep", str(slow), "--output", str(d / "two.h5"), "--workers", "1"],
                         cwd=d, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not (d / ".two.h5.lock").exists() and time.monotonic() < deadline:
        time.sleep(0.2)
    rc, o, e, s = vcirun("sweep", slow, "--output", d / "two.h5", "--workers", "1", "-q", cwd=d)
    record("output", "second sweep on a file being written", *classify_error(rc, o, e), s)
    p.kill()
    p.wait()


def _unshare_prefix():
    """`unshare --mount` (root) or with a user namespace, if this machine lets us mount a tmpfs in it."""
    if not shutil.which("unshare"):
        return None
    for prefix in (["unshare", "--mount"], ["unshare", "--user", "--map-root-user", "--mount"]):
        p = subprocess.run(prefix + ["sh", "-c", "mount -t tmpfs -o size=16k tmpfs /mnt"], capture_output=True)
        if p.returncode == 0:
            return prefix
    return None


UNSHARE = _unshare_prefix()


def _mount_wrap(setup: str):
    """A command prefix running a command string in a private mount namespace after `setup`."""
    if UNSHARE is None:
        return None
    return UNSHARE + ["sh", "-c", f"{setup} && exec sh -c \"$1\"", "sh"]


# --- corrupted results files -------------------------------------------------------------------------------------
def _good_file(d: Path) -> Path:
    cfg = d / "tiny.yaml"
    cfg.write_text(TINY)
    out = d / "good.h5"
    rc, o, e, s = vcirun("sweep", cfg, "--output", out, "--workers", "1", "-q", cwd=d)
    if rc != 0:
        raise RuntimeError(f"could not make the probe's results file: {e}")
    return out


def corruptions(good: Path, d: Path) -> list[tuple[str, Path]]:
    import h5py
    import numpy as np

    data = good.read_bytes()
    out = []

    def variant(name, fn):
        p = d / (re.sub(r"\W+", "_", name) + ".h5")
        shutil.copyfile(good, p)
        fn(p)
        out.append((name, p))

    rng = random.Random(22)
    for k in range(4):
        def blocks(p, seed=k):
            r = random.Random(seed)
            b = bytearray(p.read_bytes())
            for _ in range(8):
                at = r.randrange(0, len(b) - 4096)
                b[at:at + 4096] = bytes(r.randrange(256) for _ in range(4096))
            p.write_bytes(bytes(b))
        variant(f"random 4 kB blocks (seed {k})", blocks)
    for at in (64, 200, 1000, len(data) // 3):
        def flip(p, at=at):
            b = bytearray(p.read_bytes())
            b[at] ^= 0xFF
            p.write_bytes(bytes(b))
        variant(f"one byte flipped at offset {at} (metadata checksum)", flip)
    variant("truncated to half", lambda p: p.write_bytes(data[: len(data) // 2]))
    variant("zero bytes", lambda p: p.write_bytes(b""))
    variant("text file", lambda p: p.write_text("not an HDF5 file\n"))

    def h5edit(fn):
        def go(p):
            with h5py.File(p, "a") as f:
                fn(f)
        return go

    def runs_dataset(f):
        del f["runs"]
        f["runs"] = np.arange(3)
    variant("runs is a dataset, not a group", h5edit(runs_dataset))
    variant("history attribute not JSON", h5edit(lambda f: f.attrs.__setitem__("history", "{not json")))
    variant("tolerances and ic_keys not JSON", h5edit(lambda f: (f.attrs.__setitem__("tolerances", "x["),
                                                                   f.attrs.__setitem__("ic_keys", "]"))))
    first = sorted(h5py.File(good, "r")["runs"])[0]
    variant("a run's h is text", h5edit(lambda f: f["runs"][first].attrs.__setitem__("h", "fast")))
    variant("a run's status is a number", h5edit(lambda f: f["runs"][first].attrs.__setitem__("status", 3)))
    variant("a run's options attribute is not JSON", h5edit(lambda f: f["runs"][first].attrs.__setitem__("options", "{")))

    def drop_q(f):
        for g in f["runs"].values():
            del g["q"]
    variant("every run lost its q dataset", h5edit(drop_q))

    def bad_shape(f):
        g = f["runs"][first]
        del g["q"]
        g["q"] = np.zeros((0, 2))
    variant("a run's q has the wrong shape", h5edit(bad_shape))
    variant("references group missing", h5edit(lambda f: f.__delitem__("references")))
    variant("runs group missing", h5edit(lambda f: f.__delitem__("runs")))

    def ref_bad(f):
        g = next(iter(f["references"].values()))
        del g["q"]
    variant("a reference lost its q dataset", h5edit(ref_bad))
    return out


def run_corrupt_section(tmp: Path) -> None:
    print("corrupt: damaged results files", flush=True)
    import h5py

    from vcirun.io.checks import run_problem
    from vcirun.io.reader import load_trajectory, read_results

    d = tmp / "corrupt"
    d.mkdir()
    good = _good_file(d)
    expected = {r.run_id for r in read_results(good).runs}
    for name, path in corruptions(good, d):
        for cmd in ("info", "plot"):
            args = [cmd, path] + (["--out", d / "fig" / path.stem] if cmd == "plot" else [])
            rc, o, e, s = vcirun(*args, cwd=d, timeout=180)
            if rc == 0 and "Traceback" not in e:
                outcome, detail = "ok", "read what is readable (" + (o.strip().splitlines() or [""])[0][:80] + ")"
            else:
                outcome, detail = classify_error(rc, o, e)
            record("corrupt", f"{name} [{cmd}]", outcome, detail, s)
        rc, o, e, s = vcirun("sweep", d / "tiny.yaml", "--output", path, "--workers", "1", "-q", cwd=d, timeout=300)
        if rc == 0 and "Traceback" not in e:
            # a resume must leave every run verified and present, each exactly once
            try:
                res = read_results(path)
                with h5py.File(path, "r") as f:
                    problems = [run_problem(g) for g in f["runs"].values()]
                    nref = len(f["references"])
                good_runs = {r.run_id for r in res.runs} == expected and not any(problems) and nref == 3
                for r in res.runs:
                    load_trajectory(path, r.run_id)
                outcome = "ok" if good_runs else "wrong_ok"
                detail = f"resumed: {len(res.runs)} runs, {nref} references, problems {sum(map(bool, problems))}"
            except Exception as ex:  # noqa: BLE001
                outcome, detail = "wrong_ok", f"resumed but unreadable: {type(ex).__name__}: {ex}"
        else:
            outcome, detail = classify_error(rc, o, e)
        record("corrupt", f"{name} [sweep resume]", outcome, detail, s)
    # not a file at all, and a --out that cannot be a folder (nothing may be left behind)
    if hasattr(os, "mkfifo"):
        fifo = d / "fifo.h5"
        os.mkfifo(fifo)
        for cmd in ("info", "plot"):
            rc, o, e, s = vcirun(cmd, fifo, cwd=d, timeout=60)
            record("corrupt", f"results file is a FIFO [{cmd}]", *classify_error(rc, o, e), s)
    (d / "afile").write_text("x")
    before = listing(d)
    for name, out in [("--out under a file", d / "afile" / "figs"), ("--out is a file", d / "afile")]:
        rc, o, e, s = vcirun("plot", good, "--out", out, cwd=d, timeout=120)
        outcome, detail = classify_error(rc, o, e, left=sorted(listing(d) - before))
        if outcome == "ok" and "--out" not in detail:
            outcome, detail = "bad_message", "does not name --out: " + detail
        record("corrupt", f"plot {name}", outcome, detail, s)
    (d / "text.h5").write_text("not HDF5\n")
    before = listing(d)
    rc, o, e, s = vcirun("plot", d / "text.h5", "--out", d / "newfig" / "a", cwd=d, timeout=120)
    record("corrupt", "plot of a damaged file into a new --out [nothing left]",
           *classify_error(rc, o, e, left=sorted(listing(d) - before)), s)


# --- disk full ----------------------------------------------------------------------------------------------------
NOCHECK = """\
import sys
from vcirun.experiments import sweep
from vcirun.io.writer import ResultsWriter
sweep._check_resources = lambda *a, **k: None           # the sweep's disk estimate off, and the writer's
ResultsWriter._space_needed = lambda self, j: 0          # free-space check: meet ENOSPC in the writes
from vcirun.cli.main import app
sys.argv = ["vcirun"] + sys.argv[1:]
app()
"""


def run_disk_section(tmp: Path, quick: bool) -> None:
    print("disk: a full disk (tmpfs)", flush=True)
    mnt = tmp / "mnt"
    mnt.mkdir()
    if _mount_wrap(f"mount -t tmpfs -o size=1m tmpfs {mnt}") is None:
        record("disk", "tmpfs", "skipped", "unshare --mount / mount -t tmpfs not available here")
        return
    nocheck = tmp / "nocheck_cli.py"
    nocheck.write_text(NOCHECK)
    cfg = ROOT / "configs" / "fig4.yaml"
    sizes = ["2m"] if quick else ["1m", "2m", "6m"]
    for checked in (True, False):
        # 20m: room for the journal but not for the final copy (ENOSPC inside the HDF5 rewrite)
        for size in sizes + ["12k"] + ([] if checked else ["20m"]):
            out = mnt / "fig4.h5"
            py = f"{_q(PY)} {_q(nocheck)}" if not checked else f"{_q(PY)} -m vcirun.cli.main"
            errfile = tmp / "disk_err.txt"
            inner = (f"mount -t tmpfs -o size={size} tmpfs {mnt} && {py} sweep {cfg} --output {out} -q --workers 2 "
                     f"2>{errfile}; echo RC=$?; ls -a {mnt}; "
                     f"{_q(PY)} -c 'import h5py,sys; f=h5py.File(sys.argv[1],\"r\"); print(\"H5RUNS=%d\" % len(f[\"runs\"]))' "
                     f"{out} 2>/dev/null")
            t0 = time.monotonic()
            p = subprocess.run(UNSHARE + ["sh", "-c", inner], env=ENV, capture_output=True, text=True,
                               timeout=900, cwd=tmp)
            sec = time.monotonic() - t0
            m = re.search(r"RC=(\d+)", p.stdout)
            rc = int(m.group(1)) if m else None
            left = [ln for ln in p.stdout.splitlines() if ln.endswith(".partial")]
            err = errfile.read_text() if errfile.exists() else p.stderr
            outcome, detail = classify_error(rc, "", err, left=left)
            label = f"fig4 on a {size} tmpfs" + ("" if checked else " (free-space checks off: ENOSPC in the writes)")
            record("disk", label, outcome, detail, sec)
    # resume after the disk is enlarged: every committed run kept, the sweep completes
    out = mnt / "fig4.h5"
    inner = (f"mount -t tmpfs -o size=2m tmpfs {mnt} && {_q(PY)} {_q(nocheck)} sweep {cfg} --output {out} -q 2>/dev/null; "
             f"{_q(PY)} -c 'from vcirun.io.reader import read_results; print(\"SAVED=%d\" % len(read_results(\"{out}\").runs))'; "
             f"mount -o remount,size=64m {mnt} && {_q(PY)} -m vcirun.cli.main sweep {cfg} --output {out} -q; echo RC=$?; "
             f"{_q(PY)} -c 'import h5py; f=h5py.File(\"{out}\",\"r\"); print(\"FINAL=%d\" % len(f[\"runs\"]))'")
    t0 = time.monotonic()
    p = subprocess.run(UNSHARE + ["sh", "-c", inner], env=ENV, capture_output=True, text=True,
                       timeout=1800, cwd=tmp)
    saved = re.search(r"SAVED=(\d+)", p.stdout)
    final = re.search(r"FINAL=(\d+)", p.stdout)
    rc = re.search(r"RC=(\d+)", p.stdout)
    good = saved and final and rc and rc.group(1) == "0" and int(final.group(1)) == 408 and "Traceback" not in p.stderr
    record("disk", "disk full at 2 MB, then enlarged: resume completes", "ok" if good else "lost",
           f"committed before: {saved.group(1) if saved else '?'}; after resume: {final.group(1) if final else '?'} of 408",
           time.monotonic() - t0)


# --- kills ------------------------------------------------------------------------------------------------------------
KILL_CFG = """\
name: kill
system: cart_pendulum
methods: [CVA, VCI, MCVAC]
h: [3.2e-2, 1.0e-2]
beta: {start: 3.2, stop: 5.2, num: 20}
T: 5
reference: {kind: exact, rtol: 1.0e-10}
timing_repeats: 1
"""


class Progress:
    """A sweep subprocess whose progress lines (`[done/total] ...; S saved`) are timestamped."""

    def __init__(self, cfg: Path, out: Path, workers: int, extra=()):
        self.t0 = time.monotonic()
        self.proc = subprocess.Popen([PY, "-m", "vcirun.cli.main", "sweep", str(cfg), "--output", str(out), "--workers",
                                      str(workers), *extra], env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, cwd=cfg.parent)
        self.points: list[tuple[float, int, int]] = []  # (seconds, runs the client has, runs saved)
        self.err: list[str] = []
        threading.Thread(target=self._pump, daemon=True).start()

    def _pump(self):
        for line in self.proc.stderr:
            self.err.append(line)
            m = re.match(r"\[(\d+)/(\d+)\].*; (\d+) saved", line)
            if m:
                self.points.append((time.monotonic() - self.t0, int(m.group(1)), int(m.group(3))))

    def first_line(self, timeout: float = 600) -> float:
        """Seconds until the first run reached the client (the sweep's start-up is over)."""
        deadline = time.monotonic() + timeout
        while not self.points and self.proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        return self.points[0][0] if self.points else time.monotonic() - self.t0

    def wait(self, timeout: float = 1800) -> float:
        self.proc.wait(timeout=timeout)
        time.sleep(0.3)
        return time.monotonic() - self.t0

    def kill_at(self, seconds: float) -> float:
        while time.monotonic() - self.t0 < seconds and self.proc.poll() is None:
            time.sleep(0.01)
        t = time.monotonic() - self.t0
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait()
        time.sleep(0.3)  # the reader thread drains the last lines
        return t


def run_kill_section(tmp: Path, quick: bool) -> None:
    print("kill: SIGKILL at random moments, then resume", flush=True)
    import h5py
    import numpy as np

    from vcirun.io.reader import load_trajectory, read_results

    d = tmp / "kill"
    d.mkdir()
    cfg = d / "kill.yaml"
    cfg.write_text(KILL_CFG)
    ref = d / "uninterrupted.h5"
    p = Progress(cfg, ref, 2)
    duration = p.wait() - p.first_line()  # the sweep's run phase (after start-up)
    if p.proc.returncode != 0:
        record("kill", "uninterrupted sweep", "traceback", "".join(p.err)[-300:], duration)
        return
    ref_runs = {r.run_id: r for r in read_results(ref).runs}
    rng = random.Random(2222)
    trials = 3 if quick else 8
    for k in range(trials):
        out = d / f"k{k}.h5"
        workers = 1 + k % 2
        offset = rng.uniform(0.0, 0.9 * duration)  # a random moment of the run phase
        p = Progress(cfg, out, workers)
        t_kill = p.kill_at(p.first_line() + offset)
        saved = max((pt[2] for pt in p.points), default=0)
        try:
            with h5py.File(out, "r") as f:  # plain h5py
                h5_runs = len(f["runs"])
            now = len(read_results(out).runs)
        except FileNotFoundError:
            h5_runs = now = 0
        except Exception as ex:  # noqa: BLE001
            record("kill", f"SIGKILL at {t_kill:.1f} s ({workers} workers)", "lost", f"file unreadable: {ex}")
            continue
        rc, o, e, s = vcirun("sweep", cfg, "--output", out, "--workers", "2", "-q", cwd=d, timeout=900)
        final = read_results(out) if rc == 0 else None
        same = final is not None and {r.run_id for r in final.runs} == set(ref_runs)
        if same:  # every run bit for bit as the uninterrupted sweep's (wall times aside)
            for r in final.runs:
                a, b = load_trajectory(out, r.run_id), load_trajectory(ref, r.run_id)
                same &= all(np.array_equal(getattr(a, n), getattr(b, n)) for n in ("t", "q", "p", "H", "impacts"))
            with h5py.File(out, "r") as f:
                same &= len(f["runs"]) == len(ref_runs) and not (d / f".k{k}.h5.journal").exists()
        outcome = "ok" if (now >= saved and same and "Traceback" not in e) else ("lost" if now < saved else "wrong_ok")
        record("kill", f"SIGKILL at {t_kill:.1f} s ({workers} workers)", outcome,
               f"reported saved {saved}, committed after kill {now} ({h5_runs} in the HDF5 file, the rest in the "
               f"journal); resume identical to the uninterrupted sweep: {same}", s,
               saved=saved, committed=now, in_hdf5=h5_runs)


# --- the loss bound -------------------------------------------------------------------------------------------------
LOSS_CFG = """\
name: loss2000
system: cart_pendulum
methods: [CVA, VCI, MCVAA, MCVAC]
h: [3.2e-2, 1.0e-2]
beta: {start: 3.2, stop: 5.2, num: 250}
T: 40
reference: {kind: none}
timing_repeats: 1
store_trajectories: false
"""


def run_loss_section(tmp: Path, quick: bool) -> None:
    print("loss: SIGKILL during a 2000-run sweep", flush=True)
    from vcirun.io.reader import read_results

    d = tmp / "loss"
    d.mkdir()
    cfg = d / "loss.yaml"
    cfg.write_text(LOSS_CFG)
    rng = random.Random(2000)
    trials = 2 if quick else 6
    # the uninterrupted sweep first: its run phase bounds the kill times, its history the commit cost
    out = d / "complete.h5"
    p = Progress(cfg, out, 2)
    first = p.first_line()
    total = p.wait()
    last_run = p.points[-1][0] if p.points else total
    run_phase = max(2.0, last_run - first)
    ok = p.proc.returncode == 0
    record("loss", "the 2000-run sweep uninterrupted", "ok" if ok else "traceback",
           f"start-up {first:.1f} s, runs {run_phase:.1f} s ({2000 / run_phase:.0f} runs/s), final compaction "
           f"{total - last_run:.1f} s; file {out.stat().st_size / 2**20:.1f} MiB" if ok else "".join(p.err)[-200:],
           total, run_phase=round(run_phase, 2), startup=round(first, 2), compaction=round(total - last_run, 2))
    worst = 0.0
    for k in range(trials):
        out = d / f"l{k}.h5"
        p = Progress(cfg, out, 2)
        t_kill = p.kill_at(p.first_line() + rng.uniform(1.0, 0.9 * run_phase))
        pts = p.points
        if not pts:
            record("loss", f"kill at {t_kill:.1f} s", "skipped", "no progress line before the kill")
            continue
        have = pts[-1][1]                 # runs the client had received when it was killed
        committed = len(read_results(out).runs)
        lost = max(0, have - committed)
        # the sweep's own rate over the second before the kill, and when the client had `committed` runs
        t_c = next((t for t, n, _ in pts if n >= committed), pts[-1][0]) if committed else pts[0][0]
        window = [pt for pt in pts if pt[0] >= t_kill - 5.0]
        rate = (window[-1][1] - window[0][1]) / max(1e-9, window[-1][0] - window[0][0]) if len(window) > 1 else float("nan")
        lost_s = t_kill - t_c if lost else 0.0
        worst = max(worst, lost_s)
        outcome = "ok" if lost_s <= 3.0 else "lost"
        record("loss", f"kill at {t_kill:.1f} s", outcome,
               f"client had {have} runs, {committed} committed: {lost} lost = the runs of the last {lost_s:.2f} s "
               f"(rate {rate:.0f} runs/s)", numbers_lost=lost, seconds_lost=round(lost_s, 3), rate=round(rate, 1),
               have=have, committed=committed, t_kill=round(t_kill, 2))


# --- report --------------------------------------------------------------------------------------------------------
OUTCOMES = ["ok", "segfault", "traceback", "hang", "wrong_ok", "lost", "bad_message", "skipped"]


def render(cases: list[Case], meta: dict) -> str:
    sections = sorted({c.section for c in cases}, key=lambda s: ["config", "api", "output", "corrupt", "disk", "kill",
                                                                 "loss"].index(s) if s in ["config", "api", "output",
                                                                                           "corrupt", "disk", "kill",
                                                                                           "loss"] else 99)
    rows = ["| section | cases | " + " | ".join(OUTCOMES) + " |", "|---|---:|" + "---:|" * len(OUTCOMES)]
    for s in sections + ["all"]:
        cs = [c for c in cases if c.section == s or s == "all"]
        counts = [sum(c.outcome == o for c in cs) for o in OUTCOMES]
        label = f"**{s}**" if s == "all" else s
        rows.append(f"| {label} | {len(cs)} | " + " | ".join(str(n) for n in counts) + " |")
    bad = [c for c in cases if c.outcome not in ("ok", "skipped")]
    loss = [c for c in cases if c.section == "loss" and "seconds_lost" in c.numbers]
    table = "\n".join(rows) + "\n"
    secs = meta.get("sections", {})
    if secs:
        table += ("\nWhen each section was run (the probe runs sections separately with `--only`; the load is the "
                 "1-minute load average of the machine, shared with other work, at the section's start and end):"
                 "\n\n| section | finished at | seconds | load at start / end | mode |\n|---|---|---:|---|---|\n")
        for s in sections:
            m = secs.get(s)
            if m:
                table += (f"| {s} | {m['date']} | {m['seconds']:.0f} | {m['load'][0]:.2f} / {m['load'][1]:.2f} | "
                         f"{'--quick' if m.get('quick') else 'full'} |\n")
    text = TEMPLATE.format(machine=meta["machine"], table=table.rstrip("\n"))
    if loss:
        import yaml

        lc = yaml.safe_load(LOSS_CFG)
        interval = str(secs.get("loss", {}).get("commit_interval", "1 (the default)"))
        ci = float(interval.split()[0]) if interval.split() and interval.split()[0].replace(".", "", 1).isdigit() else 1.0
        interval = interval.replace(" (the default)", " s (the default)") if "default" in interval else interval + " s"
        whole = next((c for c in cases if c.section == "loss" and "run_phase" in c.numbers), None)
        text += ("\n### The loss bound, measured\n\nSIGKILL at a random moment of the run phase of a 2000-run sweep "
                 f"(`{lc['system']}`, {' '.join(lc['methods'])} x {len(lc['h'])} steps x {lc['beta']['num']} betas, "
                 f"T = {lc['T']}, no trajectories stored, 2 workers, commit_interval = {interval}). "
                 "`lost` = runs the client had received (its last progress line) minus the runs committed (read back "
                 "with `vcirun.io.reader.read_results` after the kill); `= the runs of the last` = the kill time minus the "
                 "moment the client had received as many runs as were committed; the rate is the client's over the "
                 "5 s before the kill.")
        if whole:
            n = whole.numbers
            text += (f" The uninterrupted sweep: start-up {n['startup']:.1f} s, run phase {n['run_phase']:.1f} s "
                     f"({2000 / n['run_phase']:.0f} runs/s on average), final compaction {n['compaction']:.1f} s.")
        text += ("\n\n| killed at | runs the client had | committed | lost | = the runs of the last | sweep rate | "
                 "rate x commit_interval |\n|---:|---:|---:|---:|---:|---:|---:|\n")
        for c in loss:
            n = c.numbers
            text += (f"| {n['t_kill']:.1f} s | {n['have']} | {n['committed']} | {n['numbers_lost']} | "
                     f"{n['seconds_lost']:.2f} s | {n['rate']:.0f} runs/s | {n['rate'] * ci:.0f} runs |\n")
        worst = max(c.numbers["seconds_lost"] for c in loss)
        most = max(c.numbers["numbers_lost"] for c in loss)
        text += (f"\nWorst case over {len(loss)} kills: {most} runs lost; the longest span lost was {worst:.2f} s "
                 f"of the sweep's output, against the stated bound of commit_interval ({ci:g} s) plus one commit "
                 "(a case counts `ok` up to 3 s).\n")
    text += "\n### Every case\n\n| section | case | outcome | detail |\n|---|---|---|---|\n"
    for c in sorted(cases, key=lambda c: sections.index(c.section)):
        detail = c.detail.replace("|", "\\|")
        text += f"| {c.section} | {c.name.replace('|', '/')} | {c.outcome} | {detail[:160]} |\n"
    if bad:
        text += "\nCases not `ok`: " + "; ".join(f"{c.section}/{c.name} ({c.outcome})" for c in bad) + "\n"
    return text


TEMPLATE = """# Reliability under hostile and broken input

Counts from `bench/reliability_probe.py` (`.venv/bin/python bench/reliability_probe.py [--only SECTION]`;
the table below is regenerated from `results/reliability.json` each time), on {machine}. Each case is a real `vcirun` command or API call on hostile input or under an
injected fault; outcomes: `ok` = the expected behaviour (a one-line `error:` naming the field or the
file and a non-zero exit, no traceback, no new file left behind; or, for controls and resumes, a
correct complete result), `segfault`, `traceback`, `hang` (no answer within the case's timeout),
`wrong_ok` (reported ok with a wrong or non-finite result), `lost` (committed runs missing after a
fault), `bad_message` (non-zero exit without exactly one `error:` line, or files left behind).

{table}

## What the guarantees are, and how they are kept

- **Bounded loss at a constant commit cost.** A commit appends the finished runs to a journal beside
  the results file (`.NAME.h5.journal`: records framed by magic, length and CRC-32, fsynced) every
  `commit_interval` seconds (default 1 s; `VCIRUN_COMMIT_INTERVAL`, or `run_sweep(commit_interval=...)`),
  also from a thread while the client waits, so a run that reaches the client is durable within
  commit_interval plus one commit. Pool workers send each run to the client as soon as it is
  computed (a task of many runs is not held back). A SIGKILL at any moment therefore loses at most
  the runs that reached the client in the last commit_interval (plus the runs still being computed).
  When the sweep ends (or is interrupted) the queued runs are appended to the journal before
  anything waits for a background compaction round (a round copies the whole file and takes
  seconds; no run waits out that round uncommitted).
  A commit costs what the new runs weigh, independent of the file's size; the HDF5 file is never
  written in place: rewrites (copy, apply, fsync, atomic rename) happen when a session starts, in
  the background while it runs (a forked child folds the journal in, in rounds at least 10 s and 4
  round durations apart, and records how far in the root attribute `journal_applied`), and when it
  finishes (the tail). `read_results`, `vcirun info`/`plot` see journalled runs at once; plain h5py
  sees the runs of the last completed round, and all of them after the sweep ends or the next
  `vcirun sweep` of the config resumes. After any kill the HDF5 file opens with plain h5py; a torn
  journal tail (a kill inside an append) is ignored by CRC.
- **Resume verifies what it trusts.** A run group counts as stored only with `complete=True` and its
  datasets present with the shapes its attributes declare (`vcirun.io.checks.run_problem`, from the run record
  table: grid rows N+1, step rows N, impact rows m, partial steps K); references alike. Anything else
  is deleted and recomputed; lost `runs`/`references` groups are recreated, missing references
  recomputed (also when every run is stored).
- **Bounded inputs.** YAML (configs and system files alike: YAML 1.2 numbers, duplicate keys refused)
  is parsed with its aliases expanded under a cap (1,000,000 values, 20,000,000 characters; checked
  on the node graph before anything is built, so a billion-laughs document is refused in
  milliseconds), text under 4 MB; expressions under 10,000 characters and 5,000 nodes; at most 64
  coordinates (and constraints) and 1,024 parameters; h >= 1e-50, T / h <= 1e12 steps; the memory of
  a run (its loop buffers from T / h and n) and of the runs in flight (workers x (buffers + result
  message) + the client's copy) refused above the limit (`max_memory` in a config, `VCIRUN_MAX_MEMORY`,
  default half the physical memory) before anything is allocated or created; the disk space a
  sweep's results need (journal and final copy) checked against the free space before the file is
  created. A method reference is a run too: its grid (T / reference.h) and memory are checked
  alike. The exact reference's solver work is bounded: its right-hand-side evaluations are
  projected to T once 200,000 are spent and refused above 5e7 (an initial state so large that the
  solver's steps collapse, beta = 1e20, or T = 1e6), in a few seconds instead of hours.
- **Identifiers.** Python reads identifiers through NFKC normalisation, so a full-width `ｋ` in
  generated code is `k`. Parameter, coordinate, constraint and system names must be ASCII, and
  distinct after NFKC (also from the velocities `<coord>_dot` and the time `t`); expressions must be
  ASCII (the message names the character and its ASCII form). Names the generated kernels use for
  their own symbols are reserved (`hh`, `tt`, `qa<k>`, `va<k>`, `qb<k>`, `cse<k>`, `xm<k>`,
  `vcT...`, `mh_...`): a parameter named `vcTQ0` was read as coordinate 0 by the kernels.
- **The Python API validates like the config layer** (`vcirun.core.bounds`): `simulate` and `reference`
  raise one `ValueError` naming the argument (`max_iter: must be >= 1 (got 0)`); flags
  (`constrained`, `energies`, `resting_contact`, `check_accuracy`) must be booleans, and `beta`
  with `q0`/`p0` is refused (one of them would be ignored). A run whose initial
  energy is not finite (q0 = 1e300) ends with status `nonfinite` and its cause, not `ok`.
- **Faults of the file system** are one line naming the path: read-only directories, a parent that
  is a file, an output that is a directory or a device, symlink loops and links into missing
  directories (an output that is a symlink is written through: the link keeps pointing at the
  results), a second writer, a full disk. A failed journal append is cut back to its last complete
  record (a retry appends right after it). Every HDF5 rewrite first reserves its blocks
  (`posix_fallocate`), so a full disk usually fails before the HDF5 library runs, and the library
  itself runs in a forked child that holds none of the parent's descriptors: HDF5 after ENOSPC prints
  errors from deallocators and can crash; the child's crash is one line here (`the HDF5 library
  crashed (signal 11) while writing .NAME.h5.partial`), its partial copy is removed, nothing
  committed is lost and the same command resumes once there is space. Damaged results files given to
  `info`, `plot` or a resuming `sweep` end in one line, or are repaired by the resume where the
  damage is confined to groups. A results path that is a FIFO is refused (opening it blocked
  forever); `plot --out` creates its folder first, names `--out` when it cannot, and removes the
  folders it created when the plot fails.
- **Cost.** Reading a 2000-run file verifies every run's datasets (low-level HDF5 API): about 25 %
  more than reading its attributes alone. The HDF5 writes themselves (about 33 attributes and 13
  datasets per run) are done by the background compactor, not the client.
"""


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", help="sections to run (config api output corrupt disk kill loss)")
    ap.add_argument("--quick", action="store_true", help="fewer kill trials and tmpfs sizes")
    ap.add_argument("--json", default=str(ROOT / "results" / "reliability.json"))
    ap.add_argument("--doc", default=str(ROOT / "docs" / "reliability.md"))
    ap.add_argument("--render-only", action="store_true", help="rewrite the doc from the JSON, run nothing")
    args = ap.parse_args(argv)
    if args.render_only:
        prev = json.loads(Path(args.json).read_text())
        cases = [Case(**c) for c in prev["cases"]]
        Path(args.doc).write_text(render(cases, prev["meta"]))
        return 0 if all(c.outcome in ("ok", "skipped") for c in cases) else 1
    sections = args.only or ["config", "api", "output", "corrupt", "disk", "kill", "loss"]
    t0 = time.monotonic()
    section_meta = {}
    with tempfile.TemporaryDirectory(prefix="vcirun-probe-") as tmpd:
        tmp = Path(tmpd)
        for s in sections:
            ts, load0 = time.monotonic(), os.getloadavg()[0]
            fn = {"config": run_config_section, "api": run_api_section, "output": run_output_section,
                  "corrupt": run_corrupt_section}.get(s)
            if fn is not None:
                fn(tmp)
            elif s in ("disk", "kill", "loss"):
                {"disk": run_disk_section, "kill": run_kill_section, "loss": run_loss_section}[s](tmp, args.quick)
            section_meta[s] = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                               "seconds": round(time.monotonic() - ts, 1),
                               "load": [round(load0, 2), round(os.getloadavg()[0], 2)],
                               "quick": bool(args.quick),
                               "commit_interval": os.environ.get("VCIRUN_COMMIT_INTERVAL", "1 (the default)")}
    meta = {"date": time.strftime("%Y-%m-%d"), "machine": f"{os.cpu_count()} cores, Linux {os.uname().release}",
            "command": "`.venv/bin/python bench/reliability_probe.py" + (" --quick" if args.quick else "")
                       + (f" --only {' '.join(args.only)}" if args.only else "") + "`",
            "seconds": time.monotonic() - t0}
    out_json = Path(args.json)
    old = []
    if args.only and out_json.exists():  # keep the other sections' cases (and when they were run)
        prev = json.loads(out_json.read_text())
        old = [Case(**c) for c in prev["cases"] if c["section"] not in sections]
        kept = {c.section for c in old}
        section_meta = {**{k: v for k, v in prev["meta"].get("sections", {}).items() if k in kept}, **section_meta}
    meta["sections"] = section_meta
    cases = old + CASES
    out_json.parent.mkdir(parents=True, exist_ok=True)
    out_json.write_text(json.dumps({"meta": meta, "cases": [asdict(c) for c in cases]}, indent=1))
    Path(args.doc).write_text(render(cases, meta))
    counts = {o: sum(c.outcome == o for c in cases) for o in OUTCOMES}
    print(json.dumps(counts))
    return 0 if all(c.outcome in ("ok", "skipped") for c in cases) else 1


if __name__ == "__main__":
    sys.exit(main())
