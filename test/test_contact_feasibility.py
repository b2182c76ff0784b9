"""Dynamic feasibility LP of dissertation eq. (III.10)-(III.16)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hand_control.contact import ContactSet, dynamic_feasibility
from hand_control.errors import InputError

G = np.array([0.0, 0.0, -9.81])
MASS = 0.2


def assert_balanced(contacts, res, com=(0.0, 0.0, 0.0), acc=(0.0, 0.0, 0.0)):
    """The returned forces satisfy (III.11), (III.12) and lie in the friction cones."""
    com, acc = np.asarray(com), np.asarray(acc)
    np.testing.assert_allclose(res.forces.sum(0), MASS * (acc - G), atol=1e-7)
    torque = np.cross(contacts.points - com, res.forces).sum(0)
    np.testing.assert_allclose(torque, 0.0, atol=1e-7)
    fn = np.einsum("kj,kj->k", res.forces, contacts.normals)
    np.testing.assert_allclose(fn, res.normal_forces, atol=1e-12)
    ft = np.linalg.norm(res.forces - fn[:, None] * contacts.normals, axis=1)
    assert np.all(fn >= -1e-9) and np.all(ft <= contacts.mu * fn + 1e-7)


@pytest.mark.parametrize("mu", [0.3, 0.5, 1.0])
def test_antipodal_pinch_is_feasible_with_margin_mu(mu):
    contacts = ContactSet([[-0.03, 0, 0], [0.03, 0, 0]], [[1, 0, 0], [-1, 0, 0]], mu)
    res = dynamic_feasibility(contacts, MASS, np.zeros(3))
    assert res.feasible and res.status == "optimal"
    assert_balanced(contacts, res)
    # each finger carries half the weight by friction: total squeeze W / mu
    assert res.normal_forces.sum() == pytest.approx(MASS * 9.81 / mu, rel=1e-7)
    assert res.margin == pytest.approx(mu, rel=1e-7)


def test_three_finger_grasp_with_offset_com_is_feasible():
    pts = np.array([[-0.03, 0, 0], [0.03, 0.02, 0], [0.03, -0.02, 0]])
    contacts = ContactSet(pts, [[1, 0, 0], [-1, 0, 0], [-1, 0, 0]], 0.8)
    com = np.array([0.0, 0.005, 0.0])
    res = dynamic_feasibility(contacts, MASS, com)
    assert res.feasible
    assert_balanced(contacts, res, com)


def test_support_from_below_carries_the_load_by_normal_force():
    contacts = ContactSet([[0, 0, -0.03]], [[0, 0, 1]], 0.5)
    res = dynamic_feasibility(contacts, MASS, np.zeros(3))
    assert res.feasible and res.margin == pytest.approx(1.0)
    np.testing.assert_allclose(res.forces, [[0, 0, MASS * 9.81]], atol=1e-9)


def test_desired_acceleration_is_part_of_the_load():
    contacts = ContactSet([[0, 0, -0.03]], [[0, 0, 1]], 0.5)
    acc = np.array([0.0, 0.0, 2.0])
    res = dynamic_feasibility(contacts, MASS, np.zeros(3), acceleration=acc)
    assert res.feasible
    assert_balanced(contacts, res, acc=acc)
    # sideways acceleration beyond the friction of a single support is infeasible
    assert not dynamic_feasibility(contacts, MASS, np.zeros(3), acceleration=[9.0, 0, 0]).feasible


@pytest.mark.parametrize("points,normals,mu", [
    ([[-0.03, 0, 0]], [[1, 0, 0]], 0.5),  # a single contact from the side
    ([[0.01, 0, -0.03]], [[0, 0, 1]], 0.5),  # a single support beside the COM: it tips over
    ([[-0.03, 0.01, 0], [-0.03, -0.01, 0]], [[1, 0, 0], [1, 0, 0]], 0.1),  # one side only
    ([[-0.03, 0.01, 0], [-0.03, -0.01, 0]], [[1, 0, 0], [1, 0, 0]], 2.0),  # even with friction
    ([[-0.03, 0, 0], [0.03, 0, 0]], [[1, 0, 0], [-1, 0, 0]], 0.0),  # frictionless pinch
])
def test_bad_grasps_are_infeasible(points, normals, mu):
    res = dynamic_feasibility(ContactSet(points, normals, mu), MASS, np.zeros(3))
    assert not res.feasible and res.status == "infeasible"
    assert res.margin == 0.0
    np.testing.assert_array_equal(res.forces, 0.0)


def test_more_friction_edges_never_lose_feasibility():
    contacts = ContactSet([[-0.03, 0, 0], [0.03, 0, 0]], [[1, 0, 0], [-1, 0, 0]], 0.5)
    for edges in (4, 8, 16):
        assert dynamic_feasibility(contacts, MASS, np.zeros(3), friction_edges=edges).feasible


def test_no_contacts_and_no_load():
    empty = ContactSet(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    assert dynamic_feasibility(empty, MASS, np.zeros(3)).status == "no_contacts"
    free_fall = dynamic_feasibility(empty, MASS, np.zeros(3), acceleration=G)
    assert free_fall.feasible and free_fall.status == "no_load" and math.isinf(free_fall.margin)


@pytest.mark.parametrize("kwargs", [
    dict(mass=0.0), dict(mass=-1.0), dict(mass=math.nan), dict(com=[0, 0]),
    dict(com=[0, 0, math.inf]), dict(gravity=[0, -9.81]), dict(acceleration=[0, 0, math.nan]),
    dict(friction_edges=3),
])
def test_bad_input_raises_input_error(kwargs):
    contacts = ContactSet([[0, 0, -0.03]], [[0, 0, 1]], 0.5)
    args = dict(mass=MASS, com=np.zeros(3)) | kwargs
    with pytest.raises(InputError):
        dynamic_feasibility(contacts, **args)


# -- joint torque limits through the contact Jacobians -------------------------------------

def cartesian_pinch(mu: float) -> ContactSet:
    """Antipodal pinch by two Cartesian fingers (3 orthogonal prismatic joints each): the
    contact Jacobian of finger i is the identity on its own three joints, so a joint's torque
    limit bounds one force component [N]."""
    jacp = np.zeros((2, 3, 6))
    jacp[0, :, 0:3] = np.eye(3)
    jacp[1, :, 3:6] = np.eye(3)
    return ContactSet([[-0.03, 0, 0], [0.03, 0, 0]], [[1, 0, 0], [-1, 0, 0]], mu, jacp=jacp)


def test_torque_limits_bound_the_squeeze():
    """Each finger needs normal force W / (2 mu) (1.962 N for 0.2 kg at mu 0.5): feasible with
    3 N per joint, infeasible with 1.5 N (status 'torque_limits': the cones alone could hold
    it), and the unbounded LP of the dissertation says yes to any mass."""
    contacts = cartesian_pinch(0.5)
    ok = dynamic_feasibility(contacts, MASS, np.zeros(3), torque_limits=np.full(6, 3.0))
    assert ok.feasible and ok.status == "optimal"
    assert_balanced(contacts, ok)
    tau = np.einsum("kjv,kj->v", contacts.jacp, ok.forces)
    np.testing.assert_allclose(ok.joint_torques, tau, atol=1e-9)
    assert np.abs(tau).max() <= 3.0 + 1e-9
    weak = dynamic_feasibility(contacts, MASS, np.zeros(3), torque_limits=np.full(6, 1.5))
    assert not weak.feasible and weak.status == "torque_limits"
    heavy = dynamic_feasibility(contacts, 50.0, np.zeros(3), torque_limits=np.full(6, 3.0))
    assert not heavy.feasible
    assert dynamic_feasibility(contacts, 50.0, np.zeros(3)).feasible  # no limits: says yes
    # an unlimited joint (inf) does not constrain: the normal joints (x) carry the squeeze
    lim = np.array([3.0, 1.5, 1.5, 3.0, 1.5, 1.5])
    assert dynamic_feasibility(contacts, 0.25, np.zeros(3), torque_limits=lim).feasible
    lim[[2, 5]] = 0.5  # the vertical joints must carry W / 2 = 1.23 N each
    assert not dynamic_feasibility(contacts, 0.25, np.zeros(3), torque_limits=lim).feasible
    lim[[2, 5]] = np.inf
    assert dynamic_feasibility(contacts, 0.25, np.zeros(3), torque_limits=lim).feasible


@pytest.mark.parametrize("bad", [np.full(5, 1.0), np.full(6, -1.0), np.full(6, np.nan)])
def test_bad_torque_limits_raise_input_error(bad):
    with pytest.raises(InputError):
        dynamic_feasibility(cartesian_pinch(0.5), MASS, np.zeros(3), torque_limits=bad)


def test_torque_limits_need_jacobians():
    contacts = ContactSet([[-0.03, 0, 0], [0.03, 0, 0]], [[1, 0, 0], [-1, 0, 0]], 0.5)
    with pytest.raises(InputError, match="Jacobians"):
        dynamic_feasibility(contacts, MASS, np.zeros(3), torque_limits=np.ones(6))


def test_grid_cell_beyond_the_hand_is_infeasible():
    """The lift-and-carry grid's planned grasp of the box, with the simulated hand's actuator
    limits: 0.2 kg at mu 0.5 is feasible; 8 kg at mu 0.3 (the grid's heavy cell) is not, the
    fingers cannot press hard enough; without the limits the LP said yes to both."""
    from hand_control.bench._grasp_grid import HEAVY_MASS, grasp_feasibility, grid_spec
    from hand_control.sim.lockstep import LockstepRunner

    runner = LockstepRunner(grid_spec("box", 0.2, 0.5, quick=True))
    light = grasp_feasibility(runner)
    assert light.feasible, light.status
    heavy = grasp_feasibility(runner, mu=0.3, mass=HEAVY_MASS)
    assert not heavy.feasible and heavy.status == "torque_limits"
    # the LP as printed (no force bounds) says yes to the same contacts
    pose = runner.world.object_pose(runner.obj.name).position
    assert dynamic_feasibility(runner.plan.contact_set(0.3), HEAVY_MASS, pose).feasible
