"""Thin rclpy wrappers: the only modules of hand_control that import rclpy or messages."""
