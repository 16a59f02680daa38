"""Sweep configurations: the YAML schema (pydantic v2, unknown keys rejected everywhere) and its loader.

A sweep is the grid  methods x h x initial conditions  on one system over [0, T]. Example::

    name: quick
    system: cart_pendulum            # or {name: cart_pendulum, params: {m2: 0.3}}, a YAML file path,
                                     # or an inline declaration (coordinates, parameters, mass_matrix, ...)
    methods: [CVA, VCI, MCVAA, MCVAC, {name: MCVA, ld: SVC, mh_order: 3, flow_order: 4, label: MCVA-SVC3}]
    h: [3.2e-2, 1.0e-2]
    beta: {start: 3.2, stop: 5.2, num: 5}   # or a list of betas, or initial_states: [{q0: [...], p0: [...]}]
    T: 5
    reference: {kind: exact, rtol: 1.0e-13}  # or {kind: method, method: CVA, h: 1.0e-4}, or {kind: none}
    tolerances: {newton_tol: 1.0e-12, event_tol: 1.0e-13}
    output: results/quick.h5
    workers: 2                        # default: every core
    executor: {kind: dask, address: tcp://10.0.0.5:8786}   # optional; default the local process pool
    store_trajectories: true
    timing_repeats: 3                 # wall_time = fastest of 3 identical runs

Relative paths: `output` is relative to the working directory (like any output option); a
system YAML file is relative to the config file.

`load_config(path)` turns every problem (missing file, YAML syntax, unknown key, wrong type, bad
value, unknown system or method, malformed expression, ...) into a `ConfigError` whose message is a
single line ``<file>: <field path>: <what is wrong and how to fix it>``.
"""
from __future__ import annotations

import difflib
import hashlib
import json
import math
import re
import typing
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import numpy as np
import yaml
from pydantic import (BaseModel, ConfigDict, Discriminator, Field, Tag, ValidationError, create_model, field_validator,
                      model_validator)

from ..core.bounds import check_scene_size
from ..core.grid import grid_end, grid_steps
from ..core.sizes import check_run_memory, parse_bytes
from ..core.tolerances import TOLERANCES
from ..core.yaml_loader import yaml_error_line, yaml_load
from ..discrete.lagrangians import LIBRARY
from ..methods.table import METHODS

__all__ = ["ConfigError", "SweepConfig", "MethodSpec", "InitialCondition", "ExecutorSpec", "load_config", "parse_config",
           "COLLISION_METHODS", "SMOOTH_METHODS", "DISCRETE_LAGRANGIANS"]

# Names `vcirun.simulate` accepts, read from the core's registries (vcirun.methods.table.METHODS,
# vcirun.discrete.lagrangians.LIBRARY): one list each.
COLLISION_METHODS = tuple(METHODS) + ("MCVA",)
DISCRETE_LAGRANGIANS = tuple(LIBRARY)
SMOOTH_METHODS = DISCRETE_LAGRANGIANS  # a bare Ld name integrates the smooth dynamics, constraint ignored
MethodName = Literal[COLLISION_METHODS + DISCRETE_LAGRANGIANS]
LdName = Literal[DISCRETE_LAGRANGIANS]
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]*$")
MAX_RUNS = 10_000_000  # methods x h x initial conditions of one sweep
MAX_CONFIG_BYTES = 4_000_000  # a config file is a few kB
# A config whose top level has this key is a study config (`vcirun study`, schema in
# vcirun.experiments.studies.schema), not a sweep; `vcirun validate` dispatches on it.
STUDY_KEY = "study"


class ConfigError(ValueError):
    """An invalid sweep configuration; `str(err)` is one line naming the file and the field."""

    def __init__(self, message: str, *, source: str | None = None, field: str | None = None):
        self.source = source
        self.field = field
        text = message if field is None else f"{field}: {message}"
        text = text if source is None else f"{source}: {text}"
        super().__init__(" ".join(text.split()))  # guaranteed single line


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)

    @model_validator(mode="before")
    @classmethod
    def _no_bools_for_numbers(cls, data):
        """pydantic reads true as 1.0 for a float field (`potential: true` was stored as 1.0): refuse it."""
        if isinstance(data, dict):
            for name, f in cls.model_fields.items():
                key = f.alias or name
                kinds = _leaf_types(f.annotation)
                if key in data and kinds & {float, int} and bool not in kinds:
                    where = _bool_inside(data[key])
                    if where is not None:
                        what = "an expression or a number" if str in kinds else "a number"
                        raise _FieldError((key, *where), f"must be {what}, not true/false")
        return data


def _leaf_types(tp) -> set:
    """The annotation's leaf types (Annotated, Optional, Union and containers unwrapped)."""
    leaves, stack = set(), [tp]
    while stack:
        t = stack.pop()
        origin = typing.get_origin(t)
        if origin is Annotated:
            stack.append(typing.get_args(t)[0])
        elif origin in (Union, list, tuple, dict):
            args = typing.get_args(t)
            stack.extend(args[1:] if origin is dict else args)
        else:
            leaves.add(t)
    return leaves


def _bool_inside(value, depth: int = 0):
    """Location (tuple) of a bool inside a value of lists/dicts, else None."""
    if isinstance(value, bool):
        return ()
    if depth < 4 and isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            where = _bool_inside(v, depth + 1)
            if where is not None:
                return (i, *where)
    if depth < 4 and isinstance(value, dict):
        for k, v in value.items():
            where = _bool_inside(v, depth + 1)
            if where is not None:
                return (str(k), *where)
    return None


PositiveFloat = Annotated[float, Field(gt=0)]


# --- system ---------------------------------------------------------------------------------------
class BuiltinSystem(_Model):
    """A built-in scene (`vcirun.scenes.data.BUILTIN_SCENE_DATA`) with optional parameter overrides."""
    name: str = Field(min_length=1)
    params: dict[str, float] = Field(default_factory=dict)


class FileSystem(_Model):
    """A system declared in its own YAML file (path relative to the config file)."""
    file: str = Field(min_length=1)
    params: dict[str, float] = Field(default_factory=dict)


class InlineSystem(_Model):
    """A system declared in the config; the keys are those of `vcirun.mechanics.load_system_yaml`."""
    name: str | None = None
    description: str | None = None
    coordinates: list[str] = Field(min_length=1)
    parameters: dict[str, float] = Field(default_factory=dict)
    mass_matrix: list[list[Union[str, float]]]
    potential: Union[str, float]
    constraint: Union[str, float] | None = None
    constraints: list[Union[str, float, dict[str, Union[str, float]]]] | None = None
    forcing: list[Union[str, float]] | None = None
    q0: list[float] | None = None
    p0: list[float] | None = None
    qdot0: list[float] | None = None

    def declaration(self) -> dict:
        """The mapping handed to `load_system_yaml` (expressions as strings, absent keys omitted)."""
        return self.model_dump(exclude_none=True)


def _system_tag(v: Any) -> str | None:
    if isinstance(v, dict):
        if "coordinates" in v or "mass_matrix" in v or "potential" in v or "constraint" in v or "constraints" in v:
            return "inline"
        return "file" if "file" in v else "builtin"
    if isinstance(v, BaseModel):
        return {BuiltinSystem: "builtin", FileSystem: "file", InlineSystem: "inline"}.get(type(v))
    return None


SystemSpec = Annotated[
    Union[Annotated[BuiltinSystem, Tag("builtin")], Annotated[FileSystem, Tag("file")],
          Annotated[InlineSystem, Tag("inline")]],
    Discriminator(_system_tag, custom_error_type="system_form",
                  custom_error_message="must be a built-in name, a YAML file path, {name: ..., params: {...}} "
                                       "or an inline declaration with coordinates, mass_matrix, potential, constraint")]


# --- methods --------------------------------------------------------------------------------------
class MethodOptions(_Model):
    """Per-method options passed to `vcirun.simulate`."""
    constrained: bool | None = None  # False: integrate the smooth dynamics, ignoring phi (Figure 1)


class MethodSpec(_Model):
    """One method of the sweep. For the generalized MCVA give `ld` and `mh_order` (and `flow_order`);
    CVA and VCI accept `ld` (the discrete Lagrangian of their full and partial steps, default SVC)."""
    name: MethodName
    ld: LdName | None = None
    mh_order: int | None = Field(default=None, ge=1, le=4)
    flow_order: Literal[4, 6] | None = None
    label: str | None = Field(default=None, min_length=1, max_length=64)
    options: MethodOptions = Field(default_factory=MethodOptions)

    @model_validator(mode="after")
    def _generalized_only(self):
        if self.name != "MCVA":
            for key in ("ld", "mh_order", "flow_order"):
                if key == "ld" and self.name in ("CVA", "VCI"):
                    continue
                if getattr(self, key) is not None:
                    raise ValueError(f"{key} is only for the generalized method (name: MCVA)"
                                     + (" and, for ld, CVA and VCI" if key == "ld" else "") + f"; {self.name} fixes it")
        else:
            for key, example in (("ld", "SVC"), ("mh_order", "3")):
                if getattr(self, key) is None:
                    raise ValueError(f"name: MCVA needs {key} (e.g. {key}: {example})")
        return self

    @property
    def display(self) -> str:
        """The label used in tables, figures and run records."""
        if self.label:
            return self.label
        if self.name == "MCVA":
            s = f"MCVA[{self.ld},s={self.mh_order}" + (f",p={self.flow_order}" if self.flow_order else "") + "]"
        elif self.ld is not None:
            s = f"{self.name}[{self.ld}]"
        else:
            s = self.name
        if self.options.constrained is False:
            s += " (no impacts)"
        return s

    def simulate_kwargs(self) -> dict:
        """Keyword arguments for `vcirun.simulate` besides system, h, T and the initial state."""
        kw = {k: getattr(self, k) for k in ("ld", "mh_order", "flow_order") if getattr(self, k) is not None}
        kw.update(self.options.model_dump(exclude_none=True))
        return kw

    def identity(self) -> dict:
        """What determines the computation (the label is cosmetic and excluded)."""
        return {"name": self.name, **self.simulate_kwargs()}


# --- initial conditions -----------------------------------------------------------------------------
class BetaRange(_Model):
    """`num` betas linearly spaced on [start, stop] (numpy.linspace), mapped to (q0, p0) by the scene's
    initial-condition map (Xi for the cart-pendulum)."""
    start: float
    stop: float
    num: int = Field(ge=1, le=100_000)

    @model_validator(mode="after")
    def _ordered(self):
        if self.start > self.stop:
            raise ValueError(f"start ({self.start:g}) must be <= stop ({self.stop:g})")
        if self.num == 1 and self.start != self.stop:
            raise ValueError("num = 1 cannot span start < stop; set stop equal to start or num >= 2")
        return self

    def values(self) -> list[float]:
        return [float(b) for b in np.linspace(self.start, self.stop, self.num)]


class BetaList(_Model):
    values_: list[float] = Field(alias="values", min_length=1, max_length=100_000)

    def values(self) -> list[float]:
        return [float(b) for b in self.values_]


BetaSpec = Annotated[
    Union[Annotated[BetaRange, Tag("range")], Annotated[BetaList, Tag("list")]],
    Discriminator(lambda v: ("list" if "values" in v else "range") if isinstance(v, dict)
                  else ("list" if isinstance(v, BetaList) else "range" if isinstance(v, BetaRange) else None),
                  custom_error_type="beta_form",
                  custom_error_message="must be {start: ..., stop: ..., num: ...} or a list of numbers")]


class InitialState(_Model):
    q0: list[float] = Field(min_length=1)
    p0: list[float] = Field(min_length=1)
    label: str | None = None

    @model_validator(mode="after")
    def _same_length(self):
        if len(self.q0) != len(self.p0):
            raise ValueError(f"q0 and p0 must have the same length (got {len(self.q0)} and {len(self.p0)})")
        return self


# --- reference, tolerances ----------------------------------------------------------------------------
class ExactReference(_Model):
    """DOP853 with event location and the exact elastic reset (`vcirun.reference`)."""
    kind: Literal["exact"]
    rtol: float = Field(default=1e-13, ge=2.3e-14, lt=1e-3)


class MethodReference(_Model):
    """A fine-step simulation, e.g. the paper's CVA benchmark."""
    kind: Literal["method"]
    method: MethodName = "CVA"
    h: PositiveFloat


class NoReference(_Model):
    kind: Literal["none"]


ReferenceSpec = Annotated[Union[ExactReference, MethodReference, NoReference], Field(discriminator="kind")]


Tolerances = create_model(
    "Tolerances", __base__=_Model, __doc__="Solver tolerances (vcirun.core.tolerances.TOLERANCES: names, bounds); "
    "unset values take its defaults (recorded per run either way).",
    **{t.name: (Union[int, None] if t.integer else Union[float, None], Field(default=None, description=t.doc, **t.bounds))
       for t in TOLERANCES.values()})


# --- executor ------------------------------------------------------------------------------------------
_ADDRESS_RE = re.compile(r"^[a-z][a-z0-9+]*://\S+$|^[^\s/:]+:\d{1,5}$")


def check_scheduler_address(address: str) -> str:
    """A Dask scheduler address: tcp://HOST:PORT, tls://HOST:PORT or HOST:PORT (ValueError otherwise)."""
    a = str(address).strip()
    if not a or not _ADDRESS_RE.match(a):
        raise ValueError(f"expected a Dask scheduler address such as tcp://HOST:8786 (got {address!r})")
    return a


class ExecutorSpec(_Model):
    """Where the runs are computed. Not part of the results: the same sweep on the local pool or on a
    Dask cluster gives the same file (see vcirun.experiments.executors)."""
    kind: Literal["local", "dask"] = "local"
    address: str | None = None       # Dask scheduler, e.g. tcp://10.0.0.5:8786 (`--scheduler` wins)
    task_size: int | None = Field(default=None, ge=1, le=1_000_000)  # runs per task; default automatic
    cache_dir: str | None = Field(default=None, min_length=1)  # VCIRUN_CACHE_DIR set on Dask workers

    @field_validator("address")
    @classmethod
    def _address(cls, v):
        return None if v is None else check_scheduler_address(v)

    @model_validator(mode="after")
    def _dask_only(self):
        if self.kind == "local":
            for key in ("address", "cache_dir"):
                if getattr(self, key) is not None:
                    raise ValueError(f"{key} is only for kind: dask")
        return self


# --- the sweep ------------------------------------------------------------------------------------------
class InitialCondition(BaseModel):
    """One point of the initial-condition axis; `key` names its reference group in the results file."""
    model_config = ConfigDict(frozen=True)
    key: str
    beta: float | None = None
    q0: tuple[float, ...] | None = None
    p0: tuple[float, ...] | None = None

    def simulate_kwargs(self) -> dict:
        if self.beta is not None:
            return {"beta": self.beta}
        if self.q0 is not None:
            return {"q0": list(self.q0), "p0": list(self.p0)}
        return {}

    def identity(self) -> dict:
        return {"beta": self.beta, "q0": self.q0, "p0": self.p0}


class SweepConfig(_Model):
    """A sweep: every method at every h from every initial condition, on [0, T]."""
    name: str = Field(min_length=1, max_length=80)
    description: str | None = Field(default=None, max_length=10_000)
    system: SystemSpec
    methods: list[MethodSpec] = Field(min_length=1, max_length=1_000)
    h: list[PositiveFloat] = Field(min_length=1, max_length=10_000)
    beta: BetaSpec | None = None
    initial_states: list[InitialState] | None = Field(default=None, min_length=1, max_length=100_000)
    T: PositiveFloat
    reference: ReferenceSpec = Field(default_factory=lambda: ExactReference(kind="exact"))
    tolerances: Tolerances = Field(default_factory=Tolerances)
    output: str | None = None
    workers: int | None = Field(default=None, ge=1, le=4096)
    executor: Union[ExecutorSpec, None] = None  # typing.Union: the unknown-key hint unwraps it
    store_trajectories: bool = True
    # Each run is integrated this many times (the integrator is deterministic, so the results are
    # identical) and its wall_time is the fastest: other processes preempting a worker would
    # otherwise add outliers of a scheduler time slice to sub-millisecond runs. 1 for long runs.
    timing_repeats: int = Field(default=3, ge=1, le=1000)
    # Memory a sweep may use for its runs in flight (text like 16GB, or bytes); default: the
    # VCIRUN_MAX_MEMORY environment variable, else half the physical memory. Not part of the results.
    max_memory: Union[str, float, None] = None

    @field_validator("max_memory")
    @classmethod
    def _memory(cls, v):
        if v is not None:
            parse_bytes(v, "max_memory")
        return v

    @field_validator("name")
    @classmethod
    def _safe_name(cls, v: str) -> str:
        if not _NAME_RE.match(v):
            raise ValueError("use letters, digits, '_', '-' and '.' only (it names the figure folder)")
        return v

    @field_validator("system", mode="before")
    @classmethod
    def _system_shorthand(cls, v):
        if isinstance(v, str):
            return {"file": v} if v.endswith((".yaml", ".yml")) else {"name": v}
        return v

    @field_validator("methods", mode="before")
    @classmethod
    def _method_shorthand(cls, v):
        if isinstance(v, list):
            return [{"name": m} if isinstance(m, str) else m for m in v]
        return v

    @field_validator("beta", mode="before")
    @classmethod
    def _beta_shorthand(cls, v):
        if isinstance(v, (list, tuple)):
            return {"values": list(v)}
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            return {"values": [v]}
        return v

    @model_validator(mode="after")
    def _consistent(self):
        seen_h: set = set()
        for i, hi in enumerate(self.h):
            if hi > self.T:
                raise _FieldError(("h", i), f"must be <= T = {self.T:g} (got {hi:g})")
            try:
                grid_steps(hi, self.T)  # underflowing h, T / h too many steps
            except ValueError as e:
                raise _FieldError(("h", i), str(e).partition(": ")[2]) from None
            if hi in seen_h:
                raise _FieldError(("h", i), f"duplicate step {hi:g}")
            seen_h.add(hi)
        n_ics = (len(self.beta.values()) if self.beta is not None
                 else len(self.initial_states) if self.initial_states is not None else 1)
        if len(self.methods) * len(self.h) * n_ics > MAX_RUNS:
            raise _FieldError(("methods",), f"the grid has {len(self.methods) * len(self.h) * n_ics:,} runs "
                                            f"(methods x h x initial conditions); the limit is {MAX_RUNS:,}")
        seen: dict[str, int] = {}
        idents: dict[str, int] = {}
        for i, m in enumerate(self.methods):
            if m.display in seen:
                raise _FieldError(("methods", i), f"duplicate label {m.display!r} (also methods[{seen[m.display]}]);"
                                                  " give one of them a different label")
            ident = json.dumps(m.identity(), sort_keys=True)
            if ident in idents:
                raise _FieldError(("methods", i), f"same method and options as methods[{idents[ident]}]")
            seen[m.display] = i
            idents[ident] = i
        if self.beta is not None and self.initial_states is not None:
            raise _FieldError(("initial_states",), "give either beta or initial_states, not both")
        if self.beta is not None:
            b = self.beta.values()
            seen_b: set = set()
            dup = [x for x in b if x in seen_b or seen_b.add(x)]  # linear: 100 000 betas are allowed
            if dup:
                raise _FieldError(("beta",), f"duplicate beta {dup[0]:g}")
        return self

    # --- derived ------------------------------------------------------------------------------------
    def initial_conditions(self) -> list[InitialCondition]:
        """The initial-condition axis: betas, explicit states, or the system's default state."""
        if self.beta is not None:
            betas = self.beta.values()
            keys = [f"beta={b:.12g}" for b in betas]
            if len(set(keys)) < len(keys):  # betas closer than 12 digits: fall back to exact reprs
                keys = [f"beta={b!r}" for b in betas]
            return [InitialCondition(key=k, beta=b) for k, b in zip(keys, betas)]
        if self.initial_states is not None:
            return [InitialCondition(key=f"state={i}", q0=tuple(s.q0), p0=tuple(s.p0))
                    for i, s in enumerate(self.initial_states)]
        return [InitialCondition(key="default")]

    def output_path(self) -> Path:
        return Path(self.output) if self.output else Path("results") / f"{self.name}.h5"

    def canonical(self) -> dict:
        """Everything that determines the results (not where they go, nor how many processes or which
        executor compute them)."""
        return self.model_dump(mode="json", by_alias=True, exclude={"output", "workers", "executor", "description",
                                                                      "max_memory"})

    def canonical_sha256(self) -> str:
        return hashlib.sha256(json.dumps(self.canonical(), sort_keys=True).encode()).hexdigest()

    def system_label(self) -> str:
        s = self.system
        if isinstance(s, BuiltinSystem):
            return s.name
        if isinstance(s, FileSystem):
            return Path(s.file).stem
        return s.name or "user_system"


class _FieldError(ValueError):
    """Raised inside model validators to point at a sub-field (pydantic would report the model)."""

    def __init__(self, loc: tuple, msg: str):
        self.loc = loc
        self.msg = msg
        super().__init__(msg)


# --- errors ------------------------------------------------------------------------------------------
_TAGS = {"builtin", "file", "inline", "range", "list", "exact", "method", "none"}
_UNION_FIELDS = {"system", "beta", "reference"}


def _clean_loc(loc: tuple) -> tuple:
    """Drop pydantic's union-member tags from an error location ('system', 'inline', 'x' -> 'system', 'x')."""
    out = []
    for i, part in enumerate(loc):
        if isinstance(part, str) and part in _TAGS and i > 0 and loc[i - 1] in _UNION_FIELDS:
            continue
        if part == "values_":
            part = "values"
        out.append(part)
    if len(out) >= 2 and out[0] == "beta" and out[1] == "values":
        out.pop(1)  # `beta: [..]` is written as a list; report beta[i]
    return tuple(out)


def format_loc(loc: tuple) -> str:
    s = ""
    for part in loc:
        if isinstance(part, int):
            s += f"[{part}]"
        else:
            s += ("." if s else "") + str(part)
    return s or "(top level)"


def _unwrap(tp):
    """Strip Annotated/Optional to the underlying type(s)."""
    while typing.get_origin(tp) is Annotated:
        tp = typing.get_args(tp)[0]
    if typing.get_origin(tp) is Union:
        return [a for t in typing.get_args(tp) if t is not type(None) for a in _unwrap(t)]
    return [tp]


_TAG_MODELS = {"builtin": BuiltinSystem, "file": FileSystem, "inline": InlineSystem, "range": BetaRange,
               "list": BetaList, "exact": ExactReference, "method": MethodReference, "none": NoReference}


def _model_at(loc: tuple, root=None):
    """The pydantic model class at a raw error location (from `root`, default SweepConfig), to list its
    allowed keys."""
    current: Any = root or SweepConfig
    for part in loc:
        if isinstance(part, str) and part in _TAG_MODELS:
            current = _TAG_MODELS[part]  # pydantic names the union member it tried
            continue
        if isinstance(current, type) and issubclass(current, BaseModel):
            fields = {(f.alias or n): f for n, f in current.model_fields.items()}
            if part not in fields:
                return None
            cands = _unwrap(fields[part].annotation)
        elif typing.get_origin(current) in (list, dict):
            cands = _unwrap(typing.get_args(current)[-1])
        elif current == "union":
            return None
        else:
            return None
        models = [c for c in cands if isinstance(c, type) and issubclass(c, BaseModel)]
        if len(models) > 1:
            current = "union"  # the next location part is the member's tag
        elif len(models) == 1:
            current = models[0]
        elif len(cands) == 1:
            current = cands[0]
        else:
            return None
    return current if isinstance(current, type) and issubclass(current, BaseModel) else None


def _allowed_keys(model) -> list[str]:
    return [f.alias or n for n, f in model.model_fields.items()]


def _describe(value) -> str:
    s = repr(value)
    return s if len(s) <= 40 else s[:37] + "..."


def _pydantic_message(err: dict, root=None) -> tuple[tuple, str]:
    raw = tuple(err["loc"])
    loc = _clean_loc(raw)
    typ, ctx, inp = err["type"], err.get("ctx") or {}, err.get("input")
    if typ == "extra_forbidden":
        key = raw[-1]
        model = _model_at(raw[:-1], root)
        allowed = _allowed_keys(model) if model else []
        hint = difflib.get_close_matches(str(key), allowed, n=1)
        msg = "unknown key"
        if hint:
            msg += f"; did you mean {hint[0]!r}?"
        if allowed:
            msg += f" (allowed: {', '.join(allowed)})"
        return loc, msg
    if typ == "missing":
        return loc, "required key is missing"
    if typ in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        op = {"greater_than": ">", "greater_than_equal": ">=", "less_than": "<", "less_than_equal": "<="}[typ]
        bound = next(iter(ctx.values()), "?")
        bound = f"{bound:g}" if isinstance(bound, (int, float)) else bound
        return loc, f"must be {op} {bound} (got {_describe(inp)})"
    if typ == "literal_error":
        return loc, f"must be one of {ctx.get('expected', '?')} (got {_describe(inp)})"
    if typ in ("float_parsing", "float_type", "finite_number"):
        return loc, f"must be a finite number (got {_describe(inp)})"
    if typ in ("int_parsing", "int_type", "int_from_float"):
        return loc, f"must be an integer (got {_describe(inp)})"
    if typ in ("bool_parsing", "bool_type"):
        return loc, f"must be true or false (got {_describe(inp)})"
    if typ in ("string_type",):
        return loc, f"must be a string (got {_describe(inp)})"
    if typ in ("list_type", "tuple_type"):
        return loc, f"must be a list (got {_describe(inp)})"
    if typ in ("dict_type", "model_type", "model_attributes_type"):
        return loc, f"must be a mapping of keys to values (got {_describe(inp)})"
    if typ == "too_short":
        return loc, "must not be empty" if ctx.get("min_length") == 1 else err["msg"]
    if typ == "union_tag_not_found" or typ == "union_tag_invalid":
        if "reference" in raw:
            return loc, ("needs kind: exact, method or none (e.g. {kind: exact, rtol: 1.0e-13})"
                         if typ == "union_tag_not_found" else
                         f"kind must be exact, method or none (got {_describe(ctx.get('tag'))})")
        return loc, err["msg"]
    if typ == "value_error":
        exc = ctx.get("error")
        if isinstance(exc, _FieldError):
            return _clean_loc(raw + exc.loc), exc.msg
        msg = str(exc) if exc is not None else err["msg"]
        return loc, msg
    return loc, err["msg"]


def _from_validation_error(e: ValidationError, source: str, root=None) -> ConfigError:
    """Every problem at once, on one line: unknown keys first (a typo such as `methdos:` is named, with
    the closest known key, and the "required key is missing" it causes is folded into it), then the
    rest in the order pydantic found them: `<file>: <field>: <problem>; <field>: <problem> (N problems)`."""
    errors = e.errors(include_url=False)
    items = [(err["type"], _pydantic_message(err, root)) for err in errors]  # root-level _FieldError: own location
    unknown = [(loc, msg) for typ, (loc, msg) in items if typ == "extra_forbidden"]
    missing = {loc for typ, (loc, _) in items if typ == "missing"}
    folded = set()
    for loc, msg in list(unknown):
        m = re.search(r"did you mean '([^']+)'", msg)
        if m and loc[:-1] + (m.group(1),) in missing:
            folded.add(loc[:-1] + (m.group(1),))
    out = [(loc, msg + (" (that key is required)" if loc[:-1] + (_hint(msg),) in folded else ""))
           for loc, msg in unknown]
    out += [(loc, msg) for typ, (loc, msg) in items if typ != "extra_forbidden" and not (typ == "missing" and loc in folded)]
    seen, uniq, lists = set(), [], set()
    for loc, msg in out:
        if (loc, msg) in seen:
            continue
        seen.add((loc, msg))
        m = re.search(r" \(allowed: [^)]*\)", msg)
        if m:  # several unknown keys of one mapping: its allowed keys once
            if (loc[:-1], m.group(0)) in lists:
                msg = msg.replace(m.group(0), "")
            lists.add((loc[:-1], m.group(0)))
        uniq.append((loc, msg))
    first_loc, first_msg = uniq[0]
    text = first_msg + "".join(f"; {format_loc(loc)}: {msg}" for loc, msg in uniq[1:])
    if len(uniq) > 1:
        text += f" ({len(uniq)} problems)"
    return ConfigError(text, source=source, field=format_loc(first_loc))


def _hint(msg: str) -> str:
    m = re.search(r"did you mean '([^']+)'", msg)
    return m.group(1) if m else ""


# --- loading -----------------------------------------------------------------------------------------
def parse_config(data, *, source: str = "<config>", base_dir: Path | None = None,
                 check_semantics: bool = True) -> SweepConfig:
    """Validate a config mapping. With `check_semantics`, also build the system (unknown built-in
    names, parameter names, malformed expressions), resolve the methods (unsupported combinations)
    and map every initial condition (beta without a map, wrong lengths, non-hyperregular M)."""
    if data is None:
        raise ConfigError("empty config; expected a mapping with keys name, system, methods, h, T, ...", source=source)
    if not isinstance(data, dict):
        raise ConfigError(f"the top level must be a mapping of keys to values (got {type(data).__name__})",
                          source=source)
    for k in data:
        if not isinstance(k, str):
            raise ConfigError(f"keys must be strings (got {k!r})", source=source)
    if STUDY_KEY in data:
        raise ConfigError(f"a study config (top-level key {STUDY_KEY}: {data[STUDY_KEY]}), not a sweep config; run it "
                          "with `vcirun study FILE`", source=source, field=STUDY_KEY)
    data = dict(data)
    if "name" not in data and source not in ("<config>", "<string>"):
        data["name"] = Path(source).stem
    try:
        cfg = SweepConfig.model_validate(data)
    except ValidationError as e:
        raise _from_validation_error(e, source) from None
    if isinstance(cfg.system, FileSystem) and base_dir is not None and not Path(cfg.system.file).is_absolute():
        cfg = cfg.model_copy(update={"system": FileSystem(file=str((base_dir / cfg.system.file)), params=cfg.system.params)})
    if check_semantics:
        check_semantics_of(cfg, source=source)
    return cfg


def read_config_data(path):
    """The parsed YAML of a config file (sweep or study); every failure is a one-line `ConfigError`."""
    source = str(path)
    p = Path(path)
    if not p.exists():
        raise ConfigError("file not found", source=source)
    if p.is_dir():
        raise ConfigError("is a directory, expected a YAML file", source=source)
    try:
        st = p.stat()
    except OSError as e:
        raise ConfigError(f"cannot read: {e}", source=source) from None
    if not p.is_file():  # a FIFO or a device would block or never end
        raise ConfigError("not a regular file, expected a YAML file", source=source)
    if st.st_size > MAX_CONFIG_BYTES:
        raise ConfigError(f"the file is {st.st_size:,} bytes; a config is a few kB (limit {MAX_CONFIG_BYTES:,})",
                          source=source)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"cannot read: {e}", source=source) from None
    try:
        data = yaml_load(text)
    except yaml.YAMLError as e:
        raise ConfigError(yaml_error_line(e), source=source) from None
    return data


def load_config(path, *, check_semantics: bool = True) -> SweepConfig:
    """Read and validate a YAML sweep config; every failure is a one-line `ConfigError`."""
    data = read_config_data(path)
    return parse_config(data, source=str(path), base_dir=Path(path).parent, check_semantics=check_semantics)


def config_text(path) -> str:
    return Path(path).read_text(encoding="utf-8")


# --- semantic checks (need the numerical core) ---------------------------------------------------------------
def build_system(cfg: SweepConfig):
    """(system argument for vcirun.simulate/reference, parameter overrides or None, MechanicalSystem)."""
    from vcirun.mechanics import load_system_yaml
    from vcirun.scenes.declarations import get_scene
    from vcirun.scenes.data import BUILTIN_SCENE_DATA, scene_args

    s = cfg.system
    if isinstance(s, BuiltinSystem):
        if scene_args(s.name) is None:  # the one scene registry (vcirun.scenes.data)
            hint = difflib.get_close_matches(s.name, list(BUILTIN_SCENE_DATA), n=1)
            raise _Semantic("system",
                            f"unknown built-in system {s.name!r}" + (f"; did you mean {hint[0]!r}?" if hint else "")
                            + f" (choose one of {', '.join(BUILTIN_SCENE_DATA)}, or a YAML file path)")
        try:
            check_scene_size(s.name)
        except ValueError as e:
            raise _Semantic("system", str(e).partition(": ")[2]) from None
        sysm = get_scene(s.name)
        return s.name, (dict(s.params) or None), sysm
    if isinstance(s, FileSystem):
        if not Path(s.file).is_file():
            fp = Path(s.file)
            why = ("is a directory" if fp.is_dir() else "is not a regular file (a FIFO, device or socket)"
                   if fp.exists() else "is a symbolic link loop or points nowhere" if fp.is_symlink() else None)
            raise _Semantic("system", f"system file {s.file} {why}; expected a YAML file" if why
                            else f"system file not found: {s.file}")
        sysm = load_system_yaml(s.file)
        return str(Path(s.file).resolve()), (dict(s.params) or None), sysm
    sysm = load_system_yaml(s.declaration(), field_prefix="system")
    return sysm, None, sysm


class _Semantic(Exception):
    def __init__(self, field: str, msg: str):
        self.field, self.msg = field, msg


def _strip_field(message: str, prefix: str) -> tuple[str, str]:
    """Split a core error 'field: reason' into (field, reason) so it can be re-prefixed."""
    head, sep, rest = message.partition(": ")
    if sep and " " not in head and head:
        return head, rest
    return prefix, message


def check_semantics_of(cfg: SweepConfig, *, source: str = "<config>") -> None:
    """Raise ConfigError for what only the core can judge. Cheap: no kernel is compiled."""
    try:
        _, params, sysm = build_system(cfg)
    except _Semantic as e:
        raise ConfigError(e.msg, source=source, field=e.field) from None
    except ValueError as e:  # ExpressionError is a ValueError; core messages start with the field
        fld, msg = _strip_field(str(e), "system")
        if not fld.startswith("system"):
            fld = "system." + fld if fld != "system" else fld
        raise ConfigError(msg, source=source, field=fld) from None
    try:
        prm = sysm.param_values(params)
    except ValueError as e:
        fld, msg = _strip_field(str(e), "system.params")
        raise ConfigError(msg, source=source, field="system." + fld if not fld.startswith("system") else fld) from None
    check_memory_of(cfg, sysm.n, source=source)
    from vcirun.methods.table import resolve_method

    for i, m in enumerate(cfg.methods):
        try:
            resolve_method(m.name, **{k: v for k, v in m.simulate_kwargs().items()
                                      if k in ("ld", "mh_order", "flow_order")})
        except (ValueError, TypeError, NotImplementedError) as e:
            _, msg = _strip_field(str(e), "")
            raise ConfigError(msg, source=source, field=f"methods[{i}]") from None
    if isinstance(cfg.reference, MethodReference):
        try:
            resolve_method(cfg.reference.method)
        except (ValueError, TypeError, NotImplementedError) as e:
            raise ConfigError(_strip_field(str(e), "")[1], source=source, field="reference.method") from None
    ics = cfg.initial_conditions()
    for i, ic in enumerate(ics):
        field = ("beta" + (f"[{i}]" if len(ics) > 1 else "") if ic.beta is not None
                 else f"initial_states[{i}]" if ic.q0 is not None else "system")
        try:
            q0, p0 = sysm.initial_state(params=prm, **ic.simulate_kwargs())
        except (ValueError, np.linalg.LinAlgError) as e:
            _, msg = _strip_field(str(e), field)
            if ic.beta is None and ic.q0 is None:
                msg += "; give beta or initial_states in the config"
            raise ConfigError(msg, source=source, field=field) from None
        if not (np.all(np.isfinite(q0)) and np.all(np.isfinite(p0))):
            raise ConfigError("maps to a non-finite initial state", source=source, field=field)
        try:
            phi0 = sysm.phi_value(q0, prm)
        except Exception:  # noqa: BLE001 - phi is checked again by the integrator
            phi0 = math.nan
        if phi0 < 0:
            raise ConfigError(f"initial state violates the constraint (phi(q0) = {phi0:.3g} < 0)",
                              source=source, field=field)


def check_memory_of(cfg: SweepConfig, n: int, *, source: str = "<config>", workers: int = 1) -> None:
    """Refuse a grid whose finest run (its buffers, `workers` of them at once) exceeds the memory limit
    (`max_memory`, else VCIRUN_MAX_MEMORY, else half the physical memory) before anything is allocated."""
    i = min(range(len(cfg.h)), key=lambda j: cfg.h[j])
    N = grid_steps(cfg.h[i], cfg.T)[2]
    try:
        check_run_memory(N, n, copies=workers, limit=cfg.max_memory, field="x",
                         hint=", or raise max_memory in the config (e.g. max_memory: 32GB)")
    except ValueError as e:
        raise ConfigError(str(e).partition(": ")[2], source=source, field=f"h[{i}]") from None
    ref = cfg.reference
    if isinstance(ref, MethodReference):
        # the reference is a run too, at reference.h on [0, T] (or the last grid point past it, as the
        # sweep's reference horizon), so `validate` refuses what the sweep's preflight would
        T_ref = max([cfg.T] + [grid_end(h, cfg.T) for h in cfg.h])
        try:
            N_ref = grid_steps(ref.h, T_ref)[2]
            check_run_memory(N_ref, n, copies=workers, limit=cfg.max_memory, field="x",
                             hint=", or raise max_memory in the config (e.g. max_memory: 32GB)")
        except ValueError as e:
            raise ConfigError(str(e).partition(": ")[2].replace("raise h ", "raise reference.h "), source=source,
                              field="reference.h") from None
