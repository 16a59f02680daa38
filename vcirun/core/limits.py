"""The caps on what one declaration, run or call may ask for: one table (`CAPS`), read by every
place that enforces a cap (the hand-written and bodies forms of a system file, the built-in scene
families, the expression parser, the time grid, `vcirun.ensemble`), so a limit is the same number
and the same message wherever it is met.

A refusal is one `ValueError` line naming the field, the count, the cap and what to do instead
(`refuse`). Memory is the other bound: a run's buffers and an ensemble's results are estimated from
the run record before anything is allocated and refused above `vcirun.core.sizes.memory_limit`
(half the physical memory unless VCIRUN_MAX_MEMORY or a sweep's max_memory says otherwise), with the
estimate in the message.

numpy only: every layer may import this.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Cap", "CAPS", "FAMILY_SIZES", "cap", "refuse", "check_count", "sized_family", "family_size_problem"]


@dataclass(frozen=True)
class Cap:
    limit: int | float
    what: str      # what is counted, plural ("coordinates")
    why: str       # why there is a cap at this number
    fix: str       # what to do instead


CAPS: dict[str, Cap] = {
    # the symbolic derivation and the generated kernels grow like n**2 (M) to n**4 (the second
    # derivatives of M), with every entry a sum over n terms
    "coordinates": Cap(32, "coordinates", "the generated kernels grow like n**2 to n**4",
                       "model fewer coordinates"),
    # the impact law's scratch is contacts x contacts (on the stack up to 4096 doubles, on the heap
    # beyond: vcirun.maps.linalg.STACK_DOUBLES) and every event search tests each contact per step
    "contacts": Cap(1000, "contacts (constraints)", "each step tests every contact and an impact solves a "
                    "contacts x contacts problem", "declare fewer contacts"),
    "parameters": Cap(1024, "parameters", "each is an argument of every generated kernel",
                      "use fewer parameters (numbers can be written into the expressions)"),
    # springs and dampers of a bodies declaration: each adds a term with its derivatives to V or f
    "force_elements": Cap(1000, "springs and dampers", "each adds its terms to the potential or the forcing",
                          "declare fewer springs and dampers"),
    "repeat": Cap(1000, "items", "one repeat declares that many items", "use a smaller range"),
    "expression_characters": Cap(10_000, "characters", "parse time and memory grow with it",
                                 "split it with parameters or simplify it"),
    "expression_nodes": Cap(5_000, "numbers, names and operations", "the generated kernels grow with it",
                            "split it with parameters or simplify it"),
    "expression_depth": Cap(100, "nesting levels", "the parser walks the tree recursively",
                            "split it or simplify it"),
    "name_characters": Cap(64, "characters", "names appear in generated code and records", "use a shorter name"),
    # beyond 1e12 steps nothing fits in memory, and T / h stops being an exact step count near 2**53
    "steps": Cap(1e12, "steps", "T / h steps of one run", "raise h or lower T"),
    # ensemble members x steps: the work of one vcirun.ensemble call (1e12 steps take days on one core)
    "ensemble_steps": Cap(1e12, "member steps (members x T / h)", "the work of one call",
                          "split the ensemble (vcirun.run.ensemble.iter_ensemble runs batches), raise h or lower T"),
}

# The built-in families named <family>_K (a name that extends another first: cradle_gap_K, cradle_K): K's range and the coordinates and contacts K gives. Every
# family stays within the coordinate cap except newton_cradle, whose model is linear in K (M = m I,
# V = 0, each phi_i the difference of two coordinates): its kernels grow like K, not K**2 to K**4.
FAMILY_SIZES = {
    #               (smallest K, largest K, coordinates(K), contacts(K))
    "n_pendulum": (1, 32, lambda k: k, lambda k: 1),
    "link_chain": (1, 30, lambda k: k + 2, lambda k: k + 1),
    "link_chain_friction": (1, 30, lambda k: k + 2, lambda k: k + 1),
    "cradle_gap": (2, 32, lambda k: k, lambda k: k - 1),
    "cradle": (2, 32, lambda k: k, lambda k: k - 1),
    "newton_cradle": (1, 128, lambda k: k, lambda k: k - 1),
}


def cap(name: str) -> int | float:
    return CAPS[name].limit


def refuse(name: str, field: str, count, fix: str | None = None, what: str | None = None) -> ValueError:
    """The ValueError of `field` over the cap `name`: count (of `what`, default the cap's), cap, and
    what to do instead."""
    c = CAPS[name]
    n = f"{count:,}" if isinstance(count, int) else f"{count:.3g}"
    lim = f"{c.limit:,}" if isinstance(c.limit, int) else f"{c.limit:.0e}"
    return ValueError(f"{field}: {n} {what or c.what}; the limit is {lim} ({c.why}); {fix or c.fix}")


def check_count(name: str, field: str, count, fix: str | None = None, what: str | None = None) -> None:
    """Refuse `count` above the cap `name` (ValueError naming `field`)."""
    if count > CAPS[name].limit:
        raise refuse(name, field, count, fix, what)


def sized_family(name) -> tuple[str, int] | None:
    """(family, K) of a name <family>_K of a sized built-in family, else None; ValueError (naming the
    system) when K is outside the family's range, before anything is built."""
    if not isinstance(name, str):
        return None
    for family in FAMILY_SIZES:
        digits = name[len(family) + 1:] if name.startswith(family + "_") else ""
        if digits.isdigit() and digits.isascii():
            lo, hi = FAMILY_SIZES[family][:2]
            if len(digits) > 12:
                raise ValueError(f"system: {name[:40]}...: {family}_K takes K from {lo} to {hi}")
            problem = family_size_problem(family, int(digits))
            if problem:
                raise ValueError(f"system: {problem}")
            return family, int(digits)
    return None


def family_size_problem(family: str, k: int) -> str | None:
    """Why <family>_K is out of range, or None."""
    lo, hi, coords, contacts = FAMILY_SIZES[family]
    if lo <= k <= hi:
        return None
    if k < lo:
        return f"{family}_{k}: {family}_K takes K from {lo} to {hi}"
    m = contacts(k)
    return (f"{family}_{k} has {coords(k):,} coordinates and {m:,} contact{'s' * (m != 1)}; {family}_K takes K "
            f"from {lo} to {hi}" + ("" if family == "newton_cradle" else
                          f" (the limit is {cap('coordinates')} coordinates: {CAPS['coordinates'].why})"))
