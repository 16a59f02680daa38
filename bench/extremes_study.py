"""The stress study ("Numerical stability at the extremes"): `make extremes`.

    .venv/bin/python bench/extremes_study.py [configs/extremes.yaml] [--only SECTION ...]

`vcirun study configs/extremes.yaml [--only SECTION,...]` (vcirun.experiments.studies.runner) with the
report written to the documentation page: every section of the config to results/extremes.json, and
docs/extremes.md rendered from it through docs/templates/extremes.md. With --only, the other sections
are taken from the existing JSON.
Paths in the config are taken from the repository root.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from vcirun.experiments.config import ConfigError  # noqa: E402
from vcirun.experiments.studies.runner import run_file  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config", nargs="?", default="configs/extremes.yaml")
    ap.add_argument("--only", nargs="*", help="sections to (re)run; the rest is read from the JSON")
    args = ap.parse_args(argv)
    config = os.path.relpath(Path(args.config).resolve(), ROOT)
    os.chdir(ROOT)   # the config's output paths are relative to the working directory
    cmd = "python bench/extremes_study.py" + ("" if Path(config).name == "extremes.yaml" else f" {config}")
    try:
        out = run_file(config, only=args.only or None, log=lambda m: print(m, flush=True), command=cmd,
                       report_output="docs/extremes.md")
    except ConfigError as e:
        raise SystemExit(f"error: {e}")
    print(f"wrote {out.report} and {out.results}")


if __name__ == "__main__":
    main()
