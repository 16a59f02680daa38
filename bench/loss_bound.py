"""The loss bound of a killed sweep, measured: SIGKILL at random moments of the run phase of a 2000-run
sweep, then how many runs the client had received against how many the file and its journal hold.

    .venv/bin/python bench/loss_bound.py [--kills 6] [--seed 2000] [--out results/loss_bound.json]

`lost` = runs the client had received (its last progress line) minus the runs committed (read back
with vcirun.io.reader.read_results after the kill); "the runs of the last s" = the kill time minus the
moment the client had received as many runs as were committed. The stated bound (docs/reliability.md)
is commit_interval (1 s by default) plus one commit. Printed and saved; nothing is asserted (the
behaviour under kills is tested by tests/cli/test_interrupt.py and tests/cli/test_faults.py).
"""
from __future__ import annotations

import argparse
import json
import os
import random
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CONFIG = """\
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


class Sweep:
    """A `vcirun sweep` subprocess whose progress lines (`[done/total] ...; S saved`) are timestamped."""

    def __init__(self, cfg: Path, out: Path, workers: int = 2):
        self.t0 = time.monotonic()
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        self.proc = subprocess.Popen([sys.executable, "-m", "vcirun.cli.main", "sweep", str(cfg), "--output", str(out),
                                      "--workers", str(workers)], env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, cwd=cfg.parent)
        self.points: list[tuple[float, int]] = []   # (seconds, runs the client has)
        threading.Thread(target=self._pump, daemon=True).start()

    def _pump(self):
        for line in self.proc.stderr:
            m = re.match(r"\[(\d+)/(\d+)\]", line)
            if m:
                self.points.append((time.monotonic() - self.t0, int(m.group(1))))

    def first(self, timeout: float = 900) -> float:
        deadline = time.monotonic() + timeout
        while not self.points and self.proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        return self.points[0][0] if self.points else time.monotonic() - self.t0

    def wait(self) -> float:
        self.proc.wait(timeout=3600)
        time.sleep(0.3)
        return time.monotonic() - self.t0

    def kill_at(self, seconds: float) -> float:
        while time.monotonic() - self.t0 < seconds and self.proc.poll() is None:
            time.sleep(0.01)
        t = time.monotonic() - self.t0
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait()
        time.sleep(0.3)   # the reader thread drains the last lines
        return t


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=6)
    ap.add_argument("--seed", type=int, default=2000)
    ap.add_argument("--out", default=str(ROOT / "results" / "loss_bound.json"))
    a = ap.parse_args(argv)
    from vcirun.io.reader import read_results

    d = Path(tempfile.mkdtemp(prefix="vcirun-loss-"))
    cfg = d / "loss.yaml"
    cfg.write_text(CONFIG)
    s = Sweep(cfg, d / "complete.h5")
    first = s.first()
    total = s.wait()
    last = s.points[-1][0] if s.points else total
    run_phase = max(2.0, last - first)
    res = {"startup_s": round(first, 2), "run_phase_s": round(run_phase, 2), "compaction_s": round(total - last, 2),
           "load": os.getloadavg()[0], "kills": []}
    print(f"uninterrupted: start-up {first:.1f} s, runs {run_phase:.1f} s ({2000 / run_phase:.0f} runs/s), final "
          f"compaction {total - last:.1f} s", flush=True)
    rng = random.Random(a.seed)
    for k in range(a.kills):
        out = d / f"k{k}.h5"
        s = Sweep(cfg, out)
        t_kill = s.kill_at(s.first() + rng.uniform(1.0, 0.9 * run_phase))
        if not s.points:
            print(f"kill at {t_kill:.1f} s: no progress line before the kill", flush=True)
            continue
        have = s.points[-1][1]
        committed = len(read_results(out).runs) if out.exists() else 0
        lost = max(0, have - committed)
        t_c = next((t for t, n in s.points if n >= committed), s.points[-1][0]) if committed else s.points[0][0]
        window = [p for p in s.points if p[0] >= t_kill - 5.0]
        rate = ((window[-1][1] - window[0][1]) / max(1e-9, window[-1][0] - window[0][0]) if len(window) > 1
                else float("nan"))
        lost_s = t_kill - t_c if lost else 0.0
        row = {"t_kill": round(t_kill, 2), "had": have, "committed": committed, "lost": lost,
               "seconds_lost": round(lost_s, 3), "rate": round(rate, 1)}
        res["kills"].append(row)
        print(f"kill at {t_kill:.1f} s: client had {have}, {committed} committed: {lost} lost = the runs of the last "
              f"{lost_s:.2f} s (rate {rate:.0f} runs/s)", flush=True)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=1))
    return res


if __name__ == "__main__":
    main()
