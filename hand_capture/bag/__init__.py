"""hand_capture .bag package."""
