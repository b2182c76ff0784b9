"""The generated template mesh: closed, outward, smooth skinning weights, shape fields."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.model import BONE_NAMES, HandModel, sample_shape
from hand_capture.model.mesh import (
    MAX_INFLUENCES,
    is_closed_manifold,
    template_mesh,
    vertex_adjacency,
)
from hand_capture.model.skeleton import template_skeleton


@pytest.fixture(scope="module")
def right() -> HandModel:
    return HandModel()


def _signed_volume(v: np.ndarray, f: np.ndarray) -> float:
    return float(np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6)


def test_size_and_topology(right: HandModel) -> None:
    v, f = right.rest_vertices, right.faces
    assert 2000 <= len(v) <= 4000
    assert f.dtype == np.int32 and f.min() == 0 and f.max() == len(v) - 1
    assert is_closed_manifold(f)
    # Euler characteristic of a sphere-like closed surface
    n_edges = len(f) * 3 // 2
    assert len(v) - n_edges + len(f) == 2
    # adult hand volume (~350-450 cm^3), positive = outward orientation
    assert 300e-6 < _signed_volume(v, f) < 500e-6
    area = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1) / 2
    assert area.min() > 1e-9  # no degenerate triangles


def test_normals_point_outward(right: HandModel) -> None:
    tm = template_mesh("right")
    sk = template_skeleton("right")
    rot, pos = sk.rest_world
    # direction from the nearest point on the vertex's main bone axis to the vertex
    b = right.vertex_labels
    axis = rot[b][:, :, 0]
    rel = tm.vertices - pos[b]
    along = np.clip(np.einsum("ij,ij->i", rel, axis), 0, sk.length[b])
    out = rel - along[:, None] * axis
    fingers = b > 0
    cos = np.einsum("ij,ij->i", out[fingers], tm.normals[fingers]) / np.linalg.norm(
        out[fingers], axis=1)
    assert np.mean(cos > 0) > 0.97
    n = right.normals(right.rest_vertices)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)
    np.testing.assert_allclose(n, tm.normals, atol=1e-9)


def test_skinning_weights(right: HandModel) -> None:
    w = right.skinning_weights
    assert w.shape == (right.n_vertices, len(BONE_NAMES))
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
    assert w.min() >= 0.0
    assert np.all((w > 0).sum(axis=1) <= MAX_INFLUENCES)
    assert set(np.unique(right.vertex_labels)) == set(range(len(BONE_NAMES)))
    # smooth: neighbouring vertices have similar weights, and some vertices blend
    adj = vertex_adjacency(right.n_vertices, right.faces).tocoo()
    jump = np.abs(w[adj.row] - w[adj.col]).max(axis=1)
    assert np.percentile(jump, 99) < 0.35
    assert np.mean(w.max(axis=1) < 0.9) > 0.1


def test_left_mesh_is_the_mirror_image() -> None:
    r, lf = template_mesh("right"), template_mesh("left")
    np.testing.assert_allclose(lf.vertices, r.vertices * [1, -1, 1])
    np.testing.assert_allclose(lf.normals, r.normals * [1, -1, 1])
    assert _signed_volume(lf.vertices, lf.faces) > 0
    assert is_closed_manifold(lf.faces)
    np.testing.assert_array_equal(lf.weights, r.weights)


def test_vertex_offsets_thicken_the_hand(right: HandModel) -> None:
    thick = right.with_shape(sample_shape(0).with_params(global_scale=1.0, alpha=np.zeros(6),
                                                         beta=np.full(5, 0.002)))
    v0 = right.rest_vertices
    v1 = thick.rest_vertices
    disp = np.einsum("ij,ij->i", v1 - v0, template_mesh("right").normals)
    assert disp.min() >= -1e-9 and disp.max() <= 0.002 * 5 + 1e-9
    assert _signed_volume(v1, right.faces) > _signed_volume(v0, right.faces) * 1.05
