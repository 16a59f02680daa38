"""Fault probe of the kernel cache: copies of one warm cache, each damaged one way, run through the CLI.

    .venv/bin/python bench/cache_fault_probe.py --template DIR [--seed N] [--only a,b] [--out FILE]

DIR is a warm cache holding the cart-pendulum's CVA and MCVAC kernels (the MCVAC module with C leaf
kernels: `vcirun simulate --method MCVAC --beta 3.2` on an empty VCIRUN_CACHE_DIR makes one). Each
case copies DIR, applies one fault (random offsets and sizes from --seed), runs `vcirun simulate`
(and where it applies a second time, or `vcirun cache info|clear`) and classifies the outcome:

  healed     exit 0 with the bits of the clean run (`said`: stderr has a line about it)
  error      exit 1 with exactly one `error:` line naming the cache directory
  signal     killed by a signal (SIGBUS, SIGSEGV, SIGABRT)
  traceback  a Python traceback on stderr
  wrong_ok   exit 0 with a result different from the clean run's
  bad        any other exit, or several error lines, or an error without the cache's name
  hang       no exit within the timeout

Sections: so, module, numba, index, core, dirs, lock, jit, cc, kill.
"""
from __future__ import annotations

import argparse
import contextlib
import glob
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
PY = sys.executable
CLI = "import sys; from vcirun.cli.main import app; sys.argv[0] = 'vcirun'; app()"
RUNS = {"MCVAC": ["simulate", "--method", "MCVAC", "--beta", "3.2"],
        "CVA": ["simulate", "--method", "CVA", "--beta", "3.2"]}
RESULTS: list[dict] = []
BAD = ("signal", "traceback", "wrong_ok", "bad", "hang")


def home_of(cache) -> Path:
    parent = Path(cache).parent
    return (parent if parent.is_dir() else Path(tempfile.gettempdir())) / "home"


def env_for(cache, **extra) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "VCIRUN_"))}
    env.update(PYTHONPATH=str(ROOT), VCIRUN_CACHE_DIR=str(cache), HOME=str(home_of(cache)))
    env.update({k: str(v) for k, v in extra.items()})
    return env


def run(cache, *args, timeout=900, **extra):
    home_of(cache).mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    try:
        p = subprocess.run([PY, "-c", CLI, *map(str, args)], env=env_for(cache, **extra), capture_output=True,
                           text=True, timeout=timeout, cwd=str(home_of(cache).parent))
        return p.returncode, p.stdout, p.stderr, time.monotonic() - t0
    except subprocess.TimeoutExpired as e:
        return None, e.stdout or "", e.stderr or "", time.monotonic() - t0


def arrays(path) -> dict | None:
    try:
        with np.load(path) as z:
            return {k: z[k].copy() for k in z.files}
    except (OSError, ValueError):
        return None


def same(a, b) -> bool:
    return a is not None and b is not None and set(a) == set(b) and all(a[k].tobytes() == b[k].tobytes() for k in a)


def classify(rc, err, out_path=None, ref=None, cache=None) -> tuple[str, str]:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    if rc is None:
        return "hang", "timed out"
    if rc < 0 or rc > 128:
        return "signal", f"signal {-rc if rc < 0 else rc - 128}"
    if "Traceback" in err:
        return "traceback", lines[-1] if lines else ""
    if rc == 0:
        if ref is None:
            return "healed", " | ".join(lines)[:200]
        return ("healed" if same(arrays(out_path), ref) else "wrong_ok"), " | ".join(lines)[:200]
    errors = [ln for ln in lines if ln.startswith("error:")]
    if rc == 1 and len(errors) == 1 and (cache is None or str(cache) in errors[0] or "VCIRUN_CACHE_DIR" in errors[0]):
        return "error", errors[0][:240]
    return "bad", f"exit {rc}: " + " | ".join(lines[-3:])[:240]


def record(section, name, outcome, detail, seconds=0.0, **more):
    RESULTS.append({"section": section, "case": name, "outcome": outcome, "detail": detail,
                    "seconds": round(seconds, 1), **more})
    print(f"  [{outcome:>9}] {section}/{name} ({seconds:.0f} s): {detail[:220]}", flush=True)


class Probe:
    def __init__(self, template: Path, work: Path, seed: int):
        self.template, self.work, self.rng = template, work, random.Random(seed)
        self.n = 0
        self.refs = {}
        c = self.copy()
        for m, args in RUNS.items():
            rc, _, err, s = run(c, *args, "--output", c.parent / "ref.npz")
            if rc != 0 or "compiling" in err:
                raise SystemExit(f"the template is not warm for {m}: exit {rc}: {err[-500:]}")
            self.refs[m] = arrays(c.parent / "ref.npz")
            print(f"clean {m}: {s:.1f} s", flush=True)

    def copy(self) -> Path:
        self.n += 1
        d = self.work / f"case{self.n:03d}"
        shutil.copytree(self.template, d / "cache", symlinks=True)
        return d / "cache"

    def k(self, c, pattern) -> list[Path]:
        return sorted(Path(p) for p in glob.glob(str(c / "kernels" / pattern)))

    def scene(self, c, method="MCVAC") -> Path:
        """The scene module of `method` (MCVAC: the one that binds a shared object)."""
        mods = self.k(c, "vk_*.py")
        if method == "MCVAC":
            return next(p for p in mods if "_bind(__file__" in p.read_text(errors="replace"))
        return next(p for p in mods if "_bind(__file__" not in p.read_text(errors="replace")
                    and "reset='cva'" in p.read_text(errors="replace"))

    def case(self, section, name, fault, method="MCVAC", twice=True, **extra):
        """Damage a copy with fault(cache), run `method`; a healed run is run again (must be silent)."""
        c = self.copy()
        try:
            fault(c)
        except Exception as e:  # noqa: BLE001
            record(section, name, "skipped", f"fault not applicable: {e}")
            return
        out = c.parent / "out.npz"
        rc, _, err, s = run(c, *RUNS[method], "--output", out, **extra)
        outcome, detail = classify(rc, err, out, self.refs[method], c)
        if outcome == "healed" and twice:
            out.unlink(missing_ok=True)
            rc2, _, err2, s2 = run(c, *RUNS[method], "--output", out, **extra)
            o2, d2 = classify(rc2, err2, out, self.refs[method], c)
            if o2 != "healed":
                outcome, detail = o2, "second run: " + d2
            elif err2.strip():
                detail += f" || second run not silent: {' '.join(err2.split())[:150]}"
            s += s2
        record(section, name, outcome, detail, s)
        return c

    # --- faults ------------------------------------------------------------------------------------------
    def flip(self, p: Path, n=1, lo=0.0, hi=1.0):
        b = bytearray(p.read_bytes())
        for _ in range(n):
            i = self.rng.randrange(int(len(b) * lo), max(int(len(b) * lo) + 1, int(len(b) * hi)))
            b[i] ^= 1 << self.rng.randrange(8)
        p.write_bytes(bytes(b))

    def truncate(self, p: Path, lo=0.05, hi=0.95):
        os.truncate(p, self.rng.randrange(int(p.stat().st_size * lo), int(p.stat().st_size * hi)))


def section_so(P: Probe):
    so = lambda c: P.k(c, "vkc_*.so")[0]  # noqa: E731
    for i in range(3):
        P.case("so", f"truncated #{i}", lambda c: P.truncate(so(c)))
    P.case("so", "empty", lambda c: os.truncate(so(c), 0))
    for i in range(4):
        P.case("so", f"one bit flipped #{i}", lambda c: P.flip(so(c)))
    P.case("so", "a block zeroed", lambda c: _zero(P, so(c)))
    P.case("so", "missing", lambda c: so(c).unlink())
    P.case("so", "another ELF in its place", lambda c: shutil.copy("/bin/true", so(c)))
    P.case("so", "a directory in its place", lambda c: _dir_for(so(c)))
    P.case("so", "flipped bit, digest record rewritten to match",
           lambda c: (P.flip(so(c)), _rewrite_sidecar(so(c))))
    P.case("so", "digest record missing", lambda c: Path(str(so(c)) + ".sha256").unlink())
    P.case("so", "digest record garbage", lambda c: Path(str(so(c)) + ".sha256").write_bytes(os.urandom(40)))
    P.case("so", "dangling symlink", lambda c: _symlink(so(c), c / "nowhere.so"))


def _zero(P, p: Path):
    b = bytearray(p.read_bytes())
    i = P.rng.randrange(0, len(b) - 256)
    b[i:i + 256] = bytes(256)
    p.write_bytes(bytes(b))


def _dir_for(p: Path):
    p.unlink()
    p.mkdir()
    (p / "x").write_text("x")


def _symlink(p: Path, target: Path):
    p.unlink()
    p.symlink_to(target)


def _rewrite_sidecar(so: Path):
    import hashlib

    Path(str(so) + ".sha256").write_text(f"{hashlib.sha256(so.read_bytes()).hexdigest()} {so.stat().st_size}\n")


def section_module(P: Probe):
    P.case("module", "hm0 edited (0.5 h -> 0.4 h)",
           lambda c: _edit(P.scene(c), "hm0 = 0.5 * h", "hm0 = 0.4 * h"))
    for i in range(3):
        P.case("module", f"one bit flipped #{i}", lambda c: P.flip(P.scene(c)))
    for i in range(2):
        P.case("module", f"truncated #{i}", lambda c: P.truncate(P.scene(c)))
    P.case("module", "empty", lambda c: os.truncate(P.scene(c), 0))
    P.case("module", "missing", lambda c: P.scene(c).unlink())
    P.case("module", "seal line removed", lambda c: _drop_last_line(P.scene(c)))
    P.case("module", "the CVA module in its place", lambda c: shutil.copy(P.scene(c, "CVA"), P.scene(c)))
    P.case("module", "a line appended", lambda c: open(P.scene(c), "a").write("x = 1\n"))
    P.case("module", "a directory in its place", lambda c: _dir_for(P.scene(c)))
    P.case("module", "CVA module edited", lambda c: P.flip(P.scene(c, "CVA"), lo=0.3, hi=0.9), method="CVA")


def _edit(p: Path, a: str, b: str):
    t = p.read_text()
    if a not in t:
        raise ValueError(f"{a!r} not in {p.name}")
    p.write_text(t.replace(a, b, 1))


def _drop_last_line(p: Path):
    lines = p.read_text().splitlines(keepends=True)
    p.write_text("".join(lines[:-1]))


def section_numba(P: Probe):
    def pick(c, ext, scene_only=True):
        mod = P.scene(c).stem
        files = P.k(c, f"__pycache__/{mod}.*.{ext}")
        return P.rng.choice(files)

    P.case("numba", "zero-length index", lambda c: os.truncate(pick(c, "nbi"), 0))
    P.case("numba", "zero-length data", lambda c: os.truncate(pick(c, "nbc"), 0))
    P.case("numba", "truncated data", lambda c: P.truncate(pick(c, "nbc")))
    P.case("numba", "truncated index", lambda c: P.truncate(pick(c, "nbi")))
    P.case("numba", "one bit of data", lambda c: P.flip(pick(c, "nbc")))
    P.case("numba", "one bit of index", lambda c: P.flip(pick(c, "nbi")))
    P.case("numba", "data of another function", lambda c: _swap(pick(c, "nbc"), pick(c, "nbc")))
    P.case("numba", "every index missing", lambda c: [p.unlink() for p in P.k(c, f"__pycache__/{P.scene(c).stem}.*.nbi")])
    P.case("numba", "numba's own (unsealed) format",
           lambda c: _unseal(pick(c, "nbi")))
    P.case("numba", "__pycache__ is a file", lambda c: (shutil.rmtree(c / "kernels" / "__pycache__"),
                                                        (c / "kernels" / "__pycache__").write_text("x")))


def _swap(a: Path, b: Path):
    if a == b:
        raise ValueError("same file")
    shutil.copy(b, a)


def _unseal(p: Path):
    data = p.read_bytes()
    p.write_bytes(data[data.index(b"\n") + 1:])


def section_index(P: Probe):
    def edit(c, fn):
        for p in P.k(c, "wi_*.json"):
            p.write_text(fn(p.read_text()))

    P.case("index", "empty entries", lambda c: edit(c, lambda t: ""))
    P.case("index", "truncated entries", lambda c: edit(c, lambda t: t[: len(t) // 2]))
    P.case("index", "a default parameter edited", lambda c: edit(c, lambda t: t.replace("0.2", "0.25", 1)))
    P.case("index", "entries swapped (MCVAC's is CVA's)", lambda c: _swap_index(P, c))
    P.case("index", "the module key of another module", lambda c: _other_key(P, c))


def _swap_index(P, c):
    a, b = P.k(c, "wi_*.json")[:2]
    ta, tb = a.read_bytes(), b.read_bytes()
    a.write_bytes(tb)
    b.write_bytes(ta)


def _other_key(P, c):
    import re

    keys = [p.stem[3:] for p in P.k(c, "vk_*.py")]
    for p in P.k(c, "wi_*.json"):
        t = p.read_text()
        own = re.search(r'"module": ?"([0-9a-f]{20})"', t).group(1)
        other = next(k for k in keys if k != own)
        p.write_text(t.replace(own, other))


def section_core(P: Probe):
    P.case("core", "a constant edited", lambda c: [_edit(p, "0.5", "0.25") for p in P.k(c, "core_*.py")])
    P.case("core", "truncated", lambda c: [P.truncate(p) for p in P.k(c, "core_*.py")])
    P.case("core", "one bit flipped (numba recompiles nothing)", lambda c: [P.flip(p) for p in P.k(c, "core_*.py")])
    P.case("core", "missing", lambda c: [p.unlink() for p in P.k(c, "core_*.py")])


def section_dirs(P: Probe):
    args = RUNS["CVA"]
    t = Path(tempfile.mkdtemp(dir=P.work))
    f = t / "afile"
    f.write_text("x")
    for name, cache, cmd, extra in [
        ("empty VCIRUN_CACHE_DIR, simulate", t / "c", args, {"VCIRUN_CACHE_DIR": ""}),
        ("empty VCIRUN_CACHE_DIR, cache info", t / "c", ["cache", "info"], {"VCIRUN_CACHE_DIR": ""}),
        ("empty VCIRUN_CACHE_DIR, cache clear", t / "c", ["cache", "clear"], {"VCIRUN_CACHE_DIR": ""}),
        ("cache is a file, simulate", f, args, {}),
        ("cache is a file, cache info", f, ["cache", "info"], {}),
        ("cache is a file, cache clear", f, ["cache", "clear"], {}),
        ("cache under a file", f / "sub", args, {}),
    ]:
        rc, _, err, s = run(cache, *cmd, **extra)
        o, d = classify(rc, err)
        record("dirs", name, o if o != "healed" else "bad", d, s)
    if (t / "kernels").exists() or (Path.cwd() / "kernels").exists():
        record("dirs", "empty VCIRUN_CACHE_DIR wrote nothing", "bad", "a kernels directory appeared")
    c = P.copy()
    shutil.rmtree(c / "kernels")
    (c / "kernels").write_text("x")
    rc, _, err, s = run(c, *args)
    record("dirs", "kernels is a file", *classify(rc, err, cache=c), s)
    rc, _, err, s = run(c, "cache", "clear")
    record("dirs", "kernels is a file, cache clear", "healed" if rc == 0 and not (c / "kernels").exists()
           else classify(rc, err)[0], err.strip()[:200], s)
    if os.geteuid() == 0:
        _read_only(P)
        _full_disk(P)


@contextlib.contextmanager
def ro_mount(path: Path):
    subprocess.run(["mount", "--bind", str(path), str(path)], check=True, capture_output=True)
    try:
        subprocess.run(["mount", "-o", "remount,ro,bind", str(path)], check=True, capture_output=True)
        yield
    finally:
        subprocess.run(["umount", str(path)], capture_output=True)


def _read_only(P: Probe):
    c = P.copy()
    home = c.parent / "home"
    nb = c.parent / "numba_elsewhere"
    with ro_mount(c):
        out = c.parent / "out.npz"
        for m in ("CVA", "MCVAC"):
            rc, _, err, s = run(c, *RUNS[m], "--output", out, NUMBA_CACHE_DIR=nb)
            o, d = classify(rc, err, out, P.refs[m], c)
            if o == "healed" and err.strip():
                o, d = "bad", "a warm read-only cache said: " + d
            record("dirs", f"read-only warm cache, {m}", o, d or "silent, same bits", s)
        rc, so, err, s = run(c, "cache", "info")
        record("dirs", "read-only cache, cache info", "healed" if rc == 0 else classify(rc, err)[0],
               (so + err).strip()[:200], s)
        n = sum(1 for _ in c.rglob("*"))
        rc, _, err, s = run(c, "cache", "clear")
        o, d = classify(rc, err, cache=c)
        if o == "error" and sum(1 for _ in c.rglob("*")) != n:
            o = "bad"
        record("dirs", "read-only cache, cache clear", o if o != "healed" else "wrong_ok", d, s)
        rc, _, err, s = run(c, "simulate", "--system", "double_pendulum", "--method", "CVA", "--T", "0.1")
        record("dirs", "read-only cache, a system it lacks", *classify(rc, err, cache=c), s)
    left = [p for p in (home / ".cache" / "numba", nb) if p.exists() and any(p.rglob("*"))]
    record("dirs", "read-only cache: no numba files elsewhere", "bad" if left else "healed",
           f"files in {left}" if left else "none")


def _full_disk(P: Probe):
    c = P.copy()
    mnt = c.parent / "small"
    mnt.mkdir()
    # room for the cache's kernels and little more (the filler takes the rest): 24 MB or 1.5 x the copy
    need = sum(f.stat().st_size for f in (c / "kernels").rglob("*") if f.is_file())
    size_mb = max(24, int(1.5 * need / 2**20) + 8)
    if subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_mb}m", "tmpfs", str(mnt)],
                      capture_output=True).returncode:
        record("dirs", "full disk", "skipped", "cannot mount a tmpfs")
        return
    try:
        for what, keep in (("module and shared object", ("vk_*", "vkc_*", "wi_*")),
                           ("numba files of the scene module", ("wi_*",))):
            shutil.rmtree(mnt / "kernels", ignore_errors=True)
            ign = shutil.ignore_patterns(*keep) if what.startswith("module") else None
            shutil.copytree(c / "kernels", mnt / "kernels", ignore=ign)
            if not what.startswith("module"):
                scene = P.scene(mnt)
                for p in P.k(mnt, f"__pycache__/{scene.stem}.*"):
                    p.unlink()
            free = shutil.disk_usage(mnt).free
            with open(mnt / "filler", "wb") as f:
                f.write(b"\0" * max(0, free - 8192))
            out = c.parent / "out.npz"
            rc, _, err, s = run(mnt, *RUNS["MCVAC"], "--output", out)
            o, d = classify(rc, err, out, P.refs["MCVAC"], mnt)
            record("dirs", f"full disk while writing the {what}", o, d, s)
            (mnt / "filler").unlink()
            out.unlink(missing_ok=True)
            rc, _, err, s = run(mnt, *RUNS["MCVAC"], "--output", out)
            record("dirs", f"full disk freed, {what}", *classify(rc, err, out, P.refs["MCVAC"], mnt), s)
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)


def section_clear(P: Probe):
    c = P.copy()
    if os.geteuid() == 0:
        with ro_mount(c / "kernels"):
            rc, so, err, s = run(c, "cache", "clear")
            o, d = classify(rc, err, cache=c)
            record("dirs", "cache clear, read-only kernels/", o if o != "healed" else "wrong_ok", d or so.strip(), s)
    nb = c.parent / "nb"
    rc, _, err, s = run(c, *RUNS["CVA"], NUMBA_CACHE_DIR=nb)
    record("dirs", "NUMBA_CACHE_DIR set, warm", "healed" if rc == 0 and "compiling" not in err
           and not any(nb.rglob("*.nb*")) else "bad", err.strip()[:200], s)
    rc, so, err, s = run(c, "cache", "clear", NUMBA_CACHE_DIR=nb)
    left = [p for p in c.rglob("*") if p.is_file()]
    record("dirs", "cache clear removes everything", "healed" if rc == 0 and not left else "bad",
           (so + err).strip()[:200] + (f"; left {left[:3]}" if left else ""), s)


def section_lock(P: Probe):
    """A compile lock held by a stopped process, and by one killed mid-compile."""
    c = P.copy()
    for p in [P.scene(c), *P.k(c, f"__pycache__/{P.scene(c).stem}.*")]:
        p.unlink()
    for p in P.k(c, "wi_*.json"):
        p.unlink()
    first = subprocess.Popen([PY, "-c", CLI, *RUNS["MCVAC"]], env=env_for(c), stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL, start_new_session=True)
    t0 = time.monotonic()
    held = None
    while time.monotonic() - t0 < 300 and held is None and first.poll() is None:
        for lk in P.k(c, "*.lock"):
            try:
                if json.loads(lk.read_text() or "{}").get("pid") == first.pid:
                    held = lk
            except ValueError:
                pass
        time.sleep(0.02)
    if held is None:
        record("lock", "stopped holder", "skipped", "the first process never held a lock")
        first.kill()
        return
    os.killpg(first.pid, signal.SIGSTOP)
    out = c.parent / "out.npz"
    rc, _, err, s = run(c, *RUNS["MCVAC"], "--output", out)
    o, d = classify(rc, err, out, P.refs["MCVAC"], c)
    if o == "healed" and "is stopped" not in err:
        o, d = "bad", "no line about the stopped holder: " + d
    record("lock", f"stopped holder of {held.name}", o, d, s)
    os.killpg(first.pid, signal.SIGKILL)
    first.wait()
    c2 = P.copy()
    for p in [P.scene(c2), *P.k(c2, f"__pycache__/{P.scene(c2).stem}.*"), *P.k(c2, "wi_*.json")]:
        p.unlink()
    for delay in (0.5, 2.0):
        first = subprocess.Popen([PY, "-c", CLI, *RUNS["MCVAC"]], env=env_for(c2), stdout=subprocess.DEVNULL,
                                 stderr=subprocess.DEVNULL, start_new_session=True)
        time.sleep(delay)
        os.killpg(first.pid, signal.SIGKILL)
        first.wait()
        out.unlink(missing_ok=True)
        rc, _, err, s = run(c2, *RUNS["MCVAC"], "--output", out)
        o, d = classify(rc, err, out, P.refs["MCVAC"], c2)
        record("lock", f"SIGKILL {delay} s into a cold run, then a run", o, d, s)


def section_kill(P: Probe):
    """SIGKILL while the C compiler runs: its directory goes with the next run."""
    c = P.copy()
    for p in [*P.k(c, "vk_*.py"), *P.k(c, "vkc_*"), *P.k(c, "wi_*.json")]:
        p.unlink()
    first = subprocess.Popen([PY, "-c", CLI, *RUNS["MCVAC"]], env=env_for(c), stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL, start_new_session=True)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 600 and not glob.glob(str(c / "kernels" / ".vkc_build.*" / "*.c")):
        time.sleep(0.01)
    os.killpg(first.pid, signal.SIGKILL)
    first.wait()
    left = glob.glob(str(c / "kernels" / ".vkc_build.*"))
    out = c.parent / "out.npz"
    rc, _, err, s = run(c, *RUNS["MCVAC"], "--output", out)
    o, d = classify(rc, err, out, P.refs["MCVAC"], c)
    after = glob.glob(str(c / "kernels" / ".vkc_build.*"))
    if o == "healed" and after:
        o, d = "bad", f"left {after}"
    record("kill", f"SIGKILL during the C compile ({len(left)} build dirs left), then a run", o, d, s)


def section_jit(P: Probe):
    from vcirun.methods.table import METHODS

    c = P.copy()
    for m in METHODS:
        args = ["simulate", "--method", m, "--beta", "3.2", "--T", "0.5"]
        rc, _, err, s = run(c, *args, "--output", c.parent / "jit.npz")
        rc2, _, err2, s2 = run(c, *args, "--output", c.parent / "py.npz", NUMBA_DISABLE_JIT=1, timeout=1800)
        if rc != 0 or rc2 != 0:
            record("jit", m, classify(rc2, err2)[0] if rc == 0 else "skipped", (err + err2).strip()[-240:], s + s2)
            continue
        a, b = arrays(c.parent / "jit.npz"), arrays(c.parent / "py.npz")
        dq = float(np.max(np.abs(a["q"] - b["q"]))) if a["q"].shape == b["q"].shape else float("inf")
        dp = float(np.max(np.abs(a["p"] - b["p"]))) if a["p"].shape == b["p"].shape else float("inf")
        record("jit", m, "healed" if max(dq, dp) < 1e-11 else "wrong_ok", f"max |dq| {dq:.1e}, |dp| {dp:.1e}",
               s + s2, dq=dq, dp=dp)


def section_cc(P: Probe):
    """A different C compiler (a wrapper of the same one): the cores are not compiled again."""
    c = P.copy()
    w = c.parent / "bin" / "cc"
    w.parent.mkdir()
    w.write_text(f"#!/bin/sh\nexec {shutil.which('cc') or shutil.which('gcc')} \"$@\"\n")
    w.chmod(0o755)
    out = c.parent / "out.npz"
    rc, _, err, s = run(c, *RUNS["MCVAC"], "--output", out, CC=w)
    o, d = classify(rc, err, out, P.refs["MCVAC"], c)
    if o == "healed" and "core" in err:
        o, d = "bad", "the core was compiled again: " + d
    record("cc", "another C compiler", o, d, s)


SECTIONS = {"so": section_so, "module": section_module, "numba": section_numba, "index": section_index,
            "core": section_core, "dirs": section_dirs, "clear": section_clear, "lock": section_lock,
            "kill": section_kill, "jit": section_jit, "cc": section_cc}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--template", required=True, type=Path)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--only", default="")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="cache_probe_"))
    try:
        P = Probe(a.template.resolve(), work, a.seed)
        for name in (a.only.split(",") if a.only else SECTIONS):
            print(f"== {name}", flush=True)
            SECTIONS[name](P)
    finally:
        subprocess.run(["umount", "-R", str(work)], capture_output=True)
        shutil.rmtree(work, ignore_errors=True)
    counts = {}
    for r in RESULTS:
        counts[r["outcome"]] = counts.get(r["outcome"], 0) + 1
    print("outcomes:", ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    print("bad outcomes:", sum(counts.get(k, 0) for k in BAD))
    if a.out:
        a.out.write_text(json.dumps({"seed": a.seed, "counts": counts, "cases": RESULTS}, indent=1))


if __name__ == "__main__":
    main()
