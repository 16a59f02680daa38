"""What the kernel cache's checks cost on a warm start: checked against unchecked, fresh processes.

    .venv/bin/python bench/cache_verify.py [--repeats 9] [--method MCVAC] [--cache-dir DIR] [--out FILE]

Each repeat runs two fresh processes, in alternating order, on the same warm cache (a copy of DIR, or
of $VCIRUN_CACHE_DIR; warmed first):
  checked    `import vcirun; vcirun.simulate('cart_pendulum', METHOD, h=1e-2, T=5, beta=3.2)`, with the
             digest functions of vcirun.codegen.cache_store timed where they run (module seals,
             warm-index seals, numba's index and data files, the shared object's digest)
  unchecked  the same with the checks replaced by loads that trust the file (seals split off, digests
             not computed): the warm start without verification
Reported: medians (and min, max) of the process wall, of the time from `import vcirun` to the first
finished simulation, the time spent in the checks, how many bytes they hashed, and the difference.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

CHILD = r"""
import json, sys, time
T0 = time.perf_counter()
mode, method = sys.argv[1], sys.argv[2]
import vcirun
from vcirun.codegen import c_link, cache_store, numba_cache
spent = {"s": 0.0, "bytes": 0, "calls": 0}

def timed(fn, size):
    def wrapper(*a, **k):
        t = time.perf_counter()
        try:
            return fn(*a, **k)
        finally:
            spent["s"] += time.perf_counter() - t
            spent["bytes"] += size(*a)
            spent["calls"] += 1
    return wrapper

if mode == "checked":
    import os
    cache_store.sha256 = timed(cache_store.sha256, lambda d: len(d))
    cache_store.file_sha256 = timed(cache_store.file_sha256, lambda p: os.path.getsize(p))
else:
    def unseal_text(data, key):
        cut = data.rfind(cache_store.SEAL.encode())
        return data[:cut].decode(), json.loads(data[cut + len(cache_store.SEAL):].decode())

    def unseal_json(data):
        entry = json.loads(data.decode())
        entry.pop("seal", None)
        return entry

    def read(self, path):
        data = cache_store.read(__import__("pathlib").Path(path))
        return None if data is None else data[data.find(b"\n") + 1:]

    cache_store.unseal_text, cache_store.unseal_json = unseal_text, unseal_json
    c_link.verify = lambda path, digest: None
    numba_cache._File._read = read
t_imp = time.perf_counter() - T0
tr = vcirun.simulate("cart_pendulum", method, h=1e-2, T=5.0, beta=3.2)
t_sim = time.perf_counter() - T0
assert tr.status == "ok", tr.status
print(json.dumps({"import_s": t_imp, "first_sim_s": t_sim, "checks_s": spent["s"], "hashed_bytes": spent["bytes"],
                  "hash_calls": spent["calls"], "q_last": list(map(float, tr.q[-1]))}))
"""


def one(mode: str, method: str, cache: Path) -> dict:
    env = dict(os.environ, VCIRUN_CACHE_DIR=str(cache), PYTHONPATH=str(ROOT))
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", CHILD, mode, method], env=env, capture_output=True, text=True,
                       timeout=1800, cwd=str(ROOT))
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise RuntimeError(f"{mode} run failed: {r.stderr.strip()[-800:]}")
    out = json.loads(r.stdout.strip().splitlines()[-1])
    out["process_s"] = wall
    out["stderr"] = r.stderr.strip()
    return out


def stats(xs) -> dict:
    return {"median": statistics.median(xs), "min": min(xs), "max": max(xs)}


def measure(repeats: int = 9, method: str = "MCVAC", cache_dir: Path | None = None) -> dict:
    src = Path(cache_dir or os.environ.get("VCIRUN_CACHE_DIR") or Path.home() / ".cache" / "vcirun")
    with tempfile.TemporaryDirectory(prefix="cache_verify_") as tmp:
        cache = Path(tmp) / "cache"
        if (src / "kernels").is_dir():
            shutil.copytree(src, cache, symlinks=True)
        warm = one("checked", method, cache)   # warms the copy (a cold build on an empty cache)
        runs = {"checked": [], "unchecked": []}
        for i in range(repeats):
            for mode in (("checked", "unchecked") if i % 2 == 0 else ("unchecked", "checked")):
                r = one(mode, method, cache)
                if r["stderr"]:
                    raise RuntimeError(f"the warm cache was not warm ({mode}): {r['stderr'][-500:]}")
                runs[mode].append(r)
    if runs["checked"][0]["q_last"] != runs["unchecked"][0]["q_last"]:
        raise RuntimeError("checked and unchecked runs differ")
    out = {"method": method, "repeats": repeats, "loadavg": os.getloadavg(), "warmup_process_s": warm["process_s"]}
    for mode, rs in runs.items():
        out[mode] = {k: stats([r[k] for r in rs]) for k in ("process_s", "first_sim_s", "import_s")}
    c = runs["checked"]
    out["checked"]["checks_s"] = stats([r["checks_s"] for r in c])
    out["checked"]["hashed_bytes"] = c[0]["hashed_bytes"]
    out["checked"]["hash_calls"] = c[0]["hash_calls"]
    out["process_diff_s"] = out["checked"]["process_s"]["median"] - out["unchecked"]["process_s"]["median"]
    out["first_sim_diff_s"] = out["checked"]["first_sim_s"]["median"] - out["unchecked"]["first_sim_s"]["median"]
    out["checks_pct_of_first_sim"] = 100.0 * out["checked"]["checks_s"]["median"] / out["checked"]["first_sim_s"]["median"]
    return out


def report(r: dict, log=print) -> None:
    ck, un = r["checked"], r["unchecked"]
    log(f"  {r['method']} warm start, {r['repeats']} pairs of fresh processes (load average {r['loadavg'][0]:.1f}):")
    for name, d in (("checked", ck), ("unchecked", un)):
        log(f"    {name:9s} process {d['process_s']['median']:.3f} s (min {d['process_s']['min']:.3f}, max "
            f"{d['process_s']['max']:.3f}); import to first simulation {d['first_sim_s']['median']:.3f} s")
    log(f"    checks in the checked runs: {ck['checks_s']['median'] * 1e3:.1f} ms median ({ck['hash_calls']} digests, "
        f"{ck['hashed_bytes'] / 1e6:.2f} MB) = {r['checks_pct_of_first_sim']:.1f} % of the time to the first simulation")
    log(f"    median difference checked - unchecked: process {r['process_diff_s'] * 1e3:+.0f} ms, "
        f"to the first simulation {r['first_sim_diff_s'] * 1e3:+.0f} ms")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--method", default="MCVAC")
    ap.add_argument("--cache-dir", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    r = measure(a.repeats, a.method, a.cache_dir)
    report(r)
    if a.out:
        a.out.write_text(json.dumps(r, indent=1))


if __name__ == "__main__":
    main()
