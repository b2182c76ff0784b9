"""hand_control: everything that turns hand poses into forces, motion and servo commands."""
