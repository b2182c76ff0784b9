"""config/camera*.yaml hold every camera parameter with its default and exact ROS type."""

from __future__ import annotations

import dataclasses

import pytest
from ros_helpers import ROOT

from hand_capture.cameras.noise import DepthNoiseConfig
from hand_capture.cameras.opencv import OpenCVConfig
from hand_capture.cameras.realsense import RealSenseConfig
from hand_capture.cameras.synthetic import SyntheticCameraConfig
from hand_capture.config import from_mapping, load_yaml
from hand_capture.nodes.camera import CameraNodeConfig
from hand_capture.nodes.synthetic_camera import SyntheticNodeConfig


def _check_section(values: dict, classes: list[type]) -> None:
    fields = {f.name: (cls, f) for cls in classes for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - set(fields))
    assert not unknown, f"unknown keys {unknown}"
    missing = sorted(set(fields) - set(values))
    assert not missing, f"keys missing from the file: {missing}"
    for key, value in values.items():
        _, f = fields[key]
        default = f.default
        if isinstance(default, tuple):
            assert isinstance(value, list) and len(value) == len(default), key
            assert all(type(v) is type(d) for v, d in zip(value, default, strict=True)), key
            assert tuple(value) == default, key
        else:
            # ROS declares the parameter with the default's type: an int for a double fails
            assert type(value) is type(default), f"{key}: {value!r} vs default {default!r}"
            assert value == default, f"{key}: file {value!r} != default {default!r}"
    for cls in classes:
        from_mapping(cls, {k: v for k, v in values.items() if fields[k][0] is cls})


@pytest.mark.parametrize("name", ["camera.yaml", "camera_synthetic.yaml"])
def test_camera_parameter_files_match_the_config_classes(name):
    data = load_yaml(ROOT / "config" / name)
    if name == "camera.yaml":
        p = dict(data["camera"]["ros__parameters"])
        _check_section(p.pop("realsense"), [RealSenseConfig])
        _check_section(p.pop("opencv"), [OpenCVConfig])
        _check_section(p, [CameraNodeConfig])
    else:
        p = dict(data["synthetic_camera"]["ros__parameters"])
        _check_section(p.pop("noise"), [DepthNoiseConfig])
        _check_section(p, [SyntheticCameraConfig, SyntheticNodeConfig])
