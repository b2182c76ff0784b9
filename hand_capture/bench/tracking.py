"""``hand-suite bench tracking``: depth hand tracking accuracy and speed (ch. II.6).

Synthetic sequences from the project's synthetic camera (320x240, its sensor noise model):
five motions (finger counting, fist, wrist rotation, translation, pinch) for three random
hand shapes different from the default. Each shape is first calibrated automatically from
three rendered frames of the predefined calibration poses (II.3.6), and tracking uses the
calibrated model. In the same run and on the same frames:

* **hybrid** tracking (II.5.1, the product);
* **teleop**: the hybrid tracker with the teleop graph's cheaper settings (the ``tracker``
  parameters of ``config/tracker.yaml`` overridden by ``config/teleop.yaml``, as the graph
  applies them: regression every few frames while tracking succeeds, deferred until the
  frame's pose is out, one refined candidate), so the speed / accuracy trade-off of those
  settings is measured;
* **ICP only**: model-based tracking initialised with the hybrid's first frame (II.6.3);
* **regressor only**: per-frame regression, best mode by E_d.

Figures: mean / median joint position error over the 21 keypoints [mm], success rate (share
of frames whose largest joint error is under 10..50 mm, Figure II.17), frames per second
(wall clock and CPU time of the tracking call alone), CPU time per frame (mean and 99th
percentile: the machine is shared, so CPU time is the steadier figure) and a per-stage time
profile. Recovery: a sequence with a gap of blank frames; the number of frames after the gap
until the success flag is back and until the largest joint error is under 20 mm again.
``--quick`` runs the same on one shape and short excerpts; ``--smoke`` on the fewest
sequences and frames that still pass through every section (the test suite's run).
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from hand_capture.bench import print_table

MOTIONS = ("finger_counting", "fist", "wrist_rotation", "translation", "pinch")
SHAPE_SEEDS = (11, 12, 13)
THRESHOLDS_MM = (10, 20, 30, 40, 50)
#: rows of the comparison: the product, the teleop graph's settings, the two ablations
MODES = ("hybrid", "teleop", "icp", "regressor")


def teleop_config():
    """The tracker's :class:`TrackerConfig` in the teleop graph: ``config/tracker.yaml``,
    then ``config/teleop.yaml`` (the graph's order of parameter files)."""
    from hand_capture.config import from_mapping, load_yaml
    from hand_capture.paths import config_dir
    from hand_capture.tracking.config import TrackerConfig

    merged: dict = {}
    for name in ("tracker.yaml", "teleop.yaml"):
        data = load_yaml(config_dir() / name) or {}
        for key in ("/**", "tracker", "/tracker"):
            merged.update((data.get(key) or {}).get("ros__parameters") or {})
    own = {f.name for f in dataclasses.fields(TrackerConfig)}
    return from_mapping(TrackerConfig, {k: v for k, v in merged.items() if k in own})


def _configs() -> dict:
    from hand_capture.tracking.config import TrackerConfig

    return {"hybrid": TrackerConfig(mode="hybrid"), "teleop": teleop_config(),
            "icp": TrackerConfig(mode="icp"), "regressor": TrackerConfig(mode="regressor")}


def _hand_length(model) -> float:
    kp = model.joint_positions(np.zeros(27))
    return float(np.linalg.norm(kp[12] - kp[0]))


def _run_mode(tracker, frames, truth_kp, mode_first=None, on_result=None):
    """Track a pre-rendered sequence: per-frame errors (N, 21) [mm], wall and CPU time [s]
    (the tracking call and a regression it deferred), success flags, stage times, and the
    CPU time until the pose is out (the tracking call alone) [s]. ``on_result(i, r)``, when
    given, sees every frame's ``TrackResult`` (outside the timed call)."""
    errs, wall, cpu, flags, regressed, pose_cpu = [], [], [], [], [], []
    stages: dict[str, float] = {}
    if mode_first is not None:
        tracker.reset(mode_first)
    else:
        tracker.reset()
    for (depth, intr), kp in zip(frames, truth_kp, strict=True):
        t0, c0 = time.perf_counter(), time.process_time()
        r = tracker.process(depth, intr)
        pose_cpu.append(time.process_time() - c0)
        deferred = tracker.run_deferred()  # as the node: after the pose is out
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        if on_result is not None:
            on_result(len(errs), r)
        for k, v in (deferred or {}).items():
            stages[k] = stages.get(k, 0.0) + v
        errs.append(np.linalg.norm(tracker.model.joint_positions(r.pose) - kp, axis=1) * 1e3)
        flags.append(r.success)
        regressed.append(r.regressed or deferred is not None)
        for k, v in r.timing.items():
            stages[k] = stages.get(k, 0.0) + v
    stages["regressed"] = float(np.sum(regressed))
    return (np.array(errs), np.array(wall), np.array(cpu), np.array(flags), stages,
            np.array(pose_cpu))


def _summary(errs: np.ndarray) -> dict[str, float]:
    mx = errs.max(axis=1)
    out = {"mean": float(errs.mean()), "median": float(np.median(errs))}
    for t in THRESHOLDS_MM:
        out[f"s{t}"] = float(np.mean(mx < t))
    return out


def run(quick: bool = False, smoke: bool = False) -> dict:
    """The figures; ``smoke``: the fewest frames and calibration rounds through the same code
    (figures meaningless)."""
    from hand_capture.bench._tracking_heldout import smoke_calibration

    with smoke_calibration(smoke):
        return _run(quick, smoke)


def _run(quick: bool, smoke: bool) -> dict:
    from hand_capture.bench._tracking_heldout import bench_calibrate
    from hand_capture.cameras.synthetic import SyntheticCamera, SyntheticCameraConfig
    from hand_capture.cameras.threads import limit_blas_threads
    from hand_capture.model import HandModel
    from hand_capture.tracking.calibration import render_calibration_frames
    from hand_capture.tracking.config import TrackerConfig
    from hand_capture.tracking.hybrid import HybridTracker, load_regressor, regressor_files
    from hand_capture.tracking.train import train_tracker

    quick = quick or smoke
    limit_blas_threads(1)
    configs = _configs()
    product = TrackerConfig()
    reg = load_regressor(product)   # the product's: with ensemble its second regressor too
    if reg is not None:
        reg_src = " + ".join(p.name for p in regressor_files(product))
    else:  # no shipped model: a small one trained here (reproducible)
        reg = train_tracker(None, seed=0, n_samples=600 if quick else 2000, n_shapes=20)
        reg_src = "trained in-run"
    shape_seeds = SHAPE_SEEDS[:1] if quick else SHAPE_SEEDS
    step = 4 if quick else 1
    max_frames = 8 if smoke else 16 if quick else 10 ** 6
    base = HandModel()
    rng = np.random.default_rng(0)

    all_err = {m: [] for m in MODES}
    all_wall = {m: [] for m in MODES}
    all_cpu = {m: [] for m in MODES}
    all_pose_cpu = {m: [] for m in MODES}
    all_stage = {m: {} for m in MODES}
    rows_seq = []
    rows_cal = []
    for seed in shape_seeds:
        cam0 = SyntheticCamera(SyntheticCameraConfig(render_color=False, shape_seed=seed))
        cam0.open()
        true_model = cam0.model
        intr = cam0.intrinsics
        t0 = time.perf_counter()
        cal = bench_calibrate(render_calibration_frames(true_model, intr, rng), model=base,
                              subject_id=f"bench{seed}")
        cal_s = time.perf_counter() - t0
        model = base.with_shape(cal.shape)
        ratio_true = _hand_length(true_model) / _hand_length(base)
        ratio_fit = _hand_length(model) / _hand_length(base)
        kp_rest_err = float(np.linalg.norm(model.joint_positions(np.zeros(27))
                                           - true_model.joint_positions(np.zeros(27)),
                                           axis=1).mean() * 1e3)
        kp_rest_err0 = float(np.linalg.norm(base.joint_positions(np.zeros(27))
                                            - true_model.joint_positions(np.zeros(27)),
                                            axis=1).mean() * 1e3)
        rows_cal.append([seed, f"{true_model.shape.global_scale:.3f}",
                         f"{ratio_true:.3f}", f"{ratio_fit:.3f}", kp_rest_err0, kp_rest_err,
                         cal.residual_mm, cal_s])
        trackers = {m: HybridTracker(model, configs[m], reg) for m in MODES}
        for clip in MOTIONS:
            cam = SyntheticCamera(SyntheticCameraConfig(render_color=False, shape_seed=seed,
                                                        clip=clip, noise_seed=seed),
                                  model=true_model)
            cam.open()
            n = int(math.floor(cam.motion.duration * 30)) + 1
            idx = list(range(0, n, step))[:max_frames]
            rendered = [cam.render(i / 30.0) for i in idx]
            frames = [(f.depth, f.depth_intrinsics) for f in rendered]
            truth = [true_model.joint_positions(f.pose) for f in rendered]
            first = None
            for m in MODES:
                e, w, c, fl, st, pc = _run_mode(trackers[m], frames, truth,
                                                first if m == "icp" else None)
                if m == "hybrid":
                    trackers[m].reset()
                    first = trackers[m].process(*frames[0]).pose
                all_err[m].append(e)
                all_wall[m].append(w)
                all_cpu[m].append(c)
                all_pose_cpu[m].append(pc)
                for k, v in st.items():
                    all_stage[m][k] = all_stage[m].get(k, 0.0) + v
                s = _summary(e)
                rows_seq.append([seed, clip, m, len(frames), s["mean"], s["median"], s["s20"],
                                 float(np.mean(fl)), 1.0 / np.mean(w)])
    print_table("calibration (II.3.6): hand length ratio to the template, mean rest-pose "
                "keypoint error [mm]",
                ["shape", "s_g", "true ratio", "fit ratio", "kp err default", "kp err fit",
                 "resid mm", "time s"], rows_cal)
    print_table("per sequence", ["shape", "motion", "mode", "frames", "mean mm", "median mm",
                                 "succ@20", "flag rate", "fps"], rows_seq)
    summ = {}
    rows = []
    for m in MODES:
        e = np.concatenate(all_err[m])
        s = _summary(e)
        w = np.concatenate(all_wall[m])
        c = np.concatenate(all_cpu[m])
        s["fps"] = 1.0 / float(np.mean(w))
        s["fps_cpu"] = 1.0 / float(np.mean(c))
        s["cpu_ms"] = 1e3 * float(np.mean(c))
        s["cpu_ms_p99"] = 1e3 * float(np.percentile(c, 99))
        s["pose_cpu_ms_p99"] = 1e3 * float(np.percentile(np.concatenate(all_pose_cpu[m]), 99))
        s["frames"] = len(e)
        s["regressed"] = all_stage[m].get("regressed", 0.0) / len(e)
        summ[m] = s
        rows.append([m, len(e), s["mean"], s["median"]] + [s[f"s{t}"] for t in THRESHOLDS_MM]
                    + [s["fps"], s["fps_cpu"], s["cpu_ms"], s["cpu_ms_p99"],
                       s["pose_cpu_ms_p99"]])
    print_table("summary (success = share of frames whose largest joint error < t mm; CPU time "
                "per frame, and until the frame's pose is out: a deferred regression after)",
                ["mode", "frames", "mean mm", "median mm"] + [f"<{t}mm" for t in THRESHOLDS_MM]
                + ["fps wall", "fps cpu", "cpu ms", "cpu ms p99", "pose cpu ms p99"], rows)
    prof_rows = []
    for m in MODES:
        nfr = summ[m]["frames"]
        prof_rows.append([m] + [1e3 * all_stage[m].get(k, 0.0) / nfr
                                for k in ("preprocess", "regression", "icp", "selection")]
                         + [summ[m]["regressed"]])
    print_table("time per frame by stage [ms] (wall clock); share of frames with regression",
                ["mode", "preprocess", "regression", "ICP", "selection", "regressed"],
                prof_rows)
    tc = configs["teleop"]
    diff = [[f.name, getattr(configs["hybrid"], f.name), getattr(tc, f.name)]
            for f in dataclasses.fields(tc)
            if getattr(tc, f.name) != getattr(configs["hybrid"], f.name)]
    print_table("teleop settings (config/teleop.yaml over config/tracker.yaml) that differ "
                "from the product's", ["parameter", "hybrid", "teleop"], diff)

    # ---------------------------------------------------------------- recovery after a gap
    seed = shape_seeds[0]
    cam = SyntheticCamera(SyntheticCameraConfig(render_color=False, shape_seed=seed,
                                                clip="wrist_rotation", noise_seed=7))
    cam.open()
    true_model = cam.model
    gap_start, gap_len, after = (10, 8, 12) if quick else (40, 20, 30)
    idx = list(range(0, gap_start + gap_len + after))
    rendered = [cam.render(i / 30.0 + 1.0) for i in idx]
    frames = []
    for i, f in enumerate(rendered):
        d = f.depth if not gap_start <= i < gap_start + gap_len else np.zeros_like(f.depth)
        frames.append((d, f.depth_intrinsics))
    truth = [true_model.joint_positions(f.pose) for f in rendered]
    cal_model = base.with_shape(bench_calibrate(
        render_calibration_frames(true_model, cam.intrinsics, rng), model=base).shape)
    rec_rows = []
    rec = {}
    for m in ("hybrid", "teleop", "icp"):
        tr = HybridTracker(cal_model, configs[m], reg)
        first = None
        if m == "icp":
            t2 = HybridTracker(cal_model, configs["hybrid"], reg)
            first = t2.process(*frames[0]).pose
        e, _, _, fl, _, _ = _run_mode(tr, frames, truth, first)
        post = slice(gap_start + gap_len, len(frames))
        mx = e[post].max(axis=1)
        ok_err = np.flatnonzero(mx < 20.0)
        ok_flag = np.flatnonzero(fl[post])
        rec[m] = (int(ok_err[0]) if ok_err.size else -1, int(ok_flag[0]) if ok_flag.size
                  else -1, float(np.mean(mx < 20.0)))
        gap_flags = fl[gap_start:gap_start + gap_len]
        rec_rows.append([m, gap_len, rec[m][1], rec[m][0], rec[m][2],
                         int(np.count_nonzero(gap_flags))])
    print_table("recovery after a gap of blank frames (frames counted from the first frame "
                "after the gap, 0 = at once; -1 = never)",
                ["mode", "gap frames", "flag back after", "err<20mm after",
                 "succ@20 after gap", "flags during gap"], rec_rows)

    h, i_, r_ = summ["hybrid"], summ["icp"], summ["regressor"]
    tl = summ["teleop"]
    out = {
        "regressor_model": reg_src,
        "frames": h["frames"], "n_shapes": len(shape_seeds), "n_motions": len(MOTIONS),
        "fps": h["fps"], "fps_cpu": h["fps_cpu"],
        "cpu_ms": h["cpu_ms"], "cpu_ms_p99": h["cpu_ms_p99"],
        "mean_joint_err_mm": h["mean"], "median_joint_err_mm": h["median"],
        **{f"success_{t}mm": h[f"s{t}"] for t in THRESHOLDS_MM},
        "teleop_fps": tl["fps"], "teleop_fps_cpu": tl["fps_cpu"],
        "teleop_cpu_ms": tl["cpu_ms"], "teleop_cpu_ms_p99": tl["cpu_ms_p99"],
        "teleop_pose_cpu_ms_p99": tl["pose_cpu_ms_p99"], "pose_cpu_ms_p99": h["pose_cpu_ms_p99"],
        "teleop_cpu_ratio_vs_hybrid": tl["cpu_ms"] / h["cpu_ms"],
        "teleop_mean_joint_err_mm": tl["mean"], "teleop_median_joint_err_mm": tl["median"],
        **{f"teleop_success_{t}mm": tl[f"s{t}"] for t in THRESHOLDS_MM},
        "teleop_regressed_share": tl["regressed"],
        "teleop_recovery_frames": rec["teleop"][0],
        "teleop_recovery_frames_flag": rec["teleop"][1],
        "teleop_stage_ms": {k: 1e3 * all_stage["teleop"].get(k, 0.0) / tl["frames"]
                            for k in ("preprocess", "regression", "icp", "selection")},
        "icp_only_mean_joint_err_mm": i_["mean"],
        **{f"icp_only_success_{t}mm": i_[f"s{t}"] for t in THRESHOLDS_MM},
        "icp_only_fps": i_["fps"],
        "regressor_only_mean_joint_err_mm": r_["mean"],
        **{f"regressor_only_success_{t}mm": r_[f"s{t}"] for t in THRESHOLDS_MM},
        "regressor_only_fps": r_["fps"],
        "fps_ratio_vs_icp_only": h["fps"] / i_["fps"],
        "recovery_frames": rec["hybrid"][0],
        "recovery_frames_flag": rec["hybrid"][1],
        "icp_only_recovery_frames": rec["icp"][0],
        "stage_ms": {k: 1e3 * all_stage["hybrid"].get(k, 0.0) / h["frames"]
                     for k in ("preprocess", "regression", "icp", "selection")},
        "calibration_kp_err_mm": float(np.mean([r[5] for r in rows_cal])),
        "calibration_kp_err_default_mm": float(np.mean([r[4] for r in rows_cal])),
    }
    # held-out family, calibration bone lengths, settings split, transport (issue 13)
    from hand_capture.bench._tracking_heldout import run_sections

    out.update(run_sections(reg, configs["hybrid"], quick, smoke))
    return out
