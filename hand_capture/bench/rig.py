"""Benchmark of the multi-view rig (``hand-suite bench rig``): studio rendering, frame
synchronisation and ChArUco calibration of the shipped 6-camera rig (config/rigs/studio6.yaml).

* **Studio**: complete groups (colour + depth + segmentation from all six 640x480 cameras) of a
  moving hand and a box, one renderer reused with shadows/reflections/skybox off; then the
  same groups with the cameras split over two processes (:class:`ParallelStudio`). Baseline in
  the same run: one camera at a time with a fresh ``mujoco.Renderer`` per view and MuJoCo's
  default rendering (three ``render()`` calls: colour, depth, segmentation).
* **Synchroniser**: six free-running 20 fps streams (seed 000's rate) with clock offsets,
  jitter and dropped frames pushed through :class:`FrameSynchronizer`: frames per second and
  the largest stamp spread inside a group.
* **Calibration**: ChArUco views rendered into every camera (the rig given radial/tangential
  distortion, sensor noise added), calibrated by :func:`calibrate_rig` and compared with the
  true poses: reprojection RMS and extrinsic errors (worst camera).

JSON keys: ``views_per_s``, ``groups_per_s``, ``parallel_groups_per_s``,
``baseline_views_per_s``, ``speedup``, ``sync_frames_per_s``, ``sync_max_skew_ms``,
``sync_dropped``, ``calib_reproj_px``, ``calib_extrinsic_mm``, ``calib_extrinsic_deg``,
``calib_views``.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any

import numpy as np

from hand_capture.bench import print_table

RIG = "studio6"


def _studio(quick: bool, smoke: bool = False) -> dict[str, float]:
    import mujoco

    from hand_capture.multiview.rig import load_rig
    from hand_capture.multiview.studio import (
        ParallelStudio,
        Studio,
        StudioNoise,
        studio_motion,
        studio_scene,
    )

    rig = load_rig(RIG)
    poses = studio_motion(1 if smoke else 4 if quick else 20)
    with Studio(rig, studio_scene(["box"]), StudioNoise()) as st:
        st.set_state(poses[0])
        st.render_all()  # warm-up (context, textures)
        t0 = time.perf_counter()
        for q in poses:
            st.set_state(q)
            st.render_all()
        dt = time.perf_counter() - t0
        model, data = st.model, st.data
        n_views = len(poses) * len(rig)
        # Baseline: one camera at a time, a fresh renderer per view, default rendering.
        n_base = 1 if smoke else 3 if quick else 12
        t0 = time.perf_counter()
        for i in range(n_base):
            r = mujoco.Renderer(model, height=st.height, width=st.width)
            cam = i % len(rig)
            r.update_scene(data, camera=cam)
            r.render()
            r.enable_depth_rendering()
            r.update_scene(data, camera=cam)
            r.render()
            r.disable_depth_rendering()
            r.enable_segmentation_rendering()
            r.update_scene(data, camera=cam)
            r.render()
            r.close()
        dt_base = time.perf_counter() - t0
        qpos = np.repeat(st.data.qpos[None], len(poses), axis=0)
    qpos[:, :27] = poses
    # The same groups with the cameras split over two processes (one per core).
    with ParallelStudio(rig, ["box"], noise=StudioNoise(), workers=2) as par:
        par.render_all(qpos[0])
        t0 = time.perf_counter()
        for q in qpos:
            par.render_all(q)
        dt_par = time.perf_counter() - t0
    views = n_views / dt
    base = n_base / dt_base
    par_views = n_views / dt_par
    print_table(f"studio: {len(rig)} cameras at {st.width}x{st.height}, colour + depth + "
                "segmentation", ["renderer", "views", "views/s", "groups/s"],
                [["studio (one pass colour+depth, no shadows)", n_views, views,
                  views / len(rig)],
                 ["studio, cameras over 2 processes", n_views, par_views,
                  par_views / len(rig)],
                 ["baseline (fresh Renderer per view, defaults)", n_base, base,
                  base / len(rig)]])
    return {"views_per_s": views, "groups_per_s": views / len(rig),
            "parallel_groups_per_s": par_views / len(rig),
            "baseline_views_per_s": base, "speedup": views / base}


def _sync(quick: bool, smoke: bool = False) -> dict[str, float]:
    from hand_capture.multiview.studio import jittered_stamps
    from hand_capture.multiview.sync import FrameSynchronizer, SyncConfig

    n_cam, n = 6, (100 if smoke else 600 if quick else 6000)
    stamps = jittered_stamps(n, 20.0, n_cam, jitter_s=0.002,
                             offsets_s=[0.0, 0.003, -0.002, 0.001, -0.003, 0.002], seed=1)
    rng = np.random.default_rng(2)
    keep = rng.random(stamps.shape) > 0.01  # 1 % of frames lost
    events = sorted((stamps[k, c] + rng.uniform(0.005, 0.015), c, stamps[k, c])
                    for k in range(n) for c in range(n_cam) if keep[k, c])
    names = [f"cam{c}" for c in range(n_cam)]
    sync = FrameSynchronizer(names, SyncConfig(tolerance_s=0.012))
    t0 = time.perf_counter()
    for arrival, c, s in events:
        sync.push(names[c], s, None, arrival)
    dt = time.perf_counter() - t0
    st = sync.stats
    print_table("synchroniser: 6 cameras, 20 fps, offsets up to 3 ms, jitter 2 ms, 1 % lost",
                ["frames", "frames/s", "groups", "dropped", "max skew [ms]"],
                [[len(events), len(events) / dt, st.groups, st.dropped,
                  st.max_skew_s * 1e3]])
    return {"sync_frames_per_s": len(events) / dt, "sync_max_skew_ms": st.max_skew_s * 1e3,
            "sync_groups": st.groups, "sync_dropped": st.dropped}


def _calibration(quick: bool, smoke: bool = False) -> dict[str, float]:
    from hand_capture.multiview.calibrate import WORLD_FROM_BOARD, calibrate_rig, compare_rigs
    from hand_capture.multiview.charuco import BoardSpec, render_board_view, sample_board_poses
    from hand_capture.multiview.rig import Rig, load_rig

    base = load_rig(RIG)
    dist = (-0.08, 0.03, 0.0005, -0.0004, 0.0)
    truth = Rig(base.name, tuple(replace(c, intrinsics=replace(c.intrinsics, distortion=dist))
                                 for c in base.cameras))
    spec = BoardSpec()
    n_views = 14 if smoke else 16 if quick else 50
    poses = sample_board_poses(spec, truth, n_views, seed=7)
    rng = np.random.default_rng(0)
    images: dict[str, list[np.ndarray]] = {c.name: [] for c in truth.cameras}
    for T in poses:
        for cam in truth.cameras:
            img = render_board_view(spec, cam, T, supersample=1 if quick else 2)
            images[cam.name].append(np.clip(img + rng.normal(0.0, 2.0, img.shape), 0, 255)
                                    .astype(np.uint8))
    res = calibrate_rig(images, spec, name="calibrated")
    est = res.rig.transformed(poses[0] @ np.linalg.inv(WORLD_FROM_BOARD))
    err = compare_rigs(est, truth)
    print_table(f"calibration: {n_views} ChArUco views, sensor noise 2/255, distortion {dist}",
                ["camera", "views", "reprojection RMS [px]", "position [mm]", "rotation [deg]"],
                [[c, res.observations[c], res.reproj_px[c], *err[c]] for c in truth.names])
    return {"calib_reproj_px": max(res.reproj_px.values()),
            "calib_extrinsic_mm": max(e[0] for e in err.values()),
            "calib_extrinsic_deg": max(e[1] for e in err.values()), "calib_views": n_views}


def run(quick: bool = False, smoke: bool = False) -> dict[str, Any]:
    """Run the three parts; see the module docstring (``smoke``: the smallest sizes)."""
    return {**_studio(quick, smoke), **_sync(quick, smoke), **_calibration(quick, smoke)}
