"""hand_capture .tracking package."""
