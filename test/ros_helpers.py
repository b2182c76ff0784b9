"""Small helpers for tests that need ROS 2 processes (not collected as tests)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent


def hand_suite(*args: str, **kwargs: object) -> subprocess.Popen:
    """Start ``hand-suite ARGS`` as a child process with merged text output."""
    return subprocess.Popen([str(VENV_BIN / "hand-suite"), *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"}, **kwargs)


def wait_for(cond: Callable[[], bool], timeout: float, period: float = 0.05) -> bool:
    """Poll ``cond`` until it is true or ``timeout`` [s] passes."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(period)
    return cond()
