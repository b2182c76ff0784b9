"""ExitTimer (hand_capture/nodes/exit_timer.py): ``_exit(code)`` from a C-library timer
thread, which works while the main thread holds the GIL, and never after ``cancel()``."""

from __future__ import annotations

import subprocess
import sys

import pytest
from ros_helpers import ROOT

from hand_capture.nodes.exit_timer import ExitTimer

HOLD_GIL = """
import sys
from hand_capture.nodes.exit_timer import ExitTimer
timer = ExitTimer.start(0.3, 7)
if "--cancel" in sys.argv:
    timer.cancel()
    timer.cancel()  # idempotent
print("armed" if timer is not None else "none", flush=True)
sum(range(10**8 if "--cancel" in sys.argv else 10**14))  # C code holding the GIL
print("returned", flush=True)
"""


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", HOLD_GIL, *args], cwd=ROOT, text=True,
                          capture_output=True, timeout=120)


def test_the_timer_exits_with_its_code_while_the_gil_is_held() -> None:
    r = _run()
    assert r.stdout == "armed\n", r.stderr
    assert r.returncode == 7


def test_a_cancelled_timer_never_fires() -> None:
    r = _run("--cancel")
    assert r.stdout == "armed\nreturned\n", r.stderr
    assert r.returncode == 0


def test_bad_arguments_are_refused() -> None:
    with pytest.raises(ValueError, match="seconds > 0"):
        ExitTimer.start(0.0, 0)
    with pytest.raises(ValueError, match="0..255"):
        ExitTimer.start(1.0, 256)
