"""The lockstep fast path (contacts with Jacobians straight from the world, trusted inputs)
against the plain path (checked inputs, Jacobians from the controller's own kinematics)."""

from __future__ import annotations

import mujoco
import numpy as np

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
