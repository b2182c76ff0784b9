"""Declare ROS parameters from a config dataclass and build the validated config from them.

One helper for every node of the suite: each field declared with
:func:`hand_capture.config.param` becomes a ROS parameter whose descriptor carries the field's
description, range and read-only flag. The values are read back, the dataclass is built and
validated; a bad value raises :class:`~hand_capture.errors.ConfigError` naming the parameter.
"""

from __future__ import annotations

import dataclasses
import typing
from typing import Any, TypeVar

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
)
from rclpy.exceptions import ParameterUninitializedException
from rclpy.node import Node
from rclpy.parameter import Parameter

from hand_capture.config import _base_type, field_meta, from_mapping

T = TypeVar("T")

_TYPES = {
    bool: ParameterType.PARAMETER_BOOL,
    int: ParameterType.PARAMETER_INTEGER,
    float: ParameterType.PARAMETER_DOUBLE,
    str: ParameterType.PARAMETER_STRING,
}
_ARRAY_TYPES = {
    bool: ParameterType.PARAMETER_BOOL_ARRAY,
    int: ParameterType.PARAMETER_INTEGER_ARRAY,
    float: ParameterType.PARAMETER_DOUBLE_ARRAY,
    str: ParameterType.PARAMETER_STRING_ARRAY,
}


def _param_type(tp: Any) -> int:
    base = _base_type(tp)
    if base in _TYPES:
        return _TYPES[base]
    if base in (tuple, list):
        args = [a for a in typing.get_args(tp) if a is not Ellipsis]
        elem = args[0] if args else float
        return _ARRAY_TYPES.get(elem, ParameterType.PARAMETER_DOUBLE_ARRAY)
    raise TypeError(f"unsupported config field type {tp!r}")


def descriptor_for(f: dataclasses.Field, tp: Any) -> ParameterDescriptor:
    """The ParameterDescriptor of one config field (description, range, read-only)."""
    meta = field_meta(f)
    ptype = _param_type(tp)
    desc = ParameterDescriptor(
        name=f.name,
        type=ptype,
        description=meta["description"],
        read_only=bool(meta["read_only"]),
    )
    if meta["choices"] is not None:
        desc.additional_constraints = f"one of {list(meta['choices'])}"
    lo, hi = meta["lo"], meta["hi"]
    if ptype == ParameterType.PARAMETER_DOUBLE and (lo is not None or hi is not None):
        desc.floating_point_range = [
            FloatingPointRange(
                from_value=float(lo if lo is not None else -1e300),
                to_value=float(hi if hi is not None else 1e300),
                step=0.0,
            )
        ]
    elif ptype == ParameterType.PARAMETER_INTEGER and (lo is not None or hi is not None):
        desc.integer_range = [
            IntegerRange(
                from_value=int(lo if lo is not None else -(2**62)),
                to_value=int(hi if hi is not None else 2**62),
                step=0,
            )
        ]
    return desc


def declare_config(node: Node, cls: type[T], prefix: str = "") -> T:
    """Declare one ROS parameter per field of ``cls`` and return the validated config.

    Args:
        node: the node that owns the parameters.
        cls: a frozen config dataclass whose fields use :func:`hand_capture.config.param`.
        prefix: optional parameter namespace, e.g. ``"qp."``.

    Raises:
        ConfigError: a parameter value is invalid; the message names it and its valid range.
    """
    hints = typing.get_type_hints(cls)
    values: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        default = f.default
        if isinstance(default, tuple):
            default = list(default)
        name = prefix + f.name
        if default is None or default == []:
            # No default, or an empty array (whose element type rclpy cannot infer): declare
            # by type only and keep the dataclass default when nothing was given.
            desc = descriptor_for(f, tp)
            node.declare_parameter(name, Parameter.Type(desc.type), desc)
            try:
                values[f.name] = node.get_parameter(name).value
            except ParameterUninitializedException:
                pass
            continue
        node.declare_parameter(name, default, descriptor_for(f, tp))
        values[f.name] = node.get_parameter(name).value
    return from_mapping(cls, values)
