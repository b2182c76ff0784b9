"""Synthetic RGB-D camera: rendered hand depth vs model geometry, ground truth, options."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.cameras.base import Frame
from hand_capture.cameras.motion import MotionClip, builtin_clip
from hand_capture.cameras.noise import DepthNoiseConfig
from hand_capture.cameras.synthetic import (
    HAND_LABEL,
    SyntheticCamera,
    SyntheticCameraConfig,
    SyntheticFrame,
    pose_in_camera,
)
from hand_capture.cameras.transforms import rotvec_to_matrix
from hand_capture.errors import ConfigError, DeviceError


@pytest.fixture(scope="module")
def cam() -> SyntheticCamera:
    c = SyntheticCamera(SyntheticCameraConfig(clip="finger_counting", noise_seed=3))
    c.open()
    return c


def _visible_vertices(cam: SyntheticCamera, frame: SyntheticFrame, tol: float = 0.003):
    """Pixels (i, j) and depths z of hand vertices seen by the camera (within tol of the
    clean rendered depth, i.e. not hidden behind another part of the hand)."""
    V = cam.model.vertices(frame.pose)
    uv = cam.intrinsics.project(V)
    ij = np.rint(uv[:, ::-1]).astype(int)
    ok = (ij[:, 0] >= 0) & (ij[:, 0] < cam.intrinsics.height) & (ij[:, 1] >= 0) & \
        (ij[:, 1] < cam.intrinsics.width)
    ij, z = ij[ok], V[ok, 2]
    clean = frame.depth_clean_m[ij[:, 0], ij[:, 1]]
    vis = (frame.labels[ij[:, 0], ij[:, 1]] == HAND_LABEL) & (np.abs(clean - z) < tol)
    return ij[vis], z[vis], clean[vis]


@pytest.mark.parametrize("t", [0.0, 2.3, 5.4])
def test_depth_at_visible_vertices_matches_within_the_noise_model(cam, t):
    frame = cam.render(t)
    assert isinstance(frame, Frame) and frame.depth.dtype == np.uint16
    ij, z, clean = _visible_vertices(cam, frame)
    assert len(z) > 500  # roughly the front half of the ~3.5k-vertex hand
    # clean depth: the vertex lies on the rendered surface (sub-pixel offset only)
    assert np.median(np.abs(clean - z)) < 0.0005
    noisy = frame.depth[ij[:, 0], ij[:, 1]].astype(float) * 1e-3
    measured = noisy > 0
    assert measured.mean() > 0.8  # edge and grazing dropouts (a fist has many grazing sides)
    # flying pixels: next to a depth jump of the clean image (or to the background)
    d = np.where(frame.depth_clean_m > 0, frame.depth_clean_m, np.inf)
    pad = np.pad(d, 1, constant_values=np.inf)
    nb = np.stack([pad[:-2, 1:-1], pad[2:, 1:-1], pad[1:-1, :-2], pad[1:-1, 2:]])
    with np.errstate(invalid="ignore"):
        edge_img = (np.abs(nb - d) > cam.noise.config.jump_m).any(axis=0)
    edge = edge_img[ij[:, 0], ij[:, 1]]
    cos = frame.cos_incidence[ij[:, 0], ij[:, 1]]
    err = noisy - clean
    sigma = cam.noise.axial_sigma(clean, cos)
    sel = measured & ~edge
    assert sel.sum() > 400
    # interior pixels: Gaussian with the model's sigma (3 sigma + 0.5 mm rounding)
    inside = np.abs(err[sel]) <= 3 * sigma[sel] + 0.0005
    assert inside.mean() > 0.98
    assert np.std(err[sel] / sigma[sel]) == pytest.approx(1.0, abs=0.25)
    # edge pixels: flying pixels stay between the surface and 0.1 m behind it at most
    fly = measured & edge
    assert np.all(err[fly] > -3 * sigma[fly] - 0.05) and np.all(err[fly] < 0.11)


def test_truth_is_in_the_camera_frame_for_a_moved_camera():
    R = rotvec_to_matrix([0.1, -0.3, 0.05])
    t = np.array([0.05, -0.02, 0.03])
    # the same scene seen by a moved camera, or by the identity camera with the poses
    # expressed in the moved camera's frame, gives the same image and the same truth
    moved = SyntheticCamera(SyntheticCameraConfig(
        clip="wrist_rotation", camera_position=tuple(t),
        camera_rotation=(0.1, -0.3, 0.05)), DepthNoiseConfig(enabled=False))
    clip = builtin_clip("wrist_rotation")
    poses = np.array([pose_in_camera(q, R, t) for q in clip.poses])
    ident = SyntheticCamera(SyntheticCameraConfig(clip="wrist_rotation"),
                            DepthNoiseConfig(enabled=False),
                            motion=MotionClip("cam", clip.times, poses))
    for c in (moved, ident):
        c.open()
    a, b = moved.render(0.0), ident.render(0.0)
    assert np.allclose(a.pose, b.pose, atol=1e-9)
    assert a.silhouette.sum() > 1000
    iou = (a.silhouette & b.silhouette).sum() / (a.silhouette | b.silhouette).sum()
    assert iou > 0.995
    both = (a.depth > 0) & (b.depth > 0)
    assert np.abs(a.depth[both].astype(int) - b.depth[both].astype(int)).max() <= 1
    # the wrist of the truth projects onto the hand
    u, v = moved.intrinsics.project(a.pose[None, :3])[0]
    assert abs(a.pose[2] - a.depth_clean_m[a.silhouette].mean()) < 0.1
    ii, jj = np.nonzero(a.silhouette)
    assert ii.min() - 5 <= v <= ii.max() + 5 and jj.min() - 5 <= u <= jj.max() + 5


def test_left_hand_is_the_mirror_image_and_shapes_differ():
    cfg = dict(clip="static")
    right = SyntheticCamera(SyntheticCameraConfig(**cfg), DepthNoiseConfig(enabled=False))
    left = SyntheticCamera(SyntheticCameraConfig(side="left", **cfg),
                           DepthNoiseConfig(enabled=False))
    a, b = right.render(0.0), left.render(0.0)
    m = np.fliplr(b.silhouette)  # wrist on the optical axis, cx at the image centre
    assert (a.silhouette & m).sum() / (a.silhouette | m).sum() > 0.98
    s1 = SyntheticCamera(SyntheticCameraConfig(shape_seed=1, **cfg)).render(0.0)
    s1b = SyntheticCamera(SyntheticCameraConfig(shape_seed=1, **cfg)).render(0.0)
    s2 = SyntheticCamera(SyntheticCameraConfig(shape_seed=2, **cfg)).render(0.0)
    assert np.array_equal(s1.silhouette, s1b.silhouette)
    assert not np.array_equal(s1.silhouette, s2.silhouette)


def test_objects_from_the_clip_and_a_scene_file(tmp_path):
    scene = tmp_path / "scene.yaml"
    scene.write_text("objects:\n  - {shape: box, size: [0.6, 0.02, 0.6], "
                     "position: [0.0, 0.1, 0.5], name: table}\n")
    c = SyntheticCamera(SyntheticCameraConfig(clip="grasp", scene_file=str(scene)))
    c.open()
    assert [o.name for o in c.objects] == ["ball", "table"]
    f = c.render(3.5)
    labels = set(np.unique(f.labels))
    assert {HAND_LABEL, 2, 3} <= labels
    assert set(f.object_poses) == {"ball", "table"}
    assert f.color is not None and f.color.shape == (240, 320, 3)
    # the ball colour shows where the ball is seen
    ball = f.labels == 2
    assert f.color[ball][:, 0].mean() > f.color[ball][:, 2].mean() + 40
    bad = tmp_path / "bad.yaml"
    bad.write_text("objects:\n  - {shape: cone, size: [1]}\n")
    with pytest.raises(ConfigError, match="cone"):
        SyntheticCamera(SyntheticCameraConfig(scene_file=str(bad))).open()


def test_read_advances_and_drops_frames_with_the_configured_probability():
    c = SyntheticCamera(SyntheticCameraConfig(fps=50.0, width=160, height=120),
                        DepthNoiseConfig(frame_drop_prob=0.3))
    with pytest.raises(DeviceError):
        c.read()
    c.open()
    frames = [c.read() for _ in range(60)]
    got = [f for f in frames if f is not None]
    assert 20 < c.dropped_frames < 30 or 0 < c.dropped_frames < 35
    assert len(got) + c.dropped_frames == 60
    seqs = [f.sequence for f in got]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    assert got[-1].clip_time_s == pytest.approx(got[-1].sequence / 50.0)
    assert got[0].depth.shape == (120, 160) and got[0].depth_intrinsics.width == 160


def test_config_validation_and_intrinsics():
    cfg = SyntheticCameraConfig(width=640, height=480, fx=500.0, cy=200.0)
    i = cfg.intrinsics()
    assert (i.fx, i.fy, i.cx, i.cy) == (500.0, 500.0, 319.5, 200.0)
    with pytest.raises(ConfigError, match="clip"):
        SyntheticCameraConfig(clip="dance")
    with pytest.raises(ConfigError, match="camera_position"):
        SyntheticCameraConfig(camera_position=(0.0, 1.0))
    with pytest.raises(ConfigError, match="fps"):
        SyntheticCameraConfig(fps=0.0)
    with pytest.raises(DeviceError, match="not found"):
        SyntheticCamera(SyntheticCameraConfig(pose_file="/nonexistent/poses.csv")).open()


def test_blas_thread_limit_is_scoped():
    from hand_capture.cameras.threads import blas_threads, get_blas_threads

    before = get_blas_threads()
    with blas_threads(1):
        assert get_blas_threads() in (1, None)
    assert get_blas_threads() == before


def test_render_benchmark_reports_its_figures():
    from hand_capture.cameras import render_benchmark, synthetic
    from hand_capture.model import HandModel, sample_shape

    out = render_benchmark(True, width=160, height=120, verbose=False)
    for key in ("render_fps", "synthetic_frame_fps", "raycast_fps", "naive_fps",
                "render_speedup_vs_naive", "render_speedup_vs_raycast", "render_fps_cpu",
                "render_agreement"):
        assert np.isfinite(out[key]) and out[key] > 0, key
    assert out["render_agreement"] > 0.999 and out["render_max_depth_diff_mm"] < 0.01
    assert out["render_speedup_vs_naive"] > 5  # vectorised vs per-triangle loop, same run
    # the (model, quick) entry point that `hand-suite bench model` calls
    out = synthetic.render_benchmark(HandModel(sample_shape(0)), True, width=80, height=60,
                                     verbose=False)
    assert out["render_fps"] > 0 and out["render_width"] == 80
