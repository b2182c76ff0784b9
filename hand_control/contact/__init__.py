"""hand_control .contact package."""
