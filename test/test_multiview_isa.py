"""Seed 000's image terms (eq. 4-7), ISA, the first-frame initialisation (visual hull + ICP)
and the learned fingertip detector (seed 002 sec. 4.1)."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.errors import InputError
from hand_capture.model import HandModel
from hand_capture.model.joints import JOINT_NAMES, root_rotation_matrix
from hand_capture.model.mjcf import home_pose
from hand_capture.multiview.imageterms import (
    SGMM,
    ColourModel,
    ImageCost,
    ImageTermsConfig,
    observe,
    silhouette_term,
)
from hand_capture.multiview.isa import ISAConfig, isa_minimise, isa_track
from hand_capture.multiview.rig import ring_rig


# ------------------------------------------------------------------ studio fixture
@pytest.fixture(scope="module")
def scene_views():
    """One hand + a box, 4 cameras at 320x240, clean and noisy colour, and the truth."""
    from hand_capture.multiview.scene_model import SceneModel, object_mesh
    from hand_capture.multiview.studio import Studio, StudioNoise, studio_scene

    rig = ring_rig("t4", 4, width=320, height=240)
    q = home_pose()
    q[5] += 0.4
    with Studio(rig, studio_scene(["box"]), StudioNoise(seed=2)) as st:
        st.set_state(q)
        views = st.render_all()
        box = st.object_pose("box")
    scene = SceneModel([HandModel()], [object_mesh("box")])
    truth = scene.pack([q], [box])
    return rig, scene, views, truth


def _perturbations(truth: np.ndarray) -> list[np.ndarray]:
    out = []
    for j, d in ((0, 0.012), (1, -0.012), (5, 0.15), (JOINT_NAMES.index("index_mcp_flex"), 0.6),
                 (JOINT_NAMES.index("thumb_tm_flex"), 0.5)):
        p = truth.copy()
        p[j] += d
        out.append(p)
    return out


# ------------------------------------------------------------------ eq. (4), (5)
def test_silhouette_term_known_answers():
    o = np.zeros((10, 10), bool)
    o[2:6, 2:6] = True                       # 16 px
    assert silhouette_term(o, o) == pytest.approx(0.0, abs=1e-6)
    far = np.zeros_like(o)
    far[7:9, 7:9] = True
    assert silhouette_term(far, o) == pytest.approx(2.0, abs=1e-6)
    half = np.zeros_like(o)
    half[2:6, 4:8] = True                    # 8 of its 16 px overlap
    assert silhouette_term(half, o) == pytest.approx(0.5 + 0.5, abs=1e-6)
    batch = silhouette_term(np.stack([o, half, far]), o)
    assert np.all(np.diff(batch) > 0)


def test_colour_model_separates_skin_from_background():
    rng = np.random.default_rng(0)
    img = np.clip(rng.normal([90, 100, 120], 8, (60, 80, 3)), 0, 255)
    mask = np.zeros((60, 80), bool)
    mask[20:40, 30:55] = True
    img[mask] = np.clip(rng.normal([220, 170, 150], 8, (mask.sum(), 3)), 0, 255)
    img = img.astype(np.uint8)
    cm = ColourModel.fit([img], [mask])
    s = cm.silhouette(img)
    assert np.mean(s[mask]) > 0.97 and np.mean(s[~mask]) < 0.03
    # eq. (4): the density peaks at the component centres
    g = SGMM.fit(img[mask].reshape(-1, 3) / 255.0, 2)
    assert g.density(np.array([220, 170, 150]) / 255.0) > g.density(np.array([0.3, 0.4, 0.5]))
    with pytest.raises(InputError):
        ColourModel.fit([img], [])


# ------------------------------------------------------------------ eq. (3), (5)-(7)
def test_every_term_is_lowest_at_the_true_pose(scene_views):
    rig, scene, views, truth = scene_views
    names = rig.names
    masks = [views[n].labels == 1 for n in names]
    cm = ColourModel.fit([views[n].rgb for n in names], masks)
    cfg = ImageTermsConfig(scale=0.5)     # 160 x 120, as 0.25 of the studio's 640 x 480
    obs = [observe(views[n].rgb, rig.camera(n), cm, cfg) for n in names]
    cost = ImageCost(scene, cfg)
    cost.learn_colours(truth, obs)
    P = np.stack([truth, *_perturbations(truth)])
    parts = cost(P, obs, parts=True)
    for term in ("silh", "color", "edge", "total"):
        assert np.all(parts[term][1:] > parts[term][0]), (term, parts[term])
    # the same with the maps cut to the search box around the scene (what isa_track does)
    from hand_capture.multiview.imageterms import hand_rois, observe_group

    boxed = observe_group({n: views[n].rgb for n in names}, rig, cm, cfg,
                          hand_rois(scene, rig, truth))
    assert all(b.silh.size < o.silh.size for b, o in zip(boxed, obs, strict=True))
    cut = cost(P, boxed, parts=True)
    assert np.all(cut["total"][1:] > cut["total"][0])
    assert np.allclose(cut["color"], parts["color"])
    # weights of eq. (3): 1.0 / 0.6 / 1.0
    cfg = ImageTermsConfig()
    assert cfg.scale == 0.25
    assert (cfg.w_silh, cfg.w_color, cfg.w_edge, cfg.window, cfg.color_cutoff) == \
        (1.0, 0.6, 1.0, 5, 0.25)
    total = parts["silh"] + parts["color"] + parts["edge"]
    assert np.allclose(parts["total"], total)


def test_moving_the_object_raises_only_the_edge_term(scene_views):
    rig, scene, views, truth = scene_views
    names = rig.names
    cm = ColourModel.fit([views[n].rgb for n in names], [views[n].labels == 1 for n in names])
    cfg = ImageTermsConfig(w_color=0.0, scale=0.5)
    obs = [observe(views[n].rgb, rig.camera(n), cm, cfg) for n in names]
    cost = ImageCost(scene, cfg)
    moved = truth.copy()
    moved[scene.slices["box"]][:2] += 0.02
    parts = cost(np.stack([truth, moved]), obs, parts=True)
    assert parts["silh"][1] == pytest.approx(parts["silh"][0])   # hand-only term (eq. 5)
    assert parts["edge"][1] > parts["edge"][0] + 0.5             # object one way (eq. 7)


def test_colour_window_and_cut_off():
    """Eq. (6): a colour found one pixel away costs little, a colour found nowhere costs T."""
    from hand_capture.multiview.imageterms import ObservedView

    cam = ring_rig("c", 1, width=40, height=40).cameras[0]
    img = np.zeros((40, 40, 3), np.uint8)
    img[20, 21] = (255, 0, 0)                 # the red pixel right of the centre
    v = observe(img, cam, None, ImageTermsConfig(scale=1.0), silhouette=np.zeros((40, 40), bool))
    assert isinstance(v, ObservedView) and len(v.inv_w) == 25
    centre = len(v.inv_w) // 2
    red = np.array([1.0, 0.0, 0.0], np.float32)
    err = np.abs(v.shifted[:, 20, 20] - red).mean(axis=1) * v.inv_w
    assert err[centre] == pytest.approx(1 / 3, abs=1e-6)        # the pixel itself is black
    assert err.min() == pytest.approx(0.0, abs=1e-6)            # its neighbour is red
    blue = np.array([0.0, 0.0, 1.0], np.float32)
    e2 = np.minimum((np.abs(v.shifted[:, 20, 20] - blue).mean(axis=1) * v.inv_w).min(), 0.25)
    assert e2 == pytest.approx(0.25)


def test_bad_image_is_refused(scene_views):
    rig, *_ = scene_views
    with pytest.raises(InputError, match="expected"):
        observe(np.zeros((10, 10, 3), np.uint8), rig.cameras[0], None)
    k = rig.cameras[0].intrinsics
    img = np.zeros((k.height, k.width, 3), np.uint8)
    with pytest.raises(InputError, match="colour model or a silhouette"):
        observe(img, rig.cameras[0], None)
    with pytest.raises(InputError, match="does not fit"):
        observe(img, rig.cameras[0], None, silhouette=np.zeros((5, 5), bool))


# ------------------------------------------------------------------ ISA
def test_isa_finds_a_known_optimum_of_a_multimodal_cost():
    opt = np.array([0.3, -0.2, 0.5, 0.1, -0.4, 0.25])

    def cost(X):
        d = X - opt
        return np.sum(d * d, 1) + 0.05 * np.sum(1 - np.cos(4 * np.pi * d), 1)

    res = isa_minimise(cost, np.zeros(6), np.full(6, 0.3), -np.ones(6), np.ones(6),
                       config=ISAConfig(n_particles=128, n_iters=25), seed=3)
    assert np.max(np.abs(res.x - opt)) < 0.02
    assert res.n_evals == 128 * 25 + 1
    assert np.all(np.diff(np.minimum.accumulate(res.history)) <= 0)
    again = isa_minimise(cost, np.zeros(6), np.full(6, 0.3), -np.ones(6), np.ones(6),
                         config=ISAConfig(n_particles=128, n_iters=25), seed=3)
    assert np.array_equal(res.x, again.x)       # seeded: reproducible
    # bounds hold and a fixed parameter (sigma 0) stays put
    sig = np.full(6, 0.3)
    sig[2] = 0.0
    res = isa_minimise(cost, np.zeros(6), sig, np.full(6, -0.1), np.full(6, 0.1),
                       config=ISAConfig(n_particles=64, n_iters=10), seed=0)
    assert np.all(np.abs(res.x) <= 0.1 + 1e-12) and res.x[2] == 0.0


def test_isa_track_runs_a_short_sequence(scene_views):
    rig, scene, views, truth = scene_views
    frames = [{n: v.rgb for n, v in views.items()}] * 2
    res = isa_track(frames, rig, scene, n_particles=8, n_iters=2, seed=0, init_params=truth)
    assert res.params.shape == (2, scene.n_params)
    assert np.array_equal(res.params[0], scene.clip(truth))
    assert np.all(np.isfinite(res.params)) and res.s_per_frame > 0
    with pytest.raises(InputError):
        isa_track([], rig, scene, init_params=truth)


# ------------------------------------------------------------------ hull + ICP
def test_visual_hull_and_icp_recover_the_global_pose():
    from hand_capture.multiview.hull import initialise
    from hand_capture.multiview.rig import load_rig
    from hand_capture.multiview.scene_model import SceneModel, object_mesh
    from hand_capture.multiview.studio import Studio, studio_scene

    rig = load_rig("studio6")
    q = np.zeros(27)                               # the flat hand (sec. 4.3)
    q[:3] = [0.02, -0.03, 0.12]
    q[3:6] = [0.2, -0.1, 0.8]
    with Studio(rig, studio_scene(["box"]), None) as st:
        st.set_state(q)
        views = st.render_all()
        box = st.object_pose("box")
    scene = SceneModel([HandModel()], [object_mesh("box")])
    res = initialise(views, scene, rig, hand_masks={n: v.labels == 1 for n, v in views.items()},
                     voxel_m=0.008,
                     object_masks={"box": {n: v.labels == 2 for n, v in views.items()}})
    # the object by the same hull + ICP: its surface within 6 mm (a box: symmetric, so the
    # surfaces are compared, not the angles)
    from scipy.spatial import cKDTree

    est = scene.object_transform(res.params[scene.slices["box"]])
    v = scene.objects[0].vertices
    d, _ = cKDTree(v @ box[:3, :3].T + box[:3, 3]).query(v @ est[:3, :3].T + est[:3, 3])
    assert d.mean() < 0.006 and np.linalg.norm(est[:3, 3] - box[:3, 3]) < 0.015
    h = HandModel()
    err = np.linalg.norm(h.joint_positions(res.params[:27]) - h.joint_positions(q), axis=1)
    R = root_rotation_matrix(res.params[3:6]).T @ root_rotation_matrix(q[3:6])
    angle = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
    assert err.mean() < 0.02 and angle < 10.0, (err.mean(), angle)
    # ISA refinement on eq. (5) + (7) from the ICP result never ends at a higher cost
    ref = initialise(views, scene, rig, hand_masks={n: v.labels == 1 for n, v in views.items()},
                     voxel_m=0.008, refine_particles=8, refine_iters=2)
    assert ref.refined and np.all(ref.params[27:] == 0)   # no object masks: the prior
    err = np.linalg.norm(h.joint_positions(ref.params[:27]) - h.joint_positions(q), axis=1)
    assert err.mean() < 0.02
    with pytest.raises(InputError, match="hull"):
        initialise(views, scene, rig,
                   hand_masks={n: np.zeros_like(v.labels, bool) for n, v in views.items()})
    # the tracker's initialiser: silhouettes from the colour model learned on a known frame
    from hand_capture.multiview.hull import HullInitializer

    images = {n: v.rgb for n, v in views.items()}
    images["cam5"] = None                          # a camera missing from the group
    init = HullInitializer(rig)
    assert init(images, scene, 0) is None          # no colour model yet
    init.learn(images, scene, scene.pack([q], [box]))
    init.prior = None
    got = init(images, scene, 0)
    assert got is not None and got.shape == (27,)
    err = np.linalg.norm(h.joint_positions(got) - h.joint_positions(q), axis=1)
    assert err.mean() < 0.025, err.mean()


# ------------------------------------------------------------------ salient detector
def test_shipped_detector_finds_fingertips_on_heldout_renders():
    from hand_capture.multiview.salient import (
        evaluate,
        load_salient_detector,
        render_views,
        tip_vertices,
    )

    det = load_salient_detector()
    views = list(render_views(2, 4242, heldout=True))   # surfaces never seen in training
    assert sum(len(v.tips) for v in views) >= 10
    r = evaluate(det, views, radius_px=6.0)
    assert r["recall"] >= 0.3 and r["precision"] >= 0.3, r
    pts, sc = det.detect(views[0].rgb)
    assert pts.shape[1] == 2 and len(pts) == len(sc) and np.all(np.diff(sc) <= 0)
    whole = det.detect(views[0].rgb, crop=False)          # the crop changes nothing
    assert np.array_equal(pts, whole[0]) and np.allclose(sc, whole[1])
    with pytest.raises(InputError, match="uint8"):
        det.detect(np.zeros((48, 64, 3), np.float32))
    blank = det.detect(np.full((48, 64, 3), 40, np.uint8))   # nothing skin-coloured
    assert len(blank[0]) == 0
    # the salient vertices matching the detections: the mesh vertices at the fingertips
    hand = HandModel()
    q = home_pose()
    tips = hand.vertices(q)[tip_vertices(hand)]
    assert np.max(np.linalg.norm(tips - hand.fingertips(q), axis=1)) < 0.004


def test_detector_training_is_seeded_and_round_trips(tmp_path):
    from hand_capture.multiview.salient import (
        DetectorConfig,
        SalientDetector,
        render_views,
        train_detector,
    )

    views = list(render_views(1, 7, cameras=3))
    cfg = DetectorConfig(n_offsets=24)
    a = train_detector(views, cfg, seed=5, n_trees=1, max_depth=6)
    b = train_detector(views, cfg, seed=5, n_trees=1, max_depth=6)
    assert np.array_equal(a.classifier.threshold, b.classifier.threshold)
    path = a.save(tmp_path / "d.npz")
    c = SalientDetector.load(path)
    img = views[0].rgb
    pa, sa = a.detect(img)
    pc, sc = c.detect(img)
    assert np.array_equal(pa, pc) and np.allclose(sa, sc)
    with pytest.raises(InputError, match="no salient detector"):
        SalientDetector.load(tmp_path / "missing.npz")
