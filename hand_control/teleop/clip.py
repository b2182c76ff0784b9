"""The embedded teleoperation performance: an operator's reach-grasp-lift, and where the camera is.

The README's main job runs teleoperation without hardware: the synthetic camera renders an
operator's hand performing a reach, grasp, lift, carry, put-down and release of the object of a
scenario, and the tracker, the grasp-phase detector, the controller and the simulation take it
from there. So that the performance meets the simulated object, it is built from the scenario's
own grasp plan (fingertip IK onto the object, :func:`hand_control.sim.grasp.plan_grasp`), in the
simulation's world frame:

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
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hand_capture.cameras.motion import (
    R_PALM_TO_CAMERA,
    Keyframe,
    MotionClip,
    save_pose_sequence,
)
from hand_capture.cameras.transforms import matrix_to_rotvec
from hand_capture.model.joints import JOINT_NAMES, pose_to_dict, root_rotation_matrix
from hand_capture.paths import data_dir
from hand_control.sim.grasp import GraspPlan

__all__ = ["TeleopPerformance", "camera_pose_for", "teleop_performance"]


_LONG_FINGER_JOINTS = [JOINT_NAMES.index(f"{f}_{j}") for f in ("index", "middle", "ring", "little")
                       for j in ("mcp_flex", "pip_flex", "dip_flex")]

#: Keyframe times of the performance [s] (durations of each segment, in order).
SEGMENTS: tuple[tuple[str, float], ...] = (
    ("reach", 1.2), ("close", 0.8), ("settle", 0.7), ("lift", 1.0), ("carry", 1.0),
    ("hold", 0.5), ("put_down", 1.0), ("release", 0.6), ("withdraw", 0.8))


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


def teleop_performance(plan: GraspPlan, *, lift: float = 0.10,
                       carry: tuple[float, float, float] = (0.0, 0.10, 0.0),
                       approach: float = 0.10, open_flexion: float = 0.1,
                       rate: float = 60.0) -> TeleopPerformance:
    """The reach-grasp-lift performance of :data:`SEGMENTS` for a planned grasp.

    Args:
        plan: the scenario's grasp (world frame).
        lift: height of the lift [m].
        carry: displacement while carrying [m].
        approach: the hand starts this far above the pre-grasp [m].
        open_flexion: flexion of the four fingers' joints in the open hand [rad].
        rate: sampling rate of the returned sequence [Hz].
    """
    grasp = plan.q_grasp
    # the operator reaches with an open hand (fingers extended, the pre-grasp's wrist and
    # thumb opposition) so that closing and releasing change the grip size clearly
    pre = plan.q_pregrasp.copy()
    pre[_LONG_FINGER_JOINTS] = open_flexion
    start = pre.copy()
    start[2] += approach

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
    """The performance of a scenario file's object (its grasp planned as the sim does)."""
    from hand_control.sim.lockstep import LockstepRunner
    from hand_control.sim.scenario import load_scenario

    spec = load_scenario(scenario)
    runner = LockstepRunner(spec)
    return teleop_performance(runner.plan, lift=spec.lift_height,
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
