"""Teleoperation end to end: the shipped performance meets the simulated object without being
made from the grasp plan, the offline chain grasps and lifts, the teleop graph lifts the box
from tracked input, and the teleop and replay graphs publish every topic of the contract."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ros_helpers import hand_suite

from hand_capture.bag import BagReader
from hand_capture.cameras.motion import MotionClip
from hand_capture.config import load_yaml
from hand_capture.paths import config_dir
from hand_control.sim.lockstep import LockstepRunner
from hand_control.sim.scenario import load_scenario
from hand_control.teleop.clip import performance_for_scenario, shipped_path
from hand_control.teleop.offline import run_teleop
from hand_control.teleop.phases import Phase

#: Topics of the README's contract that the teleop graph produces (colour images are off in
#: teleop; hand/shape needs calibration; /clock: the camera's clock is the graph's).
TELEOP_TOPICS = (
    "/camera/depth/image_raw", "/camera/depth/camera_info", "/hand/pose", "/hand/pose_truth",
    "/hand/joint_states", "/hand/markers", "/sim/joint_states", "/sim/object_pose",
    "/sim/contacts", "/control/grasp_phase", "/control/hand_target", "/control/object_target",
    "/control/joint_command", "/control/contact_forces", "/servo/joint_states", "/servo/goal",
    "/diagnostics")


@pytest.fixture(scope="module")
def performance():
    return performance_for_scenario("lift_box")


def test_shipped_performance_and_camera_pose_come_from_the_generator(performance) -> None:
    clip = MotionClip.from_file(shipped_path("lift_box"))
    assert np.allclose(clip.poses, performance.poses, atol=1e-9)
    cfg = load_yaml(config_dir() / "teleop.yaml")["/**"]["ros__parameters"]
    assert np.allclose(cfg["camera_position"], performance.camera_position, atol=1e-5)
    assert np.allclose(cfg["camera_rotation"], performance.camera_rotation, atol=1e-5)


def test_controller_period_matches_the_sims_state_rate() -> None:
    """The controller caps the object's rotational gains by its control period: in teleop it
    must be the period of the sim's joint states (timestep x steps_per_tick)."""
    from hand_capture.config import load_node_params
    from hand_control.control import ControllerNodeConfig
    from hand_control.sim.config import SimConfig, SimNodeConfig

    files = [config_dir() / f for f in ("sim.yaml", "controller.yaml", "teleop.yaml")]

    def merged(cls, node):
        vals = {}
        for f in files:
            cfg = load_node_params(cls, f, node)
            vals.update({k: v for k, v in vars(cfg).items() if v != getattr(cls(), k)})
        return cls(**vals)

    sim, node = merged(SimConfig, "sim"), merged(SimNodeConfig, "sim")
    ctl = merged(ControllerNodeConfig, "controller")
    assert ctl.control_period == pytest.approx(sim.timestep * node.steps_per_tick)


def test_offline_teleop_grasps_lifts_carries_and_releases(performance) -> None:
    idx = np.arange(0, len(performance.times), 2)  # a 30 fps camera
    runner = LockstepRunner(load_scenario("lift_box"), control_every=4)
    res = run_teleop(runner, performance.times[idx], performance.poses[idx])
    order = [int(p) for i, p in enumerate(res.phases) if i == 0 or p != res.phases[i - 1]]
    assert order == [Phase.REACHING, Phase.CLOSING, Phase.MANIPULATION, Phase.RELEASING]
    assert res.max_lift_mm > 70.0  # the performance lifts by 100 mm
    assert res.carried_mm > 70.0   # ... and carries 100 mm sideways
    assert res.qp_fallbacks == 0


def test_offline_teleop_with_tracking_like_noise_still_lifts(performance) -> None:
    """Tracking-like errors on the performance (a slow wrist drift plus per-frame jitter of
    the wrist and the fingers): the filtered wrist and the planned grasp still lift the box."""
    idx = np.arange(0, len(performance.times), 2)
    rng = np.random.default_rng(3)
    q = performance.poses[idx].copy()
    q[:, :3] += 0.003 * np.sin(np.linspace(0, 12, len(idx)))[:, None] \
        + rng.normal(0.0, 0.002, (len(idx), 3))
    q[:, 3:6] += rng.normal(0.0, 0.02, (len(idx), 3))
    q[:, 6:] += rng.normal(0.0, 0.05, (len(idx), 21))
    runner = LockstepRunner(load_scenario("lift_box"), control_every=4)
    res = run_teleop(runner, performance.times[idx], q)
    assert Phase.MANIPULATION in res.phases
    assert res.max_lift_mm > 50.0


def _topics(bag: Path) -> dict[str, int]:
    """Messages per topic of a bag."""
    counts: dict[str, int] = {}
    with BagReader(bag) as r:
        for m in r.messages():
            counts[m.topic] = counts.get(m.topic, 0) + 1
    return counts


def test_teleop_graph_lifts_the_box_from_tracked_input(tmp_path: Path) -> None:
    """The whole graph with the tracker in the loop (grasp_phase and the controller see only
    the tracked hand/pose, never the camera's ground truth): every topic is recorded and the
    grasp lifts the box off the table. On a quiet host it is lifted most of the performance's
    10 cm (bench pipeline: 98.6 mm); beside two CPU burners one of six runs held it only 30 mm
    up before it slipped, so the bound here is the box clearly off the table (20 mm)."""
    from hand_control.report.series import load_bag, max_lift_mm, positions

    p = hand_suite("run", "teleop", "-p", f"bag_recorder.output:={tmp_path}/bag")
    out, _ = p.communicate(timeout=300)
    assert p.returncode == 0, out[-5000:]
    assert "required node synthetic_camera finished" in out
    assert "grasp phase: manipulation" in out, out[-5000:]
    counts = _topics(tmp_path / "bag")
    missing = [t for t in TELEOP_TOPICS if counts.get(t, 0) == 0]
    assert not missing, (missing, counts, out[-4000:])
    data = load_bag(tmp_path / "bag", skip=("camera/depth/image_raw", "hand/markers",
                                            "control/contact_markers"))
    lift = max_lift_mm(positions(data.topics["sim/object_pose"].msgs))
    assert lift > 20.0, (lift, out[-4000:])


def test_replay_graph_runs_the_shipped_capture_through_the_chain(tmp_path: Path) -> None:
    p = hand_suite("run", "replay", "-p", f"bag_recorder.output:={tmp_path}/bag")
    out, _ = p.communicate(timeout=240)
    assert p.returncode == 0, out[-5000:]
    assert "required node bag_player finished" in out
    counts = _topics(tmp_path / "bag")
    chain = ("/hand/pose", "/control/grasp_phase", "/control/hand_target",
             "/control/joint_command", "/sim/joint_states", "/servo/goal")
    missing = [t for t in chain if counts.get(t, 0) == 0]
    assert not missing, (missing, counts, out[-4000:])
