"""Joint vocabulary, limits, pose validation and conversions (hand_capture.model.joints)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hand_capture.errors import InputError
from hand_capture.model import joints as J


def test_names_and_order() -> None:
    assert len(J.JOINT_NAMES) == 27
    assert J.JOINT_NAMES[:6] == J.ROOT_JOINTS
    assert J.JOINT_NAMES[6:11] == J.THUMB_JOINTS
    assert J.JOINT_NAMES[11:15] == ("index_mcp_abd", "index_mcp_flex", "index_pip_flex",
                                    "index_dip_flex")
    assert J.JOINT_NAMES[-1] == "little_dip_flex"
    assert J.ARTICULATED_JOINTS == J.JOINT_NAMES[6:]


def test_limits_table() -> None:
    lim = J.JOINT_LIMITS
    assert lim.shape == (27, 2)
    assert np.all(np.isinf(lim[:6]))
    assert np.all(lim[6:, 0] < lim[6:, 1])
    assert np.all(lim[6:, 0] <= 0.0) and np.all(lim[6:, 1] >= 0.0)  # zero pose is legal
    assert np.all(np.abs(lim[6:]) <= math.radians(110) + 1e-12)
    d = J.joint_limits_dict()
    assert d["index_pip_flex"] == pytest.approx((0.0, math.radians(110)))
    with pytest.raises(ValueError):
        lim[0, 0] = 1.0  # read-only


def test_clamp_and_within() -> None:
    rng = np.random.default_rng(0)
    q = rng.uniform(-4, 4, size=(50, 27))
    c = J.clamp_to_limits(q)
    assert np.all(J.within_limits(c))
    np.testing.assert_array_equal(c[:, :6], q[:, :6])  # root untouched
    inside = J.clamp_to_limits(J.clamp_to_limits(q))
    np.testing.assert_array_equal(inside, c)
    assert not np.all(J.within_limits(q))


@pytest.mark.parametrize("bad", [np.zeros(26), np.zeros((2, 28)), np.zeros((2, 3, 27)),
                                 "abc", [[1, 2], [3]]])
def test_validate_rejects_shapes(bad: object) -> None:
    with pytest.raises(InputError):
        J.validate_pose(bad)


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_validate_rejects_non_finite(value: float) -> None:
    q = np.zeros(27)
    q[12] = value
    with pytest.raises(InputError, match="index_mcp_flex"):
        J.validate_pose(q)
    with pytest.raises(InputError):
        J.clamp_to_limits(q)


def test_dict_roundtrip_and_unknown_names() -> None:
    rng = np.random.default_rng(1)
    q = rng.normal(size=27)
    d = J.pose_to_dict(q)
    assert list(d) == list(J.JOINT_NAMES)
    np.testing.assert_array_equal(J.pose_from_dict(d), q)
    partial = J.pose_from_dict({"index_pip_flex": 0.5})
    assert partial[J.JOINT_INDEX["index_pip_flex"]] == 0.5 and np.count_nonzero(partial) == 1
    with pytest.raises(InputError, match="unknown joint"):
        J.pose_from_dict({"index_pip": 0.5})
    with pytest.raises(InputError):
        J.pose_from_dict({"index_pip_flex": float("nan")})
    with pytest.raises(InputError):
        J.pose_from_dict({"index_pip_flex": "x"})
    q2 = J.pose_from_names(["thumb_ip_flex", "root_tz"], [0.3, 1.0], default=q)
    assert q2[J.JOINT_INDEX["thumb_ip_flex"]] == 0.3 and q2[2] == 1.0
    with pytest.raises(InputError):
        J.pose_from_names(["thumb_ip_flex"], [0.1, 0.2])
    with pytest.raises(InputError, match="duplicate"):
        J.pose_from_names(["thumb_ip_flex", "thumb_ip_flex"], [0.1, 0.2])
    with pytest.raises(InputError):
        J.pose_to_dict(np.zeros((2, 27)))


def test_root_rotation_conventions() -> None:
    rng = np.random.default_rng(2)
    ang = rng.uniform([-3, -1.4, -3], [3, 1.4, 3], size=(100, 3))
    r = J.root_rotation_matrix(ang)
    # intrinsic x-y-z: R = Rx @ Ry @ Rz
    a = ang[7]
    rx = J.root_rotation_matrix([a[0], 0, 0])
    ry = J.root_rotation_matrix([0, a[1], 0])
    rz = J.root_rotation_matrix([0, 0, a[2]])
    np.testing.assert_allclose(r[7], rx @ ry @ rz, atol=1e-12)
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", r, r), np.tile(np.eye(3), (100, 1, 1)),
                               atol=1e-12)
    np.testing.assert_allclose(J.root_angles_from_matrix(r), ang, atol=1e-9)
    q = J.quat_from_root_angles(ang)
    np.testing.assert_allclose(J.root_angles_from_quat(q), ang, atol=1e-9)
    np.testing.assert_allclose(J.quat_to_matrix(q), r, atol=1e-12)
    # MuJoCo's (w, x, y, z) order, one and many
    np.testing.assert_allclose(J.quat_wxyz_to_matrix(q[:, [3, 0, 1, 2]]), r, atol=1e-12)
    np.testing.assert_allclose(J.quat_wxyz_to_matrix(q[7, [3, 0, 1, 2]]), r[7], atol=1e-12)
    wxyz = J.matrix_to_quat_wxyz(r)
    np.testing.assert_array_equal(wxyz, q[:, [3, 0, 1, 2]])
    assert np.all(wxyz[:, 0] >= 0)
    np.testing.assert_allclose(J.quat_wxyz_to_matrix(J.matrix_to_quat_wxyz(r[7])), r[7],
                               atol=1e-12)
    # gimbal lock still reproduces the rotation
    lock = J.root_rotation_matrix([0.3, math.pi / 2, 0.4])
    np.testing.assert_allclose(J.root_rotation_matrix(J.root_angles_from_matrix(lock)), lock,
                               atol=1e-9)
    with pytest.raises(InputError):
        J.quat_to_matrix([0, 0, 0, 0])


def test_mirror_pose_is_an_involution() -> None:
    q = np.random.default_rng(3).normal(size=(4, 27))
    m = J.mirror_pose(q)
    np.testing.assert_array_equal(m[:, 6:], q[:, 6:])
    np.testing.assert_array_equal(J.mirror_pose(m), q)
