"""The simulation core: scenes step cleanly, contact conventions, the instability guard,
servo commands (timeout, names), grasp IK, and composite control vs PD-only on a heavy box."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.model.mjcf import build_scene
from hand_control.control import CompositeControlConfig, ControllerNodeConfig
from hand_control.errors import InputError, SimulationError
from hand_control.sim.config import SimConfig
from hand_control.sim.lockstep import LockstepRunner, build_world
from hand_control.sim.scenario import ScenarioSpec, load_scenario, scenario_names

G = 9.81


@pytest.mark.parametrize("name", scenario_names())
def test_every_scenario_scene_steps_one_second_without_warnings(name) -> None:
    world, _, _ = build_world(load_scenario(name))
    world.step(1000)
    assert world.time == pytest.approx(1.0)
    assert world.divergences == [] and world.resets == 0
    assert not any(world.soft_warnings.values())
    assert not world.data.warning.number.any()


def test_the_export_multi_object_scene_steps_one_second_without_warnings() -> None:
    world = simworld_from(build_scene(("box", "ball", "stick", "cup"), hand_gravcomp=True))
    world.step(1000)
    assert not world.data.warning.number.any() and world.divergences == []


def simworld_from(xml: str, **cfg):
    from hand_control.sim.world import SimWorld

    return SimWorld(xml, SimConfig(**cfg))


def test_contact_forces_on_a_resting_box_balance_its_weight() -> None:
    world, obj, _ = build_world(ScenarioSpec(object_kind="box", object_mass=0.3))
    world.step(300)
    cf = world.contacts()
    box = world.objects[obj.name]["body"]
    on_box = cf.select(cf.body2_id == box)
    assert len(on_box) >= 3 and set(on_box.body1) == {"table"}
    # mj_contactForce convention: body 1 pushes body 2 along the normal (table -> box, +z)
    np.testing.assert_allclose(on_box.normals, np.tile([0, 0, 1.0], (len(on_box), 1)),
                               atol=1e-6)
    np.testing.assert_allclose(cf.net_force_on(box), [0, 0, 0.3 * G], atol=1e-3)
    assert (on_box.penetration >= 0).all() and (on_box.penetration < 2e-3).all()
    assert all(c.body2 == "box" for c in on_box.items())


def test_hand_object_contacts_put_the_hand_first_with_jacobians() -> None:
    spec = ScenarioSpec(object_kind="box", object_mass=0.2)
    runner = LockstepRunner(spec)
    w = runner.world
    w.set_initial_state(runner.plan.q_grasp)  # pads 3 mm inside the faces
    w.step(1)
    cf = w.contacts("box", jacobians=True)
    assert len(cf) >= 2 and {"thumb_distal", "index_distal"} <= set(cf.body1)
    centre = w.object_pose("box").position
    # normals point from the hand into the object; forces push the object (same direction)
    assert (np.einsum("kj,kj->k", cf.normals, centre - cf.points) > 0).all()
    assert (np.einsum("kj,kj->k", cf.normals, cf.forces) > 0).all()
    assert cf.jacp.shape == (len(cf), 3, 27) and cf.jacr.shape == (len(cf), 3, 27)
    # the translational Jacobian's root columns are the identity (slides along world x, y, z)
    np.testing.assert_allclose(cf.jacp[:, :, :3], np.tile(np.eye(3), (len(cf), 1, 1)),
                               atol=1e-9)
    cs = cf.to_contact_set()
    assert len(cs) == len(cf) and cs.nv == 27


def test_instability_guard_raises_with_the_dof_on_a_huge_torque() -> None:
    world, _, _ = build_world(load_scenario("lift_box"))
    world.step(10)
    # (finger servos clip their torque to the motor range; an applied force is not clipped)
    # (a huge force couples into other DoFs through the mass matrix; MuJoCo names the first
    # bad one, so the push goes on the first DoF)
    k = world.joint_names.index("root_tx")
    world.data.qfrc_applied[world.dof_adr[k]] = 1e14  # injected past set_command's checks
    with pytest.raises(SimulationError, match="DoF 0 \\(joint 'root_tx'\\)"):
        world.step(50)
    div = world.divergences[-1]
    assert div.joint == "root_tx" and div.dof == 0 and div.action == "raise"


def test_instability_guard_reports_badqacc_from_nan_and_resets_when_configured() -> None:
    world, obj, _ = build_world(load_scenario("lift_box"), SimConfig(on_instability="reset"))
    q0 = world.data.qpos.copy()
    world.step(20)
    dof = world.objects[obj.name]["dof"]
    world.data.qfrc_applied[dof + 2] = np.nan  # a NaN force on the box's z DoF
    world.step(1)
    div = world.divergences[-1]  # (the NaN spreads over the box's 6 DoFs; the first is named)
    assert div.kind == "BADQACC" and dof <= div.dof < dof + 6 and div.joint == "box_free"
    assert world.resets == 1 and world.time == 0.0
    np.testing.assert_allclose(world.data.qpos, q0)
    world.step(100)  # and it goes on cleanly
    assert world.resets == 1


def test_nan_or_wrong_length_commands_never_reach_the_servos() -> None:
    world, _, _ = build_world(load_scenario("lift_box"))
    before = world.target.copy()
    with pytest.raises(InputError):
        world.set_command(np.full(27, np.nan))
    with pytest.raises(InputError):
        world.set_command(np.zeros(5))
    np.testing.assert_array_equal(world.target, before)


def test_unknown_joint_names_in_a_command_are_rejected_whole() -> None:
    world, _, _ = build_world(load_scenario("lift_box"))
    before = world.target.copy()
    with pytest.raises(InputError, match="no_such_joint"):
        world.command_by_name(["index_pip_flex", "no_such_joint"], [0.5, 0.1])
    with pytest.raises(InputError):
        world.command_by_name(["index_pip_flex"], [0.5, 0.6])
    np.testing.assert_array_equal(world.target, before)
    world.command_by_name(["index_pip_flex"], [0.5], [0.01])
    k = world.joint_names.index("index_pip_flex")
    assert world.target[k] == 0.5 and world.effort[k] == 0.01
    assert np.count_nonzero(world.target != before) == 1


@pytest.mark.parametrize("mode", ["zero", "hold"])
def test_command_timeout_holds_the_last_targets(mode) -> None:
    world, _, _ = build_world(load_scenario("lift_box"),
                              SimConfig(command_timeout=0.05, timeout_effort=mode))
    k = world.joint_names.index("index_pip_flex")
    target = world.target.copy()
    target[k] = 0.9
    effort = np.zeros(27)
    effort[k] = 0.05
    world.set_command(target, effort)
    world.step(40)
    assert not world.timed_out
    world.step(400)  # no command for 0.44 s
    assert world.timed_out
    np.testing.assert_array_equal(world.target, target)  # held
    q, _ = world.hand_state()
    assert q[k] == pytest.approx(0.9, abs=0.05)
    assert world.effort[k] == (0.0 if mode == "zero" else 0.05)
    world.set_command(target, effort)
    assert not world.timed_out


def test_grasp_ik_puts_the_fingertip_pads_on_the_surface() -> None:
    for name in ("lift_box", "lift_ball", "lift_cylinder"):
        runner = LockstepRunner(load_scenario(name))
        assert runner.plan.residual.max() < 6e-3, name
        assert runner.plan.fingers[0] == "thumb"
        # the thumb opposes the fingers: its normal points against theirs
        n = runner.plan.normals
        assert (n[1:] @ n[0] < -0.5).all(), name
        assert runner.feasibility()


def test_composite_lift_keeps_a_heavy_box_in_hand_while_pd_only_drops_it() -> None:
    from hand_control.bench._grasp_grid import grid_spec

    spec = grid_spec("box", 1.0, 0.3, quick=True)
    results = {}
    plan = None
    for mode in ("composite", "pd_only"):
        r = LockstepRunner(spec, gains=CompositeControlConfig(mode=mode),
                           control_every=2, plan=plan)
        plan = r.plan
        results[mode] = r.run()
    assert results["composite"].success, results["composite"]
    assert results["composite"].object_lift_mm > 60
    assert not results["pd_only"].success
    assert results["pd_only"].object_lift_mm < 20
    assert results["composite"].divergences == 0


def test_parameter_files_fill_the_config_dataclasses() -> None:
    from hand_capture.config import load_node_params
    from hand_control.sim.config import SimNodeConfig

    root = __import__("pathlib").Path(__file__).resolve().parents[1] / "config"
    sim = load_node_params(SimConfig, root / "sim.yaml", "sim")
    node = load_node_params(SimNodeConfig, root / "sim.yaml", "sim")
    ctrl = load_node_params(ControllerNodeConfig, root / "controller.yaml", "controller")
    gains = load_node_params(CompositeControlConfig, root / "controller.yaml", "controller")
    assert sim.timestep == 0.001 and sim.real_time and node.publish_clock
    assert ctrl.reference == "scripted"
    assert gains.mode == "composite" and gains.alpha3 == 1e-3 and gains.method == "dissertation"
    assert gains == CompositeControlConfig()  # the YAML states the defaults, one source
    # the sim's servos and the controller get the same PD gains
    servo = load_node_params(CompositeControlConfig, root / "sim.yaml", "sim")
    assert (servo.joint_kp, servo.joint_kd) == (gains.joint_kp, gains.joint_kd)
    for name in scenario_names():
        load_scenario(name)


def test_controller_core_falls_back_to_pd_only_and_never_outputs_nan(monkeypatch) -> None:
    from hand_control.contact.qp import ContactForceResult

    runner = LockstepRunner(load_scenario("lift_box"))
    w, core = runner.world, runner.core
    w.set_initial_state(runner.plan.q_grasp)
    w.step(5)
    q, qd = w.hand_state()
    op = w.object_pose("box")
    state = (op.position, op.quaternion, op.linear_velocity, op.angular_velocity)
    cf = w.contacts("box")
    t = runner.reference.t_lift0 + 0.1  # grasp torques on
    args = (cf.body1, cf.points, cf.normals, cf.forces, cf.friction)
    ok = core.step(t, q, qd, state, *args)  # Jacobians from the kinematic copy
    assert not ok.pd_only and np.abs(ok.efforts).max() > 0 and len(ok.planned_forces)
    # NaN in the contacts: rejected, PD only, finite
    bad_normals = cf.normals.copy()
    bad_normals[0, 0] = np.nan
    cmd = core.step(t, q, qd, state, cf.body1, cf.points, bad_normals, cf.forces, cf.friction)
    assert cmd.pd_only and not cmd.efforts.any() and np.isfinite(cmd.positions).all()
    assert core.counters["rejected_inputs"] == 1
    # the QP finds nothing: PD only, counted
    k = len(cf)
    failed = ContactForceResult(False, "max_iter", np.zeros((k, 3)), np.zeros(k), np.zeros(6),
                                1.0, 0.0, 0.0, "dissertation")
    monkeypatch.setattr(core.controller.qp, "solve", lambda *a, **kw: failed)
    cmd = core.step(t, q, qd, state, *args)
    assert cmd.pd_only and not cmd.efforts.any()
    assert core.counters["qp_fallbacks"] == 1


def test_friction_sweep_holds_down_to_0_2_and_the_box_slips_out_at_0_01() -> None:
    # seed 000 sec. 7.2: 0.75 -> 0.3 -> 0.2 -> 0.01, shortened
    spec = load_scenario("friction_sweep").with_(
        t_reach=0.3, t_close=0.4, t_settle=0.2, t_lift=0.5, t_carry=0.0, t_hold=1.4,
        carry_offset=(0.0, 0.0, 0.0), friction_schedule=(1.5, 0.3, 1.8, 0.2, 2.3, 0.01))
    res = LockstepRunner(spec, control_every=2).run(trace=True)
    t, z = res.trace["t"], res.trace["pos"][:, 2]
    z_rest = 0.0285
    held = (t > 1.5) & (t < 2.3)  # mu = 0.3, then 0.2
    assert (z[held] > z_rest + 0.07).all()
    assert z[-1] < z_rest + 0.01  # at mu = 0.01 it fell back onto the table
    assert not res.success
