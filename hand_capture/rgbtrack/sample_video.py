"""The shipped sample video: a skin-coloured hand rendered by the suite, for the webcam graph.

``python -m hand_capture.rgbtrack.sample_video [OUT]`` writes ``data/webcam/hand_pinch.mp4``
(the default): the ``pinch`` then ``wrist_rotation`` clips of the synthetic camera at
640x480, 15 fps, 60 deg horizontal field of view (what ``config/webcam_teleop.yaml`` gives the
OpenCV camera as its nominal intrinsics), MPEG-4 part 2 (``mp4v``, which OpenCV's wheels
write and read without extra codecs). MediaPipe finds the hand in every frame of it
(``test_webcam_teleop.py`` checks a sample of them).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from hand_capture.errors import DeviceError

__all__ = ["SAMPLE_VIDEO", "render_sample_frames", "write_sample_video"]

#: the shipped video, relative to the share folder (``hand_capture.paths.resolve_path``)
SAMPLE_VIDEO = "data/webcam/hand_pinch.mp4"
FPS = 15.0
HFOV_DEG = 60.0


def render_sample_frames(fps: float = FPS, width: int = 640, height: int = 480
                         ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """RGB frames (H, W, 3) uint8 and true poses (27,) of the sample's motion."""
    from hand_capture.cameras import SyntheticCamera, SyntheticCameraConfig

    frames, poses = [], []
    for clip, t0, t1 in (("pinch", 0.0, 3.1), ("wrist_rotation", 0.0, 8.8)):
        cam = SyntheticCamera(SyntheticCameraConfig(
            width=width, height=height, hfov_deg=HFOV_DEG, clip=clip, shape_seed=7,
            skin_color=(0.85, 0.64, 0.53), background_color=(0.30, 0.32, 0.36)))
        cam.open()
        for t in np.arange(t0, t1, 1.0 / fps):
            f = cam.render(float(t), noise=False)
            frames.append(f.color)
            poses.append(f.pose)
    return frames, poses


def write_sample_video(path: str | Path, fps: float = FPS) -> Path:
    """Render the sample and write it as an ``mp4v`` video; returns the path."""
    import cv2

    frames, _ = render_sample_frames(fps)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    if not writer.isOpened():
        raise DeviceError(f"OpenCV cannot write {out} with the mp4v codec")
    for f in frames:
        writer.write(np.ascontiguousarray(f[:, :, ::-1]))
    writer.release()
    return out


if __name__ == "__main__":
    from hand_capture.paths import share_dir

    target = Path(sys.argv[1]) if len(sys.argv) > 1 else share_dir() / SAMPLE_VIDEO
    p = write_sample_video(target)
    print(f"wrote {p} ({p.stat().st_size / 1024:.0f} KiB)")
