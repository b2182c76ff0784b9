"""``hand-suite bench touch``: multi-touch -> hand pose (Chung et al., Tables 1 and 2).

Training data: the trainer's set (template right hand, seed 0, cached).
Test data: held-out sequences generated with other seeds (1 and 2; fewer with ``--quick``) and
another hand shape (``sample_shape(101)``: 5 % smaller overall, 9 % broader palm), in the role
of the paper's second-day capture.

* Table 1: wrist position error [cm] and joint angle error [deg] (mean |difference| over the
  21 articulated joints), mean and standard error of the mean, for the linear, quadratic and
  cubic encodings (true finger labels) and the PCA-IK baseline (on a subsample: it runs 100 IK
  iterations per pose).
* Table 1b (full run only): the same encodings with a ridge weight chosen by cross-validation
  on the training set, to show how much of the ranking is the paper's plain least squares.
* Table 2: finger labelling accuracy by number of contacts: every test frame's contacts are
  shuffled and labelled from scratch (all labellings searched, nearest training neighbour);
  a frame counts as correct when every contact gets its finger.
* Timing, on one BLAS thread: quadratic evaluation per pose (batched) and one complete
  5-contact labelling (median and fastest of 3 passes over the test frames), against the
  PCA-IK time per pose measured in the same run (the ratio is the baseline comparison).
"""

from __future__ import annotations

import gc
import time
from typing import Any

import numpy as np

from hand_capture.bench import print_table
from hand_capture.cameras.threads import blas_threads
from hand_capture.model.joints import ARTICULATED_JOINTS, JOINT_INDEX
from hand_capture.model.shape import sample_shape
from hand_capture.touch.datagen import GenConfig, TouchDataset, build_model, load_or_generate
from hand_capture.touch.encoding import DEGREES, PolynomialEncoder, cross_validate_ridge
from hand_capture.touch.labelling import FingerLabeller
from hand_capture.touch.pcaik import PcaIk
from hand_capture.touch.touch_model import MAX_REFERENCE
from hand_capture.touch.train import TRAIN, fit_model

TEST_SHAPE_SEED = 101
TEST_SEEDS = (1, 2)
CV_RIDGES = (0.0, 1e-4, 1e-3, 1e-2, 1e-1, 1.0)
_ART = np.array([JOINT_INDEX[j] for j in ARTICULATED_JOINTS])


def errors(truth: np.ndarray, est: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame wrist position error [cm] and mean joint angle error [deg]."""
    wrist = 100.0 * np.linalg.norm(est[:, :3] - truth[:, :3], axis=1)
    angle = np.degrees(np.abs(est[:, _ART] - truth[:, _ART]).mean(axis=1))
    return wrist, angle


def _sem(x: np.ndarray) -> float:
    return float(x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan")


def datasets(quick: bool, smoke: bool = False) -> tuple[TouchDataset, TouchDataset]:
    """(train, test)."""
    per_seed = 10 if smoke else 80 if quick else 210
    train = load_or_generate(TRAIN)  # the full set in quick runs too: with a third of it the
    # quadratic (136 coefficients per DoF) already overfits the joint angles
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


def run(quick: bool = False, smoke: bool = False) -> dict[str, Any]:
    """The figures; ``smoke``: a few held-out sequences and frames through the same code."""
    t_start = time.perf_counter()
    quick = quick or smoke
    train, test = datasets(quick, smoke)
    model = fit_model(train)
    ref_rows = np.sort(np.random.default_rng(0).choice(
        len(model.reference_poses), min(MAX_REFERENCE, len(model.reference_poses)), False))
    reference = model.reference_poses[ref_rows]  # what the shipped file keeps
    u_test, _ = test.inputs()
    u_train, rel_train = train.inputs()
    figures: dict[str, Any] = {"train_frames": len(train), "test_frames": len(test)}

    # --- Table 1 ---------------------------------------------------------------------------
    rows = []
    results: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name, enc in model.encoders.items():
        est = enc.reconstruct(test.pads, test.contact)
        results[name] = errors(test.poses, est)
    pk = PcaIk(build_model(-1), rel_train)
    n_ik = min(len(test), 10 if smoke else 120 if quick else 600)
    ik_rows = np.sort(np.random.default_rng(3).choice(len(test), n_ik, replace=False))
    gc.collect()
    t0 = time.perf_counter()
    est = pk.solve(test.pads[ik_rows], test.contact[ik_rows])
    pcaik_ms = 1e3 * (time.perf_counter() - t0) / n_ik
    results["pcaik"] = errors(test.poses[ik_rows], est)
    for name in ("linear", "quadratic", "cubic", "pcaik"):
        w, a = results[name]
        figures[f"{name}_wrist_cm"] = float(w.mean())
        figures[f"{name}_angle_deg"] = float(a.mean())
        rows.append(["PCA IK" if name == "pcaik" else name.capitalize(), w.mean(), _sem(w),
                     a.mean(), _sem(a), len(w)])
    print_table("Table 1: reconstruction error on held-out data (true finger labels)",
                ["method", "wrist cm", "SEM", "angle deg", "SEM", "frames"], rows)

    # --- Table 1b: regularisation chosen on the training data alone ---------------------------
    if not quick:
        rows = []
        for name, degree in DEGREES.items():
            ridge, scores = cross_validate_ridge(u_train, rel_train, degree, CV_RIDGES,
                                                 train.sequence)
            enc = PolynomialEncoder.fit(u_train, rel_train, degree, ridge=ridge)
            w, a = errors(test.poses, enc.reconstruct(test.pads, test.contact))
            rows.append([name.capitalize(), ridge, float(scores.min()), w.mean(), _sem(w),
                         a.mean(), _sem(a)])
            figures[f"{name}_cv_ridge"] = ridge
            figures[f"{name}_cv_score"] = float(scores.min())
            figures[f"{name}_cv_wrist_cm"] = float(w.mean())
            figures[f"{name}_cv_angle_deg"] = float(a.mean())
        print_table("Table 1b: ridge weight chosen by 5-fold cross-validation on the training "
                    "set (folds by sequence; score = CV error / variance, lower is better)",
                    ["method", "ridge", "CV score", "wrist cm", "SEM", "angle deg", "SEM"],
                    rows)

    # --- Table 2 ---------------------------------------------------------------------------
    n_lab = len(test) if not quick else min(len(test), 40 if smoke else 400)
    lab_rows = np.sort(np.random.default_rng(4).choice(len(test), n_lab, replace=False))
    rows = []
    labellers = {name: FingerLabeller(enc, reference) for name, enc in model.encoders.items()}
    labellers["pcaik"] = FingerLabeller(model.encoders["linear"], u_train, mode="input")
    auto = None
    for name in ("linear", "quadratic", "cubic", "pcaik"):
        with blas_threads(1):
            acc, counts, poses = label_accuracy(labellers[name], test, lab_rows,
                                                np.random.default_rng(5))
        rows.append(["PCA IK" if name == "pcaik" else name.capitalize()]
                    + [100.0 * acc[n] for n in range(2, 6)])
        if name == "quadratic":
            for n in range(2, 6):
                figures[f"label_acc_{n}"] = acc[n]
            figures["label_frames"] = {str(n): c for n, c in counts.items()}
            auto = errors(test.poses[lab_rows], poses)
        else:
            figures[f"{name}_label_acc"] = {str(n): acc[n] for n in range(2, 6)}
    print_table("Table 2: finger labelling accuracy [%] by contacts (search from scratch)",
                ["method", "2 fingers", "3 fingers", "4 fingers", "5 fingers"], rows)
    figures["quadratic_auto_wrist_cm"] = float(auto[0].mean())
    figures["quadratic_auto_angle_deg"] = float(auto[1].mean())

    # --- timing (one BLAS thread: on a busy machine OpenBLAS threads only add waiting) -------
    quad = model.encoders["quadratic"]
    with blas_threads(1):
        eval_us = _time_eval(quad, u_test)
        labelling_ms, labelling_min_ms = _time_labelling(labellers["quadratic"], test)
        cubic_us = _time_eval(model.encoders["cubic"], u_test, batch=2000, repeats=3)
    figures.update({
        "eval_us": eval_us,
        "cubic_eval_us": cubic_us,
        "labelling_ms": labelling_ms,
        "labelling_min_ms": labelling_min_ms,
        "pcaik_ms_per_pose": pcaik_ms,
        "eval_speedup_vs_pcaik": 1e3 * pcaik_ms / eval_us,
        "pcaik_frames": n_ik,
        "pcaik_explained_variance": {str(n): pk.explained_variance(n) for n in range(2, 6)},
        "reference_poses": len(reference),
        "test_shape_scale": sample_shape(TEST_SHAPE_SEED).global_scale,
    })
    print_table("Timing (batched evaluation; PCA-IK is the same-run baseline)",
                ["what", "value", "unit"],
                [["quadratic evaluation", eval_us, "us / pose"],
                 ["cubic evaluation", cubic_us, "us / pose"],
                 ["5-contact labelling (120 candidates)", labelling_ms, "ms"],
                 ["5-contact labelling, fastest of the runs", labelling_min_ms, "ms"],
                 ["PCA-IK, 100 iterations", pcaik_ms, "ms / pose"],
                 ["quadratic speed-up over PCA-IK", figures["eval_speedup_vs_pcaik"], "x"],
                 ["quadratic with automatic labels: wrist", figures["quadratic_auto_wrist_cm"],
                  "cm"],
                 ["quadratic with automatic labels: angle",
                  figures["quadratic_auto_angle_deg"], "deg"]])
    figures["seconds"] = time.perf_counter() - t_start
    return figures

