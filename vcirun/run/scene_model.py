"""The work-precision model of a scene in this process (`SceneModel`): per candidate method, the error
constants, the coarsest resolved and asymptotic N of each start piloted, and the cost a + b N of a run;
keyed by system, parameters, horizon and options (`scene_key`). vcirun.run.choose fills and reads it;
stored measurements (a study's or a sweep's results) have their own model:
vcirun.experiments.studies.wp_model."""
from __future__ import annotations

import math
import os
import stat
from bisect import insort
from dataclasses import dataclass, field

@dataclass
class MethodModel:
    """One method on one scene: its order, error constants (one per start piloted), the coarsest
    resolved N of each, the CPU cost b per step (energies as the final run computes them) and a per
    run, and why it is not resolved (if it never was)."""

    order: float
    C: list = field(default_factory=list)
    N_resolved: list = field(default_factory=list)
    N_asymptotic: list = field(default_factory=list)
    b: float | None = None
    a: float | None = None
    unresolved: str = ""
    # the round-off floors twin runs measured on this scene (any start), each as F / sqrt(N) (F grows like
    # sqrt(N): vcirun.run.estimate.amplified_floor); inf where a twin changed the impacts
    floors: list = field(default_factory=list)

    def floor_at(self, N: int, samples: int) -> float | None:
        """The largest floor measured on the scene, scaled to an N-step run; None with fewer than
        `samples` measurements (a sample, not a bound: a start unlike those seen may amplify more)."""
        if len(self.floors) < samples:
            return None
        return max(self.floors) * math.sqrt(N)

    def medians(self) -> tuple:
        """(constant(), n_asymptotic(), n_resolved()): what the choice reads of the model for every candidate
        on every later call, kept while the lists keep their lengths (they only grow)."""
        key = (len(self.C), len(self.N_asymptotic), len(self.N_resolved))
        hit = self.__dict__.get("_all")
        if hit is None or hit[0] != key:
            hit = self.__dict__["_all"] = (key, (self.constant(), self.n_asymptotic(), self.n_resolved()))
        return hit[1]

    def constant(self) -> float | None:
        """The median error constant (cached: the model is consulted on every call)."""
        return self._median("C", float)

    def n_asymptotic(self) -> int | None:
        """The median of the coarsest N at which the order showed, over the starts piloted."""
        return self._median("N_asymptotic", int)

    def n_resolved(self) -> int | None:
        """The median of the coarsest resolved N, over the starts piloted."""
        return self._median("N_resolved", int)

    def _median(self, name: str, kind):
        """_median of the list `name` (kept with the list sorted as it grows: each call of the choice adds a
        value, and sorting the whole list again costs its length)."""
        values = getattr(self, name)
        if not values:
            return None
        memo = self.__dict__.setdefault("_medians", {})
        hit = memo.get(name)   # (length, median, the values sorted but NaNs, any NaN)
        n = len(values)
        if hit is None or hit[0] != n:
            # the lists only grow: the values added since are inserted after those equal to them (insort_right),
            # where a stable sort of the whole list puts them; a list that shrank is sorted anew
            old = hit is not None and hit[0] < n
            s, nan = (hit[2], hit[3]) if old else ([], False)
            for v in values[hit[0] if old else 0:]:
                if math.isnan(v):
                    nan = True
                else:
                    insort(s, v)
            hit = memo[name] = (n, kind(math.nan if nan else _middle(s)), s, nan)
        return hit[1]


def _median(values) -> float:
    """np.median of a list of numbers, bit for bit (the middle one, else the mean (a + b) / 2 of the two
    middle ones, as numpy's mean of two computes it; NaN if any is NaN), without numpy's per-call cost
    (~10 us; the model is consulted for every candidate on every call)."""
    s = sorted(values)
    if any(map(math.isnan, s)):
        return math.nan
    return _middle(s)


def _middle(s: list):
    """The median of a sorted list (not empty)."""
    m = len(s) // 2
    return s[m] if len(s) % 2 else (s[m - 1] + s[m]) / 2


@dataclass
class SceneModel:
    """The work-precision model of one scene (system, parameters, horizon, options) in this process:
    the scene's features (contacts, generalized force, declared reset map) and a MethodModel per
    candidate; `starts`: the starts piloted."""

    key: tuple
    T: float
    n_contacts: int = 1
    forced: bool = False
    mapped: bool = False
    methods: dict = field(default_factory=dict)
    starts: int = 0


_MODELS: dict = {}


def scene_model(key) -> SceneModel | None:
    return _MODELS.get(key)


def scene_key(system, params, T, t0, constrained, resting_contact, options, energies):
    """The key of a scene model: a built-in name or file path (with its modification time), or the
    identity of a MechanicalSystem instance; the parameters, the horizon and the options."""
    if isinstance(system, str):
        try:   # (one stat: os.path.isfile and os.path.getmtime would make two)
            st = os.stat(system)
        except (OSError, ValueError):
            st = None
        ident = (system, st.st_mtime) if st is not None and stat.S_ISREG(st.st_mode) else (system,)
    else:
        ident = ("object", id(system))
    prm = tuple(sorted((params or {}).items()))
    return ident + (prm, float(T), float(t0), constrained, bool(resting_contact), tuple(sorted(options.items())),
                    bool(energies))
