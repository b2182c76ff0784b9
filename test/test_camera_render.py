"""CPU renderers: agreement with each other and with the geometry they draw (no ROS)."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.cameras.base import Intrinsics
from hand_capture.cameras.primitives import box, cylinder, make_primitive, plane, sphere
from hand_capture.cameras.render import (
    Mesh,
    NaiveRenderer,
    RaycastRenderer,
    ZBufferRenderer,
    make_renderer,
)
from hand_capture.errors import ConfigError, InputError

INTR = Intrinsics(160, 120, 112.0, 112.0, 79.5, 59.5)


def _scene() -> list[Mesh]:
    Vs, Fs = sphere(0.05)
    Vb, Fb = box([0.06, 0.04, 0.02])
    Vp, Fp = plane([0.6, 0.6])
    return [Mesh(Vs + [0.0, 0.0, 0.45], Fs, 1, closed=True),
            Mesh(Vb + [0.03, 0.02, 0.38], Fb, 2, closed=True),  # partly in front of the ball
            Mesh(Vp + [0.0, 0.0, 0.6], Fp, 3)]                   # open wall behind


def test_renderers_agree_on_a_scene_with_occlusion():
    meshes = _scene()
    ref = ZBufferRenderer(cull_backfaces=False).render(meshes, INTR)
    for r in (ZBufferRenderer(), RaycastRenderer(), NaiveRenderer()):
        with np.errstate(all="ignore"):
            out = r.render(meshes, INTR)
        assert np.array_equal(out.hit, ref.hit), r.name
        assert np.array_equal(out.label, ref.label), r.name
        assert np.abs(out.depth - ref.depth).max() < 1e-5, r.name
        assert np.abs(out.cos_incidence - ref.cos_incidence).max() < 1e-5, r.name
    # the box occludes part of the ball, the wall fills the rest of the view
    assert {0, 1, 2, 3} >= set(np.unique(ref.label)) >= {1, 2, 3}
    assert ref.depth[ref.label == 2].max() < ref.depth[ref.label == 1].min() + 0.02


def test_depth_matches_the_analytic_plane_and_sphere():
    Vp, Fp = plane([2.0, 2.0])
    out = ZBufferRenderer().render([Mesh(Vp + [0, 0, 0.7], Fp)], INTR)
    assert out.hit.all()
    assert np.allclose(out.depth, 0.7, atol=1e-6)
    assert np.allclose(out.cos_incidence[INTR.height // 2, INTR.width // 2], 1.0, atol=1e-3)
    # ray through the principal point hits the sphere's front pole
    V, F = sphere(0.1, n_lat=64, n_lon=96)
    out = ZBufferRenderer().render([Mesh(V + [0, 0, 1.0], F, closed=True)], INTR)
    i, j = round(INTR.cy), round(INTR.cx)
    assert out.depth[i, j] == pytest.approx(0.9, abs=1e-3)


def test_depth_at_projected_visible_vertices_equals_their_depth():
    V, F = sphere(0.08, n_lat=32, n_lon=48)
    mesh = Mesh(V + [0.01, -0.02, 0.5], F, closed=True)
    out = ZBufferRenderer().render([mesh], INTR)
    uv = INTR.project(mesh.vertices)
    ij = np.rint(uv[:, ::-1]).astype(int)
    inside = (ij[:, 0] >= 0) & (ij[:, 0] < INTR.height) & (ij[:, 1] >= 0) & \
        (ij[:, 1] < INTR.width)
    d = out.depth[ij[inside, 0], ij[inside, 1]]
    z = mesh.vertices[inside, 2]
    visible = np.abs(d - z) < 0.01  # the others are behind the front surface
    assert visible.sum() > 300
    # a vertex projects within half a pixel of a sample, so depth differs by at most the
    # surface slope over half a pixel (a few mm at 0.5 m)
    assert np.median(np.abs(d[visible] - z[visible])) < 1e-3


def test_backface_culling_only_for_closed_meshes():
    V, F = sphere(0.05)
    m_closed = Mesh(V + [0, 0, 0.4], F, closed=True)
    a = ZBufferRenderer(cull_backfaces=True).render([m_closed], INTR)
    b = ZBufferRenderer(cull_backfaces=False).render([m_closed], INTR)
    assert np.array_equal(a.depth, b.depth)
    # an open plane seen from behind is still drawn (two-sided)
    Vp, Fp = plane([0.5, 0.5])
    flipped = Mesh(Vp + [0, 0, 0.5], Fp[:, ::-1])
    assert ZBufferRenderer().render([flipped], INTR).hit.any()


def test_faces_behind_the_near_plane_or_camera_are_skipped():
    V, F = box([0.1, 0.1, 0.1])
    out = ZBufferRenderer().render([Mesh(V + [0, 0, -0.5], F, closed=True)], INTR)
    assert not out.hit.any()
    out = ZBufferRenderer().render([], INTR)
    assert out.depth.shape == (INTR.height, INTR.width) and not out.hit.any()


def test_mesh_validation_and_renderer_names():
    with pytest.raises(InputError):
        Mesh(np.zeros((3, 2)), np.zeros((1, 3), int))
    with pytest.raises(InputError):
        Mesh(np.zeros((3, 3)), np.array([[0, 1, 3]]))
    with pytest.raises(InputError):
        Mesh(np.full((3, 3), np.nan), np.array([[0, 1, 2]]))
    with pytest.raises(ConfigError, match="valid"):
        make_renderer("opengl")
    with pytest.raises(ConfigError):
        make_primitive("torus", [1.0])
    with pytest.raises(ConfigError):
        make_primitive("sphere", [-1.0])


def test_primitives_are_closed_and_outward():
    for V, F in (box([0.1, 0.2, 0.3]), sphere(0.1), cylinder(0.05, 0.1)):
        # every edge shared by exactly two faces, in opposite directions
        e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
        assert len({tuple(x) for x in e}) == len(e)
        assert {tuple(x) for x in e} == {tuple(x) for x in e[:, ::-1]}
        # outward: signed volume positive
        a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
        assert np.einsum("ij,ij->i", a, np.cross(b, c)).sum() > 0


def test_huge_faces_are_rasterised_in_tiles():
    intr = Intrinsics(1280, 720, 900.0, 900.0, 639.5, 359.5)
    V, F = plane([4.0, 3.0], n=1)  # two triangles covering the whole image
    R = np.array([[1, 0, 0], [0, np.cos(0.3), -np.sin(0.3)], [0, np.sin(0.3), np.cos(0.3)]])
    mesh = Mesh(V @ R.T + [0, 0, 1.5], F)
    a = ZBufferRenderer().render([mesh], intr)
    b = RaycastRenderer().render([mesh], intr)
    assert a.hit.all() and np.array_equal(a.hit, b.hit)
    assert np.abs(a.depth - b.depth).max() < 1e-5


def test_zbuffer_equals_the_naive_loop_on_the_hand():
    """The hand's thousands of pixel-sized faces (each face's box enumerated exactly): the
    same faces and depths as the per-triangle loop, pixel for pixel, with and without
    back-face culling, in a closing fist (fingers in front of the palm)."""
    from hand_capture.cameras.synthetic import SyntheticCamera, SyntheticCameraConfig

    cam = SyntheticCamera(SyntheticCameraConfig(clip="fist", width=160, height=120))
    cam.open()
    meshes, _ = cam.scene_meshes(1.0, cam.truth_pose(1.0))
    intr = cam.intrinsics
    b = NaiveRenderer().render(meshes, intr)
    assert b.hit.sum() > 500
    for cull in (True, False):
        a = ZBufferRenderer(cull_backfaces=cull).render(meshes, intr)
        assert np.array_equal(a.hit, b.hit) and np.array_equal(a.label, b.label)
        assert np.abs(a.depth - b.depth).max() < 2e-6  # the key's 1 um depth quantum
        assert (a.face == b.face).mean() > 0.99  # equal depths may keep either face
