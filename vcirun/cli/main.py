"""The `vcirun` command line (entry point `vcirun = vcirun.cli.main:app`): presentation over the
Python API and vcirun.experiments, one module per command group.

- vcirun.cli.app: the Typer app, the one-line error rule, the console;
- vcirun.cli.simulate: `simulate`;
- vcirun.cli.animate: `animate`;
- vcirun.cli.results: `sweep`, `plot`, `validate`, `study`, `info`;
- vcirun.cli.verify: `verify`;
- vcirun.cli.systems: `systems`;
- vcirun.cli.periodic: `periodic`;
- vcirun.cli.cache: `cache info`, `cache clear`;
- vcirun.cli.recommend: `recommend`.

Expected failures (bad config, unusable results file, bad option values) print one line
`error: ...` on stderr and exit with status 1; an interrupted sweep exits 130 (SIGINT) or 143
(SIGTERM) after saving every finished run. Unexpected exceptions keep their traceback (bugs).
"""
from __future__ import annotations

from .app import app

# each module registers its commands on `app` when imported, in the order `vcirun --help` lists them
from . import simulate
from . import animate
from . import results
from . import verify
from . import systems
from . import periodic
from . import cache
from . import recommend

COMMAND_MODULES = (simulate, animate, results, verify, systems, periodic, cache, recommend)


def main() -> None:  # pragma: no cover - console entry point alternative
    app()


if __name__ == "__main__":
    app()
