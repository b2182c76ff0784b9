"""Smoke test of the held-out sections of ``hand-suite bench tracking`` (issue 13): they run
on a sliver of the data and report figures in their ranges."""

from __future__ import annotations

import math

import numpy as np

from hand_capture.bench._tracking_heldout import (
    TEMPORAL_GRID,
    calibration_section,
    heldout_section,
)
from hand_capture.tracking import HandRegressor, TrackerConfig
from hand_capture.tracking.hybrid import default_model_path


def test_heldout_and_calibration_sections_report_their_figures(capsys) -> None:
    reg = HandRegressor.load(default_model_path())
    out = heldout_section(reg, TrackerConfig(), True, cases=(("d435_848", True, 7),),
                          frames=(3, 5))
    for key in ("heldout", "forearm"):
        assert out[f"{key}_frames"] == 3
        assert math.isfinite(out[f"{key}_mean_mm"]) and out[f"{key}_mean_mm"] > 0
        assert 0.0 <= out[f"{key}_success_20mm"] <= 1.0
    cal = calibration_section(True, scales=(0.9,))
    assert cal["calib_scales"] == [0.9]
    assert cal["calib_bone_err_pct"] >= cal["calib_bone_err_pct_mean"] > 0
    # a 0.9-scale hand: the template's bones are about 10 % off (the baseline row)
    assert cal["calib_bone_err_pct_template"] > 5.0
    text = capsys.readouterr().out
    assert "held-out family" in text and "d435_848" in text and "bone-length" in text
    assert TEMPORAL_GRID[0] == 0.0 and np.all(np.diff(TEMPORAL_GRID) > 0)
