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

from .errors import ConfigError
from .loading import config_text, load_config, parse_config, read_config_data
from .schema import STUDY_KEY, InitialCondition, SweepConfig
from .semantics import build_system, check_memory_of, check_semantics_of
from .specs import (COLLISION_METHODS, DISCRETE_LAGRANGIANS, SMOOTH_METHODS, BuiltinSystem, ExecutorSpec, FileSystem,
                    InlineSystem, MethodReference, MethodSpec, NoReference, check_scheduler_address)

__all__ = ["ConfigError", "SweepConfig", "MethodSpec", "InitialCondition", "ExecutorSpec", "load_config", "parse_config",
           "read_config_data", "config_text", "build_system", "check_semantics_of", "check_memory_of", "STUDY_KEY",
           "COLLISION_METHODS", "SMOOTH_METHODS", "DISCRETE_LAGRANGIANS", "BuiltinSystem", "FileSystem",
           "InlineSystem", "MethodReference", "NoReference", "check_scheduler_address"]
