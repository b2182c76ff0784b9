"""Teleoperation in one process: a hand-pose stream drives the controller and the simulation.

What the teleop graph does over topics (grasp_phase + controller + sim nodes), in lockstep and
without DDS, for tests and offline evaluation of a recorded or generated performance:

* the grasp-phase detector (dissertation III.6) sees the operator's hand keypoints and the
  simulated object: in *manipulation* the grasp torques are on and the object's target follows
  the operator's wrist rigidly; otherwise the hand is PD-only (III.5.2 drops the grasp term while
  closing);
* each hand pose (world frame, at its own rate) becomes the PD target of the simulated hand
  through :class:`GraspRetarget` (the tracked closing replaced by the planned grasp).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from hand_capture.model import HandModel, matrix_to_quat
from hand_control.sim.lockstep import LockstepRunner
from hand_control.teleop.phases import Phase, PhaseConfig
from hand_control.teleop.retarget import InterfaceConfig, PerformanceInterface, object_matrix

__all__ = ["TeleopResult", "run_teleop"]


@dataclass(frozen=True)
class TeleopResult:
    """Outcome of an offline teleoperation run."""

    phases: np.ndarray          # (T,) Phase per hand pose
    object_positions: np.ndarray  # (T, 3) object position at each hand pose [m]
    max_lift_mm: float          # highest object lift above its start [mm]
    carried_mm: float           # horizontal object displacement at the end of manipulation [mm]
    qp_fallbacks: int


def run_teleop(runner: LockstepRunner, times: np.ndarray, poses: np.ndarray,
               phase_config: PhaseConfig | None = None,
               config: InterfaceConfig | None = None, model: HandModel | None = None,
               synthesizer: Callable[[np.ndarray, np.ndarray], Any] | None = None,
               initial: np.ndarray | None = None) -> TeleopResult:
    """Drive ``runner``'s world with world-frame hand ``poses`` (T, 27) at ``times`` (T,) [s].

    The simulation starts with the hand at ``initial`` (default ``poses[0]``; the teleop
    graph's sim starts at the scenario's start, ``runner.reference.initial_pose``) and runs
    until ``times[-1]``. ``synthesizer``: the grasp synthesised from the operator's hand as
    closing begins (III.6, :class:`~hand_control.grasp.synthesis.PerformerSynthesizer`)
    instead of the runner's plan.
    """
    w, core = runner.world, runner.core
    model = model or HandModel()
    w.reset()
    q0 = poses[0] if initial is None else np.asarray(initial, dtype=np.float64)
    w.set_initial_state(q0)
    w.set_command(q0, np.zeros(w.n_hand))
    core.grasp_override = False
    name = runner.obj.name
    op = w.object_pose(name)
    p0 = op.position.copy()
    ui = PerformanceInterface(runner.plan.q_grasp, object_matrix(op.position, op.quaternion),
                              phase_config, config, model, q_pregrasp=runner.plan.q_pregrasp,
                              synthesizer=synthesizer, closing=runner.plan.closing)
    phases, objs = [], []
    k, dt = 0, w.model.opt.timestep
    n = int(round(times[-1] / dt))
    carried = 0.0
    for _ in range(n):
        t = w.time
        while k < len(times) and times[k] <= t + 1e-12:
            q = poses[k]
            op = w.object_pose(name)
            T_obj = object_matrix(op.position, op.quaternion)
            step = ui.update(times[k], q, T_obj)
            up = step.phase
            core.hand_target_override = step.hand_target
            core.grasp_override = up.phase == Phase.MANIPULATION
            if up.object_target is not None:
                x, y, z, qw = matrix_to_quat(up.object_target[:3, :3])
                core.object_target_override = (up.object_target[:3, 3].copy(),
                                               np.array([qw, x, y, z]))
                carried = float(np.linalg.norm((op.position - p0)[:2]))
            else:
                core.object_target_override = None
            phases.append(int(up.phase))
            objs.append(op.position.copy())
            k += 1
        runner.control_step(t)
        w.step()
    o = np.array(objs)
    return TeleopResult(np.array(phases), o, float((o[:, 2] - p0[2]).max() * 1e3),
                        carried * 1e3, core.counters["qp_fallbacks"])
