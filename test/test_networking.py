"""Network defaults (issue #20 item 12): every console script (run_node) starts with
loopback-only discovery unless the environment sets the range."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from hand_capture.network import apply_network_defaults

ROOT = Path(__file__).resolve().parents[1]

# A node's main(): prints the discovery range in force when the node is built (after the
# shell's defaults, before rclpy.init ran them into rcl) and exits.
_NODE = """
import os, sys
from rclpy.node import Node
from hand_capture.nodes.shell import run_node

class Probe(Node):
    def __init__(self):
        super().__init__("probe")
        print("RANGE=" + os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "<unset>"), flush=True)
        raise KeyboardInterrupt  # a clean stop

sys.exit(run_node(Probe, ["probe"]))
"""


@pytest.mark.parametrize("given,expected", [(None, "LOCALHOST"), ("SUBNET", "SUBNET")])
def test_console_scripts_default_to_localhost_discovery(given, expected) -> None:
    env = {k: v for k, v in os.environ.items() if k != "ROS_AUTOMATIC_DISCOVERY_RANGE"}
    env["PYTHONPATH"] = str(ROOT)
    if given is not None:
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = given
    p = subprocess.run([sys.executable, "-c", _NODE], capture_output=True, text=True,
                       env=env, timeout=120)
    assert f"RANGE={expected}" in p.stdout, p.stdout + p.stderr


def test_apply_network_defaults_keeps_a_given_range() -> None:
    env: dict[str, str] = {}
    assert apply_network_defaults(env) == "LOCALHOST" and env == {
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    env = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "OFF"}
    assert apply_network_defaults(env) == "OFF"
