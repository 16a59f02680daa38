"""Assemble, cache and load one compiled module per (scene, kernel set).

The module text = generated kernels (one CSE pass each) + the numba *source units* of the numeric
layers (vcirun/maps, vcirun/collision, vcirun/modified) + the bindings `full`, `partial`, `reset`,
`modified_energy`. Everything lives in one file so that numba's on-disk cache works for the whole
event loop: numba cannot cache a function that takes another jitted function as an argument, and
a compiled loop calling compiled kernels is what makes a 500-step simulation take microseconds.

Cache key = hash(system's symbolic content, kernel set, source of the units and of this package's
code generator, vcirun and numba versions). A warm start finds the file by key before any symbolic
work is done.
"""
from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numba

from .. import __version__

_PKG = Path(__file__).resolve().parent.parent
UNITS_BASE = ["maps/linalg.py", "maps/steps.py", "collision/events.py", "collision/resets.py",
              "collision/algorithm1.py"]
# files whose text changes the generated code: hashed into the key
_GENERATOR_FILES = ["codegen/kernels.py", "codegen/printer.py", "codegen/build.py", "codegen/derive.py",
                    "discrete/lagrangians.py", "mechanics/system.py"]
# ... and, only for the MCVA family's modules (so that editing them does not invalidate CVA/VCI caches)
_MODIFIED_GENERATOR_FILES = ["modified/derive.py", "modified/series.py"]

_loaded: dict[str, object] = {}
BUILD_LOG: list[dict] = []  # (key, symbolic seconds, write seconds, cached?) for benchmarks


def cache_dir() -> Path:
    d = Path(os.environ.get("VCIRUN_CACHE_DIR", Path.home() / ".cache" / "vcirun")) / "kernels"
    d.mkdir(parents=True, exist_ok=True)
    return d


@dataclass(frozen=True)
class KernelSet:
    """What one compiled module must contain: the explicit stages of the full map, which partial map
    and reset to bind, and (MCVA family) the modified-Hamiltonian data."""

    full_stages: tuple                 # ((explicit Ld name, fraction of h), ...)
    partial: str = "ld"                # "ld" (same map as full) or "gauss"
    reset: str = "cva"                 # "cva", "vci", "mcva"
    vci_stage: str | None = None       # explicit Ld whose energy R^VCI conserves
    modified: tuple | None = None      # (Ld name, mh_order, flow_order) for the MCVA family

    def key_text(self) -> str:
        return repr(self)

    @property
    def explicit_names(self) -> tuple:
        names = [s for s, _ in self.full_stages]
        if self.vci_stage and self.vci_stage not in names:
            names.append(self.vci_stage)
        return tuple(dict.fromkeys(names))


def _units(ks: KernelSet) -> list[str]:
    units = list(UNITS_BASE)
    if ks.modified is not None:
        units[-1:-1] = ["modified/numeric.py"]
    return units


_keys: dict = {}


def module_key(system, ks: KernelSet) -> str:
    memo = (id(system), system.fingerprint(), ks)
    if memo not in _keys:
        _keys[memo] = _module_key(system, ks)
    return _keys[memo]


def _module_key(system, ks: KernelSet) -> str:
    h = hashlib.sha256()
    h.update(system.fingerprint().encode())
    h.update(ks.key_text().encode())
    h.update(f"{__version__}|{numba.__version__}|{sys.version_info[:2]}".encode())
    files = set(_units(ks)) | set(_GENERATOR_FILES)
    if ks.modified is not None:
        files |= set(_MODIFIED_GENERATOR_FILES)
    for rel in sorted(files):
        p = _PKG / rel
        if p.exists():
            h.update(p.read_bytes())
    return h.hexdigest()[:20]


def load_module(system, ks: KernelSet):
    """The compiled module for (system, ks): from memory, from the disk cache, or generated now."""
    key = module_key(system, ks)
    if key in _loaded:
        return _loaded[key]
    path = cache_dir() / f"vk_{key}.py"
    t0 = time.perf_counter()
    cached = path.exists()
    if not cached:
        from .derive import module_source  # sympy work happens only here, on a cache miss

        text = module_source(system, ks, [(_PKG / u).read_text() for u in _units(ks)])
        tmp = path.with_suffix(f".tmp{os.getpid()}")
        tmp.write_text(text)
        os.replace(tmp, path)  # atomic: parallel workers never import a half-written file
    t1 = time.perf_counter()
    name = f"vcirun_kernels_{key}"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    BUILD_LOG.append({"key": key, "system": system.name, "kernels": ks.key_text(), "cached": cached,
                      "generate_s": t1 - t0})
    _loaded[key] = mod
    return mod
