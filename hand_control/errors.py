"""Errors specific to hand_control; they extend the suite-wide hierarchy."""

from __future__ import annotations

from hand_capture.errors import ConfigError, DeviceError, HandSuiteError, InputError

__all__ = [
    "ConfigError",
    "DeviceError",
    "HandSuiteError",
    "InputError",
    "ServoError",
    "SimulationError",
    "SolverError",
]


class SolverError(HandSuiteError):
    """An optimisation problem could not be built or solved."""


class SimulationError(HandSuiteError):
    """The physics simulation diverged or was configured wrongly."""


class ServoError(DeviceError):
    """A servo bus or servo reported a fault, or did not answer."""
