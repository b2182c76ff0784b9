"""Config dataclasses: validation messages, YAML loading, ROS parameter descriptors."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from hand_capture.config import (
    from_mapping,
    from_overrides,
    load_node_params,
    param,
    validate,
)
from hand_capture.errors import ConfigError


@dataclass(frozen=True)
class Cfg:
    gain: float = param(1.0, "a gain [N/m]", lo=0.0, hi=10.0)
    mode: str = param("a", "a mode", choices=("a", "b"))
    count: int = param(3, "a count", lo=1)
    weights: tuple[float, ...] = param((1.0, 2.0), "weights", lo=0.0)

    def __post_init__(self) -> None:
        validate(self)


def test_valid_values_and_int_to_float() -> None:
    c = Cfg(gain=2, weights=[0.5])
    assert c.gain == 2.0 and isinstance(c.gain, float)
    assert c.weights == (0.5,)


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"gain": 11.0}, "out of range [0.0, 10.0]"),
        ({"gain": float("nan")}, "must be finite"),
        ({"mode": "c"}, "not one of ['a', 'b']"),
        ({"count": 0}, "Cfg.count = 0"),
        ({"count": "3"}, "must be int"),
        ({"weights": (1.0, -1.0)}, "Cfg.weights[1]"),
    ],
)
def test_invalid_values_name_field_and_range(kwargs: dict, fragment: str) -> None:
    with pytest.raises(ConfigError) as e:
        Cfg(**kwargs)
    assert fragment in str(e.value)


def test_unknown_key_lists_valid_keys() -> None:
    with pytest.raises(ConfigError, match="valid keys: \\['gain', 'mode', 'count', 'weights'\\]"):
        from_mapping(Cfg, {"gian": 1.0})


def test_from_overrides_reads_values_and_refuses_bad_items() -> None:
    c = from_overrides(Cfg, ["gain=2.5", "mode=b", "weights=[0.5, 1]"])
    assert (c.gain, c.mode, c.count, c.weights) == (2.5, "b", 3, (0.5, 1.0))
    with pytest.raises(ConfigError, match="expected KEY=VALUE"):
        from_overrides(Cfg, ["gain"])
    with pytest.raises(ConfigError, match="valid keys"):
        from_overrides(Cfg, ["gian=1"])
    with pytest.raises(ConfigError, match="out of range"):
        from_overrides(Cfg, ["gain=11"])


def test_load_node_params_merges_wildcard_and_node(tmp_path) -> None:
    f = tmp_path / "p.yaml"
    f.write_text("/**:\n  ros__parameters:\n    count: 5\n"
                 "node_a:\n  ros__parameters:\n    gain: 4.0\n    other: 1\n")
    c = load_node_params(Cfg, f, "node_a")
    assert (c.gain, c.count, c.mode) == (4.0, 5, "a")


def test_declare_config_descriptors_and_rejection() -> None:
    import rclpy
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from hand_capture.nodes.params import declare_config

    rclpy.init()
    try:
        node = Node("cfg_test", parameter_overrides=[Parameter("gain", value=3.5)])
        cfg = declare_config(node, Cfg)
        assert cfg.gain == 3.5
        desc = node.describe_parameter("gain")
        assert desc.description == "a gain [N/m]"
        assert desc.floating_point_range[0].to_value == 10.0
        assert "one of" in node.describe_parameter("mode").additional_constraints
        node.destroy_node()
        bad = Node("cfg_bad", parameter_overrides=[Parameter("mode", value="zzz")])
        with pytest.raises(ConfigError, match="not one of"):
            declare_config(bad, Cfg)
        bad.destroy_node()
    finally:
        rclpy.shutdown()
