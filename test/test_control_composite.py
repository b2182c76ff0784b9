"""Composite controller (seed 000 eq. 8-13, dissertation eq. III.19-III.23)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hand_capture.model.joints import JOINT_NAMES
from hand_control.contact import ContactForceQP, ContactSet
from hand_control.control import (
    CompositeControlConfig,
    CompositeController,
    ObjectState,
    ObjectTarget,
    grasp_torques,
    object_virtual_wrench,
    quaternion_error,
)
from hand_control.errors import InputError

NV = len(JOINT_NAMES)
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


# -- Jacobian transpose (eq. 12 / III.21) against virtual work ------------------------------

LINKS = np.array([0.045, 0.025, 0.02])  # a planar three-phalanx finger in the xy plane


def fingertip(q: np.ndarray) -> tuple[np.ndarray, float]:
    """Tip position and orientation angle (about z) of the planar finger."""
    angles = np.cumsum(q)
    p = np.array([np.sum(LINKS * np.cos(angles)), np.sum(LINKS * np.sin(angles)), 0.0])
    return p, float(angles[-1])


def numeric_jacobians(q: np.ndarray, eps: float = 1e-7) -> tuple[np.ndarray, np.ndarray]:
    jp, jr = np.zeros((3, q.size)), np.zeros((3, q.size))
    for i in range(q.size):
        dq = np.zeros(q.size)
        dq[i] = eps
        (p1, a1), (p0, a0) = fingertip(q + dq), fingertip(q - dq)
        jp[:, i] = (p1 - p0) / (2 * eps)
        jr[2, i] = (a1 - a0) / (2 * eps)
    return jp, jr


def test_grasp_torques_satisfy_the_virtual_work_identity():
    """tau . dq = f . dp + (l n) . dtheta for a small joint motion dq (finite differences)."""
    rng = np.random.default_rng(0)
    for _ in range(10):
        q = rng.uniform(0.0, 1.2, 3)
        jp, jr = numeric_jacobians(q)
        normal = np.array([0.0, 0.0, 1.0])  # torsion about z: the finger's own rotation axis
        contacts = ContactSet(fingertip(q)[0][None], normal[None], 0.5, jacp=jp[None],
                              jacr=jr[None])
        f, l_ = rng.standard_normal((1, 3)), rng.standard_normal(1)
        tau = grasp_torques(contacts, f, l_)
        dq, eps = rng.standard_normal(3), 1e-6
        (p1, a1), (p0, a0) = fingertip(q + eps * dq), fingertip(q - eps * dq)
        work = f[0] @ (p1 - p0) / (2 * eps) + l_[0] * (a1 - a0) / (2 * eps)
        assert tau @ dq == pytest.approx(work, rel=1e-6, abs=1e-9)


def test_grasp_torques_sum_over_contacts():
    rng = np.random.default_rng(1)
    k, nv = 4, 9
    jp, jr = rng.standard_normal((k, 3, nv)), rng.standard_normal((k, 3, nv))
    normals = rng.standard_normal((k, 3))
    contacts = ContactSet(rng.standard_normal((k, 3)), normals, 0.5, jacp=jp, jacr=jr)
    f, l_ = rng.standard_normal((k, 3)), rng.standard_normal(k)
    dq = rng.standard_normal(nv)
    work = sum(f[i] @ jp[i] @ dq + l_[i] * contacts.normals[i] @ jr[i] @ dq for i in range(k))
    assert grasp_torques(contacts, f, l_) @ dq == pytest.approx(work, rel=1e-12)


def test_grasp_torques_need_both_jacobians():
    contacts = ContactSet([[0, 0, 0]], [[1, 0, 0]], 0.5, jacp=np.zeros((1, 3, 4)))
    with pytest.raises(InputError, match="Jacobians"):
        grasp_torques(contacts, np.zeros((1, 3)), np.zeros(1))


# -- virtual object wrench (eq. 9 / III.22) ------------------------------------------------

def test_quaternion_error_matches_scipy_rotation_vectors():
    rng = np.random.default_rng(2)
    for _ in range(50):
        rt, rc = Rotation.random(random_state=rng), Rotation.random(random_state=rng)
        qt, qc = np.roll(rt.as_quat(), 1), np.roll(rc.as_quat(), 1)  # (w, x, y, z)
        expected = (rt * rc.inv()).as_rotvec()
        np.testing.assert_allclose(quaternion_error(qt, qc), expected, atol=1e-9)
        np.testing.assert_allclose(quaternion_error(-qt, qc), expected, atol=1e-9)  # same rotation
    np.testing.assert_allclose(quaternion_error(IDENTITY, IDENTITY), 0.0)


def test_object_virtual_wrench_is_a_pd_on_the_object_pose():
    cfg = CompositeControlConfig()
    angle = 0.3
    target = ObjectTarget([0.0, 0.0, 0.12], [math.cos(angle / 2), 0, 0, math.sin(angle / 2)])
    state = ObjectState([0.0, 0.0, 0.10], IDENTITY, [0.0, 0.0, 0.4], [0.0, 0.2, 0.0], 0.2)
    f_v, tau_v = object_virtual_wrench(cfg, state, target)
    # Table III.1: object kp = 5, kd = 0.5 for translation and rotation
    np.testing.assert_allclose(f_v, [0, 0, 5.0 * 0.02 - 0.5 * 0.4])
    np.testing.assert_allclose(tau_v, [0, -0.5 * 0.2, 5.0 * angle], atol=1e-12)


# -- the controller ------------------------------------------------------------------------

def pinch_contacts(nv: int = NV, seed: int = 3, forces: bool = False) -> ContactSet:
    rng = np.random.default_rng(seed)
    return ContactSet(
        [[-0.03, 0, 0], [0.03, 0, 0]], [[1, 0, 0], [-1, 0, 0]], [0.6, 0.7],
        forces=[[1.0, 0, 0.5], [-1.0, 0, 0.5]] if forces else None,
        jacp=rng.standard_normal((2, 3, nv)), jacr=rng.standard_normal((2, 3, nv)),
    )


def states(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return rng.uniform(-0.5, 0.5, NV), rng.uniform(-1, 1, NV), rng.uniform(-0.5, 0.5, NV)


HELD = ObjectState([0.0, 0.0, 0.1], IDENTITY, np.zeros(3), np.zeros(3), 0.2)
AT_TARGET = ObjectTarget([0.0, 0.0, 0.1], IDENTITY)


def test_pd_servos_use_the_table_gains():
    ctrl = CompositeController()
    q, qd, qt = states(np.random.default_rng(4))
    gravity = np.linspace(-0.1, 0.1, NV)
    out = ctrl.compute(q, qd, qt, gravity_torques=gravity)
    i = JOINT_NAMES.index("index_pip_flex")  # index2: kp 3.0, kd 0.1
    assert out.tau_pd[i] == pytest.approx(3.0 * (qt[i] - q[i]) - 0.1 * qd[i])
    i = JOINT_NAMES.index("root_tz")  # root translate: kp 400, kd 50
    assert out.tau_pd[i] == pytest.approx(400.0 * (qt[i] - q[i]) - 50.0 * qd[i])
    np.testing.assert_allclose(out.tau, out.tau_pd + gravity)
    assert not out.grasp_active and not out.fallback and out.qp is None
    np.testing.assert_array_equal(out.tau_grasp, 0.0)


@pytest.mark.parametrize("method", ["dissertation", "seed000"])
def test_composite_torques_are_pd_plus_gravity_plus_grasp(method):
    qp_cfg = CompositeControlConfig(method=method)  # gains and QP settings: one config
    ctrl = CompositeController(qp_cfg)
    contacts = pinch_contacts(forces=True)
    q, qd, qt = states(np.random.default_rng(5))
    gravity = np.full(NV, 0.01)
    out = ctrl.compute(q, qd, qt, HELD, AT_TARGET, contacts, gravity)
    assert out.grasp_active and not out.fallback and out.qp.found
    # at the target and at rest, the contacts are asked for the weight only (eq. 9)
    np.testing.assert_allclose(out.force_target, [0, 0, 0.2 * 9.81])
    np.testing.assert_allclose(out.torque_target, 0.0)
    ref = ContactForceQP(qp_cfg).solve(contacts, HELD.position, out.force_target,
                                       out.torque_target)
    np.testing.assert_allclose(out.qp.forces, ref.forces, atol=1e-12)
    np.testing.assert_allclose(out.tau_grasp, grasp_torques(contacts, ref.forces, ref.torsion))
    np.testing.assert_allclose(out.tau, out.tau_pd + gravity + out.tau_grasp)  # eq. (13)
    assert np.abs(out.tau_grasp).max() > 0
    assert (ctrl.steps, ctrl.grasp_steps, ctrl.fallbacks) == (1, 1, 0)


def test_failed_qp_falls_back_to_pd_only_and_is_counted():
    ctrl = CompositeController(CompositeControlConfig(max_iter=1))
    q, qd, qt = states(np.random.default_rng(6))
    for step in range(3):
        out = ctrl.compute(q, qd, qt, HELD, AT_TARGET, pinch_contacts())
        assert out.fallback and not out.grasp_active
        assert not out.qp.found and out.qp.status == "max_iter"
        np.testing.assert_array_equal(out.tau_grasp, 0.0)
        np.testing.assert_allclose(out.tau, out.tau_pd)
        assert np.isfinite(out.tau).all()
        assert ctrl.fallbacks == step + 1
    assert (ctrl.steps, ctrl.grasp_steps) == (3, 0)


@pytest.mark.parametrize("case", ["pd_only", "closing", "no_contacts", "no_object"])
def test_no_grasp_attempt(case):
    cfg = CompositeControlConfig(mode="pd_only" if case == "pd_only" else "composite")
    ctrl = CompositeController(cfg)
    q, qd, qt = states(np.random.default_rng(7))
    contacts = pinch_contacts()
    if case == "no_contacts":
        contacts = ContactSet(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    out = ctrl.compute(q, qd, qt, None if case == "no_object" else HELD, AT_TARGET, contacts,
                       grasp=case != "closing")
    assert not out.grasp_active and not out.fallback and out.qp is None
    np.testing.assert_allclose(out.tau, out.tau_pd)
    assert ctrl.fallbacks == 0 and ctrl.grasp_steps == 0


def test_gravity_compensation_can_be_switched_off():
    ctrl = CompositeController(CompositeControlConfig(gravity_compensation=False))
    q, qd, qt = states(np.random.default_rng(8))
    out = ctrl.compute(q, qd, qt, gravity_torques=np.ones(NV))
    np.testing.assert_array_equal(out.tau_gravity, 0.0)
    np.testing.assert_allclose(out.tau, out.tau_pd)


@pytest.mark.parametrize("bad", ["nan_q", "short_qd", "inf_target", "gravity_len",
                                 "no_jacobians", "jacobian_nv"])
def test_bad_input_raises_input_error(bad):
    ctrl = CompositeController()
    q, qd, qt = states(np.random.default_rng(9))
    contacts, gravity = pinch_contacts(), None
    if bad == "nan_q":
        q[3] = np.nan
    elif bad == "short_qd":
        qd = qd[:-1]
    elif bad == "inf_target":
        qt[0] = np.inf
    elif bad == "gravity_len":
        gravity = np.zeros(NV + 1)
    elif bad == "no_jacobians":
        contacts = ContactSet(contacts.points, contacts.normals, contacts.mu)
    elif bad == "jacobian_nv":
        contacts = pinch_contacts(nv=NV - 6)
    with pytest.raises(InputError):
        ctrl.compute(q, qd, qt, HELD, AT_TARGET, contacts, gravity)
    assert ctrl.steps == 0


@pytest.mark.parametrize("bad", [
    dict(position=[0, 0]), dict(quaternion=[0, 0, 0, 0]), dict(quaternion=[1, 0, 0]),
    dict(linear_velocity=[0, math.nan, 0]), dict(mass=0.0), dict(mass=math.inf),
])
def test_bad_object_state_raises_input_error(bad):
    args = dict(position=np.zeros(3), quaternion=IDENTITY, linear_velocity=np.zeros(3),
                angular_velocity=np.zeros(3), mass=0.2) | bad
    with pytest.raises(InputError):
        ObjectState(**args)


def test_controller_on_a_subset_of_joints():
    names = ("index_mcp_abd", "index_mcp_flex", "index_pip_flex", "index_dip_flex")
    ctrl = CompositeController(joint_names=names)
    np.testing.assert_array_equal(ctrl.kp, [4.0, 4.0, 3.0, 2.0])
    np.testing.assert_array_equal(ctrl.kd, [0.2, 0.2, 0.1, 0.1])
    out = ctrl.compute(np.zeros(4), np.zeros(4), np.ones(4), HELD, AT_TARGET,
                       pinch_contacts(nv=4))
    assert out.grasp_active and out.tau.shape == (4,)
