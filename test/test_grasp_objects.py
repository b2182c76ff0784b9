"""Objects to grasp: signed distance fields against analytic distances, MuJoCo's geometry of
the same object, mass properties, and clear errors for bad meshes."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import trimesh

from hand_capture.model.mjcf import build_scene
from hand_control.errors import InputError
from hand_control.grasp.objects import make_object, object_from_mesh, parse_object


def _near_surface(rng: np.random.Generator, n: int, scale: float) -> np.ndarray:
    return rng.uniform(-scale, scale, (n, 3))


def test_sdf_of_a_sphere_matches_the_analytic_distance() -> None:
    r = 0.035
    o = make_object("sphere", (r,))
    p = _near_surface(np.random.default_rng(0), 4000, 0.06)
    d = np.linalg.norm(p, axis=1) - r
    near = np.abs(d) < 0.02
    err = np.abs(o.sdf(p) - d)
    assert err[near].max() < 1.2e-3  # within about half a 2 mm voxel near the surface
    assert np.all(np.sign(o.sdf(p)[np.abs(d) > 0.003]) == np.sign(d[np.abs(d) > 0.003]))


def test_sdf_of_a_box_and_a_cylinder_match_the_analytic_distances() -> None:
    rng = np.random.default_rng(1)
    h = np.array([0.03, 0.02, 0.04])
    box = make_object("box", tuple(h))
    p = _near_surface(rng, 4000, 0.06)
    q = np.abs(p) - h
    d = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)
    near = np.abs(d) < 0.015
    assert np.abs(box.sdf(p) - d)[near].max() < 1.2e-3
    cyl = make_object("cylinder", (0.03, 0.05))
    rr = np.linalg.norm(p[:, :2], axis=1)
    qc = np.stack([rr - 0.03, np.abs(p[:, 2]) - 0.05], axis=1)
    dc = np.linalg.norm(np.maximum(qc, 0), axis=1) + np.minimum(qc.max(axis=1), 0)
    near = np.abs(dc) < 0.015
    assert np.abs(cyl.sdf(p) - dc)[near].max() < 1.5e-3  # 40-gon vs circle: 0.1 mm more


def test_sdf_gradient_and_closest_points_lie_on_the_surface() -> None:
    o = make_object("sphere", (0.03,))
    p = np.array([[0.05, 0.0, 0.0], [0.0, -0.045, 0.01], [0.0, 0.0, 0.02]])
    surf, n, d = o.sdf.closest(p)
    assert np.allclose(np.linalg.norm(surf, axis=1), 0.03, atol=1e-3)
    assert np.allclose(n, surf / np.linalg.norm(surf, axis=1, keepdims=True), atol=0.03)
    assert np.allclose(n, p / np.linalg.norm(p, axis=1, keepdims=True), atol=0.1)
    assert d[2] < 0 < d[0]
    # beyond the grid the distance keeps growing
    assert o.sdf(np.array([1.0, 0.0, 0.0])) > 0.9


@pytest.mark.parametrize("kind", ["bottle", "composite", "convex", "mug"])
def test_mujoco_collides_with_the_surface_of_the_field(kind: str) -> None:
    o = make_object(kind, (3,) if kind in ("convex", "composite") else ())
    m = mujoco.MjModel.from_xml_string(build_scene([o.object_spec(xy=(0.2, 0.05))]))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, o.name)
    assert m.body_mass[body] == pytest.approx(o.mass, rel=1e-6)
    zs = np.linspace(0.25, -0.05, 3001)
    for off in [(0.0, 0.0), (0.01, 0.005), (-0.015, 0.0), (0.0, -0.02)]:
        gid = np.zeros(1, np.int32)
        dist = mujoco.mj_ray(m, d, np.array([0.2 + off[0], 0.05 + off[1], 0.5]),
                             np.array([0.0, 0.0, -1.0]), None, 1, -1, gid)
        pts = np.stack([np.full_like(zs, off[0]), np.full_like(zs, off[1]),
                        zs - (o.bottom + 1e-4)], axis=1)
        inside = o.sdf(pts) < 0
        hit = zs[np.argmax(inside)] if inside.any() else 0.0
        assert abs((0.5 - dist) - hit) < 1.5e-3, (off, 0.5 - dist, hit)


def test_mass_properties_are_those_of_the_mesh() -> None:
    o = make_object("box", (0.03, 0.02, 0.01), mass=0.5)
    assert o.mass == 0.5
    expect = 0.5 / 12 * np.array([0.04**2 + 0.02**2, 0.06**2 + 0.02**2, 0.06**2 + 0.04**2])
    assert np.allclose(np.diag(o.inertia), expect, rtol=1e-6)
    mug = make_object("mug", mass=0.3)
    assert mug.sdf(np.zeros(3)) > 0  # the centre of mass of a mug lies in its cavity
    ext = mug.mesh.bounds[1] - mug.mesh.bounds[0]
    assert ext[1] > ext[0] + 0.015  # the handle sticks out on +y


def test_mesh_files_load_and_bad_meshes_get_clear_errors(tmp_path) -> None:
    good = tmp_path / "ico.stl"
    trimesh.creation.icosphere(radius=0.03).export(good)
    o = object_from_mesh(good, mass=0.1)
    assert abs(o.sdf(np.array([0.05, 0.0, 0.0])) - 0.02) < 1.5e-3
    assert not o.hull_only
    # a non-convex mesh: its own surface for the field, MuJoCo gets its hull
    torus = tmp_path / "torus.obj"
    trimesh.creation.torus(major_radius=0.04, minor_radius=0.012).export(torus)
    t = object_from_mesh(torus)
    assert t.hull_only and t.sdf(np.zeros(3)) > 0.02  # the hole is outside
    # open (non-manifold) mesh
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    open_mesh = trimesh.Trimesh(box.vertices, box.faces[:-2], process=False)
    bad = tmp_path / "open.stl"
    open_mesh.export(bad)
    with pytest.raises(InputError, match="closed manifold"):
        object_from_mesh(bad)
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing\n")
    with pytest.raises(InputError, match="empty|cannot read"):
        object_from_mesh(empty)
    nan = tmp_path / "nan.obj"
    nan.write_text("v 0 0 0\nv 1 0 0\nv 0 nan 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\nf 1 4 2\nf 2 4 3\n")
    with pytest.raises(InputError, match="NaN"):
        object_from_mesh(nan)
    with pytest.raises(InputError, match="does not exist"):
        object_from_mesh(tmp_path / "missing.stl")


def test_object_specs_parse_or_name_what_is_wrong() -> None:
    assert parse_object("box:0.02,0.03,0.04").half_extents == pytest.approx((0.02, 0.03, 0.04))
    with pytest.raises(InputError, match="unknown object kind"):
        parse_object("teapot")
    with pytest.raises(InputError, match="takes 3 sizes"):
        parse_object("box:0.02")
    with pytest.raises(InputError, match="positive"):
        parse_object("sphere:-0.1")
    with pytest.raises(InputError, match="numbers"):
        parse_object("sphere:abc")
