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
