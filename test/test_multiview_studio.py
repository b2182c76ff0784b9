"""Synthetic studio: the ground truth matches what is rendered in every camera."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.errors import ConfigError
from hand_capture.model import HandModel
from hand_capture.model.mjcf import build_scene, home_pose
from hand_capture.multiview.rig import Rig, load_rig, ring_rig
from hand_capture.multiview.studio import HAND_LABEL, Studio, StudioNoise, jittered_stamps


@pytest.fixture(scope="module")
def studio():
    st = Studio(load_rig("studio6"), build_scene(["box"]), StudioNoise(seed=1))
    yield st
    st.close()


def test_true_hand_keypoints_land_on_the_hand_in_every_camera(studio):
    q = home_pose()
    q[5] += 0.3
    studio.set_state(q)
    kp = HandModel().forward(q).joint_positions  # (21, 3) world [m]
    for i, cam in enumerate(studio.rig.cameras):
        view = studio.render(i)
        uv, front = cam.project(kp)
        z = cam.to_camera(kp)[:, 2]
        px = np.round(uv).astype(int)
        inside = front & (px[:, 0] >= 0) & (px[:, 0] < 640) & (px[:, 1] >= 0) & (px[:, 1] < 480)
        assert inside.all(), cam.name
        lab = view.labels[px[:, 1], px[:, 0]]
        depth = view.depth_m[px[:, 1], px[:, 0]]
        visible = np.abs(depth - z) < 0.02  # the surface within 2 cm of the joint: not occluded
        assert visible.sum() >= 5, cam.name
        assert np.all(lab[visible] == HAND_LABEL), cam.name
        assert np.mean(lab == HAND_LABEL) >= 0.8, cam.name


def test_object_ground_truth_projects_onto_its_label(studio):
    studio.set_state(home_pose())
    [name] = studio.object_names
    centre = studio.object_pose(name)[:3, 3]
    for i, cam in enumerate(studio.rig.cameras):
        view = studio.render(i)
        (u, v), = np.round(cam.project(centre[None])[0]).astype(int)
        window = view.labels[v - 2: v + 3, u - 2: u + 3]
        # the box centre is inside the box: its pixel shows the box, unless the hand covers it
        assert np.any(window == 2) or np.any(window == HAND_LABEL), cam.name


def test_depth_matches_the_table_plane(studio):
    studio.set_state(home_pose())
    cam = studio.rig.cameras[0]
    view = studio.render(0, labels=True)
    k = cam.intrinsics
    v, u = np.nonzero(view.labels == 0)
    d = view.depth_m[v, u]
    sel = (d > 0) & (d < 1.2)  # the table top in front of the camera
    rays = np.stack([(u[sel] - k.cx) / k.fx, (v[sel] - k.cy) / k.fy, np.ones(sel.sum())], 1)
    pw = (rays * d[sel, None]) @ cam.R_wc.T + cam.t_wc
    on_top = np.abs(pw[:, 2]) < 0.002
    assert on_top.mean() > 0.9  # background pixels in front of the camera are the table top


def test_noise_changes_images_but_not_ground_truth():
    rig = ring_rig("two", 2, width=160, height=120)
    with Studio(rig, build_scene(["ball"]), StudioNoise(seed=3)) as noisy, \
            Studio(rig, build_scene(["ball"]), None) as clean:
        for st in (noisy, clean):
            st.set_state(home_pose())
        a, b = noisy.render(0), clean.render(0)
        assert np.array_equal(a.labels, b.labels)
        assert np.array_equal(a.depth_m, b.depth_m)
        diff = np.abs(a.rgb.astype(int) - b.rgb.astype(int))
        assert 0.5 < diff.mean() < 20


def test_a_distorted_camera_is_refused():
    rig = ring_rig("d", 2, distortion=(-0.1, 0, 0, 0, 0))
    with pytest.raises(ConfigError, match="cam0.*ideal pinholes"):
        Studio(rig, build_scene())
    mixed = Rig("m", (ring_rig("a", 1).cameras[0],
                      ring_rig("b", 2, width=320, height=240).cameras[1]))
    with pytest.raises(ConfigError, match="one resolution"):
        Studio(mixed, build_scene())


def test_jittered_stamps_have_offsets_and_bounded_jitter():
    s = jittered_stamps(100, 20.0, 3, jitter_s=0.002, offsets_s=[0.0, 0.01, -0.01])
    d = s - (np.arange(100) / 20.0)[:, None]
    assert np.all(np.abs(d - np.array([0.0, 0.01, -0.01])) <= 0.002)


def test_rig_capture_writes_every_camera_and_the_ground_truth(tmp_path):
    from hand_capture.bag import BagReader
    from hand_capture.errors import BagError
    from hand_capture.multiview.rig import save_rig
    from hand_capture.nodes.rig_capture import write_rig_capture

    rig = save_rig(ring_rig("small", 2, width=160, height=120), tmp_path / "small.yaml")
    res = write_rig_capture(tmp_path / "bag", str(rig), seconds=0.3, fps=10,
                            objects=("box", "ball"), two_hands=True, surface_seed=4)
    assert (res.frames, res.cameras) == (3, 2)
    with BagReader(res.path) as bag:
        assert {"/cam0/color/image_raw", "/cam1/labels/image_raw", "/hand/pose_truth",
                "/hand/shape_truth",
                "/object/box/pose_truth", "/object/ball/pose_truth"} <= set(bag.topics)
        stamps: dict[str, list[float]] = {}
        for m in bag.messages():
            msg = bag.check(m)
            t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            stamps.setdefault(m.topic, []).append(t)
            if m.topic == "/cam1/labels/image_raw":
                assert np.any(np.asarray(msg.data) == HAND_LABEL)
            if m.topic == "/hand/pose_truth":
                hands = stamps.setdefault("handedness", [])
                hands.append(msg.handedness)
    assert sorted(set(stamps["handedness"])) == [0, 1]  # both hands' truth
    truth = np.array(stamps["/hand/pose_truth"][::2])
    for cam in ("cam0", "cam1"):  # own clocks: offset + jitter within 5 ms of the instant
        d = np.array(stamps[f"/{cam}/color/image_raw"]) - truth
        assert np.all(np.abs(d) <= 0.005) and np.any(d != 0)
    with pytest.raises(BagError, match="exists"):
        write_rig_capture(tmp_path / "bag", str(rig), seconds=0.1)


def test_two_hands_and_objects_get_their_own_labels():
    from hand_capture.multiview.studio import studio_scene

    with Studio(load_rig("studio6"), studio_scene(["box", "ball"], two_hands=True)) as st:
        assert st.two_hands
        assert st.label_names == ["background", "hand", "left_hand", "box", "ball"]
        assert st.object_names == ["box", "ball"]
        right, left = home_pose(), home_pose((0.0, 0.3, 0.12))
        st.set_state(right, left_pose=left)
        kp_l = HandModel(side="left").forward(left).joint_positions
        kp_r = HandModel().forward(right).joint_positions
        seen = {1: 0, 2: 0}
        for i, cam in enumerate(st.rig.cameras):
            view = st.render(i)
            for kp, lab in ((kp_r, 1), (kp_l, 2)):
                (u, v) = np.round(cam.project(kp[[0]])[0][0]).astype(int)
                seen[lab] += int(view.labels[v, u] == lab)
        assert seen[1] >= 4 and seen[2] >= 4  # each wrist on its own hand in most cameras
        with pytest.raises(Exception, match="finite"):
            st.set_state(right, left_pose=np.full(27, np.nan))


def test_a_simulated_scenario_is_rendered_with_its_own_object_motion(tmp_path):
    from hand_capture.bag import BagReader
    from hand_capture.multiview.rig import save_rig
    from hand_capture.nodes.rig_capture import write_rig_capture
    from hand_control.sim.lockstep import record_motion
    from hand_control.sim.scenario import load_scenario

    objects, qpos = record_motion(load_scenario("lift_box"), fps=10, seconds=0.4)
    assert qpos.shape[0] == 4 and [o.name for o in objects] == ["box"]
    rig = save_rig(ring_rig("small", 2, width=160, height=120), tmp_path / "small.yaml")
    res = write_rig_capture(tmp_path / "bag", str(rig), seconds=0.4, fps=10, objects=objects,
                            qpos=qpos)
    with BagReader(res.path) as bag:
        z = [bag.check(m).pose.position.z for m in bag.messages()
             if m.topic == "/object/pose_truth"]
        hands = [np.asarray(bag.check(m).positions) for m in bag.messages()
                 if m.topic == "/hand/pose_truth"]
    np.testing.assert_allclose(z, qpos[:, 29], atol=1e-9)  # box z: the simulated one
    assert len(hands) == 4


def test_a_heldout_surface_subject_stands_in_for_the_mjcf_hand():
    from hand_capture.evaldata.scene import sample_subject
    from hand_capture.evaldata.surface import sample_surface

    rng = np.random.default_rng(5)
    subject, surface = sample_subject(rng), sample_surface(rng, forearm=True, sleeve=False)
    with Studio(load_rig("studio6"), build_scene(["box"])) as st:
        q = home_pose()
        st.set_state(q)
        mjcf_view = st.render(0)
        st.set_surface(subject, surface)
        assert st.label_names == ["background", "hand", "box", "arm"]
        kp = subject.forward(q).joint_positions  # the subject's skeleton: the truth
        on_hand = 0
        for i, cam in enumerate(st.rig.cameras):
            view = st.render(i)
            assert np.any(view.labels == 3)  # the forearm is in view
            px = np.round(cam.project(kp)[0]).astype(int)
            on_hand += int(np.sum(view.labels[px[:, 1], px[:, 0]] == HAND_LABEL))
        assert on_hand >= 0.7 * 6 * len(kp)
        # another surface than the MJCF capsules
        assert not np.array_equal(st.render(0).labels == HAND_LABEL,
                                  mjcf_view.labels == HAND_LABEL)
        st.set_surface(None)
        assert st.label_names == ["background", "hand", "box"]
        np.testing.assert_array_equal(st.render(0).labels, mjcf_view.labels)


def test_parallel_studio_renders_what_one_studio_renders():
    from hand_capture.multiview.studio import ParallelStudio, studio_scene

    rig = ring_rig("three", 3, width=160, height=120)
    with Studio(rig, studio_scene(["box"])) as one:
        one.set_state(home_pose())
        q = one.data.qpos.copy()
        ref = one.render_all()
    with ParallelStudio(rig, ["box"], workers=2) as par:
        views = par.render_all(q)
        assert list(views) == list(rig.names)
        for name in rig.names:
            np.testing.assert_array_equal(views[name].labels, ref[name].labels)
            np.testing.assert_array_equal(views[name].depth_m, ref[name].depth_m)
        with pytest.raises(Exception, match="qpos"):
            par.render_all(np.zeros(3))


def test_capture_rig_cli_plays_a_motion_clip_above_the_table(tmp_path):
    from hand_capture.bag import BagReader
    from hand_capture.multiview.rig import save_rig
    from hand_capture.posemsg import pose_from_msg
    from hand_control.cli import main

    rig = save_rig(ring_rig("small", 2, width=160, height=120), tmp_path / "small.yaml")
    out = tmp_path / "bag"
    assert main(["capture", "--rig", str(rig), "--clip", "pinch", "--seconds", "0.4",
                 "--fps", "5", "-o", str(out)]) == 0
    with BagReader(out) as bag:
        roots = [pose_from_msg(bag.check(m))[:3] for m in bag.messages()
                 if m.topic == "/hand/pose_truth"]
        hand_px = [int(np.sum(np.asarray(bag.check(m).data) == HAND_LABEL))
                   for m in bag.messages() if m.topic == "/cam0/labels/image_raw"]
    assert len(roots) == 2
    assert all(0.0 < r[2] < 0.4 for r in roots)  # above the table, below the camera
    assert all(n > 50 for n in hand_px)  # the hand is in view
