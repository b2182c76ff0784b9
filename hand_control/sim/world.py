"""The simulated world: a MuJoCo model of the hand and objects, stepped with servo commands.

The hand is driven like hardware: every DoF has a PD servo (eq. 8 of seed 000 / eq. III.20)
toward the last commanded position target, plus a commanded feed-forward effort (the
composite controller's grasp torques, eq. 12). The servos are the MJCF's own ``position``
actuators (hand_capture.model.mjcf: gains of the controller config, Table 1 = Table III.1 by
default, finger torque limits as force ranges); the world never rewrites them, so the
exported model is the simulated one. The servo runs at every physics step, whatever rate the
commands arrive at:

* finger DoFs (servos without a control range): the effort is folded into the set point,
  ``ctrl = target + effort / kp``: MuJoCo applies ``kp (target - q) - kv qd + effort``,
  clipped to the force range, with the damping integrated implicitly by ``implicitfast``;
* root DoFs (servos with a control range): ``ctrl`` = target, the effort goes to
  ``qfrc_applied``;
* DoFs without an actuator: the PD torque (``kp``, ``kd`` given to the world, the table's
  by default) plus the effort through ``qfrc_applied``, every step.

Instability guard: after every step the MuJoCo warning counters (``data.warning[mjWARN_*]``)
and the hand's joint speeds are checked; a divergence is reported with the DoF
(``warning.lastinfo``) and, by config, raises :class:`SimulationError` or resets the episode
explicitly to its initial state. MuJoCo's own silent auto-reset is therefore never taken as a
normal step.
"""

from __future__ import annotations

import time as _time
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from hand_capture.model.joints import JOINT_NAMES
from hand_control.errors import ConfigError, InputError, SimulationError
from hand_control.sim.config import SimConfig
from hand_control.sim.contacts import ContactFrame

__all__ = ["Divergence", "ObjectPose", "SimWorld"]

_W = mujoco.mjtWarning
#: warnings that mean the state diverged (MuJoCo resets the data itself after BADQACC)
DIVERGENCE_WARNINGS: dict[int, str] = {
    int(_W.mjWARN_BADQACC): "BADQACC",
    int(_W.mjWARN_BADQPOS): "BADQPOS",
    int(_W.mjWARN_BADQVEL): "BADQVEL",
    int(_W.mjWARN_BADCTRL): "BADCTRL",
}
#: warnings that only degrade the solution (logged, counted)
SOFT_WARNINGS: dict[int, str] = {
    int(_W.mjWARN_CONTACTFULL): "CONTACTFULL",
    int(_W.mjWARN_CNSTRFULL): "CNSTRFULL",
    int(_W.mjWARN_INERTIA): "INERTIA",
}
_INTEGRATORS = {"Euler": 0, "RK4": 1, "implicit": 2, "implicitfast": 3}


def _clip_two_calls(x: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                    out: np.ndarray | None = None) -> np.ndarray:
    """``min(max(x, lo), hi)``, elementwise (NaN stays NaN)."""
    return np.minimum(np.maximum(x, lo), hi, out=out)


try:  # numpy's clip ufunc: the same values as _clip_two_calls in one call
    from numpy._core.umath import clip as _clip
except ImportError:  # pragma: no cover - numpy < 2
    _clip = _clip_two_calls


def _as_slice(idx: np.ndarray) -> slice | np.ndarray:
    """``idx`` as a slice when it is a run of consecutive integers (a view, no gather)."""
    if idx.size and np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size)):
        return slice(int(idx[0]), int(idx[0]) + idx.size)
    return idx


@dataclass(frozen=True)
class Divergence:
    """One detected divergence: when, which check, which DoF."""

    time: float
    kind: str
    dof: int
    joint: str
    action: str  # "raise" or "reset"

    def message(self) -> str:
        return (f"simulation diverged at t={self.time:.4f} s: {self.kind} at DoF {self.dof} "
                f"(joint {self.joint!r}); action: {self.action}")


@dataclass(frozen=True, eq=False)
class ObjectPose:
    """Pose and velocity of a free object (world frame, quaternion w, x, y, z)."""

    name: str
    position: np.ndarray
    quaternion: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray
    mass: float


class SimWorld:
    """A MuJoCo world with the hand (joints named as ``JOINT_NAMES``) and free objects.

    Args:
        xml: MJCF text (e.g. ``hand_capture.model.mjcf.build_scene(...)``).
        config: stepping, servo-hold and guard settings.
        kp, kd: (n_hand,) PD gains of hand DoFs the model gives no actuator (JOINT_NAMES
            order; by default Table 1); DoFs with a servo use the servo's gains.
        keyframe: keyframe to start from (``None``: the model's qpos0).

    Raises:
        ConfigError: the model has no hand joint, a hand actuator is not a position servo,
            or the gains have the wrong length.
    """

    def __init__(self, xml: str, config: SimConfig | None = None,
                 kp: Sequence[float] | None = None, kd: Sequence[float] | None = None,
                 keyframe: str | None = "home") -> None:
        self.config = config or SimConfig()
        try:
            self.model = mujoco.MjModel.from_xml_string(xml)
        except ValueError as e:
            raise ConfigError(f"cannot load the MJCF scene: {e}") from e
        m = self.model
        m.opt.timestep = self.config.timestep
        m.opt.integrator = _INTEGRATORS[self.config.integrator]
        self.data = mujoco.MjData(m)
        # --- the hand: joints present in the model, in JOINT_NAMES order
        names, jids = [], []
        for n in JOINT_NAMES:
            j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)
            if j >= 0:
                names.append(n)
                jids.append(j)
        if not names:
            raise ConfigError("the MJCF has none of the hand's joints (JOINT_NAMES)")
        self.joint_names: tuple[str, ...] = tuple(names)
        self._name_index = {n: i for i, n in enumerate(names)}
        self.n_hand = len(names)
        self.qpos_adr = m.jnt_qposadr[jids].astype(np.int64)
        self.dof_adr = m.jnt_dofadr[jids].astype(np.int64)
        # the hand's DoFs as one slice (a superset when they are not contiguous)
        self._dof_slice = slice(int(self.dof_adr.min()), int(self.dof_adr.max()) + 1)
        self._qpos_idx, self._dof_idx = _as_slice(self.qpos_adr), _as_slice(self.dof_adr)
        self._qpos_view = isinstance(self._qpos_idx, slice)
        self._dof_view = isinstance(self._dof_idx, slice)
        contiguous = np.array_equal(self.dof_adr, np.arange(self._dof_slice.start,
                                                            self._dof_slice.stop))
        # the hand's columns of a Jacobian: a view (slice) when its DoFs are contiguous
        self._dof_cols: slice | np.ndarray = self._dof_slice if contiguous else self.dof_adr
        hand_bodies = set(int(m.jnt_bodyid[j]) for j in jids)
        # bodies below the hand's bodies (fixed children without joints) belong to the hand too
        for b in range(1, m.nbody):
            if int(m.body_parentid[b]) in hand_bodies:
                hand_bodies.add(b)
        self.hand_body_ids = np.array(sorted(hand_bodies), dtype=np.int64)
        self._is_hand_body = np.zeros(m.nbody, dtype=bool)
        self._is_hand_body[self.hand_body_ids] = True
        if self.config.hand_gravcomp:
            m.body_gravcomp[self.hand_body_ids] = 1.0
        # --- free objects
        self.objects: dict[str, dict[str, object]] = {}
        for j in range(m.njnt):
            if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
                b = int(m.jnt_bodyid[j])
                name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b)
                geoms = np.nonzero(m.geom_bodyid == b)[0]
                self.objects[name] = {"body": b, "qpos": int(m.jnt_qposadr[j]),
                                      "dof": int(m.jnt_dofadr[j]), "geoms": geoms}
        # --- servo gains and actuators: the model's position servos, as they are
        if kp is None or kd is None:
            from hand_capture.model.mjcf import dof_gains

            kp0, kd0 = dof_gains(joint_names=self.joint_names)
            kp = kp0 if kp is None else kp
            kd = kd0 if kd is None else kd
        self.kp = np.asarray(kp, dtype=np.float64).copy()
        self.kd = np.asarray(kd, dtype=np.float64).copy()
        if self.kp.shape != (self.n_hand,) or self.kd.shape != (self.n_hand,):
            raise ConfigError(f"kp/kd need {self.n_hand} values (hand DoFs {self.joint_names})")
        self._servo_act = -np.ones(self.n_hand, dtype=np.int64)  # position servos (ctrl=target)
        for a in range(m.nu):
            if m.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT:
                continue
            j = int(m.actuator_trnid[a, 0])
            if j not in jids:
                continue
            k = jids.index(j)
            is_servo = m.actuator_biastype[a] == mujoco.mjtBias.mjBIAS_AFFINE and \
                m.actuator_biasprm[a, 1] != 0.0 and m.actuator_gainprm[a, 0] > 0.0
            if not is_servo:
                raise ConfigError(
                    f"actuator {a} of joint {self.joint_names[k]!r} is not a position servo "
                    "(the hand's DoFs need MuJoCo <position> actuators, see "
                    "hand_capture.model.mjcf)")
            self._servo_act[k] = a
            # the servo gains of the model: they are what MuJoCo applies
            self.kp[k] = m.actuator_gainprm[a, 0]
            self.kd[k] = -m.actuator_biasprm[a, 2]
        self._servo_k = np.nonzero(self._servo_act >= 0)[0]
        self._servo_a = self._servo_act[self._servo_k]
        self._servo_dof = self.dof_adr[self._servo_k]
        self._free_k = np.nonzero(self._servo_act < 0)[0]
        lo = m.actuator_ctrlrange[self._servo_a, 0].copy()
        hi = m.actuator_ctrlrange[self._servo_a, 1].copy()
        lim = m.actuator_ctrllimited[self._servo_a].astype(bool)
        self._servo_lo = np.where(lim, lo, -np.inf)
        self._servo_hi = np.where(lim, hi, np.inf)
        # root servos (ctrl-limited position actuators) take the effort through qfrc_applied
        self._ff_applied = lim
        self._force_lo = np.where(m.actuator_forcelimited[self._servo_a].astype(bool),
                                  m.actuator_forcerange[self._servo_a, 0], -np.inf)
        self._force_hi = np.where(m.actuator_forcelimited[self._servo_a].astype(bool),
                                  m.actuator_forcerange[self._servo_a, 1], np.inf)
        # (n_hand,) feed-forward effort limits of each DoF's actuator [N m or N] (+-inf for
        # a DoF without a force-limited actuator): set_command refuses efforts outside them
        self.effort_lo = np.full(self.n_hand, -np.inf)
        self.effort_hi = np.full(self.n_hand, np.inf)
        self.effort_lo[self._servo_k] = self._force_lo
        self.effort_hi[self._servo_k] = self._force_hi
        # _write_command's terms, once: set point = target + effort / kp_fold with
        # kp_fold = inf where the effort goes to qfrc_applied (effort / inf = 0 exactly)
        kp_servo = self.kp[self._servo_k]
        self._kp_fold = np.where(self._ff_applied, np.inf, kp_servo)
        self._ff_mask = self._ff_applied.astype(np.float64)
        self._all_servo = bool(np.array_equal(self._servo_k, np.arange(self.n_hand)))
        self._servo_a_idx = _as_slice(self._servo_a)
        self._servo_dof_idx = _as_slice(self._servo_dof)
        # --- episode state
        self._keyframe = -1
        if keyframe is not None:
            self._keyframe = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, keyframe)
        self._body_names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) or f"body{b}"
                            for b in range(m.nbody)]
        self._geom_names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or "world"
                            for g in range(m.ngeom)]
        self._geom_body = m.geom_bodyid.tolist()
        # the name a contact reports for each geom's side: its body, or for the world body
        # the geom itself (e.g. "table")
        self._contact_names = [self._geom_names[g] if b == 0 else self._body_names[b]
                               for g, b in enumerate(self._geom_body)]
        self._is_hand_list = self._is_hand_body.tolist()
        self._jacp = np.zeros((3, m.nv))
        self._jacr = np.zeros((3, m.nv))
        self._f6 = np.zeros(6)
        self._ft_buf = np.zeros((0, 3, 3))  # contact_torques' rows
        self._ft_rows: list[tuple[np.ndarray, ...]] = []
        self._w_buf = np.zeros((0, 6))  # wrench_torques' rows
        self._w_rows: list[tuple[np.ndarray, np.ndarray]] = []
        # views into MjData (its arrays never move): the guard reads them every step
        self._warn_number = self.data.warning.number
        self._ctrl_view = self._qfrc_view = None  # the servos' ctrl / qfrc_applied entries
        if isinstance(self._servo_a_idx, slice) and isinstance(self._servo_dof_idx, slice):
            self._ctrl_view = self.data.ctrl[self._servo_a_idx]
            self._qfrc_view = self.data.qfrc_applied[self._servo_dof_idx]
        self._qvel_hand = self.data.qvel[self._dof_slice]
        self._no_effort = np.zeros(self.n_hand)  # set_targets' efforts (never written)
        self._no_effort.setflags(write=False)
        self._has_free = self._free_k.size > 0
        self._max_speed_sq = self.config.max_joint_speed ** 2
        self.resets = 0
        self.divergences: list[Divergence] = []
        self.soft_warnings: dict[str, int] = {v: 0 for v in SOFT_WARNINGS.values()}
        self.saturated_steps = 0  # steps that ended with a servo at its force limit (counted
        # only when ``count_saturation`` is set: it costs a check per step)
        self.count_saturation = False
        self.steps = 0
        self._initial: tuple[np.ndarray, ...] | None = None
        self.reset()

    # ------------------------------------------------------------------------------- state
    def reset(self) -> None:
        """Back to the initial state (the keyframe, or what :meth:`set_initial_state` saved)."""
        m, d = self.model, self.data
        if self._initial is not None:
            mujoco.mj_resetData(m, d)
            d.qpos[:], d.qvel[:], d.act[:] = self._initial
        elif self._keyframe >= 0:
            mujoco.mj_resetDataKeyframe(m, d, self._keyframe)
        else:
            mujoco.mj_resetData(m, d)
        d.qfrc_applied[:] = 0.0
        mujoco.mj_forward(m, d)
        self.target = d.qpos[self.qpos_adr].copy()
        self.effort = np.zeros(self.n_hand)
        self.last_command_time = d.time
        self.timed_out = False
        self._write_command()
        self._warn_seen = np.array(d.warning.number, dtype=np.int64)
        self._warn_list = self._warn_seen.tolist()

    def set_initial_state(self, hand_q: np.ndarray | None = None,
                          object_poses: dict[str, tuple[Sequence[float], Sequence[float]]]
                          | None = None) -> None:
        """Place the hand and objects, zero every velocity and make this the reset state."""
        d = self.data
        mujoco.mj_resetData(self.model, d)
        if self._keyframe >= 0:
            mujoco.mj_resetDataKeyframe(self.model, d, self._keyframe)
        if hand_q is not None:
            d.qpos[self.qpos_adr] = np.asarray(hand_q, dtype=np.float64)
        for name, (pos, quat) in (object_poses or {}).items():
            a = self._object(name)["qpos"]
            d.qpos[a:a + 3] = pos
            d.qpos[a + 3:a + 7] = np.asarray(quat) / np.linalg.norm(quat)
        d.qvel[:] = 0.0
        self._initial = (d.qpos.copy(), d.qvel.copy(), d.act.copy())
        self.reset()

    @property
    def time(self) -> float:
        return float(self.data.time)

    def hand_state(self) -> tuple[np.ndarray, np.ndarray]:
        """``(q, qd)`` of the hand DoFs, (n_hand,) each, ``joint_names`` order (copies)."""
        q, qd = self.data.qpos[self._qpos_idx], self.data.qvel[self._dof_idx]
        # a slice is a view (copy it); an index array already gathered a copy
        return (q.copy() if self._qpos_view else q), (qd.copy() if self._dof_view else qd)

    def _object(self, name: str) -> dict[str, object]:
        try:
            return self.objects[name]
        except KeyError:
            raise InputError(f"no free object {name!r}; objects: {sorted(self.objects)}") from None

    def object_state_views(self, name: str) -> tuple[np.ndarray, ...]:
        """Live views into MjData of a free object's state, for a loop that reads them every
        step: ``(position, quaternion, linear velocity, angular velocity in the body frame,
        rotation matrix (3, 3))``. They change with every step; :meth:`object_pose` gives
        copies (world-frame angular velocity = ``rotation @ angular velocity``)."""
        o = self._object(name)
        d, b, v = self.data, o["body"], o["dof"]
        return (d.xipos[b], d.xquat[b], d.qvel[v:v + 3], d.qvel[v + 3:v + 6],
                d.xmat[b].reshape(3, 3))

    def object_pose(self, name: str) -> ObjectPose:
        o = self._object(name)
        d, b = self.data, o["body"]
        v = d.qvel[o["dof"]:o["dof"] + 6]
        rot = d.xmat[b].reshape(3, 3)
        return ObjectPose(name, d.xipos[b].copy(), d.xquat[b].copy(),
                          v[:3].copy(), rot @ v[3:6], float(self.model.body_mass[b]))

    # --------------------------------------------------------------------- scene changes
    def set_object_friction(self, name: str, mu: float) -> None:
        """Sliding friction of every geom of an object (it wins over the hand's: priority)."""
        if not (np.isfinite(mu) and mu > 0):
            raise InputError(f"friction must be > 0, got {mu}")
        self.model.geom_friction[self._object(name)["geoms"], 0] = mu

    def set_object_mass(self, name: str, mass: float) -> None:
        """Scale an object's mass and inertia to ``mass`` [kg]."""
        if not (np.isfinite(mass) and mass > 0):
            raise InputError(f"mass must be > 0, got {mass}")
        b = self._object(name)["body"]
        s = mass / self.model.body_mass[b]
        self.model.body_mass[b] = mass
        self.model.body_inertia[b] *= s
        mujoco.mj_setConst(self.model, self.data)

    # --------------------------------------------------------------------------- commands
    def set_command(self, target: Sequence[float] | None = None,
                    effort: Sequence[float] | None = None, check: bool = True) -> None:
        """New servo targets and feed-forward efforts for the hand DoFs (``joint_names`` order).

        ``check=False`` (the in-process controller's fast path) skips the checks: the caller
        vouches for (n_hand,) finite float64 arrays, which the world then owns (not copied).

        Raises:
            InputError: wrong length, a NaN/Inf entry, or an effort outside its actuator's
                force limits (:attr:`effort_lo`, :attr:`effort_hi`); nothing is applied then.
        """
        if not check:
            if target is not None:
                self.target = target
            if effort is not None:
                self.effort = effort
            self.last_command_time = self.data.time
            self.timed_out = False
            self._write_command()
            return
        if target is not None:
            t = np.asarray(target, dtype=np.float64)
            if t.shape != (self.n_hand,) or not np.isfinite(t).all():
                raise InputError(f"target must be {self.n_hand} finite values, got {t.shape}")
        if effort is not None:
            e = np.asarray(effort, dtype=np.float64)
            if e.shape != (self.n_hand,) or not np.isfinite(e).all():
                raise InputError(f"effort must be {self.n_hand} finite values, got {e.shape}")
            out = (e < self.effort_lo) | (e > self.effort_hi)
            if out.any():
                k = int(np.flatnonzero(out)[0])
                raise InputError(
                    f"effort of {self.joint_names[k]!r} = {e[k]:.6g} N m is outside its "
                    f"actuator's limits [{self.effort_lo[k]:.4g}, {self.effort_hi[k]:.4g}] N m"
                    f" ({int(out.sum())} efforts out of range); command refused")
        if target is not None:
            self.target = t.copy()
        if effort is not None:
            self.effort = e.copy()
        self.last_command_time = self.data.time
        self.timed_out = False
        self._write_command()

    def set_targets(self, target: np.ndarray) -> None:
        """``set_command(target, zeros, check=False)``: new servo targets without feed-forward
        efforts (the in-process controller's PD-only steps). The caller vouches for a finite
        (n_hand,) float64 array, which the world then owns (not copied)."""
        self.target = target
        self.effort = self._no_effort
        self.last_command_time = self.data.time
        self.timed_out = False
        if self._ctrl_view is not None and self._all_servo:
            # _write_command with zero efforts: the set point is the target, clipped
            _clip(target, self._servo_lo, self._servo_hi, self._ctrl_view)
            self._qfrc_view.fill(0.0)
        else:
            self._write_command()

    def command_by_name(self, names: Sequence[str], positions: Sequence[float] = (),
                        efforts: Sequence[float] = ()) -> None:
        """Apply a command carried by joint name (``hand_msgs/JointCommand``).

        Empty ``positions`` / ``efforts`` leave those unchanged; joints not named keep their
        targets and efforts.

        Raises:
            InputError: an unknown or duplicate joint name, a length mismatch or a non-finite
                value; nothing is applied then.
        """
        names = list(names)
        index = self._name_index
        unknown = [n for n in names if n not in index]
        if unknown:
            raise InputError(f"unknown joint name(s) {unknown}")
        if len(set(names)) != len(names):
            raise InputError("duplicate joint names in the command")
        idx = np.array([index[n] for n in names], dtype=np.int64)
        target, effort = self.target.copy(), self.effort.copy()
        for label, vals, arr in (("positions", positions, target), ("efforts", efforts, effort)):
            v = np.asarray(vals, dtype=np.float64)
            if v.size == 0:
                continue
            if v.shape != (len(names),):
                raise InputError(f"{len(names)} joint names but {v.size} {label}")
            if not np.isfinite(v).all():
                raise InputError(f"non-finite {label} in the command")
            arr[idx] = v
        self.set_command(target, effort)

    def _write_command(self) -> None:
        """Servo set points and feed-forward efforts into MuJoCo (once per command)."""
        if self._all_servo:
            target, eff = self.target, self.effort
        else:
            target, eff = self.target[self._servo_k], self.effort[self._servo_k]
        # ctrl = target + effort / kp for the motors, target for the root servos (clipped to
        # the control range); the root servos' effort through qfrc_applied
        setpoint = eff / self._kp_fold
        setpoint += target
        if self._ctrl_view is not None:
            _clip(setpoint, self._servo_lo, self._servo_hi, out=self._ctrl_view)
            np.multiply(eff, self._ff_mask, out=self._qfrc_view)
        else:
            d = self.data
            d.ctrl[self._servo_a_idx] = _clip(setpoint, self._servo_lo, self._servo_hi)
            d.qfrc_applied[self._servo_dof_idx] = eff * self._ff_mask

    def _apply_free(self) -> None:
        """PD (eq. 8) + effort through qfrc_applied for DoFs without an actuator."""
        d = self.data
        k = self._free_k
        q = d.qpos[self.qpos_adr[k]]
        qd = d.qvel[self.dof_adr[k]]
        d.qfrc_applied[self.dof_adr[k]] = (self.kp[k] * (self.target[k] - q)
                                           - self.kd[k] * qd + self.effort[k])

    def _check_timeout(self) -> None:
        if (self.config.command_timeout > 0 and not self.timed_out
                and self.data.time - self.last_command_time > self.config.command_timeout):
            self.timed_out = True  # hold the last targets
            if self.config.timeout_effort == "zero":
                self.effort = np.zeros(self.n_hand)
                self._write_command()

    def saturated(self) -> np.ndarray:
        """(n_hand,) whether each servo's force is at its limit in the current state."""
        out = np.zeros(self.n_hand, dtype=bool)
        f = self.data.actuator_force[self._servo_a]
        out[self._servo_k] = (f <= self._force_lo + 1e-9) | (f >= self._force_hi - 1e-9)
        return out

    # ------------------------------------------------------------------------------ step
    def step(self, n: int = 1) -> None:
        """Advance ``n`` physics steps (servo update + ``mj_step`` + guard each)."""
        m, d = self.model, self.data
        free = self._has_free
        timeout = self.config.command_timeout
        warn, v, speed_sq = self._warn_number, self._qvel_hand, self._max_speed_sq
        for _ in range(n):
            t_before = d.time
            if (timeout > 0 and not self.timed_out
                    and t_before - self.last_command_time > timeout):
                self._check_timeout()
            if free:
                self._apply_free()
            mujoco.mj_step(m, d)
            self.steps += 1
            # the guard (see _check), its usual case inline
            if not (warn.tolist() == self._warn_list and d.time >= t_before
                    and v.dot(v) <= speed_sq):
                self._check_full(t_before)
            if self.count_saturation:
                self.saturated_steps += int(self.saturated().any())

    def _check(self, t_before: float) -> None:
        # the usual case in three cheap tests: no new warning, time went on, and no hand
        # joint faster than the limit (|qd|_2 <= limit bounds every |qd_i|; False for NaN)
        v = self._qvel_hand
        if (self._warn_number.tolist() == self._warn_list and self.data.time >= t_before
                and v.dot(v) <= self._max_speed_sq):
            return
        self._check_full(t_before)

    def _check_full(self, t_before: float) -> None:
        d = self.data
        counts = d.warning.number  # (mjNWARNING,) view; the per-item accessors are slow
        kind = dof = None
        if counts.tolist() != self._warn_list:  # cheaper than numpy on 8 entries
            new = counts > self._warn_seen
            for i in np.nonzero(new)[0]:
                if int(i) in DIVERGENCE_WARNINGS and kind is None:
                    kind, dof = DIVERGENCE_WARNINGS[int(i)], int(d.warning.lastinfo[i])
                elif int(i) in SOFT_WARNINGS:
                    self.soft_warnings[SOFT_WARNINGS[int(i)]] += 1
            self._warn_seen = np.array(counts, dtype=np.int64)
            self._warn_list = self._warn_seen.tolist()
        if kind is None and d.time < t_before:  # MuJoCo reset the data by itself
            kind, dof = "AUTO_RESET", -1
        if kind is None and not (abs(d.qvel[self._dof_slice]).max()
                                 <= self.config.max_joint_speed):  # False for NaN too
            qd = d.qvel[self.dof_adr]
            fast = np.abs(qd) > self.config.max_joint_speed
            if fast.any() or not np.isfinite(qd).all():
                kind = "JOINT_SPEED"
                dof = int(self.dof_adr[np.nonzero(fast | ~np.isfinite(qd))[0][0]])
        if kind is None:
            return
        joint = "?"
        if 0 <= dof < self.model.nv:
            joint = mujoco.mj_id2name(self.model, mujoco.mjtObj.mjOBJ_JOINT,
                                      int(self.model.dof_jntid[dof])) or "?"
        div = Divergence(t_before, kind, dof, joint, self.config.on_instability)
        self.divergences.append(div)
        if self.config.on_instability == "raise":
            raise SimulationError(div.message())
        self.resets += 1
        self.reset()

    def run_realtime(self, duration: float, on_step=None) -> None:
        """Step for ``duration`` simulated seconds paced to the wall clock (config)."""
        n = int(round(duration / self.model.opt.timestep))
        t0 = _time.perf_counter()
        sim0 = self.data.time
        for _ in range(n):
            if on_step is not None:
                on_step(self)
            self.step()
            if self.config.real_time:
                ahead = (self.data.time - sim0) / self.config.real_time_factor - (
                    _time.perf_counter() - t0)
                if ahead > 0.002:
                    _time.sleep(ahead)

    # --------------------------------------------------------------------------- contacts
    def hand_body_names(self, bodies: Sequence[int]) -> tuple[str, ...]:
        """The names of body ids (e.g. the hand bodies of :meth:`object_contacts`)."""
        names = self._body_names
        return tuple(names[b] for b in bodies)

    def body_name(self, b: int, geom: int) -> str:
        """A body's name; for the world body, the geom's (e.g. "table")."""
        return self._geom_names[geom] if b == 0 else self._body_names[b]

    def object_contacts(self, body: int
                        ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, list[int]]:
        """The hand-object contacts of the current state, lean (the in-process control loop).

        The same contacts, points, normals and friction as ``contacts(object_name)`` (hand =
        body 1, normal from the hand into the object), without names, penetrations, forces
        or Jacobians: the controller maps its forces through :meth:`contact_torques`.

        Args:
            body: the object's body id (``objects[name]["body"]``).

        Returns:
            ``(K, points (K, 3), normals (K, 3), friction (K,), hand body ids [K])``, ``None``
            arrays when K = 0. Points and normals are copies; the friction may be a view into
            MjData, valid until the next step.
        """
        d = self.data
        n = d.ncon
        if n == 0:
            return 0, None, None, None, []
        con = d.contact
        geom = con.geom.tolist()
        dist = con.dist.tolist()
        gbody, is_hand = self._geom_body, self._is_hand_list
        margin = self.config.contact_margin_report
        sel: list[int] = []
        hand: list[int] = []
        flip: list[int] = []  # rows whose hand is geom 2 (their normal is flipped)
        for i in range(n):
            if dist[i] > margin:
                continue
            g1, g2 = geom[i]
            b1, b2 = gbody[g1], gbody[g2]
            if b2 == body and is_hand[b1]:
                hand.append(b1)
            elif b1 == body and is_hand[b2]:
                flip.append(len(sel))
                hand.append(b2)
            else:
                continue
            sel.append(i)
        k = len(sel)
        if k == 0:
            return 0, None, None, None, []
        i0 = sel[0]
        # the selected rows: a slice when consecutive (the usual case), else an index list
        idx = slice(i0, i0 + k) if sel[-1] == i0 + k - 1 else sel
        normals = con.frame[idx, 0:3].copy()  # the frame's first row: the normal
        if flip:
            normals[flip] *= -1.0
        return k, con.pos[idx].copy(), normals, con.friction[idx, 0], hand

    def contact_torques(self, bodies: Sequence[int], points: np.ndarray, forces: np.ndarray,
                        torsion: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """Joint torques over the hand DoFs that make the hand bodies ``bodies[k]`` apply the
        forces ``forces[k]`` at ``points[k]`` and the torsional torques ``torsion[k]`` about
        ``normals[k]``, in the current state: ``tau = sum_k Jp_k^T f_k + Jr_k^T (l_k n_k)``
        (seed 000 eq. 12, eq. III.21; ``Jp_k``, ``Jr_k`` the Jacobians of body k's material
        point at ``points[k]``), computed by MuJoCo (``mj_applyFT``) without forming the
        Jacobians.

        Returns:
            (n_hand,) torques, ``joint_names`` order (a fresh array).
        """
        m, d = self.model, self.data
        k = len(bodies)
        if k > len(self._ft_rows):  # (point, force, torque) rows of every contact, reused
            self._ft_buf = np.zeros((k, 3, 3))
            self._ft_rows = [tuple(self._ft_buf[i]) for i in range(k)]
        buf = self._ft_buf[:k]
        buf[:, 0] = points
        buf[:, 1] = forces
        np.multiply(torsion[:, None], normals, out=buf[:, 2])  # l_k n_k
        qfrc = np.zeros(m.nv)
        for b, (p, f, t) in zip(bodies, self._ft_rows, strict=False):
            mujoco.mj_applyFT(m, d, f, t, p, b, qfrc)
        return qfrc[self._dof_cols]

    def wrench_torques(self, bodies: Sequence[int], point: np.ndarray,
                       wrenches: np.ndarray) -> np.ndarray:
        """:meth:`contact_torques` with every contact's force and torque moved to one point:
        the hand bodies ``bodies[k]`` apply ``wrenches[k] = (f_k, t_k)`` at ``point`` (a
        force ``f`` at ``p`` on a rigid body is ``f`` at ``c`` with the torque ``(p - c) x
        f``: the same joint torques). ``tau = sum_k Jp_k(point)^T f_k + Jr_k^T t_k``
        (eq. 12 / III.21), computed by MuJoCo (``mj_applyFT``).

        Returns:
            (n_hand,) torques, ``joint_names`` order (a fresh array).
        """
        m, d = self.model, self.data
        k = len(bodies)
        if k > len(self._w_rows):  # (force, torque) rows of every contact, reused
            self._w_buf = np.zeros((k, 6))
            self._w_rows = [(row[0:3], row[3:6]) for row in self._w_buf]
        self._w_buf[:k] = wrenches
        qfrc = np.zeros(m.nv)
        for b, (f, t) in zip(bodies, self._w_rows, strict=False):
            mujoco.mj_applyFT(m, d, f, t, point, b, qfrc)
        return qfrc[self._dof_cols]

    def contacts(self, object_name: str | None = None, hand_only: bool = False,
                 jacobians: bool = False, forces: bool = True) -> ContactFrame:
        """The contacts of the current state.

        Args:
            object_name: only contacts between the hand and this object (hand = body 1).
            hand_only: only contacts that involve the hand (hand = body 1).
            jacobians: add the hand-side Jacobians over the hand DoFs (``mj_jac`` at the
                contact point of the hand body), for the Jacobian-transpose mapping (eq. 12).
            forces: read the contact forces (``mj_contactForce``); ``False`` leaves
                ``forces`` and ``torsional`` zero (a controller that does not use them, e.g.
                eq. III.23, saves the calls).
        """
        m, d = self.model, self.data
        n = d.ncon
        n_jac = self.n_hand if jacobians else None
        if n == 0:
            return ContactFrame.empty(d.time, n_jac)
        con = d.contact
        # plain-Python filtering: a handful of contacts, where numpy's per-call cost dominates
        geom = con.geom.tolist()
        dist = con.dist.tolist()
        gbody = self._geom_body
        is_hand = self._is_hand_list
        margin = self.config.contact_margin_report
        ob = self._object(object_name)["body"] if object_name is not None else -1
        sel: list[tuple[int, bool, int, int]] = []  # (contact, flip, geom1, geom2)
        for i in range(n):
            if dist[i] > margin:
                continue
            g1, g2 = geom[i]
            b1, b2 = gbody[g1], gbody[g2]
            h1, h2 = is_hand[b1], is_hand[b2]
            if object_name is not None:
                if not ((h1 and b2 == ob) or (h2 and b1 == ob)):
                    continue
            elif hand_only and h1 == h2:
                continue
            flip = h2 and not h1  # the hand as body 1
            sel.append((i, flip, g2, g1) if flip else (i, flip, g1, g2))
        k = len(sel)
        if k == 0:
            return ContactFrame.empty(d.time, n_jac)
        i0 = sel[0][0]
        # the selected rows: a slice when consecutive (the usual case), else an index array
        idx = slice(i0, i0 + k) if sel[-1][0] == i0 + k - 1 else np.array([c[0] for c in sel])
        frame = con.frame[idx].tolist()  # (K, 9): rows normal, tangent 1, tangent 2
        pos = np.array(con.pos[idx])  # copies: MjData is rewritten at the next step
        fric = np.array(con.friction[idx, 0])
        # the per-contact lists in one pass (plain Python: a handful of contacts)
        names = self._contact_names
        b1l, b2l, n1, n2, pen, nrm = [], [], [], [], [], []
        for c, f in zip(sel, frame, strict=True):
            b1l.append(gbody[c[2]])
            b2l.append(gbody[c[3]])
            n1.append(names[c[2]])
            n2.append(names[c[3]])
            pen.append(-dist[c[0]])
            # the normal: the frame's first row, from the hand (flipped where it was geom 2)
            nrm.append((-f[0], -f[1], -f[2]) if c[1] else (f[0], f[1], f[2]))
        normals = np.array(nrm)
        if forces:
            f6 = np.empty((k, 6))
            for r, c in enumerate(sel):
                mujoco.mj_contactForce(m, d, c[0], f6[r])
            # contact frame -> world (plain floats: a few contacts), the sign flipped where
            # the hand was geom 2 (its side: the force it applies, its normal)
            frc, tors = [], []
            for (fn, ft1, ft2, tn, _, _), (e0, e1, e2, e3, e4, e5, e6, e7, e8), c in zip(
                    f6.tolist(), frame, sel, strict=True):
                if c[1]:  # -(f R) = (-f) R
                    fn, ft1, ft2, tn = -fn, -ft1, -ft2, -tn
                frc.append((fn * e0 + ft1 * e3 + ft2 * e6, fn * e1 + ft1 * e4 + ft2 * e7,
                            fn * e2 + ft1 * e5 + ft2 * e8))
                tors.append(tn)
            force_arr, torsional = np.array(frc), np.array(tors)
        else:
            force_arr, torsional = np.zeros((k, 3)), np.zeros(k)
        bodies = np.array((b1l, b2l), dtype=np.int64)
        jacp = jacr = None
        if jacobians:
            # mj_jac writes each contact's (3, nv) rows straight into the buffer; the hand's
            # columns then in one copy, contiguous (K, 3, n_hand) blocks: eq. (12)'s products
            # reshape them to (3K, n_hand) without copying
            jac = np.empty((2, k, 3, m.nv))
            jp, jr = jac[0], jac[1]
            for r, b in enumerate(b1l):
                mujoco.mj_jac(m, d, jp[r], jr[r], pos[r], b)
            hand = np.ascontiguousarray(jac[:, :, :, self._dof_cols])
            jacp, jacr = hand[0], hand[1]
        return ContactFrame.trusted(
            tuple(n1), tuple(n2), bodies[0], bodies[1], pos, normals, np.array(pen),
            force_arr, torsional, fric, jacp, jacr, float(d.time))
