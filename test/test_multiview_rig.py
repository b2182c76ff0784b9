"""Rig files: round trip, validation naming camera and field, projection matches OpenCV."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.errors import ConfigError
from hand_capture.multiview.rig import (
    list_rigs,
    load_rig,
    look_at,
    rig_from_mapping,
    ring_rig,
    save_rig,
)


def test_shipped_rig_loads_and_round_trips(tmp_path):
    assert "studio6" in list_rigs()
    rig = load_rig("studio6")
    assert rig.names == tuple(f"cam{i}" for i in range(6))
    out = save_rig(rig, tmp_path / "copy.yaml")
    again = load_rig(out)
    for a, b in zip(rig.cameras, again.cameras, strict=True):
        assert a.intrinsics == b.intrinsics
        np.testing.assert_allclose(a.R_wc, b.R_wc, atol=1e-6)
        np.testing.assert_allclose(a.t_wc, b.t_wc, atol=1e-6)


def test_every_camera_of_the_shipped_rig_sees_the_workspace():
    rig = load_rig("studio6")
    centre = np.array([[0.0, 0.0, 0.08]])
    for cam in rig.cameras:
        uv, front = cam.project(centre)
        assert front[0]
        np.testing.assert_allclose(uv[0], [cam.intrinsics.cx, cam.intrinsics.cy], atol=0.01)


def test_projection_matches_opencv_with_distortion():
    import cv2

    rig = ring_rig("d", 3, distortion=(-0.2, 0.05, 0.001, -0.002, 0.01))
    pts = np.random.default_rng(0).uniform(-0.1, 0.1, (50, 3))
    for cam in rig.cameras:
        T = cam.T_cw
        ref, _ = cv2.projectPoints(pts, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3],
                                   cam.intrinsics.K, np.array(cam.intrinsics.distortion))
        uv, front = cam.project(pts)
        assert front.all()
        np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-9)


def test_look_at_is_an_optical_frame_with_up_upward():
    R = look_at([1.0, 0.0, 0.5], [0.0, 0.0, 0.0])
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    # image y (down) has a negative world z component: up looks up
    assert R[2, 1] < 0


def _minimal() -> dict:
    return {"rig": {"name": "r", "cameras": [
        {"name": "cam0", "width": 640, "height": 480, "fx": 500, "fy": 500, "cx": 320,
         "cy": 240, "position": [0, 0, 1], "rotation": [3.14159, 0, 0]}]}}


@pytest.mark.parametrize("edit, words", [
    (lambda c: c.pop("fx"), ["cam0", "missing field 'fx'"]),
    (lambda c: c.update(width=-3), ["cam0", "'width'"]),
    (lambda c: c.update(position=[0, 1]), ["cam0", "'position'"]),
    (lambda c: c.update(fy=float("nan")), ["cam0", "'fy'", "finite"]),
    (lambda c: c.update(distortion=[0.1]), ["cam0", "'distortion'", "5"]),
    (lambda c: c.update(distortion_model="fisheye9"), ["cam0", "plumb_bob"]),
    (lambda c: c.update(colour=True), ["cam0", "unknown field", "colour"]),
])
def test_invalid_rig_names_camera_and_field(edit, words):
    data = _minimal()
    edit(data["rig"]["cameras"][0])
    with pytest.raises(ConfigError) as e:
        rig_from_mapping(data, source="bad.yaml")
    for w in words:
        assert w in str(e.value)


def test_duplicate_names_and_unknown_camera_are_refused():
    data = _minimal()
    data["rig"]["cameras"].append(dict(data["rig"]["cameras"][0], frame_id="other"))
    with pytest.raises(ConfigError, match="unique"):
        rig_from_mapping(data)
    rig = rig_from_mapping(_minimal())
    with pytest.raises(ConfigError, match=r"cameras: \['cam0'\]"):
        rig.camera("cam7")
    with pytest.raises(ConfigError, match="studio6"):
        load_rig("no_such_rig")


def test_transformed_moves_every_camera_rigidly():
    rig = ring_rig("r", 4)
    T = np.eye(4)
    T[:3, :3] = look_at([0, 0, 0], [1, 1, 0.3])
    T[:3, 3] = [0.2, -0.1, 0.4]
    moved = rig.transformed(T)
    p = np.random.default_rng(1).uniform(-0.2, 0.2, (10, 3))
    p_moved = p @ T[:3, :3].T + T[:3, 3]
    for a, b in zip(rig.cameras, moved.cameras, strict=True):
        np.testing.assert_allclose(a.project(p)[0], b.project(p_moved)[0], atol=1e-9)


def test_realsense_hardware_sync_mode_is_set_or_refused_by_name():
    from types import SimpleNamespace

    from hand_capture.cameras.realsense import RealSenseConfig, apply_sync_mode
    from hand_capture.errors import DeviceError

    calls = []
    rs = SimpleNamespace(option=SimpleNamespace(inter_cam_sync_mode="sync"))

    def device(supported: bool):
        sensor = SimpleNamespace(supports=lambda opt: supported and opt == "sync",
                                 set_option=lambda opt, v: calls.append((opt, v)))
        return SimpleNamespace(first_depth_sensor=lambda: sensor)

    apply_sync_mode(rs, device(True), 2, "123")
    assert calls == [("sync", 2.0)]
    apply_sync_mode(rs, device(False), 0, "123")  # free-running: the device is left alone
    with pytest.raises(DeviceError, match="123 does not support inter_cam_sync_mode"):
        apply_sync_mode(rs, device(False), 1, "123")
    with pytest.raises(ConfigError, match="inter_cam_sync_mode"):
        RealSenseConfig(inter_cam_sync_mode=3)


def test_frustum_reaches_the_image_corners_at_its_depth():
    cam = ring_rig("r", 1).cameras[0]
    seg = cam.frustum_segments(0.2)
    assert seg.shape == (8, 2, 3)
    np.testing.assert_allclose(seg[:4, 0], np.repeat(cam.t_wc[None], 4, 0))
    z = cam.to_camera(seg[:4, 1])[:, 2]
    np.testing.assert_allclose(z, 0.2)
    uv, _ = cam.project(seg[:4, 1])
    np.testing.assert_allclose(uv, [[-0.5, -0.5], [639.5, -0.5], [639.5, 479.5], [-0.5, 479.5]],
                               atol=1e-9)
