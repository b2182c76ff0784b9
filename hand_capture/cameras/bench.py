"""Speed of the synthetic camera: renderers compared in one run, and the full frame.

:func:`render_benchmark` renders the default hand model through a motion clip at 320x240
(the dissertation's sensor resolution, ch. II.2) with

* ``zbuffer`` -- the vectorised numpy rasteriser the synthetic camera uses,
* ``raycast`` -- Open3D's ``RaycastingScene`` (BVH rebuilt per frame, one thread),
* ``naive`` -- a per-triangle Python loop (the baseline),

checks that they see the same pixels at the same depth, and times the whole synthetic frame
(skinning + render + depth noise + colour). BLAS is limited to one thread and every renderer
runs single-threaded, so the figures are per core. Speeds are reported as ratios to the
baseline measured in the same run, because absolute times drift on shared machines.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from hand_capture.cameras.noise import DepthNoiseConfig
from hand_capture.cameras.render import Mesh, NaiveRenderer, RaycastRenderer, ZBufferRenderer
from hand_capture.cameras.synthetic import HAND_LABEL, SyntheticCamera, SyntheticCameraConfig
from hand_capture.cameras.threads import blas_threads

__all__ = ["render_benchmark"]


def _interleaved(stages: dict[str, Callable[[int], object]], rounds: int,
                 every: dict[str, int] | None = None) -> dict[str, tuple[float, float]]:
    """Median wall and CPU time [ms] of each stage, measured round-robin.

    Every round runs each stage once (a stage in ``every`` only every k-th round), so a change
    of machine load during the run affects all stages alike. CPU time is the process time,
    i.e. the cost on one core whatever else the machine is doing.
    """
    every = every or {}
    for fn in stages.values():  # warm-up
        fn(0)
    wall: dict[str, list[float]] = {k: [] for k in stages}
    cpu: dict[str, list[float]] = {k: [] for k in stages}
    for r in range(rounds):
        for name, fn in stages.items():
            if r % every.get(name, 1):
                continue
            w0, c0 = time.perf_counter(), time.process_time()
            fn(r)
            cpu[name].append(time.process_time() - c0)
            wall[name].append(time.perf_counter() - w0)
    return {k: (float(np.median(wall[k]) * 1e3), float(np.median(cpu[k]) * 1e3))
            for k in stages}


def render_benchmark(quick: bool = False, *, model: Any = None, width: int = 320,
                     height: int = 240, clip: str = "finger_counting",
                     verbose: bool = True) -> dict[str, Any]:
    """Time the renderers and the synthetic frame; returns the figures.

    Args:
        quick: fewer frames (well under a minute on a 2-core machine).
        width, height: image size [px].
        model: hand model to render (default: the camera's default ``HandModel``).
        clip: motion clip the poses are taken from.
        verbose: print a table (``hand_capture.bench.print_table``).

    Returns:
        Medians of interleaved runs (``*_fps`` / ``*_ms`` from wall time, ``*_cpu`` from
        process CPU time, i.e. one core whatever else the machine does): ``render_fps``,
        ``render_ms``, ``render_fps_cpu`` (our z-buffer), ``raycast_fps``, ``raycast_ms``,
        ``naive_fps``, ``naive_ms`` (baselines), ``render_speedup_vs_naive``,
        ``render_speedup_vs_raycast`` (and ``_cpu``), ``synthetic_frame_fps``,
        ``synthetic_frame_ms``, ``synthetic_frame_fps_cpu`` (the whole frame: skinning +
        render + depth noise + colour), ``synthetic_skin_ms``, ``synthetic_noise_ms``,
        ``synthetic_color_ms``, ``render_agreement`` (lowest fraction of pixels where the
        renderers agree on hit/miss), ``render_max_depth_diff_mm``, ``render_faces``,
        ``render_hand_pixels``, ``render_width``, ``render_height``, ``renderer``.
    """
    with blas_threads(1):
        return _run(quick, model, width, height, clip, verbose)


def _run(quick: bool, model: Any, width: int, height: int, clip: str,
         verbose: bool) -> dict[str, Any]:
    cfg = SyntheticCameraConfig(width=width, height=height, clip=clip, noise_seed=1)
    cam = SyntheticCamera(cfg, DepthNoiseConfig(), model=model)
    cam.open()
    intr = cam.intrinsics
    n_poses = 8 if quick else 30
    times = np.linspace(0.0, cam.motion.duration, n_poses, endpoint=False)
    poses = [cam.truth_pose(t) for t in times]
    meshes = [[Mesh(cam.model.vertices(q), cam.model.faces, HAND_LABEL, closed=True)]
              for q in poses]
    n_faces = int(len(cam.model.faces))

    zbuf, ray, naive = ZBufferRenderer(), RaycastRenderer(nthreads=1), NaiveRenderer()
    outputs = {r.name: [r.render(m, intr) for m in meshes] for r in (zbuf, ray)}
    with np.errstate(all="ignore"):
        outputs["naive"] = [naive.render(meshes[0], intr)]

    # agreement of the renderers (hit masks and depths)
    agree, max_diff = [], 0.0
    for i in range(n_poses):
        a, b = outputs["zbuffer"][i], outputs["raycast"][i]
        agree.append(float(np.mean(a.hit == b.hit)))
        both = a.hit & b.hit
        if both.any():
            max_diff = max(max_diff, float(np.abs(a.depth - b.depth)[both].max()))
    a, c = outputs["zbuffer"][0], outputs["naive"][0]
    agree.append(float(np.mean(a.hit == c.hit)))

    res = outputs["zbuffer"][1]
    rng = np.random.default_rng(0)

    def naive_render(k: int) -> None:
        with np.errstate(all="ignore"):
            naive.render(meshes[k % n_poses], intr)

    stages: dict[str, Callable[[int], object]] = {
        "zbuffer": lambda k: zbuf.render(meshes[k % n_poses], intr),
        "raycast": lambda k: ray.render(meshes[k % n_poses], intr),
        "naive": naive_render,
        "skin": lambda k: cam.model.vertices(poses[k % n_poses]),
        "noise": lambda k: cam.noise.apply_mm(res.depth, res.cos_incidence, intr, rng),
        "color": lambda k: cam.shade(res),
        "frame": lambda k: cam.render(float(times[k % n_poses])),
    }
    rounds = 3 * n_poses if quick else 10 * n_poses
    every_naive = rounds // (2 if quick else 6)
    t = _interleaved(stages, rounds, every={"naive": every_naive})
    results = {k: v[0] for k, v in t.items()}
    cpu = {k: v[1] for k, v in t.items()}
    frame_ms, skin_ms, noise_ms, color_ms = (results[k] for k in ("frame", "skin", "noise",
                                                                  "color"))

    out = {
        "renderer": "zbuffer",
        "render_width": width, "render_height": height, "render_faces": n_faces,
        "render_fps": 1e3 / results["zbuffer"], "render_ms": results["zbuffer"],
        "render_fps_cpu": 1e3 / cpu["zbuffer"],
        "raycast_fps": 1e3 / results["raycast"], "raycast_ms": results["raycast"],
        "naive_fps": 1e3 / results["naive"], "naive_ms": results["naive"],
        "render_speedup_vs_naive": results["naive"] / results["zbuffer"],
        "render_speedup_vs_raycast": results["raycast"] / results["zbuffer"],
        "render_speedup_vs_naive_cpu": cpu["naive"] / cpu["zbuffer"],
        "render_speedup_vs_raycast_cpu": cpu["raycast"] / cpu["zbuffer"],
        "synthetic_frame_fps": 1e3 / frame_ms, "synthetic_frame_ms": frame_ms,
        "synthetic_frame_fps_cpu": 1e3 / cpu["frame"],
        "synthetic_skin_ms": skin_ms, "synthetic_noise_ms": noise_ms,
        "synthetic_color_ms": color_ms,
        "render_agreement": float(np.min(agree)), "render_max_depth_diff_mm": max_diff * 1e3,
        "render_hand_pixels": int(np.mean([o.hit.sum() for o in outputs["zbuffer"]])),
    }
    if verbose:
        from hand_capture.bench import print_table

        print_table(
            f"synthetic camera, {width}x{height}, {n_faces} faces, clip {clip!r}, one core",
            ["stage", "wall ms", "cpu ms", "fps (wall)", "vs naive (wall)"],
            [["render zbuffer (ours)", results["zbuffer"], cpu["zbuffer"], out["render_fps"],
              out["render_speedup_vs_naive"]],
             ["render raycast (open3d)", results["raycast"], cpu["raycast"],
              out["raycast_fps"], results["naive"] / results["raycast"]],
             ["render naive (baseline)", results["naive"], cpu["naive"], out["naive_fps"],
              1.0],
             ["skinning (model)", skin_ms, cpu["skin"], 1e3 / skin_ms, ""],
             ["depth noise", noise_ms, cpu["noise"], 1e3 / noise_ms, ""],
             ["colour + noise", color_ms, cpu["color"], 1e3 / color_ms, ""],
             ["whole frame", frame_ms, cpu["frame"], out["synthetic_frame_fps"], ""]])
        print(f"renderers agree on {100 * out['render_agreement']:.3f} % of pixels, depth "
              f"within {out['render_max_depth_diff_mm']:.4f} mm")
    return out


if __name__ == "__main__":  # pragma: no cover
    import sys

    from hand_capture.bench import json_line

    print(json_line(render_benchmark(quick="--quick" in sys.argv)))
