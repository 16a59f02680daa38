"""The checks of a sweep config that need the numerical core: the system is built (unknown names,
malformed expressions), the methods resolved, every initial condition mapped, and the finest run's
memory estimated. Cheap: no kernel is compiled, and sympy is imported only when a check runs."""
from __future__ import annotations

import difflib
import math
from pathlib import Path

import numpy as np

from ...core.bounds import check_scene_size
from ...core.grid import grid_end, grid_steps
from ...core.sizes import check_run_memory
from .errors import ConfigError
from .schema import SweepConfig
from .specs import BuiltinSystem, FileSystem, MethodReference

__all__ = ["build_system", "check_semantics_of", "check_memory_of"]


def build_system(cfg: SweepConfig):
    """(system argument for vcirun.simulate/reference, parameter overrides or None, MechanicalSystem)."""
    from vcirun.mechanics import load_system_yaml
    from vcirun.scenes.registry import get_scene
    from vcirun.scenes.registry import BUILTIN_SCENES, scene_args

    s = cfg.system
    if isinstance(s, BuiltinSystem):
        if scene_args(s.name) is None:  # the one scene registry (vcirun.scenes.registry)
            hint = difflib.get_close_matches(s.name, list(BUILTIN_SCENES), n=1)
            raise _Semantic("system",
                            f"unknown built-in system {s.name!r}" + (f"; did you mean {hint[0]!r}?" if hint else "")
                            + f" (choose one of {', '.join(BUILTIN_SCENES)}, or a YAML file path)")
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
        if m.name == "auto":   # chosen per run (simulate(tol=...))
            continue
        try:
            meth = resolve_method(m.name, **{k: v for k, v in m.simulate_kwargs().items()
                                             if k in ("ld", "mh_order", "flow_order")})
        except (ValueError, TypeError, NotImplementedError) as e:
            _, msg = _strip_field(str(e), "")
            raise ConfigError(msg, source=source, field=f"methods[{i}]") from None
        if m.tol is not None:   # the methods tol= refuses to certify
            from vcirun.run.choose import uncertifiable

            why = uncertifiable(meth, sysm.m, bool(sysm.is_forced))
            if why:
                raise ConfigError(why, source=source, field=f"methods[{i}]")
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
