"""The solver tolerances of a run: one table of names, defaults, bounds and meanings.

`vcirun.simulate` takes them as keyword options (defaults filled in by `split_options`), a sweep
config as its `tolerances:` mapping (the schema's fields and bounds are built from `TOLERANCES`),
and the compiled loop reads them from its settings vector (`vcirun.core.record.SETTINGS` names each
of them). Every run records the values it used.

numpy only: every layer may import this.
"""
from __future__ import annotations

from dataclasses import dataclass

from .values import check_number

__all__ = ["Tolerance", "TOLERANCES", "DEFAULT_TOLERANCES", "METHOD_OPTIONS", "check_tolerances", "split_options"]


@dataclass(frozen=True)
class Tolerance:
    """One tolerance: its default and bounds (gt/ge/le as in `check_number`; integer: a count)."""

    name: str
    default: float
    doc: str
    integer: bool = False
    gt: float | None = None
    ge: float | None = None
    le: float | None = None

    @property
    def bounds(self) -> dict:
        """The bounds as keyword arguments of `check_number` and of a pydantic `Field`."""
        return {k: v for k, v in (("gt", self.gt), ("ge", self.ge), ("le", self.le)) if v is not None}

    def check(self, value, field: str | None = None):
        return check_number(field or self.name, value, integer=self.integer, **self.bounds)


TOLERANCES = {t.name: t for t in (
    Tolerance("newton_tol", 1e-12, "residual tolerance of the Newton solves (full, partial and reset steps)", gt=0),
    Tolerance("event_tol", 1e-13, "tolerance of the collision-time search", gt=0),
    Tolerance("max_iter", 50, "Newton iterations per solve before newton_failed", integer=True, ge=1, le=10_000),
    Tolerance("max_impacts_step", 64, "impacts in one grid step (or steps in a row with impacts) before "
              "accumulation", integer=True, ge=1, le=100_000),
)}
DEFAULT_TOLERANCES = {name: t.default for name, t in TOLERANCES.items()}

# simulate's options that select the method rather than tune the solver
METHOD_OPTIONS = frozenset({"ld", "mh_order", "flow_order"})
_OTHER_ARGUMENTS = ("params", "constrained", "energies", "resting_contact")


def check_tolerances(values: dict) -> None:
    """Each known tolerance within its bounds (ValueError naming it)."""
    for k, v in (values or {}).items():
        if k in TOLERANCES:
            TOLERANCES[k].check(v)


def split_options(options: dict) -> tuple[dict, dict]:
    """(method options, tolerances with defaults) from simulate's **options (unknown names rejected)."""
    mopts = {k: v for k, v in options.items() if k in METHOD_OPTIONS}
    rest = {k: v for k, v in options.items() if k not in METHOD_OPTIONS}
    unknown = set(rest) - set(TOLERANCES)
    if unknown:
        known = sorted(set(TOLERANCES) | METHOD_OPTIONS | set(_OTHER_ARGUMENTS))
        raise ValueError(f"options: unknown option {sorted(unknown)[0]!r} (known: {', '.join(known)})")
    return mopts, DEFAULT_TOLERANCES | rest
