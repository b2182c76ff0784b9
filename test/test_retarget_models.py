"""The robot hand models shipped for retargeting: the LEAP Hand's conventions (servo IDs,
flat hand at 2048, 4096 counts per turn, current-based position mode, current limits), its
one-servo-per-joint map, and the servo bridge following robot/joint_command with it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hand_control.dynamixel import control_table as ct
from hand_control.dynamixel.bridge import BridgeConfig, ServoBridge
from hand_control.dynamixel.retarget import Retargeter, angles_to_ticks
from hand_control.dynamixel.servo_map import load_servo_map, servo_map_from_dict
from hand_control.errors import ConfigError
from hand_control.retarget import HandRetargeter

LEAP_ORDER = [f"{f}_{j}" for f in ("index", "middle", "ring")
              for j in ("mcp_side", "mcp_forward", "pip", "dip")] + [
    "thumb_cmc_side", "thumb_cmc_forward", "thumb_mcp", "thumb_ip"]


@pytest.fixture(scope="module")
def leap() -> HandRetargeter:
    return HandRetargeter("leap_hand")


def test_leap_servo_ids_follow_the_published_order() -> None:
    m = load_servo_map("leap_hand_joints")
    assert m.ids == tuple(range(16))
    assert list(m.names) == LEAP_ORDER  # index, middle, ring, thumb; side, forward, PIP, DIP
    assert m.joint_vocabulary == "robot" and m.operating_mode == "current_based_position"
    for s in m.servos:
        assert s.joints == ((s.name, 1.0),) and s.offset == 0.0 and s.direction == 1
        assert s.model.name == "XC330-M288" and s.current_limit_ma == 550.0
        assert s.current_limit_ma <= s.model.max_current_ma


def test_leap_model_and_map_agree_on_joints_limits_and_the_flat_hand(leap) -> None:
    m = load_servo_map("leap_hand_joints")
    assert set(leap.joint_names) == set(m.names)
    assert math.isclose(ct.TICKS_PER_RAD * 2 * math.pi, 4096.0)  # counts per turn
    rt = Retargeter(m)
    zero = rt.from_named(leap.joint_names, [0.0] * 16)
    assert np.all(angles_to_ticks(zero) == 2048.0)  # the flat hand is 2048 (pi rad in LEAP)
    for s in m.servos:  # servo limits = the model's joint limits, in ticks
        k = leap.joint_names.index(s.name)
        assert abs(angles_to_ticks(leap.lower[k]) - s.min_position) <= 1.0
        assert abs(angles_to_ticks(leap.upper[k]) - s.max_position) <= 1.0


def test_leap_model_frame_and_flexion_sign(leap) -> None:
    robot = leap.robot
    names = [p.keypoint for p in leap.config.points]
    tips = [names.index(f"{f}_tip") for f in ("index", "middle", "ring")]
    flat = robot.forward(np.zeros(16), leap.points)
    # fingers point along +x, the thumb is on +y, index on the thumb side of the ring finger
    assert np.all(flat[tips, 0] > 0.12) and flat[names.index("thumb_tip"), 1] > 0.1
    assert flat[tips[0], 1] > flat[tips[1], 1] > flat[tips[2], 1]
    # positive flexion (MCP forward, PIP, DIP) moves a fingertip towards the palm (-z)
    for j in ("index_mcp_forward", "index_pip", "index_dip"):
        q = np.zeros(16)
        q[leap.joint_names.index(j)] = 0.5
        assert robot.forward(q, leap.points)[tips[0], 2] < flat[tips[0], 2] - 0.005, j


def test_robot_map_refuses_nothing_but_empty_names_and_keeps_hand_maps_strict() -> None:
    base = {"name": "x", "joint_vocabulary": "robot",
            "servos": [{"id": 1, "model": "XC330-M288", "joints": {"joint_a": 1.0}}]}
    assert servo_map_from_dict(base).joints_used() == ("joint_a",)
    with pytest.raises(ConfigError, match="joint_vocabulary"):
        servo_map_from_dict({**base, "joint_vocabulary": "robots"})
    with pytest.raises(ConfigError, match="unknown joint name"):
        servo_map_from_dict({**base, "joint_vocabulary": "hand_model"})


def test_bridge_source_and_map_vocabulary_must_match() -> None:
    with pytest.raises(ConfigError, match="joint_vocabulary"):
        ServoBridge(BridgeConfig(servo_map="leap_hand_joints", source="tracked"))
    with pytest.raises(ConfigError, match="joint_vocabulary"):
        ServoBridge(BridgeConfig(servo_map="leap_hand", source="robot"))


def test_bridge_follows_retargeted_robot_joints_on_the_emulated_bus(leap) -> None:
    class Clock:
        t = 100.0

        def __call__(self) -> float:
            return self.t

    clock = Clock()
    b = ServoBridge(BridgeConfig(servo_map="leap_hand_joints", source="robot",
                                 packet_timeout_ms=500.0), clock=clock)
    from hand_capture.cameras.motion import builtin_clip
    from hand_capture.model.keypoints21 import keypoints21

    rt = HandRetargeter(leap.config, leap.robot)
    q = rt.solve(keypoints21(None, builtin_clip("pinch").sample(1.8))).q
    try:
        b.configure()
        b.activate()
        for _ in range(300):  # 1.5 s of control time: filter and rate limit settle
            clock.t += 0.005
            assert b.handle_joint_state(list(rt.joint_names), list(q), now=clock.t)
            b.step()
        got = [b.emulator.value(i, "goal_position") for i in b.ids]
        want = [int(np.rint(angles_to_ticks(q[rt.joint_names.index(n)]))) for n in b.names]
        assert np.abs(np.array(got) - np.array(want)).max() <= 1
        assert any(g != 2048 for g in got)
    finally:
        b.close()


def test_allegro_mjcf_model_follows_the_hand_frame_convention() -> None:
    rt = HandRetargeter("allegro_hand")
    assert rt.config.model.endswith(".xml")  # an MJCF file (the LEAP Hand is a URDF)
    assert rt.joint_names == tuple(f"joint_{k}.0" for k in range(16))
    names = [p.keypoint for p in rt.config.points]
    tips = [names.index(f"{f}_tip") for f in ("index", "middle", "ring")]
    q0 = np.clip(np.zeros(16), rt.lower, rt.upper)
    flat = rt.robot_points(q0)
    assert np.all(flat[tips, 0] > 0.12) and flat[names.index("thumb_tip"), 1] > 0.1
    assert flat[tips[0], 1] > flat[tips[1], 1] > flat[tips[2], 1]
    for j in ("joint_1.0", "joint_2.0", "joint_3.0"):  # flexion moves the tip palmwards (-z)
        q = q0.copy()
        q[rt.joint_names.index(j)] = 0.5
        assert rt.robot_points(q)[tips[0], 2] < flat[tips[0], 2] - 0.005, j
