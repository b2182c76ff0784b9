"""hand_control .dynamixel package."""
