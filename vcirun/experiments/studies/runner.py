"""Run a study config: validate it, dispatch on its kind, save the JSON results (and the report).

`run_file(path, ...)` is what `vcirun study CONFIG` and the bench scripts call:

- work_precision / long_horizon: `vcirun.experiments.workprecision.run_study`, results to `output`
  (JSON, with the scene's work-precision model `model` for work_precision: `wp_model.from_study`),
  tables printed, figures with `plot=True`; `quick=True` for a smoke run.
- extremes: `vcirun.experiments.studies.extremes.run_extremes`, results to `output` (JSON), then
  the report (`report.output`, Markdown) rendered from them through `report.template`. With `only`,
  just those sections run and the others are kept from the existing JSON, so one section can be
  refreshed without rerunning the rest.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from ..config import ConfigError
from .jsonio import load_json, nan_for_null, save_json, to_json
from .schema import ExtremesStudy, load_study

__all__ = ["StudyRun", "run_file", "run_config"]


@dataclass
class StudyRun:
    """What a study wrote: its kind, the JSON results, the report / figures, and how long it took."""
    study: str
    name: str
    results: Path
    report: Path | None = None
    figures: list[Path] = field(default_factory=list)
    seconds: float = 0.0


def _check_options(cfg, source: str, *, quick: bool, only) -> None:
    if isinstance(cfg, ExtremesStudy):
        if quick:
            raise ConfigError("--quick is for work-precision and long-horizon studies (give --only SECTION to run "
                              "part of an extremes study)", source=source)
        for s in only or ():
            if s not in cfg.sections():
                raise ConfigError(f"--only: {s!r} is not a section of this study (it has: {', '.join(cfg.sections())})",
                                  source=source)
    elif only:
        raise ConfigError("--only is for extremes studies (give --quick for a short work-precision run)", source=source)


def run_config(cfg, *, source: str = "<study>", output=None, quick: bool = False, only=None, plot: bool = False,
               log=print, tables="stdout", command: str | None = None, report_output=None) -> StudyRun:
    """Run a validated study config (see the module docstring); `tables`: a file where the work-precision
    tables are printed ("stdout": sys.stdout at the time of the call; None: not printed). The study's
    files go where the config says (results/ in the shipped configs) and never over a file the git
    repository tracks, unless named here: `output` (the JSON) or `report_output` (an extremes study's
    Markdown; `make extremes` regenerates docs/extremes.md this way). Python warnings of the runs
    (a grid note, ...) are logged once each as `note: ...` lines, not printed with their source lines."""
    import warnings

    _check_options(cfg, source, quick=quick, only=only)
    _not_tracked(quick_output(cfg.output, quick) if output is None else None, "output", source)
    if isinstance(cfg, ExtremesStudy) and cfg.report is not None and report_output is None:
        _not_tracked(cfg.report.output, "report.output", source)
    t0 = time.perf_counter()
    seen = set()

    def note(message, category, filename, lineno, file=None, line=None):
        text = f"note: {' '.join(str(message).split())}"
        if text not in seen:
            seen.add(text)
            log(text)

    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = note
        return _run(cfg, source, output, quick, only, plot, log, tables, command, report_output, t0)


def _not_tracked(path, field: str, source: str) -> None:
    """A ConfigError if `path` is a file the git repository around it tracks (the study would rewrite it)."""
    import subprocess

    if path is None or not Path(path).is_file():
        return
    p = Path(path).resolve()
    try:
        tracked = subprocess.run(["git", "-C", str(p.parent), "ls-files", "--error-unmatch", p.name],
                                 capture_output=True, timeout=10).returncode == 0
    except (OSError, subprocess.SubprocessError):   # no git: nothing is tracked
        return
    if tracked:
        raise ConfigError(f"{path} is a file of the repository (tracked by git); a study writes under results/: "
                          "set it to a path there", source=source, field=field)


def _run(cfg, source, output, quick, only, plot, log, tables, command, report_output, t0) -> StudyRun:
    if isinstance(cfg, ExtremesStudy):
        return _run_extremes(cfg, source, output=output, only=only, log=log, command=command, t0=t0,
                             report_output=report_output)
    from .. import workprecision as wp

    res = wp.run_study(cfg, quick=quick, log=log)
    if res.get("study") == "work_precision":   # the scene's work-precision model, for `vcirun recommend`
        from .wp_model import from_study

        res["model"] = from_study(res)
    path = wp.save(res, output or quick_output(cfg.output, quick))
    if tables is not None:
        wp.print_tables(wp.load(path), file=sys.stdout if tables == "stdout" else tables)
    figures = []
    if plot:
        from ..wp_figures import plot_study

        figures = list(plot_study(path))
    return StudyRun(cfg.study, res["name"], path, figures=figures, seconds=time.perf_counter() - t0)


def quick_output(path, quick: bool):
    """The results file of a study: the config's, or beside it with `_quick` for a smoke run (--quick),
    so that a smoke run never replaces full results."""
    path = Path(path)
    return path.with_name(f"{path.stem}_quick{path.suffix}") if quick else path


def _run_extremes(cfg: ExtremesStudy, source, *, output, only, log, command, t0, report_output=None) -> StudyRun:
    from .extremes import run_extremes
    from .report import render_extremes

    only = set(only) if only else None
    out_json = Path(output or cfg.output)
    res = run_extremes(cfg, log=log, only=only)
    if only and out_json.exists():
        old = nan_for_null(load_json(out_json))
        old.update({k: v for k, v in res.items() if k in only or k == "methods"})
        res = old
    save_json(res, out_json)
    report = None
    if cfg.report is not None:
        report = Path(report_output or cfg.report.output)
        report.parent.mkdir(parents=True, exist_ok=True)
        cmd = command or f"vcirun study {source}"
        report.write_text(render_extremes(nan_for_null(to_json(res)), cfg.report.template, command=cmd,
                                          config=source, json_path=str(out_json)))
    return StudyRun("extremes", cfg.name, out_json, report=report, seconds=time.perf_counter() - t0)


def run_file(path, **kw) -> StudyRun:
    """Validate the study config at `path` (one-line ConfigError on any problem) and run it; keyword
    arguments as `run_config`."""
    return run_config(load_study(path), source=str(path), **kw)
