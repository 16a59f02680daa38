"""Identifiers of user systems (coordinates, parameters, system and contact names) and the caps on
a declaration's size.

A name must be ASCII: Python reads identifiers through Unicode normalisation (NFKC), so the generated
kernels would read ``s_ｋ`` as ``s_k``; no two names may collide after it, and no name may be one the
generated code gives its own symbols.

No sympy and no numba here.
"""
from __future__ import annotations

import keyword
import re
import unicodedata

from .limits import cap
from .values import describe

__all__ = ["MAX_COORDINATES", "MAX_CONTACTS", "MAX_PARAMETERS", "MAX_NAME_CHARS", "ascii_name_problem",
           "reserved_name_problem",
           "check_identifier", "check_distinct_names", "check_system_name", "check_description"]

# Declarations of user systems (vcirun.core.limits.CAPS says why each cap is where it is).
MAX_COORDINATES = cap("coordinates")
MAX_CONTACTS = cap("contacts")
MAX_PARAMETERS = cap("parameters")
MAX_NAME_CHARS = cap("name_characters")


def ascii_name_problem(name: str) -> str | None:
    """Why `name` is not an acceptable identifier, or None. Python reads identifiers through NFKC
    (so 'ｋ' is 'k' to generated code): names must be ASCII."""
    if not isinstance(name, str) or not name:
        return "must be a non-empty name"
    if len(name) > MAX_NAME_CHARS:
        return f"name is {len(name)} characters long; the limit is {MAX_NAME_CHARS}"
    if not name.isascii():
        norm = unicodedata.normalize("NFKC", name)
        bad = next(c for c in name if not c.isascii())
        what = f"{bad!r} (U+{ord(bad):04X} {unicodedata.name(bad, 'unnamed character')})"
        if norm.isascii() and norm.isidentifier():
            return (f"{describe(name)} is not ASCII: {what} reads as {norm!r} after Unicode normalisation (NFKC); "
                    f"write {norm!r}")
        return f"{describe(name)} is not ASCII: {what}; use ASCII letters, digits and '_'"
    return None


# Names the generated code gives its own symbols (vcirun.discrete slot symbols qa0.., va0.., qb0.., hh,
# tt; vcirun.codegen.tensor placeholders vcTQ0.., vcTV0.., vcTT, temporaries vcTC0.., outputs vcTG0..;
# CSE temporaries cse0..; vcirun.modified symbols mh_*; MechanicalSystem's numeric helpers xm0..). A
# coordinate or parameter with such a name is the same sympy Symbol or the same printed name as the
# generated one, so the kernels silently read the wrong value: a parameter named vcTQ0 is read as the
# first coordinate by the tensor kernels (status ok, a wrong trajectory).
_RESERVED_NAME = re.compile(r"hh|tt|(?:qa|va|qb|cse|xm)\d+|vcT\w*|mh_\w*")


def reserved_name_problem(name) -> str | None:
    """Why `name` cannot name a coordinate or parameter because generated code uses it, or None."""
    if isinstance(name, str) and _RESERVED_NAME.fullmatch(name):
        return (f"{name!r} is reserved: the generated kernels use it for their own symbols (reserved: hh, tt, "
                "qa<k>, va<k>, qb<k>, cse<k>, xm<k>, vcT..., mh_...); choose another name")
    return None


def check_identifier(name, field: str, *, reserved=()) -> str:
    """An ASCII Python identifier, not a keyword, not starting with '_', not reserved."""
    if not isinstance(name, str):
        raise ValueError(f"{field}: must be a name (got {describe(name)})")
    problem = ascii_name_problem(name)
    if problem:
        raise ValueError(f"{field}: {problem}")
    if not name.isidentifier() or name.startswith("_"):
        raise ValueError(f"{field}: {name!r} is not a valid name (letters, digits and '_', starting with a letter)")
    if keyword.iskeyword(name):
        raise ValueError(f"{field}: {name!r} is a Python keyword; choose another name")
    if name in reserved:
        raise ValueError(f"{field}: {name!r} is reserved; choose another name")
    problem = reserved_name_problem(name)
    if problem:
        raise ValueError(f"{field}: {problem}")
    return name


def check_distinct_names(names: dict, prefix: str) -> None:
    """No two names (field -> name) equal after NFKC; each name ASCII (collisions reported first)."""
    seen: dict[str, str] = {}
    for fld, name in names.items():
        key = unicodedata.normalize("NFKC", name) if isinstance(name, str) else name
        if key in seen:
            other = seen[key]
            how = "" if names[other] == name else " after Unicode normalisation (NFKC)"
            raise ValueError(f"{prefix}.{fld}: {describe(name)} collides with {prefix}.{other} "
                             f"({describe(names[other])}){how}; names must be distinct")
        seen[key] = fld
    for fld, name in names.items():
        problem = ascii_name_problem(name)
        if problem:
            raise ValueError(f"{prefix}.{fld}: {problem}")


def check_system_name(name, field_prefix: str) -> str:
    """A system file's `name` (ASCII letters, digits, '_', '-', '.'); ValueError naming the field."""
    if not isinstance(name, str) or not name.strip():
        raise ValueError(f"{field_prefix}.name: must be a non-empty name (got {describe(name)})")
    problem = ascii_name_problem(name)
    if problem:
        raise ValueError(f"{field_prefix}.name: {problem}")
    if not all(c.isalnum() or c in "_.-" for c in name):
        raise ValueError(f"{field_prefix}.name: use letters, digits, '_', '-' and '.' only (got {name!r})")
    return name


def check_description(text, field_prefix: str) -> str:
    """A system file's `description`: text of at most 10,000 characters."""
    if text is None:
        return ""
    if not isinstance(text, str):
        raise ValueError(f"{field_prefix}.description: must be text (got {describe(text)})")
    if len(text) > 10_000:
        raise ValueError(f"{field_prefix}.description: {len(text):,} characters; the limit is 10,000")
    return text
