"""hand_control .sim package."""
