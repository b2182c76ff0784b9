"""The tube training surface (hand_capture.tracking.tubes, issue 13): a hand of another shape
than the template, on the same skeleton, that the regressor's training may draw."""

from __future__ import annotations

import numpy as np

from hand_capture.cameras.render import Mesh, make_renderer
from hand_capture.model import HandModel
from hand_capture.tracking.train import default_intrinsics, random_pose, render_samples
from hand_capture.tracking.tubes import TubeSurface, tube_mesh


def _depth(meshes: list[Mesh]) -> np.ndarray:
    return make_renderer("zbuffer").render(meshes, default_intrinsics()).depth


def test_tube_hand_covers_the_template_silhouette_with_another_surface() -> None:
    rng = np.random.default_rng(4)
    m = HandModel()
    ious, diffs = [], []
    for _ in range(6):
        q = random_pose(rng, m)
        a = _depth([Mesh(m.vertices(q), m.faces, 1, closed=True)])
        b = _depth([tube_mesh(m, q, TubeSurface.sample(rng))])
        sa, sb = a > 0, b > 0
        ious.append((sa & sb).sum() / (sa | sb).sum())
        both = sa & sb
        diffs.append(np.median(np.abs(a[both].astype(float) - b[both])))
    # the same hand in the same place ...
    assert min(ious) > 0.6
    # ... but not the same surface: the depths differ by millimetres where both are seen
    assert np.mean(diffs) > 1e-3   # [m]


def test_tube_hand_follows_the_skeleton_and_its_parameters() -> None:
    m = HandModel()
    q = np.zeros(27)
    q[2] = 0.4
    kp = m.joint_positions(q)
    base = dict(finger_scale=np.ones(5), flatness=np.ones(5), knuckle=0.0, palm_mm=28.0,
                wrist_mm=56.0, thenar=8.0)
    short = tube_mesh(m, q, TubeSurface(tip_out=0.2, stub_mm=0.0, **base)).vertices
    long_ = tube_mesh(m, q, TubeSurface(tip_out=1.0, stub_mm=40.0, **base)).vertices
    assert np.isfinite(long_).all()
    tip_dir = (kp[12] - kp[11]) / np.linalg.norm(kp[12] - kp[11])
    # the middle finger's tip ends past its keypoint by tip_out of its radius (7.75 mm)
    reach = [float(((V - kp[12]) @ tip_dir).max()) for V in (short, long_)]
    assert abs(reach[0] - 0.2 * 7.75e-3) < 1.5e-3
    assert abs(reach[1] - 7.75e-3) < 1.5e-3
    # the stub reaches 40 mm past the wrist; without it the hand ends near the wrist
    back = (kp[0] - kp[9]) / np.linalg.norm(kp[0] - kp[9])
    assert ((long_ - kp[0]) @ back).max() > 0.035
    assert ((short - kp[0]) @ back).max() < 0.02


def test_training_renders_draw_tube_hands_on_request() -> None:
    m = HandModel()
    intr = default_intrinsics()
    one = render_samples(3, np.random.default_rng(2), [m], intr, tube_prob=1.0)
    none = render_samples(3, np.random.default_rng(2), [m], intr, tube_prob=0.0)
    assert len(one) == len(none) == 3
    # the same first pose, drawn with the other surface
    np.testing.assert_array_equal(one[0].pose, none[0].pose)
    assert one[0].crop.shape != none[0].crop.shape or \
        not np.array_equal(one[0].crop, none[0].crop)
