"""Retargeting configuration: which robot hand, which of its points follow which human keypoint.

A retarget config is a YAML file per robot hand (``config/retarget/<name>.yaml``)::

    name: leap_hand
    model: ../robot_hands/leap_hand_right.urdf   # MJCF .xml or URDF .urdf, relative to this
                                                 # file; or builtin:suite_hand
    handedness: right            # the human hand it follows
    base_body: palm              # the robot body the wrist frame is fixed to
    joints: []                   # joints to optimise (default: every hinge/slide joint ...)
    fixed_joints: []             # ... except these names / patterns, held at qpos0
    wrist:                       # the human hand frame (hand_capture joints.py convention:
      pos: [-0.125, -0.051, -0.019]  # +x distal, +y thumb side, +z dorsal, origin the wrist)
      rpy: [0.0, 0.0, 0.0]       #   in base_body: position [m], roll-pitch-yaw [rad]
    points:                      # robot points that follow human keypoints (keypoints21.py)
      - {keypoint: index_tip, body: index_tip}          # or site: NAME; offset: [x, y, z]
      - {keypoint: thumb_tip, body: thumb_tip, weight: 1.0}
    solver:                      # RetargetSettings (any subset)
      mode: pinch
      scale: 1.45

Every problem of a file is listed in one :class:`ConfigError`; names of bodies, sites and
joints are checked when the robot model is loaded (:class:`~.robot.RobotHand`), and the
errors list those that exist.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hand_capture.config import from_mapping, load_yaml, param, validate
from hand_capture.model.keypoints21 import KEYPOINT21_NAMES
from hand_capture.paths import resolve_named_config
from hand_control.errors import ConfigError
from hand_control.retarget.robot import BUILTIN_SUITE_HAND

#: Retargeting modes (solver.py has the cost of each).
MODES: tuple[str, ...] = ("position", "vector", "pinch")
_TOP_KEYS = ("name", "description", "model", "handedness", "base_body", "joints",
             "fixed_joints", "wrist", "points", "solver")
_POINT_KEYS = ("keypoint", "body", "site", "offset", "weight")


@dataclass(frozen=True)
class RetargetSettings:
    """The solver's settings (the ``solver:`` block of a config; node parameters too)."""

    mode: str = param("pinch", "cost: position (robot points onto the scaled human "
                      "keypoints), vector (wrist-to-tip and tip-to-tip vectors) or pinch "
                      "(vector, closing the thumb-finger distances the operator closes)",
                      choices=MODES)
    scale: float = param(1.0, "robot size / human size: human keypoints are scaled by this "
                         "about the wrist (unitless)", lo=0.1, hi=10.0)
    filter_cutoff_hz: float = param(0.0, "low-pass cutoff on the output joints [Hz]; 0 = off",
                                    lo=0.0, hi=500.0)
    max_iterations: int = param(12, "Gauss-Newton iterations per frame at most", lo=1,
                                hi=200)
    tolerance: float = param(1e-5, "stop when the largest joint step is below this [rad]",
                             lo=1e-12, hi=1.0)
    cost_tolerance: float = param(1e-3, "stop when a step lowers the cost by less than this "
                                  "fraction (unitless)", lo=0.0, hi=1.0)
    max_step: float = param(0.3, "largest joint change of one Gauss-Newton step [rad or m]",
                            lo=1e-3, hi=10.0)
    damping: float = param(1e-3, "Levenberg-Marquardt damping of each step [m^2/rad^2]",
                           lo=0.0, hi=1.0)
    smoothness: float = param(1e-4, "weight of (q - q_previous)^2 against the squared point "
                              "errors [m^2/rad^2]: less jitter, more lag", lo=0.0, hi=1.0)
    vector_weight: float = param(1.0, "vector / pinch modes: weight of the tip-to-tip "
                                 "vectors against the wrist-to-point vectors (unitless)",
                                 lo=0.0, hi=1e3)
    pinch_close_m: float = param(0.03, "pinch mode: a human thumb-finger tip distance below "
                                 "this is a pinch; its robot distance is the human's, "
                                 "unscaled [m]", lo=0.0, hi=0.2)
    pinch_open_m: float = param(0.06, "pinch mode: above this distance the thumb-finger "
                                "vector is scaled like the others; in between, a blend [m]",
                                lo=0.001, hi=0.3)
    pinch_weight: float = param(10.0, "pinch mode: weight of a thumb-finger vector in a "
                                "pinch (unitless, blended to vector_weight at pinch_open_m)",
                                lo=0.0, hi=1e4)

    def __post_init__(self) -> None:
        validate(self)
        if self.pinch_open_m <= self.pinch_close_m:
            raise ConfigError(f"RetargetSettings.pinch_open_m = {self.pinch_open_m} must be "
                              f"above pinch_close_m = {self.pinch_close_m} [m]")


@dataclass(frozen=True)
class PointSpec:
    """A robot point (a site, or a body origin + offset) that follows a human keypoint."""

    keypoint: str
    body: str = ""
    site: str = ""
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    weight: float = 1.0


@dataclass(frozen=True)
class RetargetConfig:
    """A validated retarget config (see the module docstring for the file format)."""

    name: str
    model: str
    handedness: str
    base_body: str
    points: tuple[PointSpec, ...]
    joints: tuple[str, ...] = ()
    fixed_joints: tuple[str, ...] = ()
    wrist_pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    wrist_rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    settings: RetargetSettings = field(default_factory=RetargetSettings)
    description: str = ""
    source: str = "<dict>"

    def wrist_rotation(self) -> np.ndarray:
        """(3, 3) rotation of the human hand frame in the base body, ``Rz(y) Ry(p) Rx(r)``
        (URDF roll-pitch-yaw)."""
        r, p, y = self.wrist_rpy
        cr, sr, cp, sp, cy, sy = (math.cos(r), math.sin(r), math.cos(p), math.sin(p),
                                  math.cos(y), math.sin(y))
        return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                         [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                         [-sp, cp * sr, cp * cr]])

    def with_settings(self, **changes: Any) -> RetargetConfig:
        """A copy with some solver settings changed (validated)."""
        vals = {k: getattr(self.settings, k) for k in RetargetSettings.__dataclass_fields__}
        vals.update(changes)
        s = from_mapping(RetargetSettings, vals)
        return RetargetConfig(**{**self.__dict__, "settings": s})


def resolve_retarget_config(name_or_path: str | Path) -> Path:
    """A retarget config file from a path or a bare name such as ``leap_hand``.

    Raises:
        ConfigError: nothing found; the message lists the configs that exist.
    """
    return resolve_named_config(name_or_path, "retarget", "retarget config")


def load_retarget_config(name_or_path: str | Path) -> RetargetConfig:
    """Read and validate a retarget config (path or name under config/retarget)."""
    path = resolve_retarget_config(name_or_path)
    return retarget_config_from_dict(load_yaml(path), source=str(path), base_dir=path.parent)


def _vec3(v: Any, what: str, errors: list[str]) -> tuple[float, float, float]:
    if (not isinstance(v, (list, tuple)) or len(v) != 3
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                       and math.isfinite(x) for x in v)):
        errors.append(f"{what} must be three finite numbers, got {v!r}")
        return (0.0, 0.0, 0.0)
    return (float(v[0]), float(v[1]), float(v[2]))


def _names_list(v: Any, what: str, errors: list[str]) -> tuple[str, ...]:
    if v is None:
        return ()
    if not isinstance(v, (list, tuple)) or not all(isinstance(x, str) and x for x in v):
        errors.append(f"{what} must be a list of names, got {v!r}")
        return ()
    return tuple(v)


def retarget_config_from_dict(data: Any, source: str = "<dict>",
                              base_dir: str | Path | None = None) -> RetargetConfig:
    """Validate a retarget config given as a mapping (the parsed YAML).

    Args:
        base_dir: folder that a relative ``model`` path is relative to (the file's folder).

    Raises:
        ConfigError: listing every problem found.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"retarget config {source}: expected a mapping at the top level, "
                          f"got {type(data).__name__}")
    errors: list[str] = []
    unknown = sorted(set(data) - set(_TOP_KEYS))
    if unknown:
        errors.append(f"unknown key(s) {unknown}; valid keys: {list(_TOP_KEYS)}")
    model = data.get("model")
    if not isinstance(model, str) or not model:
        errors.append(f"model must name an MJCF / URDF file or {BUILTIN_SUITE_HAND!r}")
        model = ""
    elif model != BUILTIN_SUITE_HAND and not Path(model).expanduser().is_absolute() \
            and base_dir is not None:
        model = str((Path(base_dir) / model).resolve())
    hand = data.get("handedness", "right")
    if hand not in ("right", "left"):
        errors.append(f"handedness {hand!r} is not one of ['right', 'left']")
    base = data.get("base_body")
    if not isinstance(base, str) or not base:
        errors.append("base_body must name the robot body the wrist frame is fixed to")
        base = ""
    joints = _names_list(data.get("joints"), "joints", errors)
    fixed = _names_list(data.get("fixed_joints"), "fixed_joints", errors)
    wrist = data.get("wrist") or {}
    if not isinstance(wrist, Mapping) or set(wrist) - {"pos", "rpy"}:
        errors.append(f"wrist must be a mapping with pos [m] and rpy [rad], got {wrist!r}")
        wrist = {}
    wpos = _vec3(wrist.get("pos", [0, 0, 0]), "wrist.pos", errors)
    wrpy = _vec3(wrist.get("rpy", [0, 0, 0]), "wrist.rpy", errors)
    points: list[PointSpec] = []
    raw_points = data.get("points")
    if not isinstance(raw_points, list) or not raw_points:
        errors.append("points must be a non-empty list of {keypoint, body|site}")
        raw_points = []
    seen: set[str] = set()
    for i, p in enumerate(raw_points):
        label = f"points[{i}]"
        if not isinstance(p, Mapping):
            errors.append(f"{label} must be a mapping, got {p!r}")
            continue
        bad = sorted(set(p) - set(_POINT_KEYS))
        if bad:
            errors.append(f"{label}: unknown key(s) {bad}; valid keys: {list(_POINT_KEYS)}")
        kp = p.get("keypoint")
        if kp not in KEYPOINT21_NAMES:
            errors.append(f"{label}: keypoint {kp!r} is not one of {list(KEYPOINT21_NAMES)}")
        elif kp in seen:
            errors.append(f"{label}: keypoint {kp!r} is used twice")
        seen.add(str(kp))
        body, site = p.get("body", ""), p.get("site", "")
        if not isinstance(body, str) or not isinstance(site, str) or bool(body) == bool(site):
            errors.append(f"{label}: give exactly one of body or site (a name)")
        w = p.get("weight", 1.0)
        if not isinstance(w, (int, float)) or isinstance(w, bool) or not 0.0 <= w <= 1e3:
            errors.append(f"{label}: weight must be a number in [0, 1000], got {w!r}")
            w = 1.0
        off = _vec3(p.get("offset", [0, 0, 0]), f"{label}.offset", errors)
        points.append(PointSpec(str(kp), str(body or ""), str(site or ""), off, float(w)))
    settings = RetargetSettings()
    solver = data.get("solver") or {}
    if not isinstance(solver, Mapping):
        errors.append("solver must be a mapping of RetargetSettings keys")
    else:
        try:
            settings = from_mapping(RetargetSettings, solver)
        except ConfigError as e:
            errors.append(str(e))
    if errors:
        raise ConfigError(f"retarget config {source}: " + "; ".join(errors))
    return RetargetConfig(name=str(data.get("name", Path(source).stem)), model=model,
                          handedness=hand, base_body=base, points=tuple(points),
                          joints=joints, fixed_joints=fixed, wrist_pos=wpos, wrist_rpy=wrpy,
                          settings=settings, description=str(data.get("description", "")),
                          source=source)
