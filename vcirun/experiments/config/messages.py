"""pydantic's validation errors as one line a user can act on: the field path as written in the
config, unknown keys with the closest known one, and every problem at once."""
from __future__ import annotations

import difflib
import re
import typing
from typing import Annotated, Any, Union

from pydantic import BaseModel, ValidationError

from .errors import ConfigError, FieldError
from .schema import SweepConfig
from .specs import TAG_MODELS

__all__ = ["from_validation_error", "format_loc"]

_TAGS = {"builtin", "file", "inline", "range", "list", "exact", "method", "none"}
_UNION_FIELDS = {"system", "beta", "reference"}


def _clean_loc(loc: tuple) -> tuple:
    """Drop pydantic's union-member tags from an error location ('system', 'inline', 'x' -> 'system', 'x')."""
    out = []
    for i, part in enumerate(loc):
        if isinstance(part, str) and part in _TAGS and i > 0 and loc[i - 1] in _UNION_FIELDS:
            continue
        if part == "values_":
            part = "values"
        out.append(part)
    if len(out) >= 2 and out[0] == "beta" and out[1] == "values":
        out.pop(1)  # `beta: [..]` is written as a list; report beta[i]
    return tuple(out)


def format_loc(loc: tuple) -> str:
    s = ""
    for part in loc:
        if isinstance(part, int):
            s += f"[{part}]"
        else:
            s += ("." if s else "") + str(part)
    return s or "(top level)"


def _unwrap(tp):
    """Strip Annotated/Optional to the underlying type(s)."""
    while typing.get_origin(tp) is Annotated:
        tp = typing.get_args(tp)[0]
    if typing.get_origin(tp) is Union:
        return [a for t in typing.get_args(tp) if t is not type(None) for a in _unwrap(t)]
    return [tp]




def _model_at(loc: tuple, root=None):
    """The pydantic model class at a raw error location (from `root`, default SweepConfig), to list its
    allowed keys."""
    current: Any = root or SweepConfig
    for part in loc:
        if isinstance(part, str) and part in TAG_MODELS:
            current = TAG_MODELS[part]  # pydantic names the union member it tried
            continue
        if isinstance(current, type) and issubclass(current, BaseModel):
            fields = {(f.alias or n): f for n, f in current.model_fields.items()}
            if part not in fields:
                return None
            cands = _unwrap(fields[part].annotation)
        elif typing.get_origin(current) in (list, dict):
            cands = _unwrap(typing.get_args(current)[-1])
        elif current == "union":
            return None
        else:
            return None
        models = [c for c in cands if isinstance(c, type) and issubclass(c, BaseModel)]
        if len(models) > 1:
            current = "union"  # the next location part is the member's tag
        elif len(models) == 1:
            current = models[0]
        elif len(cands) == 1:
            current = cands[0]
        else:
            return None
    return current if isinstance(current, type) and issubclass(current, BaseModel) else None


def _allowed_keys(model) -> list[str]:
    return [f.alias or n for n, f in model.model_fields.items()]


def _describe(value) -> str:
    s = repr(value)
    return s if len(s) <= 40 else s[:37] + "..."


def _pydantic_message(err: dict, root=None) -> tuple[tuple, str]:
    raw = tuple(err["loc"])
    loc = _clean_loc(raw)
    typ, ctx, inp = err["type"], err.get("ctx") or {}, err.get("input")
    if typ == "extra_forbidden":
        key = raw[-1]
        model = _model_at(raw[:-1], root)
        allowed = _allowed_keys(model) if model else []
        hint = difflib.get_close_matches(str(key), allowed, n=1)
        msg = "unknown key"
        if hint:   # the closest key says enough; the whole list only where none is close
            msg += f"; did you mean {hint[0]!r}?"
        elif allowed:
            msg += f" (allowed: {', '.join(allowed)})"
        return loc, msg
    if typ == "missing":
        return loc, "required key is missing"
    if typ in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        op = {"greater_than": ">", "greater_than_equal": ">=", "less_than": "<", "less_than_equal": "<="}[typ]
        bound = next(iter(ctx.values()), "?")
        bound = f"{bound:g}" if isinstance(bound, (int, float)) else bound
        return loc, f"must be {op} {bound} (got {_describe(inp)})"
    if typ == "literal_error":
        return loc, f"must be one of {ctx.get('expected', '?')} (got {_describe(inp)})"
    if typ in ("float_parsing", "float_type", "finite_number"):
        return loc, f"must be a finite number (got {_describe(inp)})"
    if typ in ("int_parsing", "int_type", "int_from_float"):
        return loc, f"must be an integer (got {_describe(inp)})"
    if typ in ("bool_parsing", "bool_type"):
        return loc, f"must be true or false (got {_describe(inp)})"
    if typ in ("string_type",):
        return loc, f"must be a string (got {_describe(inp)})"
    if typ in ("list_type", "tuple_type"):
        return loc, f"must be a list (got {_describe(inp)})"
    if typ in ("dict_type", "model_type", "model_attributes_type"):
        return loc, f"must be a mapping of keys to values (got {_describe(inp)})"
    if typ == "too_short":
        return loc, "must not be empty" if ctx.get("min_length") == 1 else err["msg"]
    if typ == "union_tag_not_found" or typ == "union_tag_invalid":
        if "reference" in raw:
            return loc, ("needs kind: exact, method or none (e.g. {kind: exact, rtol: 1.0e-13})"
                         if typ == "union_tag_not_found" else
                         f"kind must be exact, method or none (got {_describe(ctx.get('tag'))})")
        return loc, err["msg"]
    if typ == "value_error":
        exc = ctx.get("error")
        if isinstance(exc, FieldError):
            return _clean_loc(raw + exc.loc), exc.msg
        msg = str(exc) if exc is not None else err["msg"]
        return loc, msg
    return loc, err["msg"]


def from_validation_error(e: ValidationError, source: str, root=None) -> ConfigError:
    """Every problem at once, on one line: unknown keys first (a typo such as `methdos:` is named, with
    the closest known key, and the "required key is missing" it causes is folded into it), then the
    rest in the order pydantic found them: `<file>: <field>: <problem>; <field>: <problem> (N problems)`."""
    errors = e.errors(include_url=False)
    items = [(err["type"], _pydantic_message(err, root)) for err in errors]  # root-level FieldError: own location
    unknown = [(loc, msg) for typ, (loc, msg) in items if typ == "extra_forbidden"]
    missing = {loc for typ, (loc, _) in items if typ == "missing"}
    folded = set()
    for loc, msg in list(unknown):
        m = re.search(r"did you mean '([^']+)'", msg)
        if m and loc[:-1] + (m.group(1),) in missing:
            folded.add(loc[:-1] + (m.group(1),))
    out = [(loc, msg.replace("?", f"? ({_hint(msg)!r} is required and missing)", 1)
            if loc[:-1] + (_hint(msg),) in folded else msg) for loc, msg in unknown]
    out += [(loc, msg) for typ, (loc, msg) in items if typ != "extra_forbidden" and not (typ == "missing" and loc in folded)]
    seen, uniq, lists = set(), [], set()
    for loc, msg in out:
        if (loc, msg) in seen:
            continue
        seen.add((loc, msg))
        m = re.search(r" \(allowed: [^)]*\)", msg)
        if m:  # several unknown keys of one mapping: its allowed keys once
            if (loc[:-1], m.group(0)) in lists:
                msg = msg.replace(m.group(0), "")
            lists.add((loc[:-1], m.group(0)))
        uniq.append((loc, msg))
    first_loc, first_msg = uniq[0]
    text = first_msg + "".join(f"; {format_loc(loc)}: {msg}" for loc, msg in uniq[1:])
    if len(uniq) > 1:
        text += f" ({len(uniq)} problems)"
    return ConfigError(text, source=source, field=format_loc(first_loc))


def _hint(msg: str) -> str:
    m = re.search(r"did you mean '([^']+)'", msg)
    return m.group(1) if m else ""
