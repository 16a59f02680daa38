"""The schema of study configs (`vcirun study CONFIG`): one validated model per kind, chosen by `study:`.

A study config is a YAML file whose top level has the key `study:` (`vcirun.experiments.config.STUDY_KEY`;
a sweep config has none). Its value picks the model:

- `study: work_precision` / `study: long_horizon` -> `WorkPrecisionStudy` (`configs/work_precision*.yaml`,
  `configs/long_horizon.yaml`): a grid of vcirun methods and steps beside scipy's solve_ivp at
  tolerances, timed (protocol in `vcirun.experiments.workprecision`).
- `study: extremes` -> `ExtremesStudy` (`configs/extremes.yaml`): hard cases, each section a family of
  runs (`vcirun.experiments.studies.extremes`), rendered into Markdown through a template.

The vocabulary is the sweep's (`system`, `params`, `methods` as in a sweep, `h`, `beta` as a list or
{start, stop, num}, `T`) and so are the rules: unknown keys are rejected everywhere, every problem
is one line ``<file>: <field>: <what is wrong>``. Paths: `output` and `report.output` are relative to
the working directory (like a sweep's `output`), `report.template` to the config file (like a
system file).

`load_study(path)` validates a study config; `load_any(path)` a sweep or a study config (what
`vcirun validate` runs).
"""
from __future__ import annotations

import difflib
import json
import os
from pathlib import Path
from typing import Literal, Union

from pydantic import Field, ValidationError, field_validator, model_validator

from ..baselines import BASELINES
from ..config import STUDY_KEY, ConfigError, MethodSpec, parse_config, read_config_data
from ..config.errors import FieldError
from ..config.messages import from_validation_error
from ..config.specs import BetaSpec, ConfigModel, MethodName, PositiveFloat
from ...scenes.registry import BUILTIN_SCENES

__all__ = ["WorkPrecisionStudy", "ExtremesStudy", "STUDY_MODELS", "parse_study", "load_study", "load_any"]


def _method_shorthand(v):
    if isinstance(v, list):
        return [{"name": m} if isinstance(m, str) else m for m in v]
    return v


# --- work precision and long horizons -------------------------------------------------------------
class WorkPrecisionStudy(ConfigModel):
    """Accuracy against time of vcirun methods beside solve_ivp (see vcirun.experiments.workprecision)."""
    study: Literal["work_precision", "long_horizon"]
    name: str = Field(min_length=1)
    description: str = ""
    system: str = Field(min_length=1)          # a built-in scene or a YAML system file
    params: dict[str, float] = Field(default_factory=dict)
    beta: BetaSpec
    T: Union[PositiveFloat, list[PositiveFloat]]   # long_horizon: a list of horizons
    methods: list[MethodSpec] = Field(min_length=1)
    h: list[PositiveFloat] = Field(min_length=1)
    baselines: dict[str, list[PositiveFloat]] = Field(default_factory=dict)  # solver -> rtols; "DOP853/numpy"
    baseline_h: Union[PositiveFloat, None] = None   # solve_ivp's output grid; null: every h of the methods
    baseline_max_T: dict[str, PositiveFloat] = Field(default_factory=dict)   # skip a solver on longer T
    repeats: int = Field(default=7, ge=1, le=1000)
    baseline_repeats: int = Field(default=5, ge=1, le=1000)
    reference_rtol: float = Field(default=1e-13, gt=0)
    max_steps: int = Field(default=2_000_000, ge=1)
    baseline_time_limit: PositiveFloat = 60.0
    output: str = "results/work_precision.json"

    @field_validator("methods", mode="before")
    @classmethod
    def _method_shorthand(cls, v):
        return _method_shorthand(v)

    @field_validator("beta", mode="before")
    @classmethod
    def _beta_shorthand(cls, v):
        if isinstance(v, (list, tuple)):
            return {"values": list(v)}
        return v

    @model_validator(mode="after")
    def _consistent(self):
        _unique_labels(self.methods)
        T_min = min(self.horizons())
        for i, h in enumerate(self.h):
            if h > T_min:
                raise FieldError(("h", i), f"{h:g} is longer than T = {T_min:g}: every step must be at most the "
                                           "horizon")
        for b in self.baselines:
            solver, _, rhs = b.partition("/")
            if solver not in BASELINES or rhs not in ("", "numpy"):
                raise FieldError(("baselines", b), f"unknown solver (choose from {', '.join(BASELINES)}; append "
                                                    "'/numpy' for a lambdified numpy right-hand side, e.g. DOP853/numpy)")
        for b in self.baseline_max_T:
            if b not in self.baselines:
                raise FieldError(("baseline_max_T", b), f"not a solver of baselines ({', '.join(self.baselines)})")
        return self

    def betas(self) -> list[float]:
        return self.beta.values()

    def horizons(self) -> list[float]:
        return [float(t) for t in (self.T if isinstance(self.T, list) else [self.T])]

    def method_specs(self) -> list[MethodSpec]:
        return list(self.methods)

    def baseline_grids(self) -> list[float]:
        return [float(self.baseline_h)] if self.baseline_h is not None else sorted(set(self.h), reverse=True)

    def describe(self) -> list[tuple[str, str]]:
        """What `vcirun validate` prints about the study."""
        b = self.betas()
        return [("system", self.system + (f" {self.params}" if self.params else "")),
                ("methods", ", ".join(m.display for m in self.methods)),
                ("h", ", ".join(f"{h:g}" for h in self.h)),
                ("beta", f"{len(b)} value(s) in [{min(b):g}, {max(b):g}]"),
                ("T", ", ".join(f"{t:g}" for t in self.horizons())),
                ("baselines", ", ".join(f"{k} ({len(v)} rtols)" for k, v in self.baselines.items()) or "none"),
                ("repeats", f"{self.repeats} vcirun, {self.baseline_repeats} solve_ivp"),
                ("output", self.output)]


def _unique_labels(methods):
    seen: dict[str, int] = {}
    for i, m in enumerate(methods):
        if m.display in seen:
            raise FieldError(("methods", i), f"duplicate label {m.display!r} (also methods[{seen[m.display]}]); "
                                              "give one of them a different label")
        seen[m.display] = i


# --- extremes: one model per section -----------------------------------------------------------------
# Each section is one family of runs of vcirun.experiments.studies (its docstring says what is measured
# against which oracle); the defaults are the ones the functions use.
# the scenes with a known construction of a grazing contact and of a start on the surface (their StudyHooks)
ContactScene = Literal[tuple(name for name, s in BUILTIN_SCENES.items()
                             if s.study is not None and s.study.graze is not None and s.study.surface is not None)]


class _Scene(ConfigModel):
    system: str = Field(min_length=1)
    beta: float | None = None


class StepLimitScene(_Scene):
    T: PositiveFloat


class StepLimit(ConfigModel):
    """Largest h at which every scanned step from h_min up returns ok (log scan, then bisection)."""
    h_min: PositiveFloat = 1e-5
    h_max: PositiveFloat = 2.0
    per_decade: int = Field(default=4, ge=1, le=100)
    rel: PositiveFloat = 1e-3
    scenes: list[StepLimitScene] = Field(min_length=1)

    @model_validator(mode="after")
    def _range(self):
        if self.h_min >= self.h_max:
            raise FieldError(("h_max",), f"must be > h_min = {self.h_min:g} (got {self.h_max:g})")
        return self


class LongHorizon(ConfigModel):
    """`steps` steps with impacts: drift of H (and Hmod for the MCVA family)."""
    system: str = "cart_pendulum"
    beta: float | None = None
    h: PositiveFloat
    steps: int = Field(ge=2, le=100_000_000)


class GrazingScene(ConfigModel):
    system: ContactScene
    beta: float | None = None


class Grazing(ConfigModel):
    """Grazing contacts: penetration depth of the unconstrained motion (normal velocity sqrt(2 phi'' depth))."""
    h: PositiveFloat
    after: PositiveFloat = 0.5
    depths: list[PositiveFloat] = Field(min_length=1)
    scenes: list[GrazingScene] = Field(min_length=1)


class BoundaryScene(_Scene):
    k: int = Field(ge=1, le=100_000)
    T: PositiveFloat


class Boundary(ConfigModel):
    """Impact exactly at t = k h (grid state phi < 0, == 0.0, > 0 by round-off)."""
    h: PositiveFloat
    scenes: list[BoundaryScene] = Field(min_length=1)


class DenseScene(_Scene):
    q0: list[float] | None = None
    p0: list[float] | None = None
    params: dict[str, float] | None = None
    h: PositiveFloat
    T: PositiveFloat

    @model_validator(mode="after")
    def _state(self):
        if (self.q0 is None) != (self.p0 is None):
            raise FieldError(("p0" if self.p0 is None else "q0",), "give q0 and p0 together")
        if self.q0 is not None and len(self.q0) != len(self.p0):
            raise FieldError(("p0",), f"must have the length of q0 ({len(self.q0)})")
        return self


class Dense(ConfigModel):
    """Several impacts in one step."""
    scenes: list[DenseScene] = Field(min_length=1)


class SurfaceScene(ConfigModel):
    system: ContactScene
    kinds: list[Literal["out", "in", "lift", "rest"]] = Field(min_length=1)

    @model_validator(mode="after")
    def _refused(self):
        refused = BUILTIN_SCENES[self.system].study.refused   # kinds the scene has no construction for
        for i, kind in enumerate(self.kinds):
            if kind in refused:
                raise FieldError(("kinds", i), refused[kind])
        return self


class Surface(ConfigModel):
    """Initial state on the constraint surface."""
    h: PositiveFloat
    T: PositiveFloat
    scenes: list[SurfaceScene] = Field(min_length=1)


class Accumulation(ConfigModel):
    """Bouncing ball with linear drag through the forced DEL."""
    h: list[PositiveFloat] = Field(min_length=1)
    T: PositiveFloat
    y0: PositiveFloat = 1.0
    c: PositiveFloat = 2.0


class Energy(ConfigModel):
    """Xi(beta) of the cart-pendulum up to large beta (the pendulum rotates fully)."""
    betas: list[float] = Field(min_length=1)
    h: list[PositiveFloat] = Field(min_length=1)
    T: PositiveFloat


class MassRatio(ConfigModel):
    """Cart-pendulum, m1 = 1, m2 = ratio."""
    ratios: list[PositiveFloat] = Field(min_length=1)
    h: list[PositiveFloat] = Field(min_length=1)
    T: PositiveFloat


class SingularMass(ConfigModel):
    """Double pendulum with m1 -> 0 (aligned release: cond(M) = 4 / m1), and m1 = 0 from a non-aligned start."""
    m1: list[PositiveFloat] = Field(min_length=1)
    h: list[PositiveFloat] = Field(min_length=1)
    T: PositiveFloat
    nonaligned_q0: list[float] = Field(min_length=2, max_length=2)


class HygieneKw(ConfigModel):
    """Initial state of a hygiene run (passed to simulate and reference)."""
    beta: float | None = None
    q0: list[float] | None = None
    p0: list[float] | None = None
    params: dict[str, float] | None = None


class HygieneScene(ConfigModel):
    system: str = Field(min_length=1)
    h: PositiveFloat
    T: PositiveFloat
    kw: HygieneKw = Field(default_factory=HygieneKw)
    reference: bool = False       # also the exact reference under np.errstate


class Hygiene(ConfigModel):
    """The whole loop uncompiled under np.errstate(all="raise")."""
    scenes: list[HygieneScene] = Field(min_length=1)


class Report(ConfigModel):
    """The Markdown rendered from the results through a template (see studies.report)."""
    template: str = Field(min_length=1)        # relative to the config file
    output: str = Field(min_length=1)          # relative to the working directory


SECTIONS = ("step_limit", "long_horizon", "grazing", "boundary", "dense", "surface", "accumulation", "energy",
            "mass_ratio", "singular_mass", "hygiene")


class ExtremesStudy(ConfigModel):
    """Numerical stability at the extremes: each present section runs for every method."""
    study: Literal["extremes"]
    name: str = Field(min_length=1)
    description: str = ""
    methods: list[MethodName] = Field(min_length=1)
    output: str = "results/extremes.json"
    report: Union[Report, None] = None
    step_limit: Union[StepLimit, None] = None
    long_horizon: Union[LongHorizon, None] = None
    grazing: Union[Grazing, None] = None
    boundary: Union[Boundary, None] = None
    dense: Union[Dense, None] = None
    surface: Union[Surface, None] = None
    accumulation: Union[Accumulation, None] = None
    energy: Union[Energy, None] = None
    mass_ratio: Union[MassRatio, None] = None
    singular_mass: Union[SingularMass, None] = None
    hygiene: Union[Hygiene, None] = None

    @model_validator(mode="after")
    def _something(self):
        if not self.sections():
            raise FieldError((), f"no section to run (give one or more of {', '.join(SECTIONS)})")
        dup = [m for i, m in enumerate(self.methods) if m in self.methods[:i]]
        if dup:
            raise FieldError(("methods", self.methods.index(dup[0], self.methods.index(dup[0]) + 1)),
                              f"duplicate method {dup[0]}")
        return self

    def sections(self) -> list[str]:
        return [s for s in SECTIONS if getattr(self, s) is not None]

    def describe(self) -> list[tuple[str, str]]:
        rep = self.report
        return [("methods", ", ".join(self.methods)), ("sections", ", ".join(self.sections())),
                ("output", self.output), ("report", f"{rep.output} (template {rep.template})" if rep else "none")]


STUDY_MODELS = {"work_precision": WorkPrecisionStudy, "long_horizon": WorkPrecisionStudy, "extremes": ExtremesStudy}
StudyConfig = Union[WorkPrecisionStudy, ExtremesStudy]


# --- loading -----------------------------------------------------------------------------------------
def parse_study(data, *, source: str = "<study>", base_dir: Path | None = None,
                check_semantics: bool = True) -> StudyConfig:
    """Validate a study config mapping (top-level `study:` picks the model); ConfigError on any problem.
    A relative report.template is resolved against base_dir (the config file's folder)."""
    if not isinstance(data, dict) or STUDY_KEY not in data:
        raise ConfigError(f"a study config needs the top-level key {STUDY_KEY}: (one of {', '.join(STUDY_MODELS)})",
                          source=source)
    kind = data[STUDY_KEY]
    model = STUDY_MODELS.get(kind) if isinstance(kind, str) else None
    if model is None:
        hint = difflib.get_close_matches(str(kind), list(STUDY_MODELS), n=1)
        raise ConfigError(f"unknown study {kind!r}" + (f"; did you mean {hint[0]!r}?" if hint else "")
                          + f" (choose one of {', '.join(STUDY_MODELS)})", source=source, field=STUDY_KEY)
    try:
        cfg = model.model_validate(data)
    except ValidationError as e:
        raise from_validation_error(e, source, root=model) from None
    if isinstance(cfg, ExtremesStudy) and cfg.report is not None and base_dir is not None \
            and not Path(cfg.report.template).is_absolute():
        rep = cfg.report.model_copy(update={"template": os.path.normpath(base_dir / cfg.report.template)})
        cfg = cfg.model_copy(update={"report": rep})
    if check_semantics:
        _check_semantics(cfg, source)
    return cfg


def load_study(path, *, check_semantics: bool = True) -> StudyConfig:
    """Read and validate a study config file; every problem is a one-line ConfigError."""
    return parse_study(read_config_data(path), source=str(path), base_dir=Path(path).parent,
                       check_semantics=check_semantics)


def load_any(path, *, check_semantics: bool = True):
    """A sweep config (vcirun.experiments.config.SweepConfig) or, when the top level has `study:`, a study
    config: what `vcirun validate` accepts."""
    data = read_config_data(path)
    if isinstance(data, dict) and STUDY_KEY in data:
        return parse_study(data, source=str(path), base_dir=Path(path).parent, check_semantics=check_semantics)
    return parse_config(data, source=str(path), base_dir=Path(path).parent, check_semantics=check_semantics)


# --- semantic checks (cheap: no kernel is compiled, no sympy for built-in scenes) ---------------------
def _check_system(name: str, params: dict | None, field: str, source: str, *, params_field: str = "params",
                  needs_ic_map: bool = False):
    from ...scenes.registry import scene_args, scene_data

    if scene_args(name) is None:
        if name.endswith((".yaml", ".yml")) or Path(name).is_file():
            if not Path(name).is_file():
                raise ConfigError(f"system file not found: {name}", source=source, field=field)
            if needs_ic_map:   # (a YAML system declares q0 and p0, never a map beta -> (q0, p0))
                raise ConfigError(f"this study starts every run from Xi(beta), a built-in scene's initial-condition "
                                  f"map, and the YAML system {name} has none; use a built-in scene with one "
                                  f"(cart_pendulum, double_pendulum), or a sweep config with initial_states",
                                  source=source, field=field)
            return
        from ...scenes.registry import BUILTIN_SCENES

        hint = difflib.get_close_matches(name, list(BUILTIN_SCENES), n=1)
        raise ConfigError(f"unknown built-in system {name!r}" + (f"; did you mean {hint[0]!r}?" if hint else "")
                          + f" (choose one of {', '.join(BUILTIN_SCENES)}, or a YAML file path)",
                          source=source, field=field)
    sd = scene_data(name)
    try:
        sd.param_values(params or None)
    except ValueError as e:
        raise ConfigError(str(e).split(": ", 1)[-1], source=source, field=params_field) from None
    if needs_ic_map and sd.ic_map is None:
        raise ConfigError(f"system {name} has no initial-condition map beta -> (q0, p0)", source=source,
                          field="beta")


def _check_method(name: str, options: dict, field: str, source: str):
    from ...methods.table import resolve_method

    try:
        resolve_method(name, **options)
    except (ValueError, TypeError, NotImplementedError) as e:
        msg = str(e)
        head, sep, rest = msg.partition(": ")
        raise ConfigError(rest if sep and " " not in head else msg, source=source, field=field) from None


def _check_semantics(cfg, source: str) -> None:
    if isinstance(cfg, WorkPrecisionStudy):
        _check_system(cfg.system, cfg.params, "system", source, needs_ic_map=True)
        if cfg.baselines:   # (the symbolic system: sympy, only for a study that runs solve_ivp)
            from ...run.resolve import resolve_system
            from ..baselines import refusal

            refused = refusal(resolve_system(cfg.system))
            if refused:
                raise ConfigError(f"{refused}; leave baselines out (baselines: {{}}) for this system",
                                  source=source, field="baselines")
        for i, m in enumerate(cfg.methods):
            _check_method(m.name, {k: v for k, v in m.simulate_kwargs().items() if k in ("ld", "mh_order", "flow_order")},
                          f"methods[{i}]", source)
        return
    for i, m in enumerate(cfg.methods):
        _check_method(m, {}, f"methods[{i}]", source)
    for sec in cfg.sections():
        body = getattr(cfg, sec)
        if sec == "long_horizon":
            _check_system(body.system, None, "long_horizon.system", source)
        for j, sc in enumerate(getattr(body, "scenes", None) or []):
            _check_system(sc.system, getattr(sc, "params", None), f"{sec}.scenes[{j}].system", source,
                          params_field=f"{sec}.scenes[{j}].params")
    if cfg.report is not None and not Path(cfg.report.template).is_file():
        raise ConfigError(f"template not found: {cfg.report.template}", source=source, field="report.template")


def dump(cfg) -> dict:
    """The config as plain JSON-able data (stored with the results)."""
    return json.loads(cfg.model_dump_json())
