"""Colour tracker core: the fit's Jacobian, pose recovery, limits, depth, status decisions."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.cameras.base import Intrinsics
from hand_capture.cameras.motion import builtin_clip
from hand_capture.errors import InputError
from hand_capture.model import JOINT_LIMITS, HandModel, sample_shape
from hand_capture.model.keypoints21 import keypoints21
from hand_capture.rgbtrack import Detection, FitConfig, KeypointFitter, RgbTracker
from hand_capture.rgbtrack.fit import project_points

INTR = Intrinsics.from_fov(640, 480, 60.0)


@pytest.fixture(scope="module")
def model():
    return HandModel(sample_shape(3))


def _poses(n: int = 6) -> list[np.ndarray]:
    out = []
    for clip in ("grasp", "pinch", "wrist_rotation"):
        c = builtin_clip(clip)
        out += [c.sample(t) for t in np.linspace(0.3, c.duration - 0.3, n // 3)]
    return out


def test_fit_jacobian_matches_finite_differences(model) -> None:
    """The analytic residual Jacobian (model keypoint Jacobian x pinhole, root rotation as a
    camera-frame increment, depth and prior rows) equals central differences of the
    residuals under the same update rule."""
    fitter = KeypointFitter(model, FitConfig(huber_px=1000.0))
    rng = np.random.default_rng(1)
    q = builtin_clip("pinch").sample(1.0)
    q[6:] = np.clip(q[6:] + rng.normal(0, 0.1, 21), JOINT_LIMITS[6:, 0] + 0.05,
                    JOINT_LIMITS[6:, 1] - 0.05)
    obs = project_points(INTR, keypoints21(model, q)) + rng.normal(0, 3.0, (21, 2))
    depth_obs = keypoints21(model, q)[:, 2] + rng.normal(0, 0.003, 21)
    prev = q + rng.normal(0, 0.02, 27)
    r0, jac, _ = fitter._residuals(q, obs, INTR, depth_obs, prev, True)
    num = np.zeros_like(jac)
    h = 1e-6
    for k in range(27):
        e = np.zeros(27)
        e[k] = h
        rp, _, _ = fitter._residuals(KeypointFitter._apply(q, e), obs, INTR, depth_obs, prev,
                                     False)
        rm, _, _ = fitter._residuals(KeypointFitter._apply(q, -e), obs, INTR, depth_obs, prev,
                                     False)
        num[:, k] = (rp - rm) / (2 * h)
    n_img = 42 + 21  # reprojection and depth rows: exact
    assert np.allclose(jac[:n_img], num[:n_img], atol=1e-4 * np.abs(num[:n_img]).max())
    # temporal rows: exact for translation and fingers, first order for the rotation
    assert np.allclose(jac[n_img:], num[n_img:], atol=0.05 * np.abs(num[n_img:]).max())


def test_fit_recovers_poses_from_clean_keypoints_cold_and_warm(model) -> None:
    """Cold starts reproduce the keypoints and the wrist distance (from the hand's known
    size); the 3-D keypoints match except where a single view is ambiguous (a finger bent
    towards or away from the camera projects alike: some pinch frames), so most frames are
    within 10 mm and every one within 20 mm on average."""
    fitter = KeypointFitter(model)
    rng = np.random.default_rng(4)
    close = 0
    poses = _poses(9)
    for q in poses:
        truth = keypoints21(model, q)
        uv = project_points(INTR, truth)
        cold = fitter.fit(uv, INTR)
        assert cold.rms_px < 1.0
        err = np.linalg.norm(cold.keypoints - truth, axis=1).mean()
        assert err < 0.02
        close += err < 0.01
        assert abs(cold.pose[2] - q[2]) < 0.01          # depth from the known hand size
        # warm start from the previous frame of a tracked motion: a few cm / tenths of rad off
        prev = q + np.r_[rng.normal(0, 0.01, 3), rng.normal(0, 0.05, 24)]
        warm = fitter.fit(uv, INTR, prev=prev)
        assert warm.rms_px < 1.5
        assert np.linalg.norm(warm.keypoints - truth, axis=1).mean() < 0.006
    assert close > len(poses) // 2


def test_fit_respects_joint_limits_on_impossible_keypoints(model) -> None:
    fitter = KeypointFitter(model)
    rng = np.random.default_rng(5)
    q = builtin_clip("grasp").sample(2.0)
    uv = project_points(INTR, keypoints21(model, q))
    for _ in range(3):
        bad = uv + rng.normal(0, 25.0, uv.shape)     # keypoints no hand can make
        res = fitter.fit(bad, INTR)
        art = res.pose[6:]
        assert (art >= JOINT_LIMITS[6:, 0] - 1e-12).all()
        assert (art <= JOINT_LIMITS[6:, 1] + 1e-12).all()


def test_depth_image_fixes_the_distance_of_a_hand_of_the_wrong_size(model) -> None:
    """A model 12 % larger than the hand puts it 12 % too far from a colour image alone; the
    aligned depth image brings the wrist back to its true distance."""
    q = builtin_clip("grasp").sample(1.0)
    truth = keypoints21(model, q)
    uv = project_points(INTR, truth)
    big = KeypointFitter(model.with_shape(model.shape.with_params(
        global_scale=model.shape.global_scale * 1.12)))
    mono = big.fit(uv, INTR)
    assert mono.pose[2] - q[2] > 0.03
    depth = np.zeros((INTR.height, INTR.width), np.float32)
    for (u, v), z in zip(np.rint(uv).astype(int), truth[:, 2], strict=True):
        depth[v - 3:v + 4, u - 3:u + 4] = z - big.config.depth_offset
    rgbd = big.fit(uv, INTR, depth_m=depth)
    assert rgbd.depth_used >= 15
    assert abs(rgbd.pose[2] - q[2]) < 0.015


def test_fit_rejects_malformed_keypoints(model) -> None:
    fitter = KeypointFitter(model)
    with pytest.raises(InputError):
        fitter.fit(np.full((21, 2), np.nan), INTR)
    with pytest.raises(InputError):
        fitter.fit(np.zeros((20, 2)), INTR)


class _ScriptedDetector:
    """Returns the given keypoints (None = no hand) frame by frame."""

    def __init__(self, frames: list) -> None:
        self.frames = list(frames)
        self.resets = 0

    def detect(self, rgb: np.ndarray) -> Detection | None:
        px = self.frames.pop(0)
        if px is None:
            return None
        return Detection(pixels=px, rel_depth=np.zeros(21), world=None, handedness="right",
                         score=0.95)

    def reset(self) -> None:
        self.resets += 1

    def close(self) -> None:
        pass


def test_tracker_status_sequence_and_lost_frames_are_counted(model) -> None:
    qs = _poses(6)
    uv = [project_points(INTR, keypoints21(model, q)) for q in qs]
    rng = np.random.default_rng(2)
    garbage = rng.uniform(0, 480, (21, 2))           # a "hand" no model pose explains
    frames = [uv[0], uv[0], None, uv[1], uv[1], garbage, uv[2]]
    tr = RgbTracker(detector=_ScriptedDetector(frames), shape=model.shape)
    img = np.zeros((480, 640, 3), np.uint8)
    out = [tr.process(img, INTR, stamp_s=0.03 * k) for k in range(len(frames))]
    assert [r.status for r in out] == ["recovering", "tracking", "lost", "recovering",
                                       "tracking", "lost", "recovering"]
    assert out[2].reason == "no_hand" and out[2].pose is None and out[2].confidence == 0.0
    assert out[5].reason == "fit_residual" and out[5].pose is None
    assert tr.counts["lost_no_hand"] == 1 and tr.counts["lost_fit_residual"] == 1
    assert 0.5 < out[1].confidence <= 1.0
    assert np.linalg.norm(out[4].keypoints - keypoints21(model, qs[1]), axis=1).mean() < 0.006


def test_tracker_rejects_an_image_that_does_not_match_the_intrinsics(model) -> None:
    tr = RgbTracker(detector=_ScriptedDetector([None]), shape=model.shape)
    with pytest.raises(InputError):
        tr.process(np.zeros((240, 320, 3), np.uint8), INTR)


def test_mediapipe_finds_no_hand_in_an_empty_image() -> None:
    tr = RgbTracker()
    res = tr.process(np.full((480, 640, 3), 60, np.uint8), INTR)
    assert res.status == "lost" and res.reason == "no_hand" and res.pose is None
    assert tr.counts["lost_no_hand"] == 1
    tr.detector.close()


def test_left_hand_fit_recovers_the_pose() -> None:
    left = HandModel(sample_shape(8), side="left")
    fitter = KeypointFitter(left)
    q = builtin_clip("pinch").sample(1.5)
    q[1] = -q[1]                       # the left hand on the other side of the image
    truth = keypoints21(left, q)
    res = fitter.fit(project_points(INTR, truth), INTR)
    assert res.rms_px < 1.0
    assert np.linalg.norm(res.keypoints - truth, axis=1).mean() < 0.01


def test_rgb_tracker_parameter_file_holds_every_parameter_with_its_default() -> None:
    from ros_helpers import ROOT
    from test_camera_config_files import _check_section

    from hand_capture.config import load_yaml
    from hand_capture.rgbtrack import DetectorConfig, RgbTrackerConfig

    data = load_yaml(ROOT / "config" / "rgb_tracker.yaml")
    p = dict(data["rgb_tracker"]["ros__parameters"])
    _check_section(p.pop("detector"), [DetectorConfig])
    _check_section(p.pop("fit"), [FitConfig])
    from hand_capture.nodes.rgb_tracker import RgbTrackerNodeConfig

    _check_section(p, [RgbTrackerConfig, RgbTrackerNodeConfig])


def test_camera_info_and_image_checks_name_the_problem() -> None:
    from types import SimpleNamespace

    from hand_capture.errors import RejectedInputError
    from hand_capture.validate import validate_camera_info, validate_image_size

    def info(**kw):
        base = dict(k=[500.0, 0, 320, 0, 500.0, 240, 0, 0, 1], d=[0.0] * 5, width=640,
                    height=480, distortion_model="plumb_bob",
                    header=SimpleNamespace(frame_id="cam"))
        return SimpleNamespace(**{**base, **kw})

    intr = validate_camera_info(info(), 640, 480)
    assert (intr.fx, intr.cx, intr.frame_id) == (500.0, 320.0, "cam")
    for bad, text in ((info(k=[float("nan")] * 9), "finite"),
                      (info(k=[0.0, 0, 320, 0, 500.0, 240, 0, 0, 1]), "> 0"),
                      (info(d=[float("inf")] * 5), "distortion"),
                      (info(width=0), "empty"),
                      (info(width=320, height=240), "the image is 640 x 480")):
        with pytest.raises(RejectedInputError, match=text):
            validate_camera_info(bad, 640, 480)
    assert validate_image_size(640, 480, "rgb8", 921600) == (640, 480)
    with pytest.raises(RejectedInputError, match="empty image"):
        validate_image_size(0, 0, "rgb8", 0)
    with pytest.raises(RejectedInputError, match="encoding"):
        validate_image_size(640, 480, "16UC1", 614400)


def test_missing_mediapipe_is_a_clear_error(monkeypatch) -> None:
    import sys

    from hand_capture.cameras.base import DriverNotInstalledError
    from hand_capture.rgbtrack import HandDetector

    for name in ("mediapipe", "mediapipe.python", "mediapipe.python.solutions",
                 "mediapipe.python.solutions.hands"):
        monkeypatch.setitem(sys.modules, name, None)      # as if not installed
    with pytest.raises(DriverNotInstalledError, match="pip install --no-deps mediapipe"):
        HandDetector()
