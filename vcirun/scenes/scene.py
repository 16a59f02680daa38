"""A built-in scene is one declaration, a `Scene`: its parameters (default, unit, meaning), its
coordinates (unit, meaning), its description, constraint and initial-condition text, a numeric start
hook and a symbolic builder. Everything else is derived from it: the numeric part (`Scene.data`, a
`SystemData`, what a warm start needs), the symbolic system (`Scene.system`, a `MechanicalSystem`)
and the catalog text (`Scene.info`, for `vcirun systems` and `Trajectory.to_xarray`).

This module and the modules declaring scenes import no sympy at module level: the symbolic builder
imports it when it is called, so a warm start resolves a scene by name without sympy. A family
(`n_pendulum_K`, `link_chain_K`, ...) is one Scene with `size` (its default K); its fields that
depend on K are functions of K.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

from ..core.system_data import SystemData, merge_params

__all__ = ["Param", "Scene", "SceneInfo", "Symbols", "StudyHooks", "EVERY_CONTACT_E"]

# the restitution map of the scenes whose contacts all take the parameter e
EVERY_CONTACT_E = {"e": ["every contact"]}


@dataclass(frozen=True)
class Param:
    """One parameter: its default value, SI unit ("" for a number) and meaning."""
    default: float
    unit: str
    meaning: str


@dataclass(frozen=True)
class SceneInfo:
    """coordinates: ((name, unit, meaning), ...); params: {name: (unit, meaning)}; constraint and
    initial-condition map in words."""
    name: str
    coordinates: tuple
    params: dict
    constraint: str
    ic_map: str = ""
    default_state: str = ""


@dataclass(frozen=True)
class StudyHooks:
    """What the contact studies (vcirun.experiments.studies.contact) need of a scene, each None where a
    study has no construction for it:
    free_params: parameter overrides that take the constraint out of reach (the unconstrained motion);
    graze(q0, params, phimin, depth) -> (q0, params): the start and parameters that move the motion's
      closest approach phimin to `depth` inside the constraint;
    surface(kind, {param: value}) -> (q, qdot): a state on phi = 0 (kinds 'out', 'in', 'rest', 'lift');
    closed_form(q0, {param: value}, T, t) -> (impact times, q[:, 0] on the times t): the exact motion;
    refused: {surface kind: why it has no construction here} (a study config naming it is refused);
    label: the scene's short name in the study report."""
    free_params: dict = field(default_factory=dict)
    graze: Callable | None = None
    surface: Callable | None = None
    closed_form: Callable | None = None
    refused: dict = field(default_factory=dict)
    label: str = ""


class _ParamSymbols:
    """The parameter symbols by attribute or by key (p.m1, p["m1"])."""

    def __init__(self, symbols: dict):
        self.__dict__.update(symbols)

    def __getitem__(self, name):
        return self.__dict__[name]


class Symbols:
    """What a symbolic builder gets: the scene data `d` (name, parameter values, start), the size `k`
    (a family's K, else None), the coordinate symbols `q`, their velocity symbols `qd` (<name>_dot),
    the parameter symbols `p` (p.m1 or p["m1"]) and `start`: a constructor's start arguments for the
    builder (vcirun.scenes.friction), else empty."""

    def __init__(self, d: SystemData, k, coordinates, params, start=None):
        import sympy as sp

        self.d, self.k, self.start = d, k, dict(start or {})
        self.q = [sp.Symbol(c) for c in coordinates]
        self.qd = [sp.Symbol(f"{c}_dot") for c in coordinates]
        self.p = _ParamSymbols({name: sp.Symbol(name) for name in params})


def _at(x, k):
    """A field's value: x(k) for a family's K-dependent field, else x."""
    return x(k) if callable(x) else x


@dataclass(frozen=True, eq=False)
class Scene:
    """One built-in scene. Fields that depend on a family's K are functions of K.
    params: {name: Param} in declaration order (the order of the kernels' parameter vector);
    coordinates: ((name, unit, meaning), ...); symbolic: Symbols -> MechanicalSystem (imports sympy);
    start: sympy-free, ({param: value}) or ({param: value}, K) -> {ic_map, default_q0, default_p0,
    default_beta, ic_map_params} (the SystemData start fields it sets); example: (the arguments `vcirun
    systems` adds to `vcirun simulate --system NAME`, what that shows)."""
    name: str
    description: object
    coordinates: object
    params: object
    constraint: object
    symbolic: Callable
    start: Callable | None = None
    ic_text: object = ""
    default_text: object = ""
    example: tuple = ("", "")
    restitution: dict | None = None
    size: int | None = None
    study: StudyHooks | None = None

    def full_name(self, k=None) -> str:
        return f"{self.name}_{int(k)}" if self.size is not None else self.name

    def _k(self, k):
        if self.size is None:
            if k is not None:
                raise ValueError(f"scene {self.name} takes no size")
            return None
        return int(self.size if k is None else k)

    def param_table(self, k=None) -> dict:
        """{name: Param} at size k."""
        return _at(self.params, self._k(k))

    def data(self, k=None, /, **overrides) -> SystemData:
        """The numeric part (no sympy): parameters with overrides, start, description."""
        k = self._k(k)
        table = _at(self.params, k)
        prm = merge_params({name: p.default for name, p in table.items()}, overrides)
        start = {} if self.start is None else (self.start(prm) if k is None else self.start(prm, k))
        return SystemData(name=self.full_name(k), n=len(_at(self.coordinates, k)), params=prm,
                          restitution=self.restitution, description=_at(self.description, k), **start)

    def system(self, k=None, /, **overrides):
        """The symbolic MechanicalSystem: the builder's M, V, constraints and forcing, with the start and
        description of `data`."""
        k = self._k(k)
        d = self.data(k, **overrides)
        s = self.symbolic(Symbols(d, k, [c[0] for c in _at(self.coordinates, k)], d.params))
        s.ic_map, s.default_beta, s.default_q0, s.default_p0 = d.ic_map, d.default_beta, d.default_q0, d.default_p0
        s.ic_map_params, s.description = d.ic_map_params, d.description
        return s

    def constructed(self, k=None, /, start=None, **overrides):
        """The builder's system at these parameters without the scene's start: a constructor's system
        (vcirun.scenes.friction) whose default state the builder makes from `start` (its q0, qdot0)."""
        k = self._k(k)
        d = replace(self.data(k, **overrides), ic_map=None, default_q0=None, default_p0=None, default_beta=None,
                    ic_map_params=False)
        return self.symbolic(Symbols(d, k, [c[0] for c in _at(self.coordinates, k)], d.params, start))

    def info(self, k=None) -> SceneInfo:
        k = self._k(k)
        return SceneInfo(self.full_name(k), _at(self.coordinates, k),
                         {name: (p.unit, p.meaning) for name, p in _at(self.params, k).items()},
                         _at(self.constraint, k), _at(self.ic_text, k), _at(self.default_text, k))
