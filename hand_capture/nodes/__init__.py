"""Thin rclpy wrappers: the only modules of hand_capture that import rclpy or messages."""
