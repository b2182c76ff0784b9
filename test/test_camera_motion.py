"""Motion clips for the synthetic camera: interpolation, joint limits, pose files (no ROS)."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.cameras.motion import (
    BASE_POSE,
    CLIPS,
    Keyframe,
    MotionClip,
    builtin_clip,
    load_motion,
    save_pose_sequence,
)
from hand_capture.errors import ConfigError, InputError
from hand_capture.model.joints import JOINT_INDEX, JOINT_LIMITS, JOINT_NAMES, within_limits


@pytest.mark.parametrize("name", sorted(CLIPS))
def test_builtin_clips_stay_within_joint_limits_and_loop_smoothly(name):
    clip = builtin_clip(name)
    ts = np.linspace(0.0, max(clip.duration, 1e-3), 400)
    q = clip.sample_many(ts)
    assert q.shape == (400, 27) and np.all(np.isfinite(q))
    assert within_limits(q).all()
    # the keyframes themselves are inside the limits (no clamping hides a bad key)
    art = slice(6, 27)
    assert np.all(clip.poses[:, art] >= JOINT_LIMITS[art, 0] - 1e-12)
    assert np.all(clip.poses[:, art] <= JOINT_LIMITS[art, 1] + 1e-12)
    # continuous: no jump between samples 1/400 of the clip apart, and it loops back
    assert np.abs(np.diff(q, axis=0)).max() < 0.1
    assert np.allclose(clip.sample(0.0), clip.sample(clip.duration), atol=1e-9)
    if clip.duration > 0:
        assert not np.allclose(q.min(0), q.max(0))  # it moves


def test_keyframes_interpolate_with_ease_in_out():
    clip = MotionClip.from_keyframes("t", [
        Keyframe(0.0, {"index_mcp_flex": 0.0, "root_tz": 0.4}),
        Keyframe(2.0, {"index_mcp_flex": 1.0}),
        Keyframe(3.0, {"root_tz": 0.5}),
    ], loop=False)
    i, z = JOINT_INDEX["index_mcp_flex"], JOINT_INDEX["root_tz"]
    assert clip.duration == 3.0
    assert clip.sample(0.0)[i] == 0.0 and clip.sample(2.0)[i] == pytest.approx(1.0)
    assert clip.sample(1.0)[i] == pytest.approx(0.5)  # smoothstep midpoint
    assert clip.sample(0.5)[i] == pytest.approx(3 * 0.25**2 - 2 * 0.25**3)
    # a joint not named in a keyframe holds its previous value
    assert clip.sample(1.3)[z] == pytest.approx(0.4)
    assert clip.sample(2.5)[z] == pytest.approx(0.45)
    # unnamed joints come from the base pose; past the end the last pose holds (no loop)
    assert clip.sample(10.0)[z] == pytest.approx(0.5)
    j = JOINT_INDEX["root_ry"]
    assert clip.sample(1.0)[j] == BASE_POSE[j]
    # linear interpolation and looping
    lin = MotionClip(clip.name, clip.times, clip.poses, interpolation="linear", loop=True)
    assert lin.sample(0.5)[i] == pytest.approx(0.25)
    assert lin.sample(3.5)[i] == pytest.approx(lin.sample(0.5)[i])


def test_samples_are_clamped_to_joint_limits():
    i = JOINT_INDEX["index_pip_flex"]
    clip = MotionClip.from_keyframes("t", [Keyframe(0.0, {"index_pip_flex": 5.0})])
    assert clip.sample(0.0)[i] == pytest.approx(JOINT_LIMITS[i, 1])


def test_grasp_clip_moves_its_object_with_the_hand():
    clip = builtin_clip("grasp")
    assert [o.name for o in clip.objects] == ["ball"]
    start = clip.object_positions(0.0)["ball"]
    lifted = clip.object_positions(3.6)["ball"]
    ty = JOINT_INDEX["root_ty"]
    dy_hand = clip.sample(3.6)[ty] - clip.sample(2.2)[ty]
    assert lifted[1] - start[1] == pytest.approx(dy_hand, abs=1e-9)
    assert np.allclose(clip.object_positions(clip.duration)["ball"], start)


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_pose_files_round_trip(tmp_path, suffix):
    clip = builtin_clip("fist")
    ts = np.linspace(0.0, clip.duration, 25)
    poses = clip.sample_many(ts)
    path = tmp_path / f"seq{suffix}"
    save_pose_sequence(path, ts, poses)
    loaded = load_motion("static", str(path), loop=False)
    assert loaded.interpolation == "linear"
    assert np.allclose(loaded.sample_many(ts), poses, atol=1e-12)
    mid = 0.5 * (ts[3] + ts[4])
    assert np.allclose(loaded.sample(mid), 0.5 * (poses[3] + poses[4]), atol=1e-9)


def test_csv_with_a_subset_of_joints_and_no_time(tmp_path):
    path = tmp_path / "few.csv"
    path.write_text("index_mcp_flex,thumb_ip_flex\n0.1,0.2\n0.3,0.4\n")
    clip = MotionClip.from_file(path, rate=10.0, loop=False)
    assert clip.duration == pytest.approx(0.1)
    q = clip.sample(0.1)
    assert q[JOINT_INDEX["index_mcp_flex"]] == pytest.approx(0.3)
    others = [k for k in range(27) if JOINT_NAMES[k] not in ("index_mcp_flex",
                                                                "thumb_ip_flex")]
    assert np.allclose(q[others], BASE_POSE[others])


def test_bad_pose_files_and_names_are_rejected(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("time,index_mcp_flex,pinky_bend\n0,0.1,0.2\n")
    with pytest.raises(InputError, match="pinky_bend"):
        MotionClip.from_file(bad)
    nan = tmp_path / "nan.csv"
    nan.write_text("index_mcp_flex\nnan\n")
    with pytest.raises(InputError, match="NaN"):
        MotionClip.from_file(nan)
    back = tmp_path / "back.csv"
    back.write_text("time,index_mcp_flex\n1.0,0\n0.5,0\n")
    with pytest.raises(InputError, match="increasing"):
        MotionClip.from_file(back)
    with pytest.raises(ConfigError, match="not found"):
        MotionClip.from_file(tmp_path / "missing.npz")
    with pytest.raises(ConfigError, match="format"):
        MotionClip.from_file(bad.rename(tmp_path / "bad.txt"))
    npz = tmp_path / "x.npz"
    np.savez(npz, poses=np.zeros((2, 27)))
    with pytest.raises(InputError, match="joint_names"):
        MotionClip.from_file(npz)
    with pytest.raises(ConfigError, match="valid"):
        builtin_clip("moonwalk")
    with pytest.raises(InputError, match="unknown joint"):
        MotionClip.from_keyframes("x", [Keyframe(0.0, {"elbow": 1.0})])
