"""Issue #20, items 1, 2, 4 and 5 (the seed corpus, as plain regression tests) and the input
validation layer (:mod:`hand_capture.validate`): every case here failed on the code the issue
was filed against."""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np
import pytest

from hand_capture.errors import InputError, RejectedInputError
from hand_capture.model import HandModel, rest_pose
from hand_capture.model.joints import ARTICULATED_JOINTS, JOINT_INDEX, JOINT_NAMES
from hand_capture.validate import (
    InputLimits,
    check_stamp,
    validate_contacts,
    validate_grasp_phase,
    validate_hand_pose,
    validate_hand_pose_msg,
    validate_joint_command,
    validate_joint_state,
    validate_pose,
    validate_touch_frame,
    validate_twist,
)
from hand_control.dynamixel import control_table as ct
from hand_control.dynamixel.bridge import ERROR, BridgeConfig, ServoBridge
from hand_control.dynamixel.retarget import Retargeter
from hand_control.dynamixel.safety import GoalLimiter
from hand_control.dynamixel.servo_map import load_servo_map
from hand_control.teleop.phases import GraspPhaseDetector, Phase

NAMES = list(ARTICULATED_JOINTS)


def pose(**angles: float) -> list[float]:
    q = dict.fromkeys(NAMES, 0.0)
    q.update(angles)
    return [q[n] for n in NAMES]


def hand_pose_msg(names=None, positions=None, status: int = 1, quat=(0.0, 0.0, 0.0, 1.0),
                  position=(0.0, 0.0, 0.4), handedness: int = 0, confidence: float = 1.0):
    """An object with the fields of hand_msgs/HandPose (no message import needed)."""
    p = SimpleNamespace(x=position[0], y=position[1], z=position[2])
    o = SimpleNamespace(x=quat[0], y=quat[1], z=quat[2], w=quat[3])
    return SimpleNamespace(joint_names=NAMES if names is None else names,
                           positions=pose() if positions is None else positions,
                           wrist_pose=SimpleNamespace(position=p, orientation=o),
                           status=status, handedness=handedness, confidence=confidence)


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def gen():
    clock = FakeClock()
    b = ServoBridge(BridgeConfig(servo_map="generic_3dof", packet_timeout_ms=100.0),
                    clock=clock)
    b.configure()
    b.activate()
    b.fake_clock = clock
    yield b
    b.close()


def run(b: ServoBridge, q: list[float] | None, cycles: int, dt: float = 0.005) -> None:
    for _ in range(cycles):
        b.fake_clock.t += dt
        if q is not None:
            b.handle_pose(NAMES, q, now=b.fake_clock.t)
        b.step()


def goals(b: ServoBridge) -> list[int]:
    return [b.emulator.value(i, "goal_position") for i in b.ids]


# ------------------------------------------------------------------------------------ item 1
def test_item1_nan_in_an_unmapped_joint_does_not_stop_the_bridge(gen) -> None:
    """generic_3dof does not use index_mcp_abd: a NaN there must not reach any servo."""
    assert "index_mcp_abd" not in gen.retarget.required
    run(gen, pose(index_mcp_flex=0.2), 50)
    nan_pose = pose(index_mcp_flex=0.2, index_mcp_abd=float("nan"))
    run(gen, nan_pose, 5)
    assert np.isfinite(gen.limiter.last).all()
    run(gen, pose(index_mcp_flex=1.2), 400)  # the bridge still follows the hand
    theta = gen.retarget.from_named(NAMES, pose(index_mcp_flex=1.2))
    want = np.clip(np.rint(theta * ct.TICKS_PER_RAD + ct.POSITION_CENTER),
                   gen.limiter.lo, gen.limiter.hi).astype(int).tolist()
    assert goals(gen) == want


def test_item1_servo_angles_read_only_the_mapped_joints() -> None:
    r = Retargeter(load_servo_map("generic_3dof"))
    q = np.zeros(len(NAMES))
    q[NAMES.index("index_mcp_abd")] = np.nan
    assert np.isfinite(r.servo_angles(q)).all()


def test_item1_goal_limiter_never_stores_a_non_finite_goal() -> None:
    lim = GoalLimiter(load_servo_map("generic_3dof"))
    lim.reset(np.full(3, 2048.0))
    goal = lim(np.array([np.nan, np.inf, 2100.0]), 0.01)
    assert np.isfinite(lim.last).all() and np.isfinite(goal).all()
    assert goal[0] == 2048.0 and goal[1] == 2048.0  # held, not moved
    lim(np.array([2060.0, 2060.0, 2100.0]), 0.01)
    assert (lim.last[:2] > 2048.0).all()  # and it moves again afterwards


def test_item1_a_skipped_write_is_logged_counted_and_not_reported_as_active(gen,
                                                                             caplog) -> None:
    run(gen, pose(), 5)
    gen.limiter.last[1] = np.nan  # a servo without a finite goal (injected)
    with caplog.at_level("WARNING"):
        run(gen, pose(), 3)
    assert gen.skipped_writes >= 3
    assert any("not written" in r.getMessage() for r in caplog.records)
    bus = gen.diagnostics()[0]
    assert bus.level == ERROR and "not written" in bus.message
    assert not bus.message.startswith("active")
    assert bus.values["skipped_writes"] == str(gen.skipped_writes)


# ------------------------------------------------------------------------------------ item 2
def test_item2_the_sim_refuses_efforts_outside_its_actuator_limits() -> None:
    from hand_control.sim.lockstep import LockstepRunner
    from hand_control.sim.scenario import load_scenario

    w = LockstepRunner(load_scenario("lift_box")).world
    before = w.effort.copy()
    with pytest.raises(InputError, match="outside its actuator's limits"):
        w.command_by_name(["root_tz"], [], [1e6])
    with pytest.raises(InputError, match="index_pip_flex"):
        w.set_command(None, np.where(np.array(w.joint_names) == "index_pip_flex", 1e6, 0.0))
    np.testing.assert_array_equal(w.effort, before)  # nothing applied
    k = w.joint_names.index("root_tz")
    w.command_by_name(["root_tz"], [], [0.9 * w.effort_hi[k]])  # within: applied
    assert w.effort[k] == pytest.approx(0.9 * w.effort_hi[k])
    w.step(50)  # and the world stays stable


@pytest.mark.parametrize("field", ["position", "velocity", "effort"])
def test_item2_joint_state_with_1e6_is_rejected(field: str) -> None:
    names = list(JOINT_NAMES)
    arrays = {"position": [0.0] * 27, "velocity": [0.0] * 27, "effort": []}
    arrays[field] = [0.0] * 27
    arrays[field][JOINT_INDEX["index_pip_flex"]] = 1e6
    with pytest.raises(RejectedInputError, match="index_pip_flex"):
        validate_joint_state(names, arrays["position"], arrays["velocity"], arrays["effort"])


def test_item2_joint_command_with_1e6_effort_is_rejected() -> None:
    with pytest.raises(RejectedInputError, match=r"effort of 'root_tz' = 1e\+06 N m"):
        validate_joint_command(["root_tz", "index_pip_flex"], [0.0, 0.5], (), [1e6, 0.0])
    with pytest.raises(RejectedInputError, match="outside"):
        validate_joint_command(["index_pip_flex"], [1e6])


@pytest.mark.parametrize("case", ["pos", "quat", "nan"])
def test_item2_object_pose_and_target_out_of_range_are_rejected(case: str) -> None:
    pos, quat = [0.0, 0.0, 0.1], [0.0, 0.0, 0.0, 1.0]
    if case == "pos":
        pos[2] = 1e6
    elif case == "quat":
        quat = [0.0, 0.0, 0.0, 1e6]
    else:
        pos[0] = float("nan")
    with pytest.raises(RejectedInputError):
        validate_pose(pos, quat)
    p, q = validate_pose([0.0, 0.0, 0.1], [0.0, 0.0, 0.0, 1.0])
    np.testing.assert_allclose(q, [1.0, 0.0, 0.0, 0.0])  # wxyz


def test_item2_object_twist_of_1e6_is_rejected() -> None:
    with pytest.raises(RejectedInputError, match="m/s"):
        validate_twist([1e6, 0, 0], [0, 0, 0])
    with pytest.raises(RejectedInputError, match="rad/s"):
        validate_twist([0, 0, 0], [0, 0, 1e6])
    validate_twist([0.1, 0, 0], [0, 0, 1.0])


# ------------------------------------------------------------------------------------ item 4
@pytest.mark.parametrize("value", [1e6, 1e308, 3.0])
def test_item4_out_of_range_angles_are_rejected_before_the_servo_map(gen, value) -> None:
    run(gen, pose(index_mcp_flex=0.3), 50)
    before = goals(gen)
    assert not gen.handle_pose(NAMES, pose(index_mcp_flex=value), now=gen.fake_clock.t)
    run(gen, None, 20)
    assert goals(gen) == before  # not driven to the servo limit
    with pytest.raises(RejectedInputError, match="index_mcp_flex"):
        validate_hand_pose_msg(hand_pose_msg(positions=pose(index_mcp_flex=value)))


def test_item4_empty_hand_pose_is_rejected_not_a_flat_hand() -> None:
    with pytest.raises(RejectedInputError, match="empty pose"):
        validate_hand_pose_msg(hand_pose_msg(names=[], positions=[]))
    with pytest.raises(RejectedInputError, match="thumb_ip_flex"):
        validate_hand_pose_msg(hand_pose_msg(names=[n for n in NAMES if n != "thumb_ip_flex"],
                                             positions=[0.0] * 20))


def test_item4_status_255_and_bad_enumerations_are_rejected() -> None:
    with pytest.raises(RejectedInputError, match="status 255"):
        validate_hand_pose_msg(hand_pose_msg(status=255))
    with pytest.raises(RejectedInputError, match="handedness"):
        validate_hand_pose_msg(hand_pose_msg(handedness=7))
    with pytest.raises(RejectedInputError, match="confidence"):
        validate_hand_pose_msg(hand_pose_msg(confidence=float("nan")))
    with pytest.raises(RejectedInputError, match="phase 9"):
        validate_grasp_phase(9)
    assert validate_grasp_phase(2) == 2


def test_item4_duplicated_joint_names_are_rejected() -> None:
    with pytest.raises(RejectedInputError, match="duplicate"):
        validate_joint_state(["index_pip_flex", "index_pip_flex"], [0.1, 0.2])
    with pytest.raises(RejectedInputError, match="duplicate"):
        validate_joint_command(["index_pip_flex", "index_pip_flex"], [0.1, 0.2])
    names = NAMES[:-1] + [NAMES[0]]
    with pytest.raises(RejectedInputError, match="duplicate"):
        validate_hand_pose_msg(hand_pose_msg(names=names))


def test_item4_touches_far_off_the_surface_are_rejected() -> None:
    with pytest.raises(RejectedInputError, match="touch x"):
        validate_touch_frame([1], [(1e6, 0.05)], [True], 0.197, 0.148)
    with pytest.raises(RejectedInputError, match="surface width"):
        validate_touch_frame([1], [(0.05, 0.05)], [True], 1e9, 0.148)
    pos = validate_touch_frame([1, 2], [(0.0, 0.0), (0.197, 0.148)], [True, True], 0.197,
                               0.148)
    assert pos.shape == (2, 2)


def test_item4_touch_encoder_node_boundary_refuses_off_surface_touches() -> None:
    from hand_capture.nodes.touch_encoder import frame_from_msg

    hdr = SimpleNamespace(stamp=SimpleNamespace(sec=1, nanosec=0), frame_id="s")
    msg = SimpleNamespace(header=hdr, width=0.197, height=0.148, points=[
        SimpleNamespace(session_id=1, x=1e6, y=0.05, in_contact=True)])
    with pytest.raises(InputError, match="touch x"):
        frame_from_msg(msg)


# ------------------------------------------------------------------------------------ item 5
def _grasp_sequence():
    """(t, keypoints, wrist, object) updates: reach, close, hold, then open the grip."""
    from test_teleop_phases import _pose, _wrist

    m = HandModel()
    kp0 = m.forward(_pose(0.0, 0.0)).joint_positions
    obj = np.eye(4)
    obj[:3, 3] = kp0[[0, 5, 9, 13, 17]].mean(axis=0)
    seq = [_pose(x, 0.0) for x in np.linspace(0.5, 0.0, 30)]
    seq += [_pose(0.0, c) for c in list(np.linspace(0.0, 0.8, 10)) + [0.8] * 20]
    opening = [_pose(0.0, c) for c in list(np.linspace(0.8, 0.0, 8)) + [0.0] * 12]
    frames = [(m.forward(q).joint_positions, _wrist(q)) for q in seq + opening]
    return frames, len(seq), obj


def test_item5_a_future_stamp_does_not_freeze_the_grasp_phase_detector() -> None:
    frames, n_grasp, obj = _grasp_sequence()
    det = GraspPhaseDetector()
    dt = 1 / 30
    for k in range(n_grasp):
        up = det.update(k * dt, *frames[k], obj)
    assert up.phase == Phase.MANIPULATION
    det.update(4e9, *frames[n_grasp - 1], obj)  # one stamp from the far future
    phases = [det.update((k + 1) * dt, *frames[k], obj).phase
              for k in range(n_grasp, len(frames))]
    assert Phase.RELEASING in phases  # the release is still detected
    assert det.time_jumps == 1


def test_item5_check_stamp_refuses_future_stamps() -> None:
    check_stamp(100.5, 100.0)  # within the 1 s tolerance
    with pytest.raises(RejectedInputError, match="future"):
        check_stamp(4e9, 100.0)
    check_stamp(4e9, 0.0)  # a simulated clock that has not started: no check
    check_stamp(4e9, 100.0, InputLimits(future_stamp_tolerance=0.0))  # disabled


# ------------------------------------------------------------------------ validation layer
def test_hand_pose_round_trip_matches_posemsg() -> None:
    from hand_capture.posemsg import pose_from_msg

    rng = np.random.default_rng(3)
    q = rest_pose()
    q[6:] = rng.uniform(0.0, 0.3, 21)
    msg = hand_pose_msg(positions=[float(q[JOINT_INDEX[n]]) for n in NAMES])
    np.testing.assert_allclose(validate_hand_pose_msg(msg), pose_from_msg(msg), atol=1e-12)


def test_errors_name_the_value_range_and_unit() -> None:
    with pytest.raises(RejectedInputError) as e:
        validate_hand_pose(NAMES, pose(index_pip_flex=1e6), (0, 0, 0), (0, 0, 0, 1), 1)
    text = str(e.value)
    assert "index_pip_flex" in text and "1e+06" in text and "rad" in text and "[" in text


def test_contacts_are_checked() -> None:
    p = np.zeros((1, 3))
    n = np.array([[0.0, 0.0, 1.0]])
    f = np.array([[0.0, 0.0, 2.0]])
    validate_contacts(p, n, f, np.array([0.8]))
    with pytest.raises(RejectedInputError, match="contact force"):
        validate_contacts(p, n, f * 1e9, np.array([0.8]))
    with pytest.raises(RejectedInputError, match="NaN"):
        validate_contacts(p * np.nan, n, f, np.array([0.8]))
    with pytest.raises(RejectedInputError, match="friction"):
        validate_contacts(p, n, f, np.array([-1.0]))


def test_input_gate_counts_logs_and_takes_the_limits_from_node_parameters(ros) -> None:
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from hand_capture.nodes.gate import InputGate

    node = Node("gate_test", parameter_overrides=[Parameter("input.max_effort", value=10.0)])
    try:
        gate = InputGate(node)
        assert gate.limits.max_effort == 10.0
        assert gate.check("cmd", validate_joint_command, ["root_tz"], [], [], [20.0]) is None
        assert gate.check("cmd", validate_joint_command, ["root_tz"], [], [], [5.0]) is not None
        assert gate.check("pose", validate_pose, [0, 0, 1e6], [0, 0, 0, 1]) is None
        assert gate.check("pose", validate_pose, [0, 0, 1e6], [0, 0, 0, 1]) is None
        v = gate.values()
        assert v["rejected_total"] == "3" and v["rejected/cmd"] == "1"
        assert v["rejected/pose"] == "2" and "1e+06" in v["last_rejection/pose"]
        stamp = SimpleNamespace(sec=int(time.time()) + 3600, nanosec=0)
        assert not gate.stamp_ok("hand/pose", stamp)
        assert gate.rejected["hand/pose"] == 1
    finally:
        node.destroy_node()
