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


def test_spread_fingers_spreads_open_fingers_and_leaves_curled_ones():
    """The spread validation motions (``spread_fingers``): open fingers' tips move away from
    the middle fingertip, within the joint limits; a finger curled at 1.2 rad of MCP
    flexion keeps its abduction; no spread leaves the pose as it is."""
    import numpy as np

    from hand_capture.bench._tracking_heldout import spread_fingers
    from hand_capture.model import JOINT_INDEX, JOINT_LIMITS, HandModel

    m = HandModel()
    q = np.zeros(27)
    q[JOINT_INDEX["little_mcp_flex"]] = 1.2
    s = spread_fingers(q, 15.0)
    assert np.array_equal(spread_fingers(q, 0.0), q)
    kp0, kp = m.joint_positions(q), m.joint_positions(s)
    for tip in (8, 16):   # index, ring: farther from the middle fingertip (12)
        assert (np.linalg.norm(kp[tip] - kp[12]) - np.linalg.norm(kp0[tip] - kp0[12])) > 0.01
    assert s[JOINT_INDEX["little_mcp_abd"]] == 0.0
    assert np.all(s >= JOINT_LIMITS[:, 0]) and np.all(s <= JOINT_LIMITS[:, 1])
    wide = spread_fingers(np.zeros(27), 40.0)   # clipped into the limits
    assert wide[JOINT_INDEX["ring_mcp_abd"]] == JOINT_LIMITS[JOINT_INDEX["ring_mcp_abd"], 0]


def test_the_spread_family_is_the_scripts_alone(tv, monkeypatch):
    """``spread`` (the surface and capsule families with the fingers spread) is a choice of
    the script, not a bench section; it renders its sequences with a spread."""
    from hand_capture.bench import _tracking_heldout as th

    assert "spread" in tv.SECTIONS and "spread" not in tv.BENCH_SECTIONS
    spreads = []

    def fake_sequence(seed, clip, n, step, surface, spread_deg=0.0):
        spreads.append(spread_deg)
        raise RuntimeError("stop")

    monkeypatch.setattr(th, "suite_surface_sequence", fake_sequence)
    with pytest.raises(RuntimeError, match="stop"):
        tv._spread_section(None, None)
    assert len(spreads) == 1 and 8.0 <= spreads[0] <= 20.0


def test_the_tube_families_draw_a_tube_hand_per_sequence(tv, monkeypatch):
    """``tube`` / ``tube_forearm`` (the hand drawn as a swept-tube surface) are choices of the
    script, not bench sections; each sequence gets its own tube hand, posed with the
    skeleton (its fingertip reaches the tip keypoint), and the forearm family passes it to
    the forearm renderer."""
    import numpy as np

    from hand_capture.bench import _tracking_heldout as th
    from hand_capture.model import HandModel

    for name in ("tube", "tube_forearm"):
        assert name in tv.SECTIONS and name not in tv.BENCH_SECTIONS
    m = HandModel()
    q = np.zeros(27)
    hands = []

    def fake_forearm(seed, clip, n, step, surface=None, **kw):
        hands.append(surface)
        if len(hands) == 2:
            raise RuntimeError("stop")
        return None, None, [], [], []

    monkeypatch.setattr(th, "suite_forearm_sequence", fake_forearm)
    monkeypatch.setattr(th, "_suite_calibration", lambda *a, **k: None)
    monkeypatch.setattr(th, "with_artifacts", lambda frames, seed: frames)
    monkeypatch.setattr(th, "_score", lambda *a, **k: {"errs": np.zeros((0, 21))})

    class Tracker:   # tracks nothing: the renderer is faked above
        def __init__(self, *a) -> None:
            pass

        def set_calibration(self, cal) -> None:
            pass

    from hand_capture.tracking import hybrid
    monkeypatch.setattr(hybrid, "HybridTracker", Tracker)
    with pytest.raises(RuntimeError, match="stop"):
        tv._tube_section(None, None, forearm=True)
    assert all(isinstance(h, tv.TubeHand) for h in hands)
    assert hands[0].surface.palm_mm != hands[1].surface.palm_mm   # the next sequence: another hand
    mesh = hands[0].mesh_fn(m)(q)
    tip = m.joint_positions(q)[8]                    # the index fingertip keypoint
    assert np.min(np.linalg.norm(mesh.vertices - tip, axis=1)) < 0.012
    assert len(mesh.vertices) != len(m.vertices(q))  # not the template's mesh


def test_the_moving_tube_family_moves_the_wrist(tv, monkeypatch):
    """``tube_moving`` (a script section, not the bench's) is ``tube`` with the wrist on a
    smooth path: it starts where the clip's wrist is and moves a few millimetres a 30 fps
    frame, where the suite's clips hold it still."""
    import numpy as np

    from hand_capture.bench import _tracking_heldout as th

    assert "tube_moving" in tv.SECTIONS and "tube_moving" not in tv.BENCH_SECTIONS
    path = th.moving_wrist_path(np.random.default_rng(0), 60, 1)
    assert path.shape == (60, 3) and np.all(path[0] == 0.0)
    speed = np.linalg.norm(np.diff(path, axis=0), axis=1).mean() * 1e3   # [mm a frame]
    assert 1.5 < speed < 8.0, speed
    paths = []

    def fake_sequence(seed, clip, n, step, hand, wrist_path=None, **kw):
        paths.append(wrist_path)
        raise RuntimeError("stop")

    monkeypatch.setattr(th, "suite_surface_sequence", fake_sequence)
    for moving in (False, True):
        with pytest.raises(RuntimeError, match="stop"):
            tv._tube_section(None, None, forearm=False, moving=moving)
    assert paths[0] is None and paths[1].shape == (20, 3)
    assert np.abs(paths[1]).max() > 0.01                  # the wrist leaves its start


def test_the_moving_forearm_family_moves_the_hand_and_its_forearm(tv, monkeypatch):
    """``tube_moving_forearm`` passes the section's wrist path to the forearm sequence, and
    that sequence moves the hand's keypoints by the path with the forearm following (the
    arm's pixels move too), frame by frame."""
    import numpy as np

    from hand_capture.bench import _tracking_heldout as th

    assert "tube_moving_forearm" in tv.SECTIONS
    assert "tube_moving_forearm" not in tv.BENCH_SECTIONS
    path = np.array([[0.0, 0.0, 0.0], [0.03, 0.0, 0.0], [0.0, 0.025, 0.01]])
    _, _, _, still, still_lab = th.suite_forearm_sequence(25, "fist", 3, 2)
    _, _, _, moved, moved_lab = th.suite_forearm_sequence(25, "fist", 3, 2, wrist_path=path)
    for k in range(3):
        np.testing.assert_allclose(moved[k] - still[k], np.broadcast_to(path[k], (21, 3)),
                                   atol=1e-9)
    assert np.array_equal(still_lab[0], moved_lab[0])      # the path starts at zero
    cols = [np.nonzero(lab == 2)[1].mean() for lab in (still_lab[1], moved_lab[1])]
    assert cols[1] - cols[0] > 5.0                          # the arm moved right with it [px]
    paths = []

    def fake_forearm(seed, clip, n, step, wrist_path=None, **kw):
        paths.append(wrist_path)
        raise RuntimeError("stop")

    monkeypatch.setattr(th, "suite_forearm_sequence", fake_forearm)
    for section in ("tube_forearm", "tube_moving_forearm"):
        with pytest.raises(RuntimeError, match="stop"):
            tv._run(section, None, None)
    assert paths[0] is None and paths[1].shape == (20, 3)


def test_the_moving_sleeve_family_puts_a_sleeve_on_the_moving_forearm(tv, monkeypatch):
    """``tube_moving_sleeve`` is ``tube_moving_forearm`` with the suite's sleeve: the section
    asks the forearm sequence for the wrist path and the sleeve, and a sleeved arm shows
    more arm pixels (the sleeve is wider than the arm) where the hand is the same."""
    import numpy as np

    from hand_capture.bench import _tracking_heldout as th

    assert "tube_moving_sleeve" in tv.SECTIONS
    assert "tube_moving_sleeve" not in tv.BENCH_SECTIONS
    _, _, _, bare_kp, bare = th.suite_forearm_sequence(25, "fist", 1, 2)
    _, _, _, sleeve_kp, sleeved = th.suite_forearm_sequence(25, "fist", 1, 2, sleeve=True)
    np.testing.assert_array_equal(bare_kp[0], sleeve_kp[0])
    assert np.count_nonzero(sleeved[0] == 2) > np.count_nonzero(bare[0] == 2)
    calls = []

    def fake_forearm(seed, clip, n, step, wrist_path=None, sleeve=False, **kw):
        calls.append((wrist_path, sleeve))
        raise RuntimeError("stop")

    monkeypatch.setattr(th, "suite_forearm_sequence", fake_forearm)
    for section in ("tube_moving_forearm", "tube_moving_sleeve"):
        with pytest.raises(RuntimeError, match="stop"):
            tv._run(section, None, None)
    assert [s for _, s in calls] == [False, True]
    assert all(p is not None and p.shape == (20, 3) for p, _ in calls)
