"""FK, LBS, Jacobians (vs finite differences), shape, mirroring and collision capsules."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.errors import InputError
from hand_capture.model import (
    FINGERTIP_KEYPOINTS,
    JOINT_INDEX,
    JOINT_LIMITS,
    KEYPOINT_NAMES,
    N_ALPHA,
    N_BETA,
    HandModel,
    HandShape,
    default_shape,
    mirror_pose,
    sample_shape,
)
from hand_capture.model.skeleton import HAND_LENGTH_M


def random_poses(rng: np.random.Generator, n: int) -> np.ndarray:
    lo = np.r_[-0.3, -0.3, -0.3, -np.pi, -1.2, -np.pi, JOINT_LIMITS[6:, 0]]
    hi = np.r_[0.3, 0.3, 0.3, np.pi, 1.2, np.pi, JOINT_LIMITS[6:, 1]]
    return rng.uniform(lo, hi, size=(n, 27))


@pytest.fixture(scope="module")
def model() -> HandModel:
    return HandModel(sample_shape(7))


def test_rest_pose_dimensions() -> None:
    m = HandModel(default_shape())
    kp = m.joint_positions(np.zeros(27))
    assert kp.shape == (21, 3) and KEYPOINT_NAMES[0] == "wrist"
    np.testing.assert_allclose(kp[0], 0.0)
    mid_tip = kp[KEYPOINT_NAMES.index("middle_tip")]
    # the wrist joint centre lies a little proximal of the crease: 0.17-0.19 m to the tip
    assert 0.9 * HAND_LENGTH_M < mid_tip[0] < 1.02 * HAND_LENGTH_M
    v = m.rest_vertices
    assert v[:, 0].max() == pytest.approx(mid_tip[0], abs=0.004)  # the tip is on the surface
    tips = m.fingertips(np.zeros(27))
    assert tips[0, 1] > tips[1, 1] > tips[2, 1] > tips[3, 1] > tips[4, 1]  # thumb radial (+y)
    pads = m.fingertips(np.zeros(27), where="pad")
    assert np.all(pads[:, 2] < tips[:, 2])  # pads are on the palmar side (-z)
    with pytest.raises(InputError):
        m.fingertips(np.zeros(27), where="nail")


def test_flexion_and_abduction_directions() -> None:
    m = HandModel()
    q = np.zeros(27)
    q[JOINT_INDEX["index_mcp_flex"]] = 0.8
    tip = m.fingertips(q)[1]
    assert tip[2] < -0.03  # flexion moves towards the palm (-z)
    q = np.zeros(27)
    q[JOINT_INDEX["little_mcp_abd"]] = 0.3
    assert m.fingertips(q)[4, 1] > m.fingertips(np.zeros(27))[4, 1]  # towards the thumb
    q = np.zeros(27)
    q[JOINT_INDEX["thumb_tm_flex"]] = 0.8
    d = m.fingertips(q)[0] - m.fingertips(np.zeros(27))[0]
    assert d[1] < 0 and d[2] < 0  # thumb flexion: ulnar and palmar (opposition)


def test_batch_matches_single(model: HandModel) -> None:
    q = random_poses(np.random.default_rng(0), 5)
    fb = model.forward(q, normals=True)
    for i in range(5):
        f = model.forward(q[i], normals=True)
        np.testing.assert_allclose(fb.vertices[i], f.vertices, atol=1e-12)
        np.testing.assert_allclose(fb.joint_positions[i], f.joint_positions, atol=1e-12)
        np.testing.assert_allclose(fb.joint_frames[i], f.joint_frames, atol=1e-12)
        np.testing.assert_allclose(fb.normals[i], f.normals, atol=1e-12)
    assert fb.fingertips.shape == (5, 5, 3)
    np.testing.assert_allclose(fb.fingertips, fb.joint_positions[:, FINGERTIP_KEYPOINTS])
    idx = np.array([0, 17, 999, model.n_vertices - 1])
    np.testing.assert_allclose(model.vertices(q, idx), fb.vertices[:, idx], atol=1e-12)


def test_frames_are_rigid(model: HandModel) -> None:
    q = random_poses(np.random.default_rng(1), 3)
    fr = model.forward(q).joint_frames
    r = fr[..., :3, :3]
    np.testing.assert_allclose(r @ np.swapaxes(r, -1, -2), np.broadcast_to(np.eye(3), r.shape),
                               atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    # bone lengths do not change with the pose
    kp = model.joint_positions(q)
    kp0 = model.joint_positions(np.zeros(27))
    for f in range(5):
        seg = kp[:, 1 + 4 * f:5 + 4 * f]
        seg0 = kp0[1 + 4 * f:5 + 4 * f]
        np.testing.assert_allclose(np.linalg.norm(np.diff(seg, axis=1), axis=-1),
                                   np.broadcast_to(np.linalg.norm(np.diff(seg0, axis=0), axis=-1),
                                                   (3, 3)), atol=1e-12)


def _fd(fn, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    cols = []
    for k in range(x.size):
        d = np.zeros_like(x)
        d[k] = eps
        cols.append((fn(x + d) - fn(x - d)) / (2 * eps))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("side", ["right", "left"])
def test_pose_jacobians_match_finite_differences(side: str) -> None:
    m = HandModel(sample_shape(11), side=side)
    rng = np.random.default_rng(2)
    for q in random_poses(rng, 3):
        jac = m.jacobian(q)
        assert jac.shape == (m.n_vertices, 3, 27)
        np.testing.assert_allclose(jac, _fd(m.vertices, q), atol=2e-8)
        idx = rng.choice(m.n_vertices, 50, replace=False)
        np.testing.assert_allclose(m.jacobian(q, idx), jac[idx], atol=1e-12)
        np.testing.assert_allclose(m.keypoint_jacobian(q), _fd(m.joint_positions, q), atol=2e-8)
    qb = random_poses(rng, 2)
    jb = m.jacobian(qb, np.arange(10))
    np.testing.assert_allclose(jb[1], m.jacobian(qb[1], np.arange(10)), atol=1e-12)


def test_shape_jacobian_matches_finite_differences(model: HandModel) -> None:
    q = random_poses(np.random.default_rng(3), 1)[0]
    p0 = model.shape.params

    def verts(p: np.ndarray) -> np.ndarray:
        return model.with_shape(HandShape.from_params(p)).vertices(q)

    def kps(p: np.ndarray) -> np.ndarray:
        return model.with_shape(HandShape.from_params(p)).joint_positions(q)

    jac = model.shape_jacobian(q)
    assert jac.shape == (model.n_vertices, 3, 1 + N_ALPHA + N_BETA)
    np.testing.assert_allclose(jac, _fd(verts, p0), atol=2e-8)
    np.testing.assert_allclose(model.shape_jacobian(q, keypoints=True), _fd(kps, p0), atol=2e-8)
    idx = np.array([3, 300, 3000])
    np.testing.assert_allclose(model.shape_jacobian(q, idx), jac[idx], atol=1e-12)


def test_global_scale_scales_about_the_wrist() -> None:
    m = HandModel()
    big = m.with_shape(HandShape(global_scale=1.1))
    q = random_poses(np.random.default_rng(4), 1)[0]
    t = q[:3]
    np.testing.assert_allclose(big.vertices(q) - t, 1.1 * (m.vertices(q) - t), atol=1e-12)


def test_sampled_shapes_differ_plausibly() -> None:
    m = HandModel()
    lengths = []
    for s in range(20):
        shape = sample_shape(s)
        assert shape == sample_shape(s)  # reproducible
        mm = m.with_shape(shape)
        kp = mm.joint_positions(np.zeros(27))
        lengths.append(kp[KEYPOINT_NAMES.index("middle_tip"), 0])
        assert np.all(mm.bone_lengths > 0.005)
    lengths = np.array(lengths)
    assert lengths.std() > 0.004 and 0.14 < lengths.min() and lengths.max() < 0.24
    with pytest.raises(InputError):
        HandShape(global_scale=float("nan"))
    with pytest.raises(InputError):
        HandShape(alpha=(0.0,) * (N_ALPHA + 1))
    with pytest.raises(InputError):
        HandShape(beta=(0.5,) * N_BETA)
    fields = sample_shape(1).to_msg_fields()
    assert len(fields["bone_names"]) == len(fields["bone_scales"]) == 17
    back = HandShape.from_msg_fields(fields["global_scale"], fields["alpha"], fields["beta"])
    np.testing.assert_allclose(back.params, sample_shape(1).params)


def test_left_hand_mirrors_right() -> None:
    shape = sample_shape(5)
    r, lf = HandModel(shape, "right"), HandModel(shape, "left")
    m = np.array([1.0, -1.0, 1.0])
    rng = np.random.default_rng(6)
    for q in random_poses(rng, 4):
        fr, fl = r.forward(q), lf.forward(mirror_pose(q))
        np.testing.assert_allclose(fl.vertices, fr.vertices * m, atol=1e-12)
        np.testing.assert_allclose(fl.joint_positions, fr.joint_positions * m, atol=1e-12)
        # with the root at the origin, the same finger angles give the mirror image
        q0 = q.copy()
        q0[:6] = 0
        np.testing.assert_allclose(lf.vertices(q0), r.vertices(q0) * m, atol=1e-12)
    assert np.all(lf.fingertips(np.zeros(27))[:, 1][0] < 0)  # left thumb on -y


def test_bad_inputs(model: HandModel) -> None:
    with pytest.raises(InputError):
        model.forward(np.full(27, np.nan))
    with pytest.raises(InputError):
        model.vertices(np.zeros(21))
    with pytest.raises(InputError):
        model.jacobian(np.zeros(27), np.array([model.n_vertices]))
    with pytest.raises(InputError):
        model.jacobian(np.zeros(27), np.array([0.5]))
    with pytest.raises(InputError):
        HandModel(side="both")
    with pytest.raises(InputError):
        HandModel(shape="big")  # type: ignore[arg-type]


def test_capsules_and_self_penetration(model: HandModel) -> None:
    caps = model.capsules
    assert len({c.name for c in caps}) == len(caps)
    assert {c.bone for c in caps} == set(range(16))
    assert all(0.004 < c.radius < 0.02 for c in caps)
    seg = model.capsule_segments(np.zeros(27))
    assert seg.shape == (len(caps), 2, 3)
    # the capsules cover the skeleton: every keypoint but the wrist lies inside one
    kp = model.joint_positions(np.zeros(27))[1:]
    from hand_capture.model.hand import segment_distance
    d = np.min([segment_distance(kp, kp, np.broadcast_to(s[0], kp.shape),
                                 np.broadcast_to(s[1], kp.shape)) - c.radius
                for s, c in zip(seg, caps, strict=True)], axis=0)
    assert np.all(d < 1e-3)  # (within the girth offsets of the sampled shape)
    assert model.self_penetration(np.zeros(27)).max() < 0
    q = np.zeros(27)
    q[JOINT_INDEX["index_mcp_abd"]] = -0.35  # index pushed into the middle finger
    q[JOINT_INDEX["middle_mcp_abd"]] = 0.35
    assert model.self_penetration(q).max() > 0.003
    assert model.self_penetration(np.zeros((2, 27))).shape == (2, len(model.capsule_pairs))


def test_segment_distance_cases() -> None:
    from hand_capture.model.hand import segment_distance
    p0, p1 = np.array([0.0, 0, 0]), np.array([1.0, 0, 0])
    assert segment_distance(p0, p1, np.array([0.5, 1, 0]), np.array([0.5, 2, 0])) == 1.0
    assert segment_distance(p0, p1, np.array([2.0, 0, 0]), np.array([3.0, 0, 0])) == 1.0
    assert segment_distance(p0, p1, np.array([0.0, 0, 1]), np.array([1.0, 0, 1])) == 1.0
    assert segment_distance(p0, p1, np.array([0.5, -1, 0]), np.array([0.5, 1, 0])) == 0.0
    assert segment_distance(p0, p0, np.array([0.0, 3, 4]), np.array([0.0, 3, 4])) == 5.0


def test_linearize_matches_vertices_and_jacobian(model: HandModel) -> None:
    rng = np.random.default_rng(9)
    q = random_poses(rng, 2)
    idx = rng.choice(model.n_vertices, 40, replace=False)
    for qq, sub in ((q[0], None), (q[0], idx), (q, idx)):
        pts, jac = model.linearize(qq, sub)
        np.testing.assert_allclose(pts, model.vertices(qq, sub), atol=1e-12)
        np.testing.assert_allclose(jac, model.jacobian(qq, sub), atol=1e-12)
