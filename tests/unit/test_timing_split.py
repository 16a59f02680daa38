"""wall_time is integration only: numba's first call of a freshly loaded module's loop (loading its
machine code, or compiling it) is made untimed before the timed call; sweeps report the time spent
preparing kernels apart from the runs."""
from __future__ import annotations

import numpy as np

import vcirun
from vcirun.codegen import build
from vcirun.codegen.kernel_cache import KernelCache


class _Counting:
    """A module proxy recording the N of every loop call."""

    def __init__(self, mod):
        self._mod, self.calls = mod, []
        self.__name__ = mod.__name__ + "_proxy"

    def __getattr__(self, name):
        return getattr(self._mod, name)

    def integrate(self, *args):
        self.calls.append(int(args[4]))
        return self._mod.integrate(*args)


def test_first_call_of_a_module_is_made_untimed():
    real = build.load_module
    proxies = []

    def loader(system, ks):
        proxies.append(_Counting(real(system, ks)))
        return proxies[-1]

    kc = KernelCache(loader=loader)   # one cache for both calls: it remembers the first call
    a = vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=1, beta=3.2, loader=kc)
    b = vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=1, beta=3.2, loader=kc)
    calls = [c for p in proxies for c in p.calls]
    assert calls == [1, 100, 100]      # one untimed step, then only the two timed integrations
    np.testing.assert_array_equal(a.q, b.q)
    assert a.wall_time > 0 and b.wall_time > 0


def test_sweep_reports_preparation_apart(tmp_path):
    from vcirun.experiments.config import parse_config
    from vcirun.experiments.sweep import run_sweep

    cfg = parse_config({"name": "prep", "system": "cart_pendulum", "methods": ["CVA"], "h": [3.2e-2],
                        "beta": [3.2], "T": 0.3, "timing_repeats": 1, "reference": {"kind": "none"},
                        "output": str(tmp_path / "p.h5")})
    s = run_sweep(cfg, workers=1, progress=False)
    assert s.computed == 1 and 0 < s.prepare_time < s.wall_time
