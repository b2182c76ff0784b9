"""Scenario reference motions: reach, close, lift and carry (or pour) an object.

A scenario file (``config/scenarios/<name>.yaml``, flat keys = the fields of
:class:`ScenarioSpec`) names an object, its mass and friction, the phase durations and the
object's target trajectory. :class:`Reference` turns it into the two reference trajectories of
the composite controller (seed 000 sec. 5; dissertation sec. III.5-III.6):

* the hand's PD targets ``q_target(t)`` (27,): reaching above the object with the fingers open
  (the pre-grasp), closing onto the grasp pose found by fingertip IK (``grasp.plan_grasp``),
  then the wrist moving with the object target (lift, carry, rotate) while the fingers hold
  the grasp pose;
* the object's target pose (position of its centre of mass, quaternion w, x, y, z).

Phases follow the dissertation's performance interface (reaching, closing, manipulation): the
grasp torques are off while reaching and closing (sec. III.5.2: "we drop the grasp joint
torque term for the closing phase") and on from the settle phase.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from hand_capture.cameras.transforms import rotvec_to_matrix
from hand_capture.config import from_mapping, load_yaml, param, validate
from hand_capture.model.joints import (
    root_angles_from_matrix,
    root_rotation_matrix,
)
from hand_control.errors import ConfigError
from hand_control.sim.grasp import GraspPlan

__all__ = ["PHASES", "RefSample", "Reference", "ScenarioSpec", "load_scenario",
           "scenario_dir", "scenario_names"]

PHASES = ("reaching", "closing", "settling", "lifting", "carrying", "holding")


@dataclass(frozen=True)
class ScenarioSpec:
    """One reference motion (flat YAML keys)."""

    name: str = param("lift_box", "scenario name")
    description: str = param("", "one line: what the scenario shows")
    object_kind: str = param("box", "box | ball | cylinder (an upright stick)",
                             choices=("box", "ball", "cylinder"))
    object_size: tuple[float, ...] = param(
        (), "box half extents (3) | ball radius (1) | cylinder radius, half height (2) [m]; "
        "empty = the MJCF export's default", lo=0.005, hi=0.2)
    object_shape: str = param(
        "", "instead of object_kind: any object, a mesh file or KIND[:sizes] of "
        "hand_control.grasp.objects (e.g. mug, bottle:0.03,0.08, torus, convex:3)")
    object_yaw: float = param(0.0, "the object's turn about z on the table [rad]",
                              lo=-math.pi, hi=math.pi)
    grasp_source: str = param(
        "ik", "ik: fingertip IK onto the object (box, ball, cylinder, or an object_shape's "
        "primitive proxy) | synthesis: grasp synthesis from the grasp database (eq. III.4)",
        choices=("ik", "synthesis"))
    grip_mode: str = param("", "grip mode of the synthesis ('' = the best scoring one)")
    object_mass: float = param(0.2, "object mass [kg]", lo=0.005, hi=10.0)
    object_friction: float = param(0.75, "sliding friction of the object (seed 000 sec. 7.2)",
                                   lo=0.001, hi=3.0)
    object_xy: tuple[float, ...] = param((0.12, 0.0), "object position on the table [m]")
    grasp_depth: float = param(0.003, "fingertip pads aimed this far inside the surface [m]",
                               lo=0.0, hi=0.01)
    t_reach: float = param(0.5, "reaching phase [s]", lo=0.05)
    t_close: float = param(0.5, "closing phase [s]", lo=0.05)
    t_settle: float = param(0.3, "settling phase: grasp on, object still on the table [s]",
                            lo=0.0)
    t_lift: float = param(1.0, "lifting phase [s]", lo=0.0)
    t_carry: float = param(1.0, "carrying / rotating phase [s]", lo=0.0)
    t_hold: float = param(0.7, "holding phase at the end [s]", lo=0.0)
    lift_height: float = param(0.10, "lift of the object target [m]", lo=0.0, hi=0.5)
    carry_offset: tuple[float, ...] = param((0.0, 0.10, 0.0),
                                            "object target displacement while carrying [m]")
    carry_rotation: tuple[float, ...] = param(
        (0.0, 0.0, 0.0), "object target rotation while carrying, rotation vector in the "
        "world frame about the object's centre [rad] (pouring: a tilt about x)")
    friction_schedule: tuple[float, ...] = param(
        (), "object friction changes during the run: t0, mu0, t1, mu1, ... [s, -]")
    perturb_mass: float = param(0.0, "falling ball that hits the object (0 = none) [kg]",
                                lo=0.0, hi=2.0)
    perturb_radius: float = param(0.015, "radius of the falling ball [m]", lo=0.005, hi=0.05)
    perturb_height: float = param(0.12, "drop height above the object's top [m]", lo=0.0)
    perturb_time: float = param(3.0, "time the ball is released [s]", lo=0.0)
    success_tolerance: float = param(
        0.03, "the object counts as carried when it ends within this of its target [m]",
        lo=0.001)

    def __post_init__(self) -> None:
        validate(self)
        n = {"box": 3, "ball": 1, "cylinder": 2}[self.object_kind]
        if self.object_size and len(self.object_size) != n:
            raise ConfigError(f"ScenarioSpec.object_size: a {self.object_kind} needs {n} "
                              f"values, got {self.object_size}")
        for name in ("carry_offset", "carry_rotation"):
            if len(getattr(self, name)) != 3:
                raise ConfigError(f"ScenarioSpec.{name} needs 3 values")
        if len(self.object_xy) != 2:
            raise ConfigError("ScenarioSpec.object_xy needs 2 values")
        fs = self.friction_schedule
        if len(fs) % 2 or any(mu <= 0 for mu in fs[1::2]):
            raise ConfigError("ScenarioSpec.friction_schedule needs pairs t, mu with mu > 0")

    @property
    def duration(self) -> float:
        return (self.t_reach + self.t_close + self.t_settle + self.t_lift + self.t_carry
                + self.t_hold)

    def with_(self, **changes: Any) -> ScenarioSpec:
        return replace(self, **changes)


def scenario_dir() -> Path:
    """``config/scenarios`` of the source tree (or of the installed share directory)."""
    here = Path(__file__).resolve().parents[2] / "config" / "scenarios"
    if here.is_dir():
        return here
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory("hand_suite")) / "config" / "scenarios"
    except Exception:
        return here


def scenario_names() -> list[str]:
    return sorted(p.stem for p in scenario_dir().glob("*.yaml"))


def load_scenario(name_or_path: str | Path) -> ScenarioSpec:
    """A scenario by name (``config/scenarios/<name>.yaml``) or path.

    Raises:
        ConfigError: missing file, unknown key or bad value (naming it).
    """
    p = Path(name_or_path)
    if not p.suffix:
        p = scenario_dir() / f"{name_or_path}.yaml"
    data = load_yaml(p) or {}
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: a scenario is a mapping of ScenarioSpec fields")
    return from_mapping(ScenarioSpec, data)


def _smooth(x: float) -> float:
    """Smoothstep on [0, 1] (zero velocity at both ends)."""
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


def _smooth_array(x: np.ndarray) -> np.ndarray:
    """:func:`_smooth` elementwise (the same operations, so the same values)."""
    x = np.minimum(np.maximum(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def _rotvec_quat(v: np.ndarray) -> np.ndarray:
    a = float(np.linalg.norm(v))
    if a < 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.r_[math.cos(a / 2), math.sin(a / 2) * v / a]


@dataclass(frozen=True, eq=False)
class RefSample:
    """The references at one instant."""

    phase: str
    q_target: np.ndarray
    object_position: np.ndarray
    object_quaternion: np.ndarray
    grasp: bool


def _ref_sample(phase: str, q: np.ndarray, pos: np.ndarray, quat: np.ndarray,
                grasp: bool) -> RefSample:
    """A :class:`RefSample` without the frozen-dataclass ``__init__`` (one per step)."""
    r = object.__new__(RefSample)
    r.__dict__.update(phase=phase, q_target=q, object_position=pos, object_quaternion=quat,
                      grasp=grasp)
    return r


class Reference:
    """Reference trajectories of one scenario (see the module docstring).

    Args:
        spec: the scenario.
        plan: the grasp (poses from fingertip IK).
        object_position, object_quaternion: the object's initial pose (w, x, y, z).
        approach_height: the wrist starts this far above the pre-grasp [m].
    """

    def __init__(self, spec: ScenarioSpec, plan: GraspPlan, object_position: np.ndarray,
                 object_quaternion: np.ndarray, approach_height: float = 0.06) -> None:
        self.spec = spec
        self.plan = plan
        self.p0 = np.asarray(object_position, dtype=np.float64).copy()
        self.quat0 = np.asarray(object_quaternion, dtype=np.float64).copy()
        self.q_start = plan.q_pregrasp.copy()
        self.q_start[2] += approach_height
        if plan.reaching is not None:
            self.q_start = np.asarray(plan.reaching[0], dtype=np.float64).copy()
        s = spec
        self.t_close0 = s.t_reach
        self.t_settle0 = self.t_close0 + s.t_close
        self.t_lift0 = self.t_settle0 + s.t_settle
        self.t_carry0 = self.t_lift0 + s.t_lift
        self.t_hold0 = self.t_carry0 + s.t_carry
        self.t_end = self.t_hold0 + s.t_hold
        self._root_rot0 = root_rotation_matrix(plan.q_grasp[3:6])
        self._rotates = bool(np.any(np.asarray(spec.carry_rotation) != 0.0))
        self._last_t = math.nan
        self._last: RefSample | None = None
        self._index: dict[float, int] = {}  # tabulated times -> row (see precompute)
        self._table: tuple[np.ndarray, ...] = ()
        self._rows: tuple[list, ...] = ()  # the table's rows (see precompute)

    def is_finite(self) -> bool:
        """Every sample is finite: true when the start pose, the grasp plan and the object's
        initial pose are (a validated spec; the samples interpolate between them)."""
        return all(bool(np.isfinite(np.asarray(a, dtype=np.float64)).all()) for a in (
            self.q_start, self.plan.q_pregrasp, self.plan.q_grasp, self.p0, self.quat0,
            *(m for m in (self.plan.closing, self.plan.reaching) if m is not None)))

    def precompute(self, dt: float, t0: float = 0.0, steps: int | None = None) -> None:
        """Tabulate the references at the times a simulation stepping by ``dt`` from ``t0``
        reaches, to the end of the scenario (+ 2 steps).

        The times are the same floating-point sums as the simulator's clock (MuJoCo adds the
        timestep to ``time`` at every step), so a lookup is an exact dictionary hit and
        returns the values :meth:`_sample` computes at that time (the table is computed with
        the same operations, vectorised over time); any other time is sampled as before.
        A control loop at 1 kHz then reads a row instead of evaluating the trajectory.
        """
        if not (dt > 0 and math.isfinite(dt) and math.isfinite(t0)):
            raise ConfigError(f"Reference.precompute: bad dt={dt} or t0={t0}")
        n = steps if steps is not None else int(math.ceil((self.t_end - t0) / dt)) + 2
        times = [t0]
        t = t0
        for _ in range(max(n, 0)):
            t += dt
            times.append(t)
        self._table = q, pos, quat, phase, grasp = self._sample_many(np.array(times))
        self._index = {t: i for i, t in enumerate(times)}
        # the rows as __call__ hands them out, once: read-only views and plain values
        self._rows = (list(q), list(pos), list(quat), [PHASES[p] for p in phase.tolist()],
                      grasp.tolist())
        self._last_t = math.nan

    def _sample_many(self, t: np.ndarray) -> tuple[np.ndarray, ...]:
        """:meth:`_sample` at every time of ``t``, as read-only arrays
        ``(q (N, n), position (N, 3), quaternion (N, 4), phase index (N,), grasp (N,))``."""
        s, plan = self.spec, self.plan
        n = t.shape[0]
        q = np.empty((n, self.q_start.shape[0]))
        pos = np.empty((n, 3))
        quat = np.empty((n, 4))
        pos[:], quat[:] = self.p0, self.quat0
        reach = t < self.t_close0
        close = ~reach & (t < self.t_settle0)
        hold = ~(reach | close)
        if plan.reaching is not None:
            q[reach] = self._motion_at(plan.reaching, t[reach] / s.t_reach)
        else:
            a = _smooth_array(t[reach] / s.t_reach)[:, None]
            q[reach] = (1 - a) * self.q_start + a * plan.q_pregrasp
        if plan.closing is not None:
            q[close] = self._motion_at(plan.closing, (t[close] - self.t_close0) / s.t_close)
        else:
            a = _smooth_array((t[close] - self.t_close0) / s.t_close)[:, None]
            q[close] = (1 - a) * plan.q_pregrasp + a * plan.q_grasp
        th = t[hold]
        if self._rotates:  # pouring: per-row (rotations), the scalar code itself
            rows = [self._sample(float(ti)) for ti in th.tolist()]
            q[hold] = [r.q_target for r in rows]
            pos[hold] = [r.object_position for r in rows]
            quat[hold] = [r.object_quaternion for r in rows]
        elif th.size:
            lift = s.lift_height * (_smooth_array((th - self.t_lift0) / s.t_lift)
                                    if s.t_lift > 0 else (th >= self.t_lift0).astype(float))
            ac = (_smooth_array((th - self.t_carry0) / s.t_carry) if s.t_carry > 0
                  else (th >= self.t_carry0).astype(float))
            up = np.zeros((th.shape[0], 3))
            up[:, 2] = lift
            ph = self.p0 + up + ac[:, None] * np.asarray(s.carry_offset)
            pos[hold] = ph
            quat[hold] = self.object_target(float(th[0]))[1]  # constant without rotation
            qh = np.tile(plan.q_grasp, (th.shape[0], 1))
            qh[:, 0:3] += ph - self.p0
            q[hold] = qh
        phase = np.searchsorted(
            np.array([self.t_close0, self.t_settle0, self.t_lift0, self.t_carry0,
                      self.t_hold0]), t, side="right")
        grasp = phase >= 2
        for arr in (q, pos, quat, phase, grasp):
            arr.setflags(write=False)
        return q, pos, quat, phase, grasp

    @staticmethod
    def _motion_at(c: np.ndarray, u: np.ndarray) -> np.ndarray:
        """A plan's motion (reaching, closing) at phase fractions ``u`` (N,) in [0, 1],
        (N, 27): linear interpolation between its frames (its own timing)."""
        x = np.clip(u, 0.0, 1.0) * (len(c) - 1)
        i0 = np.minimum(np.floor(x).astype(np.int64), len(c) - 2)
        a = (x - i0)[:, None]
        return (1 - a) * c[i0] + a * c[i0 + 1]

    @property
    def initial_pose(self) -> np.ndarray:
        return self.q_start.copy()

    def object_target(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Target position and quaternion (w, x, y, z) of the object at time ``t``."""
        s = self.spec
        lift = s.lift_height * (_smooth((t - self.t_lift0) / s.t_lift) if s.t_lift > 0
                                else float(t >= self.t_lift0))
        a = (_smooth((t - self.t_carry0) / s.t_carry) if s.t_carry > 0
             else float(t >= self.t_carry0))
        pos = self.p0 + np.array([0.0, 0.0, lift]) + a * np.asarray(s.carry_offset)
        rv = a * np.asarray(s.carry_rotation, dtype=np.float64)
        return pos, _quat_mul(_rotvec_quat(rv), self.quat0)

    def __call__(self, t: float) -> RefSample:
        if t == self._last_t:
            return self._last
        i = self._index.get(t)
        if i is None:
            self._last = self._sample(t)
        else:  # a tabulated time (see precompute): the row, read-only views
            q, pos, quat, phase, grasp = self._rows
            self._last = _ref_sample(phase[i], q[i], pos[i], quat[i], grasp[i])
        self._last_t = t
        return self._last

    def _sample(self, t: float) -> RefSample:
        s = self.spec
        if t < self.t_close0:
            if self.plan.reaching is not None:
                q = self._motion_at(self.plan.reaching, np.array([t / s.t_reach]))[0]
            else:
                a = _smooth(t / s.t_reach)
                q = (1 - a) * self.q_start + a * self.plan.q_pregrasp
            pos, quat = self.p0, self.quat0
            return RefSample("reaching", q, pos.copy(), quat.copy(), False)
        if t < self.t_settle0:
            if self.plan.closing is not None:
                q = self._motion_at(self.plan.closing,
                                    np.array([(t - self.t_close0) / s.t_close]))[0]
            else:
                a = _smooth((t - self.t_close0) / s.t_close)
                q = (1 - a) * self.plan.q_pregrasp + a * self.plan.q_grasp
            return RefSample("closing", q, self.p0.copy(), self.quat0.copy(), False)
        pos, quat = self.object_target(t)
        # the wrist follows the object target rigidly (rotation about the object's centre)
        rv = (pos - self.p0)
        a = (_smooth((t - self.t_carry0) / s.t_carry) if s.t_carry > 0
             else float(t >= self.t_carry0))
        q = self.plan.q_grasp.copy()
        q[0:3] += rv
        if self._rotates:
            rot = rotvec_to_matrix(a * np.asarray(s.carry_rotation, dtype=np.float64))
            q[0:3] = self.p0 + rv + rot @ (self.plan.q_grasp[0:3] - self.p0)
            q[3:6] = root_angles_from_matrix(rot @ self._root_rot0)
        phase = ("settling" if t < self.t_lift0 else "lifting" if t < self.t_carry0
                 else "carrying" if t < self.t_hold0 else "holding")
        return RefSample(phase, q, pos, quat, True)
