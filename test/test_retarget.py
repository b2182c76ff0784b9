"""Retargeting onto robot hand models (hand_control.retarget): Jacobians, limits, loading,
config errors, self-retargeting and pinches."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.cameras.motion import builtin_clip
from hand_capture.model import JOINT_LIMITS, rest_pose
from hand_capture.model.keypoints21 import keypoints21
from hand_capture.model.mjcf import export_mjcf
from hand_control.errors import ConfigError, InputError
from hand_control.retarget import (
    HandRetargeter,
    RobotHand,
    load_mujoco_model,
    load_retarget_config,
    retarget_config_from_dict,
    solve_box_qp,
)
from hand_control.retarget.config import resolve_retarget_config


@pytest.fixture(scope="module")
def leap() -> HandRetargeter:
    return HandRetargeter("leap_hand")


@pytest.fixture(scope="module")
def suite() -> HandRetargeter:
    return HandRetargeter("suite_hand")


def _random_pose(rng: np.random.Generator) -> np.ndarray:
    q = rest_pose()
    lo, hi = JOINT_LIMITS[6:].T
    q[6:] = rng.uniform(lo, hi)
    q[0:3] = rng.uniform(-0.3, 0.3, 3)
    q[3:6] = rng.uniform(-1.2, 1.2, 3)
    return q


@pytest.mark.parametrize("name", ["leap", "suite"])
@pytest.mark.parametrize("mode", ["position", "vector", "pinch"])
def test_jacobian_matches_finite_differences(name: str, mode: str, request) -> None:
    base = request.getfixturevalue(name)
    rt = HandRetargeter(base.config.with_settings(mode=mode), base.robot)
    rng = np.random.default_rng(4)
    human = rt.human_points(keypoints21(None, builtin_clip("pinch").sample(1.6)))
    q = np.clip(rt.robot.reference_q() + rng.uniform(-0.4, 0.4, rt.robot.n) + 0.3,
                rt.lower + 0.02, rt.upper - 0.02)
    r0, jac, _ = rt.residual_and_jacobian(q, human)
    eps = 1e-6
    num = np.empty_like(jac)
    for k in range(rt.robot.n):
        dq = np.zeros(rt.robot.n)
        dq[k] = eps
        rp, _, _ = rt.residual_and_jacobian(q + dq, human)
        rm, _, _ = rt.residual_and_jacobian(q - dq, human)
        num[:, k] = (rp - rm) / (2 * eps)
    assert np.abs(jac).max() > 1e-3  # not a zero Jacobian
    np.testing.assert_allclose(jac, num, atol=1e-7)


def test_box_qp_meets_the_kkt_conditions() -> None:
    rng = np.random.default_rng(0)
    for _ in range(50):
        n = 8
        a = rng.normal(size=(12, n))
        h = a.T @ a + 1e-3 * np.eye(n)
        g = rng.normal(size=n) * 3
        lo, hi = -rng.uniform(0.05, 1, n), rng.uniform(0.05, 1, n)
        x = solve_box_qp(h, g, lo, hi)
        assert np.all(x >= lo) and np.all(x <= hi)
        grad = h @ x + g
        inside = (x > lo + 1e-9) & (x < hi - 1e-9)
        np.testing.assert_allclose(grad[inside], 0.0, atol=1e-8)
        assert np.all(grad[x <= lo + 1e-9] >= -1e-8)  # pushing outwards at a lower bound
        assert np.all(grad[x >= hi - 1e-9] <= 1e-8)


def test_joint_limits_hold_for_unreachable_and_wild_inputs(leap: HandRetargeter) -> None:
    rt = HandRetargeter(leap.config, leap.robot)
    rng = np.random.default_rng(1)
    kp0 = keypoints21(None, rest_pose())
    for k in range(40):
        kp = kp0.copy()
        kp[1:] = kp0[0] + (kp0[1:] - kp0[0]) * rng.uniform(0.2, 3.0)  # shrunk / stretched
        kp[5:] += rng.normal(0, 0.03, (16, 3)) * (k % 3)  # and torn apart
        res = rt.solve(kp, stamp_s=0.01 * k)
        assert np.all(res.q >= rt.lower) and np.all(res.q <= rt.upper)
        assert np.all(res.q_solved >= rt.lower) and np.all(res.q_solved <= rt.upper)
        assert np.isfinite(res.q).all()


def test_self_retargeting_returns_the_input_within_a_millimetre(suite: HandRetargeter
                                                                 ) -> None:
    rt = HandRetargeter(suite.config, suite.robot)
    worst = 0.0
    for clip in ("pinch", "fist", "finger_counting", "wrist_rotation"):
        c = builtin_clip(clip)
        rt.reset()
        for t in np.arange(0.0, c.duration, 0.1):
            q = c.sample(float(t))
            res = rt.solve_pose(q)
            # the robot is the suite's hand at its root: compare tips in the hand frame
            worst = max(worst, float(res.point_error_m[:5].max()))
    assert worst < 1e-3, worst
    rng = np.random.default_rng(7)
    for _ in range(5):  # cold starts from random poses
        rt.reset()
        assert rt.solve_pose(_random_pose(rng)).point_error_m[:5].max() < 1e-3


def test_pinch_mode_closes_the_pinch_the_operator_closes(leap: HandRetargeter) -> None:
    c = builtin_clip("pinch")
    kp = keypoints21(None, c.sample(1.8))  # the pinch is held 1.5 - 2.1 s
    errs = {}
    for mode in ("position", "pinch"):
        rt = HandRetargeter(leap.config.with_settings(mode=mode), leap.robot)
        human = rt.human_points(kp)
        res = rt.solve(kp)
        for _ in range(3):
            res = rt.solve(kp)
        p = rt.robot_points(res.q)
        d_h = np.linalg.norm(human[1] - human[0])
        assert d_h < rt.settings.pinch_close_m
        errs[mode] = abs(np.linalg.norm(p[1] - p[0]) - d_h)
    assert errs["pinch"] < 0.010
    assert errs["pinch"] < errs["position"]


def test_nan_keypoints_are_refused_and_change_nothing(leap: HandRetargeter) -> None:
    rt = HandRetargeter(leap.config, leap.robot)
    good = rt.solve(keypoints21(None, builtin_clip("pinch").sample(1.0)))
    kp = keypoints21(None, rest_pose())
    kp[8] = np.nan
    with pytest.raises(InputError, match="index_tip"):
        rt.solve(kp)
    kp = keypoints21(None, rest_pose())
    kp[0] = np.inf  # the wrist: no hand frame
    with pytest.raises(InputError):
        rt.solve(kp)
    np.testing.assert_array_equal(rt._q, good.q_solved)


def test_urdf_and_mjcf_files_both_load(tmp_path) -> None:
    urdf = load_retarget_config("leap_hand")
    assert urdf.model.endswith(".urdf")
    m = load_mujoco_model(urdf.model)
    assert m.njnt == 16
    files = export_mjcf(tmp_path, scenes={})
    cfg = retarget_config_from_dict({
        "model": str(files.hand), "base_body": "palm", "fixed_joints": ["root_*"],
        "points": [{"keypoint": "index_tip", "site": "index_tip"},
                   {"keypoint": "thumb_tip", "site": "thumb_tip"}],
        "solver": {"mode": "vector", "damping": 1e-6, "smoothness": 1e-6}})
    rt = HandRetargeter(cfg)
    assert rt.robot.n == 21 and "index_pip_flex" in rt.joint_names
    q = rest_pose()
    q[[13, 14]] = (0.6, 0.8)  # index MCP / PIP flexion
    res = rt.solve_pose(q)
    assert res.point_error_m.max() < 1e-3
    # a URDF with meshes that do not exist still loads (visuals / collisions dropped)
    text = (resolve_retarget_config("leap_hand").parent / urdf.model).read_text()
    text = text.replace('<link name="palm">', '<link name="palm"><visual><geometry><mesh '
                        'filename="package://nowhere/palm.stl"/></geometry></visual>')
    (tmp_path / "leap.urdf").write_text(text)
    assert load_mujoco_model(tmp_path / "leap.urdf").nbody == m.nbody


def _leap_dict(**changes) -> dict:
    d = {"model": load_retarget_config("leap_hand").model, "base_body": "palm",
         "points": [{"keypoint": "index_tip", "body": "index_tip"}]}
    d.update(changes)
    return d


def test_missing_body_site_or_joint_is_named_with_those_that_exist() -> None:
    with pytest.raises(ConfigError, match=r"no body 'index_fingertip'.*'index_tip'"):
        HandRetargeter(retarget_config_from_dict(_leap_dict(
            points=[{"keypoint": "index_tip", "body": "index_fingertip"}])))
    with pytest.raises(ConfigError, match=r"no site 'tip'.*sites: \[\]"):
        HandRetargeter(retarget_config_from_dict(_leap_dict(
            points=[{"keypoint": "index_tip", "site": "tip"}])))
    with pytest.raises(ConfigError, match=r"no body 'hand'.*'palm'"):
        HandRetargeter(retarget_config_from_dict(_leap_dict(base_body="hand")))
    with pytest.raises(ConfigError, match=r"joint 'index_abd' does not exist.*index_mcp_side"):
        HandRetargeter(retarget_config_from_dict(_leap_dict(joints=["index_abd"])))


def test_config_errors_are_listed_together() -> None:
    with pytest.raises(ConfigError) as e:
        retarget_config_from_dict({"model": "x.urdf", "base_body": "palm", "colour": 1,
                                   "points": [{"keypoint": "index_nail", "body": "a"},
                                              {"keypoint": "thumb_tip"}],
                                   "solver": {"mode": "magic"}})
    text = str(e.value)
    for part in ("colour", "index_nail", "exactly one of body or site", "magic"):
        assert part in text
    with pytest.raises(ConfigError, match="does not exist"):
        HandRetargeter(retarget_config_from_dict({"model": "/nope/x.urdf", "base_body": "p",
                                                  "points": [{"keypoint": "index_tip",
                                                              "body": "b"}]}))
    with pytest.raises(ConfigError, match="available"):
        load_retarget_config("allegro_hand_9000")


def test_base_body_moved_by_an_optimised_joint_is_refused() -> None:
    m = load_mujoco_model(load_retarget_config("leap_hand").model)
    with pytest.raises(ConfigError, match="moves with optimised joint"):
        RobotHand(m, "index_distal")


def test_the_camera_frame_does_not_matter(leap: HandRetargeter) -> None:
    from hand_capture.model import root_rotation_matrix

    kp = keypoints21(None, builtin_clip("pinch").sample(1.8))
    rot = root_rotation_matrix(np.array([0.7, -1.1, 2.0]))
    moved = kp @ rot.T + np.array([0.3, -0.2, 0.9])  # the same hand seen from elsewhere
    a = HandRetargeter(leap.config, leap.robot).solve(kp)
    b = HandRetargeter(leap.config, leap.robot).solve(moved)
    np.testing.assert_allclose(a.q, b.q, atol=1e-6)


def test_wrist_rpy_follows_the_urdf_convention() -> None:
    cfg = retarget_config_from_dict({**_leap_dict(), "wrist": {"rpy": [0.3, -0.5, 1.2]}})
    r, p, y = cfg.wrist_rpy

    def rx(a):
        return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])

    def ry(a):
        return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])

    def rz(a):
        return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])

    np.testing.assert_allclose(cfg.wrist_rotation(), rz(y) @ ry(p) @ rx(r), atol=1e-12)
