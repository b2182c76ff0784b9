"""The calibration validation study (scripts/calibration_validation.py, issue #13; not
shipped): its forearm / sleeve subjects and its command line."""

from __future__ import annotations

import json

import numpy as np
import pytest
from script_helpers import load_script

from hand_capture.cameras.render import Mesh


@pytest.fixture(scope="module")
def cv():
    return load_script("calibration_validation")


def test_forearm_and_sleeve_keep_the_subjects_draws(cv):
    """A forearm (and a sleeve on odd subjects) is added from a generator of its own: the
    subject's shape, surface and noise generator are those without it."""
    q = np.zeros(27)
    q[2] = 0.42
    for i in (0, 1):
        true, variant, rng = cv.subject(i)
        plain = cv.subject_meshes(true, variant, i, False)
        arm = cv.subject_meshes(true, variant, i, True)
        sleeve = cv.subject_meshes(true, variant, i, True, ((0.01, 0.025), (0.04, 0.08)))
        assert (plain is None) == (variant is None)
        assert len(arm(q)) == 2 and all(isinstance(m, Mesh) for m in arm(q))
        assert len(sleeve(q)) == (3 if i % 2 else 2)      # sleeves on every second subject
        true2, variant2, rng2 = cv.subject(i)
        assert true2.shape == true.shape and variant2 == variant
        assert rng2.random() == rng.random()
    # the sleeve is wider than the arm it covers
    true, variant, _ = cv.subject(1)
    _, arm_mesh, sl = cv.subject_meshes(true, variant, 1, True, ((0.01, 0.025), (0.04, 0.08)))(q)
    kp = true.joint_positions(q)
    d = (kp[0] - kp[9]) / np.linalg.norm(kp[0] - kp[9])

    def radius(m: Mesh) -> float:
        v = m.vertices - kp[0]
        return float(np.max(np.linalg.norm(v - np.outer(v @ d, d), axis=1)))

    assert radius(sl) > radius(arm_mesh) + 0.009


def test_command_line_runs_and_rejects_unknown_keys(cv, capsys):
    assert cv.main(["-n", "1", "--forearm", "--sleeves", "-q"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["n"] == 1 and out["forearm"] is True and out["sleeves"]
    assert np.isfinite(out["mean"])
    assert cv.main(["-n", "1", "--set", "no_such_key=1"]) == 2
    assert "keys:" in capsys.readouterr().err
