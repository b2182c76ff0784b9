"""The controller core apart from the simulation: one config for every gain (settable through
ROS), seed 000's eq. 10-11 in closed loop, limits that hold for any input, and the
exported MJCF being the simulated model (Menagerie-style: every scene steps warning-free)."""

from __future__ import annotations

import subprocess
import sys

import mujoco
import numpy as np
import pytest

from hand_capture.model.mjcf import export_mjcf
from hand_control.control import CompositeControlConfig
from hand_control.sim import LockstepRunner, SimConfig, SimWorld, load_scenario, scenario_names
from hand_control.sim.lockstep import build_world


def test_control_does_not_depend_on_the_simulation() -> None:
    code = ("import sys, hand_control.control as c; "
            "bad = [m for m in sys.modules if m.startswith('hand_control.sim') or m == 'mujoco'"
            " or m.startswith('hand_control.nodes')]; print(bad); assert not bad, bad")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


@pytest.fixture(scope="module")
def grasp_state():
    """A lockstep run of lift_box to the lifting phase: the sim's inputs to the controller."""
    runner = LockstepRunner(load_scenario("lift_box"), control_every=2)
    runner.run(duration=1.5)
    return runner


def _inputs(runner):
    w = runner.world
    cf = w.contacts(runner.obj.name)
    op = w.object_pose(runner.obj.name)
    q, qd = w.hand_state()
    return w.time, q, qd, op, cf


def test_gain_set_through_ros_changes_the_torques(ros, grasp_state) -> None:
    """Two controller nodes, one started with ``-p object_kp_translate:=60``, get the same sim
    state over topics: the stiffer object servo asks for other grasp torques."""
    from geometry_msgs.msg import PoseStamped, TwistStamped
    from hand_msgs.msg import ContactArray, JointCommand
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState

    from hand_control.nodes.controller import ControllerNode
    from hand_control.nodes.convert import contact_array, stamp

    peer, add, spin_until = ros
    t, q, qd, op, cf = _inputs(grasp_state)
    t_target = grasp_state.reference(t).object_position
    assert np.linalg.norm(op.position - t_target) > 1e-3  # the object servo has work to do
    nodes = {
        "base": add(ControllerNode(namespace="base", parameter_overrides=[
            Parameter("scenario", value="lift_box")])),
        "stiff": add(ControllerNode(namespace="stiff", parameter_overrides=[
            Parameter("scenario", value="lift_box"),
            Parameter("object_kp_translate", value=60.0)])),
    }
    assert nodes["stiff"].gains.object_kp_translate == 60.0
    assert nodes["base"].gains == CompositeControlConfig()
    got: dict[str, list] = {n: [] for n in nodes}
    pubs = {}
    for n in nodes:
        peer.create_subscription(JointCommand, f"/{n}/control/joint_command", got[n].append, 10)
        pubs[n] = [peer.create_publisher(m, f"/{n}/{topic}", 10) for m, topic in (
            (PoseStamped, "sim/object_pose"), (TwistStamped, "sim/object_twist"),
            (ContactArray, "sim/contacts"), (JointState, "sim/joint_states"))]
    pose, twist, js = PoseStamped(), TwistStamped(), JointState()
    for msg in (pose, twist, js):
        stamp(msg.header, t)
    pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = op.position.tolist()
    o = pose.pose.orientation
    o.w, o.x, o.y, o.z = op.quaternion.tolist()
    twist.twist.linear.x, twist.twist.linear.y, twist.twist.linear.z = \
        op.linear_velocity.tolist()
    js.name = list(grasp_state.world.joint_names)
    js.position, js.velocity = q.tolist(), qd.tolist()
    contacts = contact_array(cf, t, "world")
    assert len(contacts.contacts) >= 2

    def publish() -> None:
        for p_pose, p_twist, p_contacts, p_js in pubs.values():
            p_pose.publish(pose)
            p_twist.publish(twist)
            p_contacts.publish(contacts)
            p_js.publish(js)

    def answered() -> bool:
        return all(got[n] and any(abs(e) > 0 for e in got[n][-1].efforts) for n in nodes)

    assert spin_until(answered, 30.0, tick=publish), {n: len(v) for n, v in got.items()}
    base = np.array(got["base"][-1].efforts)
    stiff = np.array(got["stiff"][-1].efforts)
    assert np.abs(stiff - base).max() > 1e-3, (base, stiff)
    lim = nodes["base"].core.kin.effort_limits
    assert (np.abs(base) <= lim).all() and (np.abs(stiff) <= lim).all()


def test_seed000_method_runs_in_closed_loop() -> None:
    """``method: seed000`` (eq. 10-11: scaled simulator contact forces) is selectable and runs
    the lockstep loop: grasp torques from its QP, no divergence."""
    spec = load_scenario("lift_box")
    r = LockstepRunner(spec, control_every=2, gains=CompositeControlConfig(method="seed000"))
    assert r._contact_forces  # the path that reads the simulator's contact forces
    res = r.run(duration=2.0)
    out = r.core.last_output
    assert out is not None and out.qp is not None and out.qp.method == "seed000"
    assert r.controller.grasp_steps > 100 and res.divergences == 0
    assert not r.last_command.pd_only and np.abs(r.last_command.efforts).max() > 1e-3


@pytest.mark.parametrize("case", ["huge_object_pose", "huge_target", "nan_state",
                                  "huge_contact_force"])
def test_controller_output_stays_finite_and_within_limits(grasp_state, case) -> None:
    core = grasp_state.core
    t, q, qd, op, cf = _inputs(grasp_state)
    pose = [op.position.copy(), op.quaternion.copy(), op.linear_velocity.copy(),
            op.angular_velocity.copy()]
    forces = cf.forces.copy()
    core.object_target_override = None
    if case == "huge_object_pose":
        pose[0] = pose[0] + 1e6
        pose[2] = np.full(3, 1e6)
    elif case == "huge_target":
        core.object_target_override = (np.array([1e6, -1e6, 1e6]), np.array([1.0, 0, 0, 0]))
        core.config = core.config.__class__(target_cutoff=0.0)
    elif case == "nan_state":
        q = q.copy()
        q[7] = np.nan
    else:
        forces = forces * 1e6
    before = core.counters["saturated"]
    try:
        cmd = core.step(t, q, qd, tuple(pose), cf.body1, cf.points, cf.normals, forces,
                        cf.friction)
    finally:
        core.object_target_override = None
    lim, plim = core.kin.effort_limits, core.kin.position_limits
    assert np.isfinite(cmd.efforts).all() and np.isfinite(cmd.positions).all()
    assert (np.abs(cmd.efforts) <= lim).all()
    assert ((cmd.positions >= plim[:, 0]) & (cmd.positions <= plim[:, 1])).all()
    if case in ("huge_object_pose", "huge_target"):
        assert core.counters["saturated"] > before  # counted, not silently clipped
        assert np.isclose(np.abs(cmd.efforts) / lim, 1.0).any()


def test_exported_scene_behaves_like_the_simulated_model(tmp_path) -> None:
    """``hand-suite mjcf`` output stepped in plain MuJoCo = the sim's world: same servos, same
    trajectory (the sim writes ctrl, never rewrites the actuators)."""
    files = export_mjcf(tmp_path)
    path = files.scenes["scene_box"]
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    world = SimWorld(path.read_text(), SimConfig(hand_gravcomp=False))
    rng = np.random.default_rng(1)
    lo, hi = m.jnt_range[6:27, 0], m.jnt_range[6:27, 1]
    target = d.qpos[:27].copy()
    for i in range(600):
        if i % 100 == 0:
            target[6:] = rng.uniform(lo, hi)
            world.set_command(target)
            d.ctrl[:27] = target
        mujoco.mj_step(m, d)
        world.step()
    np.testing.assert_allclose(world.data.qpos, d.qpos, atol=1e-12)
    assert np.abs(d.qpos[6:27] - target[6:]).max() > 0  # it moved toward the targets
    assert np.median(np.abs(d.qpos[6:27] - target[6:])) < 0.1


def _assert_steps_clean(m, d, steps: int, label: str) -> None:
    for _ in range(steps):
        mujoco.mj_step(m, d)
    warn = [int(w.number) for w in d.warning]
    assert not any(warn), (label, warn)
    assert np.isfinite(d.qpos).all() and np.isfinite(d.qvel).all(), label


def test_every_exported_scene_and_scenario_world_steps_without_warnings(tmp_path) -> None:
    """Menagerie-style: load every model the suite writes and step it; any MuJoCo warning
    (contact / constraint buffer full, bad qacc, inertia) fails."""
    files = export_mjcf(tmp_path)
    for p in [files.hand, *files.scenes.values()]:
        m = mujoco.MjModel.from_xml_path(str(p))
        d = mujoco.MjData(m)
        mujoco.mj_resetDataKeyframe(m, d, 0)
        _assert_steps_clean(m, d, 500, p.name)
    for name in scenario_names():
        world, _, _ = build_world(load_scenario(name))
        m, d = world.model, mujoco.MjData(world.model)
        mujoco.mj_resetDataKeyframe(m, d, 0)
        _assert_steps_clean(m, d, 500, name)


def test_sim_node_writes_the_servo_gains_of_its_parameters_into_the_model(ros) -> None:
    """``-p sim.joint_kp:=...`` reaches MuJoCo: the world's position servos carry the gains."""
    from rclpy.parameter import Parameter

    from hand_capture.model.joints import JOINT_NAMES
    from hand_control.control import joint_gains
    from hand_control.nodes.sim import SimNode

    _, add, _ = ros
    kp = [2.0 * v for v in CompositeControlConfig().joint_kp]
    sim = add(SimNode(parameter_overrides=[Parameter("scenario", value="lift_box"),
                                           Parameter("real_time", value=False),
                                           Parameter("joint_kp", value=kp)]))
    want, _ = joint_gains(sim.gains, JOINT_NAMES)
    m = sim.world.model
    np.testing.assert_allclose(m.actuator_gainprm[:27, 0], want)
    np.testing.assert_allclose(sim.world.kp, want)
    i = JOINT_NAMES.index("index_mcp_flex")
    assert m.actuator_gainprm[i, 0] == 8.0  # Table 1's index1 Kp = 4, doubled
