"""hand_capture .model package."""
