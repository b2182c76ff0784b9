"""The forearm's hold on a hand moving along its axis (scripts/forearm_axis_lag.py, issue
#13; analysis, not shipped): a hand alone is followed, and the script's figures say so."""

from __future__ import annotations

import json

import numpy as np
from script_helpers import load_script


def test_a_hand_moving_along_its_axis_is_followed_without_a_forearm(capsys) -> None:
    fl = load_script("forearm_axis_lag")
    lag, err = fl.track_along_axis(fl.TrackerConfig(arm_classifier=False), 4, 0.008, 4,
                                   arm=False)
    assert lag.shape == err.shape == (4,)
    assert abs(lag[0]) < 1.0                         # started at the truth
    assert np.abs(lag).max() < 3.0, lag               # 24 mm of motion, followed
    assert fl.main(["--seeds", "4", "--frames", "3"]) == 0
    figures = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(figures) == {"lag_hand_mm", "error_hand_mm", "lag_arm_mm", "error_arm_mm"}
    assert abs(figures["lag_hand_mm"]) < 3.0
    assert fl.main(["--frames", "1"]) == 2
    assert fl.main(["--config", "no_such_field=1"]) == 2
