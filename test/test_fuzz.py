"""Fuzz suite (issue #20): malformed and extreme inputs never give a non-finite or out-of-limit
command, a crash or a hang.

Property-based (``hypothesis``, a bounded number of examples, no deadline) for each node's core
entry point behind its node-boundary validation: the validation layer itself, the servo map +
goal limiter + bridge write path on the emulated bus, the simulated world's command path, the
controller core step, the grasp-phase detector and the touch encoder; then a seeded generator
of hostile messages through ROS in two small in-process graphs (sim + controller, servo bridge).
The issue's own cases are kept as explicit ``@example`` seeds (and as plain regression tests in
``test_hostile_input.py``). ``hand-suite bench fuzz`` runs the same generators longer.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from hand_capture.errors import InputError
from hand_capture.model.joints import ARTICULATED_JOINTS, JOINT_NAMES
from hand_capture.validate import (
    DEFAULT_LIMITS,
    joint_bounds,
    validate_contacts,
    validate_hand_pose,
    validate_joint_command,
    validate_joint_state,
    validate_pose,
    validate_twist,
)
from hand_control.dynamixel import control_table as ct

NAMES = list(ARTICULATED_JOINTS)
NAN, INF = float("nan"), float("inf")
FUZZ = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow,
                                       HealthCheck.function_scoped_fixture])

#: numbers a hostile or clumsy publisher sends
hostile = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([NAN, INF, -INF, 1e6, -1e6, 1e308, -1e308, 0.0, 3.0, -3.0]),
    st.floats(-2.0, 2.0),
)
names_any = st.lists(st.sampled_from([*JOINT_NAMES, "bogus", ""]), max_size=30)


def _with(**angles: float) -> list[float]:
    """21 articulated joint values, zero but for ``angles``."""
    return [float(angles.get(n, 0.0)) for n in NAMES]


# -------------------------------------------------------------------- the validation layer
@FUZZ
@given(names_any, st.lists(hostile, max_size=30), st.lists(hostile, max_size=30),
       st.lists(hostile, max_size=30))
@example(["index_pip_flex", "index_pip_flex"], [0.1, 0.2], [], [])  # duplicated names
@example(list(JOINT_NAMES), [1e6] * 27, [], [])
def test_joint_state_and_command_validation(names, pos, vel, eff) -> None:
    for fn in (validate_joint_state, validate_joint_command):
        try:
            t, p, third = fn(names, pos, vel, eff)
        except InputError:
            continue
        assert len(set(t)) == len(t) == len(names) and len(t) > 0
        lo, hi = joint_bounds(t)
        assert np.isfinite(p).all() and ((p >= lo) & (p <= hi)).all()
        if fn is validate_joint_command and len(third):
            assert np.isfinite(third).all()
            assert (np.abs(third) <= DEFAULT_LIMITS.max_effort).all()


@FUZZ
@given(st.one_of(st.just(NAMES), names_any), st.lists(hostile, max_size=25),
       st.lists(hostile, min_size=3, max_size=3), st.lists(hostile, min_size=4, max_size=4),
       st.integers(0, 255), st.integers(0, 255), hostile)
@example([], [], [0, 0, 0], [0, 0, 0, 1], 1, 0, 1.0)  # the empty HandPose
@example(NAMES, [0.0] * 21, [0, 0, 0], [0, 0, 0, 1], 255, 0, 1.0)  # status 255
def test_hand_pose_validation(names, vals, p, o, status, side, conf) -> None:
    try:
        q = validate_hand_pose(names, vals, p, o, status, side, conf)
    except InputError:
        return
    assert status <= 4 and side <= 1 and 0.0 <= conf <= 1.0
    assert q.shape == (27,) and np.isfinite(q).all()
    lo, hi = joint_bounds(tuple(JOINT_NAMES[6:]))
    assert ((q[6:] >= lo) & (q[6:] <= hi)).all()


@FUZZ
@given(st.lists(hostile, min_size=3, max_size=3), st.lists(hostile, min_size=4, max_size=4),
       st.lists(hostile, min_size=3, max_size=3))
@example([0, 0, 1e6], [0, 0, 0, 1], [0, 0, 0])
def test_pose_and_twist_validation(p, o, w) -> None:
    try:
        pos, quat = validate_pose(p, o)
        assert np.isfinite(pos).all() and abs(np.linalg.norm(quat) - 1) < 1e-9
        assert (np.abs(pos) <= DEFAULT_LIMITS.max_position).all()
    except InputError:
        pass
    try:
        v, a = validate_twist(p, w)
        assert np.isfinite(v).all() and np.isfinite(a).all()
    except InputError:
        pass


@FUZZ
@given(st.integers(0, 3), st.lists(hostile, min_size=30, max_size=30))
@example(1, [0.0] * 8 + [1.0] + [0.0] * 8 + [1.0] + [0.0] * 8 + [1e6] + [0.5] * 3)
def test_contact_validation(k, vals) -> None:
    a = np.array(vals)
    pts, nrm, frc = (a[i:i + 3 * k].reshape(k, 3) for i in (0, 9, 18))
    try:
        p, n, f, mu = validate_contacts(pts, nrm, frc, a[27:27 + k])
    except InputError:
        return
    assert np.isfinite(p).all() and np.isfinite(f).all() and np.isfinite(mu).all()
    assert (np.linalg.norm(f, axis=1) <= DEFAULT_LIMITS.max_contact_force).all()


# -------------------------------------------- servo map + goal limiter + bridge write path
@pytest.fixture(scope="module")
def bridge():
    from hand_control.dynamixel.bridge import BridgeConfig, ServoBridge

    clock = [100.0]
    b = ServoBridge(BridgeConfig(servo_map="generic_3dof", packet_timeout_ms=100.0,
                                 filter_cutoff_hz=0.0), clock=lambda: clock[0])
    b.configure()
    b.activate()
    b.fake_clock = clock
    yield b
    b.close()


def _cycle(b, names, values, n: int = 2, dt: float = 0.005) -> bool:
    ok = b.handle_pose(names, values, now=b.fake_clock[0])
    for _ in range(n):
        b.fake_clock[0] += dt
        b.step()
    return ok


@FUZZ
@given(st.lists(hostile, min_size=21, max_size=21), st.booleans())
@example(_with(index_mcp_abd=NAN), False)  # item 1: NaN in a joint the map does not use
@example(_with(index_mcp_flex=1e6), False)  # item 4: 1e6 in a joint the map uses
@example(_with(index_mcp_flex=1e308), False)
def test_bridge_write_path_never_commands_garbage(bridge, values, shuffle) -> None:
    """Straight into the core (no node validation): whatever comes, the goals stay finite and
    within the servo limits, an accepted pose has every used joint within its range, and the
    bridge follows the next valid pose (it was not stopped)."""
    b = bridge
    names = NAMES[::-1] if shuffle else NAMES
    vals = values[::-1] if shuffle else values
    ok = _cycle(b, names, vals)
    if ok:
        q = dict(zip(names, vals, strict=True))
        used = np.array([q[j] for j in b.retarget.required])
        lo, hi = joint_bounds(b.retarget.required)
        assert np.isfinite(used).all() and ((used >= lo) & (used <= hi)).all()
    last = b.limiter.last
    assert np.isfinite(last).all() and ((last >= b.limiter.lo) & (last <= b.limiter.hi)).all()
    emu_goals = np.array([b.emulator.value(i, "goal_position") for i in b.ids])
    assert ((emu_goals >= b.limiter.lo) & (emu_goals <= b.limiter.hi)).all()
    # still alive: a valid pose moves the goals to it (rate-limited: 50 ms cycles, at most
    # 0.2 rad each at 4 rad/s)
    target = [0.0] * 21
    target[NAMES.index("index_pip_flex")] = 0.9
    for _ in range(25):
        _cycle(b, NAMES, target, 1, dt=0.05)
    theta = b.retarget.from_named(NAMES, target)
    want = np.clip(np.rint(theta * ct.TICKS_PER_RAD + ct.POSITION_CENTER), b.limiter.lo,
                   b.limiter.hi)
    got = np.array([b.emulator.value(i, "goal_position") for i in b.ids])
    assert np.abs(got - want).max() <= 1
    assert b.skipped_writes == 0


# ------------------------------------------------------------ the world and the controller
@pytest.fixture(scope="module")
def runner():
    from hand_control.sim.lockstep import LockstepRunner
    from hand_control.sim.scenario import load_scenario

    return LockstepRunner(load_scenario("lift_box"))


@st.composite
def _commands(draw):
    names = draw(st.lists(st.sampled_from(JOINT_NAMES), min_size=1, max_size=6, unique=True))
    n = len(names)
    pos = draw(st.one_of(st.just([]), st.lists(hostile, min_size=n, max_size=n),
                         st.lists(hostile, max_size=7)))
    eff = draw(st.one_of(st.lists(hostile, min_size=n, max_size=n),
                         st.lists(st.floats(-1e3, 1e3), min_size=n, max_size=n),
                         st.lists(hostile, max_size=7)))
    return names, pos, eff


@FUZZ
@given(_commands(), st.booleans())
@example((["root_tz"], [], [1e6]), False)  # item 2: one 1e6 effort
@example((["index_pip_flex"], [], [3.0]), False)  # finite, beyond the 2.4 N m actuator
@example((["index_pip_flex"], [1e6], []), True)
def test_world_command_path_refuses_out_of_limit_efforts(runner, cmd, node) -> None:
    """The simulated world's command path, straight (``node`` False) or behind the sim node's
    validation: either refused, or applied with every effort within its actuator's limits."""
    w = runner.world
    names, pos, eff = cmd
    try:
        if node:
            names, pos, eff = validate_joint_command(names, pos, (), eff)
        w.command_by_name(names, pos, eff)
    except InputError:
        pass
    assert np.isfinite(w.effort).all() and np.isfinite(w.target).all()
    assert ((w.effort >= w.effort_lo) & (w.effort <= w.effort_hi)).all()
    assert np.isfinite(w.data.ctrl).all()


def test_world_stays_stable_after_the_fuzzed_commands(runner) -> None:
    w = runner.world
    w.set_command(w.hand_state()[0], np.zeros(w.n_hand))
    w.step(200)  # raises SimulationError on a divergence
    assert np.isfinite(w.hand_state()[0]).all()


@FUZZ
@given(st.lists(hostile, min_size=27, max_size=27), st.lists(hostile, min_size=27,
                                                              max_size=27),
       st.lists(hostile, min_size=3, max_size=3), st.lists(hostile, min_size=4, max_size=4),
       st.floats(0.0, 10.0))
@example([1e6] + [0.0] * 26, [0.0] * 27, [0.0, 0.0, 0.1], [0, 0, 0, 1], 1.0)
def test_controller_core_step_behind_node_validation(runner, q, qd, p, o, t) -> None:
    """The controller node's joint-state and object-pose paths: accepted inputs give finite
    commands whose efforts the world accepts."""
    core = runner.core
    try:
        names, qv, qdv = validate_joint_state(JOINT_NAMES, q, qd, known=set(JOINT_NAMES))
        pos, quat = validate_pose(p, o)
    except InputError:
        return
    cmd = core.step(t, qv, qdv, (pos, quat, np.zeros(3), np.zeros(3)), [], np.zeros((0, 3)),
                    np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    assert np.isfinite(cmd.positions).all() and np.isfinite(cmd.efforts).all()
    w = runner.world
    assert ((cmd.efforts >= w.effort_lo) & (cmd.efforts <= w.effort_hi)).all()


# ---------------------------------------------------------------- the grasp-phase detector
def _grasp_frames():
    from test_teleop_phases import _pose, _wrist

    from hand_capture.model import HandModel

    m = HandModel()
    kp0 = m.forward(_pose(0.0, 0.0)).joint_positions
    obj = np.eye(4)
    obj[:3, 3] = kp0[[0, 5, 9, 13, 17]].mean(axis=0)
    qs = [_pose(x, 0.0) for x in np.linspace(0.5, 0.0, 30)]
    qs += [_pose(0.0, c) for c in list(np.linspace(0.0, 0.8, 10)) + [0.8] * 30]
    qs += [_pose(0.0, c) for c in list(np.linspace(0.8, 0.0, 8)) + [0.0] * 25]
    return [(m.forward(q).joint_positions, _wrist(q)) for q in qs], obj


@pytest.fixture(scope="module")
def grasp_frames():
    return _grasp_frames()


@FUZZ
@given(st.integers(0, 102), st.one_of(st.floats(-1e12, 1e12), st.sampled_from(
    [4e9, 1e9, 100.0, -1.0, 0.0])), st.integers(1, 3))
@example(65, 4e9, 1)  # item 5: one future stamp in manipulation
@example(45, 4e9, 1)  # ... and while closing
def test_phase_detector_is_never_frozen_by_a_stamp(grasp_frames, at, stamp, n) -> None:
    """One to three hand poses with any finite stamp, anywhere in a grasp: the grasp and its
    release are still detected with the frames that follow."""
    from hand_control.teleop.phases import GraspPhaseDetector, Phase

    frames, obj = grasp_frames
    det = GraspPhaseDetector()
    seen = set()
    for k, (kp, wrist) in enumerate(frames):
        if k == at:
            for _ in range(n):
                det.update(stamp, kp, wrist, obj)
        seen.add(det.update(k / 30, kp, wrist, obj).phase)
    assert Phase.MANIPULATION in seen and Phase.RELEASING in seen


# -------------------------------------------------------------------------- touch encoder
@pytest.fixture(scope="module")
def encoder():
    from hand_capture.touch.encoder import TouchEncoder, TouchEncoderConfig

    return TouchEncoder(TouchEncoderConfig())


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 5), hostile, hostile, st.booleans()), max_size=7),
       st.sampled_from([0.197, 1.0, 10.0, 1e9, 0.0, NAN]),
       st.sampled_from([0.148, 0.5, 10.0, -1.0, INF]))
@example([(1, 1e6, 0.05, True)], 0.197, 0.148)  # item 4: a touch 1e6 m off the surface
def test_touch_encoder_behind_its_node_boundary(encoder, pts, width, height) -> None:
    from types import SimpleNamespace

    from hand_capture.nodes.touch_encoder import frame_from_msg

    msg = SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=1, nanosec=0), frame_id="s"),
        width=width, height=height,
        points=[SimpleNamespace(session_id=i, x=x, y=y, in_contact=c) for i, x, y, c in pts])
    try:
        res = encoder.process(frame_from_msg(msg))
    except InputError:
        return
    if res is not None:
        assert np.isfinite(res.pose).all()
        assert np.abs(res.pose[6:]).max() < 50.0  # bounded (the issue saw 1.6e14 rad)


# -------------------------------------------------------------- through ROS, small graphs
def _hostile_value(rng: np.random.Generator) -> float:
    return float(rng.choice([NAN, INF, -INF, 1e6, -1e6, 1e308, rng.normal() * 10]))


def _hostile_joint_command(rng, JointCommand):
    names = list(rng.choice(JOINT_NAMES, size=int(rng.integers(0, 8))))
    if rng.random() < 0.3 and names:
        names.append(names[0])  # duplicated
    if rng.random() < 0.2:
        names.append("bogus")
    n = len(names) + int(rng.integers(-1, 2)) * (rng.random() < 0.3)
    vals = [_hostile_value(rng) if rng.random() < 0.5 else 0.1 for _ in range(max(n, 0))]
    effs = [_hostile_value(rng) if rng.random() < 0.5 else 0.0 for _ in range(max(n, 0))]
    return JointCommand(joint_names=names, positions=vals, efforts=effs)


def test_sim_and_controller_graph_survives_hostile_messages(ros) -> None:
    from geometry_msgs.msg import PoseStamped, TwistStamped
    from hand_msgs.msg import JointCommand
    from rclpy.parameter import Parameter
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import JointState

    from hand_control.nodes.controller import ControllerNode
    from hand_control.nodes.sim import SimNode

    peer, add, spin_until = ros
    sim = add(SimNode(parameter_overrides=[Parameter("scenario", value="lift_box"),
                                           Parameter("real_time", value=False),
                                           Parameter("command_timeout", value=1.0)]))
    ctrl = add(ControllerNode(parameter_overrides=[Parameter("scenario", value="lift_box")]))
    cmds: list = []
    peer.create_subscription(JointCommand, "control/joint_command", cmds.append, 100)
    pub_cmd = peer.create_publisher(JointCommand, "control/joint_command", 10)
    pub_js = peer.create_publisher(JointState, "sim/joint_states", qos_profile_sensor_data)
    pub_pose = peer.create_publisher(PoseStamped, "sim/object_pose", qos_profile_sensor_data)
    pub_twist = peer.create_publisher(TwistStamped, "sim/object_twist",
                                      qos_profile_sensor_data)
    pub_target = peer.create_publisher(PoseStamped, "control/object_target", 10)
    assert spin_until(lambda: sim.world.time > 0.2 and len(cmds) > 5, 30.0)
    rng = np.random.default_rng(20)
    # the seeds first, then generated ones
    seeds = [JointCommand(joint_names=["root_tz"], efforts=[1e6]),
             JointState(name=list(JOINT_NAMES), position=[1e6] + [0.0] * 26,
                        velocity=[0.0] * 27),
             JointState(name=list(JOINT_NAMES[:-1]) + [JOINT_NAMES[0]],  # duplicated name
                        position=[0.0] * 27, velocity=[0.0] * 27)]
    for k in range(60):
        kind = k % 5
        if k < len(seeds):
            msg, pub = seeds[k], (pub_cmd if k == 0 else pub_js)
        elif kind == 0:
            msg, pub = _hostile_joint_command(rng, JointCommand), pub_cmd
        elif kind == 1:
            n = int(rng.integers(0, 30))
            msg = JointState(name=list(rng.choice(JOINT_NAMES, size=min(n, 27),
                                                  replace=False)),
                             position=[_hostile_value(rng) for _ in range(n)],
                             velocity=[_hostile_value(rng) for _ in range(n)])
            pub = pub_js
        elif kind in (2, 4):
            msg = PoseStamped()
            p, o = msg.pose.position, msg.pose.orientation
            p.x, p.y, p.z = (_hostile_value(rng) for _ in range(3))
            o.x, o.y, o.z, o.w = (_hostile_value(rng) for _ in range(4))
            pub = pub_pose if kind == 2 else pub_target
        else:
            msg = TwistStamped()
            msg.twist.linear.x = _hostile_value(rng)
            msg.twist.angular.z = _hostile_value(rng)
            pub = pub_twist
        pub.publish(msg)
        spin_until(lambda: False, 0.02)
    t_before = sim.world.time
    n_before = len(cmds)
    assert spin_until(lambda: sim.world.time > t_before + 0.3 and len(cmds) > n_before + 20,
                      30.0), "the graph stopped"
    w = sim.world
    ours = [c for c in cmds if list(c.joint_names) == list(w.joint_names)]  # the controller's
    assert len(ours) > 20
    for c in ours:
        e, q = np.array(c.efforts), np.array(c.positions)
        assert np.isfinite(e).all() and np.isfinite(q).all()
        assert ((e >= w.effort_lo) & (e <= w.effort_hi)).all()
        assert (np.abs(e) < 1e3).all()
    assert sim.rejected > 0 and ctrl.gate.rejected["sim/joint_states"] >= 2
    assert ctrl.gate.rejected["sim/object_pose"] > 0
    assert math.isfinite(w.time) and np.isfinite(w.hand_state()[0]).all()


def test_servo_bridge_node_survives_hostile_poses(ros) -> None:
    from hand_msgs.msg import HandPose
    from rclpy.parameter import Parameter
    from rclpy.qos import qos_profile_sensor_data

    from hand_control.nodes.servo_bridge import ServoBridgeNode

    peer, add, spin_until = ros
    node = add(ServoBridgeNode(parameter_overrides=[
        Parameter("servo_map", value="generic_3dof"),
        Parameter("packet_timeout_ms", value=100.0)]))
    assert spin_until(lambda: node.core is not None and node.core.state.value == "active",
                      20.0)
    b = node.core
    pub = peer.create_publisher(HandPose, "hand/pose", qos_profile_sensor_data)
    rng = np.random.default_rng(4)

    def pose_msg(values, names=NAMES, status=HandPose.STATUS_TRACKING):
        return HandPose(joint_names=list(names), positions=[float(v) for v in values],
                        status=status, handedness=HandPose.HAND_RIGHT)

    hostile_msgs = [pose_msg(_with(index_mcp_abd=NAN)),  # item 1
                    pose_msg(_with(index_mcp_flex=1e6)),  # item 4
                    pose_msg([], names=[]),  # empty
                    pose_msg([0.0] * 21, status=255),
                    pose_msg([0.0] * 21, names=NAMES[:-1] + NAMES[:1])]
    for _ in range(25):
        vals = [_hostile_value(rng) if rng.random() < 0.2 else rng.uniform(-0.2, 0.6)
                for _ in range(21)]
        hostile_msgs.append(pose_msg(vals))
    for m in hostile_msgs:
        pub.publish(m)
        spin_until(lambda: False, 0.02)
        last = b.limiter.last
        assert np.isfinite(last).all()
        assert ((last >= b.limiter.lo) & (last <= b.limiter.hi)).all()
    assert node.gate.total >= 5
    good = [0.0] * 21
    good[NAMES.index("index_pip_flex")] = 0.9
    want = int(np.clip(np.rint(b.retarget.from_named(NAMES, good)[1] * ct.TICKS_PER_RAD
                               + ct.POSITION_CENTER), b.limiter.lo[1], b.limiter.hi[1]))

    def follows() -> bool:
        pub.publish(pose_msg(good))
        return abs(b.emulator.value(b.ids[1], "goal_position") - want) <= 1

    assert spin_until(follows, 20.0)
    assert b.state.value == "active" and b.skipped_writes == 0


def test_grasp_phase_node_rejects_hostile_poses_and_future_stamps(ros) -> None:
    import time as _time

    from geometry_msgs.msg import PoseStamped
    from hand_msgs.msg import HandPose
    from rclpy.parameter import Parameter

    from hand_capture.posemsg import fill_pose_msg
    from hand_control.nodes.grasp_phase import GraspPhaseNode

    peer, add, spin_until = ros
    node = add(GraspPhaseNode(parameter_overrides=[Parameter("scenario", value="lift_box")]))
    hands: list = []
    peer.create_subscription(HandPose, "control/hand_target", hands.append, 50)
    pub_hand = peer.create_publisher(HandPose, "hand/pose", 50)
    pub_obj = peer.create_publisher(PoseStamped, "sim/object_pose", 10)
    obj = PoseStamped()
    obj.pose.position.z, obj.pose.orientation.w = 0.05, 1.0

    def hand(**kw) -> HandPose:
        q = np.zeros(27)
        q[2] = 0.3
        msg = fill_pose_msg(HandPose(), q, status="tracking")
        msg.header.frame_id = "world"
        msg.header.stamp.sec = int(_time.time()) - 1
        for k, v in kw.items():
            setattr(msg, k, v)
        return msg

    bad_angle = hand()
    bad_angle.positions = [1e6] + list(bad_angle.positions[1:])  # item 4
    future = hand()
    future.header.stamp.sec = int(_time.time()) + 10**6  # item 5: a future stamp
    hostile = [bad_angle, future, hand(status=255), hand(joint_names=[], positions=[])]
    assert spin_until(lambda: pub_hand.get_subscription_count() > 0, 10.0)
    for m in hostile:
        pub_obj.publish(obj)
        pub_hand.publish(m)
        spin_until(lambda: False, 0.05)
    assert spin_until(lambda: node.gate.rejected["hand/pose"] >= 4, 10.0), node.gate.values()
    assert not hands  # nothing of it reached the controller's target

    def follows() -> bool:
        pub_obj.publish(obj)
        pub_hand.publish(hand())
        return bool(hands)

    assert spin_until(follows, 10.0)
    assert all(np.isfinite(h.positions).all() and max(abs(v) for v in h.positions) < 3.0
               for h in hands)
