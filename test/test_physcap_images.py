"""The image cost of eq. (3) in physics capture: a capture with multi-view images (rendered by
the studio from the ground truth) gets the silhouette / colour / edge terms in every simulated
frame's energy."""

from __future__ import annotations

import numpy as np
import pytest

from hand_control.physcap.capture import Capture, CaptureError, PhysCapConfig, optimise_capture

N = 4  # frames


@pytest.fixture(scope="module")
def filmed():
    """A short lift_box capture (truth and a ``contacts``-corrupted reference, 4 frames) and
    the studio's 4-camera images of the truth."""
    from hand_capture.multiview.rig import ring_rig
    from hand_capture.multiview.studio import HAND_LABEL, Studio, StudioNoise, studio_scene
    from hand_control.physcap.images import capture_images
    from hand_control.physcap.synth import corrupt, scenario_capture
    from hand_control.physcap.world import object_spec
    from hand_control.sim.scenario import load_scenario

    spec = load_scenario("lift_box").with_(t_lift=0.4, t_carry=0.1, t_hold=0.1)
    full = scenario_capture(spec, t_start=0.5, t_end=1.5)
    truth = Capture("t", full.times[:N], full.hand_q[:N], full.object_pose[:N], full.obj)
    sc = corrupt(full, "contacts", seed=1)
    ref = Capture("r", full.times[:N], sc.capture.hand_q[:N], sc.capture.object_pose[:N],
                  full.obj)
    rig = ring_rig("t4", 4, width=320, height=240)
    groups, masks = [], {}
    with Studio(rig, studio_scene([object_spec(full.obj)]), StudioNoise(seed=3)) as st:
        for i in range(N):
            st.set_state(truth.hand_q[i], truth.object_pose[i])
            views = st.render_all()
            groups.append({n: v.rgb for n, v in views.items()})
            if i == 0:
                masks = {n: v.labels == HAND_LABEL for n, v in views.items()}
    from hand_capture.multiview.imageterms import ImageTermsConfig

    images = capture_images(full.obj, rig, groups, masks, ref.hand_q[0], ref.object_pose[0],
                            ImageTermsConfig(scale=0.5))
    return truth, ref, images


def test_image_term_prefers_the_true_hand_and_object(filmed):
    truth, ref, images = filmed
    for f in range(1, N):
        e = images.energies(f, np.stack([truth.hand_q[f], ref.hand_q[f], truth.hand_q[f]]),
                            np.stack([truth.object_pose[f], truth.object_pose[f],
                                      truth.object_pose[f] + [0.02, 0, 0, 0, 0, 0, 0]]))
        assert e[0] < e[1], (f, e)   # the fingers 10-20 mm off cost more
        assert e[0] < e[2], (f, e)   # so does the object 2 cm off


def test_optimise_capture_adds_the_image_term(filmed):
    _, ref, images = filmed
    cfg = PhysCapConfig(n_samples=8, n_keep=2)
    plain = optimise_capture(ref, cfg)
    with_images = optimise_capture(ref, cfg, images=images)
    # frame 0 is the same state in both: its energy differs by exactly the image term
    e0 = images.energies(0, ref.hand_q[:1], ref.object_pose[:1])[0]
    assert e0 > 0.0
    assert with_images.costs[0] == pytest.approx(plain.costs[0] + e0)
    assert np.isfinite(with_images.costs).all() and with_images.hand_q.shape == (N, 27)
    # images must match the capture's frames on the step grid
    short = Capture("s", ref.times[:3], ref.hand_q[:3], ref.object_pose[:3], ref.obj)
    with pytest.raises(CaptureError, match="one group per frame"):
        optimise_capture(short, cfg, images=images)
