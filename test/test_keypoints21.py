"""The common 21-keypoint order, the model's keypoints in it, and HandKeypoints messages."""

from __future__ import annotations

import numpy as np
import pytest
from geometry_msgs.msg import Point
from hand_msgs.msg import HandKeypoints

from hand_capture.errors import InputError, RejectedInputError
from hand_capture.model import JOINT_INDEX, HandModel, rest_pose
from hand_capture.model.keypoints21 import (
    FINGER_INDEX,
    KEYPOINT21_NAMES,
    TIP_INDEX,
    keypoints21,
)
from hand_capture.posemsg import fill_keypoints_msg, keypoints_from_msg
from hand_capture.validate import validate_hand_keypoints_msg


def test_order_is_wrist_then_four_per_finger_base_to_tip() -> None:
    assert KEYPOINT21_NAMES[:5] == ("wrist", "thumb_cmc", "thumb_mcp", "thumb_ip", "thumb_tip")
    assert KEYPOINT21_NAMES[5:9] == ("index_mcp", "index_pip", "index_dip", "index_tip")
    assert KEYPOINT21_NAMES[17:] == ("little_mcp", "little_pip", "little_dip", "little_tip")
    assert [KEYPOINT21_NAMES[i] for i in TIP_INDEX] == [
        "thumb_tip", "index_tip", "middle_tip", "ring_tip", "little_tip"]
    assert list(FINGER_INDEX["ring"]) == [13, 14, 15, 16]


def test_model_keypoints_land_on_their_names() -> None:
    model = HandModel()
    q = rest_pose()
    q[JOINT_INDEX["index_pip_flex"]] = 1.2  # bends index PIP: moves the DIP and tip only
    kp0 = keypoints21(model, rest_pose())
    kp1 = keypoints21(model, q)
    moved = {KEYPOINT21_NAMES[i] for i in np.flatnonzero(np.linalg.norm(kp1 - kp0, axis=1)
                                                          > 1e-6)}
    assert moved == {"index_dip", "index_tip"}
    # the wrist is the root position; the middle tip is the farthest point along +x
    q[0:3] = (0.1, -0.2, 0.3)
    np.testing.assert_allclose(keypoints21(model, q)[0], (0.1, -0.2, 0.3), atol=1e-12)
    assert int(np.argmax(kp0[:, 0])) == KEYPOINT21_NAMES.index("middle_tip")
    # thumb on +y for the right hand, batch shape kept, None = template model
    assert kp0[4, 1] > kp0[8, 1]
    assert keypoints21(None, np.stack([q, q])).shape == (2, 21, 3)


def test_message_round_trip_and_shape_errors() -> None:
    kp = keypoints21(None, rest_pose())
    px = np.arange(42, dtype=float).reshape(21, 2)
    msg = fill_keypoints_msg(HandKeypoints(), kp, px, np.full(21, 0.5), point_type=Point,
                             side="left", status="lost", confidence=0.25, source="t")
    assert msg.handedness == HandKeypoints.HAND_LEFT
    out = keypoints_from_msg(msg)
    np.testing.assert_allclose(out.points, kp)
    np.testing.assert_allclose(out.pixels, px)
    assert (out.side, out.status, out.confidence, out.source) == ("left", 3, 0.25, "t")
    empty = keypoints_from_msg(fill_keypoints_msg(HandKeypoints(), pixels=px))
    assert empty.points is None and empty.scores is None
    with pytest.raises(InputError, match="21"):
        fill_keypoints_msg(HandKeypoints(), kp[:20], point_type=Point)
    with pytest.raises(InputError, match="point_type"):
        fill_keypoints_msg(HandKeypoints(), kp)
    with pytest.raises(InputError, match="20 points"):
        keypoints_from_msg(HandKeypoints(points=[Point()] * 20))


def test_validation_names_nan_keypoints_and_lets_lost_frames_through() -> None:
    kp = keypoints21(None, rest_pose())
    kp[8] = np.nan
    msg = fill_keypoints_msg(HandKeypoints(), kp, point_type=Point)
    with pytest.raises(RejectedInputError, match="index_tip"):
        validate_hand_keypoints_msg(msg)
    lost = fill_keypoints_msg(HandKeypoints(), status="lost")
    pts, side, status = validate_hand_keypoints_msg(lost)
    assert np.isnan(pts).all() and status == 3 and side == "right"
    with pytest.raises(RejectedInputError, match="21 are needed"):
        validate_hand_keypoints_msg(fill_keypoints_msg(HandKeypoints()))


def test_hand_frame_of_model_keypoints_is_the_root_frame() -> None:
    from hand_capture.model import root_rotation_matrix
    from hand_capture.model.keypoints21 import hand_frame_from_keypoints21

    rng = np.random.default_rng(3)
    for side in ("right", "left"):
        q = rest_pose()
        q[0:3] = rng.uniform(-0.3, 0.3, 3)
        q[3:6] = rng.uniform(-1.2, 1.2, 3)
        q[6:] = rng.uniform(-0.2, 0.6, 21)  # finger joints do not move the palm points
        rot, origin = hand_frame_from_keypoints21(keypoints21(None, q, side), side)
        np.testing.assert_allclose(rot, root_rotation_matrix(q[3:6]), atol=1e-9)
        np.testing.assert_allclose(origin, q[0:3], atol=1e-12)
    bad = keypoints21(None, rest_pose())
    bad[5] = np.nan
    with pytest.raises(InputError, match="palm keypoints"):
        hand_frame_from_keypoints21(bad)


def test_hostile_keypoint_messages_are_refused_never_crash() -> None:
    rng = np.random.default_rng(20)
    good = keypoints21(None, rest_pose())
    specials = [np.nan, np.inf, -np.inf, 1e308, -1e12, 0.0]
    for _ in range(300):
        n = int(rng.choice([0, 1, 20, 21, 21, 21, 22, 400]))
        pts = good[np.arange(n) % 21] + rng.normal(0, 0.01, (n, 3))
        if n and rng.random() < 0.5:
            pts[rng.integers(n), rng.integers(3)] = rng.choice(specials)
        msg = HandKeypoints(points=[Point(x=float(a), y=float(b), z=float(c))
                                    for a, b, c in pts])
        msg.status = int(rng.choice([0, 1, 2, 3, 4, 5, 255]))
        msg.handedness = int(rng.choice([0, 1, 2]))
        msg.confidence = float(rng.choice([0.5, 1.0, -0.1, 2.0]))
        try:
            out, side, status = validate_hand_keypoints_msg(msg)
        except RejectedInputError:
            continue
        assert out.shape == (21, 3) and side in ("right", "left") and status in range(5)
        assert np.isfinite(out).all() or (status == 3 and np.isnan(out).all())
        assert np.nan_to_num(np.abs(out)).max() <= 10.0
