"""Rig calibration: Jacobian against finite differences, recovery of a known rig, and errors
that name the camera and what is missing."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.multiview import calibrate as C
from hand_capture.multiview.calibrate import (
    WORLD_FROM_BOARD,
    CalibrationError,
    calibrate_from_detections,
    calibrate_rig,
    compare_rigs,
)
from hand_capture.multiview.charuco import (
    BoardSpec,
    Detection,
    boards_seen_by,
    detect_board,
    parse_board,
    render_board_view,
    sample_board_poses,
)
from hand_capture.multiview.rig import ring_rig

SPEC = BoardSpec()


def _synthetic_detections(rig, poses, noise_px: float, seed: int = 0):
    """Projected board corners (exact geometry + Gaussian pixel noise) of every camera that
    sees the board at each pose."""
    rng = np.random.default_rng(seed)
    dets = {c.name: {} for c in rig.cameras}
    for v, T in enumerate(poses):
        Xw = SPEC.corners @ T[:3, :3].T + T[:3, 3]
        for cam in rig.cameras:
            n = T[:3, 2]
            if n @ (cam.t_wc - Xw.mean(0)) >= 0:  # sees the back of the board
                continue
            uv, front = cam.project(Xw)
            k = cam.intrinsics
            ok = front & (uv[:, 0] > 0) & (uv[:, 0] < k.width) & (uv[:, 1] > 0) & (
                uv[:, 1] < k.height)
            if ok.sum() >= C.MIN_CORNERS:
                ids = np.flatnonzero(ok)
                dets[cam.name][v] = Detection(ids, uv[ids] + rng.normal(0, noise_px,
                                                                        (len(ids), 2)))
    return dets


def _in_true_world(result, poses):
    return result.rig.transformed(poses[0] @ np.linalg.inv(WORLD_FROM_BOARD))


@pytest.fixture(scope="module")
def rig_and_poses():
    rig = ring_rig("truth", 6, distortion=(-0.08, 0.03, 0.0005, -0.0004, 0.0))
    return rig, sample_board_poses(SPEC, rig, 40, seed=3)


def test_refinement_jacobian_matches_finite_differences(rig_and_poses):
    rig, poses = rig_and_poses
    dets = _synthetic_detections(rig, poses[:8], noise_px=0.3)
    cams = list(dets)
    intr = {c: C._intrinsics(c, dets[c], (640, 480), SPEC) for c in cams}
    T_cb = {(c, v): C._pnp(SPEC, d, intr[c]) for c in cams for v, d in dets[c].items()}
    T_wc, T_wb = C._chain(cams, dets, T_cb, 0, 8)
    probe: dict = {}
    C._refine(cams, dets, SPEC, intr, T_wc, T_wb, 0, {}, _probe=probe)
    x0, ev = probe["x0"], probe["evaluate"]
    J = ev(x0, True).toarray()
    h = 1e-6
    for j in range(x0.size):
        dx = np.zeros_like(x0)
        dx[j] = h
        fd = (ev(x0 + dx, False) - ev(x0 - dx, False)) / (2 * h)
        np.testing.assert_allclose(J[:, j], fd, atol=1e-3 * max(1.0, np.abs(fd).max()))


def test_recovers_a_known_rig_from_noisy_corners(rig_and_poses):
    rig, poses = rig_and_poses
    dets = _synthetic_detections(rig, poses, noise_px=0.2)
    res = calibrate_from_detections(dets, {c.name: (640, 480) for c in rig.cameras}, SPEC,
                                    len(poses))
    for name, (mm, deg) in compare_rigs(_in_true_world(res, poses), rig).items():
        assert mm < 2.0 and deg < 0.2, (name, mm, deg)
    for cam in res.rig.cameras:
        true = rig.camera(cam.name).intrinsics
        assert abs(cam.intrinsics.fx - true.fx) < 0.005 * true.fx
        assert res.reproj_px[cam.name] < 0.3  # the corner noise is 0.2 px per axis


def test_rendered_board_is_detected_where_the_camera_projects_it():
    rig = ring_rig("r", 3, distortion=(-0.1, 0.02, 0.0, 0.0, 0.0))
    T = sample_board_poses(SPEC, rig, 2, min_cameras=2, seed=1)[1]
    seen = boards_seen_by(SPEC, rig, T, min_cos=0.6)
    assert seen
    for cam in map(rig.camera, seen):
        d = detect_board(SPEC, render_board_view(SPEC, cam, T))
        assert len(d) >= 12
        uv, _ = cam.project(SPEC.corners[d.ids] @ T[:3, :3].T + T[:3, 3])
        assert np.sqrt(np.mean(np.sum((uv - d.pixels) ** 2, axis=1))) < 0.5


def test_calibrates_from_rendered_images_and_the_cli_writes_the_rig(tmp_path):
    import cv2

    from hand_control.cli import main

    rig = ring_rig("truth", 3)
    poses = sample_board_poses(SPEC, rig, 16, seed=5, min_cameras=2)
    rng = np.random.default_rng(0)
    for cam in rig.cameras:
        (tmp_path / "views" / cam.name).mkdir(parents=True)
        for v, T in enumerate(poses):
            img = render_board_view(SPEC, cam, T, supersample=1)
            img = np.clip(img + rng.normal(0, 2.0, img.shape), 0, 255).astype(np.uint8)
            cv2.imwrite(str(tmp_path / "views" / cam.name / f"{v:03d}.png"), img)
    out = tmp_path / "rigs" / "mine.yaml"
    assert main(["calibrate", "rig", str(tmp_path / "views"), "-o", str(out)]) == 0
    from hand_capture.multiview.rig import load_rig

    est = load_rig(out)
    assert est.names == rig.names
    assert all(c.reproj_px is not None and c.reproj_px < 0.6 for c in est.cameras)
    moved = est.transformed(poses[0] @ np.linalg.inv(WORLD_FROM_BOARD))
    for name, (mm, deg) in compare_rigs(moved, rig).items():
        assert mm < 10.0 and deg < 2.0, (name, mm, deg)  # few views: coarse


def test_errors_name_the_camera_and_what_is_missing(rig_and_poses):
    rig, poses = rig_and_poses
    dets = _synthetic_detections(rig, poses, noise_px=0.2)
    sizes = {c.name: (640, 480) for c in rig.cameras}
    blind = dict(dets, cam2={})
    with pytest.raises(CalibrationError, match="camera 'cam2'.*not found in any"):
        calibrate_from_detections(blind, sizes, SPEC, len(poses))
    few = dict(dets, cam1=dict(list(dets["cam1"].items())[:2]))
    with pytest.raises(CalibrationError, match="camera 'cam1'.*2 views.*at least 4"):
        calibrate_from_detections(few, sizes, SPEC, len(poses))
    # cam3 only sees views that no other camera sees: it cannot be linked
    others = set().union(*(dets[c].keys() for c in ("cam0", "cam1", "cam2")))
    lonely = {c: dict(d) for c, d in dets.items() if c in ("cam0", "cam1", "cam2")}
    lonely["cam3"] = {100 + i: d for i, d in enumerate(dets["cam3"].values())}
    assert not others & set(lonely["cam3"])
    with pytest.raises(CalibrationError, match=r"\['cam3'\] never share a board view"):
        calibrate_from_detections(lonely, {c: sizes[c] for c in lonely}, SPEC, 200)
    with pytest.raises(CalibrationError, match="reference view 7"):
        calibrate_from_detections({c: {v: d for v, d in x.items() if v != 7}
                                   for c, x in dets.items()}, sizes, SPEC, len(poses),
                                  reference_view=7)


def test_blank_images_report_the_camera():
    blank = np.full((480, 640), 128, np.uint8)
    with pytest.raises(CalibrationError, match="camera 'left'.*not found"):
        calibrate_rig({"left": [blank] * 4, "right": [blank] * 4}, SPEC)


def test_board_text_is_parsed_or_refused_with_the_expected_form():
    b = parse_board("8x6:0.03:0.022:DICT_5X5_100")
    assert (b.squares_x, b.squares_y, b.square_m, b.marker_m) == (8, 6, 0.03, 0.022)
    with pytest.raises(Exception, match="SQUARESxSQUARES"):
        parse_board("8by6")


def test_calibrates_from_a_bag_of_unsynchronised_cameras(tmp_path):
    """`hand-suite calibrate rig BAG`: board images on camN/color/image_raw, each camera on its
    own clock (offsets, jitter); the synchroniser groups them into views."""
    from builtin_interfaces.msg import Time
    from rclpy.serialization import serialize_message

    from hand_capture.bag import BagWriter
    from hand_capture.multiview.rig import load_rig
    from hand_capture.nodes.images import numpy_to_image
    from hand_control.cli import main

    rig = ring_rig("truth", 3)
    poses = sample_board_poses(SPEC, rig, 14, seed=5, min_cameras=2)
    bag = BagWriter(tmp_path / "boards", storage="mcap")
    for cam in rig.cameras:
        bag.add_topic(f"/{cam.name}/color/image_raw", "sensor_msgs/msg/Image")
    rng = np.random.default_rng(2)
    for v, T in enumerate(poses):  # one board placement a second
        for i, cam in enumerate(rig.cameras):
            t = 100.0 + v + 0.003 * i + rng.uniform(-0.001, 0.001)
            ns = int(round(t * 1e9))
            img = np.dstack([render_board_view(SPEC, cam, T, supersample=1)] * 3)
            msg = numpy_to_image(img, "rgb8", Time(sec=ns // 10**9, nanosec=ns % 10**9),
                                 cam.intrinsics.frame_id)
            bag.write(f"/{cam.name}/color/image_raw", ns + 5_000_000, serialize_message(msg))
    bag.close()
    out = tmp_path / "rig.yaml"
    assert main(["calibrate", "rig", str(tmp_path / "boards"), "-o", str(out)]) == 0
    est = load_rig(out)
    assert est.names == rig.names
    moved = est.transformed(poses[0] @ np.linalg.inv(WORLD_FROM_BOARD))
    for name, (mm, deg) in compare_rigs(moved, rig).items():
        assert mm < 10.0 and deg < 2.0, (name, mm, deg)
