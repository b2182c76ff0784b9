"""Benchmarks of hand_control (contact, sim, servo, pipeline)."""
