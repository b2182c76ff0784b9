"""MuJoCo simulation of the hand and objects, grasp planning, scenarios and the lockstep loop.

    world = SimWorld(build_scene(...), SimConfig())      # servos, guard, contacts (world.py)
    runner = LockstepRunner(load_scenario("lift_box"))   # sim + composite controller, no DDS
    result = runner.run()                                # success, tracking error, RTF

Command line: ``python -m hand_control.sim [SCENARIO ...] [--mode composite|pd_only|both]``.
"""

from hand_control.sim.config import SimConfig, SimNodeConfig
from hand_control.sim.contacts import ContactFrame, SimContact
from hand_control.sim.control_loop import (
    Command,
    ControllerCore,
    ControllerNodeConfig,
    HandKinematics,
)
from hand_control.sim.grasp import GraspPlan, fingertip_ik, plan_grasp, surface_contacts
from hand_control.sim.lockstep import EpisodeResult, LockstepRunner, build_world, run_episode
from hand_control.sim.scenario import (
    Reference,
    RefSample,
    ScenarioSpec,
    load_scenario,
    scenario_names,
)
from hand_control.sim.world import Divergence, ObjectPose, SimWorld

__all__ = [
    "Command", "ContactFrame", "ControllerCore", "ControllerNodeConfig", "Divergence",
    "EpisodeResult", "GraspPlan", "HandKinematics", "LockstepRunner", "ObjectPose", "RefSample",
    "Reference", "ScenarioSpec", "SimConfig", "SimContact", "SimNodeConfig", "SimWorld",
    "build_world", "fingertip_ik", "load_scenario", "plan_grasp", "run_episode",
    "scenario_names", "surface_contacts",
]
