"""Ceiling of finger labelling on the touch held-out family (analysis, never shipped).

How well can ANY labeller name the fingers from the contacts alone on
:mod:`hand_capture.touch.heldout`? Classifiers are trained ON the held-out family itself (other
seeds, hence other subjects, postures, placements and panel noise) and tested on the frames of
``hand-suite bench touch`` (``HeldoutConfig()``, seed 900000, 1,200 frames). A classifier that
has seen this family's own finger-set frequencies and layouts estimates (from below) the Bayes
ceiling of the family; a labeller trained elsewhere, like the shipped one, cannot be expected
to beat it. Nothing here is used by the suite: it only reads the held-out generator.

Per contact count n the contacts are put in a canonical order (by surface x), and the class is
the finger of each contact in that order (a full labelling: 20, 60, 120 and 120 possible
classes for n = 2..5). Features: the positions less their centroid in the surface frame, the
same in the contacts' own frame (principal axis of the contacts on x), and every pairwise
distance. Classifiers: k-nearest neighbours (standardised features) and a random forest
(scikit-learn; gradient-boosted trees did far worse on 2 contacts, 17 %, and were
dropped). A frame counts as right when every contact gets its finger, as in the bench.

    PYTHONPATH=. .venv/bin/python scripts/touch_label_ceiling.py [--seeds 8] [--frames 2400]
    PYTHONPATH=. .venv/bin/python scripts/touch_label_ceiling.py --validation

``--validation`` is the other half of the study and touches no held-out frame: the shipped
labeller's nearest-neighbour weight (``LabellerConfig.nn_scale``) over a grid, on frames of the
TRAINING generator with unseen seeds and hands (seeds 52-54, ``sample_shape(17..19)``, the
wide wrist / curl settings of the training's third part), the set it is chosen on.

The held-out training frames are cached in ``data/touch/cache/heldout/`` (git-ignored).
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from collections import Counter

import numpy as np

from hand_capture.touch.datagen import (
    GenConfig,
    TouchDataset,
    build_model,
    cache_dir,
    load_or_generate,
)
from hand_capture.touch.heldout import SEED_BASE, HeldoutConfig, generate_heldout

FINGER = "TIMRL"  # thumb, index, middle, ring, little
PAPER = {2: 55.66, 3: 70.72, 4: 79.36, 5: 99.88}


def heldout_frames(cfg: HeldoutConfig) -> tuple[np.ndarray, np.ndarray]:
    """(reported (N, 5, 2) [m], contact (N, 5)) of the held-out family for ``cfg``, cached."""
    path = cache_dir() / "heldout" / f"heldout_{cfg.seed}_{cfg.frames}.npz"
    if path.exists():
        d = np.load(path)
        return d["reported"], d["contact"]
    ds, reported = generate_heldout(cfg)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, reported=reported, contact=ds.contact)
    tmp.replace(path)
    return reported, ds.contact


def features(reported: np.ndarray, contact: np.ndarray, n: int
             ) -> tuple[np.ndarray, np.ndarray]:
    """Features (F, d) and class keys (F,) of the frames with ``n`` contacts.

    The contacts are sorted by surface x; the key is "1" and the finger of each in that order,
    as decimal digits (thumb 0 .. little 4).
    """
    rows = np.flatnonzero(contact.sum(axis=1) == n)
    feats, keys = [], []
    pairs = list(itertools.combinations(range(n), 2))
    for i in rows:
        fingers = np.flatnonzero(contact[i])
        p = reported[i, fingers]
        order = np.argsort(p[:, 0], kind="stable")
        p, fingers = p[order], fingers[order]
        c = p - p.mean(axis=0)
        # the contacts' own frame: principal axis on x, pointing from the first to the last
        w, v = np.linalg.eigh(c.T @ c)
        ax = v[:, -1] if (c[-1] - c[0]) @ v[:, -1] >= 0 else -v[:, -1]
        rot = np.array([[ax[0], ax[1]], [-ax[1], ax[0]]])
        own = c @ rot.T
        dist = [np.linalg.norm(p[a] - p[b]) for a, b in pairs]
        feats.append(np.concatenate([c.ravel(), own.ravel(), dist]))
        keys.append(int("1" + "".join(str(f) for f in fingers)))  # "1": keeps a leading 0
    return np.asarray(feats), np.asarray(keys)


def classifiers(seed: int) -> dict[str, object]:
    """k-NN with 15, 50 and 150 neighbours (standardised features) and a random forest."""
    from sklearn.ensemble import RandomForestClassifier
    from sklearn.neighbors import KNeighborsClassifier
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    knn = {f"knn{k}": make_pipeline(StandardScaler(), KNeighborsClassifier(k)) for k in
           (15, 50, 150)}
    return {**knn, "forest": RandomForestClassifier(300, min_samples_leaf=5, n_jobs=1,
                                                    random_state=seed)}


#: the validation frames of ``--validation``: training generator, seeds and hands unseen
VALIDATION = tuple(GenConfig(sequences=500, frames=8, seed=s, shape_seed=h, yaw_deg=45.0,
                             roll_sd_deg=10.0, pitch_deg=(-12.0, 10.0), curl=(0.0, 0.9),
                             curl_sd=0.12) for s, h in ((52, 17), (53, 18), (54, 19)))
NN_SCALES = (0.25, 0.5, 1.0, 2.0, 4.0, 100.0)


def label_accuracy(labeller: object, ds: TouchDataset, frames: int
                   ) -> tuple[list[float], list[int]]:
    """Accuracy [%] of ``labeller`` for 2..5 contacts and the frames of each count, on
    ``frames`` rows of ``ds`` (contacts shuffled, searched from scratch)."""
    rows = np.sort(np.random.default_rng(1).choice(len(ds), min(frames, len(ds)), False))
    rng = np.random.default_rng(5)
    hits: dict[int, list[bool]] = {n: [] for n in range(2, 6)}
    for i in rows:
        fingers = np.flatnonzero(ds.contact[i])[rng.permutation(ds.n_contacts[i])]
        res = labeller.search(ds.pads[i, fingers])
        hits[len(fingers)].append(bool(np.array_equal(res.labels, fingers)))
    return ([100.0 * float(np.mean(hits[n])) for n in range(2, 6)],
            [len(hits[n]) for n in range(2, 6)])


def validation(frames: int = 2000) -> dict[str, list[float]]:
    """Accuracy [%] by contacts (2..5) of the shipped labeller per ``nn_scale`` on
    :data:`VALIDATION` (``frames`` of them, contacts shuffled, searched from scratch)."""
    from hand_capture.touch.labelling import FingerLabeller, LabellerConfig
    from hand_capture.touch.touch_model import TouchModel

    model = TouchModel.load()
    val = TouchDataset.concatenate([load_or_generate(c, model=build_model(c.shape_seed))
                                    for c in VALIDATION])
    out: dict[str, list[float]] = {}
    for scale in NN_SCALES:
        lab = FingerLabeller(model.encoder("quadratic"), model.reference_poses,
                             LabellerConfig(nn_scale=scale), layout=model.layout)
        out[str(scale)], counts = label_accuracy(lab, val, frames)
        print(f"nn_scale {scale:7g}: " + " / ".join(f"{a:.1f}" for a in out[str(scale)])
              + f"  (mean of 2-4: {np.mean(out[str(scale)][:3]):.2f}; frames "
              + " / ".join(map(str, counts)) + ")", flush=True)
    return out


def _set_name(key: int) -> str:
    return "+".join(FINGER[int(f)] for f in sorted(str(key)[1:]))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=8, help="held-out seeds to train on")
    ap.add_argument("--frames", type=int, default=2400, help="frames per training seed")
    ap.add_argument("--validation", action="store_true", help="choose the nearest-neighbour "
                    "weight on training-generator frames instead (no held-out frame)")
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    if a.validation:
        print(json.dumps({"validation_label_acc": validation()}))
        return 0
    test_cfg = HeldoutConfig()  # the bench's held-out frames
    train = [heldout_frames(HeldoutConfig(frames=a.frames, seed=SEED_BASE + 1000 * (k + 1)))
             for k in range(a.seeds)]
    rep_tr = np.concatenate([r for r, _ in train])
    con_tr = np.concatenate([c for _, c in train])
    rep_te, con_te = heldout_frames(test_cfg)
    print(f"{len(rep_tr)} held-out training frames ({a.seeds} seeds), {len(rep_te)} test "
          f"frames (seed {test_cfg.seed}), {time.perf_counter() - t0:.0f} s")
    figures: dict[str, dict[str, float]] = {}
    confusions: dict[str, list[str]] = {}
    print(f"{'contacts':>8} {'train':>6} {'test':>5}  " + " ".join(
        f"{k:>8}" for k in classifiers(0)) + f" {'half':>8} {'set ok':>7} {'paper':>6}")
    for n in range(2, 6):
        x_tr, y_tr = features(rep_tr, con_tr, n)
        x_te, y_te = features(rep_te, con_te, n)
        accs, preds = {}, {}
        for name, clf in classifiers(n).items():
            clf.fit(x_tr, y_tr)
            preds[name] = clf.predict(x_te)
            accs[name] = 100.0 * float(np.mean(preds[name] == y_te))
        best = max(accs, key=accs.get)
        # saturation: the best classifier on half the training frames
        half = classifiers(n)[best].fit(x_tr[: len(x_tr) // 2], y_tr[: len(y_tr) // 2])
        accs["half"] = 100.0 * float(np.mean(half.predict(x_te) == y_te))
        sets_te = np.array([_set_name(k) for k in y_te])
        sets_pr = np.array([_set_name(k) for k in preds[best]])
        accs["set_right"] = 100.0 * float(np.mean(sets_te == sets_pr))
        accs["best"] = accs[best]
        figures[str(n)] = accs
        wrong = Counter(f"{t}->{p}" for t, p in zip(sets_te, sets_pr, strict=True) if t != p)
        confusions[str(n)] = [f"{k} x{v}" for k, v in wrong.most_common(4)]
        print(f"{n:>8} {len(y_tr):>6} {len(y_te):>5}  " + " ".join(
            f"{accs[k]:8.1f}" for k in classifiers(0)) + f" {accs['half']:8.1f} "
            f"{accs['set_right']:7.1f} {PAPER[n]:6.1f}")
    print("most frequent finger-set confusions of the best classifier (true->chosen):")
    for n, c in confusions.items():
        print(f"  {n} contacts: {', '.join(c)}")
    print(json.dumps({"ceiling_label_acc": {n: f["best"] / 100 for n, f in figures.items()},
                      "by_classifier": figures, "confusions": confusions,
                      "train_frames": len(rep_tr), "test_frames": len(rep_te),
                      "seconds": time.perf_counter() - t0}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
