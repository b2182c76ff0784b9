"""The embedded teleoperation performance: an operator's reach-grasp-lift, and where the camera is.

The README's main job runs teleoperation without hardware: the synthetic camera renders an
operator's hand performing a reach, grasp, lift, carry, put-down and release of the object of a
scenario, and the tracker, the grasp-phase detector, the controller and the simulation take it
from there. The performance is authored like a human one, independently of the controller's
grasp plan (the fingertip IK that retargeting later puts in place of the tracked fingers), so
that "the box is lifted" tests the tracking and the retargeting, not a plan fed back to itself:

* the hand shapes are two human grasp keyframes (the clip library's flat hand
  :data:`hand_capture.cameras.motion.OPEN`, and
  :data:`TOP_GRASP`, a closed top grasp, fingers curled and thumb opposed); the closed
  shape is the blend between them whose thumb-to-fingers aperture equals the object's width
  (less a squeeze), found by bisection on forward kinematics;
* the wrist comes from above, palm down, fingers forward and pitched down by ``pitch`` (the
  usual human top grasp), with the palm centre ``palm_clearance`` above the object's top;
* the keyframes, in the simulation's world frame:

    start (open, raised and drawn back) -> pre-grasp -> grasp (closing) -> hold still (the grip
    settles) -> lift -> carry -> hold -> put down -> open (release) -> withdraw

The camera pose is the teleoperation mapping from the operator's space to the world: the camera
optical frame expressed in the world. It is chosen so that at the grasp the operator's palm
faces the camera, fingers up, as the tracker is trained to see hands (``tracking/train.py``),
at ``distance`` from the palm. With a top grasp that puts the virtual camera under the
(transparent) table; the operator simply shows the palm to a real camera.

``python -m hand_control.teleop.clip [--scenario lift_box] [--out FILE]`` regenerates the
shipped ``data/teleop/<scenario>.npz`` and prints the camera pose for ``config/teleop.yaml``.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hand_capture.cameras.motion import (
    OPEN,
    R_PALM_TO_CAMERA,
    Keyframe,
    MotionClip,
    save_pose_sequence,
)
from hand_capture.cameras.transforms import matrix_to_rotvec
from hand_capture.errors import ConfigError
from hand_capture.model import HandModel
from hand_capture.model.joints import (
    JOINT_INDEX,
    pose_from_dict,
    pose_to_dict,
    root_angles_from_matrix,
    root_rotation_matrix,
)
from hand_capture.paths import data_dir
from hand_control.teleop.phases import palm_center

__all__ = ["TOP_GRASP", "TeleopPerformance", "camera_pose_for", "closed_hand_for_aperture",
           "operator_performance"]

#: Keyframe times of the performance [s] (durations of each segment, in order).
SEGMENTS: tuple[tuple[str, float], ...] = (
    ("reach", 1.2), ("close", 0.8), ("settle", 0.7), ("lift", 1.0), ("carry", 1.0),
    ("hold", 0.5), ("put_down", 1.0), ("release", 0.6), ("withdraw", 0.8))

_D = math.radians
#: Keyframe of a closed human top grasp (authored, joint angles in degrees): the four fingers
#: curled (MCP 60, PIP 60, DIP 30), the thumb opposed; thumb-to-fingers aperture 27 mm.
TOP_GRASP: dict[str, float] = {
    **{f"{f}_{j}": _D(a) for f in ("index", "middle", "ring", "little")
       for j, a in (("mcp_abd", 0.0), ("mcp_flex", 60.0), ("pip_flex", 60.0),
                    ("dip_flex", 30.0))},
    "thumb_tm_abd": _D(30.0), "thumb_tm_flex": _D(30.0), "thumb_mcp_abd": 0.0,
    "thumb_mcp_flex": _D(20.0), "thumb_ip_flex": _D(15.0)}
_FINGER_JOINTS = [JOINT_INDEX[k] for k in OPEN]  # the joints the two keyframes set
_THUMB_TIP, _FINGER_TIPS = 4, (8, 12)  # keypoints: thumb tip; index and middle tips


@dataclass(frozen=True)
class TeleopPerformance:
    """An operator performance in the world frame and the camera that sees it."""

    times: np.ndarray            # (T,) [s]
    poses: np.ndarray            # (T, 27) world-frame hand poses (JOINT_NAMES order)
    camera_position: np.ndarray  # (3,) camera optical centre in the world [m]
    camera_rotation: np.ndarray  # (3,) camera orientation in the world, rotation vector [rad]


def camera_pose_for(q_grasp: np.ndarray, distance: float = 0.42
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Camera (position [m], rotation vector [rad]) in the world that sees the wrist of the
    world-frame pose ``q_grasp`` palm-on at ``distance`` [m] (camera +z through the wrist)."""
    R_world_root = root_rotation_matrix(q_grasp[3:6])
    R_wc = R_world_root @ R_PALM_TO_CAMERA.T  # so that R_wc^T R_world_root = palm-on
    t_wc = q_grasp[0:3] - R_wc @ np.array([0.0, 0.0, distance])
    return t_wc, matrix_to_rotvec(R_wc)


def _aperture(model: HandModel, q: np.ndarray) -> float:
    """Thumb tip to the mean of the index and middle tips [m]."""
    kp = model.joint_positions(q)
    return float(np.linalg.norm(kp[_THUMB_TIP] - kp[list(_FINGER_TIPS)].mean(axis=0)))


def closed_hand_for_aperture(aperture: float, model: HandModel | None = None
                             ) -> tuple[np.ndarray, float]:
    """The blend ``(1 - s) OPEN + s TOP_GRASP`` of the two human keyframes whose aperture is
    ``aperture`` [m] (bisection on ``s``; the aperture shrinks as ``s`` grows).

    Returns:
        (27,) pose (root at the origin, identity rotation) and ``s``.

    Raises:
        ConfigError: ``aperture`` is outside what the keyframes span.
    """
    model = model or HandModel()
    q_open, q_closed = pose_from_dict(OPEN), pose_from_dict(TOP_GRASP)

    def pose(s: float) -> np.ndarray:
        q = np.zeros(27)
        q[_FINGER_JOINTS] = (1 - s) * q_open[_FINGER_JOINTS] + s * q_closed[_FINGER_JOINTS]
        return q

    hi, lo = _aperture(model, pose(0.0)), _aperture(model, pose(1.0))
    if not lo <= aperture <= hi:
        raise ConfigError(f"grasp aperture {aperture * 1e3:.1f} mm is outside what the hand "
                          f"keyframes span [{lo * 1e3:.1f}, {hi * 1e3:.1f}] mm")
    a, b = 0.0, 1.0
    for _ in range(40):
        m = 0.5 * (a + b)
        a, b = (m, b) if _aperture(model, pose(m)) > aperture else (a, m)
    s = 0.5 * (a + b)
    return pose(s), s


def operator_performance(center: Sequence[float], width: float, top: float, *,
                         lift: float = 0.10,
                         carry: tuple[float, float, float] = (0.0, 0.10, 0.0),
                         pitch_deg: float = 25.0, palm_clearance: float = 0.03,
                         squeeze: float = 0.02, approach: float = 0.15,
                         rate: float = 60.0) -> TeleopPerformance:
    """The reach-grasp-lift performance of :data:`SEGMENTS` for an object (module docstring).

    Args:
        center: (3,) the object's centre in the world [m].
        width: the object's width between the grasping fingers [m].
        top: height of the object's top above its centre [m].
        lift: height of the lift [m].
        carry: displacement while carrying [m].
        pitch_deg: the fingers point this far down from horizontal [deg].
        palm_clearance: the palm centre this far above the object's top at the grasp [m].
        squeeze: the closed hand's aperture is the width less this [m] (the operator holds
            nothing, and closes a little further than the object).
        approach: the hand starts this far above (and half as far behind) the pre-grasp [m].
        rate: sampling rate of the returned sequence [Hz].
    """
    model = HandModel()
    q_closed, _ = closed_hand_for_aperture(width - squeeze, model)
    q_open = pose_from_dict(OPEN)
    p = math.radians(pitch_deg)
    # palm down, fingers along world +x pitched down (rotation about world +y), thumb to +y
    R = np.array([[math.cos(p), 0.0, math.sin(p)], [0.0, 1.0, 0.0],
                  [-math.sin(p), 0.0, math.cos(p)]])
    root = np.array(root_angles_from_matrix(R))

    def hand(q_shape: np.ndarray, palm_at: np.ndarray) -> np.ndarray:
        """``q_shape``'s fingers with the wrist placed so that the palm centre is at
        ``palm_at`` (palm centre from FK of that very hand shape)."""
        q = q_shape.copy()
        q[3:6] = root
        q[0:3] = 0.0
        q[0:3] = palm_at - palm_center(model.joint_positions(q))
        return q

    c = np.asarray(center, dtype=np.float64)
    palm_grasp = c + np.array([0.0, 0.0, top + palm_clearance])
    grasp = hand(q_closed, palm_grasp)
    pre = hand(q_open, palm_grasp + np.array([0.0, 0.0, 0.03]))
    start = hand(q_open, palm_grasp + np.array([-0.5 * approach, 0.0, approach]))

    def at(q: np.ndarray, dz: float = 0.0, dxyz=(0.0, 0.0, 0.0)) -> dict[str, float]:
        out = q.copy()
        out[0:3] += np.asarray(dxyz) + np.array([0.0, 0.0, dz])
        return pose_to_dict(out)

    moved = np.asarray(carry, dtype=float)
    poses = {
        "reach": at(pre), "close": at(grasp), "settle": at(grasp),
        "lift": at(grasp, lift), "carry": at(grasp, lift, moved), "hold": at(grasp, lift, moved),
        "put_down": at(grasp, 0.0, moved), "release": at(pre, 0.0, moved),
        "withdraw": at(pre, approach, moved),
    }
    kfs, t = [Keyframe(0.0, pose_to_dict(start))], 0.0
    for name, dt in SEGMENTS:
        t += dt
        kfs.append(Keyframe(t, poses[name]))
    clip = MotionClip.from_keyframes("teleop", kfs, base=start, loop=False)
    times = np.arange(0.0, clip.duration + 1e-9, 1.0 / rate)
    q = clip.sample_many(times)
    cam_t, cam_r = camera_pose_for(grasp)
    return TeleopPerformance(times, q, cam_t, cam_r)


def shipped_path(scenario: str) -> Path:
    """``data/teleop/<scenario>.npz``."""
    return data_dir() / "teleop" / f"{scenario}.npz"


def performance_for_scenario(scenario: str) -> TeleopPerformance:
    """The performance for a scenario file's object: its geometry and resting place only (no
    grasp plan)."""
    from hand_control.sim.lockstep import object_spec
    from hand_control.sim.scenario import load_scenario

    spec = load_scenario(scenario)
    obj, size = object_spec(spec)
    if spec.object_kind == "box":
        width, top = 2.0 * min(size[0], size[1]), size[2]
    elif spec.object_kind == "ball":
        width, top = 2.0 * size[0], size[0]
    else:  # an upright cylinder
        width, top = 2.0 * size[0], size[1]
    return operator_performance(obj.pos, width, top, lift=spec.lift_height,
                                carry=tuple(spec.carry_offset))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m hand_control.teleop.clip",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--scenario", default="lift_box")
    ap.add_argument("--out", default=None, help="npz file (default: the shipped one)")
    a = ap.parse_args(argv)
    perf = performance_for_scenario(a.scenario)
    out = Path(a.out) if a.out else shipped_path(a.scenario)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_pose_sequence(out, perf.times, perf.poses)
    fmt = ", ".join
    print(f"wrote {out} ({len(perf.times)} poses, {perf.times[-1]:.2f} s)")
    print(f"camera_position: [{fmt(f'{v:.6f}' for v in perf.camera_position)}]")
    print(f"camera_rotation: [{fmt(f'{v:.6f}' for v in perf.camera_rotation)}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
