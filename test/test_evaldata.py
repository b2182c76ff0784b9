"""The held-out evaluation family for the depth tracker (hand_capture.evaldata, issue 13):
the split from training holds both ways, and the family renders what it promises."""

from __future__ import annotations

import ast
import subprocess
import sys

import numpy as np
import pytest
from ros_helpers import ROOT

from hand_capture.errors import ConfigError

#: what the held-out family may import from the suite: the camera pinhole, errors, the
#: skeleton's forward kinematics and joint vocabulary, and itself
_ALLOWED = ("hand_capture.cameras.base", "hand_capture.errors", "hand_capture.model",
            "hand_capture.model.joints", "hand_capture.model.skeleton", "hand_capture.evaldata")
#: the training generator's pieces (surface rasteriser, noise model, keyframe motions,
#: synthetic camera, the training code and the whole tracker)
_GENERATOR = ("hand_capture.cameras.render", "hand_capture.cameras.noise",
              "hand_capture.cameras.motion", "hand_capture.cameras.synthetic",
              "hand_capture.model.mesh", "hand_capture.tracking")


def _imports(path) -> list[str]:
    """Every module a file imports, at any depth (lazy imports in functions included)."""
    names = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
    return names


def test_evaldata_imports_nothing_of_the_training_generator() -> None:
    files = sorted((ROOT / "hand_capture" / "evaldata").glob("*.py"))
    assert files
    for f in files:
        for name in _imports(f):
            if not name.startswith("hand_capture"):
                continue
            assert not name.startswith(_GENERATOR), f"{f.name} imports {name}"
            assert name in _ALLOWED or name.startswith("hand_capture.evaldata."), \
                f"{f.name} imports {name}, not on the held-out family's allowed list"


def _code_strings(path) -> list[str]:
    """Imported module names and string constants of a file, docstrings left out."""
    tree = ast.parse(path.read_text())
    docs = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value,
                                                                     ast.Constant):
                docs.add(id(body[0].value))
    consts = [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)
              and isinstance(n.value, str) and id(n) not in docs]
    return _imports(path) + consts


def test_training_never_reaches_evaldata() -> None:
    # statically: no tracker, camera or model code imports or names the held-out family
    # (docstrings and comments may mention it)
    for pkg in ("tracking", "cameras", "model"):
        for f in sorted((ROOT / "hand_capture" / pkg).rglob("*.py")):
            assert not any("evaldata" in t for t in _code_strings(f)), \
                f"{f} uses hand_capture.evaldata"
    # and at run time: training (and the tracker package it pulls in) leaves it unloaded;
    # the arm classifier's training (renders with per-pixel labels) runs on a sliver
    code = ("import sys, hand_capture.tracking.train, hand_capture.tracking\n"
            "from hand_capture.tracking.armseg import train_arm_classifier\n"
            "clf = train_arm_classifier(None, n_frames=8, n_shapes=2, n_trees=1)\n"
            "assert int(clf.info['n_frames']) == 8\n"
            "bad = [m for m in sys.modules if m.startswith('hand_capture.evaldata')]\n"
            "assert not bad, bad\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr


def test_sequence_is_reproducible_and_scored_on_the_skeleton() -> None:
    from hand_capture.evaldata import CAMERAS, make_sequence

    a = make_sequence(4, 3, "d435_848", step=3)
    b = make_sequence(4, 3, "d435_848", step=3)
    intr = CAMERAS["d435_848"].intrinsics
    assert (intr.width, intr.height) == (848, 480)
    for (da, ia), (db, _) in zip(a.frames, b.frames, strict=True):
        assert da.dtype == np.uint16 and da.shape == (480, 848) and ia == intr
        np.testing.assert_array_equal(da, db)
    np.testing.assert_allclose(a.keypoints, a.model.joint_positions(a.poses))
    # the hand is in view, at the camera's working distance
    z = a.frames[0][0][a.labels[0] == 1]
    z = z[z > 0]
    assert z.size > 1000
    lo, hi = CAMERAS["d435_848"].hand_depth_m
    assert lo - 0.15 < np.median(z) / 1e3 < hi + 0.15


def test_forearm_and_clutter_are_in_view_only_when_asked() -> None:
    from hand_capture.evaldata import make_sequence

    bare = make_sequence(5, 1, "d435_640", noise=False)
    arm = make_sequence(5, 1, "d435_640", forearm=True, sleeve=True, clutter=True, noise=False)
    assert set(np.unique(bare.labels)) == {0, 1}
    labs = set(np.unique(arm.labels))
    assert {1, 2, 4} <= labs
    # the forearm is a large part of the view, joined to the hand
    for seed in (5, 6, 7):
        lone = make_sequence(seed, 1, "d435_640", forearm=True, sleeve=False, noise=False)
        lab = lone.labels[0]
        assert np.count_nonzero(lab == 2) > 0.5 * np.count_nonzero(lab == 1)
    # same subject and motion with and without: the extra parts are added, not moved
    np.testing.assert_allclose(bare.keypoints, arm.keypoints)


def test_stereo_noise_shadows_the_left_side_of_near_objects() -> None:
    from hand_capture.cameras.base import Intrinsics
    from hand_capture.evaldata.stereo import StereoNoiseConfig, apply_stereo_noise

    intr = Intrinsics(width=200, height=60, fx=200.0, fy=200.0, cx=100.0, cy=30.0)
    z = np.full((60, 200), 1.0)
    z[:, 100:140] = 0.4              # a near box in front of a far wall
    cfg = StereoNoiseConfig(hole_rate=0.0, flying_rate=0.0, fatten_px=0,
                            disparity_sd_px=0.0, white_sd_px=0.0)
    out = apply_stereo_noise(z, intr, np.random.default_rng(0), cfg)
    # disparity step: 200 * 0.05 * (1/0.4 - 1/1.0) = 15 px of shadow left of the box
    row = out[30]
    assert np.all(row[86:99] == 0)
    assert np.all(row[60:84] > 0) and np.all(row[145:190] > 0)
    assert abs(int(row[120]) - 400) <= 1 and abs(int(row[60]) - 1000) <= 3
    # edge fattening grows the near box into the wall on its right
    fat = apply_stereo_noise(z, intr, np.random.default_rng(0),
                             StereoNoiseConfig(hole_rate=0.0, flying_rate=0.0, fatten_px=2,
                                               disparity_sd_px=0.0, white_sd_px=0.0))
    assert np.all(fat[:, 140] < 500)
    # noise grows with distance (disparity noise: sd_z ~ z^2)
    rng = np.random.default_rng(1)
    noisy = [apply_stereo_noise(np.full((60, 200), d), intr, rng,
                                StereoNoiseConfig(hole_rate=0.0)).astype(float)
             for d in (0.3, 0.9)]
    assert noisy[1][noisy[1] > 0].std() > 3 * noisy[0][noisy[0] > 0].std()


def test_motions_stay_inside_the_joint_limits() -> None:
    from hand_capture.evaldata.motion import random_motion
    from hand_capture.model import JOINT_LIMITS

    for seed, kind in ((0, "sine"), (1, "walk")):
        q = random_motion(np.random.default_rng(seed), 90, kind=kind)
        assert q.shape == (90, 27)
        assert np.all(q[:, 6:] >= JOINT_LIMITS[6:, 0] - 1e-9)
        assert np.all(q[:, 6:] <= JOINT_LIMITS[6:, 1] + 1e-9)
        assert np.ptp(q[:, 6:], axis=0).max() > 0.3      # the fingers move
        assert np.abs(np.diff(q[:, :3], axis=0)).max() < 0.02   # no jumps of the wrist


def test_bad_requests_are_refused() -> None:
    from hand_capture.evaldata import make_sequence
    from hand_capture.evaldata.stereo import StereoNoiseConfig

    with pytest.raises(ConfigError, match="d435_640"):
        make_sequence(0, 1, "kinect")
    with pytest.raises(ConfigError, match="baseline_m"):
        StereoNoiseConfig(baseline_m=0.0)
