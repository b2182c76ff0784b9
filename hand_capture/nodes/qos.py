"""QoS profiles for subscriptions that want the newest message, never a backlog.

The executor takes one queued message per subscription per wake-up (rclpy's, and
:class:`~hand_capture.nodes.executor.LeanExecutor` without batching). When a node's callbacks
take longer than its inputs' period (a tracker on a large frame, the simulation stepping on
a loaded CPU), a deeper queue hands it messages that grow older with every wake-up; depth 1
hands it the newest one, and the ones it skipped are gone.
"""

from __future__ import annotations

from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

__all__ = ["newest_command_qos", "newest_sensor_qos"]


def newest_sensor_qos() -> QoSProfile:
    """SensorDataQoS (best effort, volatile, keep-last) with depth 1: matches any sensor
    publisher, realsense-ros included."""
    s = qos_profile_sensor_data
    return QoSProfile(depth=1, reliability=s.reliability, durability=s.durability,
                      history=s.history)


def newest_command_qos() -> QoSProfile:
    """Reliable, keep-last depth 1: for absolute set-points (joint position commands), where
    the newest one supersedes every earlier one."""
    return QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
