"""hand_capture .touch package."""
