"""``hand-suite bench physcap``: physics-based manipulation capture (seed 000 sec. 6-7).

Captures with ground truth come from simulation scenarios (the composite controller grasping
and lifting an object, recorded at 20 fps from the end of reaching to the end of lifting) and
are corrupted like a tracker (:mod:`hand_control.physcap.synth`): the ``tracker`` model
(per-frame noise + one or two grasping fingers 10-20 mm off, the wrong contacts) is what the
optimiser was tuned on; the ``drift`` model (correlated errors, growing finger errors with
abduction, outlier frames) on the pour scenario's motion is held out (not used while building).

Per capture, three optimisations with the same number of samples per step:
contact-based sampling with composite control, random sampling with composite control (seed
000 Fig. 8 left), and contact-based sampling with PD-only control (sec. 7.3: no virtual
forces). Success: the object ends within 30 mm of the capture's final position and never
falls 30 mm below it after lifting. Errors against the truth: the simulated object position
(``object_err_mm``) and the 21 hand keypoints (``hand_err_mm``), beside the noisy reference's
(``ref_*``). Retargeting (sec. 7.2): the first capture's optimised control applied to three
new objects and two lower frictions (``retarget_success``), and to a very low friction where
the object must slip (``low_friction_slipped``). ``dask_speedup_2w``: the batch runner with 2
worker processes against 1 (``hand_control.physcap.batch.measure_dask_speedup``).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from hand_capture.bench import print_table
from hand_capture.model.hand import HandModel
from hand_control.physcap.capture import CapturedObject, PhysCapConfig, optimise_capture
from hand_control.physcap.retarget import retarget
from hand_control.physcap.synth import corrupt, scenario_capture
from hand_control.sim.scenario import load_scenario

_METHODS = {"contact": {}, "random": {"sampling": "random"}, "pd_only": {"control": "pd_only"}}


def _captures(quick: bool, smoke: bool) -> list[tuple[str, Any]]:
    """(split, SyntheticCapture) pairs: ``in`` = the tracker model the optimiser was tuned
    on; ``heldout`` = the drift model (and the pour motion), never used while building."""
    if smoke:
        spec = load_scenario("lift_box").with_(t_lift=0.4, t_carry=0.1, t_hold=0.1)
        truth = scenario_capture(spec, t_start=0.5, t_end=1.5)
        return [("in", corrupt(truth, "tracker", seed=0))]
    if quick:  # shorter lifts (1.6 s captures)
        short = {"t_lift": 0.6, "t_carry": 0.1, "t_hold": 0.1}
        box = scenario_capture(load_scenario("lift_box").with_(**short), t_end=2.1)
        return [("in", corrupt(box, "tracker", seed=0)), ("heldout", corrupt(box, "drift", 7))]
    box = scenario_capture(load_scenario("lift_box"))
    pour = scenario_capture(load_scenario("pour_cylinder"))
    ball = scenario_capture(load_scenario("lift_ball"))
    cyl = scenario_capture(load_scenario("lift_cylinder"))
    return ([("in", corrupt(box, "tracker", seed=s)) for s in (0, 1, 2, 3)]
            + [("in", corrupt(ball, "tracker", seed=0)), ("in", corrupt(cyl, "tracker", 0))]
            + [("heldout", corrupt(pour, "drift", seed=s)) for s in (5, 6)]
            + [("heldout", corrupt(box, "drift", seed=7))])


def _errors(model: HandModel, truth: Any, hand_q: np.ndarray, object_pose: np.ndarray
            ) -> tuple[float, float]:
    """Mean object position error and mean 21-keypoint hand error against the truth [mm]."""
    obj = float(np.linalg.norm(object_pose[:, :3] - truth.object_pose[:, :3], axis=1).mean())
    kp = np.linalg.norm(model.joint_positions(hand_q) - model.joint_positions(truth.hand_q),
                        axis=-1).mean()
    return obj * 1e3, float(kp) * 1e3


def run(quick: bool = False, smoke: bool = False) -> dict[str, Any]:
    """The figures (see the module docstring)."""
    from hand_capture.cameras.threads import limit_blas_threads

    limit_blas_threads(1)
    n = 8 if smoke else 24 if quick else 32
    keep = max(2, n // 4)
    caps = _captures(quick, smoke)
    model = HandModel()
    rows, per = [], {m: [] for m in _METHODS}
    first = None
    for split, sc in caps:
        ref_obj, ref_hand = _errors(model, sc.truth, sc.capture.hand_q, sc.capture.object_pose)
        for method, kw in _METHODS.items():
            r = optimise_capture(sc.capture, PhysCapConfig(n_samples=n, n_keep=keep, **kw))
            obj_err, hand_err = _errors(model, sc.truth, r.hand_q, r.object_pose)
            per[method].append(dict(split=split, success=r.success, obj=obj_err, hand=hand_err,
                                    ref_obj=ref_obj, ref_hand=ref_hand, s=r.s_per_frame))
            rows.append([sc.capture.name, split, method, r.success, obj_err, hand_err, ref_obj,
                         ref_hand, r.s_per_frame])
            if method == "contact" and first is None:
                first = r
    print_table(f"physcap: optimised captures ({n} samples per 0.05 s step, keep {keep})",
                ["capture", "split", "method", "success", "object_err_mm", "hand_err_mm",
                 "ref_object_err_mm", "ref_hand_err_mm", "s_per_frame"], rows)

    # samples simulated by 2 threads (own MjData + controller each) against 1
    threads: dict[str, Any] = {}
    if not smoke:
        c = caps[0][1].capture
        short = type(c)(c.name, c.times[:8], c.hand_q[:8], c.object_pose[:8], c.obj)
        t1 = optimise_capture(short, PhysCapConfig(n_samples=32, n_keep=8)).frame_seconds.sum()
        t2 = optimise_capture(short, PhysCapConfig(n_samples=32, n_keep=8, n_threads=2)
                              ).frame_seconds.sum()
        threads = {"threads2_speedup": float(t1 / t2)}
        print(f"\n2 threads vs 1: {t1:.2f} s / {t2:.2f} s = {t1 / t2:.2f}x (7 steps, 32 samples)")

    # fewer / more samples: the same result? (contact sampling, the in-distribution captures)
    sweep: dict[str, Any] = {}
    if not (quick or smoke):
        sw_rows = []
        ins = [sc for split, sc in caps if split == "in"][:4]
        # (method, samples, finger half-width): the narrow hypercube leaves the contact
        # corrections to the seeds (random sampling then keeps the reference's wrong ones)
        for method, m, width in (("contact", 16, 0.08), ("random", 16, 0.08),
                                 ("contact", 64, 0.08), ("contact", 32, 0.04),
                                 ("random", 32, 0.04)):
            ok, errs = [], []
            for sc in ins:
                r = optimise_capture(sc.capture, PhysCapConfig(
                    n_samples=m, n_keep=m // 4, finger_width=width, **_METHODS[method]))
                ok.append(r.success)
                errs.append(_errors(model, sc.truth, r.hand_q, r.object_pose)[0])
            tag = f"{m}" if width == 0.08 else f"{m}_narrow"
            sweep[f"{method}_success_{tag}"] = float(np.mean(ok))
            sweep[f"{method}_object_err_mm_{tag}"] = float(np.mean(errs))
            sw_rows.append([method, m, width, float(np.mean(ok)), float(np.mean(errs))])
        for method in ("contact", "random"):
            base = [p for p in per[method] if p["split"] == "in"][:4]
            sw_rows.append([method, n, 0.08, float(np.mean([p["success"] for p in base])),
                            float(np.mean([p["obj"] for p in base]))])
        # the paper's 1500 samples per step: the time per frame, on the first 4 frames
        sc = ins[0]
        c = sc.capture
        short = type(c)(c.name, c.times[:4], c.hand_q[:4], c.object_pose[:4], c.obj)
        r = optimise_capture(short, PhysCapConfig(n_samples=1500, n_keep=150))
        sweep["s_per_frame_1500"] = r.s_per_frame
        print_table("samples per step and finger hypercube half-width (4 lift_box captures)",
                    ["sampling", "samples", "finger_width_rad", "success", "object_err_mm"],
                    sw_rows)
        print(f"1500 samples per step (seed 000's default): {r.s_per_frame:.2f} s per frame")

    def rate(method: str, split: str | None = None) -> float:
        v = [p["success"] for p in per[method] if split is None or p["split"] == split]
        return float(np.mean(v)) if v else float("nan")

    def mean(method: str, key: str, split: str | None = None) -> float:
        v = [p[key] for p in per[method] if split is None or p["split"] == split]
        return float(np.mean(v)) if v else float("nan")

    # retargeting the first capture's control (sec. 7.2)
    cases = [("cylinder 150 g", CapturedObject("cylinder", (0.028, 0.045), 0.15, 0.75), {}),
             ("ball 100 g", CapturedObject("sphere", (0.032,), 0.1, 0.75), {}),
             ("flat box 150 g", CapturedObject("box", (0.04, 0.0285, 0.02), 0.15, 0.75), {}),
             ("box 350 g", CapturedObject("box", first.obj.size, 0.35, 0.75), {}),
             ("friction 0.4", None, {"friction": 0.4}),
             ("friction 0.25", None, {"friction": 0.25})]
    if smoke:
        cases = cases[:1] + cases[-1:]
    rt_rows, ok = [], []
    for label, obj, kw in cases:
        o = retarget(first, obj, label=label, **kw)
        ok.append(o.success)
        rt_rows.append([label, o.success, o.final_error_m * 1e3, o.lift_m * 1e3])
    slip = retarget(first, None, friction=0.03, label="friction 0.03")
    rt_rows.append([slip.label + " (must slip)", slip.success, slip.final_error_m * 1e3,
                    slip.lift_m * 1e3])
    print_table(f"retargeting {first.name}'s control (source success {first.success})",
                ["target", "success", "final_err_mm", "lift_mm"], rt_rows)

    dask: dict[str, Any] = {"dask_speedup_2w": None}
    try:
        from hand_control.physcap.batch import measure_dask_speedup

        t0 = time.perf_counter()
        dcfg = PhysCapConfig(n_samples=8 if smoke else 16, n_keep=2)
        dask = measure_dask_speedup([sc.capture for _, sc in caps][:2] if len(caps) > 1
                                    else [caps[0][1].capture, caps[0][1].truth], dcfg,
                                    quick=quick or smoke)
        print(f"\ndask: 1 worker {dask.get('dask_1w_s')} s, 2 workers {dask.get('dask_2w_s')} s,"
              f" speed-up {dask.get('dask_speedup_2w')}, identical {dask.get('dask_identical')}"
              f" ({time.perf_counter() - t0:.1f} s)")
    except ImportError as e:
        print(f"\ndask: not measured ({e})")
    return {
        "bench": "physcap", "samples_per_step": n, "captures": len(caps),
        "s_per_frame": mean("contact", "s"),
        "contact_sampling_success": rate("contact"),
        "random_sampling_success": rate("random"),
        "pd_only_success": rate("pd_only"),
        "heldout_contact_sampling_success": rate("contact", "heldout"),
        "heldout_random_sampling_success": rate("random", "heldout"),
        "object_err_mm": mean("contact", "obj"), "hand_err_mm": mean("contact", "hand"),
        "ref_object_err_mm": mean("contact", "ref_obj"),
        "ref_hand_err_mm": mean("contact", "ref_hand"),
        "heldout_object_err_mm": mean("contact", "obj", "heldout"),
        "random_object_err_mm": mean("random", "obj"),
        "retarget_success": float(np.mean(ok)), "retarget_cases": len(ok),
        "low_friction_slipped": bool(not slip.success), **sweep, **threads,
        **{k: v for k, v in dask.items() if k.startswith("dask_")},
    }
