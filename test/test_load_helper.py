"""test/load.py: the CPU burners that HAND_SUITE_TEST_LOAD starts stop by themselves."""

from __future__ import annotations

import pytest
from load import CpuLoad
from ros_helpers import wait_for


def test_burners_run_then_stop_by_themselves() -> None:
    load = CpuLoad(2, seconds=0.5).start()
    try:
        assert len(load.procs) == 2
        assert wait_for(lambda: load.alive() == 0, 30.0), "burners outlived their deadline"
    finally:
        load.stop()


def test_bad_arguments_are_refused() -> None:
    with pytest.raises(ValueError, match="burners"):
        CpuLoad(-1)
    with pytest.raises(ValueError, match="seconds"):
        CpuLoad(1, seconds=0.0)


_SIGINT_PROBE = """
import signal, subprocess, sys
from ros_helpers import restore_ctrl_c

def child_ignores_sigint() -> bool:
    out = subprocess.run(["grep", "SigIgn", "/proc/self/status"], capture_output=True,
                         text=True, check=True).stdout
    return bool(int(out.split()[1], 16) & (1 << (signal.SIGINT - 1)))

signal.signal(signal.SIGINT, signal.SIG_IGN)  # as `cmd &` from a shell starts a process
print(child_ignores_sigint(), restore_ctrl_c(), child_ignores_sigint(), restore_ctrl_c())
"""


def test_a_suite_started_in_the_background_still_interrupts_its_children() -> None:
    """A shell's `cmd &` starts the suite with SIGINT ignored, and every child inherited it: a
    run of the suite launched that way failed the tests that stop a program with Ctrl-C.
    restore_ctrl_c (called by conftest) gives children their default Ctrl-C back."""
    import subprocess
    import sys

    from ros_helpers import ROOT

    out = subprocess.run([sys.executable, "-c", _SIGINT_PROBE], capture_output=True, text=True,
                         cwd=ROOT / "test", env={"PYTHONPATH": str(ROOT / "test")}, timeout=60)
    assert out.returncode == 0, out.stderr
    # before: the child ignores SIGINT; restored (True); after: it does not; nothing to redo
    assert out.stdout.split() == ["True", "True", "False", "False"], out.stdout
