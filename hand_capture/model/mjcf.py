"""MJCF export of the hand model and of table-top scenes (MuJoCo Menagerie style).

The exported hand has the numpy model's skeleton exactly (same bones, offsets, rest rotations,
joint axes, limits and DoF order), so MuJoCo's ``mj_kinematics`` body positions equal
``HandModel.forward(q).joint_frames`` to round-off for the same 27 values in ``qpos``.

* Bodies: ``palm`` (root) and ``{finger}_{segment}`` (BONE_NAMES), each with its origin at the
  proximal joint centre. Sites ``{finger}_tip`` at the fingertips and ``palm_center``.
* Joints: JOINT_NAMES, in that order, so the hand's ``qpos[:27]`` / ``qvel[:27]`` are the model's
  pose / velocity vector. The root is three slides (world x, y, z) and three hinges about the
  moving x, y, z axes (joints.py); slides have ``ref`` = the body position so that
  ``qpos = root position``, and the default ``qpos0`` holds the hand above the table. The
  root orientation stays three hinges, not a ball joint: the suite's pose vector (tracking,
  FK, servo maps, bags) is 27 angles, a MuJoCo ``position`` actuator drives one scalar DoF
  (a ball joint's 3 DoFs would need a custom servo), and the singularity at ``root_ry =
  +-pi/2`` (palm pointing straight up or down, in the numpy model as well) is outside the
  scenarios' reach; a user who needs it there re-parameterises in joints.py.
* Actuators, named like their joints and in the same order (``ctrl[i]`` drives DoF i): a
  MuJoCo ``position`` servo per DoF, ``kp (ctrl - q) - kv qd`` (eq. 8 / III.20, gains of seed
  000 Table 1 = Table III.1 or those given), clipped to the DoF's force range (the finger
  torque limits of :func:`finger_torque_limits`). This is the model the simulation steps:
  ``SimWorld`` writes ``ctrl`` and never rewrites the actuators, so the exported files behave
  the same in MuJoCo's viewer.
* Geoms: one capsule per collision capsule of the model (``HandModel.capsules``), density of
  soft tissue (1100 kg/m^3), ``condim=4`` (torsional friction, as the papers' contact model
  uses torsional torques). The hand does not collide with itself (contype 2 / conaffinity 1);
  objects and the table collide with everything.
* Inertia: finger joints carry an ``armature`` below the MCP links' own inertia
  (:data:`FINGER_ARMATURE`, the reasons there); the servo damping is integrated implicitly.
  The wrist hinges carry an armature sized from their servos' damping (at least kd x the
  timestep, :func:`root_rot_armature`), which keeps a force-clamped wrist servo stable.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from hand_capture.errors import ConfigError, InputError
from hand_capture.model.hand import HandModel
from hand_capture.model.joints import (
    FINGERS,
    JOINT_LIMITS,
    JOINT_NAMES,
    N_DOF,
    matrix_to_quat,
)
from hand_capture.model.shape import HandShape
from hand_capture.model.skeleton import (
    BONE_ABD_DOF,
    BONE_FLEX_DOF,
    BONE_NAMES,
    BONE_PARENT,
    LEVELS,
    N_BONES,
)

#: simulation step of the papers' controllers (dissertation ch. III.7: 1 ms)
TIMESTEP: float = 0.001
#: soft-tissue density for the finger masses [kg/m^3]
TISSUE_DENSITY: float = 1100.0
#: mass of the palm body (carpus + metacarpals + soft tissue) [kg]; with the fingers the hand
#: weighs about 0.4 kg, ~0.6 % of a 70 kg body (de Leva 1996 segment mass fraction 0.61 %)
PALM_MASS: float = 0.30
#: finger joint armature [kg m^2]: the reflected rotor inertia a joint drive adds. The
#: template hand's links about their joint axes (the joint's diagonal of the mass matrix at
#: home, computed from the capsules at TISSUE_DENSITY; test_model_mjcf checks it) range from
#: 2e-7 (little DIP) and 3-5e-7 (other DIPs) over 2e-6 - 1e-5 (IP, PIPs) to 3e-5 - 1.8e-4
#: kg m^2 (MCPs, thumb TM). The armature is 2e-5: below every MCP / TM link (<= 0.7x), but
#: 2-10x the PIP / IP links and 40-100x the distal ones (the former 1e-3 was 10x - 5000x the
#: links). It is not smaller because a force-limited servo whose damping saturates with its
#: force (a target step of a radian) then whips the lighter links past 200 rad/s within a
#: few ms (tried: 5e-7 and 5e-6 trip the 200 rad/s guard of SimWorld on a random target
#: step); a finger's tendons and muscles add inertia of their own. The servos' damping is
#: integrated implicitly (``implicitfast``). Light links need stiffer contacts:
#: :data:`HAND_SOLREF`.
FINGER_ARMATURE: float = 2e-5
#: contact softness of the hand's and the objects' geoms (MuJoCo solref: time constant [s],
#: damping ratio; solimp: MuJoCo's default). MuJoCo's constraint model is mass-normalised:
#: the penetration that carries a force F grows with the inverse effective mass at the
#: contact, (1 - d) / d * F / (m k), k ~ 1 / timeconst^2. With realistic (light) finger
#: links the default 0.02 s lets a 15 N grasp sink millimetres into the object and slip;
#: 4 ms (>= 2 timesteps, MuJoCo's stability rule) makes the contact 25x stiffer. Measured on
#: a grid of boxes 0.2 - 1 kg, mu 0.3 - 0.8: with the default the composite controller
#: lifts 4 of 9, with 4 ms 9 of 9; (0.004, d = 0.95 - 0.99) also lifts them but loses the
#: noisy-teleop lift of test_teleop_graph.
HAND_SOLREF: tuple[float, float] = (0.004, 1.0)
HAND_SOLIMP: tuple[float, float, float] = (0.9, 0.95, 0.001)
#: wrist rotation armature [kg m^2], the least one; a root hinge gets
#: ``max(ROOT_ROT_ARMATURE, kd * TIMESTEP)`` (:func:`root_rot_armature`). The hand's own
#: inertia about the wrist axes is only 5e-4 - 3e-3, and the servo's damping (Table 1: kd =
#: 50 N m s/rad) on it is a 20-100 us time constant: stable only while MuJoCo integrates the
#: damping implicitly, which it does not for an actuator clamped at its force range. Then the
#: damping acts explicitly, kd dt / I = 15-100 >> 2, and the clamped servo flips between +-20 N
#: m every step (measured: +-20 rad/s chatter) and loses its joint: replaying a teleop run's
#: commands, the wrist swung 67 deg off its command (raising the limit makes it diverge). With
#: kd dt / I <= 1 a clamped servo only saturates; 0.05 kg m^2 is also what a geared wrist drive
#: reflects (a 5e-6 kg m^2 rotor through a 100:1 gear).
ROOT_ROT_ARMATURE: float = 0.05
#: default height of the wrist above the table top at qpos0 [m]
DEFAULT_ROOT_POS: tuple[float, float, float] = (0.0, 0.0, 0.12)
#: largest fingertip force of a finger's flexors [N], for the finger torque limits
#: (:func:`finger_torque_limits`): in a maximal power grip of ~115 N the index and middle
#: fingers each carry ~32 % = ~37 N (Z.-M. Li 2002, "The influence of wrist position on
#: individual finger forces during forceful grip", J Hand Surg Am 27(5): 886-896); the
#: thumb opposes the fingers and carries about twice that.
FINGER_TIP_FORCE: float = 40.0
THUMB_TIP_FORCE: float = 80.0
#: smallest finger joint torque limit [N m] (abduction DoFs near the tip)
MIN_FINGER_TORQUE: float = 0.3
#: force / torque limits of the wrist servos [N, N m]
ROOT_FORCE_LIMIT: float = 150.0
ROOT_TORQUE_LIMIT: float = 20.0

# --- Table 1 of seed 000 (= Table III.1 of 003): (kp, kd) per table row, root to tip ---------
#: The gain table, one row per joint of the hand numbered from the root (``index1`` = MCP,
#: ``thumb1`` = TM), plus the wrist translation [N/m, N s/m] and rotation [N m/rad, N m s/rad].
#: Data only: the controller's one gain config (hand_control.control.CompositeControlConfig)
#: takes its defaults from it, and the MJCF's position servos get their gains from that
#: config (``build_scene(servo_kp=..., servo_kd=...)``), the table's when none is given.
GAIN_TABLE: dict[str, tuple[float, float]] = {
    "root_translate": (400.0, 50.0), "root_rotate": (600.0, 50.0),
    "thumb1": (10.0, 0.3), "thumb2": (8.0, 0.2), "thumb3": (4.0, 0.4),
    "index1": (4.0, 0.2), "index2": (3.0, 0.1), "index3": (2.0, 0.1),
    "middle1": (4.0, 0.4), "middle2": (4.0, 0.1), "middle3": (2.0, 0.1),
    "ring1": (4.0, 0.4), "ring2": (3.0, 0.1), "ring3": (2.0, 0.1),
    "pinky1": (4.0, 0.4), "pinky2": (3.0, 0.1), "pinky3": (2.0, 0.1),
}
#: the rows of the table, in the order of the gain config's ``joint_kp`` / ``joint_kd``
GAIN_ROWS: tuple[str, ...] = tuple(GAIN_TABLE)
_TABLE_FINGER = {"little": "pinky"}  # the tables call the little finger "pinky"
# joint of the model -> its number in the tables (root to tip)
_THUMB_JOINT = {"tm": 1, "mcp": 2, "ip": 3}
_FINGER_JOINT = {"mcp": 1, "pip": 2, "dip": 3}


def gain_row(joint_name: str) -> str:
    """The row of Table 1 / III.1 that holds the gains of a joint of the hand model (a
    joint's DoFs share its row: ``index_mcp_abd`` and ``index_mcp_flex`` use ``index1``).

    Raises:
        ConfigError: for a name outside the model's vocabulary (``JOINT_NAMES``).
    """
    if joint_name in ("root_tx", "root_ty", "root_tz"):
        return "root_translate"
    if joint_name in ("root_rx", "root_ry", "root_rz"):
        return "root_rotate"
    finger, _, rest = joint_name.partition("_")
    joint = rest.partition("_")[0]
    numbers = _THUMB_JOINT if finger == "thumb" else _FINGER_JOINT
    if finger in FINGERS and joint in numbers:
        return f"{_TABLE_FINGER.get(finger, finger)}{numbers[joint]}"
    raise ConfigError(f"joint {joint_name!r} has no row in the gain table (rows: {GAIN_ROWS})")


def dof_gains(row_kp: Sequence[float] | None = None, row_kd: Sequence[float] | None = None,
              joint_names: Sequence[str] = JOINT_NAMES) -> tuple[np.ndarray, np.ndarray]:
    """Per-DoF ``(kp, kd)`` for ``joint_names`` from per-row gains (``GAIN_ROWS`` order;
    ``None`` = the table's)."""
    kp_rows = np.array([GAIN_TABLE[r][0] for r in GAIN_ROWS] if row_kp is None else row_kp,
                       dtype=np.float64)
    kd_rows = np.array([GAIN_TABLE[r][1] for r in GAIN_ROWS] if row_kd is None else row_kd,
                       dtype=np.float64)
    if kp_rows.shape != (len(GAIN_ROWS),) or kd_rows.shape != (len(GAIN_ROWS),):
        raise ConfigError(f"gains need one value per row {GAIN_ROWS}")
    rows = [GAIN_ROWS.index(gain_row(n)) for n in joint_names]
    return kp_rows[rows], kd_rows[rows]


def finger_torque_limits(model: HandModel | None = None) -> np.ndarray:
    """(27,) torque limit of every finger DoF [N m] (root entries 0): the largest fingertip
    force (``FINGER_TIP_FORCE``, thumb ``THUMB_TIP_FORCE``) times the distance from the joint
    to the fingertip in the model's rest pose, at least ``MIN_FINGER_TORQUE``. For the
    template hand: ~3.6 N m at the index MCP, ~1.8 at the PIP, ~0.9 at the DIP (Purves and
    Berme 1980, J Biomed Eng 2(4): 285-289, measured 0.6 / 1.0 N m at the index PIP / MCP
    in a two-finger twisting task, below these maxima)."""
    model = model or HandModel()
    frames = model.forward(np.zeros(N_DOF)).joint_frames
    lim = np.zeros(N_DOF)
    for fi, f in enumerate(FINGERS):
        tip_bone = LEVELS[2, fi]
        rot, org = frames[tip_bone][:3, :3], frames[tip_bone][:3, 3]
        tip = org + rot @ model.bone_tips[tip_bone]
        force = THUMB_TIP_FORCE if f == "thumb" else FINGER_TIP_FORCE
        for lvl in range(3):
            b = LEVELS[lvl, fi]
            arm = float(np.linalg.norm(tip - frames[b][:3, 3]))
            for d in (BONE_ABD_DOF[b], BONE_FLEX_DOF[b]):
                if d >= 0:
                    lim[d] = max(force * arm, MIN_FINGER_TORQUE)
    return lim


# ---------------------------------------------------------------------------------------------
# Scene objects
# ---------------------------------------------------------------------------------------------
_KINDS = ("box", "ball", "stick", "cup", "composite")
_PART_TYPES = ("box", "sphere", "cylinder", "capsule", "ellipsoid", "mesh")


@dataclass(frozen=True)
class GeomPart:
    """One collision geom of a ``composite`` object, in the object's body frame.

    ``type``: a MuJoCo primitive (``size`` as MuJoCo's, ``pos``, ``quat`` w, x, y, z) or
    ``mesh`` (``vertices`` flat x, y, z, ..., ``faces`` flat i, j, k, ...; MuJoCo collides
    with the mesh's convex hull, so a mesh part should be convex). ``volume`` [m^3] splits
    the object's mass between its parts.
    """

    type: str
    size: tuple[float, ...] = ()
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    vertices: tuple[float, ...] = ()
    faces: tuple[int, ...] = ()
    volume: float = 0.0

    def __post_init__(self) -> None:
        if self.type not in _PART_TYPES:
            raise InputError(f"geom part type must be one of {_PART_TYPES}, got {self.type!r}")
        if not (math.isfinite(self.volume) and self.volume > 0):
            raise InputError(f"geom part volume must be > 0 m^3, got {self.volume}")
        if self.type == "mesh" and (len(self.vertices) < 12 or len(self.vertices) % 3
                                    or len(self.faces) < 12 or len(self.faces) % 3):
            raise InputError("a mesh part needs >= 4 vertices and >= 4 faces (flat triples)")
        vals = (*self.size, *self.pos, *self.quat, *self.vertices)
        if not all(math.isfinite(v) for v in vals):
            raise InputError("geom part values must be finite")


@dataclass(frozen=True)
class ObjectSpec:
    """A free rigid object on the table.

    size per kind: box ``(hx, hy, hz)`` half extents; ball ``(r,)``; stick ``(r, half_length)``
    (a cylinder lying along x); cup ``(outer_r, half_height, wall)`` with a handle on +y;
    composite ``(hx, hy, hz)``: the half extents of its bounding box about the body origin,
    its geoms in ``parts`` (:class:`GeomPart`, e.g. the convex pieces of a mesh).
    ``pos`` is the object centre in the world; ``None`` puts it on the table in front of the
    hand. ``friction`` is the sliding coefficient (it wins over the hand's and the table's).
    """

    kind: str
    name: str = ""
    size: tuple[float, ...] = ()
    mass: float = 0.0
    friction: float = 0.0
    pos: tuple[float, float, float] | None = None
    euler: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rgba: tuple[float, float, float, float] = (0.3, 0.5, 0.8, 1.0)
    parts: tuple[GeomPart, ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in _KINDS:
            raise InputError(f"object kind must be one of {_KINDS}, got {self.kind!r}")
        if (self.kind == "composite") != bool(self.parts):
            raise InputError("a composite object needs its geom parts (and only it has them)")
        d = _OBJECT_DEFAULTS[self.kind]
        size = tuple(float(s) for s in (self.size or d["size"]))
        if len(size) != len(d["size"]) or not all(math.isfinite(s) and s > 0 for s in size):
            raise InputError(f"{self.kind} size must be {len(d['size'])} positive values, "
                             f"got {size}")
        mass = float(self.mass or d["mass"])
        friction = float(self.friction or d["friction"])
        if not (math.isfinite(mass) and 0 < mass <= 50):
            raise InputError(f"object mass must be in (0, 50] kg, got {mass}")
        if not (math.isfinite(friction) and 0 < friction <= 5):
            raise InputError(f"object friction must be in (0, 5], got {friction}")
        if self.kind == "cup" and size[2] >= size[0]:
            raise InputError("cup wall must be thinner than its radius")
        object.__setattr__(self, "size", size)
        object.__setattr__(self, "mass", mass)
        object.__setattr__(self, "friction", friction)
        object.__setattr__(self, "name", self.name or self.kind)

    @property
    def half_height(self) -> float:
        """Half of the object's vertical extent when resting in its default orientation."""
        s = self.size
        return s[2] if self.kind in ("box", "composite") else s[1] if self.kind == "cup" \
            else s[0]


# Objects of the papers (seed 000: cup, solid ball, long round stick, magic cube); sizes and
# masses of ordinary household items: 57 mm cube ~0.1 kg, 70 mm ball, 30 mm x 30 cm stick,
# 80 mm x 10 cm mug ~0.3 kg. Friction: wood / plastic / rubber / glazed ceramic on skin.
_OBJECT_DEFAULTS: dict[str, dict[str, object]] = {
    "box": {"size": (0.0285, 0.0285, 0.0285), "mass": 0.10, "friction": 0.6},
    "ball": {"size": (0.035,), "mass": 0.15, "friction": 0.8},
    "stick": {"size": (0.015, 0.15), "mass": 0.10, "friction": 0.6},
    "cup": {"size": (0.04, 0.05, 0.004), "mass": 0.30, "friction": 0.5},
    "composite": {"size": (0.03, 0.03, 0.03), "mass": 0.20, "friction": 0.6},
}
# default places on the table, in front of / beside the hand so that nothing touches at "home"
_DEFAULT_XY = {"box": (0.26, -0.12), "ball": (0.27, 0.02), "stick": (0.15, 0.17),
               "cup": (0.38, -0.02), "composite": (0.26, -0.12)}


# ---------------------------------------------------------------------------------------------
# XML helpers
# ---------------------------------------------------------------------------------------------
def _f(x: float) -> str:
    s = f"{float(x):.9g}"
    return "0" if s == "-0" else s


def _v(vals: Iterable[float]) -> str:
    return " ".join(_f(x) for x in vals)


def _wxyz(rot: np.ndarray) -> np.ndarray:
    q = matrix_to_quat(rot)  # x y z w
    return np.array([q[3], q[0], q[1], q[2]])


def _attrs(**kw: object) -> str:
    return " ".join(f"{k.rstrip('_')}={quoteattr(str(v))}" for k, v in kw.items()
                    if v is not None)


# ---------------------------------------------------------------------------------------------
# Hand
# ---------------------------------------------------------------------------------------------
def _hand_defaults() -> str:
    return f"""  <default>
    <default class="hand">
      <joint type="hinge" armature="{_f(FINGER_ARMATURE)}" damping="0" limited="true"/>
      <geom type="capsule" contype="2" conaffinity="1" condim="4" friction="1 0.005 0.0001"
            solref="{_f(HAND_SOLREF[0])} {_f(HAND_SOLREF[1])}" solimp="{_v(HAND_SOLIMP)}"
            density="{_f(TISSUE_DENSITY)}" rgba="0.87 0.68 0.58 1" group="2"/>
      <site type="sphere" size="0.004" rgba="0.9 0.1 0.1 1" group="4"/>
      <position ctrllimited="false" forcelimited="true"/>
      <default class="root_slide">
        <joint type="slide" armature="0" limited="false"/>
        <position ctrllimited="true" forcerange="{_f(-ROOT_FORCE_LIMIT)} {_f(ROOT_FORCE_LIMIT)}"/>
      </default>
      <default class="root_hinge">
        <joint type="hinge" armature="{_f(ROOT_ROT_ARMATURE)}" limited="false"/>
        <position ctrllimited="true"
                  forcerange="{_f(-ROOT_TORQUE_LIMIT)} {_f(ROOT_TORQUE_LIMIT)}"/>
      </default>
    </default>
    <default class="object">
      <geom contype="1" conaffinity="3" condim="4" priority="1" group="1"
            solref="{_f(HAND_SOLREF[0])} {_f(HAND_SOLREF[1])}" solimp="{_v(HAND_SOLIMP)}"/>
    </default>
  </default>
"""


def _hand_body(model: HandModel, root_pos: Sequence[float], root_kd: np.ndarray,
               indent: str = "    ", gravcomp: bool = False) -> str:
    """The hand's bodies and joints; ``root_kd``: (6,) the root servos' damping, which sizes
    the wrist hinges' armature (:func:`root_rot_armature`)."""
    sk = model.skeleton
    off = model.bone_offsets
    caps_by_bone: dict[int, list] = {}
    for c in model.capsules:
        caps_by_bone.setdefault(c.bone, []).append(c)
    tip_local = model.bone_tips
    gc = ' gravcomp="1"' if gravcomp else ""
    lines: list[str] = []

    def joint_xml(dof: int, axis: Sequence[float], pad: str) -> str:
        lo, hi = JOINT_LIMITS[dof]
        return (f'{pad}<joint name="{JOINT_NAMES[dof]}" axis="{_v(axis)}" '
                f'range="{_f(lo)} {_f(hi)}"/>')

    def geoms(b: int, pad: str) -> None:
        for c in caps_by_bone.get(b, []):
            lines.append(f'{pad}<geom name="{c.name}" fromto="{_v(c.p0)} {_v(c.p1)}" '
                         f'size="{_f(c.radius)}"/>')

    def body(b: int, pad: str) -> None:
        quat = _wxyz(sk.rest_rot[b])
        lines.append(f'{pad}<body name="{BONE_NAMES[b]}" pos="{_v(off[b])}" '
                     f'quat="{_v(quat)}"{gc}>')
        p2 = pad + "  "
        sign = sk.abd_axis_sign
        if BONE_ABD_DOF[b] >= 0:
            lines.append(joint_xml(BONE_ABD_DOF[b], (0, 0, sign), p2))
        lines.append(joint_xml(BONE_FLEX_DOF[b], (0, 1, 0), p2))
        geoms(b, p2)
        children = [c for c in range(N_BONES) if BONE_PARENT[c] == b]
        if not children:
            finger = BONE_NAMES[b].split("_")[0]
            lines.append(f'{p2}<site name="{finger}_tip" pos="{_v(tip_local[b])}"/>')
        for c in children:
            body(c, p2)
        lines.append(f"{pad}</body>")

    rp = [float(x) for x in root_pos]
    lines.append(f'{indent}<body name="palm" pos="{_v(rp)}" childclass="hand"{gc}>')
    p1 = indent + "  "
    com = model.palm_box()[0]
    lines.append(f'{p1}<inertial pos="{_v(com)}" mass="{_f(PALM_MASS)}" '
                 f'diaginertia="{_v(model.palm_inertia(PALM_MASS))}"/>')
    for k, ax in enumerate(("1 0 0", "0 1 0", "0 0 1")):
        lines.append(f'{p1}<joint name="{JOINT_NAMES[k]}" class="root_slide" axis="{ax}" '
                     f'ref="{_f(rp[k])}"/>')
    arm = root_rot_armature(root_kd[3:6])
    for k, ax in enumerate(("1 0 0", "0 1 0", "0 0 1")):
        lines.append(f'{p1}<joint name="{JOINT_NAMES[3 + k]}" class="root_hinge" axis="{ax}" '
                     f'armature="{_f(arm[k])}"/>')
    geoms(0, p1)
    lines.append(f'{p1}<site name="palm_center" pos="{_v(com)}"/>')
    for c in range(1, N_BONES):
        if BONE_PARENT[c] == 0:
            body(c, p1)
    lines.append(f"{indent}</body>")
    return "\n".join(lines)


def root_rot_armature(kd: Sequence[float]) -> np.ndarray:
    """(3,) armature [kg m^2] of the wrist hinges for their servos' damping ``kd`` (3,) [N m
    s/rad]: at least ``kd * TIMESTEP``, so that the damping stays stable at the timestep when
    MuJoCo integrates it explicitly (a force-clamped servo; :data:`ROOT_ROT_ARMATURE`)."""
    return np.maximum(ROOT_ROT_ARMATURE, np.asarray(kd, dtype=np.float64) * TIMESTEP)


def _servo_gains(servo_kp: Sequence[float] | None, servo_kd: Sequence[float] | None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Per-DoF servo gains (JOINT_NAMES order), the table's where ``None``."""
    kp, kd = dof_gains()
    kp = kp if servo_kp is None else np.asarray(servo_kp, dtype=np.float64)
    kd = kd if servo_kd is None else np.asarray(servo_kd, dtype=np.float64)
    if kp.shape != (N_DOF,) or kd.shape != (N_DOF,) or not (
            np.isfinite(kp).all() and np.isfinite(kd).all() and (kp > 0).all()
            and (kd >= 0).all()):
        raise ConfigError(f"servo gains need {N_DOF} finite values (kp > 0, kd >= 0), "
                          "JOINT_NAMES order")
    return kp, kd


def _actuators(root_pos: Sequence[float], kp: np.ndarray, kd: np.ndarray,
               torque_limits: np.ndarray) -> str:
    """One MuJoCo ``position`` servo per DoF: ``kp (ctrl - q) - kv qd`` (eq. 8 / III.20,
    gains of Table 1 = Table III.1 unless given), clipped to the DoF's force range. The
    finger servos have no control range: a feed-forward effort ``e`` is commanded as the set
    point ``target + e / kp`` (``SimWorld``)."""
    out = ["  <actuator>"]
    for k in range(N_DOF):
        n = JOINT_NAMES[k]
        gains = f'kp="{_f(kp[k])}" kv="{_f(kd[k])}"'
        if k < 3:
            r = float(root_pos[k])
            out.append(f'    <position name="{n}" joint="{n}" class="root_slide" {gains} '
                       f'ctrlrange="{_f(r - 0.5)} {_f(r + 0.5)}"/>')
        elif k < 6:
            out.append(f'    <position name="{n}" joint="{n}" class="root_hinge" {gains} '
                       f'ctrlrange="{_f(-math.pi)} {_f(math.pi)}"/>')
        else:
            lim = torque_limits[k]
            out.append(f'    <position name="{n}" joint="{n}" class="hand" {gains} '
                       f'forcerange="{_f(-lim)} {_f(lim)}"/>')
    out.append("  </actuator>")
    return "\n".join(out)


def _sensors() -> str:
    out = ["  <sensor>"]
    for f in FINGERS:
        out.append(f'    <framepos name="{f}_tip_pos" objtype="site" objname="{f}_tip"/>')
    out.append("  </sensor>")
    return "\n".join(out)


def _home_qpos_hand(root_pos: Sequence[float]) -> np.ndarray:
    """A relaxed, slightly flexed hand above the table."""
    q = np.zeros(N_DOF)
    q[0:3] = root_pos
    for f in FINGERS[1:]:
        q[JOINT_NAMES.index(f"{f}_mcp_flex")] = 0.25
        q[JOINT_NAMES.index(f"{f}_pip_flex")] = 0.35
        q[JOINT_NAMES.index(f"{f}_dip_flex")] = 0.2
    q[JOINT_NAMES.index("thumb_tm_abd")] = 0.2
    q[JOINT_NAMES.index("thumb_mcp_flex")] = 0.15
    q[JOINT_NAMES.index("thumb_ip_flex")] = 0.15
    return np.clip(q, JOINT_LIMITS[:, 0], JOINT_LIMITS[:, 1])


def home_pose(root_pos: Sequence[float] = DEFAULT_ROOT_POS) -> np.ndarray:
    """The ``home`` keyframe's hand pose (27,) in JOINT_NAMES order."""
    return _home_qpos_hand(root_pos)


def _check_side(hand: str) -> None:
    if hand not in ("right", "left"):
        raise InputError(f"hand must be 'right' or 'left', got {hand!r}")


def build_hand(shape: HandShape | None = None, hand: str = "right",
               root_pos: Sequence[float] = DEFAULT_ROOT_POS,
               servo_kp: Sequence[float] | None = None,
               servo_kd: Sequence[float] | None = None,
               model: HandModel | None = None) -> str:
    """MJCF of the hand alone (``hand.xml``): defaults, the hand, actuators, a ``home`` key.
    ``servo_kp``, ``servo_kd``: (27,) servo gains per DoF (JOINT_NAMES order; ``None`` =
    Table 1 / III.1, :func:`dof_gains` maps per-row gains)."""
    _check_side(hand)
    model = model or HandModel(shape, side=hand)
    kp, kd = _servo_gains(servo_kp, servo_kd)
    home = _home_qpos_hand(root_pos)
    return f"""<mujoco model="hand_suite {hand} hand">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{_f(TIMESTEP)}" integrator="implicitfast" cone="elliptic" impratio="10"/>
{_hand_defaults()}
  <worldbody>
{_hand_body(model, root_pos, kd[:6])}
  </worldbody>
{_actuators(root_pos, kp, kd, finger_torque_limits(model))}
{_sensors()}
  <keyframe>
    <key name="home" qpos="{_v(home)}" ctrl="{_v(home)}"/>
  </keyframe>
</mujoco>
"""


# ---------------------------------------------------------------------------------------------
# Scenes
# ---------------------------------------------------------------------------------------------
def _object_xml(obj: ObjectSpec, pos: Sequence[float]) -> tuple[str, np.ndarray]:
    """Body XML of a free object and its initial qpos (7,)."""
    s = obj.size
    rgba = _v(obj.rgba)
    fr = f"{_f(obj.friction)} 0.005 0.0001"
    geoms: list[tuple[str, float]] = []  # (geom xml without mass, volume)
    if obj.kind == "box":
        geoms.append((f'type="box" size="{_v(s)}"', 8 * s[0] * s[1] * s[2]))
    elif obj.kind == "ball":
        geoms.append((f'type="sphere" size="{_f(s[0])}"', 4 / 3 * math.pi * s[0] ** 3))
    elif obj.kind == "stick":
        geoms.append((f'type="cylinder" size="{_f(s[0])} {_f(s[1])}" '
                       'quat="0.7071068 0 0.7071068 0"', math.pi * s[0] ** 2 * 2 * s[1]))
    elif obj.kind == "composite":
        for i, part in enumerate(obj.parts):
            shape = (f'type="mesh" mesh="{obj.name}_mesh{i}"' if part.type == "mesh" else
                     f'type="{part.type}" size="{_v(part.size)}"')
            geoms.append((f'{shape} pos="{_v(part.pos)}" quat="{_v(part.quat)}"', part.volume))
    else:  # cup: bottom disc, ring of wall boxes, handle of three capsules
        r, hh, wall = s
        geoms.append((f'type="cylinder" size="{_f(r)} {_f(wall / 2)}" '
                       f'pos="0 0 {_f(-hh + wall / 2)}"', math.pi * r * r * wall))
        n = 16
        rm = r - wall / 2
        half_w = rm * math.tan(math.pi / n) + 1e-4
        for i in range(n):
            a = 2 * math.pi * i / n
            q = (math.cos(a / 2), 0.0, 0.0, math.sin(a / 2))
            # the wall stands on the bottom disc, so only the disc touches the table
            geoms.append((f'type="box" size="{_f(wall / 2)} {_f(half_w)} {_f(hh - wall / 2)}" '
                          f'pos="{_f(rm * math.cos(a))} {_f(rm * math.sin(a))} {_f(wall / 2)}" '
                          f'quat="{_v(q)}"', wall * 2 * half_w * (2 * hh - wall)))
        # handle: a C of capsules on +y
        y0, y1 = r, r + 0.6 * hh
        z0 = 0.55 * hh
        hrad = 0.006
        for p0, p1 in (((0, y0 - 0.002, z0), (0, y1, z0)), ((0, y1, z0), (0, y1, -z0)),
                       ((0, y1, -z0), (0, y0 - 0.002, -z0))):
            length = float(np.linalg.norm(np.subtract(p1, p0)))
            geoms.append((f'type="capsule" fromto="{_v(p0)} {_v(p1)}" size="{_f(hrad)}"',
                          math.pi * hrad ** 2 * length))
    total = sum(v for _, v in geoms)
    body = [f'    <body name="{obj.name}" pos="{_v(pos)}" euler="{_v(obj.euler)}">',
            f'      <freejoint name="{obj.name}_free"/>']
    for i, (g, vol) in enumerate(geoms):
        body.append(f'      <geom name="{obj.name}_{i}" class="object" {g} '
                    f'mass="{_f(obj.mass * vol / total)}" friction="{fr}" rgba="{rgba}"/>')
    body.append("    </body>")
    quat = _euler_xyz_quat(obj.euler)
    return "\n".join(body), np.r_[pos, quat]


def _mesh_assets(specs: Sequence[ObjectSpec]) -> str:
    """``<asset>`` with the mesh parts of composite objects (inline vertices and faces)."""
    meshes = [f'    <mesh name="{o.name}_mesh{i}" vertex="{_v(p.vertices)}" '
              f'face="{" ".join(str(int(f)) for f in p.faces)}"/>'
              for o in specs for i, p in enumerate(o.parts) if p.type == "mesh"]
    return "  <asset>\n" + "\n".join(meshes) + "\n  </asset>" if meshes else ""


def _euler_xyz_quat(euler: Sequence[float]) -> np.ndarray:
    """MuJoCo's default euler sequence 'xyz' (intrinsic... extrinsic-free) -> quat (w,x,y,z)."""
    from hand_capture.model.joints import root_rotation_matrix

    return _wxyz(root_rotation_matrix(np.asarray(euler, dtype=float)))


def _as_spec(o: ObjectSpec | str) -> ObjectSpec:
    if isinstance(o, ObjectSpec):
        return o
    if isinstance(o, str):
        return ObjectSpec(kind=o)
    raise InputError(f"objects must be ObjectSpec or a kind name {_KINDS}, got {o!r}")


def build_scene(objects: Sequence[ObjectSpec | str] = (), shape: HandShape | None = None,
                hand: str = "right", root_pos: Sequence[float] = DEFAULT_ROOT_POS,
                servo_kp: Sequence[float] | None = None,
                servo_kd: Sequence[float] | None = None, table_friction: float = 0.5,
                hand_gravcomp: bool = False, model: HandModel | None = None) -> str:
    """A self-contained MJCF scene: floor, a table whose top is the plane z = 0, the hand and
    free objects (kinds 'box', 'ball', 'stick', 'cup' or :class:`ObjectSpec`).

    The hand comes first, so ``qpos[:27]``, ``qvel[:27]`` and ``ctrl[:27]`` are the hand's, in
    JOINT_NAMES order; each object adds a free joint ``{name}_free`` (7 qpos, 6 qvel). The
    ``home`` keyframe holds the hand above the table and the objects at rest on it.
    ``hand_gravcomp`` cancels gravity on the hand bodies (then the controller must not add
    its own gravity term, eq. III.19). ``servo_kp``, ``servo_kd``: as :func:`build_hand`.
    """
    _check_side(hand)
    if not (math.isfinite(table_friction) and 0 < table_friction <= 5):
        raise InputError(f"table_friction must be in (0, 5], got {table_friction}")
    model = model or HandModel(shape, side=hand)
    kp, kd = _servo_gains(servo_kp, servo_kd)
    specs = [_as_spec(o) for o in objects]
    names = [o.name for o in specs]
    if len(set(names)) != len(names):
        raise InputError(f"object names must be unique, got {names}")
    bodies, qpos_obj = [], []
    for o in specs:
        if o.pos is None:
            x, y = _DEFAULT_XY[o.kind]
            pos = (x, -y if hand == "left" else y, o.half_height + 1e-4)
        else:
            pos = o.pos
        xml, q = _object_xml(o, pos)
        bodies.append(xml)
        qpos_obj.append(q)
    home = _home_qpos_hand(root_pos)
    key_qpos = np.concatenate([home] + qpos_obj)
    key_ctrl = home
    objs = "\n".join(bodies)
    return f"""<mujoco model="hand_suite scene ({hand} hand)">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{_f(TIMESTEP)}" integrator="implicitfast" cone="elliptic" impratio="10"/>
  <visual>
    <headlight diffuse="0.6 0.6 0.6" ambient="0.3 0.3 0.3" specular="0 0 0"/>
    <global offwidth="640" offheight="480"/>
  </visual>
{_hand_defaults()}
{_mesh_assets(specs)}
  <worldbody>
    <light pos="0 0 1.5" dir="0 0 -1" directional="true"/>
    <geom name="floor" type="plane" size="2 2 0.05" pos="0 0 -0.75" rgba="0.5 0.5 0.5 1"
          contype="1" conaffinity="3"/>
    <geom name="table" type="box" size="0.4 0.4 0.02" pos="0.15 0 -0.02" rgba="0.55 0.4 0.3 1"
          contype="1" conaffinity="3" condim="4" friction="{_f(table_friction)} 0.005 0.0001"/>
{_hand_body(model, root_pos, kd[:6], gravcomp=hand_gravcomp)}
{objs}
  </worldbody>
{_actuators(root_pos, kp, kd, finger_torque_limits(model))}
{_sensors()}
  <keyframe>
    <key name="home" qpos="{_v(key_qpos)}" ctrl="{_v(key_ctrl)}"/>
  </keyframe>
</mujoco>
"""


@dataclass(frozen=True)
class ExportedFiles:
    hand: Path
    scenes: dict[str, Path] = field(default_factory=dict)


#: the scenes written by :func:`export_mjcf`: name -> objects
DEFAULT_SCENES: dict[str, tuple[str, ...]] = {
    "scene": (),
    "scene_box": ("box",),
    "scene_ball": ("ball",),
    "scene_stick": ("stick",),
    "scene_cup": ("cup",),
    "scene_objects": ("box", "ball", "stick", "cup"),
}


def export_mjcf(out_dir: str | Path, shape: HandShape | None = None, hand: str = "right",
                scenes: dict[str, Sequence[ObjectSpec | str]] | None = None) -> ExportedFiles:
    """Write ``hand.xml`` and one ``<name>.xml`` per scene (default :data:`DEFAULT_SCENES`)
    into ``out_dir``; every file is self-contained."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    model = HandModel(shape, side=hand)
    hand_path = out / "hand.xml"
    hand_path.write_text(build_hand(hand=hand, model=model))
    written = {}
    for name, objs in (DEFAULT_SCENES if scenes is None else scenes).items():
        p = out / f"{name}.xml"
        p.write_text(build_scene(objs, hand=hand, model=model))
        written[name] = p
    return ExportedFiles(hand_path, written)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m hand_capture.model.mjcf OUT_DIR [--hand left] [--shape-seed N]``."""
    import argparse

    from hand_capture.model.shape import sample_shape

    ap = argparse.ArgumentParser(description="Write hand.xml and the MJCF scenes.")
    ap.add_argument("out_dir")
    ap.add_argument("--hand", choices=("right", "left"), default="right")
    ap.add_argument("--shape-seed", type=int, default=-1,
                    help="sample a subject shape with this seed (default: the template)")
    args = ap.parse_args(argv)
    shape = None if args.shape_seed < 0 else sample_shape(args.shape_seed)
    out = export_mjcf(args.out_dir, shape=shape, hand=args.hand)
    for p in [out.hand, *out.scenes.values()]:
        print(p)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
