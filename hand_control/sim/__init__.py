"""MuJoCo simulation of the hand and objects, grasp planning, scenarios and the lockstep loop.

    world = SimWorld(build_scene(...), SimConfig())      # servos, guard, contacts (world.py)
    runner = LockstepRunner(load_scenario("lift_box"))   # sim + composite controller, no DDS
                                                         # (hand_control.control.loop)
    result = runner.run()                                # success, tracking error, RTF

Command line: ``python -m hand_control.sim [SCENARIO ...] [--mode composite|pd_only|both]``.
"""

from hand_control.sim.config import SimConfig, SimNodeConfig
from hand_control.sim.contacts import ContactFrame, SimContact
from hand_control.sim.grasp import GraspPlan, fingertip_ik, plan_grasp, surface_contacts
from hand_control.sim.kinematics import MujocoKinematics, hand_limits
from hand_control.sim.lockstep import (
    ControllerSetup,
    EpisodeResult,
    LockstepRunner,
    build_world,
    controller_setup,
    run_episode,
)
from hand_control.sim.scenario import (
    Reference,
    RefSample,
    ScenarioSpec,
    load_scenario,
    scenario_names,
)
from hand_control.sim.world import Divergence, ObjectPose, SimWorld

__all__ = [
    "ContactFrame", "ControllerSetup", "Divergence", "EpisodeResult", "GraspPlan",
    "LockstepRunner", "MujocoKinematics", "ObjectPose", "RefSample", "Reference",
    "ScenarioSpec", "SimConfig", "SimContact", "SimNodeConfig", "SimWorld", "build_world",
    "controller_setup", "fingertip_ik", "hand_limits", "load_scenario", "plan_grasp",
    "run_episode", "scenario_names", "surface_contacts",
]
