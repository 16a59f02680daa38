"""The work-precision model of a scene from stored measurements: per method, the error constant of
e = C_h h^p (p the method's verified order through impacts) and the cost a + b N of an N-step run,
and from them the method and h predicted to reach an L2 error tol at the least cost.

Sources: a work-precision study's results (`vcirun study`, kind work_precision: its summary, medians
over initial conditions; the runner keeps the model in the JSON as "model") and a sweep's results
file (`vcirun.open_results`: medians over initial conditions of l2_error and wall_time). `vcirun
recommend SYSTEM --tol TOL` reads them (vcirun.cli.recommend).

Fit. Per method the points (h, median error) are taken from the coarsest h whose error shrinks at
least at order p - 1 to the next finer h, down to the finest h above the reference's floor (three
times its self-reported accuracy: errors there are the reference's); C_h is the median of e / h^p
over those points. The cost a + b N of an N-step run is the least-squares line through the points
(a at least 0). Prediction for tol: h = (TARGET tol
/ C_h)^(1/p) (TARGET of vcirun.run.choose), at most the coarsest h fitted; flagged "extrapolated"
where h lies outside the fitted range and "below the measurements" where tol is below the smallest
error measured.
"""
from __future__ import annotations

import math
import statistics

MODEL_VERSION = 1


def _order(label: str, spec=None):
    from ...methods.table import resolve_method

    try:
        if spec is not None:
            m = resolve_method(spec["name"], **{k: v for k, v in spec.items()
                                                if k in ("ld", "mh_order", "flow_order") and v is not None})
        else:
            m = resolve_method(label)
        return int(m.impact_order)
    except (ValueError, KeyError, TypeError):
        return None


def fit_points(points: list, order: int, T: float, floor: float = 0.0) -> dict:
    """The model of one method from points [{"h", "err", "cost", "N"}] (medians over initial conditions;
    err NaN where a run failed)."""
    pts = sorted([p for p in points if p.get("err") is not None and math.isfinite(p["err"]) and p["err"] > 0],
                 key=lambda p: -p["h"])
    out = {"order": order, "points": len(pts), "C_h": None, "a": None, "b": None, "h_fit": None,
           "err_min": min((p["err"] for p in pts), default=None), "note": ""}
    costs = [p for p in points if p.get("cost") is not None and math.isfinite(p["cost"]) and p.get("N")]
    if costs:
        # least squares cost = a + b N (the large runs set b; a at least 0)
        Ns = [float(p["N"]) for p in costs]
        cs = [float(p["cost"]) for p in costs]
        if len(costs) >= 2 and max(Ns) > min(Ns):
            mN, mc = statistics.fmean(Ns), statistics.fmean(cs)
            b = sum((n - mN) * (c - mc) for n, c in zip(Ns, cs)) / sum((n - mN) ** 2 for n in Ns)
            if not b > 0:
                b = max(cs) / max(Ns)
            a = max(0.0, mc - b * mN)
        else:
            a, b = 0.0, cs[0] / Ns[0]
        out["a"], out["b"] = a, b
    if len(pts) < 2 or not order:
        out["note"] = "fewer than two points" if order else "order unknown"
        return out
    usable = []
    for p, q in zip(pts[:-1], pts[1:]):
        if q["err"] <= floor:
            break
        obs = math.log(p["err"] / q["err"]) / math.log(p["h"] / q["h"])
        if obs >= order - 1.0:
            usable += [x for x in (p, q) if not any(x is y for y in usable)]
    if not usable:
        usable = [p for p in pts if p["err"] > floor]
        out["note"] = "no two steps shrink the error at the order: pre-asymptotic fit"
    if not usable:
        out["note"] = "every error is at the reference's floor"
        return out
    out["C_h"] = statistics.median([p["err"] / p["h"] ** order for p in usable])
    out["h_fit"] = [usable[-1]["h"], usable[0]["h"]]
    return out


def predict(model: dict, tol: float, T: float) -> list[dict]:
    """Rows {method, order, C_h, h, N, predicted_error, predicted_cost, note} sorted by predicted cost
    (methods that cannot be predicted last)."""
    from ...run.choose import TARGET

    rows = []
    for label, m in model["methods"].items():
        row = {"method": label, "order": m["order"], "C_h": m["C_h"], "b": m["b"], "h": None, "N": None,
               "predicted_error": None, "predicted_cost": None, "note": m.get("note", "")}
        if m["C_h"] is None or m["b"] is None:
            rows.append(row)
            continue
        p = m["order"]
        h = (TARGET * tol / m["C_h"]) ** (1.0 / p) if m["C_h"] > 0 else T
        lo, hi = m["h_fit"]
        notes = []
        if h > hi:
            h = hi
            notes.append("coarsest fitted h")
        elif h < lo:
            notes.append("extrapolated below the finest fitted h")
        if m.get("err_min") is not None and tol < m["err_min"]:
            notes.append("tol below the smallest error measured")
        N = max(1, math.ceil(T / h - 1e-9))
        row.update(h=T / N, N=N, predicted_error=m["C_h"] * (T / N) ** p, predicted_cost=(m["a"] or 0.0) + m["b"] * N)
        row["note"] = "; ".join([x for x in [row["note"]] + notes if x])
        rows.append(row)
    return sorted(rows, key=lambda r: (r["predicted_cost"] is None, r["predicted_cost"] or 0.0))


def from_study(res: dict) -> dict:
    """The model of a work-precision study's results (its summary: medians over initial conditions,
    CPU seconds of the whole call)."""
    cfg = res.get("config") or {}
    specs = {}
    for m in cfg.get("methods") or []:
        spec = {"name": m} if isinstance(m, str) else dict(m)
        label = spec.get("label") or _display(spec)
        specs[label] = spec
    refs = res.get("references") or []
    acc = [r.get("accuracy") for r in refs if r.get("accuracy") is not None and math.isfinite(r.get("accuracy"))]
    floor = 3.0 * max(acc) if acc else 0.0
    models = {}
    for T in sorted({p["T"] for p in res.get("summary", [])}):
        methods = {}
        for label in sorted({p["label"] for p in res["summary"] if p["kind"] == "vcirun" and p["T"] == T}):
            pts = [{"h": p["h"], "err": p["err"] if p.get("all_ok") else math.nan, "cost": p.get("cpu"),
                    "N": max(1, math.floor(T / p["h"] + 1e-9))}
                   for p in res["summary"] if p["kind"] == "vcirun" and p["label"] == label and p["T"] == T]
            order = _order(label, specs.get(label))
            methods[label] = fit_points(pts, order, T, floor)
        models[f"{T:g}"] = {"T": T, "methods": methods}
    return {"version": MODEL_VERSION, "system": cfg.get("system"), "params": cfg.get("params") or {},
            "source": f"work-precision study {res.get('name')}", "cost": "CPU seconds of the whole simulate() call",
            "floor": floor, "horizons": models}


def _display(spec: dict) -> str:
    from ..config.specs import MethodSpec

    try:
        return MethodSpec(**spec).display
    except Exception:  # noqa: BLE001 - a label only
        return str(spec.get("name"))


def from_results(path) -> dict:
    """The model of a sweep's results file (medians over initial conditions of l2_error and wall_time,
    the compiled loop's time)."""
    import numpy as np

    from ...io.reader import read_results
    from ...io.results import collect

    res = read_results(path)
    table = collect(res)
    a = res.attrs
    T = float(a.get("T", float("nan")))
    labels = list(table.dims["method"])
    hs = list(table.dims["h"])
    l2 = table.variables.get("l2_error")
    wall = table.variables.get("wall_time")
    status = table.variables.get("status")
    specs = {m.get("label"): m for m in (a.get("methods") or []) if isinstance(m, dict)}
    acc = table.variables.get("reference_accuracy")
    floor = 3.0 * float(np.nanmax(acc[1])) if acc is not None and np.isfinite(acc[1]).any() else 0.0
    methods = {}
    for i, label in enumerate(labels):
        if isinstance(specs.get(label), dict) and specs[label].get("tol") is not None:
            continue   # runs of simulate(tol=...): their h is chosen per run, not a point of a method's curve
        pts = []
        for j, h in enumerate(hs):
            ok = status is not None and all(s == "ok" for s in status[1][i, j])
            err = float(np.median(l2[1][i, j])) if l2 is not None and ok else math.nan
            cost = float(np.median(wall[1][i, j])) if wall is not None and ok else math.nan
            pts.append({"h": float(h), "err": err, "cost": cost, "N": max(1, math.floor(T / h + 1e-9))})
        spec = specs.get(label)
        spec = (spec.get("spec") or spec) if isinstance(spec, dict) else None
        methods[str(label)] = fit_points(pts, _order(str(label), _spec_of(spec, label)), T, floor)
    return {"version": MODEL_VERSION, "system": str(a.get("system", "")), "params": {},
            "source": f"sweep results {path}", "cost": "compiled-loop seconds (wall_time)", "floor": floor,
            "horizons": {f"{T:g}": {"T": T, "methods": methods}}}


def _spec_of(spec, label):
    if not isinstance(spec, dict):
        return None
    keys = {k: spec.get(k) for k in ("name", "ld", "mh_order", "flow_order") if spec.get(k) is not None}
    return keys if "name" in keys else None
