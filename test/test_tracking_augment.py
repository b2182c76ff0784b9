"""Stereo camera artifacts on the tracker's training renders (hand_capture.tracking.augment,
issue 13): each artifact does what the module says, at the strength asked for, and bad
settings or images are refused."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.errors import ConfigError, InputError
from hand_capture.tracking.augment import ArtifactConfig, add_artifacts

NONE = ArtifactConfig(fatten_px=(0, 0), shadow_px=(0, 0), hole_share=(0.0, 0.0),
                      wave_sd_mm=(0.0, 0.0))


def _scene() -> np.ndarray:
    """A wall at 0.6 m with a box at 0.4 m in front of it, empty above (H 60, W 80) [m]."""
    d = np.zeros((60, 80), np.float32)
    d[20:, :] = 0.6
    d[30:50, 30:50] = 0.4
    return d


def test_no_artifacts_leave_the_image_as_it_was() -> None:
    d = _scene()
    out = add_artifacts(d, np.random.default_rng(0), NONE)
    assert np.array_equal(out, d) and out is not d


@pytest.mark.parametrize("k", [1, 2])
def test_edge_fattening_grows_the_nearer_side_by_k_pixels(k: int) -> None:
    d = _scene()
    cfg = ArtifactConfig(fatten_px=(k, k), shadow_px=(0, 0), hole_share=(0.0, 0.0),
                         wave_sd_mm=(0.0, 0.0))
    out = add_artifacts(d, np.random.default_rng(0), cfg)
    box = out == np.float32(0.4)
    rows, cols = np.nonzero(box)
    assert (rows.min(), rows.max(), cols.min(), cols.max()) == (30 - k, 49 + k, 30 - k, 49 + k)
    # the wall grows into the empty rows above it; nothing else changes
    assert np.all(out[20 - k:20, :] == np.float32(0.6)) and np.all(out[:20 - k] == 0)
    far = ~box & (d > 0)
    assert np.array_equal(out[far], d[far])


def test_the_occlusion_band_lies_beside_the_nearer_surface_on_one_side() -> None:
    d = _scene()
    cfg = ArtifactConfig(fatten_px=(0, 0), shadow_px=(3, 3), hole_share=(0.0, 0.0),
                         wave_sd_mm=(0.0, 0.0))
    sides = set()
    for seed in range(8):
        out = add_artifacts(d, np.random.default_rng(seed), cfg)
        lost = (d > 0) & (out == 0)
        rows, cols = np.nonzero(lost)
        assert set(rows) == set(range(30, 50))          # beside the box only
        assert lost.sum() == 3 * 20                     # 3 px of the wall
        assert cols.max() < 30 or cols.min() > 49       # on one side of it
        sides.add("left" if cols.max() < 30 else "right")
        assert np.all(out[30:50, 30:50] == np.float32(0.4))
    assert sides == {"left", "right"}


def test_holes_cover_about_the_share_asked_for() -> None:
    d = _scene()
    cfg = ArtifactConfig(fatten_px=(0, 0), shadow_px=(0, 0), hole_share=(0.05, 0.05),
                         hole_radius_px=(2.0, 2.0), wave_sd_mm=(0.0, 0.0))
    out = add_artifacts(d, np.random.default_rng(3), cfg)
    lost = ((d > 0) & (out == 0)).sum() / (d > 0).sum()
    assert 0.02 < lost < 0.06                      # blobs overlap and run off the edges
    assert np.array_equal(out[out > 0], d[out > 0])


def test_the_correlated_error_is_smooth_and_grows_with_distance() -> None:
    d = _scene()
    cfg = ArtifactConfig(fatten_px=(0, 0), shadow_px=(0, 0), hole_share=(0.0, 0.0),
                         wave_sd_mm=(2.0, 2.0), wave_px=(6.0, 6.0))
    out = add_artifacts(d, np.random.default_rng(5), cfg)
    err = (out - d) * 1e3                          # [mm]
    wall = err[20:30, :]                           # 0.6 m: 2 mm x (0.6 / 0.4)^2 = 4.5 mm
    assert 2.0 < wall.std() < 7.0
    # neighbours agree far more than for white noise
    assert np.abs(np.diff(wall, axis=1)).mean() < 0.3 * wall.std()
    assert np.all(out[d == 0] == 0)


def test_bad_settings_and_images_are_refused() -> None:
    with pytest.raises(ConfigError, match="lo <= hi"):
        ArtifactConfig(fatten_px=(2, 1))
    with pytest.raises(ConfigError):
        ArtifactConfig(hole_share=(0.0, 0.9))
    bad = _scene()
    bad[0, 0] = np.nan
    with pytest.raises(InputError):
        add_artifacts(bad, np.random.default_rng(0))
    with pytest.raises(InputError):
        add_artifacts(np.zeros(5, np.float32), np.random.default_rng(0))
