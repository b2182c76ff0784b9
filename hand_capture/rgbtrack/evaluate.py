"""Speed and accuracy of the colour tracker on rendered colour images with ground truth.

Two families of images, both 640x480:

* ``suite``: the suite's own renderer (:class:`~hand_capture.cameras.SyntheticCamera`: the
  skinned template mesh, Lambert shading with a light at the camera, skin albedo, colour
  noise) playing the built-in motion clips with sampled hand shapes, with a forearm (an
  elliptic cylinder continuing from the wrist: MediaPipe is trained on photographs, where a
  hand always has one; without it the detector misses more frames, which
  ``rgb_no_forearm_detection_rate`` reports on the same clips);
* ``heldout``: the independent hand surfaces of :mod:`hand_capture.evaldata` (capsules and
  ellipsoids, forearms, their own random motions and camera intrinsics, a table, an object
  and the body behind the hand), which render depth only: here they are shaded in colour
  from the normals of their exact depth (Lambert, light at the camera, a skin albedo drawn
  per sequence, grey-brown clutter, sensor-like noise). Nothing of the tracker was built
  from either (MediaPipe is trained on real photographs; the fit has no learnt part).

Figures (:func:`rgb_tracker_figures`):

* ``rgb_tracker_fps``: frames per second of detect + fit on 640x480 images, in tracking
  mode over the ``suite`` sequences (one BLAS thread), with ``rgb_detector_fps`` (the
  detector alone on the same frames: the baseline the fit's cost is a ratio of) and
  ``rgb_static_detector_fps`` (MediaPipe detecting the palm in every frame);
  ``rgb_tracker_cpu_ms``: CPU time per frame (all threads), which a loaded machine inflates
  less than the wall time;
* ``rgb_keypoint_err_px``: mean 2-D distance between MediaPipe's keypoints and the projected
  true keypoints of the model over detected frames of the ``suite`` family
  (``rgb_heldout_keypoint_err_px`` for the held-out family), with the medians, the error of
  the fitted model's reprojection and of its 3-D keypoints [mm];
* ``rgb_detection_rate`` / ``rgb_heldout_detection_rate``: share of frames with a hand found;
  ``rgb_tracked_rate``: share of frames with status TRACKING or RECOVERING;
* ``rgb_wrist_depth_err_mm`` (colour only, scale from the true shape) and
  ``rgb_rgbd_wrist_depth_err_mm`` (with the aligned depth image): the wrist distance error.

The true keypoints are the model's joint centres; MediaPipe's landmarks follow its own
annotators (e.g. the wrist at the wrist crease, the thumb CMC near the thenar), so part of
the 2-D error is this difference of definitions, which the per-keypoint means show.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from hand_capture.cameras.base import Intrinsics
from hand_capture.cameras.threads import blas_threads
from hand_capture.model import HandModel
from hand_capture.model.keypoints21 import KEYPOINT21_NAMES, MODEL_TO_21
from hand_capture.rgbtrack.detector import DetectorConfig, HandDetector
from hand_capture.rgbtrack.fit import project_points
from hand_capture.rgbtrack.tracker import RgbTracker, RgbTrackerConfig

__all__ = ["RenderedSequence", "forearm_mesh", "heldout_sequences", "rgb_tracker_figures",
           "shade_depth", "suite_sequences"]

SUITE_CLIPS = ("finger_counting", "pinch", "grasp", "wrist_rotation")
SKIN = ((0.87, 0.68, 0.58), (0.80, 0.60, 0.48), (0.62, 0.45, 0.34), (0.92, 0.76, 0.66))


@dataclass
class RenderedSequence:
    """Colour frames with truth: ``images`` (N, H, W, 3) uint8 RGB, ``depth_m`` (N, H, W)
    float32 [m] (0 = none), ``keypoints`` (N, 21, 3) true keypoints [m] (common 21 order),
    ``poses`` (N, 27), the true ``model`` and the pinhole ``intr``; ``fps`` of the motion."""

    name: str
    images: np.ndarray
    depth_m: np.ndarray
    keypoints: np.ndarray
    poses: np.ndarray
    model: HandModel
    intr: Intrinsics
    fps: float


def forearm_mesh(pose: np.ndarray, color: tuple[float, float, float],
                 length: float = 0.24, radius: float = 0.028) -> object:
    """A forearm for the synthetic camera: an elliptic cylinder (``radius`` across the palm,
    3/4 of it dorsal-palmar) of ``length`` [m] along the hand frame's -x from the wrist,
    placed by the pose's root (camera frame), labelled and coloured as the hand."""
    from hand_capture.cameras.primitives import cylinder
    from hand_capture.cameras.render import Mesh
    from hand_capture.cameras.synthetic import HAND_LABEL
    from hand_capture.model.joints import root_rotation_matrix

    v, f = cylinder(radius, length, 24)
    p = v @ np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]).T   # z -> -x
    p[:, 2] *= 0.75
    p[:, 0] -= 0.5 * length - 0.01
    rot = root_rotation_matrix(pose[3:6])
    return Mesh(p @ rot.T + pose[:3], f, HAND_LABEL, tuple(color), closed=False)


def _camera_class(forearm: bool) -> type:
    from hand_capture.cameras import SyntheticCamera

    if not forearm:
        return SyntheticCamera

    class _WithForearm(SyntheticCamera):
        def scene_meshes(self, clip_time: float, pose_cam: np.ndarray) -> tuple:
            meshes, poses = super().scene_meshes(clip_time, pose_cam)
            meshes.append(forearm_mesh(pose_cam, self.config.skin_color))
            return meshes, poses

    return _WithForearm


def suite_sequences(n_frames: int, clips: tuple[str, ...] = SUITE_CLIPS,
                    step: int = 2, forearm: bool = True) -> list[RenderedSequence]:
    """The suite renderer's colour images of ``clips`` (every ``step``-th frame at 30 fps),
    each with a sampled hand shape (seeds 11, 12, ...), with or without a forearm."""
    from hand_capture.cameras import SyntheticCameraConfig

    out = []
    for k, clip in enumerate(clips):
        cfg = SyntheticCameraConfig(width=640, height=480, hfov_deg=60.0, clip=clip,
                                    shape_seed=11 + k, noise_seed=k,
                                    skin_color=SKIN[k % len(SKIN)])
        cam = _camera_class(forearm)(cfg)
        cam.open()
        ims, ds, kps, qs = [], [], [], []
        for i in range(n_frames):
            f = cam.render(0.2 + i * step / 30.0)
            ims.append(f.color)
            ds.append(f.depth.astype(np.float32) * 1e-3)
            kps.append(cam.model.joint_positions(f.pose)[MODEL_TO_21])
            qs.append(f.pose)
        out.append(RenderedSequence(f"suite/{clip}", np.stack(ims), np.stack(ds),
                                    np.stack(kps), np.stack(qs), cam.model, cam.intrinsics,
                                    30.0 / step))
    return out


def shade_depth(depth_m: np.ndarray, labels: np.ndarray, intr: Intrinsics,
                albedo: dict[int, tuple[float, float, float]],
                background: tuple[float, float, float], rng: np.random.Generator,
                ambient: float = 0.35, noise_sd: float = 3.0) -> np.ndarray:
    """Lambert-shaded RGB (light at the camera) of a depth image: normals from the
    back-projected points' image gradients, albedo by label, Gaussian noise [grey levels]."""
    pts = intr.backproject(depth_m)
    du = np.gradient(pts, axis=1)
    dv = np.gradient(pts, axis=0)
    n = np.cross(du, dv)
    n /= np.maximum(np.linalg.norm(n, axis=2, keepdims=True), 1e-12)
    ray = pts / np.maximum(np.linalg.norm(pts, axis=2, keepdims=True), 1e-12)
    cos = np.abs(np.einsum("hwc,hwc->hw", n, ray))
    img = np.empty(depth_m.shape + (3,), np.float32)
    img[:] = np.asarray(background, np.float32)
    for lab, col in albedo.items():
        m = (labels == lab) & (depth_m > 0)
        img[m] = np.asarray(col, np.float32) * (ambient + (1 - ambient) * cos[m, None])
    out = img * 255.0 + rng.normal(0.0, noise_sd, img.shape)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def heldout_sequences(n_seq: int, n_frames: int, step: int = 2) -> list[RenderedSequence]:
    """The held-out surfaces of :mod:`hand_capture.evaldata` shaded in colour (seeds 300+)."""
    from hand_capture.evaldata import make_sequence
    from hand_capture.evaldata.scene import CLUTTER

    out = []
    for k in range(n_seq):
        seq = make_sequence(300 + k, n_frames, "d435_640", forearm=k % 2 == 1,
                            clutter=True, noise=False, step=step)
        rng = np.random.default_rng(300 + k)
        skin = SKIN[(k + 1) % len(SKIN)]
        albedo = {1: skin, 2: skin, 3: (0.25, 0.3, 0.45), CLUTTER: (0.55, 0.5, 0.42)}
        ims, ds = [], []
        for (d_mm, intr), lab in zip(seq.frames, seq.labels, strict=True):
            d = d_mm.astype(np.float32) * 1e-3
            ims.append(shade_depth(d, lab, intr, albedo, (0.2, 0.21, 0.24), rng))
            ds.append(d)
        intr = seq.frames[0][1]
        out.append(RenderedSequence(f"heldout/{k}", np.stack(ims), np.stack(ds),
                                    seq.keypoints[:, MODEL_TO_21], seq.poses, seq.model, intr,
                                    30.0 / step))
    return out


def _run(seqs: list[RenderedSequence], use_depth: bool) -> dict[str, np.ndarray]:
    """Track every sequence (a fresh tracker with the true shape each); per-frame arrays."""
    det_err, fit_err, err3d, wrist_dz, det_ok, good, t_frame, per_kp, cpu = (
        [] for _ in range(9))
    for s in seqs:
        tr = RgbTracker(RgbTrackerConfig(side=s.model.side, use_depth=use_depth),
                        shape=s.model.shape)
        for i in range(len(s.images)):
            t0, c0 = time.perf_counter(), time.process_time()
            r = tr.process(s.images[i], s.intr, stamp_s=i / s.fps,
                           depth_m=s.depth_m[i] if use_depth else None)
            t_frame.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
            truth2d = project_points(s.intr, s.keypoints[i])
            det_ok.append(r.detection is not None)
            good.append(r.good)
            if r.detection is not None:
                e = np.linalg.norm(r.detection.pixels - truth2d, axis=1)
                det_err.append(e.mean())
                per_kp.append(e)
            if r.good:
                fit_err.append(np.linalg.norm(r.fit.projected - truth2d, axis=1).mean())
                err3d.append(np.linalg.norm(r.keypoints - s.keypoints[i], axis=1).mean())
                wrist_dz.append(abs(r.keypoints[0, 2] - s.keypoints[i][0, 2]))
        tr.detector.close()
    arr = {k: np.asarray(v, float) for k, v in (
        ("det_err", det_err), ("fit_err", fit_err), ("err3d", err3d), ("wrist_dz", wrist_dz),
        ("det_ok", det_ok), ("good", good), ("t_frame", t_frame), ("cpu", cpu))}
    arr["per_kp"] = np.asarray(per_kp).reshape(-1, 21)
    return arr


def _detection_rate(seqs: list[RenderedSequence]) -> float:
    n = found = 0
    for s in seqs:
        det = HandDetector()
        for im in s.images:
            found += det.detect(im) is not None
            n += 1
        det.close()
    return found / max(n, 1)


def _detector_fps(seqs: list[RenderedSequence], static: bool) -> float:
    n, t = 0, 0.0
    for s in seqs:
        det = HandDetector(DetectorConfig(static_image_mode=static))
        det.detect(s.images[0])   # warm-up (graph start)
        t0 = time.perf_counter()
        for im in s.images:
            det.detect(im)
        t += time.perf_counter() - t0
        n += len(s.images)
        det.close()
    return n / max(t, 1e-9)


def _mean(x: np.ndarray) -> float:
    return float(np.mean(x)) if len(x) else float("nan")


def _median(x: np.ndarray) -> float:
    return float(np.median(x)) if len(x) else float("nan")


def rgb_tracker_figures(quick: bool = False, smoke: bool = False,
                        verbose: bool = False) -> dict:
    """The colour tracker's figures (module docstring); ``verbose`` prints the tables.

    Sizes: full 4 clips x 60 frames + 4 held-out sequences x 60 frames; quick 2 x 30 +
    2 x 30; smoke 1 x 8 + 1 x 8.
    """
    n_clip, n_frames, n_held = (1, 8, 1) if smoke else (2, 30, 2) if quick else (4, 60, 4)
    suite = suite_sequences(n_frames, SUITE_CLIPS[:n_clip] if n_clip < 4 else SUITE_CLIPS)
    held = heldout_sequences(n_held, n_frames)
    with blas_threads(1):
        _run(suite[:1], False) if not smoke else None  # warm caches (first graph start)
        s_rgb = _run(suite, False)
        s_rgbd = _run(suite, True)
        h_rgb = _run(held, False)
        h_rgbd = _run(held, True)
        bare = _detection_rate(suite_sequences(
            n_frames, SUITE_CLIPS[:n_clip] if n_clip < 4 else SUITE_CLIPS, forearm=False))
        det_fps = _detector_fps(suite, static=False)
        static_fps = _detector_fps(suite, static=True)
    fps = len(s_rgb["t_frame"]) / max(float(np.sum(s_rgb["t_frame"])), 1e-9)
    fig = {
        "rgb_tracker_fps": round(fps, 1),
        "rgb_tracker_ms_p50": round(1e3 * _median(s_rgb["t_frame"]), 2),
        "rgb_tracker_cpu_ms": round(1e3 * _mean(s_rgb["cpu"]), 2),
        "rgb_detector_fps": round(det_fps, 1),
        "rgb_static_detector_fps": round(static_fps, 1),
        "rgb_fps_vs_detector": round(fps / max(det_fps, 1e-9), 3),
        "rgb_keypoint_err_px": round(_mean(s_rgb["det_err"]), 2),
        "rgb_keypoint_err_px_p50": round(_median(s_rgb["det_err"]), 2),
        "rgb_fit_reproj_err_px": round(_mean(s_rgb["fit_err"]), 2),
        "rgb_detection_rate": round(_mean(s_rgb["det_ok"]), 3),
        "rgb_tracked_rate": round(_mean(s_rgb["good"]), 3),
        "rgb_no_forearm_detection_rate": round(bare, 3),
        "rgb_keypoint_3d_err_mm": round(1e3 * _median(s_rgb["err3d"]), 1),
        "rgb_wrist_depth_err_mm": round(1e3 * _median(s_rgb["wrist_dz"]), 1),
        "rgb_rgbd_keypoint_3d_err_mm": round(1e3 * _median(s_rgbd["err3d"]), 1),
        "rgb_rgbd_wrist_depth_err_mm": round(1e3 * _median(s_rgbd["wrist_dz"]), 1),
        "rgb_heldout_keypoint_err_px": round(_mean(h_rgb["det_err"]), 2),
        "rgb_heldout_keypoint_err_px_p50": round(_median(h_rgb["det_err"]), 2),
        "rgb_heldout_detection_rate": round(_mean(h_rgb["det_ok"]), 3),
        "rgb_heldout_tracked_rate": round(_mean(h_rgb["good"]), 3),
        "rgb_heldout_keypoint_3d_err_mm": round(1e3 * _median(h_rgb["err3d"]), 1),
        "rgb_heldout_rgbd_keypoint_3d_err_mm": round(1e3 * _median(h_rgbd["err3d"]), 1),
        "rgb_heldout_rgbd_wrist_depth_err_mm": round(1e3 * _median(h_rgbd["wrist_dz"]), 1),
        "rgb_frames": int(len(s_rgb["t_frame"])),
        "rgb_heldout_frames": int(len(h_rgb["t_frame"])),
    }
    if verbose:
        from hand_capture.bench import print_table

        rows = []
        for name, a, b in (("suite renderer", s_rgb, s_rgbd), ("held-out surfaces", h_rgb,
                                                               h_rgbd)):
            rows.append([name, len(a["t_frame"]), f"{_mean(a['det_ok']):.2f}",
                         f"{_mean(a['good']):.2f}", f"{_mean(a['det_err']):.1f}",
                         f"{_median(a['det_err']):.1f}", f"{_mean(a['fit_err']):.1f}",
                         f"{1e3 * _median(a['err3d']):.0f}",
                         f"{1e3 * _median(b['err3d']):.0f}",
                         f"{1e3 * _median(a['wrist_dz']):.0f}",
                         f"{1e3 * _median(b['wrist_dz']):.0f}"])
        print_table("Colour tracker on rendered 640x480 images (median 3-D errors)",
                    ["images", "frames", "detected", "tracked", "2-D err px",
                     "p50 px", "fit reproj px", "3-D mm rgb", "3-D mm rgbd", "wrist z mm rgb",
                     "wrist z mm rgbd"], rows)
        print_table("Speed (one BLAS thread)", ["stage", "fps"],
                    [["detect + fit (tracking mode)", f"{fps:.1f}"],
                     ["detector alone (baseline)", f"{det_fps:.1f}"],
                     ["detector, palm detection every frame", f"{static_fps:.1f}"]])
        kp = np.concatenate([s_rgb["per_kp"], h_rgb["per_kp"]])
        if len(kp):
            m = kp.mean(axis=0)
            print_table("Worst keypoints (2-D, both families)", ["keypoint", "mean err px"],
                        [[KEYPOINT21_NAMES[i], f"{m[i]:.1f}"] for i in np.argsort(-m)[:6]])
    return fig
