"""The lockstep fast paths against the plain ones: contacts with Jacobians straight from the
world (trusted inputs) against checked inputs with Jacobians from the controller's own
kinematics, and ControllerCore.step_world (lean contacts, the QP on arrays, mj_applyFT)
against ControllerCore.step."""

from __future__ import annotations

from dataclasses import fields

import mujoco
import numpy as np
import pytest

from hand_control.contact.qp import ContactForceResult
from hand_control.control import Command
from hand_control.errors import InputError
from hand_control.sim.lockstep import LockstepRunner
from hand_control.sim.scenario import ScenarioSpec


def _grasping_runner() -> LockstepRunner:
    runner = LockstepRunner(ScenarioSpec(object_kind="box", object_mass=0.2))
    w = runner.world
    w.set_initial_state(runner.plan.q_grasp)  # pads 3 mm inside the faces
    w.step(2)
    return runner


def test_contact_jacobians_are_contiguous_and_match_mj_jac() -> None:
    runner = _grasping_runner()
    w = runner.world
    cf = w.contacts("box", jacobians=True, forces=False)
    assert len(cf) >= 2
    assert cf.jacp.flags.c_contiguous and cf.jacr.flags.c_contiguous
    m, d = w.model, w.data
    jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for k in range(len(cf)):
        mujoco.mj_jac(m, d, jp, jr, cf.points[k], int(cf.body1_id[k]))
        np.testing.assert_array_equal(cf.jacp[k], jp[:, w.dof_adr])
        np.testing.assert_array_equal(cf.jacr[k], jr[:, w.dof_adr])
    # the frame owns its arrays: the next step does not rewrite them
    before = cf.jacp.copy(), cf.points.copy()
    w.step(1)
    np.testing.assert_array_equal(cf.jacp, before[0])
    np.testing.assert_array_equal(cf.points, before[1])
    # the same bodies, points and normals as the frame with forces
    full = w.contacts("box", jacobians=True)
    assert full.body1 == w.contacts("box", forces=False).body1


def test_lockstep_step_matches_the_checked_path() -> None:
    runner = _grasping_runner()
    w, core = runner.world, runner.core
    t = runner.reference.t_carry0  # grasp torques on
    # after mj_step the kinematics are those of the step's start; the controller's own
    # kinematics (plain path) use the current q: make the two agree
    mujoco.mj_forward(w.model, w.data)
    cf = w.contacts(runner.obj.name, jacobians=True, forces=False)
    q, qd = w.hand_state()
    pos, quat, vel, omega_body, rot = runner._obj_views
    pose = (pos.copy(), quat.copy(), vel.copy(), rot.dot(omega_body))
    fast = core.step(t, q, qd, pose, cf.body1, cf.points, cf.normals, cf.forces, cf.friction,
                     contact_set=cf.to_contact_set(trusted=True), trusted=True)
    core.controller.qp._passive.clear()  # the same (cold) start for both
    plain = core.step(t, q.copy(), qd.copy(), pose, list(cf.body1), cf.points.copy(),
                      cf.normals.copy(), cf.forces.copy(), cf.friction.copy())
    assert not fast.pd_only and not plain.pd_only
    np.testing.assert_allclose(fast.efforts, plain.efforts, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(fast.positions, plain.positions)
    np.testing.assert_allclose(fast.planned_forces, plain.planned_forces, rtol=1e-9,
                               atol=1e-12)


def _short(name: str):
    from hand_control.sim.scenario import load_scenario

    return load_scenario(name).with_(t_reach=0.3, t_close=0.3, t_settle=0.1, t_lift=0.3,
                                     t_carry=0.3, t_hold=0.1)


@pytest.mark.parametrize("name", ["lift_box", "lift_cylinder"])
def test_step_world_matches_the_frame_path_at_every_step_of_an_episode(name: str) -> None:
    """ControllerCore.step_world (the lockstep loop: lean contacts, the QP on arrays, the
    Jacobian transpose by mj_applyFT about the centre of mass) against ControllerCore.step
    with the world's ContactFrame and its stacked Jacobians, on the same state at every step:
    the same targets and contacts, the same forces and efforts up to rounding."""
    runner = LockstepRunner(_short(name))
    w, core = runner.world, runner.core
    w.reset()
    q, qd = runner._hand_views
    pos, quat, vel, omega_body, rot = runner._obj_views
    grasp_steps = 0
    for _ in range(int(round(runner.reference.t_end / w.model.opt.timestep))):
        t = w.data.time
        if core.needs_contacts(t):
            cf = w.contacts(runner.obj.name, jacobians=True, forces=False)
            plain = core.step(t, q, qd, (pos, quat, vel, rot.dot(omega_body)), cf.body1,
                              cf.points, cf.normals, cf.forces, cf.friction,
                              contact_set=cf.to_contact_set(trusted=True) if len(cf) else None,
                              trusted=True)
            fast = core.step_world(t, w, runner._object_body, q, qd, runner._obj_views)
            assert fast.pd_only == plain.pd_only and fast.phase == plain.phase
            np.testing.assert_array_equal(fast.positions, plain.positions)
            assert fast.contact_bodies == plain.contact_bodies
            np.testing.assert_array_equal(fast.contact_points, plain.contact_points)
            np.testing.assert_array_equal(fast.contact_normals, plain.contact_normals)
            np.testing.assert_allclose(fast.efforts, plain.efforts, rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(fast.planned_forces, plain.planned_forces, rtol=1e-9,
                                       atol=1e-9)
            np.testing.assert_allclose(fast.planned_torsion, plain.planned_torsion,
                                       rtol=1e-9, atol=1e-9)
            grasp_steps += not fast.pd_only
        else:
            fast = core.step_world(t, w, runner._object_body, q, qd, runner._obj_views)
        assert set(fast.__dict__) == {f.name for f in fields(Command)}
        w.set_command(fast.positions, fast.efforts, check=False)
        w.step()
    assert grasp_steps > 300
    assert core.counters["qp_fallbacks"] == 0


def test_step_world_output_and_counters_are_those_of_step() -> None:
    runner = _grasping_runner()
    w, core = runner.world, runner.core
    t = runner.reference.t_carry0  # grasp torques on
    mujoco.mj_forward(w.model, w.data)
    q, qd = w.hand_state()
    pos, quat, vel, omega_body, rot = runner._obj_views
    cf = w.contacts(runner.obj.name, jacobians=True, forces=False)
    plain = core.step(t, q, qd, (pos, quat, vel, rot.dot(omega_body)), cf.body1, cf.points,
                      cf.normals, cf.forces, cf.friction,
                      contact_set=cf.to_contact_set(trusted=True), trusted=True)
    ref_out = core.last_output
    assert not plain.pd_only and ref_out.grasp_active
    steps, grasp_steps = core.controller.steps, core.controller.grasp_steps
    fast = core.step_world(t, w, runner._object_body, q, qd, runner._obj_views)
    out = core.last_output  # built from the step's ingredients
    assert (core.controller.steps, core.controller.grasp_steps) == (steps + 1, grasp_steps + 1)
    assert out.grasp_active and not out.fallback and out.qp.found
    for name in ("tau", "tau_pd", "tau_gravity", "tau_grasp", "force_target", "torque_target"):
        np.testing.assert_allclose(getattr(out, name), getattr(ref_out, name), rtol=1e-9,
                                   atol=1e-9, err_msg=name)
    np.testing.assert_allclose(out.tau_grasp, fast.efforts, rtol=0, atol=0)
    assert core.last_output is out  # built once
    # the QP finds nothing: PD only, counted as a fallback
    k = len(cf)
    failed = ContactForceResult(False, "max_iter", np.zeros((k, 3)), np.zeros(k), np.zeros(6),
                                1.0, 0.0, 0.0, "dissertation")
    qp = core.controller.qp
    qp.solve_arrays = lambda *a, **kw: failed
    cmd = core.step_world(t, w, runner._object_body, q, qd, runner._obj_views)
    assert cmd.pd_only and not cmd.efforts.any() and core.counters["qp_fallbacks"] == 1
    assert core.controller.fallbacks == 1 and core.last_output.fallback
    # bad input inside the QP: rejected, PD only

    def bad(*a, **kw):
        raise InputError("bad")

    qp.solve_arrays = bad
    cmd = core.step_world(t, w, runner._object_body, q, qd, runner._obj_views)
    assert cmd.pd_only and core.counters["rejected_inputs"] == 1
    del qp.solve_arrays
    # a non-finite hand target from outside: replaced by the state, counted
    target = runner.plan.q_grasp.copy()
    target[7] = np.nan
    core.hand_target_override = target
    cmd = core.step_world(t, w, runner._object_body, q, qd, runner._obj_views)
    assert cmd.pd_only and np.isfinite(cmd.positions).all()
    assert core.counters["non_finite_outputs"] == 1


def test_object_contacts_are_those_of_contacts() -> None:
    runner = _grasping_runner()
    w = runner.world
    k, points, normals, mu, hand = w.object_contacts(runner._object_body)
    cf = w.contacts(runner.obj.name, forces=False)
    assert k == len(cf) >= 2
    np.testing.assert_array_equal(points, cf.points)
    np.testing.assert_array_equal(normals, cf.normals)
    np.testing.assert_array_equal(mu, cf.friction)
    assert hand == cf.body1_id.tolist()
    assert w.object_contacts(w.objects[runner.obj.name]["body"] + 100)[0] == 0


def test_wrench_and_contact_torques_are_the_jacobian_transpose() -> None:
    """tau = sum_k Jp_k^T f_k + Jr_k^T (l_k n_k) (eq. 12), by mj_applyFT at the contact points
    and with each contact's wrench moved to the centre of mass."""
    runner = _grasping_runner()
    w = runner.world
    cf = w.contacts(runner.obj.name, jacobians=True, forces=False)
    k = len(cf)
    rng = np.random.default_rng(3)
    forces, torsion = rng.standard_normal((k, 3)), rng.standard_normal(k)
    com = runner._obj_views[0]
    expected = (forces.reshape(-1) @ cf.jacp.reshape(3 * k, -1)
                + (torsion[:, None] * cf.normals).reshape(-1) @ cf.jacr.reshape(3 * k, -1))
    at_points = w.contact_torques(cf.body1_id.tolist(), cf.points, forces, torsion, cf.normals)
    moment = np.cross(cf.points - com, forces) + torsion[:, None] * cf.normals
    at_com = w.wrench_torques(cf.body1_id.tolist(), com, np.hstack((forces, moment)))
    assert at_points.shape == at_com.shape == (w.n_hand,)
    np.testing.assert_allclose(at_points, expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(at_com, expected, rtol=1e-12, atol=1e-12)


def test_set_targets_is_set_command_with_zero_efforts() -> None:
    runner = _grasping_runner()
    w = runner.world
    target = runner.plan.q_grasp + 0.01
    w.set_command(target, 0.5 * w.effort_hi)  # any in-range efforts, replaced below
    w.set_targets(target.copy())
    ctrl, qfrc = w.data.ctrl.copy(), w.data.qfrc_applied.copy()
    w.set_command(target, np.zeros(w.n_hand))
    np.testing.assert_array_equal(ctrl, w.data.ctrl)
    np.testing.assert_array_equal(qfrc, w.data.qfrc_applied)
