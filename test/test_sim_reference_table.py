"""Reference.precompute: the tabulated rows (what the lockstep loop reads at every step) are
the samples Reference._sample computes at those times."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hand_control.sim.lockstep import LockstepRunner
from hand_control.sim.scenario import PHASES, load_scenario


@pytest.mark.parametrize("name", ["lift_box", "pour_cylinder"])
def test_tabulated_rows_match_the_sampled_reference(name: str) -> None:
    spec = load_scenario(name).with_(t_reach=0.05, t_close=0.05, t_settle=0.05, t_lift=0.1,
                                     t_carry=0.1, t_hold=0.05)
    ref = LockstepRunner(spec).reference
    dt = 1e-3
    ref.precompute(dt, t0=0.0)
    t, times = 0.0, []
    while t < ref.t_end + dt:  # the simulator's clock: repeated sums
        times.append(t)
        t += dt
    phases = set()
    for t in times:
        row = ref(t)
        assert ref(t) is row  # the same time twice: the same sample
        ref._last_t = math.nan  # then a sample computed from scratch
        plain = ref._sample(t)
        assert type(row.phase) is str and row.phase == plain.phase
        assert type(row.grasp) is bool and row.grasp == plain.grasp
        phases.add(row.phase)
        for a, b in ((row.q_target, plain.q_target),
                     (row.object_position, plain.object_position),
                     (row.object_quaternion, plain.object_quaternion)):
            assert a.dtype == np.float64 and not a.flags.writeable
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)
    assert phases == set(PHASES)
    # a time off the table: sampled as before
    off = ref(times[10] + 0.25 * dt)
    ref._last_t = math.nan
    np.testing.assert_array_equal(off.q_target, ref._sample(times[10] + 0.25 * dt).q_target)
