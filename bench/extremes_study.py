"""The stress study of issue 8 ("Numerical stability at the extremes"): one command for the table.

    .venv/bin/python bench/extremes_study.py [configs/extremes.yaml] [--only SECTION ...]

Runs every section of the config through vcirun.stress, writes the raw numbers to
results/extremes.json and the tables to docs/extremes.md (the README's section is pasted from
there). With --only, the other sections are taken from an existing results/extremes.json, so a
single section can be refreshed without rerunning the rest.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from vcirun import stress  # noqa: E402


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if np.isfinite(x) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def _restore(x):
    """JSON null (non-finite float) back to nan, so the renderer prints '-'."""
    if isinstance(x, dict):
        return {k: _restore(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_restore(v) for v in x]
    return float("nan") if x is None else x


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config", nargs="?", default=str(ROOT / "configs" / "extremes.yaml"))
    ap.add_argument("--only", nargs="*", help="sections to (re)run; the rest is read from the JSON")
    args = ap.parse_args(argv)
    cfg = stress.load_study_config(args.config)
    out_md = ROOT / cfg.get("output", "docs/extremes.md")  # (absolute paths in the config stay absolute)
    out_json = ROOT / cfg.get("json", "results/extremes.json")
    res = stress.run_study(cfg, log=lambda m: print(m, flush=True), only=set(args.only) if args.only else None)
    if args.only and out_json.exists():
        old = _restore(json.loads(out_json.read_text()))
        old.update({k: v for k, v in res.items() if k in args.only or k in ("methods",)})
        res = old
    out_json.parent.mkdir(parents=True, exist_ok=True)
    out_json.write_text(json.dumps(_jsonable(res), indent=1))
    out_md.parent.mkdir(parents=True, exist_ok=True)
    cmd = "python bench/extremes_study.py" + ("" if Path(args.config).name == "extremes.yaml" else f" {args.config}")
    out_md.write_text(stress.render_markdown(_restore(_jsonable(res)), cmd))
    print(f"wrote {out_md} and {out_json}")


if __name__ == "__main__":
    main()
