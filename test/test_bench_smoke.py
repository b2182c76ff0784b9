"""Every ``hand-suite bench NAME`` runs: its smallest mode (``--smoke``, or ``--quick`` where a
bench has none) through the CLI, in a subprocess as a user runs it, and its last line is one
JSON object with the figures the README quotes.

Table-driven: a new benchmark adds a row to ``BENCHES`` (``test_every_bench_has_a_row`` fails
until it does). Rows marked ``slow`` take most of a minute on a loaded 2-core machine even in
their smallest mode; they run in CI like the others (``-m "not slow"`` skips them locally).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: bench name -> (keys its last JSON line must carry, pytest marks)
BENCHES: dict[str, tuple[tuple[str, ...], tuple[pytest.MarkDecorator, ...]]] = {
    "bag": (("msgs_per_s", "replay_msgs_per_s", "baseline_msgs_per_s", "record_vs_baseline",
             "replay_vs_baseline"), ()),
    "contact": (("composite_success", "pd_only_success", "success_ratio", "grid_split",
                 "alpha_chosen", "val_composite_success_by_alpha", "grid_cells",
                 "feasible_cells", "qp_grid_problems", "qp_p50_us", "osqp_p50_us",
                 "speedup_vs_osqp", "max_abs_diff_vs_osqp", "cvxpy_p50_us", "speedup_vs_cvxpy",
                 "max_abs_diff_vs_cvxpy", "qp_grid_unreachable", "seed000_qp_p50_us",
                 "feasibility_lp_p50_us", "control_step_p50_us"), ()),
    "executor": (("lean_vs_rclpy_0_subs", "lean_vs_rclpy_25_subs"), ()),
    "fuzz": (("cases", "failures", "msgs_per_s"), ()),
    "grasp": (("synth_success", "ik_baseline_success", "no_collision_success",
               "no_polygon_success", "no_cone_success", "synth_ms_p50", "synth_cpu_ms_p50",
               "lp_feasible_cases"), (pytest.mark.slow,)),  # 5 simulated lifts
    "model": (("fk_lbs_ms", "baseline_fk_lbs_ms", "fk_lbs_speedup", "fk_lbs_batch_speedup",
               "fk_lbs_speedup_vs_naive", "vectorised_max_diff_m", "jacobian_speedup",
               "render_fps", "raycast_fps", "render_speedup_vs_raycast"), ()),
    "physcap": (("s_per_frame", "contact_sampling_success", "random_sampling_success",
                 "pd_only_success", "object_err_mm", "hand_err_mm", "retarget_success",
                 "low_friction_slipped", "dask_speedup_2w", "heavy_test_contact_sampling_success",
                 "light_test_contact_sampling_success", "test_contact_vs_random_p",
                 "studio_contact_success", "studio_image_object_err_mm",
                 "studio_confirm_contact_success", "studio_confirm_p", "fewest_n_samples",
                 "fewest_clearly_better"),
                (pytest.mark.slow,)),  # 3 optimisations + a 1- and a 2-worker Dask cluster
    "multiview": (("lo_full_mean_mm", "lo_full_own_mesh_mean_mm", "lo_ec_mean_mm",
                   "lo_eco_mean_mm", "isa128_mean_mm", "object_err_mm", "object_err_deg",
                   "s_per_frame", "isa128_s_per_frame", "render_ms"),
                  (pytest.mark.slow,)),  # renders and tracks 4 variants
    "pipeline": (("latency_p50_ms", "latency_p99_ms", "fps", "truth_latency_p50_ms",
                  "latency_vs_truth", "lift_mm"), (pytest.mark.slow,)),  # 3 graph runs
    "retarget": (("tip_err_mm", "joint_map_tip_err_mm", "pinch_err_mm", "joint_map_pinch_err_mm",
                  "retarget_ms_p50", "joint_map_ms_p50", "jitter_mrad", "tip_err_mm_heldout",
                  "joint_map_tip_err_mm_heldout", "other_tip_err_mm",
                  "other_joint_map_tip_err_mm", "self_tip_err_mm", "rgb_tracker_fps",
                  "rgb_keypoint_err_px"), ()),
    "rgb": (("rgb_tracker_fps", "rgb_detector_fps", "rgb_fps_vs_detector",
             "rgb_keypoint_err_px", "rgb_detection_rate", "rgb_heldout_keypoint_err_px",
             "rgb_heldout_detection_rate", "rgb_rgbd_wrist_depth_err_mm"), ()),
    "rig": (("views_per_s", "groups_per_s", "parallel_groups_per_s", "baseline_views_per_s",
             "speedup",
             "sync_frames_per_s", "sync_max_skew_ms", "calib_reproj_px", "calib_extrinsic_mm",
             "calib_extrinsic_deg"), ()),
    "servo": (("loop_hz", "cycle_p50_ms", "baseline_loop_hz", "loop_ratio",
               "pose_to_bus_ms_p50"), ()),
    "sim": (("baseline_rtf", "lockstep_rtf", "lockstep_vs_baseline", "lockstep_success",
             "topics_rtf", "topics2_rtf"), ()),
    "touch": (("quadratic_wrist_cm", "quadratic_angle_deg", "pcaik_wrist_cm", "label_acc_5",
               "eval_us", "eval_speedup_vs_pcaik", "heldout_quadratic_wrist_cm",
               "heldout_quadratic_angle_deg", "heldout_label_acc_2", "heldout_label_acc_3",
               "heldout_label_acc_4", "heldout_label_acc_5", "heldout_layout_nn025_label_acc"),
              (pytest.mark.slow,)),  # new data sets
    "tracking": (("fps", "mean_joint_err_mm", "success_20mm", "icp_only_mean_joint_err_mm",
                  "fps_ratio_vs_icp_only", "heldout_mean_mm", "heldout_success_20mm",
                  "forearm_mean_mm", "forearm_success_20mm", "calib_bone_err_pct",
                  "large_frame_delivery", "temporal_weight_chosen", "forearm_seg_arm_pct",
                  "val_forearm_mean_mm", "val_forearm_first_mean_mm", "val_arm_pixel_acc",
                  "forearm_cut_only_mean_mm", "heldout_arm_pixel_acc", "val_surface_mean_mm",
                  "val_surface_before_mean_mm", "heldout_before_mean_mm",
                  "heldout_truth_drift_mm", "val_surface_no_finger_postures_mean_mm",
                  "val_capsule_mean_mm", "val_capsule_reset_mean_mm",
                  "val_stereo_surface_mean_mm", "val_stereo_capsule_mean_mm",
                  "val_table_mean_mm", "val_table_no_plane_mean_mm",
                  "val_table_seg_table_pct", "val_capsule_forearm_mean_mm",
                  "val_far_forearm_mean_mm", "val_far_forearm_first_mean_mm",
                  "val_far_forearm_arm_pixel_acc", "val_near_forearm_mean_mm",
                  "val_near_forearm_first_mean_mm", "val_near_forearm_arm_pixel_acc",
                  "val_distractor_mean_mm", "val_distractor_no_roi_mean_mm"), ()),
}


def _check_tracking(figures: dict, text: str) -> None:
    """The held-out, forearm and calibration sections (issue 13) report figures in their
    ranges, with the same run's baselines."""
    for key in ("heldout", "forearm"):
        assert figures[f"{key}_frames"] == 6  # the smoke's one sequence of 6 frames each
        assert math.isfinite(figures[f"{key}_mean_mm"]) and figures[f"{key}_mean_mm"] > 0
        assert 0.0 <= figures[f"{key}_success_20mm"] <= 1.0
    # the forearm frames' segment against the true labels
    assert 0.0 <= figures["forearm_seg_arm_pct"] <= 100.0
    assert 0.0 <= figures["forearm_seg_hand_kept_pct"] <= 100.0
    assert 0.0 <= figures["forearm_seg_missed_rate"] <= 1.0
    assert 0.0 < figures["heldout_seg_hand_kept_pct"] <= 100.0
    # the geometric cut alone (the baseline) and the arm classifier's pixel accuracy
    assert figures["forearm_cut_only_mean_mm"] > 0
    assert 0.5 < figures["heldout_arm_pixel_acc"] <= 1.0
    # before -> after of the surface-tolerance settings, and the drift from the true pose
    for key in ("", "_stub_not_optional", "_no_finger_swap", "_before"):
        assert figures[f"heldout{key}_mean_mm"] > 0
        assert 0.0 <= figures[f"heldout{key}_truth_drift_mm"] < 100.0
    # calibration: the smoke's one scale (1.15), whose template bones are about 15 % off
    assert figures["calib_scales"] == [1.15]
    assert figures["calib_bone_err_pct"] >= figures["calib_bone_err_pct_mean"] > 0
    assert figures["calib_bone_err_pct_template"] > 5.0
    # the table behind the hand: the segment's share on it, with and without the removal
    for key in ("val_table", "val_table_no_plane"):
        assert 0.0 <= figures[f"{key}_seg_table_pct"] <= 100.0
    # a box nearer the camera than the hand: the segment's share on it, both ways
    for key in ("val_distractor", "val_distractor_no_roi"):
        assert 0.0 <= figures[f"{key}_seg_on_box_pct"] <= 100.0
    # the forearm validation on the collision capsules and with a farther or nearer camera
    assert 0.5 < figures["val_far_forearm_arm_pixel_acc"] <= 1.0
    assert 0.5 < figures["val_near_forearm_arm_pixel_acc"] <= 1.0
    for title in ("forearm frames", "classifier + cut", "held-out family", "d435_640",
                  "bone-length", "surface-tolerance settings", "a table behind the hand",
                  "drawn as its collision capsules", "0.2 m farther", "0.15 m nearer",
                  "nearer the camera than the hand"):
        assert title in text, title


#: bench name -> a check of its figures (the JSON line) and printed tables beyond the keys
CHECKS: dict[str, Callable[[dict, str], None]] = {"tracking": _check_tracking}


def test_every_bench_has_a_row():
    from hand_control.cli import available_benches

    assert sorted(available_benches()) == sorted(BENCHES), \
        "add a row to BENCHES for every `hand-suite bench --list` name"


@pytest.mark.parametrize("name", [pytest.param(n, marks=m) for n, (_, m) in BENCHES.items()])
def test_bench_smoke(name, tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    out = subprocess.run(
        [sys.executable, "-c", "import sys; from hand_control.cli import main; "
         "sys.exit(main(sys.argv[1:]))", "bench", name, "--smoke"],
        capture_output=True, text=True, cwd=tmp_path, env=env, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    lines = out.stdout.strip().splitlines()
    assert lines, out.stderr[-3000:]
    figures = json.loads(lines[-1])  # the last line: one JSON object
    assert figures["bench"] == name and figures["smoke"] is True
    missing = [k for k in BENCHES[name][0] if k not in figures]
    assert not missing, f"bench {name}: keys missing from the JSON line: {missing}"
    if name in CHECKS:
        CHECKS[name](figures, out.stdout)
