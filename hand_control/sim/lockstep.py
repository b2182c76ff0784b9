"""Simulation and composite controller in one process, in lockstep, without DDS.

The same core classes the nodes wrap (:class:`SimWorld`, :class:`CompositeController`,
:class:`Reference`) run one scenario here for benchmarks, tests and offline work. Per control
step (every ``control_every`` physics steps; 1 = the 1 kHz of the dissertation):

1. read the hand state, the object state and the hand-object contacts;
2. the composite controller (seed 000 eq. 8-13) computes the grasp torques ``tau_grasp``
   realising the virtual object wrench (eq. 9) through the contact-force QP (III.23) and the
   Jacobian transpose (eq. 12, computed by MuJoCo at the contacts of the live state:
   :meth:`ControllerCore.step_world`; seed 000's eq. 10, which needs the simulator's contact
   forces, goes through a :class:`ContactFrame` and :meth:`ControllerCore.step`; select it
   with ``CompositeControlConfig(method="seed000")``);
3. the sim's servos get the reference pose as PD targets (eq. 8, applied at every physics
   step) and ``tau_grasp`` as feed-forward effort. Gravity on the hand is cancelled inside
   MuJoCo (``hand_gravcomp``), which is ``tau_gravity`` of eq. (III.19).

PD-only trajectory tracking (the papers' baseline, dissertation sec. III.8.2) is the same run
with ``CompositeControlConfig(mode="pd_only")``: no grasp torques. The controller
(:mod:`hand_control.control.loop`) sees the world through the kinematics interface
(:class:`MujocoKinematics`, and :class:`SimWorld` as ``LiveContacts``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from hand_capture.model.joints import JOINT_NAMES, quat_wxyz_to_matrix
from hand_capture.model.mjcf import ObjectSpec, build_scene
from hand_control.contact.feasibility import dynamic_feasibility
from hand_control.control import (
    CompositeControlConfig,
    ControllerCore,
    ControllerNodeConfig,
    joint_gains,
)
from hand_control.errors import ConfigError
from hand_control.sim.config import SimConfig
from hand_control.sim.contacts import ContactFrame
from hand_control.sim.grasp import GraspPlan, plan_grasp
from hand_control.sim.kinematics import MujocoKinematics
from hand_control.sim.scenario import Reference, ScenarioSpec
from hand_control.sim.world import SimWorld

__all__ = ["ControllerSetup", "EpisodeResult", "LockstepRunner", "build_world",
           "controller_setup", "object_spec", "run_episode"]

IMPACT_BALL = "impact_ball"
_DEFAULT_SIZES = {"box": (0.0285, 0.0285, 0.0285), "ball": (0.035,), "cylinder": (0.03, 0.06)}


_GRASP_OBJECTS: dict[tuple, object] = {}


def scenario_object(spec: ScenarioSpec) -> object:
    """The :class:`~hand_control.grasp.objects.GraspObject` of a scenario's ``object_shape``
    (built once per shape, mass and friction: its distance field takes a second)."""
    from hand_control.grasp.objects import parse_object

    key = (spec.object_shape, spec.object_mass, spec.object_friction)
    if key not in _GRASP_OBJECTS:
        _GRASP_OBJECTS[key] = parse_object(spec.object_shape, spec.object_mass,
                                           spec.object_friction, name="object")
    return _GRASP_OBJECTS[key]


def object_spec(spec: ScenarioSpec) -> tuple[ObjectSpec, tuple[float, ...]]:
    """The MJCF object of a scenario, resting on the table, and its size."""
    x, y = spec.object_xy
    if spec.object_shape:
        g = scenario_object(spec)
        o = g.object_spec((x, y), spec.object_yaw)
        return o, tuple(o.size)
    size = tuple(spec.object_size) or _DEFAULT_SIZES[spec.object_kind]
    if spec.object_kind == "cylinder":  # the export's "stick" stood on its end
        o = ObjectSpec("stick", name="cylinder", size=size, mass=spec.object_mass,
                       friction=spec.object_friction, pos=(x, y, size[1] + 1e-4),
                       euler=(0.0, math.pi / 2, 0.0), rgba=(0.8, 0.5, 0.2, 1.0))
    else:
        h = size[2] if spec.object_kind == "box" else size[0]
        o = ObjectSpec(spec.object_kind, name=spec.object_kind, size=size,
                       mass=spec.object_mass, friction=spec.object_friction,
                       pos=(x, y, h + 1e-4))
    return o, size


def scene_objects(spec: ScenarioSpec) -> tuple[list[ObjectSpec], tuple[float, ...]]:
    """The scenario's free objects in scene order (its object, then the optional falling
    ball) and the object's size."""
    obj, size = object_spec(spec)
    objects = [obj]
    if spec.perturb_mass > 0:
        r = spec.perturb_radius
        objects.append(ObjectSpec("ball", name=IMPACT_BALL, size=(r,), mass=spec.perturb_mass,
                                  friction=0.5, pos=(0.45, 0.30, r + 1e-4),
                                  rgba=(0.8, 0.2, 0.2, 1.0)))
    return objects, size


def build_world(spec: ScenarioSpec, config: SimConfig | None = None,
                gains: CompositeControlConfig | None = None
                ) -> tuple[SimWorld, ObjectSpec, tuple[float, ...]]:
    """The MuJoCo world of a scenario (hand, table, object, optional falling ball); its
    servos get the PD gains of ``gains`` (default: Table 1 = Table III.1) in the MJCF."""
    objects, size = scene_objects(spec)
    obj = objects[0]
    config = config or SimConfig()
    kp, kd = joint_gains(gains or CompositeControlConfig(), JOINT_NAMES)
    xml = build_scene(objects, hand_gravcomp=config.hand_gravcomp, servo_kp=kp, servo_kd=kd)
    return SimWorld(xml, config), obj, size


def scenario_plan(spec: ScenarioSpec, world: SimWorld, obj: ObjectSpec,
                  size: tuple[float, ...]) -> GraspPlan:
    """The scenario's grasp: fingertip IK onto the object (or onto an ``object_shape``'s
    primitive proxy), or grasp synthesis (``grasp_source: synthesis``, dissertation III.4).

    Raises:
        ConfigError: IK asked for an object without a primitive proxy.
        SolverError: the IK or the synthesis found no grasp.
    """
    pose = world.object_pose(obj.name)
    if spec.grasp_source == "synthesis":
        from hand_control.grasp.synthesis import synthesize_for_world

        g = scenario_object(spec) if spec.object_shape else None
        return synthesize_for_world(spec, obj, g, pose.position, pose.quaternion)
    if not spec.object_shape:
        return plan_grasp(world.model, obj.name, obj.kind, size, pose.position,
                          pose.quaternion, depth=spec.grasp_depth,
                          upright_cylinder=spec.object_kind == "cylinder")
    g = scenario_object(spec)
    if g.ik_proxy is None:
        raise ConfigError(f"scenario {spec.name}: the fingertip IK substitute has no "
                          f"primitive layout for {spec.object_shape!r}; use grasp_source: "
                          "synthesis")
    kind, psize, offset = g.ik_proxy
    centre = pose.position + quat_wxyz_to_matrix(pose.quaternion) @ np.asarray(offset)
    return plan_grasp(world.model, obj.name, kind, psize, centre, pose.quaternion,
                      depth=spec.grasp_depth, upright_cylinder=kind == "stick")


@dataclass
class ControllerSetup:
    """What a controller of a scenario needs, built from the scenario's world (not stepped):
    the world, its object, the grasp plan, the reference motion and the controller core."""

    world: SimWorld
    obj: ObjectSpec
    size: tuple[float, ...]
    plan: GraspPlan
    reference: Reference
    core: ControllerCore


def controller_setup(spec: ScenarioSpec, sim_config: SimConfig | None = None,
                     controller_config: ControllerNodeConfig | None = None,
                     gains: CompositeControlConfig | None = None, control_period: float = 0.001,
                     plan: GraspPlan | None = None) -> ControllerSetup:
    """The scenario's world, grasp plan (fingertip IK), reference and a
    :class:`ControllerCore` on the world's kinematics (:class:`MujocoKinematics`)."""
    world, obj, size = build_world(spec, sim_config, gains)
    pose = world.object_pose(obj.name)
    plan = plan or scenario_plan(spec, world, obj, size)
    reference = Reference(spec, plan, pose.position, pose.quaternion)
    body = world.objects[obj.name]["body"]
    core = ControllerCore(
        MujocoKinematics(world), reference, spec.object_mass,
        controller_config or ControllerNodeConfig(scenario=spec.name), gains,
        object_inertia=float(world.model.body_inertia[body].min()),
        control_period=control_period)
    return ControllerSetup(world, obj, size, plan, reference, core)


@dataclass
class EpisodeResult:
    """Outcome of one lockstep episode (errors over lifting, carrying and holding)."""

    scenario: str
    mode: str
    success: bool
    feasible: bool
    final_error_mm: float
    pos_err_mean_mm: float
    pos_err_max_mm: float
    rot_err_mean_deg: float
    object_lift_mm: float
    steps: int
    control_steps: int
    qp_fallbacks: int
    divergences: int
    wall_s: float
    sim_s: float
    control_s: float
    grasp_residual_mm: float
    trace: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def rtf(self) -> float:
        return self.sim_s / self.wall_s if self.wall_s > 0 else math.inf


def _angle_deg(qa: np.ndarray, qb: np.ndarray) -> float:
    return math.degrees(2.0 * math.acos(min(1.0, abs(float(qa @ qb)))))


class LockstepRunner:
    """Run scenarios with the sim and the composite controller in one process.

    Args:
        spec: the scenario.
        sim_config: the world's settings (1 ms step, guard).
        controller_config: the controller's own settings (reference source, filters).
        control_every: physics steps per control step (1 = 1 kHz).
        plan: a grasp plan (default: fingertip IK on the scenario's object).
        gains: every gain and QP setting (``mode="pd_only"`` for the baseline,
            ``method="seed000"`` for seed 000's eq. 10-11); the sim's servos get its PD gains.
    """

    def __init__(self, spec: ScenarioSpec, sim_config: SimConfig | None = None,
                 controller_config: ControllerNodeConfig | None = None,
                 control_every: int = 1, plan: GraspPlan | None = None,
                 gains: CompositeControlConfig | None = None) -> None:
        self.spec = spec
        self.control_every = max(1, int(control_every))
        timestep = (sim_config or SimConfig()).timestep
        setup = controller_setup(spec, sim_config, controller_config, gains,
                                 control_period=self.control_every * timestep, plan=plan)
        self.world, self.obj, self.size = setup.world, setup.obj, setup.size
        self.plan, self.reference, self.core = setup.plan, setup.reference, setup.core
        self.controller_config = self.core.config
        self.gains = self.core.gains
        self.controller = self.core.controller
        self._no_contacts = ContactFrame.empty(0.0)
        # the simulator's contact forces: only seed 000's eq. (10) uses them; the other
        # methods take the lean path (ControllerCore.step_world)
        self._contact_forces = self.controller.qp.config.method == "seed000"
        self._object_body = int(self.world.objects[self.obj.name]["body"])
        # Live views into MjData (its arrays never move), read at every step: the object's
        # state and the hand's joints. The controller uses them within the step only.
        w = self.world
        self._obj_views = w.object_state_views(self.obj.name)
        self._obj_pos, self._obj_quat = self._obj_views[0], self._obj_views[1]
        self._hand_views = None
        if isinstance(w._qpos_idx, slice) and isinstance(w._dof_idx, slice):
            self._hand_views = (w.data.qpos[w._qpos_idx], w.data.qvel[w._dof_idx])
        self.world.set_initial_state(self.reference.initial_pose)
        self.world.set_command(self.reference.initial_pose, np.zeros(self.world.n_hand))
        # the references at every physics step's time, once (a row lookup per step)
        self.reference.precompute(self.world.model.opt.timestep, t0=self.world.time)

    def feasibility(self, mu: float | None = None, mass: float | None = None) -> bool:
        """Dynamic feasibility LP (III.10-III.16) of the planned contacts for this object."""
        mu = self.spec.object_friction if mu is None else mu
        mass = self.spec.object_mass if mass is None else mass
        r = dynamic_feasibility(self.plan.contact_set(mu), mass,
                                self.world.object_pose(self.obj.name).position)
        return bool(r.feasible)

    def control_step(self, t: float) -> None:
        """One controller update: references, state, contacts -> servo command."""
        w = self.world
        q, qd = w.hand_state() if self._hand_views is None else self._hand_views
        if not self._contact_forces:
            cmd = self.core.step_world(t, w, self._object_body, q, qd, self._obj_views)
            if cmd.pd_only:  # zero efforts
                w.set_targets(cmd.positions)
            else:
                w.set_command(cmd.positions, cmd.efforts, check=False)  # fresh, finite
            self.last_command = cmd
            return
        self._control_step_frame(t, q, qd)

    def _control_step_frame(self, t: float, q: np.ndarray, qd: np.ndarray) -> None:
        """:meth:`control_step` through a :class:`ContactFrame` with the contact Jacobians
        and :meth:`ControllerCore.step` (every contact-force method, seed 000's included)."""
        w = self.world
        pos, quat, vel, omega_body, rot = self._obj_views
        composite = self.core.needs_contacts(t)
        cf = w.contacts(self.obj.name, jacobians=True, forces=self._contact_forces) \
            if composite else self._no_contacts
        # everything comes from the world in this process: the controller's fast path
        # (no re-validation of the simulator's arrays; its output is still checked)
        cmd = self.core.step(
            t, q, qd, (pos, quat, vel, rot.dot(omega_body)),  # angular velocity, world frame
            cf.body1, cf.points, cf.normals, cf.forces, cf.friction,
            contact_set=cf.to_contact_set(trusted=True) if composite and len(cf) else None,
            trusted=True)
        w.set_command(cmd.positions, cmd.efforts, check=False)  # fresh, finite (n_hand,)
        self.last_command = cmd

    def _tracking_errors(self, times: list[float], poses: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
        """Position [m] and orientation [deg] errors of the object vs its target at ``times``
        (``poses``: (N, 7) position + quaternion after each of those steps); ``[nan]`` when
        there are none."""
        if not times:
            return np.array([math.nan]), np.array([math.nan])
        refs = [self.reference(t) for t in times]
        target = np.array([r.object_position for r in refs])
        tquat = np.array([r.object_quaternion for r in refs])
        pos_err = np.sqrt(((poses[:, 0:3] - target) ** 2).sum(axis=1))
        dot = np.minimum(1.0, np.abs((poses[:, 3:7] * tquat).sum(axis=1)))
        return pos_err, np.degrees(2.0 * np.arccos(dot))

    def _events(self, t: float, schedule: list[tuple[float, float]], dropped: list[bool]
                ) -> None:
        while schedule and t >= schedule[0][0]:
            self.world.set_object_friction(self.obj.name, schedule.pop(0)[1])
        s = self.spec
        if s.perturb_mass > 0 and not dropped[0] and t >= s.perturb_time:
            dropped[0] = True
            p = self.world.object_pose(self.obj.name).position
            o = self.world.objects[IMPACT_BALL]
            d = self.world.data
            top = self.size[2] if self.obj.kind in ("box", "composite") else self.size[0] if \
                self.obj.kind == "ball" else self.size[1]
            d.qpos[o["qpos"]:o["qpos"] + 3] = p + np.array([0.0, 0.0, top + s.perturb_height
                                                             + s.perturb_radius])
            d.qpos[o["qpos"] + 3:o["qpos"] + 7] = (1, 0, 0, 0)
            d.qvel[o["dof"]:o["dof"] + 6] = 0.0

    def run(self, duration: float | None = None, trace: bool = False) -> EpisodeResult:
        """Run the episode from the initial state; returns the tracking figures.

        Raises:
            SimulationError: the simulation diverged (with ``on_instability: raise``).
        """
        w = self.world
        w.reset()
        spec = self.spec
        duration = self.reference.t_end if duration is None else duration
        n = int(round(duration / w.model.opt.timestep))
        fs = spec.friction_schedule
        schedule = sorted(zip(fs[0::2], fs[1::2], strict=True))
        dropped = [spec.perturb_mass <= 0]
        p_init = w.object_pose(self.obj.name).position.copy()
        tr = {"t": [], "pos": [], "target": [], "phase": [], "qpos": []}
        t_ctrl = 0.0
        control_steps = 0
        t_lift0 = self.reference.t_lift0
        obj_pos, obj_quat = self._obj_pos, self._obj_quat  # live views
        # the object's pose after every step from lifting on, for the tracking errors
        # (computed once after the loop)
        times: list[float] = []
        poses: list[list[float]] = []
        every = self.control_every
        control_step, step, perf = self.control_step, w.step, time.perf_counter
        d = w.data
        t0 = time.perf_counter()
        for i in range(n):
            t = d.time
            if schedule or not dropped[0]:
                self._events(t, schedule, dropped)
            if i % every == 0:
                c0 = perf()
                control_step(t)
                t_ctrl += perf() - c0
                control_steps += 1
            step()
            if t >= t_lift0:
                times.append(t)
                poses.append(obj_pos.tolist() + obj_quat.tolist())
            if trace and i % 10 == 0:
                ref = self.reference(t)
                op = w.object_pose(self.obj.name)
                tr["t"].append(t)
                tr["pos"].append(op.position)
                tr["target"].append(ref.object_position)
                tr["phase"].append(ref.phase)
                tr["qpos"].append(d.qpos.copy())
        wall = time.perf_counter() - t0
        op = w.object_pose(self.obj.name)
        target, _ = self.reference.object_target(w.time)
        final = float(np.linalg.norm(op.position - target))
        lifted = float(op.position[2] - p_init[2])
        success = final < spec.success_tolerance and (
            spec.lift_height == 0 or lifted > 0.5 * spec.lift_height)
        e, re = self._tracking_errors(times, np.array(poses).reshape(len(times), 7))
        return EpisodeResult(
            scenario=spec.name, mode=self.gains.mode, success=bool(success),
            feasible=self.feasibility(), final_error_mm=final * 1e3,
            pos_err_mean_mm=float(e.mean() * 1e3), pos_err_max_mm=float(e.max() * 1e3),
            rot_err_mean_deg=float(re.mean()), object_lift_mm=lifted * 1e3, steps=n,
            control_steps=control_steps, qp_fallbacks=self.core.counters["qp_fallbacks"],
            divergences=len(w.divergences), wall_s=wall, sim_s=n * w.model.opt.timestep,
            control_s=t_ctrl, grasp_residual_mm=float(self.plan.residual.max() * 1e3),
            trace={k: np.asarray(v) for k, v in tr.items()} if trace else {})


def record_motion(spec: ScenarioSpec, fps: float, seconds: float | None = None
                  ) -> tuple[list[ObjectSpec], np.ndarray]:
    """The scenario's episode under the composite controller, sampled at ``fps``: the scene's
    objects (the order of their free joints) and the full ``qpos`` (n, nq) of every frame, so
    that a renderer of the same scene shows physically consistent hand and object motion
    (seed 000's capture data are such motions).

    Raises:
        SimulationError: the simulation diverged.
    """
    runner = LockstepRunner(spec)
    duration = runner.reference.t_end if seconds is None else float(seconds)
    tr = runner.run(duration=duration, trace=True).trace
    n = max(1, int(duration * fps))
    idx = np.searchsorted(tr["t"], np.arange(n) / fps).clip(0, len(tr["t"]) - 1)
    return scene_objects(spec)[0], tr["qpos"][idx]


def run_episode(spec: ScenarioSpec, mode: str = "composite", control_every: int = 1,
                sim_config: SimConfig | None = None,
                gains: CompositeControlConfig | None = None) -> EpisodeResult:
    """One episode of ``spec`` with the composite controller or PD only (``mode`` overrides
    ``gains.mode``).

    Raises:
        SimulationError: the simulation diverged (``on_instability: raise``).
    """
    gains = replace(gains or CompositeControlConfig(), mode=mode)
    return LockstepRunner(spec, sim_config, None, control_every, gains=gains).run()
