"""The errors of the config layer: `ConfigError` (what a user sees: one line naming the file and the
field) and `FieldError` (raised inside the schema's validators to point at a sub-field)."""
from __future__ import annotations

__all__ = ["ConfigError", "FieldError"]


class ConfigError(ValueError):
    """An invalid sweep configuration; `str(err)` is one line naming the file and the field."""

    def __init__(self, message: str, *, source: str | None = None, field: str | None = None):
        self.source = source
        self.field = field
        text = message if field is None else f"{field}: {message}"
        text = text if source is None else f"{source}: {text}"
        super().__init__(" ".join(text.split()))  # guaranteed single line



class FieldError(ValueError):
    """Raised inside model validators to point at a sub-field (pydantic would report the model)."""

    def __init__(self, loc: tuple, msg: str):
        self.loc = loc
        self.msg = msg
        super().__init__(msg)
