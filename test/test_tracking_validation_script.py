"""The tracker's validation study on more shapes (scripts/tracking_validation.py, issue #13;
not shipped): its per-sequence file, its paired comparison and its command line."""

from __future__ import annotations

import json

import pytest
from script_helpers import load_script


@pytest.fixture(scope="module")
def tv():
    return load_script("tracking_validation")


def test_one_shape_writes_its_sequences_and_compares_paired(tv, tmp_path, capsys):
    from hand_capture.bench import _tracking_heldout as th

    seeds = th.ARM_VAL_SEEDS
    out = tmp_path / "a.json"
    assert tv.main(["--shapes", "25", "25", "--sections", "surface", "--out", str(out)]) == 0
    assert th.ARM_VAL_SEEDS == seeds and th._score.__name__ == "_score"   # restored
    run = json.loads(out.read_text())
    assert run["shapes"] == [25]
    rows = run["sequences"]["surface"]
    assert len(rows) == 4 and all(0.0 < m < 100.0 and 0.0 <= s <= 1.0 for m, s in rows)
    assert run["figures"]["val_surface_mean_mm"] == pytest.approx(
        sum(m for m, _ in rows) / 4, abs=0.01)   # 20 frames each: the sequences' mean
    capsys.readouterr()
    # the same sequences against a run 1 mm worse on each: -1.00, all four better
    other = tmp_path / "b.json"
    other.write_text(json.dumps({**run, "sequences": {"surface": [[m + 1.0, s]
                                                                  for m, s in rows]}}))
    tv._paired(run["sequences"], json.loads(other.read_text())["sequences"])
    line = capsys.readouterr().out
    assert "difference -1.00 +- 0.00" in line and "better 4" in line and "worse 0" in line


def test_a_bad_override_is_refused(tv, capsys):
    assert tv.main(["--config", "no_such_key=1"]) == 2
    assert "valid keys" in capsys.readouterr().err


def test_the_stereo_forearm_family_is_the_scripts_alone(tv):
    """``stereo_forearm`` (the forearm family with a stereo camera's artifacts) is a choice
    of the script, not a bench section, and combines with no other camera or surface."""
    from hand_capture.bench import _tracking_heldout as th
    from hand_capture.errors import ConfigError
    from hand_capture.tracking.config import TrackerConfig

    assert "stereo_forearm" in tv.SECTIONS and "stereo_forearm" not in tv.BENCH_SECTIONS
    with pytest.raises(ConfigError, match="at most one"):
        th.forearm_validation_section(None, TrackerConfig(), False, far=True, stereo=True)
