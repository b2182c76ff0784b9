"""Retargeting the operator's hand onto the planned grasp (III.6): where the grasp is put, how
the hand gets there, and when the controller is told that the hand holds the object. Pure
numpy (no simulation): a synthetic plan and operator poses."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.model import JOINT_INDEX, rest_pose
from hand_control.teleop.phases import Phase
from hand_control.teleop.retarget import (
    GraspRetarget,
    InterfaceConfig,
    PerformanceInterface,
    pose_matrix,
)

FLEX = [j for j in JOINT_INDEX if j.endswith(("_mcp_flex", "_pip_flex", "_dip_flex"))
        and not j.startswith("thumb")]
OBJECT = np.eye(4)
OBJECT[:3, 3] = (0.12, 0.0, 0.03)


def _hand(xyz, close: float = 0.0) -> np.ndarray:
    q = rest_pose().copy()
    q[0:3] = xyz
    for j in FLEX:
        q[JOINT_INDEX[j]] = close
    return q


#: a plan 10 cm to the side of where the operator will close the hand
Q_GRASP = _hand((0.08, -0.10, 0.08), 0.9)
Q_PRE = _hand((0.08, -0.10, 0.08), 0.3)


def _retarget() -> GraspRetarget:
    return GraspRetarget(Q_GRASP, OBJECT, q_pregrasp=Q_PRE, closing_span=0.008,
                         approach=InterfaceConfig())


def test_the_grasp_stays_where_the_object_rested_when_closing_began() -> None:
    """A box pushed by the closing fingers must not drag the grasp target after it (a plan
    that followed the object pushed it 2-3 cm and then dropped it)."""
    r = _retarget()
    q_op = _hand((0.06, 0.0, 0.15))
    T_op = pose_matrix(q_op)
    r.target(q_op, T_op, Phase.CLOSING, OBJECT, t=0.0)
    pushed = OBJECT.copy()
    pushed[:3, 3] += (0.0, 0.02, 0.0)
    q = r.target(q_op, T_op, Phase.CLOSING, pushed, t=5.0)  # long after the approach
    assert np.allclose(q[0:3], Q_GRASP[0:3], atol=1e-9)


def test_the_wrist_comes_down_onto_the_grasp_from_above_at_a_bounded_speed() -> None:
    cfg = InterfaceConfig()
    r = _retarget()
    q_op = _hand((0.06, 0.0, 0.15))
    T_op = pose_matrix(q_op)
    ts = np.arange(0.0, 3.0, 1 / 60)
    wrists = np.array([r.target(q_op, T_op, Phase.CLOSING, OBJECT, t=t)[0:3] for t in ts])
    speed = np.linalg.norm(np.diff(wrists, axis=0), axis=1) * 60
    assert speed.max() <= 1.6 * cfg.approach_speed  # smoothstep peaks at 1.5x the mean
    # over the plan's spot (x, y within 2 mm) it is still approach_height above it
    over = np.linalg.norm(wrists[:, :2] - Q_GRASP[:2], axis=1) < 0.002
    first = int(np.argmax(over))
    assert wrists[first, 2] == pytest.approx(Q_GRASP[2] + cfg.approach_height, abs=2e-3)
    assert np.allclose(wrists[-1], Q_GRASP[0:3], atol=1e-9)


def test_the_fingers_close_only_after_the_wrist_has_arrived_and_settled() -> None:
    cfg = InterfaceConfig()
    r = _retarget()
    q_op = _hand((0.06, 0.0, 0.15))
    T_op = pose_matrix(q_op)
    closed = _hand((0.06, 0.0, 0.15), 0.6)  # the operator closed the hand at once
    r.target(q_op, T_op, Phase.CLOSING, OBJECT, t=0.0)
    j = JOINT_INDEX["index_pip_flex"]
    t, flex = 1 / 60, []
    while t < 3.0:
        q = r.target(closed, T_op, Phase.CLOSING, OBJECT, t=t)
        at_plan = np.allclose(q[0:3], Q_GRASP[0:3], atol=1e-9)
        flex.append((t, at_plan, q[j]))
        t += 1 / 60
    # while the wrist travels the fingers go to the pre-grasp, never past it
    assert all(f <= Q_PRE[j] + 1e-9 for _, at, f in flex if not at)
    closing = [(tt, f) for tt, _, f in flex if f > Q_PRE[j] + 1e-6]
    arrived = min(tt for tt, at, _ in flex if at)
    assert closing and closing[0][0] >= arrived + cfg.settle_time - 1 / 60
    # ... and close at most at the configured rate, ending at the grasp
    assert flex[-1][2] == pytest.approx(Q_GRASP[j])
    rate = np.diff([f for _, f in closing]) * 60
    assert rate.max() <= (Q_GRASP[j] - Q_PRE[j]) / cfg.close_time * 1.01


def test_manipulation_is_reported_once_the_hands_grasp_has_closed() -> None:
    """The operator's grasp is detected before the hand's grasp is made: until the hand has
    closed, the controller is told 'closing' (PD only, no object target), and the object then
    follows the operator's wrist from that moment (no jump from the wrist's drift)."""
    ui = PerformanceInterface(Q_GRASP, OBJECT, q_pregrasp=Q_PRE)
    x0 = OBJECT[:3, 3] + (-0.06, 0.0, 0.06)
    t, reported, detected = 0.0, [], []
    for k in range(240):  # 4 s at 60 Hz: away, then in at 1 s, closing at once, holding
        t = k / 60
        close = float(np.clip((t - 1.0) / 0.2, 0.0, 1.0)) * 0.5
        away = (0.0, 0.0, 0.2) if t < 1.0 else (0.0, 0.0, 0.001 * t)  # drifts up 1 mm/s
        q = _hand(x0 + away, close)
        st = ui.update(t, q, OBJECT)
        reported.append(st.phase.phase)
        detected.append(ui.detector.phase)
        if st.phase.phase == Phase.MANIPULATION and st.phase.changed:
            T0 = st.phase.object_target
            assert np.allclose(T0, OBJECT, atol=1e-9)  # starts where the object is
        if st.phase.phase != Phase.MANIPULATION:
            assert st.phase.object_target is None
    first_detected = detected.index(Phase.MANIPULATION)
    first_reported = reported.index(Phase.MANIPULATION)
    assert first_reported > first_detected
    assert reported[first_detected:first_reported] == \
        [Phase.CLOSING] * (first_reported - first_detected)
    assert ui.retarget.closed
