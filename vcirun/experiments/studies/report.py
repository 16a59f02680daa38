"""The extremes report: Markdown from the study results and a template (docs/templates/extremes.md).

The template holds the prose (section introductions, the findings with their dates); this module
only turns results into tables and numbers. Template syntax, nothing else:

- `{{name}}` is replaced by the value `name` of the context (`extremes_context`); an unknown name
  is an error naming it;
- a line `<!-- if SECTION -->` ... a line `<!-- end if -->` keeps what is between only when the
  results hold a non-empty SECTION (blocks do not nest);
- a line starting with `<!--#` is a template comment and is dropped.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ...scenes.registry import find_scene
from .schema import SECTIONS


def _label(system: str) -> str:
    """A scene's short name in the report (its StudyHooks.label), else its name."""
    found = find_scene(system)
    study = found[0].study if found is not None else None
    return (study.label if study is not None else "") or system

__all__ = ["render", "render_extremes", "extremes_context"]

_IF = re.compile(r"^<!-- if (\w+) -->$")
_END = "<!-- end if -->"
_FIELD = re.compile(r"\{\{(\w+)\}\}")


def render(template: str, context: dict, present=(), *, source: str = "<template>") -> str:
    """Apply the template syntax above: blocks of the sections in `present` kept, placeholders filled."""
    out, keep, block = [], True, None
    for i, line in enumerate(template.split("\n"), 1):
        m = _IF.match(line)
        if m:
            if block is not None:
                raise ValueError(f"{source}:{i}: '<!-- if {m.group(1)} -->' inside the block of {block!r} "
                                 "(blocks do not nest)")
            block, keep = m.group(1), m.group(1) in present
            continue
        if line == _END:
            if block is None:
                raise ValueError(f"{source}:{i}: '{_END}' without '<!-- if ... -->'")
            block, keep = None, True
            continue
        if line.startswith("<!--#") or not keep:
            continue
        out.append(line)
    if block is not None:
        raise ValueError(f"{source}: the block of {block!r} is not closed ('{_END}')")

    def field(m):
        if m.group(1) not in context:
            raise ValueError(f"{source}: unknown placeholder {{{{{m.group(1)}}}}} (known: {', '.join(sorted(context))})")
        return str(context[m.group(1)])

    return _FIELD.sub(field, "\n".join(out))


# --- number formats -----------------------------------------------------------------------------------
def _g(x, fmt=".2g"):
    if x is None:
        return "-"
    try:
        if not np.isfinite(x):
            return "-"
    except TypeError:
        return str(x)
    return format(x, fmt)


def _num(x) -> str:
    """A config value as written by hand: 1e-05 -> '1e-5', 1000000 -> '1e6', 5.0 -> '5', 0.05 -> '0.05'."""
    s = format(x, "g")
    if "e" in s:
        mant, exp = s.split("e")
        s = f"{mant}e{int(exp)}"
    return s


def _pow10(x) -> str:
    """An order of magnitude as written in prose: 1e-05 -> '1e-5', 1e6 -> '1e6', 100 -> '100', 0.5 -> '0.5'."""
    e = np.log10(x) if x > 0 else np.nan
    if np.isfinite(e) and e == round(e) and abs(e) >= 3:
        return f"1e{int(round(e))}"
    return _num(x)


def _short(status, cause=""):
    if status == "ok":
        return "ok"
    c = cause.split(" (")[0].split(":")[0] if cause else ""
    return f"**{status}**" + (f" ({c})" if c else "")


def _unique(xs) -> list:
    out = []
    for x in xs:
        if x not in out:
            out.append(x)
    return out


_COUNT = {1: "one", 2: "two", 3: "three", 4: "four", 5: "five"}


def _checkpoints(r) -> list[int]:
    return [int(k) for k in r.get("maxdev_H", {})]


# --- overview ------------------------------------------------------------------------------------------
def _overview_table(res: dict) -> list:
    """The summary table (per method: stable h per scene, drift slopes, outcome of each hard case)."""
    methods = res.get("methods", [])

    def pick(section, **kw):
        return [r for r in res.get(section, []) if all(r.get(k) == v for k, v in kw.items())]

    def stable(m, scene):
        r = pick("step_limit", method=m, system=scene)
        if not r:
            return "-"
        r = r[0]
        if r.get("h_past") is None or not np.isfinite(r["h_past"]):
            return f"<= {r['h_max']:g} (no failure)"
        return f"<= {_g(r['h_limit'], '.3g')}, then {r['status_past']}"

    def graze(m):
        rs = pick("grazing", method=m)
        if not rs:
            return "-"
        ok = sum(1 for r in rs if r["status"] == "ok" and r.get("err", np.inf) <= r.get("bound", -1))
        return f"{ok}/{len(rs)} ok within bound" if ok == len(rs) else f"{ok}/{len(rs)} ok; " + ", ".join(
            sorted({r["status"] for r in rs if r["status"] != "ok"}))

    def boundary(m):
        rs = pick("boundary", method=m)
        vs = [v for r in rs for v in r["variants"].values()]
        if not vs:
            return "-"
        ok = [v for v in vs if v.get("status") == "ok" and v.get("impacts") == v.get("ref_impacts")]
        dt = max((abs(v["dt_first"]) for v in ok), default=np.nan)
        return f"{len(ok)}/{len(vs)} ok, impact at k h to {_g(dt, '.0e')}"

    def dense(m):
        out = []
        for r in pick("dense", method=m):
            sc = _label(r["system"])
            if r["status"] == "ok":
                out.append(f"{sc}: ok {r.get('impacts')}/{r.get('ref_impacts')} impacts")
            else:
                out.append(f"{sc}: {r['status'].split(':')[0]}")
        return "; ".join(out) or "-"

    def surface(m):
        rs = pick("surface", method=m)
        if not rs:
            return "-"
        ok = [r for r in rs if r["status"] == "ok" and r.get("impacts") == r.get("ref_impacts")]
        other = sorted({f"{r['kind']}: {r['status']}" for r in rs if r not in ok})
        return f"{len(ok)}/{len(rs)} ok" + ("; " + ", ".join(other) if other else "")

    def accum(m):
        rs = pick("accumulation", method=m)
        if not rs:
            return "-"
        r = rs[0]
        if r["status"] == "accumulation":
            return f"accumulation, onset {_g(r.get('onset'), '.3g')} (exact {_g(r['exact_onset'], '.3g')}), h = {r['h']:g}"
        if r["status"] == "ok":
            held = f", held from t = {_g(r['held_from'], '.4g')}" if "held_from" in r else ""
            return f"ok: settles{held}, err {_g(r.get('err_after_onset'))} after onset, h = {r['h']:g}"
        return r["status"].split(":")[0] + (" (forced system)" if "forced" in r["status"] else "")

    top_beta = max((y["beta"] for y in res.get("energy", [])), default=None)

    def energy(m):
        r = next((x for x in pick("energy", method=m) if x["beta"] == top_beta), None)
        if r is None:
            return "-"
        last = r["runs"][-1]
        return (f"L2 {_g(last.get('l2'))} at h = {last['h']:g}" + (f", order {last['order']:.2f}" if "order" in last
                                                                   else "")) if "l2" in last else last["status"]

    def ratio(m):
        rs = pick("mass_ratio", method=m)
        if not rs:
            return "-"
        conv = [r["ratio"] for r in rs if all(x["status"] == "ok" for x in r["runs"][1:])
                and r["runs"][-1].get("order", 0) > 1.8]
        hard = [r for r in rs if r["ratio"] not in conv]
        out = [f"order 2 for {', '.join(f'{x:g}' for x in conv)}"] if conv else []
        for r in hard:
            ok = [x for x in r["runs"] if x["status"] == "ok"]
            fails = sorted({x["status"] for x in r["runs"] if x["status"] != "ok"})
            best = min(ok, key=lambda x: x["h"]) if ok else None
            out.append(f"{r['ratio']:g}: " + (f"L2 {_g(best.get('l2'))} at h = {best['h']:g}" if best else "no ok run")
                       + (f", {'/'.join(fails)} at larger h (cause named)" if fails else ""))
        return "; ".join(out)

    def singular(m):
        rs = pick("singular_mass", method=m)
        if not rs:
            return "-"
        parts = []
        for r in rs:
            tag = f"{r['m1']:g}" if r["m1"] else "0 (non-aligned)"
            if "input_error" in r:
                parts.append("0 (aligned): ValueError at input")
                continue
            ok = [x for x in r["runs"] if x["status"] == "ok"]
            named = all(x["cause"] for x in r["runs"] if x["status"] != "ok")
            txt = f"{tag}: " + (f"ok for h <= {max(x['h'] for x in ok):g}" if ok else "stops")
            if any(x["status"] != "ok" for x in r["runs"]):
                txt += ", stops above" * bool(ok) + (" (cause named)" if named else " (a failure without cause)")
            bad = [x for x in ok if x.get("dH", 0) > 3.0]   # 10 % of the scene's energy scale, 29 J
            if bad:
                txt += f"; ok runs with max abs(H - H0) up to {_g(max(x['dH'] for x in bad))}"
            parts.append(txt)
        return "; ".join(parts)

    def hyg(m):
        cs = [c for c in res.get("hygiene", {}).get("cases", []) if c["method"] == m]
        if not cs:
            return "-"
        ok = sum(1 for c in cs if c["status"] == "ok")
        return "clean" if ok == len(cs) else f"{ok}/{len(cs)} clean"

    def long(m):
        r = next(iter(pick("long_horizon", method=m)), None)
        if r is None:
            return "-", "-"
        return _g(r.get("slope_H"), ".1e"), _g(r.get("slope_Hmod"), ".1e")

    cols = ["method", "stable h, cart-pendulum", "stable h, double pendulum", "dH/dt", "dHmod/dt", "grazing",
            "impact at a grid point", "several impacts per step", "start on the surface", "accumulation",
            f"beta = {_g(top_beta, 'g')}", "mass ratio m2/m1", "nearly singular M (m1)", "FP hygiene"]
    L = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for m in methods:
        sH, sM = long(m)
        L.append("| " + " | ".join([m, stable(m, "cart_pendulum"), stable(m, "double_pendulum"), sH, sM, graze(m),
                                    boundary(m), dense(m), surface(m), accum(m), energy(m), ratio(m), singular(m),
                                    hyg(m)]) + " |")
    return L


def _long_horizon_growth(res: dict) -> str:
    """'MCVAA a -> b J from 1e5 to 1e6 steps (xb/a; slope ..)' for the MCVA family: the last decade."""
    parts = []
    for m in ("MCVAA", "MCVAC"):
        r = next((x for x in res.get("long_horizon", []) if x["method"] == m), None)
        d = r.get("maxdev_Hmod") if r else None
        if d and len(d) >= 2:
            (k0, v0), (k1, v1) = list(d.items())[-2:]
            parts.append(f"{m} {_g(v0)} -> {_g(v1)} J from {_pow10(int(k0))} to {_pow10(int(k1))} steps "
                         f"(x{v1 / v0:.1f}; slope {_g(r.get('slope_Hmod'), '.1e')} J/s)")
    return "; ".join(parts) or "-"


# --- sections ------------------------------------------------------------------------------------------
def _step_limit_table(res):
    L = ["| scene | method | stable h range | status just past h* | max abs(H - H0) at h* | ok above h* | "
         "largest scanned h with max abs(H - H0) <= 10 % E | crashes |", "|---|---|---|---|---|---|---|---|"]
    for r in res["step_limit"]:
        rng = f"[{r['h_min']:g}, {_g(r['h_limit'], '.4g')}]" if r.get("h_limit") else "none"
        cause = r["message_past"].split("; cause: ")[1] if "; cause: " in r.get("message_past", "") else ""
        has_past = r.get("h_past") is not None and np.isfinite(r["h_past"])
        past = (f"{_short(r['status_past'], cause)} at {_g(r['h_past'], '.4g')}" if has_past
                else f"none up to h = {r['h_max']:g}")
        above = ", ".join(_g(h, ".3g") for h in r.get("ok_above", [])) or "-"
        L.append(f"| {r['system']} | {r['method']} | {rng} | {past} | {_g(r['dH_at_limit'])} | {above} | "
                 f"{_g(r.get('h_energy10'), '.3g')} | {len(r['crashes'])} |")
    return L


def _long_horizon_table(res):
    rs = res["long_horizon"]
    at = " / ".join(_pow10(c) for c in _checkpoints(rs[0]))
    L = [f"| method | status | impacts | slope of H (J/s) | max abs(H - H0) @{at} | slope of Hmod | "
         f"max abs(Hmod - Hmod0) @{at} | wall (s) |", "|---|---|---|---|---|---|---|---|"]
    for r in rs:
        devH = " / ".join(_g(v) for v in r.get("maxdev_H", {}).values()) or "-"
        devM = " / ".join(_g(v) for v in r.get("maxdev_Hmod", {}).values()) or "-"
        L.append(f"| {r['method']} | {r['status']} | {r.get('impacts', '-')} | {_g(r.get('slope_H'), '.2e')} | "
                 f"{devH} | {_g(r.get('slope_Hmod'), '.2e')} | {devM} | {_g(r.get('wall_time'), '.1f')} |")
    return L


def _grazing_tables(res):
    methods = res.get("methods", [])
    L = []
    for sc in sorted({r["system"] for r in res["grazing"]}):
        rows = [r for r in res["grazing"] if r["system"] == sc]
        depths = sorted({r["depth"] for r in rows}, reverse=True)
        L.append(f"{sc}, h = {_num(rows[0]['h'])}:\n")
        L.append("| depth | vn | " + " | ".join(methods) + " |")
        L.append("|---|---|" + "---|" * len(methods))
        for d in depths:
            cells = []
            for m in methods:
                r = next((x for x in rows if x["depth"] == d and x["method"] == m), None)
                if r is None:
                    cells.append("-")
                elif r["status"] == "ok":
                    cells.append(f"ok {r.get('impacts')}/{r.get('ref_impacts')}, {_g(r.get('err'))} "
                                 f"(bound {_g(r.get('bound'))})")
                else:
                    cells.append(_short(r["status"], r.get("cause", "")))
            vn = next(x["vn"] for x in rows if x["depth"] == d)
            L.append(f"| {d:.0e} | {_g(vn)} | " + " | ".join(cells) + " |")
        L.append("")
    return L[:-1]


def _boundary_table(res):
    L = ["| scene | method | phi_k < 0 | phi_k == 0.0 | phi_k > 0 | spread of final states |", "|---|---|---|---|---|---|"]
    for r in res["boundary"]:
        cells = []
        for key in ("neg", "zero", "pos"):
            v = r["variants"].get(key, {})
            if v.get("status") == "ok":
                cells.append(f"ok, {_g(v.get('dt_first'), '.1e')}, {v.get('impacts')}/{v.get('ref_impacts')}, "
                             f"L2 {_g(v.get('l2'))}")
            else:
                cells.append(v.get("status", "-"))
        L.append(f"| {r['system']} (h = {_num(r['h'])}, k = {r['k']}) | {r['method']} | " + " | ".join(cells)
                 + f" | {_g(r.get('spread_final'))} |")
    return L


def _dense_table(res):
    L = ["| scene | method | status | impacts / exact | max per step | max impact-time error | error |",
         "|---|---|---|---|---|---|---|"]
    for r in res["dense"]:
        err = r.get("l2", r.get("err"))
        L.append(f"| {r['system']} (h = {_num(r['h'])}, T = {_num(r['T'])}) | {r['method']} | "
                 f"{_short(r['status'], r.get('cause', ''))} | "
                 f"{r.get('impacts', '-')}/{r.get('ref_impacts', '-')} | {r.get('max_per_step', '-')} | "
                 f"{_g(r.get('dt_impacts'))} | {_g(err)} ({'L2' if 'l2' in r else 'max'}) |")
    return L


def _surface_table(res):
    methods = res.get("methods", [])
    L = ["| scene | kind | " + " | ".join(methods) + " |", "|---|---|" + "---|" * len(methods)]
    keys = _unique((r["system"], r["kind"]) for r in res["surface"])
    for sc, kind in keys:
        cells = []
        for m in methods:
            r = next((x for x in res["surface"] if x["system"] == sc and x["kind"] == kind and x["method"] == m), None)
            if r is None:
                cells.append("-")
            elif r["status"] == "ok" and "l2" in r:
                cells.append(f"ok {r['impacts']}/{r['ref_impacts']} impacts, L2 {_g(r['l2'])}")
            else:
                cells.append(_short(r["status"], r.get("cause", "")))
        L.append(f"| {sc} | {kind} | " + " | ".join(cells) + " |")
    return L


def _accumulation_table(res):
    L = ["| method | h | status | reported onset | exact onset | held from | stopped at | impacts | err after onset |",
         "|---|---|---|---|---|---|---|---|---|"]
    for r in res["accumulation"]:
        L.append(f"| {r['method']} | {_num(r['h'])} | {r['status']} | {_g(r.get('onset'), '.4g')} | "
                 f"{_g(r['exact_onset'], '.4g')} | {_g(r.get('held_from'), '.4g')} | {_g(r.get('fail_time'), '.4g')} | {r.get('impacts', '-')} | "
                 f"{_g(r.get('err_after_onset'))} |")
    return L


def _convergence_cells(r):
    return [(f"{_g(x['l2'])}" + (f" ({x['order']:.2f})" if "order" in x else "")) if "l2" in x
            else _short(x["status"], x.get("cause", "")) for x in r["runs"]]


def _energy_table(res):
    hs = [r["h"] for r in res["energy"][0]["runs"]]
    L = ["| beta | H0 (J) | theta span | method | " + " | ".join(f"h = {h:g}" for h in hs) + " |",
         "|---|---|---|---|" + "---|" * len(hs)]
    for r in res["energy"]:
        H0 = next((x["H0"] for x in r["runs"] if "H0" in x), np.nan)
        L.append(f"| {_num(r['beta'])} | {_g(H0, '.4g')} | {_g(r['theta_span'], '.3g')} | {r['method']} | "
                 + " | ".join(_convergence_cells(r)) + " |")
    return L


def _mass_ratio_table(res):
    hs = [r["h"] for r in res["mass_ratio"][0]["runs"]]
    L = ["| m2/m1 | max cond(M) | exact impacts | method | " + " | ".join(f"h = {h:g}" for h in hs) + " |",
         "|---|---|---|---|" + "---|" * len(hs)]
    for r in res["mass_ratio"]:
        L.append(f"| {r['ratio']:g} | {_g(r['cond_max'])} | {r['ref_impacts']} | {r['method']} | "
                 + " | ".join(_convergence_cells(r)) + " |")
    return L


def _singular_mass_table(res):
    hs = sorted({x["h"] for r in res["singular_mass"] for x in r["runs"]}, reverse=True)
    L = ["| m1 | cond0 | method | " + " | ".join(f"h = {h:g}" for h in hs) + " | reference |",
         "|---|---|---|" + "---|" * len(hs) + "---|"]
    for r in res["singular_mass"]:
        if "input_error" in r:
            L.append(f"| {r['m1']:g} | inf | {r['method']} | " + " | ".join(["ValueError at input (M not positive "
                     "definite at q0)"] + ["-"] * (len(hs) - 1)) + " | - |")
            continue
        cells = []
        for h in hs:
            x = next((x for x in r["runs"] if x["h"] == h), None)
            if x is None:
                cells.append("-")
            elif x["status"] == "ok":
                good = r.get("ref_accuracy", np.inf) < 1e-6
                cells.append(f"ok, L2 {_g(x.get('l2'))}" if good and "l2" in x else f"ok, dH {_g(x.get('dH'))}")
            else:
                cells.append(_short(x["status"], x.get("cause", "")))
        refc = (f"acc {_g(r.get('ref_accuracy'))}" if "ref_accuracy" in r else r.get("ref_error", "-")[:60])
        tag = f"{r['m1']:g}" + (" (non-aligned start)" if r["m1"] == 0 else "")
        L.append(f"| {tag} | {_g(r.get('cond0'))} | {r['method']} | " + " | ".join(cells) + f" | {refc} |")
    return L


def _hygiene_table(res):
    hy = res["hygiene"]
    L = ["| scene | h | T | method | outcome | impacts | finite |", "|---|---|---|---|---|---|---|"]
    for c in hy.get("cases", []):
        L.append(f"| {c['system']} | {_num(c['h'])} | {_num(c['T'])} | {c['method']} | {c['status']} | "
                 f"{c.get('impacts', '-')} | {c.get('finite', '-')} |")
    if hy.get("error"):
        L.append(f"\nhygiene run failed: `{hy['error'][-300:]}`")
    return L


_TABLES = {"step_limit": _step_limit_table, "long_horizon": _long_horizon_table, "grazing": _grazing_tables,
           "boundary": _boundary_table, "dense": _dense_table, "surface": _surface_table,
           "accumulation": _accumulation_table, "energy": _energy_table, "mass_ratio": _mass_ratio_table,
           "singular_mass": _singular_mass_table, "hygiene": _hygiene_table}


# --- the context -----------------------------------------------------------------------------------
def present_sections(res: dict) -> list[str]:
    return [s for s in SECTIONS if res.get(s)]


def extremes_context(res: dict, *, command: str, config: str, template: str, json_path: str) -> dict:
    """Every value the extremes template may use: run facts, one table per present section, and the
    numbers the section introductions quote (read from the results, so they always match the tables)."""
    # the introductions' numbers of absent sections (only the overview quotes them unconditionally)
    ctx = dict.fromkeys(("step_h_min", "step_h_max", "step_T", "step_per_decade", "step_rel_percent", "long_steps",
                         "long_steps_e", "long_h", "long_T", "long_start", "long_checkpoints", "long_n_checkpoints",
                         "accumulation_c", "accumulation_T", "energy_beta_max", "energy_T", "mass_ratio_T",
                         "mass_ratio_min", "mass_ratio_max", "hygiene_control"), "-")
    ctx |= {"command": command, "config": config, "template": template, "json": json_path,
           "started": res.get("started", ""), "wall_time": f"{res.get('wall_time', 0):.0f}",
           "methods": ", ".join(res.get("methods", [])), "overview_table": "\n".join(_overview_table(res)),
           "long_horizon_growth": _long_horizon_growth(res)}
    for sec in present_sections(res):
        ctx[f"{sec}_table"] = "\n".join(_TABLES[sec](res))
    sl = res.get("step_limit") or []
    if sl:
        r0 = sl[0]
        ctx.update(step_h_min=_pow10(r0["h_min"]), step_h_max=_num(r0["h_max"]),
                   step_T=", ".join(_num(t) for t in _unique(r["T"] for r in sl)),
                   step_per_decade=_num(r0.get("per_decade", float("nan"))),
                   step_rel_percent=_num(100 * r0.get("rel", float("nan"))))
    lh = res.get("long_horizon") or []
    if lh:
        r0 = lh[0]
        cps = _checkpoints(r0)
        ctx.update(long_steps=_pow10(r0["steps"]), long_steps_e=f"{r0['steps']:.0e}", long_h=_num(r0["h"]),
                   long_T=f"{r0['steps'] * r0['h']:g}",
                   long_start=f"Xi({_num(r0['beta'])})" if r0.get("beta") is not None else "the default state",
                   long_checkpoints=", ".join(_pow10(c) for c in cps), long_n_checkpoints=_COUNT.get(len(cps), len(cps)))
    acc = res.get("accumulation") or []
    if acc:
        ctx.update(accumulation_c=str(float(acc[0]["c"])), accumulation_T=_num(acc[0]["T"]))
    en = res.get("energy") or []
    if en:
        ctx.update(energy_beta_max=_num(max(r["beta"] for r in en)),
                   energy_T=", ".join(_num(t) for t in _unique(r["T"] for r in en)))
    mr = res.get("mass_ratio") or []
    if mr:
        ctx.update(mass_ratio_T=_num(mr[0]["T"]), mass_ratio_min=_pow10(min(r["ratio"] for r in mr)),
                   mass_ratio_max=_pow10(max(r["ratio"] for r in mr)))
    hy = res.get("hygiene") or {}
    if hy:
        ctx["hygiene_control"] = hy.get("control", "-")
    return ctx


def render_extremes(res: dict, template_path, *, command: str, config: str, json_path: str) -> str:
    """docs/extremes.md: the template at template_path filled from the study results."""
    p = Path(template_path)
    text = p.read_text(encoding="utf-8")
    ctx = extremes_context(res, command=command, config=config, template=str(template_path), json_path=json_path)
    return render(text, ctx, present_sections(res), source=str(template_path))
