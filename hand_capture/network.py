"""Network defaults of every process of the suite: a loopback-only ROS graph unless asked.

``hand-suite``, every node's ``main()`` (:func:`hand_capture.nodes.shell.run_node`) and the
launch files set ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` when the environment does not set
it, so a node is not discoverable from (and does not talk to) other machines by default. Set the
variable yourself (``SUBNET``, ``SYSTEM_DEFAULT`` or ``OFF``) to change it; see the README's
"Networking and safety".
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping

DISCOVERY_RANGE_VAR = "ROS_AUTOMATIC_DISCOVERY_RANGE"
DEFAULT_DISCOVERY_RANGE = "LOCALHOST"


def apply_network_defaults(env: MutableMapping[str, str] | None = None) -> str:
    """Set the discovery range to localhost unless ``env`` (default ``os.environ``) sets it;
    returns the range in force. Must run before ``rclpy.init`` (rcl reads it there)."""
    env = os.environ if env is None else env
    if not env.get(DISCOVERY_RANGE_VAR):
        env[DISCOVERY_RANGE_VAR] = DEFAULT_DISCOVERY_RANGE
    return env[DISCOVERY_RANGE_VAR]
