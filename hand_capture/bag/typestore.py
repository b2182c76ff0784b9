"""Message definitions for bags: the ROS 2 Kilted type store plus hand_msgs and any
other interface package found in the ament prefixes.

Recorded bags carry the full definition of every type they hold (rosbag2 format 9), so a
workstation's ``ros2 bag play`` or any MCAP viewer can decode them without our code.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from hand_capture.errors import BagError

_REPO_MSG_DIR = Path(__file__).resolve().parents[2] / "hand_msgs" / "msg"


def _ament_prefixes() -> list[Path]:
    prefixes = [Path(p) for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    import sys

    prefixes.append(Path(sys.prefix))
    return prefixes


def find_msg_file(msgtype: str) -> Path | None:
    """Locate the ``.msg`` file of ``pkg/msg/Name`` in the ament prefixes (or this repo)."""
    try:
        pkg, kind, name = msgtype.split("/")
    except ValueError:
        return None
    if kind != "msg":
        return None
    for prefix in _ament_prefixes():
        cand = prefix / "share" / pkg / "msg" / f"{name}.msg"
        if cand.is_file():
            return cand
    if pkg == "hand_msgs" and (_REPO_MSG_DIR / f"{name}.msg").is_file():
        return _REPO_MSG_DIR / f"{name}.msg"
    return None


def _register(store: Typestore, msgtype: str, seen: set[str]) -> None:
    if msgtype in store.fielddefs or msgtype in seen:
        return
    seen.add(msgtype)
    path = find_msg_file(msgtype)
    if path is None:
        raise BagError(
            f"no message definition for {msgtype!r}: looked for share/<pkg>/msg/<Name>.msg in "
            f"{[str(p) for p in _ament_prefixes()]}"
        )
    types = get_types_from_msg(path.read_text(), msgtype)
    # Register dependencies first (nested custom types).
    for _, fields in types.values():
        for _fname, fdesc in fields:
            for dep in _nested_names(fdesc):
                _register(store, dep, seen)
    store.register(types)


def _nested_names(fdesc: object) -> list[str]:
    """Names of message types referenced by a rosbags field descriptor."""
    out: list[str] = []
    if isinstance(fdesc, tuple):
        for item in fdesc:
            if isinstance(item, str) and item.count("/") == 2:
                out.append(item)
            else:
                out.extend(_nested_names(item))
    return out


@lru_cache(maxsize=1)
def default_typestore() -> Typestore:
    """The ROS 2 Kilted type store with every hand_msgs message registered."""
    store = get_typestore(Stores.ROS2_KILTED)
    for path in sorted(_REPO_MSG_DIR.glob("*.msg")):
        ensure_type(store, f"hand_msgs/msg/{path.stem}")
    return store


def ensure_type(store: Typestore, msgtype: str) -> None:
    """Make sure ``msgtype`` (``pkg/msg/Name``) is known to ``store``, loading its .msg file.

    Raises:
        BagError: the definition cannot be found.
    """
    _register(store, msgtype, set())
