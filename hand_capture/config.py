"""Validated, frozen configuration dataclasses.

Every core object of the suite is built from a frozen dataclass whose fields are declared with
:func:`param`. The same metadata (description, range, choices) is used to

* validate the values on construction (:func:`validate`, called from ``__post_init__``),
* fill the dataclass from a YAML mapping (:func:`from_mapping`, :func:`load_node_params`),
* declare ROS parameters with descriptors (``hand_capture.nodes.params``).

Example::

    @dataclass(frozen=True)
    class TrackerConfig:
        data_weight: float = param(1.0, "weight of the data term (eq. II.21)", lo=0.0)

        def __post_init__(self) -> None:
            validate(self)
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

from hand_capture.errors import ConfigError

T = TypeVar("T")

_SCALARS = (bool, int, float, str)


def param(
    default: Any,
    description: str,
    *,
    lo: float | None = None,
    hi: float | None = None,
    choices: Sequence[Any] | None = None,
    read_only: bool = False,
) -> Any:
    """Declare a configuration field with its documentation and valid range.

    Args:
        default: default value; lists/tuples are stored as tuples (the dataclass is frozen).
        description: one line with the unit, e.g. ``"control period [s]"``.
        lo, hi: inclusive bounds for numbers (or for every element of a numeric sequence).
        choices: the valid values for a string or number.
        read_only: the ROS parameter cannot be changed after start-up.
    """
    meta = {
        "description": description,
        "lo": lo,
        "hi": hi,
        "choices": tuple(choices) if choices is not None else None,
        "read_only": read_only,
    }
    if isinstance(default, list):
        default = tuple(default)
    return dataclasses.field(default=default, metadata=meta)


def field_meta(f: dataclasses.Field) -> dict[str, Any]:
    """Metadata of a field declared with :func:`param` (empty defaults otherwise)."""
    meta = {"description": "", "lo": None, "hi": None, "choices": None, "read_only": False}
    meta.update(dict(f.metadata))
    return meta


def _base_type(tp: Any) -> Any:
    """Strip ``X | None`` and return the origin of generics (``tuple[float, ...]`` -> tuple)."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return _base_type(args[0]) if len(args) == 1 else tp
    return origin or tp


def _check_number(name: str, value: float, meta: Mapping[str, Any]) -> None:
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"{name} must be finite, got {value}")
    lo, hi = meta["lo"], meta["hi"]
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        lo_s = "-inf" if lo is None else lo
        hi_s = "inf" if hi is None else hi
        raise ConfigError(f"{name} = {value} is out of range [{lo_s}, {hi_s}]")


def validate(cfg: Any) -> None:
    """Check every field of a config dataclass against its type, range and choices.

    Raises:
        ConfigError: naming the field, the value and the valid range or choices.
    """
    hints = typing.get_type_hints(type(cfg))
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        meta = field_meta(f)
        name = f"{type(cfg).__name__}.{f.name}"
        tp = _base_type(hints.get(f.name, Any))
        if value is None:
            continue
        if tp is float and isinstance(value, int) and not isinstance(value, bool):
            object.__setattr__(cfg, f.name, float(value))
            value = float(value)
        if tp in _SCALARS and not isinstance(value, tp):
            raise ConfigError(f"{name} must be {tp.__name__}, got {value!r}")
        if tp is tuple and isinstance(value, list):
            value = tuple(value)
            object.__setattr__(cfg, f.name, value)
        if meta["choices"] is not None and value not in meta["choices"]:
            raise ConfigError(f"{name} = {value!r} is not one of {list(meta['choices'])}")
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            _check_number(name, value, meta)
        elif isinstance(value, tuple):
            for i, v in enumerate(value):
                if isinstance(v, (int, float)) and not isinstance(v, bool):
                    _check_number(f"{name}[{i}]", v, meta)


def from_mapping(cls: type[T], values: Mapping[str, Any]) -> T:
    """Build a config dataclass from a mapping, refusing unknown keys.

    Raises:
        ConfigError: for an unknown key (the message lists the valid keys) or a bad value.
    """
    names = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise ConfigError(f"unknown {cls.__name__} key(s) {unknown}; valid keys: {names}")
    kwargs = {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}
    try:
        return cls(**kwargs)
    except TypeError as e:
        raise ConfigError(f"cannot build {cls.__name__}: {e}") from e


def from_overrides(cls: type[T], items: Sequence[str]) -> T:
    """Build a config dataclass from ``KEY=VALUE`` strings (command-line overrides).

    Each value is read as YAML (``true``, ``0.5``, ``[1, 2]``); unset keys keep their defaults.

    Raises:
        ConfigError: an item without ``=``, an unknown key (the message lists the valid
            keys) or a bad value.
    """
    import yaml

    values: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"bad override {item!r}; expected KEY=VALUE")
        try:
            values[key] = yaml.safe_load(text)
        except yaml.YAMLError as e:
            raise ConfigError(f"override {item!r}: {text!r} is not a value: {e}") from e
    return from_mapping(cls, values)


def load_yaml(path: str | Path) -> Any:
    """Read a YAML file; a missing or malformed file raises :class:`ConfigError`."""
    import yaml

    p = Path(path)
    try:
        with p.open() as fh:
            return yaml.safe_load(fh)
    except FileNotFoundError as e:
        raise ConfigError(f"file not found: {p}") from e
    except yaml.YAMLError as e:
        raise ConfigError(f"{p} is not valid YAML: {e}") from e


def load_node_params(cls: type[T], path: str | Path, node_name: str) -> T:
    """Fill a config dataclass from a ROS parameter file (``node: {ros__parameters: ...}``).

    Keys absent from the file keep their defaults; ``/**`` entries apply to every node.
    """
    data = load_yaml(path) or {}
    merged: dict[str, Any] = {}
    for key in ("/**", node_name, f"/{node_name}"):
        section = data.get(key) or {}
        merged.update(section.get("ros__parameters", {}) or {})
    own = {f.name for f in dataclasses.fields(cls)}
    return from_mapping(cls, {k: v for k, v in merged.items() if k in own})
