"""The held-out family on more subjects (scripts/heldout_more_subjects.py, issue #13;
reporting only): its command line refuses bad requests before tracking anything, and one
sequence is tracked as the bench's held-out section tracks it."""

from __future__ import annotations

import numpy as np
import pytest
from script_helpers import load_script


@pytest.fixture(scope="module")
def hm():
    return load_script("heldout_more_subjects")


def test_bad_requests_are_refused(hm, capsys):
    assert hm.main(["--config", "no_such_key=1"]) == 2
    assert "valid keys" in capsys.readouterr().err
    assert hm.main(["--subjects", "0"]) == 2
    assert hm.main(["--jobs", "0"]) == 2


def test_offset_zero_is_the_benchs_sequence(hm):
    # the bench's held-out section on its first case, 4 frames, and the script's job for
    # the same case at offset 0 score the same frames the same way (one code path)
    from hand_capture.bench import _tracking_heldout as th
    from hand_capture.model import HandModel
    from hand_capture.tracking.config import TrackerConfig
    from hand_capture.tracking.hybrid import HybridTracker, load_regressor

    k, offset, arm, e = hm._track((0, 0, False, TrackerConfig(), 4))
    assert (k, offset, arm) == (0, 0, False) and e.shape == (4, 21)
    cam, clutter, seed = th.HELDOUT[0]
    seq, _, cal = th.heldout_case(0, cam, clutter, seed, False, 4, 1)
    # the product's regressors, as the bench loads them (with ensemble: both)
    tr = HybridTracker(HandModel(), TrackerConfig(), load_regressor(TrackerConfig()))
    tr.set_calibration(cal)
    np.testing.assert_array_equal(e, th._score(tr, seq.frames, seq.keypoints)["errs"])
    # another offset: another subject
    assert not np.array_equal(e, hm._track((0, 1000, False, TrackerConfig(), 4))[3])
