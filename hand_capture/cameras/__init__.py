"""hand_capture .cameras package."""
