"""hand_control .control package."""
