"""Depth-sensor noise model: statistics, quantisation, dropouts, flying pixels (no ROS)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hand_capture.cameras.base import Intrinsics, depth_m_to_mm
from hand_capture.cameras.noise import ColorNoise, DepthNoiseConfig, DepthNoiseModel
from hand_capture.cameras.primitives import box, plane
from hand_capture.cameras.render import Mesh, ZBufferRenderer
from hand_capture.cameras.transforms import rotvec_to_matrix
from hand_capture.errors import ConfigError

INTR = Intrinsics(320, 240, 228.5, 228.5, 159.5, 119.5)
QUIET = dict(dropout_prob=0.0, flying_prob=0.0)  # only axial noise and quantisation


def _wall(z: float, tilt_deg: float = 0.0):
    V, F = plane([20.0, 20.0], n=64)
    R = rotvec_to_matrix([0.0, math.radians(tilt_deg), 0.0])
    return ZBufferRenderer().render([Mesh(V @ R.T + [0, 0, z], F)], INTR)


def test_axial_std_grows_with_distance_squared():
    model = DepthNoiseModel(DepthNoiseConfig(**QUIET))
    rng = np.random.default_rng(0)
    measured = []
    for z in (0.3, 0.6, 1.2, 2.0):
        res = _wall(z)
        mm = model.apply_mm(res.depth, res.cos_incidence, INTR, rng)
        assert mm.dtype == np.uint16 and (mm > 0).all()
        err = mm.astype(float) * 1e-3 - res.depth
        sigma = float(model.axial_sigma(z))
        expected = math.sqrt(sigma**2 + 1e-6 / 12.0)  # plus 1 mm rounding
        assert abs(err.mean()) < 0.1 * sigma
        assert err.std() == pytest.approx(expected, rel=0.05)
        measured.append(err.std())
    assert np.all(np.diff(measured) > 0)
    c = model.config
    # the growth is quadratic: (sigma(2) - sigma0) / (sigma(1) - sigma0) = 4
    g = (model.axial_sigma(2.0) - c.sigma_base_m) / (model.axial_sigma(1.0) - c.sigma_base_m)
    assert g == pytest.approx(4.0)


def test_noise_free_output_is_rounded_to_millimetres():
    model = DepthNoiseModel(DepthNoiseConfig(enabled=False))
    res = _wall(0.4567, tilt_deg=30.0)
    mm = model.apply_mm(res.depth, res.cos_incidence, INTR, np.random.default_rng(0))
    assert mm.dtype == np.uint16
    assert np.abs(mm.astype(float) - res.depth * 1e3).max() <= 0.5 + 1e-3
    assert np.array_equal(depth_m_to_mm(np.array([[0.0, np.nan, 70.0, 0.0015]])),
                          np.array([[0, 0, 0, 2]], np.uint16))


def test_disparity_quantisation_step_grows_with_distance_squared():
    cfg = DepthNoiseConfig(**QUIET, sigma_base_m=0.0, sigma_quad_per_m=0.0, sigma_angle_m=0.0,
                           baseline_m=0.05, disparity_step_px=0.125)
    model = DepthNoiseModel(cfg)
    for z in (1.0, 2.0):
        res = _wall(z, tilt_deg=40.0)  # a range of depths around z
        out = model.apply(res.depth, res.cos_incidence, INTR, np.random.default_rng(0))
        levels = np.unique(out[out > 0])
        near = levels[np.abs(levels - z) < 0.1 * z]
        step = np.median(np.diff(near))
        assert step == pytest.approx(float(model.quantization_step(z, INTR.fx)), rel=0.1)
    assert model.quantization_step(2.0, INTR.fx) > 3.5 * model.quantization_step(1.0, INTR.fx)


def test_grazing_surfaces_lose_pixels():
    model = DepthNoiseModel(DepthNoiseConfig(**QUIET))
    rng = np.random.default_rng(1)
    facing = _wall(1.0, tilt_deg=20.0)  # incidence <= 20 + 35 deg at the image edge
    out = model.apply(facing.depth, facing.cos_incidence, INTR, rng)
    assert (out > 0).mean() > 0.999
    # a wall seen at 50..85+ deg: dropout follows the linear ramp of the incidence angle
    grazing = _wall(1.0, tilt_deg=80.0)
    out = model.apply(grazing.depth, grazing.cos_incidence, INTR, rng)
    theta = np.degrees(np.arccos(np.clip(grazing.cos_incidence, 0, 1)))
    kept = out > 0
    c = model.config
    assert kept[grazing.hit & (theta < c.grazing_start_deg)].all()
    assert not kept[grazing.hit & (theta > c.grazing_full_deg)].any()
    for lo in (72.0, 76.0, 80.0):
        sel = grazing.hit & (theta >= lo) & (theta < lo + 2.0)
        assert sel.sum() > 300
        expected_drop = (lo + 1.0 - c.grazing_start_deg) / (c.grazing_full_deg -
                                                             c.grazing_start_deg)
        assert 1.0 - kept[sel].mean() == pytest.approx(expected_drop, abs=0.06)


def test_flying_pixels_lie_between_foreground_and_background():
    Vb, Fb = box([0.2, 0.2, 0.05])
    Vp, Fp = plane([20.0, 20.0])
    res = ZBufferRenderer().render([Mesh(Vb + [0, 0, 0.5], Fb, 2, closed=True),
                                    Mesh(Vp + [0, 0, 1.0], Fp, 3)], INTR)
    cfg = DepthNoiseConfig(dropout_prob=0.0, flying_prob=1.0, sigma_base_m=0.0,
                           sigma_quad_per_m=0.0, sigma_angle_m=0.0)
    out = DepthNoiseModel(cfg).apply(res.depth, res.cos_incidence, INTR,
                                     np.random.default_rng(2))
    fg = res.label == 2
    # 4-neighbourhood edge of the box, on both sides
    edge = np.zeros_like(fg)
    for ax, sh in ((0, 1), (0, -1), (1, 1), (1, -1)):
        edge |= fg != np.roll(fg, sh, axis=ax)
    between = (out > 0.476) & (out < 0.999)
    assert between[edge].mean() > 0.9       # edge pixels mixed between 0.475 and 1.0 m
    assert not between[~edge].any()         # nowhere else
    assert np.allclose(out[fg & ~edge], 0.475, atol=1e-6)


def test_seeded_noise_is_reproducible_and_frame_drops_follow_their_probability():
    model = DepthNoiseModel(DepthNoiseConfig(frame_drop_prob=0.25))
    res = _wall(0.5, tilt_deg=20.0)
    a = model.apply_mm(res.depth, res.cos_incidence, INTR, np.random.default_rng(7))
    b = model.apply_mm(res.depth, res.cos_incidence, INTR, np.random.default_rng(7))
    c = model.apply_mm(res.depth, res.cos_incidence, INTR, np.random.default_rng(8))
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    rng = np.random.default_rng(0)
    drops = sum(model.drop_frame(rng) for _ in range(2000))
    assert 400 < drops < 600


def test_colour_noise_pool_has_the_requested_std():
    rng = np.random.default_rng(0)
    img = np.full((120, 160, 3), 128, np.uint8)
    cn = ColorNoise(img.shape, 3.0, rng)
    out = cn.apply(img, rng).astype(float) - 128
    assert out.std() == pytest.approx(3.0, rel=0.05)
    assert not np.array_equal(cn.apply(img, rng), cn.apply(img, rng))


def test_noise_config_is_validated():
    with pytest.raises(ConfigError, match="grazing_full_deg"):
        DepthNoiseConfig(grazing_start_deg=80.0, grazing_full_deg=70.0)
    with pytest.raises(ConfigError, match="sigma_base_m"):
        DepthNoiseConfig(sigma_base_m=-1.0)
    with pytest.raises(ConfigError, match="max_range_m"):
        DepthNoiseConfig(min_range_m=2.0, max_range_m=1.0)


def test_apply_mm_is_apply_in_millimetres_on_the_valid_window():
    """apply_mm converts only the window of valid pixels; the result is apply()'s image in
    millimetres, for the same draws (also with the hand cut by the image border)."""
    from hand_capture.cameras.synthetic import SyntheticCamera, SyntheticCameraConfig

    cam = SyntheticCamera(SyntheticCameraConfig(clip="grasp", width=160, height=120))
    cam.open()
    res = cam._renderer.render(cam.scene_meshes(1.0, cam.truth_pose(1.0))[0], cam.intrinsics)
    model = DepthNoiseModel(DepthNoiseConfig(flying_prob=0.5, dropout_prob=0.01))
    for cut in (slice(None), slice(40, None)):
        d, c = res.depth[cut, cut], res.cos_incidence[cut, cut]
        a = model.apply(d, c, cam.intrinsics, np.random.default_rng(3))
        b = model.apply_mm(d, c, cam.intrinsics, np.random.default_rng(3))
        assert (b > 0).sum() > 100
        assert np.array_equal(depth_m_to_mm(a), b)
