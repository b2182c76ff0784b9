"""Servo maps: which DYNAMIXEL follows which hand-model joints, and within which limits.

A servo map is a YAML file per robot hand (``config/servo_maps/<name>.yaml``)::

    name: leap_hand
    handedness: right            # right | left | any: which HandPose messages are followed
    operating_mode: current_based_position   # or position
    defaults:                    # optional, applied to every servo (servo keys override)
      model: XC330-M288
      current_limit_ma: 550
    servos:
      - id: 1
        name: index_mcp_flex
        joints: {index_mcp_flex: 1.0}     # weighted sum of hand-model joints [rad]
        scale: 1.0
        offset: 0.0                        # servo angle at zero joint angles [rad]
        direction: 1                       # +1 or -1
        min_position: 1800                 # [tick], within the model's 0..4095
        max_position: 3500

Servo angle (rad, 0 at the centre tick 2048) = offset + direction * scale * sum_j w_j * q_j,
goal tick = 2048 + angle * 4096 / (2 pi). Joint names are those of
``hand_capture.model.joints.ARTICULATED_JOINTS`` (``joint_vocabulary: hand_model``, the default),
or, with ``joint_vocabulary: robot``, the joint names of a robot hand model (the retargeting
node's ``robot/joint_command``; any names, typically one servo per robot joint with weight 1).
Maps are validated on load; every problem found
is listed in one :class:`ConfigError` (unknown joint names list the valid ones, duplicate IDs name
both servos, limits outside the model's range name the range, ...).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hand_capture.config import load_yaml
from hand_capture.model.joints import ARTICULATED_JOINTS
from hand_capture.paths import resolve_named_config
from hand_control.dynamixel.control_table import (
    MODELS,
    OPERATING_MODES,
    VELOCITY_UNIT_RAD_S,
    ModelSpec,
)
from hand_control.errors import ConfigError

#: Joint vocabularies of a map: the hand model's articulated joints, or a robot model's joints.
JOINT_VOCABULARIES = ("hand_model", "robot")
#: Operating modes a servo map may ask for (the bridge commands positions).
MAP_OPERATING_MODES = ("position", "current_based_position")
HANDEDNESS = ("right", "left", "any")

_SERVO_KEYS = (
    "id", "name", "model", "joints", "scale", "offset", "direction", "min_position",
    "max_position", "current_limit_ma", "goal_current_ma", "profile_velocity_rad_s",
    "max_velocity_rad_s",
)
_TOP_KEYS = ("name", "description", "handedness", "operating_mode", "joint_vocabulary",
             "defaults", "servos")
_DEFAULT_MAX_VELOCITY = 6.0  # rad/s, software rate limit when a map gives none


@dataclass(frozen=True)
class ServoSpec:
    """One servo of a map, validated. Angles in rad, positions in ticks, currents in mA."""

    id: int
    name: str
    model: ModelSpec
    joints: tuple[tuple[str, float], ...]
    scale: float
    offset: float
    direction: int
    min_position: int
    max_position: int
    current_limit_ma: float
    goal_current_ma: float
    profile_velocity_rad_s: float
    max_velocity_rad_s: float

    @property
    def current_limit_raw(self) -> int:
        return int(round(self.current_limit_ma / self.model.current_unit_ma))

    @property
    def goal_current_raw(self) -> int:
        return int(round(self.goal_current_ma / self.model.current_unit_ma))

    @property
    def profile_velocity_raw(self) -> int:
        return int(round(self.profile_velocity_rad_s / VELOCITY_UNIT_RAD_S))


@dataclass(frozen=True)
class ServoMap:
    """A validated servo map (see the module docstring for the file format)."""

    name: str
    description: str
    handedness: str
    operating_mode: str
    servos: tuple[ServoSpec, ...]
    source: str = "<dict>"
    joint_vocabulary: str = "hand_model"

    @property
    def ids(self) -> tuple[int, ...]:
        return tuple(s.id for s in self.servos)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.servos)

    @property
    def operating_mode_value(self) -> int:
        return OPERATING_MODES[self.operating_mode]

    def by_id(self, dxl_id: int) -> ServoSpec:
        for s in self.servos:
            if s.id == dxl_id:
                return s
        raise KeyError(f"servo ID {dxl_id} is not in servo map {self.name!r}")

    def joints_used(self) -> tuple[str, ...]:
        seen: dict[str, None] = {}
        for s in self.servos:
            for j, _ in s.joints:
                seen.setdefault(j, None)
        return tuple(seen)


def resolve_servo_map(name_or_path: str | Path) -> Path:
    """A servo map file from a path or a bare name such as ``leap_hand``.

    Raises:
        ConfigError: nothing found; the message lists the maps that exist.
    """
    return resolve_named_config(name_or_path, "servo_maps", "servo map")


def load_servo_map(name_or_path: str | Path) -> ServoMap:
    """Read and validate a servo map YAML file (path or name under config/servo_maps)."""
    path = resolve_servo_map(name_or_path)
    data = load_yaml(path)
    return servo_map_from_dict(data, source=str(path))


def _finite(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def servo_map_from_dict(data: Any, source: str = "<dict>") -> ServoMap:
    """Validate a servo map given as a mapping (the parsed YAML).

    Raises:
        ConfigError: listing every problem found, each naming the servo and the valid values.
    """
    errors: list[str] = []
    if not isinstance(data, Mapping):
        raise ConfigError(f"servo map {source}: expected a mapping at the top level, "
                          f"got {type(data).__name__}")
    unknown = sorted(set(data) - set(_TOP_KEYS))
    if unknown:
        errors.append(f"unknown top-level key(s) {unknown}; valid keys: {list(_TOP_KEYS)}")
    name = str(data.get("name", Path(source).stem))
    handedness = data.get("handedness", "any")
    if handedness not in HANDEDNESS:
        errors.append(f"handedness {handedness!r} is not one of {list(HANDEDNESS)}")
    vocab = data.get("joint_vocabulary", "hand_model")
    if vocab not in JOINT_VOCABULARIES:
        errors.append(f"joint_vocabulary {vocab!r} is not one of {list(JOINT_VOCABULARIES)}")
        vocab = "hand_model"
    mode = data.get("operating_mode", "position")
    if mode not in MAP_OPERATING_MODES:
        errors.append(f"operating_mode {mode!r} is not one of {list(MAP_OPERATING_MODES)}")
    defaults = data.get("defaults") or {}
    if not isinstance(defaults, Mapping):
        errors.append("defaults must be a mapping of servo keys")
        defaults = {}
    bad_defaults = sorted(set(defaults) - (set(_SERVO_KEYS) - {"id", "name"}))
    if bad_defaults:
        errors.append(f"defaults: unknown key(s) {bad_defaults}; valid keys: "
                      f"{[k for k in _SERVO_KEYS if k not in ('id', 'name')]}")
    raw_servos = data.get("servos")
    if not isinstance(raw_servos, list) or not raw_servos:
        errors.append("servos must be a non-empty list")
        raw_servos = []

    servos: list[ServoSpec] = []
    for i, raw in enumerate(raw_servos):
        if not isinstance(raw, Mapping):
            errors.append(f"servos[{i}] must be a mapping, got {raw!r}")
            continue
        entry = {**defaults, **raw}
        spec = _servo_from_entry(i, entry, errors, vocab == "hand_model")
        if spec is not None:
            servos.append(spec)

    ids: dict[int, str] = {}
    names: set[str] = set()
    for s in servos:
        if s.id in ids:
            errors.append(f"duplicate servo ID {s.id}: used by {ids[s.id]!r} and {s.name!r}")
        else:
            ids[s.id] = s.name
        if s.name in names:
            errors.append(f"duplicate servo name {s.name!r}")
        names.add(s.name)

    if errors:
        raise ConfigError(f"servo map {source}: " + "; ".join(errors))
    return ServoMap(name=name, description=str(data.get("description", "")),
                    handedness=handedness, operating_mode=mode, servos=tuple(servos),
                    source=source, joint_vocabulary=vocab)


def _servo_from_entry(i: int, e: Mapping[str, Any], errors: list[str],
                      hand_model: bool = True) -> ServoSpec | None:
    n0 = len(errors)
    label = f"servos[{i}]"
    unknown = sorted(set(e) - set(_SERVO_KEYS))
    if unknown:
        errors.append(f"{label}: unknown key(s) {unknown}; valid keys: {list(_SERVO_KEYS)}")
    dxl_id = e.get("id")
    if not isinstance(dxl_id, int) or isinstance(dxl_id, bool) or not 0 <= dxl_id <= 252:
        errors.append(f"{label}: id must be an integer in 0..252, got {dxl_id!r}")
        dxl_id = -1
    name = str(e.get("name", f"servo_{dxl_id}"))
    label = f"servo {name!r} (id {dxl_id})"

    model_name = e.get("model")
    model = MODELS.get(str(model_name)) if model_name is not None else None
    if model is None:
        errors.append(f"{label}: model {model_name!r} is not known; known models: "
                      f"{sorted(MODELS)}")

    joints_raw = e.get("joints")
    joints: list[tuple[str, float]] = []
    if isinstance(joints_raw, str):
        joints_raw = {joints_raw: 1.0}
    if not isinstance(joints_raw, Mapping) or not joints_raw:
        errors.append(f"{label}: joints must be a non-empty mapping joint_name: weight")
    else:
        known = ARTICULATED_JOINTS if hand_model else tuple(
            j for j in joints_raw if isinstance(j, str) and j)
        bad = [j for j in joints_raw if j not in known]
        if bad:
            errors.append(f"{label}: unknown joint name(s) {bad}; valid joints: "
                          + (f"{list(ARTICULATED_JOINTS)}" if hand_model else
                             "non-empty names (joint_vocabulary: robot)"))
        for j, w in joints_raw.items():
            if not _finite(w):
                errors.append(f"{label}: weight of joint {j!r} must be a finite number, "
                              f"got {w!r}")
            elif j in known:
                joints.append((str(j), float(w)))

    scale = e.get("scale", 1.0)
    if not _finite(scale) or scale == 0:
        errors.append(f"{label}: scale must be a finite non-zero number, got {scale!r}")
    offset = e.get("offset", 0.0)
    if not _finite(offset) or abs(offset) > 2 * math.pi:
        errors.append(f"{label}: offset must be a number of radians in [-2 pi, 2 pi], "
                      f"got {offset!r}")
    direction = e.get("direction", 1)
    if direction not in (1, -1) or isinstance(direction, bool):
        errors.append(f"{label}: direction must be 1 or -1, got {direction!r}")

    lo_m = model.min_position if model else 0
    hi_m = model.max_position if model else 4095
    lo = e.get("min_position", lo_m)
    hi = e.get("max_position", hi_m)
    for key, v in (("min_position", lo), ("max_position", hi)):
        if not isinstance(v, int) or isinstance(v, bool) or not lo_m <= v <= hi_m:
            errors.append(f"{label}: {key} = {v!r} is outside the model's position range "
                          f"{lo_m}..{hi_m} [tick]")
    if isinstance(lo, int) and isinstance(hi, int) and lo >= hi:
        errors.append(f"{label}: min_position {lo} must be below max_position {hi}")

    max_ma = model.max_current_ma if model else math.inf
    cur = e.get("current_limit_ma", max_ma if model else None)
    if not _finite(cur) or not 0 < cur <= max_ma:
        errors.append(f"{label}: current_limit_ma = {cur!r} is outside (0, {max_ma:g}] mA, "
                      f"the Current Limit range of {model_name}")
    goal_cur = e.get("goal_current_ma", cur)
    if not _finite(goal_cur) or (_finite(cur) and not 0 < goal_cur <= cur):
        errors.append(f"{label}: goal_current_ma = {goal_cur!r} must be in (0, "
                      f"current_limit_ma = {cur!r}]")
    prof = e.get("profile_velocity_rad_s", 0.0)
    if not _finite(prof) or prof < 0 or prof / VELOCITY_UNIT_RAD_S > 32767:
        errors.append(f"{label}: profile_velocity_rad_s must be in [0, "
                      f"{32767 * VELOCITY_UNIT_RAD_S:.1f}] (0 = no profile), got {prof!r}")
    vmax = e.get("max_velocity_rad_s", _DEFAULT_MAX_VELOCITY)
    if not _finite(vmax) or vmax <= 0:
        errors.append(f"{label}: max_velocity_rad_s must be a positive number, got {vmax!r}")

    if len(errors) > n0 or model is None:
        return None
    return ServoSpec(
        id=dxl_id, name=name, model=model, joints=tuple(joints), scale=float(scale),
        offset=float(offset), direction=int(direction), min_position=int(lo),
        max_position=int(hi), current_limit_ma=float(cur), goal_current_ma=float(goal_cur),
        profile_velocity_rad_s=float(prof), max_velocity_rad_s=float(vmax),
    )
