"""``hand-suite bench touch``: multi-touch -> hand pose (Chung et al., Tables 1 and 2).

Training data: the trainer's set (:data:`~hand_capture.touch.train.TRAIN_PARTS`: template
right hand and eight sampled subjects, cached).
In-distribution test data: sequences from the training generator with other seeds (1 and 2;
fewer with ``--quick``) and another hand shape (``sample_shape(101)``: 5 % smaller overall,
9 % broader palm), in the role of the paper's second-day capture.
Held-out test data: :mod:`hand_capture.touch.heldout`, a family the training never sees
(grasp keyframes, wrist yaw +-45 / tilt -5..35 / roll +-20 deg, hands 0.92-1.08, anywhere on
an iPad-sized surface, panel offset, jitter and quantisation); 1,200 frames (480 quick).

* Table 1: wrist position error [cm] and joint angle error [deg] (mean |difference| over the
  21 articulated joints), mean and standard error of the mean, for the linear, quadratic and
  cubic encodings (true finger labels) and the PCA-IK baseline (on a subsample: it runs 100 IK
  iterations per pose). The encodings are fitted as the shipped model is
  (:func:`~hand_capture.touch.train.fit_model`): in the contacts' frame
  (:class:`~hand_capture.touch.encoding.ContactFrame`), each with the ridge weight chosen by
  5-fold cross-validation on the training set (folds by sequence; keys ``<name>_cv_ridge``,
  ``<name>_cv_score``; ``--quick`` takes the weights of the shipped file when it was fitted
  on the same training set, and a full run says whether its own agree:
  ``cv_ridges_equal_shipped``). The row "Quadratic, paper's frame" (keys ``leftmost_*``) is the
  quadratic fitted the same way on the same data relative to the leftmost contact, unturned,
  as in the paper: the before/after comparison of that departure. The rows "..., plain least
  squares (paper)" (keys ``<name>_lsq_*``) are the encodings in the contacts' frame fitted
  without a ridge, as in the paper: the before/after comparison of the cross-validated ridge.
* Table 2: finger labelling accuracy by number of contacts: every test frame's contacts are
  shuffled and labelled from scratch (all labellings searched, nearest training neighbour);
  a frame counts as correct when every contact gets its finger. The row "Quadratic + layout"
  is the shipped labeller (nearest neighbour plus the layout prior,
  :class:`~hand_capture.touch.labelling.LayoutPrior`); ``label_acc_N`` are its figures,
  ``quadratic_nearest_label_acc`` the paper's criterion alone and ``layout_nn025_label_acc``
  the shipped labeller with the nearest-neighbour weight it had before (0.25 rad).
* Held-out tables H1 / H2: Table 1 and Table 2 on the held-out family (``heldout_*`` keys).
* Timing, on one BLAS thread: quadratic evaluation per pose (batched) and one complete
  5-contact labelling (median and fastest of 3 passes over the test frames), against the
  PCA-IK time per pose measured in the same run (the ratio is the baseline comparison).
"""

from __future__ import annotations

import gc
import json
import time
from dataclasses import replace
from typing import Any

import numpy as np

from hand_capture.bench import print_table
from hand_capture.cameras.threads import blas_threads
from hand_capture.model.joints import ARTICULATED_JOINTS, JOINT_INDEX
from hand_capture.model.shape import sample_shape
from hand_capture.touch.datagen import GenConfig, TouchDataset, build_model, load_or_generate
from hand_capture.touch.encoding import DEGREES, PolynomialEncoder
from hand_capture.touch.heldout import HeldoutConfig, generate_heldout
from hand_capture.touch.labelling import FingerLabeller, LabellerConfig
from hand_capture.touch.pcaik import PcaIk
from hand_capture.touch.touch_model import MAX_REFERENCE
from hand_capture.touch.train import (
    TRAIN,
    TRAIN_PARTS,
    fit_encoders,
    fit_model,
    shipped_ridges,
    training_set,
)

TEST_SHAPE_SEED = 101
TEST_SEEDS = (1, 2)
_ART = np.array([JOINT_INDEX[j] for j in ARTICULATED_JOINTS])


def errors(truth: np.ndarray, est: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame wrist position error [cm] and mean joint angle error [deg]."""
    wrist = 100.0 * np.linalg.norm(est[:, :3] - truth[:, :3], axis=1)
    angle = np.degrees(np.abs(est[:, _ART] - truth[:, _ART]).mean(axis=1))
    return wrist, angle


def _sem(x: np.ndarray) -> float:
    return float(x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan")


#: ``--smoke``'s training set: every part of the trainer's set with a twentieth of its
#: sequences (the same code on a set a fresh checkout generates in seconds, not minutes)
SMOKE_PARTS: tuple[GenConfig, ...] = tuple(replace(c, sequences=c.sequences // 20)
                                           for c in TRAIN_PARTS)


def datasets(quick: bool, smoke: bool = False) -> tuple[TouchDataset, TouchDataset]:
    """(train, test); ``smoke``: a few test sequences and :data:`SMOKE_PARTS` only."""
    per_seed = 10 if smoke else 80 if quick else 210
    # the full set in quick runs too: with a third of the template part alone the quadratic
    # (136 coefficients per DoF) already overfits the joint angles
    train = training_set(SMOKE_PARTS if smoke else TRAIN_PARTS)
    test_model = build_model(TEST_SHAPE_SEED)
    parts = [load_or_generate(GenConfig(sequences=per_seed, frames=TRAIN.frames, seed=s,
                                        shape_seed=TEST_SHAPE_SEED), model=test_model)
             for s in TEST_SEEDS]
    test = TouchDataset.concatenate(parts)
    return train, test


def label_accuracy(labeller: FingerLabeller, test: TouchDataset, rows: np.ndarray,
                   rng: np.random.Generator) -> tuple[dict[int, float], dict[int, int],
                                                      np.ndarray]:
    """Accuracy by contact count of a from-scratch search on shuffled contacts; also the
    reconstructed absolute poses (NaN rows for mode 'input')."""
    hits: dict[int, list[bool]] = {n: [] for n in range(2, 6)}
    poses = np.full((len(rows), test.poses.shape[1]), np.nan)
    for k, i in enumerate(rows):
        fingers = np.nonzero(test.contact[i])[0]
        perm = rng.permutation(len(fingers))
        res = labeller.search(test.pads[i, fingers[perm]])
        hits[len(fingers)].append(bool(np.array_equal(res.labels, fingers[perm])))
        if res.pose is not None:
            poses[k] = res.pose
    acc = {n: float(np.mean(v)) if v else float("nan") for n, v in hits.items()}
    return acc, {n: len(v) for n, v in hits.items()}, poses


def _time_eval(encoder: object, u: np.ndarray, batch: int = 10000, repeats: int = 7) -> float:
    """Median time per pose [us] of batched evaluation."""
    ub = np.resize(u, (batch, u.shape[1]))
    encoder.predict(ub)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        encoder.predict(ub)
        times.append(time.perf_counter() - t0)
    return 1e6 * float(np.median(times)) / batch


def _time_labelling(labeller: FingerLabeller, test: TouchDataset, n: int = 200,
                    passes: int = 3) -> tuple[float, float]:
    """Median and minimum time [ms] of one complete labelling of 5 contacts (``passes`` over
    the first ``n`` 5-contact frames; the minimum shows the cost without other load)."""
    rows = np.nonzero(test.n_contacts == 5)[0][:n]
    for i in rows[:5]:
        labeller.search(test.pads[i])
    times = []
    for _ in range(passes):
        for i in rows:
            t0 = time.perf_counter()
            labeller.search(test.pads[i])
            times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times)), 1e3 * float(np.min(times))


#: Table 1's rows in order (the encoders of the run, then PCA-IK, then the comparisons).
TABLE1_ROWS = ("linear", "quadratic", "cubic", "pcaik", "leftmost", "linear_lsq",
               "quadratic_lsq", "cubic_lsq")


def _methods_table(title: str, encoders: dict[str, PolynomialEncoder], pk: PcaIk,
                   test: TouchDataset, n_ik: int, seed: int
                   ) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], float]:
    """Table 1 on ``test`` (its ``pads`` are the encoder input): per-frame errors by method
    (the ``encoders`` by name, and "pcaik"), and the PCA-IK time per pose [ms] (on ``n_ik``
    frames)."""
    results: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name, enc in encoders.items():
        results[name] = errors(test.poses, enc.reconstruct(test.pads, test.contact))
    n_ik = min(len(test), n_ik)
    ik_rows = np.sort(np.random.default_rng(seed).choice(len(test), n_ik, replace=False))
    gc.collect()
    t0 = time.perf_counter()
    est = pk.solve(test.pads[ik_rows], test.contact[ik_rows])
    pcaik_ms = 1e3 * (time.perf_counter() - t0) / n_ik
    results["pcaik"] = errors(test.poses[ik_rows], est)
    rows = []
    for name in TABLE1_ROWS:
        if name in results:
            w, a = results[name]
            rows.append([_label(name), w.mean(), _sem(w), a.mean(), _sem(a), len(w)])
    print_table(title, ["method", "wrist cm", "SEM", "angle deg", "SEM", "frames"], rows)
    return results, pcaik_ms


def _ridges(meta: dict[str, str]) -> str:
    """The ridge weights of a model's meta, e.g. ``linear 0, quadratic 0.001, cubic 0.01``."""
    return ", ".join(f"{n} {float(meta[f'ridge_{n}']):g}" for n in DEGREES)


def _label(name: str) -> str:
    if name.endswith("_lsq"):
        return f"{name[:-4].capitalize()}, plain least squares (paper)"
    return {"pcaik": "PCA IK", "layout": "Quadratic + layout",
            "layout_nn025": "Quadratic + layout, nn_scale 0.25 (before)",
            "leftmost": "Quadratic, paper's frame"}.get(name, name.capitalize())


def _labelling_table(title: str, labellers: dict[str, FingerLabeller], test: TouchDataset,
                     n_lab: int, seed: int) -> tuple[dict[str, dict[int, float]],
                                                     dict[int, int], np.ndarray, np.ndarray]:
    """Table 2 on ``test``: accuracy by contacts per labeller; the frame counts; the rows
    used and the poses of the shipped labeller ('layout')."""
    n_lab = min(len(test), n_lab)
    lab_rows = np.sort(np.random.default_rng(seed).choice(len(test), n_lab, replace=False))
    accs: dict[str, dict[int, float]] = {}
    rows, counts, poses = [], {}, np.zeros((0, 27))
    for name, lab in labellers.items():
        with blas_threads(1):
            acc, counts, p = label_accuracy(lab, test, lab_rows, np.random.default_rng(5))
        accs[name] = acc
        if name == "layout":
            poses = p
        rows.append([_label(name)] + [100.0 * acc[n] for n in range(2, 6)])
    rows.append(["(paper, quadratic)", *PAPER_LABEL_ACC])
    print_table(title, ["method", "2 fingers", "3 fingers", "4 fingers", "5 fingers"], rows)
    return accs, counts, lab_rows, poses


#: Table 2 of the paper, quadratic encoding [%] for 2, 3, 4, 5 contacts
PAPER_LABEL_ACC = (55.66, 70.72, 79.36, 99.88)


def run(quick: bool = False, smoke: bool = False) -> dict[str, Any]:
    """The figures; ``smoke``: a few test and held-out frames through the same code."""
    t_start = time.perf_counter()
    quick = quick or smoke
    train, test = datasets(quick, smoke)
    heldout, reported = generate_heldout(HeldoutConfig(
        frames=120 if smoke else 480 if quick else 1200))
    # the encoders see what the panel reports; the truth poses stay
    heldout_in = TouchDataset(heldout.poses, reported, heldout.contact, heldout.sequence,
                              heldout.frame, heldout.motion)
    # quick runs take the shipped file's cross-validated weights when it was fitted on the
    # same training set (the same fit, without the minute of cross-validation)
    given = shipped_ridges() if quick else None
    model = fit_model(train, ridge=given)
    ref_rows = np.sort(np.random.default_rng(0).choice(
        len(model.reference_poses), min(MAX_REFERENCE, len(model.reference_poses)), False))
    reference = model.reference_poses[ref_rows]  # what the shipped file keeps
    u_test, _ = test.inputs(model.frame)
    u_train, rel_train = train.inputs(model.frame)  # the encoders' frame
    _, rel_leftmost = train.inputs()  # root relative to the leftmost contact (PCA-IK)
    figures: dict[str, Any] = {"train_frames": len(train), "test_frames": len(test),
                               "heldout_frames": len(heldout)}

    # --- Table 1 ---------------------------------------------------------------------------
    pk = PcaIk(build_model(-1), rel_leftmost)
    compared = dict(model.encoders)
    # the paper's frame (relative to the leftmost contact, unturned), fitted as the product is:
    # the before/after baseline of the contacts' frame
    compared["leftmost"] = fit_encoders(*train.inputs(), train.sequence,
                                        degrees=("quadratic",))[0]["quadratic"]
    # the paper's plain least squares in the product's frame: before/after of the CV ridge
    for name, degree in DEGREES.items():
        compared[f"{name}_lsq"] = PolynomialEncoder.fit(u_train, rel_train, degree,
                                                        frame=model.frame)
    for name in DEGREES:
        figures[f"{name}_cv_ridge"] = float(model.meta[f"ridge_{name}"])
        if given is None:
            figures[f"{name}_cv_score"] = min(json.loads(model.meta[f"cv_scores_{name}"]))
    if given is None:  # the run's own cross-validation agrees with the shipped file?
        figures["cv_ridges_equal_shipped"] = shipped_ridges() == {
            n: figures[f"{n}_cv_ridge"] for n in DEGREES}
    results, pcaik_ms = _methods_table(
        "Table 1: reconstruction error, in-distribution test (true finger labels; ridges by "
        f"5-fold CV on the training set{' (the shipped file)' if given else ''}: "
        f"{_ridges(model.meta)})", compared, pk, test,
        10 if smoke else 120 if quick else 600, 3)
    held, _ = _methods_table(
        "Table H1: reconstruction error, held-out family (true finger labels, panel noise)",
        compared, pk, heldout_in, 10 if smoke else 120 if quick else 400, 6)
    for section, res in (("", results), ("heldout_", held)):
        for name in TABLE1_ROWS:
            w, a = res[name]
            figures[f"{section}{name}_wrist_cm"] = float(w.mean())
            figures[f"{section}{name}_wrist_sem"] = _sem(w)
            figures[f"{section}{name}_angle_deg"] = float(a.mean())
            figures[f"{section}{name}_angle_sem"] = _sem(a)

    # --- Table 2 ---------------------------------------------------------------------------
    labellers = {name: FingerLabeller(enc, reference, LabellerConfig(criterion="nearest"))
                 for name, enc in model.encoders.items()}
    labellers["pcaik"] = FingerLabeller(model.encoders["linear"], u_train, mode="input")
    labellers["layout"] = FingerLabeller(model.encoders["quadratic"], reference,
                                         layout=model.layout)
    # the nearest-neighbour weight shipped before (0.25 rad; issue #13): same-run comparison
    labellers["layout_nn025"] = FingerLabeller(model.encoders["quadratic"], reference,
                                               LabellerConfig(nn_scale=0.25),
                                               layout=model.layout)
    n_quick = 40 if smoke else 400
    for section, data, n_lab, seed in (("", test, n_quick if quick else len(test), 4),
                                       ("heldout_", heldout_in,
                                        n_quick if quick else len(heldout_in), 7)):
        title = ("Table 2: finger labelling accuracy [%] by contacts (search from scratch), "
                 + ("in-distribution test" if not section else "held-out family"))
        accs, counts, lab_rows, poses = _labelling_table(title, labellers, data, n_lab, seed)
        for n in range(2, 6):
            figures[f"{section}label_acc_{n}"] = accs["layout"][n]
        figures[f"{section}label_frames"] = {str(n): c for n, c in counts.items()}
        for name in ("linear", "cubic", "pcaik", "layout_nn025"):
            figures[f"{section}{name}_label_acc"] = {str(n): accs[name][n] for n in range(2, 6)}
        figures[f"{section}quadratic_nearest_label_acc"] = {
            str(n): accs["quadratic"][n] for n in range(2, 6)}
        auto = errors(data.poses[lab_rows], poses)
        figures[f"{section}quadratic_auto_wrist_cm"] = float(auto[0].mean())
        figures[f"{section}quadratic_auto_angle_deg"] = float(auto[1].mean())

    # --- timing (one BLAS thread: on a busy machine OpenBLAS threads only add waiting) -------
    quad = model.encoders["quadratic"]
    with blas_threads(1):
        eval_us = _time_eval(quad, u_test)
        labelling_ms, labelling_min_ms = _time_labelling(labellers["layout"], test)
        cubic_us = _time_eval(model.encoders["cubic"], u_test, batch=2000, repeats=3)
    figures.update({
        "eval_us": eval_us,
        "cubic_eval_us": cubic_us,
        "labelling_ms": labelling_ms,
        "labelling_min_ms": labelling_min_ms,
        "pcaik_ms_per_pose": pcaik_ms,
        "eval_speedup_vs_pcaik": 1e3 * pcaik_ms / eval_us,
        "pcaik_explained_variance": {str(n): pk.explained_variance(n) for n in range(2, 6)},
        "reference_poses": len(reference),
        "test_shape_scale": sample_shape(TEST_SHAPE_SEED).global_scale,
    })
    print_table("Timing (batched evaluation; PCA-IK is the same-run baseline)",
                ["what", "value", "unit"],
                [["quadratic evaluation", eval_us, "us / pose"],
                 ["cubic evaluation", cubic_us, "us / pose"],
                 ["5-contact labelling with layout (120 candidates)", labelling_ms, "ms"],
                 ["5-contact labelling, fastest of the runs", labelling_min_ms, "ms"],
                 ["PCA-IK, 100 iterations", pcaik_ms, "ms / pose"],
                 ["quadratic speed-up over PCA-IK", figures["eval_speedup_vs_pcaik"], "x"],
                 ["quadratic with automatic labels: wrist", figures["quadratic_auto_wrist_cm"],
                  "cm"],
                 ["quadratic with automatic labels: angle",
                  figures["quadratic_auto_angle_deg"], "deg"]])
    figures["seconds"] = time.perf_counter() - t_start
    return figures
