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


def named_config_names(subdir: str) -> list[str]:
    """Names (file stems) of the YAML files shipped in ``config/<subdir>/``."""
    try:
        folder = config_dir() / subdir
    except Exception:  # no source tree and no ament index: nothing is shipped
        return []
    return sorted(f.stem for f in folder.glob("*.yaml")) if folder.is_dir() else []


def resolve_named_config(name_or_path: str | Path, subdir: str, what: str) -> Path:
    """A YAML file given as a path, or as a bare name of ``config/<subdir>/NAME.yaml``.

    Args:
        name_or_path: a file path (absolute, relative to the working directory or to the share
            folder) or a bare name such as ``leap_hand`` (``.yaml`` optional).
        subdir: the folder under ``config/`` that holds the named files, e.g. ``servo_maps``.
        what: what the file is, for the error message, e.g. ``"servo map"``.

    Raises:
        ConfigError: nothing found; the message lists the names that exist.
    """
    from hand_capture.errors import ConfigError

    p = resolve_path(name_or_path)
    if p.is_file():
        return p
    name = str(name_or_path)
    names = named_config_names(subdir)
    if "/" not in name:
        stem = name.removesuffix(".yaml")
        if stem in names:
            return config_dir() / subdir / f"{stem}.yaml"
    raise ConfigError(f"{what} {name!r} not found (not a file, not a name under "
                      f"config/{subdir}/); available {what}s: {names}")
