"""hand_capture: everything that turns sensors into hand poses (pure core + thin nodes)."""
