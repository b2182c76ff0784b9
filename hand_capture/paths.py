"""Where the suite's data files live: the source tree, or the ament share folder."""

from __future__ import annotations

from pathlib import Path

PACKAGE = "hand_suite"
_SOURCE_ROOT = Path(__file__).resolve().parents[1]


def share_dir() -> Path:
    """The folder holding ``config/`` and ``launch/``.

    The source checkout when running from it (editable install, tests), else the installed
    ament share folder ``share/hand_suite`` (colcon install on a ROS 2 workstation).
    """
    if (_SOURCE_ROOT / "config").is_dir() and (_SOURCE_ROOT / "launch").is_dir():
        return _SOURCE_ROOT
    from ament_index_python.packages import get_package_share_directory

    return Path(get_package_share_directory(PACKAGE))


def config_dir() -> Path:
    """``config/``: parameter files, graph descriptions, servo maps."""
    return share_dir() / "config"


def data_dir() -> Path:
    """``data/``: shipped models (touch encodings, tracker forest) and the sample capture."""
    return share_dir() / "data"


def resolve_path(path: str | Path) -> Path:
    """``path`` as given, or, when it is relative and missing from the working directory, the
    same path under :func:`share_dir` (so ``data/sample_capture`` names the shipped file from
    anywhere)."""
    p = Path(path).expanduser()
    if not p.is_absolute() and not p.exists() and (share_dir() / p).exists():
        return share_dir() / p
    return p
