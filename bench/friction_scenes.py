"""Coulomb friction in the integrators against the closed forms, and the cost of a held step with
friction (`make bench BENCH_ARGS="--only friction_scenes"`; standalone: python bench/friction_scenes.py).

Rows (vcirun.scenes.friction and vcirun.scenes.friction_oracles; docs/derivations/friction.md):
  ramp      a block held on a ramp at 1.05x its static margin (mu_s = 1.05 tan theta) for 10 s: its
            displacement (target 0 to 1e-14 m); with MuJoCo where it is installed (python -m pip install
            mujoco), a box on the same ramp with friction 1.05 tan theta at MuJoCo's defaults, side by side
  ball      Capobianco's spinning ball (w0 = 10 sticks, w0 = 50 slides): the mode at the impact, xdot+ and
            the rolling start against the closed form, per method
  incline   launched uphill: the stop time and the final position (stick and slide-back cases)
  oscillator the Coulomb oscillator's turning times and rest position at three steps, with the
            observed order
  cost      microseconds per held step sliding with friction (the incline, mu = 0.2: the lean core with
            friction compiled in) against the same block sliding without friction (its frictionless
            declaration: the lean frictionless core), CVA, medians of interleaved runs; target <= 1.5x
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

METHODS = ("CVA", "VCI", "MCVAA", "CVA4")

_MUJOCO_SCRIPT = r"""
import json, math, sys
import mujoco, numpy as np
th = float(sys.argv[1]); mu = 1.05 * math.tan(th)
xml = f'''<mujoco><option gravity="{9.81*math.sin(th)} 0 {-9.81*math.cos(th)}"/>
<worldbody><geom type="plane" size="5 5 0.1" friction="{mu} 0.005 0.0001"/>
<body pos="0 0 0.1"><freejoint/><geom type="box" size="0.1 0.1 0.1" mass="1" friction="{mu} 0.005 0.0001"/></body>
</worldbody></mujoco>'''
m = mujoco.MjModel.from_xml_string(xml); d = mujoco.MjData(m)
mujoco.mj_forward(m, d)
for _ in range(int(1.0 / m.opt.timestep)):   # settle onto the plane for 1 s, then measure 10 s
    mujoco.mj_step(m, d)
x0 = d.qpos[:3].copy()
for _ in range(int(10.0 / m.opt.timestep)):
    mujoco.mj_step(m, d)
print(json.dumps({"version": mujoco.__version__, "timestep": m.opt.timestep,
                  "displacement": float(np.linalg.norm(d.qpos[:2] - x0[:2]))}))
"""


def _mujoco(theta, python=None):
    """The MuJoCo row: its box's displacement in 10 s, or None where mujoco does not import."""
    for exe in ([python] if python else []) + [sys.executable, os.environ.get("VCIRUN_MUJOCO_PYTHON", "")]:
        if not exe:
            continue
        try:
            r = subprocess.run([exe, "-c", _MUJOCO_SCRIPT, str(theta)], capture_output=True, text=True, timeout=600)
        except (OSError, subprocess.TimeoutExpired):
            continue
        if r.returncode == 0:
            return json.loads(r.stdout.strip().splitlines()[-1])
    return None


def section_friction_scenes(res, quick=False, methods=METHODS, log=print):
    import vcirun
    from vcirun.scenes import friction as scenes
    from vcirun.scenes import friction_oracles as oracles

    out = res.setdefault("friction_scenes", {})
    th = 0.3
    log("\n## friction: a block held on a ramp at 1.05x its static margin, 10 s")
    log("| method | h | displacement (m) | status |")
    log("|---|---|---|---|")
    ramp = {}
    for m in methods[:1] if quick else methods:
        tr = vcirun.simulate(scenes.incline(th, mu=0.2, mu_s=1.05 * math.tan(th)), m, h=1e-3, T=10.0)
        dx = float(np.max(np.abs(tr.q - tr.q[0])))
        ramp[m] = dx
        log(f"| {m} | 1e-3 | {dx:.3g} | {tr.status} |")
    mj = _mujoco(th)
    if mj is None:
        log("| MuJoCo | - | (not installed: python -m pip install mujoco, or VCIRUN_MUJOCO_PYTHON) | |")
    else:
        log(f"| MuJoCo {mj['version']} (box, defaults) | {mj['timestep']:g} | {mj['displacement']:.3g} | creeps |")
    out["ramp"] = {"vcirun": ramp, "mujoco": mj}

    log("\n## friction: Capobianco's spinning ball against the closed form (h = 1e-3)")
    log("| method | w0 | mode at impact | err xdot+ | err rolling start | err rolling xdot |")
    log("|---|---|---|---|---|---|")
    ball = []
    for m in methods[:2] if quick else methods:
        for w0 in (10.0, 50.0):
            ex = oracles.spinning_ball(w0)
            tr = vcirun.simulate(scenes.spinning_ball(w0), m, h=1e-3, T=1.2)
            k = int(np.searchsorted(tr.t, ex.t1)) + 1
            mode = {2: "stick", 1: "slip", -1: "slip"}.get(int(tr.contact_mode[k, 0]), "free")
            e_x = abs(tr.impact_p_plus[0][0] - ex.xdot_plus)
            e_t = abs(tr.mode_changes[0] - ex.t_roll) if len(tr.mode_changes) else (0.0 if ex.sticks else math.inf)
            e_r = abs(tr.p[-1, 0] - ex.xdot_roll)
            ball.append({"method": m, "w0": w0, "mode": mode, "err_xdot_plus": e_x, "err_t_roll": e_t, "err_roll": e_r})
            log(f"| {m} | {w0:g} | {mode} ({'stick' if ex.sticks else 'slip'} exact) | {e_x:.2e} | {e_t:.2e} | {e_r:.2e} |")
    out["ball"] = ball

    log("\n## friction: incline launched uphill (theta 0.3, mu 0.2, v0 2): stop time and position at T = 1")
    log("| method | mu_s | h | err stop time | err position |")
    log("|---|---|---|---|---|")
    inc = []
    for m in methods[:1] if quick else methods:
        for mu_s in (0.25, 0.35):
            for h in (1e-2, 1e-3):
                tr = vcirun.simulate(scenes.incline(th, mu=0.2, mu_s=mu_s, v0=2.0), m, h=h, T=1.0)
                ex = oracles.incline(th, mu=0.2, mu_s=mu_s, v0=2.0)
                s = math.cos(th) * tr.q[-1, 0] + math.sin(th) * tr.q[-1, 1]
                et, ex_ = abs(tr.mode_changes[0] - ex.t_stop), abs(s - ex.state(tr.t[-1])[0])
                inc.append({"method": m, "mu_s": mu_s, "h": h, "err_stop": et, "err_x": ex_})
                log(f"| {m} | {mu_s} | {h:g} | {et:.2e} | {ex_:.2e} |")
    out["incline"] = inc

    log("\n## friction: Coulomb oscillator (k = 10, mu = 0.1, x0 = 1): turning times and rest position")
    log("| method | h | err turns | err rest | order (turns) |")
    log("|---|---|---|---|---|")
    osc = []
    for m in methods[:1] if quick else methods:
        prev = None
        for h in (4e-3, 2e-3, 1e-3):
            tr = vcirun.simulate(scenes.coulomb_oscillator(1.0, k=10.0, mu=0.1), m, h=h, T=6.0)
            ex = oracles.coulomb_oscillator(1.0, k=10.0, mu=0.1)
            n = min(len(tr.mode_changes), len(ex.turns))
            et = max(abs(a - b) for a, b in zip(tr.mode_changes[:n], [t for t, _ in ex.turns[:n]])) if n else math.inf
            er = abs(tr.q[-1, 0] - ex.x_stop)
            order = math.log2(prev / et) if prev and et > 0 else float("nan")
            prev = et
            osc.append({"method": m, "h": h, "err_turns": et, "err_rest": er, "turns": n, "exact_turns": len(ex.turns)})
            log(f"| {m} | {h:g} | {et:.2e} | {er:.2e} | {order:.2f} |")
    out["oscillator"] = osc

    log("\n## friction: cost of a held step sliding with friction against the same step without (CVA, h = 1e-3)")
    from vcirun.mechanics.system import Constraint, MechanicalSystem
    import sympy as sp

    fr = scenes.incline(0.3, mu=0.2, mu_s=0.2, v0=0.0)
    x, y = sp.symbols("x y")
    M_, g_, th_ = sp.symbols("m g theta")
    smooth = MechanicalSystem(name="incline_frictionless", q=[x, y],
                              params={"m": 1.0, "g": 9.81, "theta": 0.3},
                              M=sp.eye(2) * M_, V=M_ * g_ * y,
                              constraints=[Constraint("slope", -sp.sin(th_) * x + sp.cos(th_) * y, sp.Integer(0))])
    smooth.default_q0, smooth.default_p0 = np.zeros(2), np.zeros(2)
    pair = (("friction", fr), ("frictionless", smooth))
    for _, sysm in pair:   # (compiled in the foreground: no interpreted run among the timed ones)
        vcirun.simulate(sysm, "CVA", h=1e-3, T=0.01, tier="compiled")
    ws = {name: [] for name, _ in pair}
    for _ in range(7 if quick else 21):   # interleaved: both see the same load
        for name, sysm in pair:
            tr = vcirun.simulate(sysm, "CVA", h=1e-3, T=2.0, energies=False)
            ws[name].append(tr.wall_time / (len(tr.t) - 1))
    times = {name: float(np.median(w)) * 1e6 for name, w in ws.items()}
    ratio = times["friction"] / times["frictionless"]
    log(f"| held step sliding | {times['friction']:.2f} us with friction | {times['frictionless']:.2f} us without "
        f"| ratio {ratio:.2f} (target <= 1.5) |")
    out["cost"] = {"us_friction": times["friction"], "us_frictionless": times["frictionless"], "ratio": ratio}
    return out


if __name__ == "__main__":
    res = {}
    section_friction_scenes(res, quick="--quick" in sys.argv)
    Path("results").mkdir(exist_ok=True)
    Path("results/bench_friction_scenes.json").write_text(json.dumps(res, indent=1, default=float))
