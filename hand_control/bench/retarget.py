"""``hand-suite bench retarget``: human hand -> robot hand retargeting against today's joint map.

For each robot hand model (the LEAP Hand of ``config/retarget/leap_hand.yaml``; the Allegro
Hand, ``allegro_hand``, the "other" robot; and the suite's own exported hand, ``suite_hand``,
as the self-retargeting check) and each motion, every frame's 21 human keypoints are
retargeted by the optimiser (:class:`hand_control.retarget.HandRetargeter`, the config's mode)
and, as the baseline, through today's weighted joint map (``config/servo_maps/leap_hand.yaml``:
human joint angles -> servo angles = the LEAP joints, clipped to their limits; the same map
applied by joint order to the Allegro's joint_0.0 .. joint_15.0, whose fingers have the same
base / three-flexion layout; the identity for the suite's hand). Figures, per method, in the
same run:

* ``tip_err_mm``: mean distance of the robot's fingertips from the scaled human fingertips
  placed in the robot (the retargeting target: human tips in the human hand frame x the
  config's scale, through the config's wrist frame), over every frame and mapped fingertip;
* ``pinch_err_mm``: in pinches (human thumb-index tip distance below ``pinch_close_m``,
  30 mm), the mean |robot thumb-index distance - human distance|;
* ``jitter_mrad``: joint-space jitter, mean |q[t+1] - 2 q[t] + q[t-1]| over joints and frames
  at 30 Hz [mrad], on the smooth in-distribution clips (what the method adds), and
  ``jitter_mrad_heldout`` with the keypoint noise, and the same after the servo bridge's
  default low-pass (``*_heldout_lowpass``: what the servos follow). On noisy keypoints the
  joint map gets its human joint angles from the same keypoints, by retargeting them onto
  the suite's own hand (an inverse kinematics of the suite's model), so both methods see the
  same tracker noise; on clean sequences it gets the exact angles;
* ``retarget_ms_p50``: median wall time of one frame (keypoints in, joints out) [ms], and the
  joint map's (``joint_map_ms_p50``) for the ratio.

Motions: the suite's built-in clips (finger counting, fist, pinch, grasp) performed by the
template hand -- the hand the LEAP config's scale and wrist were fitted on -- and, held out,
the embedded teleoperation performance (``data/teleop/lift_box.npz``) and the same clips
performed by other operators' hand shapes (``sample_shape`` seeds) with 3 mm Gaussian noise on
every keypoint (a tracker's), neither of which the configs were built from. Top-level keys are
the LEAP Hand's on everything; ``*_indist`` / ``*_heldout`` split them; ``other_*`` are the
Allegro Hand's; ``self_tip_err_mm`` is the suite's hand retargeted onto itself (in-distribution
clips: the input comes back).

The colour tracker's figures (``rgb_tracker_fps``, ``rgb_keypoint_err_px``) come from
:func:`hand_capture.rgbtrack.evaluate.rgb_tracker_figures`, the ``rgb`` bench's function.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hand_capture.bench import print_table
from hand_capture.cameras.motion import builtin_clip, load_motion
from hand_capture.model import HandModel, sample_shape
from hand_capture.model.joints import ARTICULATED_JOINTS, JOINT_INDEX
from hand_capture.model.keypoints21 import keypoints21
from hand_control.dynamixel.bridge import BridgeConfig
from hand_control.dynamixel.retarget import LowPassFilter, Retargeter
from hand_control.dynamixel.servo_map import load_servo_map
from hand_control.retarget import HandRetargeter

CLIPS = ("finger_counting", "fist", "pinch", "grasp")
TELEOP = "data/teleop/lift_box.npz"
RATE_HZ = 30.0
NOISE_M = 0.003
BRIDGE_CUTOFF_HZ = BridgeConfig().filter_cutoff_hz  # the servo bridge's default low-pass
_ART = np.array([JOINT_INDEX[j] for j in ARTICULATED_JOINTS])


@dataclass
class Motion:
    """One evaluation sequence: poses (T, 27), the operator's hand model, keypoint noise."""

    name: str
    split: str  # "indist" or "heldout"
    poses: np.ndarray
    model: HandModel | None = None
    noise_m: float = 0.0
    seed: int = 0


@dataclass
class Tally:
    """Per-frame errors of one method on one robot."""

    tip: list[float] = field(default_factory=list)
    pinch: list[float] = field(default_factory=list)
    jitter: list[float] = field(default_factory=list)
    ms: list[float] = field(default_factory=list)

    def add_sequence(self, q: np.ndarray) -> None:
        if len(q) >= 3:
            self.jitter.extend(np.abs(q[2:] - 2 * q[1:-1] + q[:-2]).mean(axis=1).tolist())

    def figures(self) -> dict[str, float]:
        def mean(v: list[float]) -> float:
            return float(np.mean(v)) if v else float("nan")

        return {"tip_err_mm": 1e3 * mean(self.tip), "pinch_err_mm": 1e3 * mean(self.pinch),
                "jitter_mrad": 1e3 * mean(self.jitter),
                "ms_p50": float(np.median(self.ms)) if self.ms else float("nan"),
                "pinch_frames": len(self.pinch)}


def _sample(poses_clip: Any, n_max: int, start: float = 0.0) -> np.ndarray:
    ts = np.arange(start, poses_clip.duration, 1.0 / RATE_HZ)[:n_max]
    return poses_clip.sample_many(ts)


def motions(quick: bool, smoke: bool) -> list[Motion]:
    """The in-distribution and held-out sequences (module docstring)."""
    n = 12 if smoke else 90 if quick else 10_000
    clips = CLIPS[2:3] if smoke else CLIPS
    # smoke: the pinch clip from the closing (1.2 s), so that it has pinch frames
    out = [Motion(c, "indist", _sample(builtin_clip(c), n, 1.2 if smoke else 0.0))
           for c in clips]
    teleop = load_motion("static", TELEOP, loop=False)
    out.append(Motion("teleop", "heldout", _sample(teleop, n)))
    seeds = (11,) if smoke else (11, 12) if quick else (11, 12, 13)
    for k, seed in enumerate(seeds):
        c = clips[k % len(clips)] if smoke else CLIPS[(k + 2) % len(CLIPS)]
        out.append(Motion(f"{c}/shape{seed}+noise", "heldout", _sample(builtin_clip(c), n),
                          HandModel(sample_shape(seed)), NOISE_M, seed))
    return out


def joint_map_for(rt: HandRetargeter) -> tuple[Any, np.ndarray | None]:
    """Today's joint map onto the robot's joints: (Retargeter, column order) for the LEAP
    Hand, (None, indices into the articulated joints) for the suite's hand (identity)."""
    if rt.config.name == "leap_hand":
        jm = Retargeter(load_servo_map("leap_hand"))
        return jm, np.array([jm.servo_map.names.index(n) for n in rt.joint_names])
    if rt.config.name == "allegro_hand":  # servo i of the LEAP map -> joint_i.0
        jm = Retargeter(load_servo_map("leap_hand"))
        return jm, np.array([int(float(n.split("_")[1])) for n in rt.joint_names])
    return None, np.array([ARTICULATED_JOINTS.index(n) for n in rt.joint_names])


def evaluate(rt: HandRetargeter, seqs: list[Motion], ik: HandRetargeter | None = None
             ) -> dict[str, dict[str, Tally]]:
    """Tallies by split ('indist', 'heldout') and method ('opt', 'map', 'filt': the
    optimiser after the bridge's low-pass). ``ik``: the suite's hand retargeted onto itself,
    which gives the joint map its human joint angles from noisy keypoints (so both methods
    see the same tracker noise); without it the joint map gets the exact angles."""
    jm, cols = joint_map_for(rt)
    names = [p.keypoint for p in rt.config.points]
    tips = rt.tip_rows
    th, ix = names.index("thumb_tip"), names.index("index_tip")
    close = rt.settings.pinch_close_m
    out = {s: {"opt": Tally(), "map": Tally(), "filt": Tally()} for s in ("indist", "heldout")}
    for m in seqs:
        rng = np.random.default_rng(m.seed)
        kp_all = keypoints21(m.model, m.poses)
        rt.reset()
        if ik is not None:
            ik.reset()
        q_opt, q_map, targets = [], [], []
        tal = out[m.split]
        for k in range(len(m.poses)):
            clean = kp_all[k]
            seen = clean + rng.normal(0.0, m.noise_m, clean.shape) if m.noise_m else clean
            t0 = time.perf_counter()
            res = rt.solve(seen)
            tal["opt"].ms.append(1e3 * (time.perf_counter() - t0))
            q_human = m.poses[k][_ART]
            if m.noise_m and ik is not None:  # the angles a tracker would give: noisy too
                q_human = ik.solve(seen).q  # the suite hand's joints = ARTICULATED_JOINTS
            t0 = time.perf_counter()
            if jm is not None:
                qm = jm.servo_angles(q_human)[cols]
            else:
                qm = q_human[cols]
            qm = np.clip(qm, rt.lower, rt.upper)
            tal["map"].ms.append(1e3 * (time.perf_counter() - t0))
            human = rt.human_points(clean)
            target = rt.targets(human)
            d_h = float(np.linalg.norm(human[ix] - human[th]))
            for key, q in (("opt", res.q), ("map", qm)):
                p = rt.robot_points(q)
                tal[key].tip.extend(np.linalg.norm(p[tips] - target[tips], axis=1).tolist())
                if d_h < close:
                    tal[key].pinch.append(abs(float(np.linalg.norm(p[ix] - p[th])) - d_h))
            q_opt.append(res.q)
            q_map.append(qm)
            targets.append(target[tips])
        tal["opt"].add_sequence(np.asarray(q_opt))
        tal["map"].add_sequence(np.asarray(q_map))
        # what the servos follow: the bridge's low-pass (filter_cutoff_hz) on the joints
        lp = LowPassFilter(BRIDGE_CUTOFF_HZ)
        q_f = np.array([lp(q, 1.0 / RATE_HZ).copy() for q in q_opt])
        tal["filt"].add_sequence(q_f)
        for q, tgt in zip(q_f, targets, strict=True):
            tal["filt"].tip.extend(np.linalg.norm(rt.robot_points(q)[tips] - tgt,
                                                  axis=1).tolist())
    return out


def _merge(a: Tally, b: Tally) -> Tally:
    return Tally(a.tip + b.tip, a.pinch + b.pinch, a.jitter + b.jitter, a.ms + b.ms)


def run(quick: bool = False, smoke: bool = False) -> dict[str, Any]:
    """Print the tables; return the figures for the last JSON line."""
    seqs = motions(quick, smoke)
    ik = HandRetargeter("suite_hand")
    assert ik.joint_names == ARTICULATED_JOINTS
    figs: dict[str, Any] = {}
    rows = []
    for robot, prefix in (("leap_hand", ""), ("allegro_hand", "other_"),
                          ("suite_hand", "self_")):
        rt = HandRetargeter(robot)
        if prefix == "self_":  # the check: the template hand onto itself
            res = evaluate(rt, [m for m in seqs if m.split == "indist"], ik)
            fo = res["indist"]["opt"].figures()
            rows.append([robot, "indist", "optimiser (self)", fo["tip_err_mm"],
                         fo["pinch_err_mm"], fo["pinch_frames"], fo["jitter_mrad"],
                         fo["ms_p50"]])
            figs["self_tip_err_mm"] = round(fo["tip_err_mm"], 4)
            figs["self_tip_err_mm_max"] = round(1e3 * max(res["indist"]["opt"].tip), 4)
            continue
        res = evaluate(rt, seqs, ik)
        for split in ("all", "indist", "heldout"):
            if split == "all":
                opt = _merge(res["indist"]["opt"], res["heldout"]["opt"])
                mp = _merge(res["indist"]["map"], res["heldout"]["map"])
            else:
                opt, mp = res[split]["opt"], res[split]["map"]
            fo, fm = opt.figures(), mp.figures()
            rows.append([robot, split, "optimiser (" + rt.settings.mode + ")",
                         fo["tip_err_mm"], fo["pinch_err_mm"], fo["pinch_frames"],
                         fo["jitter_mrad"], fo["ms_p50"]])
            rows.append([robot, split, "joint map", fm["tip_err_mm"], fm["pinch_err_mm"],
                         fm["pinch_frames"], fm["jitter_mrad"], fm["ms_p50"]])
            if split == "heldout":
                ff = res[split]["filt"].figures()
                rows.append([robot, split, f"optimiser + {BRIDGE_CUTOFF_HZ:g} Hz low-pass",
                             ff["tip_err_mm"], "", "", ff["jitter_mrad"], ""])
                figs[f"{prefix}jitter_mrad_heldout_lowpass"] = round(ff["jitter_mrad"], 3)
                figs[f"{prefix}tip_err_mm_heldout_lowpass"] = round(ff["tip_err_mm"], 2)
            sfx = "" if split == "all" else f"_{split}"
            figs[f"{prefix}tip_err_mm{sfx}"] = round(fo["tip_err_mm"], 2)
            figs[f"{prefix}joint_map_tip_err_mm{sfx}"] = round(fm["tip_err_mm"], 2)
            figs[f"{prefix}pinch_err_mm{sfx}"] = round(fo["pinch_err_mm"], 2)
            figs[f"{prefix}joint_map_pinch_err_mm{sfx}"] = round(fm["pinch_err_mm"], 2)
            if split != "all":  # smooth input (indist) / noisy keypoints (heldout)
                jsfx = "" if split == "indist" else "_heldout"
                figs[f"{prefix}jitter_mrad{jsfx}"] = round(fo["jitter_mrad"], 3)
                figs[f"{prefix}joint_map_jitter_mrad{jsfx}"] = round(fm["jitter_mrad"], 3)
            else:
                figs[f"{prefix}retarget_ms_p50"] = round(fo["ms_p50"], 3)
                figs[f"{prefix}joint_map_ms_p50"] = round(fm["ms_p50"], 4)
                figs[f"{prefix}tip_err_vs_joint_map"] = round(
                    fo["tip_err_mm"] / max(fm["tip_err_mm"], 1e-9), 3)
    print_table("Retargeting: robot fingertips vs the scaled human fingertips "
                f"({len(seqs)} sequences at {RATE_HZ:g} Hz; held out: teleop performance, "
                f"other hand shapes + {NOISE_M * 1e3:g} mm keypoint noise)",
                ["robot", "data", "method", "tip_err_mm", "pinch_err_mm", "pinch_frames",
                 "jitter_mrad", "ms_p50"], rows)
    figs["frames"] = int(sum(len(m.poses) for m in seqs))
    figs.update(_rgb_figures(quick, smoke))
    return figs


def _rgb_figures(quick: bool, smoke: bool) -> dict[str, Any]:
    """The colour tracker's keys (the rgb bench's function, run here too)."""
    from hand_capture.rgbtrack.evaluate import rgb_tracker_figures

    f = rgb_tracker_figures(quick=quick, smoke=smoke)
    keep = ("rgb_tracker_fps", "rgb_keypoint_err_px", "rgb_heldout_keypoint_err_px",
            "rgb_fps_vs_detector", "rgb_detection_rate")
    print_table("Colour tracker (hand-suite bench rgb for the details)", ["figure", "value"],
                [[k, f.get(k)] for k in keep])
    return {k: f[k] for k in keep if k in f}
