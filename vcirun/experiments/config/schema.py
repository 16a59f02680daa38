"""The sweep config: every method at every h from every initial condition, on [0, T] (`SweepConfig`),
and the points of its initial-condition axis (`InitialCondition`)."""
from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path
from typing import Literal, Union

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from ...core.grid import grid_steps
from ...core.sizes import parse_bytes
from .errors import FieldError
from .specs import (BetaSpec, BuiltinSystem, ConfigModel, ExactReference, ExecutorSpec, FileSystem, InitialState,
                    MethodSpec, PositiveFloat, ReferenceSpec, SystemSpec, Tolerances)

__all__ = ["STUDY_KEY", "MAX_RUNS", "InitialCondition", "SweepConfig"]

_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]*$")
MAX_RUNS = 10_000_000  # methods x h x initial conditions of one sweep
# A config whose top level has this key is a study config (`vcirun study`, schema in
# vcirun.experiments.studies.schema), not a sweep; `vcirun validate` dispatches on it.
STUDY_KEY = "study"


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


class StoreEvery(ConfigModel):
    """`store: {every: k}`: every k-th grid state of each run (and the last one)."""
    every: int = Field(ge=2, le=10_000_000)


class SweepConfig(ConfigModel):
    """A sweep: every method at every h from every initial condition, on [0, T]."""
    name: str = Field(min_length=1, max_length=80)
    description: str | None = Field(default=None, max_length=10_000)
    system: SystemSpec
    methods: list[MethodSpec] = Field(min_length=1, max_length=1_000)
    h: list[PositiveFloat] = Field(min_length=1, max_length=10_000)
    # tol: runs of vcirun.simulate(..., tol=t) for each t in place of methods x h (methods, if given, are
    # then the only candidate of their runs; h, if given, the largest steps allowed; default [T])
    tol: list[PositiveFloat] | None = Field(default=None, min_length=1, max_length=100)
    # error_estimate: every ok run also stores its error estimate (tr.error_estimate(): est_l2, est_status, ...)
    error_estimate: bool = False
    beta: BetaSpec | None = None
    initial_states: list[InitialState] | None = Field(default=None, min_length=1, max_length=100_000)
    T: PositiveFloat
    reference: ReferenceSpec = Field(default_factory=lambda: ExactReference(kind="exact"))
    tolerances: Tolerances = Field(default_factory=Tolerances)
    output: str | None = None
    workers: int | None = Field(default=None, ge=1, le=4096)
    executor: Union[ExecutorSpec, None] = None  # typing.Union: the unknown-key hint unwraps it
    store_trajectories: bool = True
    # what a run stores: "full" (every grid state), {every: k} (every k-th grid state and the last, with
    # the whole impact record), "metrics" (the impact record and the summaries: store_trajectories: false)
    store: Union[Literal["full", "metrics"], StoreEvery, None] = None
    # Each run is integrated this many times (the integrator is deterministic, so the results are
    # identical) and its wall_time is the fastest: other processes preempting a worker would
    # otherwise add outliers of a scheduler time slice to sub-millisecond runs. 1 for long runs.
    timing_repeats: int = Field(default=3, ge=1, le=1000)
    # Memory a sweep may use for its runs in flight (text like 16GB, or bytes); default: the
    # VCIRUN_MAX_MEMORY environment variable, else half the physical memory. Not part of the results.
    max_memory: Union[str, float, None] = None

    @field_validator("store", mode="before")
    @classmethod
    def _store(cls, v):
        """One message for the three forms (rather than one per alternative of the union)."""
        if v is None or v in ("full", "metrics"):
            return v
        every = v.get("every") if isinstance(v, dict) and set(v) == {"every"} else None
        if isinstance(every, int) and not isinstance(every, bool) and 2 <= every <= 10_000_000:
            return v
        raise ValueError(f"must be full, metrics or {{every: k}} with an integer k >= 2 (got {v!r})")

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

    @model_validator(mode="before")
    @classmethod
    def _tolerance_runs(cls, data):
        """`tol: [t, ...]` (or one t): the methods become one entry {name: auto or the method, tol: t} per
        tolerance and method; h defaults to [T] (no largest step). Without tol, methods and h are required."""
        if not isinstance(data, dict):
            return data
        tols = data.get("tol")
        if tols is None:
            return data
        tols = tols if isinstance(tols, list) else [tols]
        data = dict(data, tol=tols)
        bad = [t for t in tols if not (isinstance(t, (int, float)) and not isinstance(t, bool) and 0 < t < float("inf"))]
        if bad:   # (named here: the methods it would have made would be reported missing instead)
            raise ValueError(f"tol: each entry must be a positive number, e.g. 1.0e-6 (got {bad[0]!r})")
        twice = sorted({t for t in tols if tols.count(t) > 1})
        if twice:
            raise ValueError(f"tol: {twice[0]:g} is listed twice; list each tolerance once")
        methods = data.get("methods") or ["auto"]
        if isinstance(methods, list):
            entries = []
            for t in tols:
                for m in methods:
                    spec = {"name": m} if isinstance(m, str) else dict(m) if isinstance(m, dict) else m
                    if isinstance(spec, dict):
                        spec.setdefault("tol", t)
                    entries.append(spec)
            data["methods"] = entries
        if data.get("h") is None and isinstance(data.get("T"), (int, float)) and not isinstance(data.get("T"), bool):
            data["h"] = [data["T"]]
        return data

    @field_validator("tol", mode="before")
    @classmethod
    def _tol_shorthand(cls, v):
        return [v] if isinstance(v, (int, float)) and not isinstance(v, bool) else v

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
                raise FieldError(("h", i), f"must be <= T = {self.T:g} (got {hi:g})")
            try:
                grid_steps(hi, self.T)  # underflowing h, T / h too many steps
            except ValueError as e:
                raise FieldError(("h", i), str(e).partition(": ")[2]) from None
            if hi in seen_h:
                raise FieldError(("h", i), f"duplicate step {hi:g}")
            seen_h.add(hi)
        n_ics = (len(self.beta.values()) if self.beta is not None
                 else len(self.initial_states) if self.initial_states is not None else 1)
        if len(self.methods) * len(self.h) * n_ics > MAX_RUNS:
            raise FieldError(("methods",), f"the grid has {len(self.methods) * len(self.h) * n_ics:,} runs "
                                            f"(methods x h x initial conditions); the limit is {MAX_RUNS:,}")
        seen: dict[str, int] = {}
        idents: dict[str, int] = {}
        for i, m in enumerate(self.methods):
            if m.display in seen:
                raise FieldError(("methods", i), f"duplicate label {m.display!r} (also methods[{seen[m.display]}]);"
                                                  " give one of them a different label")
            ident = json.dumps(m.identity(), sort_keys=True)
            if ident in idents:
                raise FieldError(("methods", i), f"same method and options as methods[{idents[ident]}]")
            seen[m.display] = i
            idents[ident] = i
        if self.store is not None and (self.store == "metrics") == self.store_trajectories \
                and "store_trajectories" in self.model_fields_set:
            raise FieldError(("store",), f"conflicts with store_trajectories: {str(self.store_trajectories).lower()}; "
                                         "give one of them (store: full, metrics or {every: k})")
        if self.beta is not None and self.initial_states is not None:
            raise FieldError(("initial_states",), "give either beta or initial_states, not both")
        if self.beta is not None:
            b = self.beta.values()
            seen_b: set = set()
            dup = [x for x in b if x in seen_b or seen_b.add(x)]  # linear: 100 000 betas are allowed
            if dup:
                raise FieldError(("beta",), f"duplicate beta {dup[0]:g}")
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

    @property
    def store_every(self) -> int:
        """Grid states each run stores: 1 every one, k every k-th (and the last), 0 none (metrics only)."""
        if self.store is None:
            return 1 if self.store_trajectories else 0
        if isinstance(self.store, StoreEvery):
            return self.store.every
        return 1 if self.store == "full" else 0

    def output_path(self) -> Path:
        return Path(self.output) if self.output else Path("results") / f"{self.name}.h5"

    def canonical(self) -> dict:
        """Everything that determines the results (not where they go, nor how many processes or which
        executor compute them)."""
        # (store: only when given, so configs without it keep their key)
        return self.model_dump(mode="json", by_alias=True, exclude={"output", "workers", "executor", "description",
                                                                      "max_memory"} | ({"store"} if self.store is None
                                                                                       else set()))

    def canonical_sha256(self) -> str:
        return hashlib.sha256(json.dumps(self.canonical(), sort_keys=True).encode()).hexdigest()

    def system_label(self) -> str:
        s = self.system
        if isinstance(s, BuiltinSystem):
            return s.name
        if isinstance(s, FileSystem):
            return Path(s.file).stem
        return s.name or "user_system"
