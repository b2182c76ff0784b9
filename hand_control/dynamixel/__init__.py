"""DYNAMIXEL servo hands (Protocol 2.0): drive a servo hand from the tracked or simulated hand.

Modules (no rclpy; the ROS node is ``hand_control.nodes.servo_bridge``):

* ``control_table``: X-series control-table addresses, models, error bits, units;
* ``servo_map``: per-hand YAML maps (servo ID, model, followed joints, limits), validated;
* ``retarget``: hand-model joint angles -> servo angles, low-pass filter;
* ``safety``: goal clamping and rate limiting, input timeout, failure counter, fault latch;
* ``bus``: bus I/O through ``dynamixel_sdk`` with explicit per-servo results;
* ``bridge``: :class:`~hand_control.dynamixel.bridge.ServoBridge`, the control loop;
* ``protocol`` and ``emulator``: packets, and a multi-servo emulator on a pty
  (``python -m hand_control.dynamixel.emulator --map leap_hand``).
"""
