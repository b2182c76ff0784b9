"""Exception hierarchy shared by the whole suite.

Every error the suite raises on purpose derives from :class:`HandSuiteError`, so a caller can
catch the suite's failures without catching programming errors. Third-party exceptions are
wrapped with ``raise ... from e`` so the original cause stays visible.
"""

from __future__ import annotations


class HandSuiteError(Exception):
    """Base class of every error raised on purpose by hand_suite."""


class ConfigError(HandSuiteError, ValueError):
    """A configuration value is missing, of the wrong type or out of its valid range."""


class InputError(HandSuiteError, ValueError):
    """Data handed to a core function is malformed (NaN, Inf, wrong shape, unknown name)."""


class RejectedInputError(InputError):
    """A message failed the input-validation layer (:mod:`hand_capture.validate`): the text
    names the field, the value and the valid range with its unit. Nodes count and log it."""


class DeviceError(HandSuiteError):
    """A hardware device (camera, touch surface, servo bus) is missing or failed."""


class BagError(HandSuiteError):
    """A rosbag2 bag cannot be written or read (missing, truncated, corrupt)."""


class GraphError(HandSuiteError):
    """A node graph cannot be described, started or stopped."""
