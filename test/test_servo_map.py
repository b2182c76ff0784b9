"""Servo maps: the shipped maps load; bad maps are refused with messages that say what is
wrong; retargeting follows the map's weights, scale, offset and direction."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from hand_capture.model.joints import ARTICULATED_JOINTS
from hand_control.dynamixel.control_table import TICKS_PER_RAD
from hand_control.dynamixel.retarget import LowPassFilter, Retargeter, angles_to_ticks
from hand_control.dynamixel.servo_map import load_servo_map, servo_map_from_dict
from hand_control.errors import ConfigError, InputError

GOOD = {
    "name": "t",
    "handedness": "right",
    "operating_mode": "position",
    "defaults": {"model": "XL330-M288"},
    "servos": [
        {"id": 1, "name": "a", "joints": {"index_mcp_flex": 1.0}},
        {"id": 2, "name": "b", "joints": {"index_pip_flex": 0.5, "index_dip_flex": 0.5},
         "scale": 2.0, "offset": 0.1, "direction": -1, "min_position": 100,
         "max_position": 4000},
    ],
}


def bad(**changes) -> dict:
    d = copy.deepcopy(GOOD)
    for path, value in changes.items():
        *keys, last = path.split("__")
        node = d
        for k in keys:
            node = node[int(k)] if k.isdigit() else node[k]
        node[int(last) if last.isdigit() else last] = value
    return d


def test_shipped_maps_load() -> None:
    leap = load_servo_map("leap_hand")
    assert len(leap.servos) == 16 and leap.ids == tuple(range(16))
    assert {s.model.name for s in leap.servos} == {"XC330-M288"}
    assert leap.operating_mode == "current_based_position"
    generic = load_servo_map("generic_3dof")
    assert len(generic.servos) == 3
    assert generic.by_id(3).model.name == "XM430-W350"
    assert generic.by_id(3).current_limit_raw == round(1500 / 2.69)  # 2.69 mA units


@pytest.mark.parametrize(("data", "words"), [
    (bad(servos__0__joints={"index_mcp_flx": 1.0}),
     ["unknown joint name(s) ['index_mcp_flx']", "valid joints:", "thumb_tm_abd"]),
    (bad(servos__1__id=1), ["duplicate servo ID 1", "'a'", "'b'"]),
    (bad(servos__1__max_position=5000), ["max_position = 5000", "0..4095"]),
    (bad(servos__1__min_position=4000, servos__1__max_position=100), ["must be below"]),
    (bad(servos__0__model="XC999"), ["model 'XC999' is not known", "XC330-M288"]),
    (bad(servos__0__current_limit_ma=5000), ["current_limit_ma = 5000", "1750"]),
    (bad(servos__0__direction=2), ["direction must be 1 or -1"]),
    (bad(servos__0__id=300), ["id must be an integer in 0..252"]),
    (bad(servos__0__speed=3), ["unknown key(s) ['speed']", "valid keys"]),
    (bad(operating_mode="velocity"), ["operating_mode 'velocity'", "current_based_position"]),
    (bad(servos__0__joints={"index_mcp_flex": float("nan")}), ["finite number"]),
    (bad(servos=[]), ["non-empty list"]),
])
def test_bad_maps_say_what_is_wrong(data, words) -> None:
    with pytest.raises(ConfigError) as e:
        servo_map_from_dict(data)
    for w in words:
        assert w in str(e.value), str(e.value)


def test_every_problem_is_listed_at_once() -> None:
    data = bad(servos__0__model="nope", servos__1__direction=0, handedness="both")
    msg = str(pytest.raises(ConfigError, servo_map_from_dict, data).value)
    assert "model 'nope'" in msg and "direction" in msg and "handedness" in msg


def test_missing_map_lists_the_available_ones() -> None:
    with pytest.raises(ConfigError, match=r"available servo maps: \[.*'leap_hand'"):
        load_servo_map("no_such_hand")


def test_retarget_weights_scale_offset_direction() -> None:
    smap = servo_map_from_dict(GOOD)
    rt = Retargeter(smap)
    q = dict.fromkeys(ARTICULATED_JOINTS, 0.0)
    q.update(index_mcp_flex=0.4, index_pip_flex=0.2, index_dip_flex=0.6)
    theta = rt.from_named(list(q), list(q.values()))
    assert theta[0] == pytest.approx(0.4)
    assert theta[1] == pytest.approx(0.1 - 2.0 * (0.5 * 0.2 + 0.5 * 0.6))
    assert angles_to_ticks(theta)[0] == pytest.approx(2048 + 0.4 * TICKS_PER_RAD)
    # by name: order does not matter, only the joints the map uses are needed
    theta2 = rt.from_named(["index_dip_flex", "index_pip_flex", "index_mcp_flex"],
                           [0.6, 0.2, 0.4])
    assert np.allclose(theta, theta2)


@pytest.mark.parametrize(("names", "values", "match"), [
    (["index_mcp_flex", "index_pip_flex"], [0.1, 0.2], "missing"),
    (["index_mcp_flex", "index_pip_flex", "index_dip_flex"], [0.1, np.nan, 0.0], "non-finite"),
    (["index_mcp_flex", "index_pip_flex", "index_dip_flex"], [0.1, 0.2], "3 joint names"),
    (["index_mcp_flex", "index_pip_flex", "index_dip_flex", "wrist"], [0] * 4, "unknown"),
    (["index_mcp_flex", "index_mcp_flex", "index_pip_flex", "index_dip_flex"], [0] * 4,
     "duplicate"),
])
def test_bad_input_is_rejected(names, values, match) -> None:
    rt = Retargeter(servo_map_from_dict(GOOD))
    with pytest.raises(InputError, match=match):
        rt.from_named(names, values)


def test_extra_names_are_ignored_when_not_strict() -> None:
    rt = Retargeter(servo_map_from_dict(GOOD))
    names = ["object_x", "index_mcp_flex", "index_pip_flex", "index_dip_flex"]
    assert rt.from_named(names, [5.0, 0.3, 0.0, 0.0], strict=False)[0] == pytest.approx(0.3)


def test_low_pass_filter_is_first_order() -> None:
    f = LowPassFilter(cutoff_hz=10.0)
    f.reset(np.zeros(1))
    y = f(np.ones(1), dt=0.01)
    assert y[0] == pytest.approx(1 - np.exp(-2 * np.pi * 10 * 0.01))
    for _ in range(200):
        y = f(np.ones(1), dt=0.01)
    assert y[0] == pytest.approx(1.0)
    off = LowPassFilter(cutoff_hz=0.0)
    off.reset(np.zeros(1))
    assert off(np.ones(1), 0.01)[0] == 1.0
