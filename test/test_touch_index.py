"""The exact bounded nearest-neighbour search of the finger labelling (BoundedIndex)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from hand_capture.errors import InputError
from hand_capture.touch.labelling import BoundedIndex, _kmeans


def _clustered(rng: np.random.Generator, m: int = 1500, dim: int = 27) -> np.ndarray:
    centres = rng.normal(0.0, 2.0, (20, dim))
    return centres[rng.integers(20, size=m)] + rng.normal(0.0, 0.4, (m, dim))


@pytest.fixture(scope="module")
def ref() -> np.ndarray:
    return _clustered(np.random.default_rng(0))


@pytest.fixture(scope="module")
def index(ref) -> BoundedIndex:
    return BoundedIndex(ref, clusters=32)


def _exhaustive(ref: np.ndarray, x: np.ndarray) -> tuple[int, float]:
    d, _ = cKDTree(ref).query(x)
    return int(np.argmin(d)), float(d.min())


def test_best_is_the_exhaustive_argmin(ref, index):
    rng = np.random.default_rng(1)
    for trial in range(40):
        n = (3, 20, 120)[trial % 3]
        # candidates like the labelling's: one near the data, the rest scattered farther out
        x = ref[rng.integers(len(ref), size=n)] + rng.normal(0.0, 0.3 + trial * 0.05, (n, 27))
        k, d = index.best(x)
        k_ref, d_ref = _exhaustive(ref, x)
        assert k == k_ref
        assert d == pytest.approx(d_ref, rel=1e-12, abs=1e-12)


def test_best_exact_on_ties_and_near_ties(ref, index):
    rng = np.random.default_rng(2)
    x = ref[rng.integers(len(ref), size=120)] + rng.normal(0.0, 1.0, (120, 27))
    # a point on the reference (distance 0) wins; its duplicate later in the batch does not
    x[70] = ref[5]
    x[90] = ref[5]
    k, d = index.best(x)
    assert (k, d) == (70, 0.0)
    # two candidates 1e-9 apart in distance: far below float32 resolution, still exact
    direction = rng.normal(size=27)
    direction /= np.linalg.norm(direction)
    x[70] = ref[5] + 0.05 * direction
    x[90] = ref[9] + 0.05 * (1.0 - 1e-9) * direction
    k_ref, d_ref = _exhaustive(ref, x)
    assert k_ref == 90  # (the 0.05 ball around each point is empty of other points)
    assert index.best(x) == (90, pytest.approx(d_ref, rel=1e-12))


def test_best_far_away_and_large_candidates(ref, index):
    rng = np.random.default_rng(3)
    x = rng.normal(0.0, 1.0, (60, 27)) * 50.0 + 100.0
    k, d = index.best(x)
    assert (k, d) == (_exhaustive(ref, x)[0], pytest.approx(_exhaustive(ref, x)[1], rel=1e-12))


def test_distances_match_the_kd_tree(ref, index):
    x = np.random.default_rng(4).normal(0.0, 2.0, (30, 27))
    d, j = index.distances(x)
    d_ref, j_ref = cKDTree(ref).query(x)
    np.testing.assert_allclose(d, d_ref, rtol=1e-12)
    np.testing.assert_array_equal(j, j_ref)


def test_lower_bounds_hold(ref, index):
    x = np.random.default_rng(5).normal(0.0, 3.0, (200, 27))
    x_sq = np.einsum("ij,ij->i", x, x)
    assert (index.lower_bounds(x, x_sq) <= cKDTree(ref).query(x)[0]).all()


def test_kmeans_cells_and_radii(ref, index):
    centres, member = _kmeans(ref, 32, 12, seed=0)
    again = _kmeans(ref, 32, 12, seed=0)
    np.testing.assert_array_equal(centres, again[0])  # deterministic
    assert len(centres) <= 32 and set(np.unique(member)) == set(range(len(centres)))
    # every reference point lies within its cell's radius
    c2, m2 = _kmeans(index.points, 32, 12, seed=0)
    np.testing.assert_array_equal(c2, index.centres)
    assert (np.linalg.norm(index.points - c2[m2], axis=1) <= index.radii[m2] + 1e-12).all()
    # fewer distinct points than cells: duplicates collapse, nothing breaks
    few = np.repeat(ref[:3], 10, axis=0)
    small = BoundedIndex(few, clusters=16)
    assert len(small.centres) <= 3
    assert small.best(ref[:40])[0] in (0, 1, 2)


def test_rejects_bad_input(index):
    with pytest.raises(InputError):
        index.best(np.full((4, 27), np.nan))
    with pytest.raises(InputError):
        index.best(np.zeros((0, 27)))
    with pytest.raises(InputError):
        BoundedIndex(np.zeros((0, 27)))


def test_best_in_the_input_space_of_pca_ik():
    """The PCA-IK labelling searches the 15-D inputs u with the same index."""
    rng = np.random.default_rng(6)
    ref = _clustered(rng, m=800, dim=15)
    index = BoundedIndex(ref)
    for _ in range(10):
        x = ref[rng.integers(len(ref), size=60)] + rng.normal(0.0, 0.5, (60, 15))
        k, d = index.best(x)
        assert (k, d) == (_exhaustive(ref, x)[0], pytest.approx(_exhaustive(ref, x)[1]))
