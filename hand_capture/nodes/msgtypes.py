"""Message classes by name, and conversions between type-name spellings."""

from __future__ import annotations

import importlib
from typing import Any

from hand_capture.errors import InputError


def message_class(msgtype: str) -> Any:
    """The rclpy message class of ``pkg/msg/Name`` (or ``pkg/Name``).

    Raises:
        InputError: the package or message does not exist in this environment.
    """
    parts = msgtype.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3:
        raise InputError(f"bad message type {msgtype!r}; expected 'pkg/msg/Name'")
    pkg, kind, name = parts
    try:
        module = importlib.import_module(f"{pkg}.{kind}")
        return getattr(module, name)
    except (ImportError, AttributeError) as e:
        raise InputError(f"message type {msgtype!r} is not installed: {e}") from e
