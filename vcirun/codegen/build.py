"""The kernel cache's entry point for the other layers: `load_module` (the module of a symbolic system and a
kernel set, from the default vcirun.codegen.kernel_cache.KernelCache, on a tier of vcirun.codegen.tiers),
`module_key`, and the names of vcirun.codegen.modules (build mode, keys, texts), which say what a module
is.
"""
from __future__ import annotations

from .kernel_set import KernelSet
from .modules import (  # noqa: F401 - the names other layers import from here
    _PKG,
    BUILDS,
    WARM_FORMAT,
    backend_id,
    build_id,
    build_mode,
    build_policy,
    building,
    cache_dir,
    core_ndof,
    family,
    generate,
    interpreted_text,
    module_key_of,
    module_text,
    specialized_key,
    system_core_features,
    warm_key_of,
)


def load_module(system, ks: KernelSet, tier: str | None = "compiled"):
    """The module for (symbolic system, ks) from the default kernel cache on `tier`: "compiled" (waiting
    for the compiler if need be), or "interpreted", "auto", None ($VCIRUN_TIER, else auto)
    (vcirun.codegen.tiers.load_module)."""
    from .tiers import load_module as on_tier

    return on_tier(system, ks, tier)


def module_key(system, ks: KernelSet) -> str:
    """The module key of (symbolic system, ks), memoised by the default kernel cache."""
    from .kernel_cache import default

    return default().module_key(system, ks)
