"""Held-out and split sections of ``hand-suite bench tracking`` (issue 13).

* **Held-out family** (:mod:`hand_capture.evaldata`, nothing of it used in training): hands
  of capsules and ellipsoids with varied finger thickness, palm and nails, analytic ray
  casting, stereo-like noise, D435-like (640x480, 848x480) and D405-like (640x480) cameras,
  sinusoid / random-walk motions, clutter (table, object, body) in half of the sequences;
  without and with a forearm (and sleeve) in view. Each subject calibrates first (II.3.6)
  from frames of the calibration poses rendered the same way (with the forearm when it is
  in view, as a user's would be) and is tracked with the product settings.
* **Capsule validation family** (:class:`CapsuleSurface`, validation only): the suite's
  own collision capsules drawn as the hand (another surface SHAPE, where the surface
  validation family only moves the template along its normals), the suite's renderer and
  noise; tracked through and from a reset tracker. Settings may be chosen here; the
  held-out family stays for reporting.
* **Calibration bone lengths**: subjects of global scale 0.85..1.15 from both families;
  mean relative bone-length error of the calibrated model (16 bones) beside the template's.
* **Settings split**: ``cost_temporal_weight`` (lambda_2 of eq. II.20) chosen on a
  validation split (synthetic-camera shapes 21, 22) and reported on a test split (the
  bench's shapes 11..13), both from the training family.
* **Resolution**: the same held-out sequences at 424x240, 640x480 and 848x480 (tracker CPU
  time per frame and accuracy), for the camera defaults.
* **Transport**: share of 640x480 16UC1 frames published at 30 Hz that reach a subscriber
  with the tracker's QoS in another process, with the graphs' DDS profile and, as the
  baseline, with Fast DDS defaults.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from hand_capture.bench import print_table
from hand_capture.errors import ConfigError

if TYPE_CHECKING:
    from hand_capture.cameras.base import Intrinsics
    from hand_capture.model import HandModel

#: (camera, clutter, seed) of the held-out sequences; forearm sequences use seed + 100
HELDOUT = (("d435_640", False, 101), ("d435_640", True, 102), ("d435_848", False, 103),
           ("d435_848", True, 104), ("d405_640", False, 105), ("d405_640", True, 106))
HELDOUT_QUICK = (("d435_640", False, 101), ("d405_640", True, 106))
SCALES = (0.85, 0.925, 1.0, 1.075, 1.15)
TEMPORAL_GRID = (0.0, 10.0, 30.0, 100.0, 300.0)
VAL_SEEDS = (21, 22)
#: validation shapes of forearm handling (the suite's generator; the arm classifier's
#: settings were chosen here)
ARM_VAL_SEEDS = (21, 22, 23, 24)
#: the far forearm validation family's camera (:func:`forearm_validation_section` ``far``):
#: D435-like depth (640x480, 87 deg) 0.2 m behind the suite's camera
FAR_CAMERA = {"width": 640, "height": 480, "hfov_deg": 87.0, "camera_position": (0.0, 0.0, -0.2)}
#: the near forearm validation family's camera (``near``): a finer 640x480 depth image (70
#: deg, fx 457 px) 0.15 m nearer the hand than the suite's camera (hand at a D405's
#: distances, about 0.2-0.3 m), where a pixel covers 0.4-0.7 mm of the hand (the suite's
#: 320x240 camera: 1.3-2.4 mm)
NEAR_CAMERA = {"width": 640, "height": 480, "hfov_deg": 70.0,
               "camera_position": (0.0, 0.0, 0.15)}
#: the hard validation set's sleeve: its radius beyond the arm's and where it starts past the
#: wrist, uniform ranges [m]
SLEEVE_WIDER_M, SLEEVE_START_M = (0.01, 0.025), (0.04, 0.08)
#: shape / pose rounds of each calibration in a ``--smoke`` run (the product's 30 in every
#: other run): the same code on the fewest rounds; a smoke run's figures mean nothing
SMOKE_CAL_ROUNDS = 3
_smoke_rounds: list[int] = []  # set while a smoke run goes on (:func:`smoke_calibration`)


@contextmanager
def smoke_calibration(smoke: bool) -> Iterator[None]:
    """Within it, :func:`bench_calibrate` runs :data:`SMOKE_CAL_ROUNDS` rounds if ``smoke``."""
    if smoke:
        _smoke_rounds.append(SMOKE_CAL_ROUNDS)
    try:
        yield
    finally:
        if smoke:
            _smoke_rounds.pop()


def bench_calibrate(frames, **kwargs):
    """:func:`~hand_capture.tracking.calibration.calibrate` as the benchmark runs it: the
    product's settings, fewer rounds in a smoke run (:func:`smoke_calibration`)."""
    from hand_capture.tracking.calibration import calibrate

    if _smoke_rounds:
        kwargs.setdefault("rounds", _smoke_rounds[-1])
    return calibrate(frames, **kwargs)


def _bone_err_pct(model, true_model) -> float:
    lf, lt = np.asarray(model.bone_lengths), np.asarray(true_model.bone_lengths)
    return float(np.mean(np.abs(lf - lt) / lt) * 100.0)


def segment_quality(pixels: np.ndarray, label: np.ndarray, depth: np.ndarray
                    ) -> tuple[float, float]:
    """How well the tracker's hand segment (after the forearm cut) matches the truth.

    Args:
        pixels: (N, 2) the segment's pixels (u, v) (``HandObservation.pixels``).
        label: (H, W) primitive labels of the frame (1 hand, 2 forearm, 3 sleeve, 4
            clutter; :class:`~hand_capture.evaldata.HeldoutSequence`).
        depth: (H, W) the frame's depth (0 = no measurement).

    Returns:
        ``(arm_pct, hand_kept_pct)``: the share of the segment on the forearm or sleeve
        [%] (0 for an empty segment), and the share of the measured hand pixels in it [%]
        (100 when no hand pixel is measured).
    """
    px = np.asarray(pixels).astype(np.int64).reshape(-1, 2)
    lab = label[px[:, 1], px[:, 0]]
    arm = 100.0 * float(np.mean((lab == 2) | (lab == 3))) if len(lab) else 0.0
    n_hand = int(np.count_nonzero((label == 1) & (depth > 0)))
    # measured pixels only (the tracker fills a stereo camera's short gaps: fill_gaps)
    measured = depth[px[:, 1], px[:, 0]] > 0
    kept = 100.0 * np.count_nonzero((lab == 1) & measured) / n_hand if n_hand else 100.0
    return arm, float(kept)


def arm_pixel_counts(arm, frames, labels, config) -> tuple[int, int]:
    """Pixels of the segmented hands (before any cut) the arm classifier labels right, and
    all labelled ones: arm = forearm or sleeve (labels 2, 3), hand = 1; other pixels
    (clutter, unlabelled) left out. ``(0, 0)`` without a classifier."""
    from hand_capture.tracking.preprocess import segment_hand

    if arm is None:
        return 0, 0
    right = total = 0
    for (depth, intr), lab in zip(frames, labels, strict=True):
        obs = segment_hand(depth, intr, config)
        if not obs.found:
            continue
        v, u, _ = obs.vuz
        p = arm.segment_probability(obs.depth_m, obs.mask, obs.box, v, u, intr,
                                    config.arm_grid_mm)
        lv = lab[v, u]
        ok = (lv >= 1) & (lv <= 3)
        right += int(np.count_nonzero((p[ok] > config.arm_threshold) == (lv[ok] >= 2)))
        total += int(np.count_nonzero(ok))
    return right, total


def _score(tracker, frames, truth, labels=None, on_result=None) -> dict:
    """Track a sequence; with ``labels`` also the segment quality per frame
    (:func:`segment_quality`) and which cut made it (``plane``: the frame followed a
    tracked one, so the forearm was cut at the previous wrist; else the cloud's shape);
    ``on_result(i, r)``, when given, sees every frame's result too."""
    from hand_capture.bench.tracking import _run_mode, _summary

    seg: list[tuple[float, float, bool]] = []
    last = [False]

    def each(i: int, r) -> None:
        if labels is not None:
            o = r.observation
            px = o.pixels if o is not None and o.found else np.zeros((0, 2))
            seg.append((*segment_quality(px, labels[i], frames[i][0]), last[0]))
            last[0] = bool(r.success)
        if on_result is not None:
            on_result(i, r)

    e, w, c, fl, _, _ = _run_mode(tracker, frames, truth,
                                  on_result=None if labels is None and on_result is None
                                  else each)
    s = _summary(e)
    s.update(errs=e, cpu=c, wall=w, flags=fl, seg=np.array(seg).reshape(-1, 3))
    return s


def heldout_case(k: int, cam: str, clutter: bool, seed: int, arm: bool, n: int, step: int):
    """The held-out sequence of case ``k`` (camera, clutter, ``seed`` with the forearm's
    offset already added; with a forearm bare arm and sleeve alternate, so each camera gets
    both), its calibration frames (one set for every setting calibrated on it) and the
    template's calibration from them: ``(HeldoutSequence, frames, CalibrationResult)``."""
    from hand_capture.evaldata import calibration_frames, make_sequence
    from hand_capture.model import HandModel
    from hand_capture.tracking.calibration import CALIBRATION_POSES

    seq = make_sequence(seed, n, cam, forearm=arm, clutter=clutter, step=step,
                        sleeve=bool((k + k // 2) % 2))
    calf = calibration_frames(seq.model, seq.surface, list(CALIBRATION_POSES.values()), cam,
                              np.random.default_rng(seed))
    return seq, calf, bench_calibrate(calf, model=HandModel())


def heldout_section(reg, config, quick: bool, cases: tuple | None = None,
                    frames: tuple[int, int] | None = None) -> dict:
    """Track the held-out family without and with a forearm (see the module doc);
    ``cases`` / ``frames`` ((count, step)) override the quick / full choice."""
    from hand_capture.bench.tracking import _summary
    from hand_capture.evaldata import make_sequence
    from hand_capture.model import HandModel
    from hand_capture.tracking.hybrid import HybridTracker

    cases = cases or (HELDOUT_QUICK if quick else HELDOUT)
    n, step = frames or ((12, 3) if quick else (60, 1))
    base = HandModel()
    rows, agg = [], {"heldout": [], "forearm": []}
    cpu: dict[str, list] = {"heldout": [], "forearm": []}
    seg: dict[str, list] = {"heldout": [], "forearm": []}
    cut_only: list[np.ndarray] = []
    by_var: dict[str, list] = {}
    drift: dict[str, list] = {}
    acc = [0, 0]
    for arm in (False, True):
        key = "forearm" if arm else "heldout"
        for k, (cam, clutter, seed) in enumerate(cases):
            seed = seed + (100 if arm else 0)
            t0 = time.perf_counter()
            seq, calf, cal = heldout_case(k, cam, clutter, seed, arm, n, step)
            t_render = (time.perf_counter() - t0) / n
            model = base.with_shape(cal.shape)
            tracker = HybridTracker(base, config, reg)
            tracker.set_calibration(cal)   # as the node: the shape, and tau from the fit
            s = _score(tracker, seq.frames, seq.keypoints, seq.labels)
            if arm and tracker.arm is not None:
                # the baseline in the same run: the geometric forearm cut alone
                t_cut = HybridTracker(base, dataclasses.replace(config, arm_classifier=False),
                                      reg)
                t_cut.set_calibration(cal)
                cut_only.append(_score(t_cut, seq.frames, seq.keypoints)["errs"])
                acc = [a + b for a, b in zip(acc, arm_pixel_counts(
                    tracker.arm, seq.frames, seq.labels, config), strict=True)]
            agg[key].append(s["errs"])
            cpu[key].append(s["cpu"])
            seg[key].append(s["seg"])
            rows.append([key, cam, "yes" if clutter else "no",
                         "sleeve" if seq.surface.sleeve else ("arm" if arm else "-"),
                         f"{seq.model.shape.global_scale:.3f}",
                         f"{model.shape.global_scale:.3f}",
                         _bone_err_pct(model, seq.model), len(seq.frames), s["mean"],
                         s["median"], s["s20"], float(np.mean(s["flags"])),
                         float(np.mean(s["seg"][:, 0])), float(np.mean(s["seg"][:, 1])),
                         1e3 * float(np.mean(s["cpu"])), 1e3 * t_render])
            if not arm:   # before -> after: the surface-tolerance settings one by one
                # (tracking and calibration), and how far each drifts from the true pose
                for name, (_, c) in surface_variants(config).items():
                    if c == config:
                        e_v = s["errs"]
                    else:
                        cal_v = bench_calibrate(calf, model=base, config=c)
                        t_v = HybridTracker(base, c, reg)
                        t_v.set_calibration(cal_v)
                        e_v = _score(t_v, seq.frames, seq.keypoints)["errs"]
                    by_var.setdefault(name, []).append(e_v)
                    drift.setdefault(name, []).append(truth_drift_mm(
                        seq.model, c, reg, seq.frames, seq.poses, seq.keypoints))
            if not arm and k == 0:   # what the first sequence's error is made of
                exact = make_sequence(seed, n, cam, clutter=clutter, step=step, noise=False)
                diag = {"same": s,
                        "exact depth": _score(HybridTracker(model, config, reg), exact.frames,
                                              exact.keypoints),
                        "uncalibrated": _score(HybridTracker(base, config, reg), seq.frames,
                                               seq.keypoints)}
    print_table("held-out diagnostics, first sequence: the same with exact depth (no noise), "
                "and with the uncalibrated template", ["variant", "mean mm", "succ@20"],
                [[k, v["mean"], v["s20"]] for k, v in diag.items()])
    print_table("held-out family (hand_capture.evaldata: capsule/ellipsoid hands, ray casting, "
                "stereo-like noise, other cameras and motions), calibrated per subject, "
                "product settings",
                ["set", "camera", "clutter", "arm", "s_g true", "s_g fit", "bone err %",
                 "frames", "mean mm", "median mm", "succ@20", "flag rate", "seg arm %",
                 "hand kept %", "cpu ms", "render ms"], rows)
    out = {"heldout_first_mean_mm": diag["same"]["mean"],
           "heldout_first_exact_depth_mean_mm": diag["exact depth"]["mean"],
           "heldout_first_uncalibrated_mean_mm": diag["uncalibrated"]["mean"]}
    # what the forearm frames' error is made of: the segment the tracker fitted, by the cut
    # that made it (at the previous wrist while tracking, else from the cloud's shape)
    sq = np.concatenate(seg["forearm"])
    ef = np.concatenate(agg["forearm"]).mean(axis=1)
    srows = []
    for name, sel in (("previous wrist", sq[:, 2] > 0),
                      ("cloud, then fitted wrist", sq[:, 2] == 0),
                      ("all", np.ones(len(sq), bool))):
        srows.append([name, int(sel.sum())] + ([float(np.mean(sq[sel, 0])),
                                                 float(np.mean(sq[sel, 1])),
                                                 float(np.mean(sq[sel, 1] < 20.0)),
                                                 float(np.mean(ef[sel]))]
                                                if sel.any() else [math.nan] * 4))
    print_table("forearm frames: the fitted segment against the true labels (seg arm %: share "
                "of the segment on the forearm or sleeve; hand kept %: share of the measured "
                "hand pixels in it; missed: hand kept under 20 %), by the cut that made it",
                ["cut", "frames", "seg arm %", "hand kept %", "missed", "mean mm"], srows)
    out.update({"forearm_seg_arm_pct": srows[2][2], "forearm_seg_hand_kept_pct": srows[2][3],
                "forearm_seg_missed_rate": srows[2][4],
                "forearm_seg_arm_pct_plane": srows[0][2],
                "forearm_seg_arm_pct_cloud": srows[1][2],
                "heldout_seg_hand_kept_pct": float(np.mean(
                    np.concatenate(seg["heldout"])[:, 1]))})
    if cut_only:
        e_cut, e_now = _summary(np.concatenate(cut_only)), _summary(np.concatenate(
            agg["forearm"]))
        print_table("forearm frames of the held-out family: the geometric forearm cut alone "
                    "(before the arm classifier) and with the classifier first (product); "
                    "classifier pixel accuracy on the segmented hands",
                    ["forearm handling", "mean mm", "succ@20", "pixel acc"],
                    [["cut only", e_cut["mean"], e_cut["s20"], ""],
                     ["classifier + cut", e_now["mean"], e_now["s20"], acc[0] / max(acc[1], 1)]])
        out.update({"forearm_cut_only_mean_mm": e_cut["mean"],
                    "forearm_cut_only_success_20mm": e_cut["s20"],
                    "heldout_arm_pixel_acc": acc[0] / max(acc[1], 1)})
    vrows = []
    for name, (key, _) in surface_variants(config).items():
        sm = _summary(np.concatenate(by_var[name]))
        d = float(np.concatenate(drift[name]).mean())
        vrows.append([name, sm["mean"], sm["median"], sm["s20"], d])
        out.update({f"heldout{key}_mean_mm": sm["mean"], f"heldout{key}_success_20mm": sm["s20"],
                    f"heldout{key}_truth_drift_mm": d})
    print_table("held-out, no forearm: surface-tolerance settings (before = neither; each "
                "calibrates and tracks with its settings); drift = mean keypoint distance "
                "after 5 ICP passes started at the true pose with the true shape",
                ["settings", "mean mm", "median mm", "succ@20", "drift mm"], vrows)
    for key in ("heldout", "forearm"):
        e = np.concatenate(agg[key])
        s = _summary(e)
        c = np.concatenate(cpu[key])
        out.update({f"{key}_mean_mm": s["mean"], f"{key}_median_mm": s["median"],
                    **{f"{key}_success_{t}mm": s[f"s{t}"] for t in (10, 20, 30, 50)},
                    f"{key}_frames": len(e), f"{key}_cpu_ms": 1e3 * float(np.mean(c)),
                    f"{key}_cpu_ms_p99": 1e3 * float(np.percentile(c, 99))})
    return out


def suite_forearm_sequence(seed: int, clip: str, n: int, step: int, *, close: bool = False,
                           clutter: bool = False, sleeve: bool = False, table: bool = False,
                           surface: SurfaceVariant | CapsuleSurface | None = None,
                           camera: dict | None = None, distractor: bool = False,
                           wrist_path: np.ndarray | None = None
                           ) -> tuple[HandModel, Intrinsics, list, list, list]:
    """A sequence of the suite's own generator with a forearm in view: the synthetic
    camera's shape ``seed`` and motion ``clip`` (its mesh, rasteriser and noise model,
    320x240) with the training renders' forearm (:func:`~hand_capture.tracking.train.
    forearm_mesh`, radius, length and bend drawn from ``seed``). Nothing of the held-out
    family: a validation set to tune forearm handling on.

    Harder scenes of the same generator (the arm classifier's failure case, issue 13):
    ``close`` a close-range wide camera (87 deg, 0.15 m nearer the hand: about 0.25 m);
    ``clutter`` a box of the suite's primitives (60-100 mm) 10 mm behind the palm that slides
    in from the side over the sequence until it touches the hand; ``sleeve`` a wider cylinder
    (10-25 mm over the arm's radius) over the forearm from 40-80 mm past the wrist;
    ``table`` a plane filling the view (a table or a wall) 50-120 mm behind the first frame's
    farthest keypoint, tilted up to 10 deg about both image axes, which the forearm runs
    into (as an arm resting on a table joins it). ``distractor`` a box (50-90 mm) nearer the
    camera than the hand (its far face 50-120 mm in front of the nearest keypoint), beside
    it and not touching it (70-100 mm from the middle MCP across the hand's axis, plus half
    the box), which slides into view over four frames a third into the sequence and then
    moves with the hand (another hand or a held object; the hand is then no longer the
    nearest thing in view). ``surface`` replaces the hand's surface
    (:class:`SurfaceVariant`, :class:`CapsuleSurface`; None: the template mesh); ``camera``
    overrides fields of the synthetic camera's config (e.g. ``width``, ``height``,
    ``hfov_deg``, ``camera_position``; after ``close``'s). ``wrist_path`` (n, 3) [m] is
    added to the root translation frame by frame, the forearm following the hand
    (:func:`moving_wrist_path`).

    Returns:
        ``(model, intrinsics, frames, keypoints, labels)``: the true model, the pinhole,
        ``n`` frames ``(depth uint16 [mm], intrinsics)`` (every ``step``-th of 30 fps), the
        (21, 3) true keypoints [m] and (H, W) labels (1 hand, 2 forearm or sleeve, 4
        clutter, 0 other) of each.
    """
    from hand_capture.cameras.primitives import box, plane
    from hand_capture.cameras.render import Mesh, make_renderer
    from hand_capture.cameras.synthetic import SyntheticCamera, SyntheticCameraConfig
    from hand_capture.tracking.train import draw_forearm, forearm_mesh

    rng = np.random.default_rng(seed * 1000 + sum(map(ord, clip)))
    near = {"hfov_deg": 87.0, "camera_position": (0.0, 0.0, 0.15)} if close else {}
    near.update(camera or {})
    cam = SyntheticCamera(SyntheticCameraConfig(render_color=False, shape_seed=seed, clip=clip,
                                                noise_seed=seed + 1000, **near))
    cam.open()
    radius, length, bend = draw_forearm(rng)
    extra: list = []
    if sleeve:
        extra.append((radius + rng.uniform(*SLEEVE_WIDER_M), rng.uniform(*SLEEVE_START_M)))
    renderer = make_renderer("zbuffer")
    last = int(math.floor(cam.motion.duration * 30))
    frames, kps, labels = [], [], []
    obj = None
    hand_mesh = surface.mesh_fn(cam.model) if surface is not None else None
    idx = list(range(0, last + 1, step))[:n]
    if table:   # drawn after the forearm: the other variants' draws stay the same
        kp = cam.model.joint_positions(cam.truth_pose(idx[0] / 30.0))
        centre = kp.mean(axis=0)
        centre[2] = kp[:, 2].max() + rng.uniform(0.05, 0.12)
        ax, ay = np.deg2rad(rng.uniform(-10.0, 10.0, 2))
        rot = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(ax), -np.sin(ax)],
                        [0.0, np.sin(ax), np.cos(ax)]]) @ np.array(
            [[np.cos(ay), 0.0, np.sin(ay)], [0.0, 1.0, 0.0], [-np.sin(ay), 0.0, np.cos(ay)]])
        tv, tf = plane((2.0, 2.0), n=16)
        extra_meshes = [Mesh(tv @ rot.T + centre, tf, 254)]
    else:
        extra_meshes = []
    if distractor:   # drawn last: the other variants' draws stay the same
        d_size = rng.uniform(0.05, 0.09, 3)
        d_side = float(rng.choice([-1.0, 1.0]))
        d_lateral = rng.uniform(0.07, 0.1) + 0.5 * float(d_size[:2].max())
        d_nearer = rng.uniform(0.05, 0.12) + 0.5 * float(d_size[2])
        d_in = len(idx) // 3
        d_mesh = box(d_size)
    for k, i in enumerate(idx):
        t = i / 30.0
        pose = cam.truth_pose(t)
        if wrist_path is not None:
            pose = pose.copy()
            pose[0:3] += wrist_path[k]
        meshes, _ = cam.scene_meshes(t, pose)
        if distractor:
            kp = cam.model.joint_positions(pose)
            side = np.cross(kp[9] - kp[0], [0.0, 0.0, 1.0])
            side *= d_side / max(float(np.linalg.norm(side)), 1e-9)
            out = 0.6 * float(np.clip(1.0 - (k - d_in) / 4.0, 0.0, 1.0))  # out of view first
            c = kp[9] + side * (d_lateral + out)
            c[2] = kp[:, 2].min() - d_nearer
            meshes.append(Mesh(d_mesh[0] + c, d_mesh[1], 254, closed=True))
        if hand_mesh is not None:
            meshes[0] = hand_mesh(pose)
        arm = forearm_mesh(cam.model, pose, radius, length, bend, label=255)
        meshes += [arm] + [forearm_mesh(cam.model, pose, r, length, bend, label=255, start=s)
                           for r, s in extra]
        if clutter:
            if obj is None:   # beside the first frame's palm, across the arm in the image
                kp = cam.model.joint_positions(pose)
                side = np.cross(kp[9] - kp[0], [0.0, 0.0, 1.0])
                side *= rng.choice([-1.0, 1.0]) / max(float(np.linalg.norm(side)), 1e-9)
                size = rng.uniform(0.06, 0.1, 3)
                c = kp[9] + side * (0.045 + 0.5 * size[0])
                c[2] += 0.5 * size[2] + 0.01
                obj = box(size)
            # it slides in from 120 mm away to the hand's side over the sequence
            gap = 0.12 * (1.0 - k / max(len(idx) - 1, 1))
            meshes.append(Mesh(obj[0] + c + side * gap, obj[1], 254, closed=True))
        res = renderer.render(meshes + extra_meshes, cam.intrinsics)
        frames.append((cam.noise.apply_mm(res.depth, res.cos_incidence, cam.intrinsics, rng),
                       cam.intrinsics))
        kps.append(cam.model.joint_positions(pose))
        labels.append(np.select([res.label == 255, res.label == 254, res.label > 0],
                                [2, 4, 1], 0).astype(np.int16))
    return cam.model, cam.intrinsics, frames, kps, labels


@dataclass(frozen=True)
class SurfaceVariant:
    """Another hand surface on the suite's own model and renderer (the validation family of
    surface tolerance, issue 13; nothing of the held-out family): the template mesh with
    its palm and fingers moved along their normals and its wrist stub cut short.

    Attributes:
        palm_mm: the palm's surface (vertex label 0) moved outwards by this [mm].
        finger_mm: the fingers' surface moved outwards by this [mm].
        stub_m: the mesh kept up to this far beyond the wrist keypoint (the template's
            reaches 0.036) [m, at template size].
    """

    palm_mm: float = 0.0
    finger_mm: float = 0.0
    stub_m: float = 0.036

    @staticmethod
    def sample(rng: np.random.Generator) -> SurfaceVariant:
        """A random variant: palm -1..+3 mm, fingers -1..+1.5 mm, stub 0..20 mm."""
        return SurfaceVariant(float(rng.uniform(-1.0, 3.0)), float(rng.uniform(-1.0, 1.5)),
                              float(rng.uniform(0.0, 0.02)))

    def mesh_fn(self, model: HandModel):
        """``q (27,) -> Mesh`` of ``model`` in pose ``q`` with this surface."""
        from hand_capture.cameras.render import Mesh
        from hand_capture.tracking.icp import beyond_wrist

        keep = beyond_wrist(model) <= self.stub_m * float(model.shape.global_scale) + 1e-9
        faces = model.faces[keep[model.faces].all(axis=1)]
        off = np.where(model.vertex_labels == 0, self.palm_mm, self.finger_mm) * 1e-3
        closed = bool(keep.all())

        def fn(q: np.ndarray) -> Mesh:
            V = model.vertices(q)
            return Mesh(V + model.normals(V) * off[:, None], faces, 1, closed=closed)

        return fn


@dataclass(frozen=True)
class CapsuleSurface:
    """The suite's own collision capsules (:attr:`HandModel.capsules`, the MJCF hand's geoms)
    drawn as the hand surface: a validation family of another SHAPE than the template's
    (:class:`SurfaceVariant` only moves the template along its normals), the kind of
    mismatch a user's hand brings. Cylindrical fingers with round tips, a palm of a few
    capsules with a flat end at the wrist, no stub beyond it. The suite's own geometry,
    nothing of the held-out family (:mod:`hand_capture.evaldata`).
    """

    def mesh_fn(self, model: HandModel):
        """``q (27,) -> Mesh`` of ``model``'s capsules in pose ``q`` (one closed mesh)."""
        import trimesh

        from hand_capture.cameras.render import Mesh

        parts = [trimesh.creation.capsule(height=float(np.linalg.norm(c.p1 - c.p0)),
                                          radius=c.radius, count=[8, 12])
                 for c in model.capsules]
        local = [np.asarray(m.vertices) for m in parts]       # along z, centred
        start = np.cumsum([0] + [len(v) for v in local])
        faces = np.concatenate([np.asarray(m.faces) + o for m, o in zip(parts, start[:-1],
                                                                       strict=True)])

        def fn(q: np.ndarray) -> Mesh:
            seg = model.capsule_segments(q)
            out = []
            for (a, b), v in zip(seg, local, strict=True):
                z = (b - a) / max(float(np.linalg.norm(b - a)), 1e-12)
                x = np.cross(z, (1.0, 0.0, 0.0) if abs(z[0]) < 0.9 else (0.0, 1.0, 0.0))
                x /= np.linalg.norm(x)
                out.append(0.5 * (a + b) + v @ np.stack([x, np.cross(z, x), z]))
            return Mesh(np.concatenate(out), faces, 1, closed=True)

        return fn


#: the long fingers' share of a spread (:func:`spread_fingers`): MCP abduction away from
#: the middle finger is + for the index, - for the ring and the little finger
_SPREAD = (("index", 1.0), ("ring", -1.0), ("little", -1.6))


def spread_fingers(pose: np.ndarray, spread_deg: float) -> np.ndarray:
    """``pose`` (27,) with the long fingers spread apart from the middle finger: each MCP
    abduction moved by ``spread_deg`` [deg] times its share (index 1, ring 1, little 1.6),
    faded out as the finger curls (none from 1.2 rad of MCP flexion), clipped into the joint
    limits. The suite's motions keep every abduction at zero; a real open hand spreads."""
    from hand_capture.model import JOINT_INDEX, JOINT_LIMITS

    q = np.array(pose, dtype=float)
    for f, share in _SPREAD:
        i = JOINT_INDEX[f"{f}_mcp_abd"]
        open_ = float(np.clip(1.0 - q[JOINT_INDEX[f"{f}_mcp_flex"]] / 1.2, 0.0, 1.0))
        q[i] = np.clip(q[i] + math.radians(spread_deg) * share * open_, *JOINT_LIMITS[i])
    return q


def moving_wrist_path(rng: np.random.Generator, n: int, step: int) -> np.ndarray:
    """A smooth path (n, 3) [m] for the wrist of a suite clip, frames ``step`` apart at 30
    fps: along each camera axis two sinusoids of 0.25-0.8 Hz with random phases, 10-25 mm
    each across the image and 5-15 mm in depth, moved to start at zero. The validation
    plan's clips hold the wrist still; this moves it about 3.7 mm a 30 fps frame on average (the
    held-out family: 2.4-7 mm, by its own generator)."""
    t = np.arange(n) * step / 30.0
    p = np.zeros((n, 3))
    for axis, (lo, hi) in enumerate(((0.010, 0.025), (0.010, 0.025), (0.005, 0.015))):
        for _ in range(2):
            f, a = rng.uniform(0.25, 0.8), rng.uniform(lo, hi)
            p[:, axis] += a * np.sin(2.0 * np.pi * f * t + rng.uniform(0.0, 2.0 * np.pi))
    return p - p[0]


def suite_surface_sequence(seed: int, clip: str, n: int, step: int,
                           variant: SurfaceVariant | CapsuleSurface,
                           fingers: np.ndarray | None = None, spread_deg: float = 0.0,
                           wrist_path: np.ndarray | None = None
                           ) -> tuple[HandModel, Intrinsics, list, list, list, list]:
    """A sequence of the suite's generator (the synthetic camera's shape ``seed``, motion
    ``clip``, rasteriser and noise model, 320x240) with the hand's surface replaced by
    ``variant``; ``fingers`` (n, 21) [rad], when given, replaces the clip's finger joint
    angles frame by frame (the wrist keeps the clip's path); ``spread_deg`` spreads the
    fingers (:func:`spread_fingers`); ``wrist_path`` (n, 3) [m] is added to the root
    translation frame by frame (:func:`moving_wrist_path`). Returns ``(model, intrinsics,
    frames, keypoints, poses, calibration frames)`` (the calibration poses rendered with the
    same surface and noise)."""
    from hand_capture.cameras.render import make_renderer
    from hand_capture.cameras.synthetic import SyntheticCamera, SyntheticCameraConfig
    from hand_capture.tracking.calibration import render_calibration_frames

    rng = np.random.default_rng(seed * 1000 + 7 + sum(map(ord, clip)))
    cam = SyntheticCamera(SyntheticCameraConfig(render_color=False, shape_seed=seed, clip=clip,
                                                noise_seed=seed + 2000))
    cam.open()
    mesh = variant.mesh_fn(cam.model)
    renderer = make_renderer("zbuffer")
    last = int(math.floor(cam.motion.duration * 30))
    frames, kps, poses = [], [], []
    for k, i in enumerate(list(range(0, last + 1, step))[:n]):
        pose = cam.truth_pose(i / 30.0)
        if fingers is not None:
            pose = pose.copy()
            pose[6:] = fingers[k]
        if spread_deg:
            pose = spread_fingers(pose, spread_deg)
        if wrist_path is not None:
            pose = pose.copy()
            pose[0:3] += wrist_path[k]
        poses.append(pose)
        res = renderer.render([mesh(pose)], cam.intrinsics)
        frames.append((cam.noise.apply_mm(res.depth, res.cos_incidence, cam.intrinsics, rng),
                       cam.intrinsics))
        kps.append(cam.model.joint_positions(pose))
    cal = render_calibration_frames(cam.model, cam.intrinsics, rng, mesh_fn=mesh)
    return cam.model, cam.intrinsics, frames, kps, poses, cal


def truth_drift_mm(model: HandModel, config, reg, frames: list, poses, keypoints,
                   passes: int = 5, every: int = 6) -> np.ndarray:
    """How far the fit moves away from the truth: every ``every``-th frame, ICP alone
    (``mode`` icp, the true shape ``model``) started at the true pose and run ``passes``
    times on that frame; the mean keypoint distance to the truth after it [mm], per frame."""
    from hand_capture.tracking.hybrid import HybridTracker

    tr = HybridTracker(model, dataclasses.replace(config, mode="icp"), reg)
    out = []
    for (depth, intr), q, kp in list(zip(frames, poses, keypoints, strict=True))[::every]:
        q = np.asarray(q, float)
        for _ in range(passes):
            tr.reset(q)
            q = tr.process(depth, intr).pose
        out.append(float(np.linalg.norm(model.joint_positions(q) - kp, axis=1).mean()) * 1e3)
    return np.array(out)


def surface_variants(config) -> dict[str, tuple[str, object]]:
    """The surface-tolerance settings compared in the same run: ``name -> (key suffix,
    config)``: the product, without the straight / curled finger postures, without the
    optional wrist stub, without the finger-wise selection, and before (neither)."""
    rep = dataclasses.replace
    return {"product": ("", config),
            "no finger postures": ("_no_finger_postures", rep(config, finger_postures=False)),
            "stub not optional": ("_stub_not_optional", rep(config, wrist_optional=False)),
            "no finger swap": ("_no_finger_swap", rep(config, finger_swap=False)),
            "before (neither)": ("_before", rep(config, wrist_optional=False,
                                                finger_swap=False))}


def _validation_plan(quick: bool, smoke: bool = False
                     ) -> tuple[tuple[int, ...], tuple[str, ...], int, int]:
    """The validation families' sequences (surface, capsule and forearm validation): the
    shapes :data:`ARM_VAL_SEEDS`, the motions, the frames per sequence and their step
    (``smoke``: one short sequence)."""
    if smoke:
        return ARM_VAL_SEEDS[:1], ("pinch",), 6, 4
    if quick:
        return ARM_VAL_SEEDS[:1], ("finger_counting", "pinch"), 8, 4
    return ARM_VAL_SEEDS, ("finger_counting", "wrist_rotation", "pinch", "fist"), 20, 3


def validation_surface(seed: int, clip: str) -> SurfaceVariant:
    """The surface validation family's surface of shape ``seed`` in motion ``clip`` (the
    same in every section that uses that family)."""
    return SurfaceVariant.sample(np.random.default_rng(seed * 10 + len(clip)))


def surface_validation_section(reg, config, quick: bool,
                               variants: dict[str, tuple[str, object]] | None = None,
                               smoke: bool = False) -> dict:
    """Surface tolerance on the validation family (:class:`SurfaceVariant` on the suite's
    own mesh, renderer and noise, shapes :data:`ARM_VAL_SEEDS`): where the optional wrist
    stub (``wrist_optional``, ``wrist_optional_m``) and the finger-wise selection
    (``finger_swap``) were chosen. The variants of :func:`surface_variants` (tracking and
    calibration), each calibrated per sequence from the same surface: keypoint error,
    success@20, calibrated bone-length error and the drift from the true pose
    (:func:`truth_drift_mm`), and the tracker's CPU time per frame [ms]. ``variants``
    (default :func:`surface_variants`) replaces the compared settings (the regressor
    validation, ``scripts/regressor_validation.py``, scores the product alone)."""
    from hand_capture.bench.tracking import _summary
    from hand_capture.model import HandModel
    from hand_capture.tracking.hybrid import HybridTracker

    seeds, clips, n, step = _validation_plan(quick, smoke)
    base = HandModel()
    variants = surface_variants(config) if variants is None else variants
    res: dict[str, dict[str, list]] = {k: {"e": [], "b": [], "d": [], "c": []}
                                       for k in variants}
    for seed in seeds:
        for clip in clips:
            v = validation_surface(seed, clip)
            true, _, frames, kps, poses, calf = suite_surface_sequence(seed, clip, n, step, v)
            for name, (_, cfg) in variants.items():
                cal = bench_calibrate(calf, model=base, config=cfg)
                tr = HybridTracker(base, cfg, reg)
                tr.set_calibration(cal)
                sc = _score(tr, frames, kps)
                res[name]["e"].append(sc["errs"])
                res[name]["c"].append(sc["cpu"])
                res[name]["b"].append(_bone_err_pct(tr.model, true))
                res[name]["d"].append(truth_drift_mm(true, cfg, reg, frames, poses, kps,
                                                     every=4))
    rows, out = [], {}
    for name, (key, _) in variants.items():
        sm = _summary(np.concatenate(res[name]["e"]))
        b = res[name]["b"]
        d = float(np.concatenate(res[name]["d"]).mean())
        rows.append([name, sm["mean"], sm["median"], sm["s20"], float(np.mean(b)),
                     float(np.max(b)), d])
        out.update({f"val_surface{key}_mean_mm": sm["mean"],
                    f"val_surface{key}_success_20mm": sm["s20"],
                    f"val_surface{key}_bone_err_pct": float(np.mean(b)),
                    f"val_surface{key}_truth_drift_mm": d,
                    f"val_surface{key}_cpu_ms": float(np.concatenate(res[name]["c"]).mean())
                    * 1e3})
    print_table(f"surface validation family (the suite's mesh: palm -1..+3 mm, fingers -1..+1.5 "
                f"mm, wrist stub cut 0-20 mm past the wrist; shapes {seeds}): surface-tolerance "
                "settings", ["settings", "mean mm", "median mm", "succ@20", "bone err %",
                             "bone err max %", "drift mm"], rows)
    return out


def capsule_validation_section(reg, config, quick: bool, smoke: bool = False) -> dict:
    """The tracker on the capsule validation family (:class:`CapsuleSurface`: the suite's
    collision capsules as the hand, its renderer and noise, shapes :data:`ARM_VAL_SEEDS`,
    the surface validation's motions), product settings, calibrated per sequence from the
    same surface: keypoint error and success@20 tracked through (per motion and all),
    calibrated bone-length error, drift from the true pose (:func:`truth_drift_mm`), and
    every frame from a reset tracker (the regressor's re-initialisation on a surface it was
    not trained on)."""
    from hand_capture.bench.tracking import _summary
    from hand_capture.model import HandModel
    from hand_capture.tracking.hybrid import HybridTracker

    seeds, clips, n, step = _validation_plan(quick, smoke)
    base = HandModel()
    surface = CapsuleSurface()
    by_clip: dict[str, dict[str, list]] = {c: {"e": [], "f": []} for c in clips}
    bones, drift, cpu = [], [], []
    for seed in seeds:
        for clip in clips:
            true, _, frames, kps, poses, calf = suite_surface_sequence(seed, clip, n, step,
                                                                       surface)
            tr = HybridTracker(base, config, reg)
            tr.set_calibration(bench_calibrate(calf, model=base, config=config))
            sc = _score(tr, frames, kps)
            by_clip[clip]["e"].append(sc["errs"])
            cpu.append(sc["cpu"])
            bones.append(_bone_err_pct(tr.model, true))
            drift.append(truth_drift_mm(true, config, reg, frames, poses, kps, every=4))
            hand_only = [(d > 0).astype(np.uint8) for d, _ in frames]   # no forearm here
            by_clip[clip]["f"].append(_score_first(tr, frames, kps, hand_only)["errs"])
    rows = []
    for name, sel in [(c, (c,)) for c in clips] + [("all", clips)]:
        e = _summary(np.concatenate([x for c in sel for x in by_clip[c]["e"]]))
        f = _summary(np.concatenate([x for c in sel for x in by_clip[c]["f"]]))
        rows.append([name, e["mean"], e["median"], e["s20"], f["mean"], f["s20"]])
    print_table(f"capsule validation family (the suite's collision capsules as the hand, its "
                f"renderer and noise; shapes {seeds}), product settings: tracked through, and "
                "every frame from a reset tracker",
                ["motion", "mean mm", "median mm", "succ@20", "reset mean mm",
                 "reset succ@20"], rows)
    d = float(np.concatenate(drift).mean())
    print(f"capsule validation: bone err {np.mean(bones):.2f} % mean, {np.max(bones):.2f} % "
          f"worst; drift from the true pose {d:.2f} mm")
    return {"val_capsule_mean_mm": rows[-1][1], "val_capsule_median_mm": rows[-1][2],
            "val_capsule_success_20mm": rows[-1][3], "val_capsule_reset_mean_mm": rows[-1][4],
            "val_capsule_reset_success_20mm": rows[-1][5],
            "val_capsule_bone_err_pct": float(np.mean(bones)),
            "val_capsule_truth_drift_mm": d,
            "val_capsule_cpu_ms": float(np.concatenate(cpu).mean()) * 1e3}


def with_artifacts(frames: list, seed: int) -> list:
    """``frames`` ((depth uint16 [mm], intrinsics) each) with a stereo camera's artifacts
    (:func:`~hand_capture.tracking.augment.add_artifacts_mm`, drawn from ``seed``)."""
    from hand_capture.tracking.augment import add_artifacts_mm

    rng = np.random.default_rng(seed)
    return [(add_artifacts_mm(d, rng), intr) for d, intr in frames]


def stereo_validation_section(reg, config, quick: bool, smoke: bool = False) -> dict:
    """The surface and capsule validation families (same subjects, motions and surfaces)
    with a stereo camera's artifacts on every frame and calibration frame
    (:mod:`hand_capture.tracking.augment`: edge fattening, occlusion bands, holes,
    correlated error; the suite's own model, not the held-out family's). Product settings,
    calibrated per sequence on the artifact frames, tracked through. The same families
    without the artifacts are :func:`surface_validation_section` (product row) and
    :func:`capsule_validation_section` in the same run: the difference is what the
    artifacts cost."""
    from hand_capture.bench.tracking import _summary
    from hand_capture.model import HandModel
    from hand_capture.tracking.hybrid import HybridTracker

    seeds, clips, n, step = _validation_plan(quick, smoke)
    base = HandModel()
    errs: dict[str, list] = {"surface": [], "capsule": []}
    for seed in seeds:
        for clip in clips:
            for family in errs:
                surface = CapsuleSurface() if family == "capsule" else \
                    validation_surface(seed, clip)
                _, _, frames, kps, _, calf = suite_surface_sequence(seed, clip, n, step,
                                                                    surface)
                art = 7000 + 100 * seed + 10 * len(clip) + (family == "capsule")
                tr = HybridTracker(base, config, reg)
                tr.set_calibration(bench_calibrate(with_artifacts(calf, art + 5), model=base,
                                                   config=config))
                errs[family].append(_score(tr, with_artifacts(frames, art), kps)["errs"])
    rows, out = [], {}
    for family, parts in errs.items():
        sm = _summary(np.concatenate(parts))
        rows.append([family, sm["mean"], sm["median"], sm["s20"]])
        out.update({f"val_stereo_{family}_mean_mm": sm["mean"],
                    f"val_stereo_{family}_success_20mm": sm["s20"]})
    print_table(f"stereo artifacts validation (the surface and capsule validation families, "
                f"shapes {seeds}, with the suite's model of a stereo camera's artifacts), "
                "product settings, tracked through",
                ["family", "mean mm", "median mm", "succ@20"], rows)
    return out


def track_with_candidate(tracker, frames: list, poses: list, truth: list, extra) -> np.ndarray:
    """Keypoint errors (n, 21) [mm] of ``tracker`` on ``frames`` from a reset, with one more
    candidate in each frame's pool: ``extra(q, prev)`` (the frame's true pose, the tracker's
    previous pose) returns it, and it joins as the deferred regression's carry does
    (screened, refined and selected like the others); None leaves the tracker's own carry.
    The diagnosis of ``scripts/tracking_oracle.py`` and of the tube families' ``--oracle``."""
    tracker.reset()
    out = []
    for (depth, intr), q, kp in zip(frames, poses, truth, strict=True):
        cand = extra(q, tracker.prev)
        if cand is not None:
            tracker._carry = cand
        r = tracker.process(depth, intr)
        tracker.run_deferred()
        out.append(np.linalg.norm(tracker.model.joint_positions(r.pose) - kp, axis=1) * 1e3)
    return np.array(out)


def _score_first(tracker, frames, truth, labels) -> dict:
    """Every frame tracked from a reset tracker (the first frame, or after a lost one: no
    previous wrist to cut the forearm at); as :func:`_score`."""
    from hand_capture.bench.tracking import _summary

    errs, seg = [], []
    for (depth, intr), kp, lab in zip(frames, truth, labels, strict=True):
        tracker.reset()
        r = tracker.process(depth, intr)
        errs.append(np.linalg.norm(tracker.model.joint_positions(r.pose) - kp, axis=1) * 1e3)
        o = r.observation
        px = o.pixels if o is not None and o.found else np.zeros((0, 2))
        seg.append((*segment_quality(px, lab, depth), False))
    e = np.array(errs)
    s = _summary(e)
    s.update(errs=e, seg=np.array(seg).reshape(-1, 3))
    return s


def _suite_calibration(true, intr, seed: int, base, surface=None):
    """The calibration of the validation subject ``true`` from its rendered calibration
    frames (:func:`~hand_capture.tracking.calibration.render_calibration_frames`, drawn from
    ``seed + 500``; ``surface`` a :class:`SurfaceVariant` or :class:`CapsuleSurface` drawn
    instead of the template mesh), starting from ``base``."""
    from hand_capture.tracking.calibration import render_calibration_frames

    mesh_fn = surface.mesh_fn(true) if surface is not None else None
    return bench_calibrate(render_calibration_frames(true, intr, np.random.default_rng(
        seed + 500), mesh_fn=mesh_fn), model=base)


def _track_both_paths(reg, base, cal, cfg, frames, kps, labels) -> tuple[object, dict]:
    """A tracker with ``cfg``, calibrated by ``cal``, scored on the sequence tracked through
    (:func:`_score`) and from a reset tracker on every frame (:func:`_score_first`).
    Returns the tracker and the scores by path (``sequence``, ``first frame``)."""
    from hand_capture.tracking.hybrid import HybridTracker

    tracker = HybridTracker(base, cfg, reg)
    tracker.set_calibration(cal)
    return tracker, {path: fn(tracker, frames, kps, labels)
                     for path, fn in (("sequence", _score), ("first frame", _score_first))}


def forearm_validation_section(reg, config, quick: bool, product_only: bool = False,
                               smoke: bool = False, capsules: bool = False, far: bool = False,
                               near: bool = False, stereo: bool = False) -> dict:
    """The tracker with a forearm in view on the suite's own generator (validation shapes
    :data:`ARM_VAL_SEEDS`; :func:`suite_forearm_sequence`), calibrated per shape: where
    forearm handling is tuned, beside the held-out figure it is reported on. Two paths:
    ``sequence`` (tracked through; the forearm mostly cut at the previous wrist) and
    ``first frame`` (every frame from a reset tracker: the hard case, no previous wrist),
    each with the product's forearm handling and, as the baseline in the same run, the
    geometric cut alone (``arm_classifier`` off). ``cloud cut``: the share of frames cut
    without a previous wrist. Also the arm classifier's pixel accuracy on these frames.
    ``product_only``: the product alone, without the cut-alone baseline and the hard set
    (:func:`_hard_forearm_validation`; the regressor validation's use). ``capsules``: the
    hand drawn as the suite's collision capsules (:class:`CapsuleSurface`, calibrated on
    them; keys ``val_capsule_forearm*``, without the hard set); ``far``: a D435-like camera
    (640x480, 87 deg) 0.2 m farther than the suite's (keys ``val_far_forearm*``, without the
    hard set); ``near``: a finer camera 0.15 m nearer (:data:`NEAR_CAMERA`; keys
    ``val_near_forearm*``, without the hard set); ``stereo``: the frames with a stereo
    camera's artifacts (:func:`with_artifacts`; calibrated on the clean frames; keys
    ``val_stereo_forearm*``, without the hard set)."""
    from hand_capture.bench.tracking import _summary
    from hand_capture.model import HandModel

    seeds, clips, n, step = _validation_plan(quick, smoke)
    surface = CapsuleSurface() if capsules else None
    if capsules + far + near + stereo > 1:
        raise ConfigError("forearm_validation_section: at most one of capsules, far, near, "
                          "stereo")
    camera = FAR_CAMERA if far else NEAR_CAMERA if near else None
    fam = ("val_capsule_forearm" if capsules else "val_far_forearm" if far
           else "val_near_forearm" if near else "val_stereo_forearm" if stereo
           else "val_forearm")
    base = HandModel()
    variants = {"product": config}
    if not product_only:
        variants["cut only"] = dataclasses.replace(config, arm_classifier=False)
    res: dict[tuple[str, str], list] = {}
    acc = [0, 0]
    arm = None
    for seed in seeds:
        for clip in clips:
            true, intr, frames, kps, labels = suite_forearm_sequence(
                seed, clip, n, step, surface=surface, camera=camera)
            if stereo:
                frames = with_artifacts(frames, 9000 + 100 * seed + len(clip))
            cal = _suite_calibration(true, intr, seed, base, surface)
            for name, cfg in variants.items():
                tracker, scores = _track_both_paths(reg, base, cal, cfg, frames, kps, labels)
                if name == "product":
                    arm = tracker.arm
                    acc = [a + b for a, b in zip(acc, arm_pixel_counts(
                        arm, frames, labels, cfg), strict=True)]
                for path, s in scores.items():
                    res.setdefault((name, path), []).append((s["errs"], s["seg"]))
    rows, out = [], {}
    for (name, path), parts in res.items():
        e = np.concatenate([p[0] for p in parts])
        sq = np.concatenate([p[1] for p in parts])
        sm = _summary(e)
        rows.append([name, path, len(e), sm["mean"], sm["median"], sm["s20"],
                     float(np.mean(sq[:, 0])), float(np.mean(sq[:, 1])),
                     float(np.mean(sq[:, 2] == 0))])
        tag = {"sequence": "", "first frame": "_first"}[path]
        pre = fam if name == "product" else f"{fam}_cut_only"
        out.update({f"{pre}{tag}_mean_mm": sm["mean"], f"{pre}{tag}_success_20mm": sm["s20"],
                    f"{pre}{tag}_seg_arm_pct": rows[-1][6],
                    f"{pre}{tag}_seg_hand_kept_pct": rows[-1][7]})
        if name == "product" and path == "sequence":
            out[f"{fam}_cloud_cut_share"] = rows[-1][8]
    print_table(f"forearm in view, the suite's own generator (validation shapes {seeds}, the "
                "training renders' forearm"
                + (", the hand drawn as its collision capsules" if capsules else "")
                + (", a 640x480 87 deg camera 0.2 m farther" if far else "")
                + (", a 640x480 70 deg camera 0.15 m nearer" if near else "")
                + (", a stereo camera's artifacts" if stereo else "")
                + "): forearm handling is tuned here and reported on the held-out family; "
                "first frame = every frame from a reset tracker",
                ["forearm handling", "path", "frames", "mean mm", "median mm", "succ@20",
                 "seg arm %", "hand kept %", "cloud cut"], rows)
    if not product_only and not capsules and not far and not near and not stereo:
        out.update(_hard_forearm_validation(reg, config, seeds, quick))
    if arm is not None:
        key = "val_arm_pixel_acc" if fam == "val_forearm" else f"{fam}_arm_pixel_acc"
        out[key] = acc[0] / max(acc[1], 1)
        print(f"arm classifier pixel accuracy on these frames: {out[key]:.3f} "
              f"({acc[1]} labelled pixels)")
    return out


def _clutter_shares(reg, variants: dict, quick: bool, smoke: bool, **scene) -> dict:
    """The forearm validation sequences with ``scene`` (:func:`suite_forearm_sequence`
    keywords: a table, a distractor), each calibrated per shape and tracked through by every
    variant (``name -> (key, config)``; the first is the product, scored per sequence by
    :func:`_score` for the validation script): ``name -> [(errors (n, 21) [mm], share of
    each frame's segment on the clutter (label 4), share of the hand's pixels kept)]``."""
    from hand_capture.bench.tracking import _run_mode
    from hand_capture.model import HandModel
    from hand_capture.tracking.hybrid import HybridTracker

    seeds, clips, n, step = _validation_plan(quick, smoke)
    base = HandModel()
    res: dict[str, list] = {name: [] for name in variants}
    for seed in seeds:
        for clip in clips:
            true, intr, frames, kps, labels = suite_forearm_sequence(seed, clip, n, step,
                                                                     **scene)
            cal = _suite_calibration(true, intr, seed, base)
            for k, (name, (_, cfg)) in enumerate(variants.items()):
                tracker = HybridTracker(base, cfg, reg)
                tracker.set_calibration(cal)
                seg: list[tuple[float, float]] = []

                def on_result(i: int, r, seg=seg, labels=labels, frames=frames) -> None:
                    o = r.observation
                    px = o.pixels if o is not None and o.found else np.zeros((0, 2))
                    lab = labels[i][px[:, 1].astype(np.int64), px[:, 0].astype(np.int64)]
                    seg.append((float(np.mean(lab == 4)) if len(lab) else 0.0,
                                segment_quality(px, labels[i], frames[i][0])[1]))

                e = (_score(tracker, frames, kps, on_result=on_result)["errs"] if k == 0
                     else _run_mode(tracker, frames, kps, on_result=on_result)[0])
                clutter, kept = np.array(seg).reshape(-1, 2).T
                res[name].append((e, clutter, kept))
    return res


def table_validation_section(reg, config, quick: bool, smoke: bool = False) -> dict:
    """A table (or wall) behind the hand on the suite's generator (the forearm validation
    sequences with :func:`suite_forearm_sequence` ``table``): the product against
    ``plane_removal`` off in the same run, each calibrated per shape and tracked through;
    also the segment against the true labels (share of the segment on the table, share of
    the hand kept)."""
    from hand_capture.bench.tracking import _summary

    seeds = _validation_plan(quick, smoke)[0]
    variants = {"product": ("val_table", config),
                "no plane removal": ("val_table_no_plane",
                                     dataclasses.replace(config, plane_removal=False))}
    res = _clutter_shares(reg, variants, quick, smoke, table=True)
    rows, out = [], {}
    for name, parts in res.items():
        sm = _summary(np.concatenate([p[0] for p in parts]))
        table_pct = 100.0 * float(np.mean(np.concatenate([p[1] for p in parts])))
        kept_pct = float(np.mean(np.concatenate([p[2] for p in parts])))
        rows.append([name, sm["mean"], sm["median"], sm["s20"], table_pct, kept_pct])
        key = variants[name][0]
        out.update({f"{key}_mean_mm": sm["mean"], f"{key}_success_20mm": sm["s20"],
                    f"{key}_seg_table_pct": table_pct})
    print_table(f"a table behind the hand (the forearm validation sequences, shapes {seeds}, "
                "with a plane 50-120 mm behind the hand that the forearm runs into): "
                "plane_removal against off, tracked through",
                ["segmentation", "mean mm", "median mm", "succ@20", "seg table %",
                 "hand kept %"], rows)
    return out


def distractor_validation_section(reg, config, quick: bool, smoke: bool = False) -> dict:
    """Something nearer the camera than the hand, beside it (the forearm validation
    sequences with :func:`suite_forearm_sequence` ``distractor``: a box that enters the view
    a third into each sequence): the product against ``track_roi_m`` 0 (the segment from
    the nearest pixel in view) in the same run, each calibrated per shape and tracked
    through; also the share of frames whose segment lies mostly on the box."""
    from hand_capture.bench.tracking import _summary

    seeds = _validation_plan(quick, smoke)[0]
    variants = {"product": ("val_distractor", config),
                "nearest in view": ("val_distractor_no_roi",
                                    dataclasses.replace(config, track_roi_m=0.0))}
    res = _clutter_shares(reg, variants, quick, smoke, distractor=True)
    rows, out = [], {}
    for name, parts in res.items():
        sm = _summary(np.concatenate([p[0] for p in parts]))
        box_pct = 100.0 * float(np.mean(np.concatenate([p[1] for p in parts]) > 0.5))
        rows.append([name, sm["mean"], sm["median"], sm["s20"], box_pct])
        key = variants[name][0]
        out.update({f"{key}_mean_mm": sm["mean"], f"{key}_success_20mm": sm["s20"],
                    f"{key}_seg_on_box_pct": box_pct})
    print_table(f"a box nearer the camera than the hand, beside it (the forearm validation "
                f"sequences, shapes {seeds}, the box in view from a third into each): "
                "segment near the tracked hand (track_roi_m) against the nearest pixel in "
                "view, tracked through",
                ["segmentation", "mean mm", "median mm", "succ@20", "seg on box %"], rows)
    return out


def _hard_forearm_validation(reg, config, seeds: tuple[int, ...], quick: bool) -> dict:
    """The arm classifier's failure case on the suite's generator (issue 13): a close-range
    wide camera, a sleeve over the forearm and a box sliding in until it touches the hand
    (:func:`suite_forearm_sequence` ``close``, ``clutter``, ``sleeve``). The classifier was
    trained on hand and arm only: it keeps the box with the hand, and once the arm is gone
    the box dominates the cloud. Product (with ``arm_fallback``: a failed frame the
    classifier cut is retried on the cut alone, the lower E_d kept), without the fallback,
    and the cut alone, each tracked through and from a reset tracker on every frame."""
    from hand_capture.bench.tracking import _summary
    from hand_capture.model import HandModel

    clips = ("pinch",) if quick else ("pinch", "fist")
    n, step = (6, 6) if quick else (12, 3)
    variants = {"product": ("val_hard", config),
                "no fallback": ("val_hard_no_fallback",
                                dataclasses.replace(config, arm_fallback=False)),
                "cut only": ("val_hard_cut_only",
                             dataclasses.replace(config, arm_classifier=False))}
    base = HandModel()
    res: dict[tuple[str, str], list] = {}
    for seed in seeds:
        for clip in clips:
            true, intr, frames, kps, labels = suite_forearm_sequence(
                seed, clip, n, step, close=True, clutter=True, sleeve=True)
            cal = _suite_calibration(true, intr, seed, base)
            for name, (_, cfg) in variants.items():
                _, scores = _track_both_paths(reg, base, cal, cfg, frames, kps, labels)
                for path, s in scores.items():
                    res.setdefault((name, path), []).append(s["errs"])
    rows, out = [], {}
    for (name, path), parts in res.items():
        sm = _summary(np.concatenate(parts))
        rows.append([name, path, sum(map(len, parts)), sm["mean"], sm["median"], sm["s20"]])
        key = variants[name][0] + ("_first" if path == "first frame" else "")
        out.update({f"{key}_mean_mm": sm["mean"], f"{key}_success_20mm": sm["s20"]})
    print_table(f"forearm + sleeve + clutter touching the hand, close-range camera (the "
                f"suite's generator, validation shapes {seeds}): the classifier's fallback to "
                "the cut alone on a failed frame", ["forearm handling", "path", "frames",
                                                    "mean mm", "median mm", "succ@20"], rows)
    return out


def calibration_section(quick: bool, scales: tuple[float, ...] | None = None) -> dict:
    """Bone-length error of calibration on both families, scales 0.85..1.15; the held-out
    subjects also with a forearm (bare or sleeved) in view, their surface drawn from a
    generator of its own so that the rows without it keep their draws."""
    from hand_capture.evaldata import calibration_frames, sample_subject, sample_surface
    from hand_capture.model import N_ALPHA, HandModel, HandShape
    from hand_capture.tracking.calibration import (
        CALIBRATION_POSES,
        render_calibration_frames,
    )
    from hand_capture.tracking.train import default_intrinsics

    scales = scales or ((0.85, 1.15) if quick else SCALES)
    base = HandModel()
    fams = ("suite", "heldout", "heldout forearm")
    rows, fit, tmpl = [], {f: [] for f in fams}, {f: [] for f in fams}
    for k, s in enumerate(scales):
        rng = np.random.default_rng(300 + k)
        # the suite's family: its mesh, rasteriser and noise model, 320x240
        alpha = np.clip(rng.normal(0.0, 0.7, N_ALPHA), -1.5, 1.5)
        true_s = HandModel(HandShape(s, tuple(alpha)))
        frames_s = render_calibration_frames(true_s, default_intrinsics(), rng)
        # the held-out family: capsule hand, ray casting, stereo-like noise, D435 640x480
        true_h = sample_subject(rng, scale=s)
        frames_h = calibration_frames(true_h, sample_surface(rng, forearm=False),
                                      list(CALIBRATION_POSES.values()), "d435_640", rng)
        rng_f = np.random.default_rng(400 + k)
        frames_f = calibration_frames(true_h, sample_surface(rng_f, forearm=True),
                                      list(CALIBRATION_POSES.values()), "d435_640", rng_f)
        for fam, true, frames in (("suite", true_s, frames_s), ("heldout", true_h, frames_h),
                                  ("heldout forearm", true_h, frames_f)):
            t0 = time.perf_counter()
            cal = bench_calibrate(frames, model=base)
            m = base.with_shape(cal.shape)
            fit[fam].append(_bone_err_pct(m, true))
            tmpl[fam].append(_bone_err_pct(base, true))
            rows.append([fam, s, f"{cal.shape.global_scale:.3f}", tmpl[fam][-1],
                         fit[fam][-1], cal.residual_mm, time.perf_counter() - t0])
    print_table("calibration: mean relative bone-length error [%] of the 16 bones (template = "
                "no calibration)", ["family", "true s_g", "fit s_g", "template %",
                                    "calibrated %", "resid mm", "time s"], rows)
    allfit = fit["suite"] + fit["heldout"]
    return {"calib_bone_err_pct": float(np.max(allfit)),
            "calib_bone_err_pct_mean": float(np.mean(allfit)),
            "calib_bone_err_pct_suite": float(np.mean(fit["suite"])),
            "calib_bone_err_pct_heldout": float(np.mean(fit["heldout"])),
            "calib_bone_err_pct_template": float(np.mean(tmpl["suite"] + tmpl["heldout"])),
            "calib_bone_err_pct_heldout_forearm": float(np.mean(fit["heldout forearm"])),
            "calib_bone_err_pct_heldout_forearm_worst": float(np.max(fit["heldout forearm"])),
            "calib_scales": list(scales)}


def _suite_frames(seed: int, clip: str, n: int, step: int, t0: float):
    from hand_capture.cameras.synthetic import SyntheticCamera, SyntheticCameraConfig

    cam = SyntheticCamera(SyntheticCameraConfig(render_color=False, shape_seed=seed, clip=clip,
                                                noise_seed=seed + 1000))
    cam.open()
    last = int(math.floor(cam.motion.duration * 30))
    idx = list(range(0, last + 1, step))[:n]
    rendered = [cam.render(t0 + i / 30.0) for i in idx]
    return (cam.model, cam.intrinsics, [(f.depth, f.depth_intrinsics) for f in rendered],
            [cam.model.joint_positions(f.pose) for f in rendered])


def split_section(reg, config, quick: bool, smoke: bool = False) -> dict:
    """Choose ``cost_temporal_weight`` on validation shapes, report it on test shapes
    (``smoke``: two weights, one motion)."""
    from hand_capture.bench.tracking import MOTIONS, SHAPE_SEEDS
    from hand_capture.model import HandModel
    from hand_capture.tracking.calibration import render_calibration_frames
    from hand_capture.tracking.hybrid import HybridTracker

    grid = (0.0, 30.0) if smoke else (0.0, 30.0, 300.0) if quick else TEMPORAL_GRID
    motions = ("finger_counting",) if smoke else \
        ("finger_counting", "wrist_rotation") if quick else MOTIONS
    n, step = (10, 3) if quick else (45, 2)
    splits = {"validation": VAL_SEEDS[:1] if quick else VAL_SEEDS,
              "test": SHAPE_SEEDS[:1] if quick else SHAPE_SEEDS}
    base = HandModel()
    data: dict[str, list] = {"validation": [], "test": []}
    for split, seeds in splits.items():
        for seed in seeds:
            rng = np.random.default_rng(seed + 500)
            for clip in motions:
                true, intr, frames, truth = _suite_frames(seed, clip, n, step, 0.0)
                cal = bench_calibrate(render_calibration_frames(true, intr, rng), model=base)
                data[split].append((base.with_shape(cal.shape), frames, truth))
    res: dict[str, dict[float, float]] = {"validation": {}, "test": {}}
    s20: dict[float, float] = {}
    for w in grid:
        cfg = dataclasses.replace(config, cost_temporal_weight=w)
        for split in ("validation", "test"):
            errs = [_score(HybridTracker(m, cfg, reg), fr, tr)["errs"]
                    for m, fr, tr in data[split]]
            e = np.concatenate(errs)
            res[split][w] = float(e.mean())
            if split == "test":
                s20[w] = float(np.mean(e.max(axis=1) < 20.0))
    chosen = min(grid, key=lambda w: (round(res["validation"][w], 2), w))
    rows = [[w, res["validation"][w], res["test"][w], s20[w],
             "chosen" if w == chosen else ("config" if w == config.cost_temporal_weight
                                           else "")] for w in grid]
    print_table(f"cost_temporal_weight (eq. II.20 lambda_2): chosen on validation shapes "
                f"{splits['validation']}, reported on test shapes {splits['test']} "
                f"(config/tracker.yaml: {config.cost_temporal_weight})",
                ["weight", "val mean mm", "test mean mm", "test succ@20", ""], rows)
    return {"temporal_weight_chosen": chosen,
            "temporal_weight_config": config.cost_temporal_weight,
            "temporal_weight_val_mean_mm": res["validation"][chosen],
            "temporal_weight_test_mean_mm": res["test"][chosen],
            "temporal_weight_test_success_20mm": s20[chosen],
            "temporal_weight_config_test_mean_mm": res["test"].get(
                config.cost_temporal_weight, float("nan"))}


def resolution_section(reg, config, quick: bool) -> dict:
    """The same held-out sequences seen by a D435 at 424x240, 640x480 and 848x480: tracker
    CPU time per frame and accuracy (what ``config/camera.yaml`` defaults to)."""
    from hand_capture.evaldata import calibration_frames, make_sequence
    from hand_capture.model import HandModel
    from hand_capture.tracking.calibration import CALIBRATION_POSES
    from hand_capture.tracking.hybrid import HybridTracker

    seeds = (401,) if quick else (401, 402, 403)
    n, step = (10, 3) if quick else (60, 1)
    base = HandModel()
    rows, out = [], {}
    for cam in ("d435_424", "d435_640", "d435_848"):
        errs, cpu = [], []
        for seed in seeds:
            seq = make_sequence(seed, n, cam, step=step)
            cal = bench_calibrate(calibration_frames(seq.model, seq.surface,
                                                     list(CALIBRATION_POSES.values()), cam,
                                                     np.random.default_rng(seed)), model=base)
            s = _score(HybridTracker(base.with_shape(cal.shape), config, reg), seq.frames,
                       seq.keypoints)
            errs.append(s["errs"])
            cpu.append(s["cpu"])
        e, c = np.concatenate(errs), np.concatenate(cpu)
        r = {"mean_mm": float(e.mean()), "success_20mm": float(np.mean(e.max(axis=1) < 20)),
             "cpu_ms": 1e3 * float(c.mean()), "cpu_ms_p99": 1e3 * float(np.percentile(c, 99))}
        out[cam] = r
        rows.append([cam, len(e), r["mean_mm"], r["success_20mm"], r["cpu_ms"],
                     r["cpu_ms_p99"]])
    print_table("camera resolution (held-out, no forearm, same subjects and motions): the "
                "tracker's CPU time per frame (30 Hz leaves 33 ms)",
                ["camera", "frames", "mean mm", "succ@20", "cpu ms", "cpu ms p99"], rows)
    return {"resolution": out}


def transport_section(quick: bool) -> dict:
    """640x480 frames at 30 Hz to the tracker's QoS: graphs' profile vs Fast DDS defaults."""
    from hand_capture.bench._delivery import measure_delivery

    n = 30 if quick else 150
    rows, out = [], {}
    for name, prof in (("graphs' profile", True), ("Fast DDS defaults", False)):
        r = measure_delivery(n, 30.0, 640, 480, profile=prof, timeout_s=60.0)
        rows.append([name, r["sent"], r["received"], r["delivery"], r["lost"]])
        key = "large_frame_delivery" if prof else "large_frame_delivery_default"
        out[key] = r["delivery"]
        out[key.replace("delivery", "lost")] = r["lost"]
    print_table("transport: 640x480 16UC1 at 30 Hz, camera QoS -> tracker QoS, two processes "
                "(lost: never reached the reader, warm-up included; the rest of the frames not "
                "taken were overwritten in the depth-1 queue)",
                ["DDS", "sent", "received", "delivery", "lost"], rows)
    return out


def run_sections(reg, config, quick: bool, smoke: bool = False) -> dict:
    """Every section above, in order; their figures merged. ``smoke``: the same code on the
    fewest sequences and frames (``hand-suite bench tracking --smoke``; its figures mean
    nothing)."""
    out = {}
    out.update(heldout_section(reg, config, quick, cases=HELDOUT_QUICK[:1] if smoke else None,
                               frames=(6, 6) if smoke else None))
    out.update(surface_validation_section(reg, config, quick, smoke=smoke))
    out.update(capsule_validation_section(reg, config, quick, smoke=smoke))
    out.update(stereo_validation_section(reg, config, quick, smoke=smoke))
    out.update(forearm_validation_section(reg, config, quick, smoke=smoke))
    for kind in ("capsules", "far", "near"):   # the product only: other surface, cameras
        out.update(forearm_validation_section(reg, config, quick, product_only=True,
                                              smoke=smoke, **{kind: True}))
    out.update(table_validation_section(reg, config, quick, smoke=smoke))
    out.update(distractor_validation_section(reg, config, quick, smoke=smoke))
    out.update(calibration_section(quick, scales=(1.15,) if smoke else None))
    out.update(split_section(reg, config, quick, smoke))
    out.update(resolution_section(reg, config, quick))
    out.update(transport_section(quick))
    return out
