"""Every weight and threshold of the depth hand tracker (dissertation ch. II.4-II.5).

One frozen dataclass, :class:`TrackerConfig`, filled from ``config/tracker.yaml`` or from the
tracker node's ROS parameters (the same field names).
"""

from __future__ import annotations

from dataclasses import dataclass

from hand_capture.config import param, validate
from hand_capture.errors import ConfigError


@dataclass(frozen=True)
class TrackerConfig:
    """Parameters of preprocessing, Gauss-Newton ICP, regression and the hybrid scheme."""

    # -- preprocessing -------------------------------------------------------------------
    near_m: float = param(0.12, "nearest depth considered [m]", lo=0.0, hi=10.0)
    far_m: float = param(1.2, "farthest depth considered [m]", lo=0.01, hi=20.0)
    band_m: float = param(0.16, "depth band kept behind the nearest hand pixel [m]", lo=0.01,
                          hi=2.0)
    grow_m: float = param(0.4, "when the band's component runs out of the image (an arm "
                          "reaching in), grow it over depth-continuous pixels up to this "
                          "far behind the band (preprocess); 0 = off [m]", lo=0.0, hi=2.0)
    jump_m: float = param(0.02, "depth step between neighbouring pixels that separates "
                          "surfaces when growing [m]", lo=0.001, hi=0.5)
    min_hand_pixels: int = param(60, "fewer hand pixels than this = no hand in view", lo=1)
    track_roi_m: float = param(0.1, "while tracking (the previous frame passed eq. II.19), "
                               "segment only within this margin of the ball around the "
                               "previous pose's keypoints (their centroid, radius their "
                               "farthest): something nearer the camera elsewhere is not "
                               "taken for the hand; the whole image when nothing is found "
                               "there; 0 = off [m]", lo=0.0, hi=2.0)
    wrist_cut_m: float = param(0.0, "drop points farther than this from the cloud centroid; "
                               "0 = no wrist cut [m]", lo=0.0, hi=1.0)
    forearm_cut: bool = param(True, "remove the forearm from the segmented hand "
                              "(preprocess.cut_forearm): beyond the previous pose's wrist "
                              "while tracking, else by the cloud's shape")
    arm_classifier: bool = param(True, "before the forearm cut, drop the pixels the per-pixel "
                                 "hand/arm classifier (tracking.armseg, data/tracker/arm.npz "
                                 "when present) calls arm; asked only on a segment that runs "
                                 "out of the image or is longer than forearm_reach_m")
    arm_fallback: bool = param(True, "when the classifier dropped pixels and the frame fails "
                               "eq. II.19, run it again on the forearm cut alone and keep the "
                               "result of lower E_d (the classifier cannot do worse than the "
                               "cut on a lost frame)")
    fallback_union: bool = param(True, "on a frame without a tracked pose, arm_fallback's "
                                 "result replaces the classifier's only when its E_d is lower "
                                 "on its own segment and on the union of both segments")
    fallback_arm_free_m: float = param(0.08, "in that comparison, cost_arm_optional leaves "
                                       "out the data past a pose's wrist only up to this far "
                                       "beyond its wrist plane [m, at template size]; 0 = all "
                                       "of it", lo=0.0, hi=1.0)
    flip_retry: bool = param(False, "when a frame whose forearm was cut from the cloud's shape "
                             "fails eq. II.19, run it again with the cloud's other end taken "
                             "for the arm and keep the result of lower E_d")
    split_retry: bool = param(True, "when a frame fails eq. II.19 and its segment splits "
                              "along depth steps of jump_m into pieces, run it again without "
                              "the pieces of at least split_share of it but the one nearest "
                              "the camera (an object touching the hand; "
                              "preprocess.split_surfaces); its result is kept when it passes "
                              "eq. II.19 at a lower E_d")
    plane_removal: bool = param(True, "drop a large plane (a table, a wall, the body) and "
                                "everything behind it from a segment larger than "
                                "plane_min_area_m2, then keep the surface nearest the camera "
                                "(preprocess.drop_background_plane)")
    plane_tol_m: float = param(0.01, "pixels this close to the plane belong to it [m]",
                               lo=0.002, hi=0.05)
    plane_min_area_m2: float = param(0.03, "a segment or plane smaller than this is no "
                                     "background (the palm side of a hand is about 0.015) "
                                     "[m^2]", lo=0.005, hi=1.0)
    plane_min_width_m: float = param(0.12, "a plane narrower than this across its second axis "
                                     "is no background (a forearm's side) [m]", lo=0.02,
                                     hi=1.0)
    split_share: float = param(0.1, "split_retry drops pieces at least this share of the "
                               "segment", lo=0.01, hi=0.9)
    arm_model_file: str = param("", "trained arm classifier (.npz); empty = data/tracker/"
                                "arm.npz when present")
    arm_threshold: float = param(0.5, "arm probability above which a pixel is dropped",
                                 lo=0.05, hi=0.95)
    arm_grid_mm: float = param(4.0, "spacing on the hand of the pixels the arm classifier "
                               "evaluates (the rest read the smoothed grid) [mm]", lo=0.5,
                               hi=20.0)
    arm_margin_m: float = param(0.035, "arm pixels this close to the classified hand are kept "
                                "(the model's wrist reaches into the arm's silhouette) [m]",
                                lo=0.0, hi=0.2)
    forearm_margin_m: float = param(0.036, "while tracking: points farther than this beyond "
                                    "the previous wrist (along the forearm) are cut; the "
                                    "template mesh's wrist reaches 36 mm beyond the wrist "
                                    "keypoint (a shorter cut leaves model without data, "
                                    "which shrinks the fit) [m, at template size]", lo=0.0,
                                    hi=0.2)
    cut_hand_end_mm: float = param(20.0, "while tracking: the forearm cut's wrist moves "
                                   "along the forearm by as far as the segment's fingertip "
                                   "end lies beyond the previous pose's, when that is at most "
                                   "this [mm]; 0 = the previous wrist (a moving hand's cut "
                                   "then lags and keeps more forearm)",
                                   lo=0.0, hi=100.0)
    forearm_reach_m: float = param(0.25, "a cloud longer than this along its axis holds a "
                                   "forearm (a hand alone cannot be) [m, at template size]",
                                   lo=0.05, hi=0.6)
    forearm_border_m: float = param(0.2, "a cloud longer than this whose one end runs out "
                                    "of the image holds a forearm there [m, at template "
                                    "size]", lo=0.05, hi=0.6)
    forearm_wrist_m: float = param(0.05, "palm centre to the cut along the arm axis when "
                                   "cutting from the cloud's shape (the mesh's wrist end) "
                                   "[m, at template size]", lo=0.02, hi=0.2)
    max_points: int = param(160, "observed points used per ICP iteration (subsampled)",
                            lo=16, hi=20000)
    # a stereo camera's short gaps (tracking/preprocess.py, fill_row_gaps): chosen on the
    # stereo validation family (bench tracking's val_stereo_*)
    fill_band_px: int = param(4, "gaps along a row up to this long beside a depth step take "
                              "the farther side's depth (a stereo camera's occlusion band; "
                              "0 = off) [px]", lo=0, hi=16)
    fill_hole_px: int = param(3, "gaps along a row or column up to this long between "
                              "similar depths are interpolated (matching holes; 0 = off) "
                              "[px]", lo=0, hi=16)
    fill_step_m: float = param(0.015, "depth difference across a gap that makes it an "
                               "occlusion band, not a hole [m]", lo=0.001, hi=0.5)
    # -- model-based tracking (II.5.2) ---------------------------------------------------
    data_weight: float = param(1.0, "lambda_1, data term weight (eq. II.21; residuals in mm)",
                               lo=0.0)
    # the paper's 0.2 (units not given) is too weak against our data term in mm: 50 chosen
    # on the validation families (bench tracking's surface, capsule, forearm, stereo)
    smooth_weight: float = param(50.0, "lambda_2, smoothness term weight (eq. II.24; "
                                 "translations in mm, angles in rad; the paper's 0.2 is "
                                 "too weak against a data term in mm)", lo=0.0)
    # the previous pose damps fast wrist motion as much as jitter with the weight of 50:
    # the in-distribution translation clip lagged 2.6 -> 6.0 mm (twenty-fourth session)
    smooth_predict: str = param(
        "translation", "reference of the smoothness term (eq. II.24): the previous pose "
        "(off), or that pose moved on by the change between the last two tracked frames "
        "(constant velocity) in the global translation only, or in every degree of freedom "
        "(pose)",
        choices=("off", "translation", "pose"))
    calibration_smooth_weight: float = param(
        0.2, "lambda_2 in the calibration's pose fits, which hold each pose near its own "
        "start, not a previous frame (II.3.6; the paper's 0.2: 50 pulled the fitted scales "
        "3-5 % off)", lo=0.0)
    limit_weight: float = param(1000.0, "lambda_3, joint-limit term weight (eq. II.25)",
                                lo=0.0)
    reverse_weight: float = param(0.5, "weight of the model-to-data pairs (off-silhouette "
                                  "facing vertices to their nearest point; 0 = eq. II.23 only)",
                                  lo=0.0)
    wrist_optional: bool = param(True, "the template's wrist stub (surface beyond "
                                 "wrist_optional_m past the wrist keypoint) is optional: no "
                                 "model-to-data pairs from it (II.23), nor in calibration's "
                                 "off-hand test (real data there is forearm, sleeve, cut or "
                                 "nothing)")
    wrist_optional_m: float = param(0.0, "where the optional wrist stub begins, beyond the "
                                    "wrist keypoint along the forearm [m, at template size; "
                                    "calibration with a forearm in view lowers it to its "
                                    "data cut, calibrate(recut_margin_m)]",
                                    lo=-0.04, hi=0.036)
    reverse_margin_px: float = param(2.0, "model-to-data pairs only for vertices projecting "
                                     "farther than this off the hand [px]", lo=0.0)
    damping: float = param(1e-2, "Levenberg damping added to J^T J (stabilises II.27)",
                           lo=0.0)
    window_px: float = param(24.0, "half size of the 2D correspondence window [px] (II.22)",
                             lo=1.0, hi=1000.0)
    window_candidates: int = param(8, "vertices examined per observed point in the window",
                                   lo=1, hi=64)
    window_fallback: bool = param(True, "a point with no vertex in its window takes the "
                                  "nearest facing vertex in 3D")
    robust_mm: float = param(8.0, "Huber scale of the ICP data residuals (eq. II.23 "
                             "made robust by iteratively reweighted least squares); 0 = "
                             "plain least squares [mm]", lo=0.0, hi=100.0)
    outlier_mm: float = param(40.0, "correspondences farther than this are dropped [mm]",
                              lo=1.0)
    model_stride: int = param(2, "use every n-th model vertex as correspondence candidate",
                              lo=1, hi=32)
    icp_iterations: int = param(3, "Gauss-Newton iterations per candidate (step 4)", lo=0,
                                hi=50)
    palm_iterations: int = param(1, "palm-only refinement iterations (steps 1 and 3)", lo=0,
                                 hi=50)
    overlap_weight: float = param(100.0, "weight of the fingers' penetration residuals in the "
                                  "Gauss-Newton energy (a term added to eq. II.21: one "
                                  "residual [mm] per penetrating capsule pair of two of the "
                                  "four fingers, hand_capture.tracking.overlap)", lo=0.0)
    max_step_rad: float = param(0.35, "largest angle change per GN step [rad]", lo=0.01,
                                hi=3.2)
    # -- success test and candidate selection (II.5.1) -----------------------------------
    success_tau_mm: float = param(25.0, "tau of eq. II.19: mean depth error of success [mm]",
                                  lo=0.1)
    tau_fit_ratio: float = param(1.6, "after calibration tau is at least this times the "
                                 "E_d of the calibration fit (HybridTracker.tau_mm)", lo=1.0,
                                 hi=10.0)
    tau_max_mm: float = param(40.0, "largest tau the calibration may set [mm]", lo=0.1)
    depth_cap_mm: float = param(60.0, "per-pixel cap of |I_r - I| in E_d [mm]", lo=1.0)
    cost_downsample: int = param(2, "image downsampling of the E_d evaluation", lo=1, hi=8)
    cost_footprint_mm: float = param(1.1, "least size of an E_d pixel on the hand [mm]: the "
                                     "downsampling rises above cost_downsample where the "
                                     "hand is near or the camera fine (icp.cost_grid); 0 = "
                                     "cost_downsample always", lo=0.0, hi=10.0)
    cost_stub_optional: bool = param(True, "on a frame whose segment had no forearm cut "
                                     "off: in E_d (eq. II.19, II.20) a pixel where the "
                                     "model's optional wrist stub (wrist_optional) is the "
                                     "rendered surface and no data lies counts for nothing "
                                     "(a hand ending at the wrist; where data lies it is "
                                     "compared)")
    cost_arm_optional: bool = param(True, "on a frame whose forearm was cut off: in E_d "
                                    "(eq. II.19, II.20) a data pixel past the pose's wrist "
                                    "(its side of the plane through the wrist keypoint, "
                                    "normal to the middle MCP - wrist direction) where the "
                                    "model renders nothing counts for nothing (the arm the "
                                    "cut left, wider than the model's wrist)")
    cost_data_weight: float = param(1.0, "lambda_1 of the candidate cost (eq. II.20)", lo=0.0)
    cost_temporal_weight: float = param(0.0, "lambda_2 of the candidate cost (eq. II.20; "
                                        "mm per rad^2 / m^2 of pose change); 0 chosen on the "
                                        "bench's validation split (bench tracking)", lo=0.0)
    finger_swap: bool = param(True, "after step 4, each finger of the selected pose may "
                              "take another refined candidate's angles for that finger when "
                              "that lowers the candidate cost of eq. II.20 (greedy, finger "
                              "by finger), then one more Gauss-Newton iteration")
    finger_postures: bool = param(True, "the finger-wise selection (finger_swap) also "
                                  "tries each finger straight and curled (flexion angles at "
                                  "fixed postures, abduction kept), so a finger none of the "
                                  "candidates has right can still be found")
    keep_unrefined: bool = param(True, "step 4 keeps a screened candidate as it was when "
                                 "its refinement raised its cost of eq. II.20 (the "
                                 "refinement's smoothness term holds it near the previous "
                                 "pose, which a regressed candidate may rightly leave)")
    abduction_trial: bool = param(True, "after the finger-wise selection the selected pose "
                                  "is also refined from the four fingers' abduction set to "
                                  "zero (all at once) and replaced when that lowers the cost "
                                  "of eq. II.20: two neighbouring fingers fitted to each "
                                  "other's points (crossed) are not mended one finger at a "
                                  "time")
    abduction_min_deg: float = param(3.0, "the abduction trial runs only when one of the "
                                     "four fingers' MCP abduction is at least this [deg] "
                                     "(the crossed fingers it mends were at 20-38; 3 chosen "
                                     "on the validation families: the same accuracy for "
                                     "about 6 % less CPU a frame)", lo=0.0, hi=90.0)
    exchange_trial: bool = param(True, "after the finger-wise selection two of the four "
                                 "fingers may exchange their flexion angles (each pair "
                                 "tried, the cheapest taken and refined when it lowers the "
                                 "cost of eq. II.20): a straight finger fitted to another's "
                                 "points, that one curled where the first is, is not mended "
                                 "one finger at a time")
    # -- regression (II.4) ---------------------------------------------------------------
    regress_previous: bool = param(True, "step 2 also regresses the fingers on the previous "
                                   "pose's palm (after its palm-only iteration of step 3): "
                                   "one more candidate, the tracked palm with regressed "
                                   "fingers, so a finger tracked wrong can be replaced "
                                   "while the palm is right")
    shift_previous: bool = param(True, "step 3 also starts from the previous pose moved by "
                                 "the shift of the hand segment's centroid since the last "
                                 "frame (one more candidate while tracking, its own "
                                 "smoothness reference): a wrist that moves several mm a "
                                 "frame")
    shift_min_mm: float = param(3.0, "shift_previous only when the centroid moved at least "
                                "this far [mm] (a finger closing moves it a few mm)", lo=0.0)
    n_modes: int = param(1, "palm modes kept by clustering the leaves (II.4.3), each "
                         "regressor's; in hybrid mode on a frame with a tracked pose only "
                         "(acquire_modes on one without)", lo=1, hi=16)
    ik_iterations: int = param(2, "finger IK Gauss-Newton steps per finger cascade stage",
                               lo=1, hi=20)
    refine_top: int = param(2, "candidates fully refined after screening (step 4)", lo=1,
                            hi=32)
    acquire_modes: int = param(6, "palm modes of step 1 on a frame without a tracked "
                               "previous pose (the first frame, after a loss; hybrid mode): "
                               "a wider search where no previous pose carries the fit (at "
                               "most: the regressor's leaves may hold fewer); 0 = n_modes",
                               lo=0, hi=16)
    acquire_refine_top: int = param(6, "candidates refined in step 4 on such a frame; "
                                    "0 = refine_top", lo=0, hi=32)
    acquire_icp_iterations: int = param(12, "Gauss-Newton iterations of each candidate of "
                                        "step 4 on such a frame (its candidates start far "
                                        "from the hand: no previous pose); 0 = "
                                        "icp_iterations", lo=0, hi=50)
    acquire_above_tau: float = param(0.8, "while tracking, a frame whose previous E_d was "
                                     "above this share of tau (eq. II.19) searches as one "
                                     "without a tracked pose (acquire_*, candidates refined "
                                     "without the smoothness term; the previous pose stays "
                                     "a candidate): a wrong acquisition that passes eq. "
                                     "II.19 is searched again; 0 = off", lo=0.0, hi=1.0)
    regress_every: int = param(1, "run the regression (steps 1-2) every n-th frame while the "
                               "previous frame tracked successfully (eq. II.19); frames in "
                               "between refine the previous pose only; after a failure it "
                               "runs on every frame; 1 = every frame", lo=1, hi=1000)
    regress_above_mm: float = param(0.0, "with regress_every > 1: run the regression anyway "
                                    "when the previous frame's E_d (eq. II.19) is above this, "
                                    "i.e. tracked but doubtful [mm]; 0 = never", lo=0.0)
    defer_regression: bool = param(False, "with regress_every > 1: a regression due while "
                                   "the previous frame tracked runs after the frame's pose "
                                   "is out (HybridTracker.run_deferred), on the same frame; "
                                   "its best candidate joins the next frame's pool if it "
                                   "beat the tracked pose there. After a failure it runs at "
                                   "once, as without this")
    model_file: str = param("", "trained regressor (.npz); empty = data/tracker/"
                            "regressor.npz when present")
    ensemble: bool = param(True, "a second trained regressor's candidates join the pool "
                           "of steps 1-2 (its palm modes, and its finger regression on every "
                           "palm); off = the one regressor of II.4")
    ensemble_frames: str = param("all", "frames on which the second regressor of ensemble "
                                 "proposes candidates too: all = every frame that regresses; "
                                 "acquire = those that search wide (no tracked pose, or one in "
                                 "doubt: acquire_above_tau), about the single regressor's CPU "
                                 "a frame", choices=("all", "acquire"))
    second_model_file: str = param("", "the second regressor (.npz) of ensemble; empty = "
                                   "data/tracker/regressor_tubes.npz when present")
    mode: str = param("hybrid", "tracking mode", choices=("hybrid", "icp", "regressor"))
    side: str = param("right", "hand side", choices=("right", "left"))

    def __post_init__(self) -> None:
        validate(self)
        if self.far_m <= self.near_m:
            raise ConfigError(f"TrackerConfig.far_m ({self.far_m}) must exceed near_m "
                              f"({self.near_m})")
