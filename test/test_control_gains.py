"""PD gains of seed 000 Table 1 / dissertation Table III.1 and their mapping onto the model."""

from __future__ import annotations

import pytest

from hand_capture.config import from_mapping
from hand_capture.errors import ConfigError
from hand_capture.model.joints import JOINT_NAMES
from hand_control.control import GAIN_ROWS, CompositeControlConfig, gain_row, joint_gains

TABLE = {  # row: (Kp, Kd), as printed in both tables
    "root_translate": (400.0, 50.0), "root_rotate": (600.0, 50.0),
    "thumb1": (10.0, 0.3), "thumb2": (8.0, 0.2), "thumb3": (4.0, 0.4),
    "index1": (4.0, 0.2), "index2": (3.0, 0.1), "index3": (2.0, 0.1),
    "middle1": (4.0, 0.4), "middle2": (4.0, 0.1), "middle3": (2.0, 0.1),
    "ring1": (4.0, 0.4), "ring2": (3.0, 0.1), "ring3": (2.0, 0.1),
    "pinky1": (4.0, 0.4), "pinky2": (3.0, 0.1), "pinky3": (2.0, 0.1),
}


def test_defaults_are_the_papers_tables():
    cfg = CompositeControlConfig()
    assert dict(zip(GAIN_ROWS, zip(cfg.joint_kp, cfg.joint_kd, strict=True), strict=True)) \
        == TABLE
    assert (cfg.object_kp_translate, cfg.object_kd_translate) == (5.0, 0.5)
    assert (cfg.object_kp_rotate, cfg.object_kd_rotate) == (5.0, 0.5)


@pytest.mark.parametrize("joint,row", [
    ("root_tx", "root_translate"), ("root_rz", "root_rotate"),
    ("thumb_tm_abd", "thumb1"), ("thumb_tm_flex", "thumb1"), ("thumb_mcp_flex", "thumb2"),
    ("thumb_ip_flex", "thumb3"), ("index_mcp_abd", "index1"), ("middle_pip_flex", "middle2"),
    ("ring_dip_flex", "ring3"), ("little_mcp_flex", "pinky1"), ("little_dip_flex", "pinky3"),
])
def test_gain_rows_of_model_joints(joint, row):
    assert gain_row(joint) == row


def test_every_model_joint_has_gains():
    kp, kd = joint_gains(CompositeControlConfig(), JOINT_NAMES)
    assert kp.shape == kd.shape == (len(JOINT_NAMES),)
    for name, p, d in zip(JOINT_NAMES, kp, kd, strict=True):
        assert (p, d) == TABLE[gain_row(name)]


@pytest.mark.parametrize("name", ["pinky_mcp_flex", "index_tip", "wrist", "thumb_dip_flex", ""])
def test_unknown_joint_is_a_config_error(name):
    with pytest.raises(ConfigError):
        gain_row(name)


@pytest.mark.parametrize("kwargs", [
    dict(joint_kp=(1.0,) * 16), dict(joint_kd=(0.1,) * 18), dict(joint_kp=(-1.0,) * 17),
    dict(mode="pd"), dict(gravity=(0.0, -9.81)), dict(object_kp_rotate=-5.0),
])
def test_bad_config_is_a_config_error(kwargs):
    with pytest.raises(ConfigError):
        CompositeControlConfig(**kwargs)


def test_config_from_a_parameter_mapping():
    cfg = from_mapping(CompositeControlConfig, {"mode": "pd_only", "joint_kp": [2.0] * 17})
    assert cfg.mode == "pd_only" and cfg.joint_kp == (2.0,) * 17

