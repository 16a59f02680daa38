"""Reading a sweep config: the file (size, encoding, YAML) and its validation, every failure a
one-line `ConfigError`."""
from __future__ import annotations

from pathlib import Path

import yaml
from pydantic import ValidationError

from ...core.yaml_loader import yaml_error_line, yaml_load
from .errors import ConfigError
from .messages import from_validation_error
from .schema import STUDY_KEY, SweepConfig
from .semantics import check_semantics_of
from .specs import FileSystem

__all__ = ["MAX_CONFIG_BYTES", "parse_config", "read_config_data", "load_config", "config_text"]

MAX_CONFIG_BYTES = 4_000_000  # a config file is a few kB


def parse_config(data, *, source: str = "<config>", base_dir: Path | None = None,
                 check_semantics: bool = True) -> SweepConfig:
    """Validate a config mapping. With `check_semantics`, also build the system (unknown built-in
    names, parameter names, malformed expressions), resolve the methods (unsupported combinations)
    and map every initial condition (beta without a map, wrong lengths, non-hyperregular M)."""
    if data is None:
        raise ConfigError("empty config; expected a mapping with keys name, system, methods, h, T, ...", source=source)
    if not isinstance(data, dict):
        raise ConfigError(f"the top level must be a mapping of keys to values (got {type(data).__name__})",
                          source=source)
    for k in data:
        if not isinstance(k, str):
            raise ConfigError(f"keys must be strings (got {k!r})", source=source)
    if STUDY_KEY in data:
        raise ConfigError(f"a study config (top-level key {STUDY_KEY}: {data[STUDY_KEY]}), not a sweep config; run it "
                          "with `vcirun study FILE`", source=source, field=STUDY_KEY)
    data = dict(data)
    if "name" not in data and source not in ("<config>", "<string>"):
        data["name"] = Path(source).stem
    try:
        cfg = SweepConfig.model_validate(data)
    except ValidationError as e:
        raise from_validation_error(e, source) from None
    if isinstance(cfg.system, FileSystem) and base_dir is not None and not Path(cfg.system.file).is_absolute():
        cfg = cfg.model_copy(update={"system": FileSystem(file=str((base_dir / cfg.system.file)), params=cfg.system.params)})
    if check_semantics:
        check_semantics_of(cfg, source=source)
    return cfg


def read_config_data(path):
    """The parsed YAML of a config file (sweep or study); every failure is a one-line `ConfigError`."""
    source = str(path)
    p = Path(path)
    if not p.exists():
        raise ConfigError("file not found", source=source)
    if p.is_dir():
        raise ConfigError("is a directory, expected a YAML file", source=source)
    try:
        st = p.stat()
    except OSError as e:
        raise ConfigError(f"cannot read: {e}", source=source) from None
    if not p.is_file():  # a FIFO or a device would block or never end
        raise ConfigError("not a regular file, expected a YAML file", source=source)
    if st.st_size > MAX_CONFIG_BYTES:
        raise ConfigError(f"the file is {st.st_size:,} bytes; a config is a few kB (limit {MAX_CONFIG_BYTES:,})",
                          source=source)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"cannot read: {e}", source=source) from None
    try:
        data = yaml_load(text)
    except yaml.YAMLError as e:
        raise ConfigError(yaml_error_line(e), source=source) from None
    return data


def load_config(path, *, check_semantics: bool = True) -> SweepConfig:
    """Read and validate a YAML sweep config; every failure is a one-line `ConfigError`."""
    data = read_config_data(path)
    return parse_config(data, source=str(path), base_dir=Path(path).parent, check_semantics=check_semantics)


def config_text(path) -> str:
    return Path(path).read_text(encoding="utf-8")
