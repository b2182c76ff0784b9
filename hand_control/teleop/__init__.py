"""Teleoperation: the performance interface that turns a tracked hand into grasp phases."""
