"""The parts of a sweep config's schema (pydantic v2, unknown keys rejected everywhere): the system,
the methods, the initial conditions, the reference, the solver tolerances and the executor.
`ConfigModel` is the base of every config model (sweep and study configs alike): frozen, no
unknown keys, no inf/nan, and no true/false where a number is expected."""
from __future__ import annotations

import re
import typing
from typing import Annotated, Any, Literal, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Discriminator, Field, Tag, create_model, field_validator, model_validator

from ...core.tolerances import TOLERANCES
from ...discrete.lagrangians import LIBRARY
from ...methods.table import METHODS
from .errors import FieldError

__all__ = ["COLLISION_METHODS", "DISCRETE_LAGRANGIANS", "SMOOTH_METHODS", "MethodName", "LdName", "ConfigModel",
           "PositiveFloat", "BuiltinSystem", "FileSystem", "InlineSystem", "SystemSpec", "MethodOptions", "MethodSpec",
           "BetaRange", "BetaList", "BetaSpec", "InitialState", "ExactReference", "MethodReference", "NoReference",
           "ReferenceSpec", "Tolerances", "check_scheduler_address", "ExecutorSpec", "TAG_MODELS"]

# Names `vcirun.simulate` accepts, read from the core's registries (vcirun.methods.table.METHODS,
# vcirun.discrete.lagrangians.LIBRARY): one list each.
COLLISION_METHODS = tuple(METHODS) + ("MCVA",)
DISCRETE_LAGRANGIANS = tuple(LIBRARY)
SMOOTH_METHODS = DISCRETE_LAGRANGIANS  # a bare Ld name integrates the smooth dynamics, constraint ignored
MethodName = Literal[COLLISION_METHODS + DISCRETE_LAGRANGIANS]
LdName = Literal[DISCRETE_LAGRANGIANS]


class ConfigModel(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)

    @model_validator(mode="before")
    @classmethod
    def _no_bools_for_numbers(cls, data):
        """pydantic would read true as 1.0 for a float field (`potential: true` as 1.0): refuse it."""
        if isinstance(data, dict):
            for name, f in cls.model_fields.items():
                key = f.alias or name
                kinds = _leaf_types(f.annotation)
                if key in data and kinds & {float, int} and bool not in kinds:
                    where = _bool_inside(data[key])
                    if where is not None:
                        what = "an expression or a number" if str in kinds else "a number"
                        raise FieldError((key, *where), f"must be {what}, not true/false")
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
class BuiltinSystem(ConfigModel):
    """A built-in scene (`vcirun.scenes.registry.BUILTIN_SCENES`) with optional parameter overrides."""
    name: str = Field(min_length=1)
    params: dict[str, float] = Field(default_factory=dict)


class FileSystem(ConfigModel):
    """A system declared in its own YAML file (path relative to the config file)."""
    file: str = Field(min_length=1)
    params: dict[str, float] = Field(default_factory=dict)


class InlineSystem(ConfigModel):
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
class MethodOptions(ConfigModel):
    """Per-method options passed to `vcirun.simulate`."""
    constrained: bool | None = None  # False: integrate the smooth dynamics, ignoring phi (Figure 1)


class MethodSpec(ConfigModel):
    """One method of the sweep. For the generalized MCVA give `ld` and `mh_order` (and `flow_order`);
    CVA and VCI accept `ld` (the discrete Lagrangian of their full and partial steps, default SVC).
    tol: the run is `vcirun.simulate(..., tol=tol)` (name "auto": the method chosen too; a method name:
    the only candidate); a sweep config's top-level `tol:` makes these entries."""
    name: Literal[COLLISION_METHODS + DISCRETE_LAGRANGIANS + ("auto",)]
    ld: LdName | None = None
    mh_order: int | None = Field(default=None, ge=1, le=4)
    flow_order: Literal[4, 6] | None = None
    label: str | None = Field(default=None, min_length=1, max_length=64)
    options: MethodOptions = Field(default_factory=MethodOptions)
    tol: PositiveFloat | None = None

    @model_validator(mode="after")
    def _generalized_only(self):
        if self.name == "auto" and self.tol is None:
            raise ValueError("name: auto (the method chosen for a tolerance) needs tol (or give tol: at the top "
                             "level of the config)")
        if self.tol is not None and self.options.constrained is False:
            raise ValueError("tol measures the error of the constrained motion; drop options.constrained: false")
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
        if self.tol is not None and not self.label:
            s = f"tol={self.tol:g}" if self.name == "auto" else f"{s} tol={self.tol:g}"
        return s

    def simulate_kwargs(self) -> dict:
        """Keyword arguments for `vcirun.simulate` besides system, h, T and the initial state."""
        kw = {k: getattr(self, k) for k in ("ld", "mh_order", "flow_order", "tol") if getattr(self, k) is not None}
        kw.update(self.options.model_dump(exclude_none=True))
        return kw

    def identity(self) -> dict:
        """What determines the computation (the label is cosmetic and excluded)."""
        return {"name": self.name, **self.simulate_kwargs()}


# --- initial conditions -----------------------------------------------------------------------------
class BetaRange(ConfigModel):
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


class BetaList(ConfigModel):
    values_: list[float] = Field(alias="values", min_length=1, max_length=100_000)

    def values(self) -> list[float]:
        return [float(b) for b in self.values_]


BetaSpec = Annotated[
    Union[Annotated[BetaRange, Tag("range")], Annotated[BetaList, Tag("list")]],
    Discriminator(lambda v: ("list" if "values" in v else "range") if isinstance(v, dict)
                  else ("list" if isinstance(v, BetaList) else "range" if isinstance(v, BetaRange) else None),
                  custom_error_type="beta_form",
                  custom_error_message="must be {start: ..., stop: ..., num: ...} or a list of numbers")]


class InitialState(ConfigModel):
    q0: list[float] = Field(min_length=1)
    p0: list[float] = Field(min_length=1)
    label: str | None = None

    @model_validator(mode="after")
    def _same_length(self):
        if len(self.q0) != len(self.p0):
            raise ValueError(f"q0 and p0 must have the same length (got {len(self.q0)} and {len(self.p0)})")
        return self


# --- reference, tolerances ----------------------------------------------------------------------------
class ExactReference(ConfigModel):
    """DOP853 with event location and the exact elastic reset (`vcirun.reference`)."""
    kind: Literal["exact"]
    rtol: float = Field(default=1e-13, ge=2.3e-14, lt=1e-3)


class MethodReference(ConfigModel):
    """A fine-step simulation, e.g. the paper's CVA benchmark."""
    kind: Literal["method"]
    method: MethodName = "CVA"
    h: PositiveFloat


class NoReference(ConfigModel):
    kind: Literal["none"]


ReferenceSpec = Annotated[Union[ExactReference, MethodReference, NoReference], Field(discriminator="kind")]


Tolerances = create_model(
    "Tolerances", __base__=ConfigModel, __doc__="Solver tolerances (vcirun.core.tolerances.TOLERANCES: names, bounds); "
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


class ExecutorSpec(ConfigModel):
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


# the union members by the tag pydantic names them with in error locations
TAG_MODELS = {"builtin": BuiltinSystem, "file": FileSystem, "inline": InlineSystem, "range": BetaRange,
              "list": BetaList, "exact": ExactReference, "method": MethodReference, "none": NoReference}
