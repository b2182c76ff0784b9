"""A robot hand loaded from MJCF or URDF (through MuJoCo): joints, points, FK and Jacobians.

Kinematics only: the optimised joints (1-DoF hinge or slide joints) are set in ``qpos``, every
other joint is held at its reference value (``qpos0``), and ``mj_kinematics`` + ``mj_comPos``
give body poses; point Jacobians are MuJoCo's analytic ``mj_jac`` (the columns of the
optimised joints' DoFs).

URDF files are read as MuJoCo reads them, with two changes so that any robot description
loads for kinematics: ``<visual>`` and ``<collision>`` elements are dropped (no mesh files are
needed) and links without ``<inertial>`` get a tiny one; static bodies are kept
(``fusestatic="false"``) so fixed fingertip links remain bodies a config can name.
"""

from __future__ import annotations

import fnmatch
import functools
import io
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from hand_control.errors import ConfigError, InputError

#: ``model:`` value that builds the suite's own exported hand (hand_capture.model.mjcf).
BUILTIN_SUITE_HAND = "builtin:suite_hand"
_HINGE, _SLIDE = int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)


def _prepare_urdf(text: str, source: str) -> str:
    """URDF text MuJoCo can compile for kinematics (see the module docstring)."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise ConfigError(f"robot model {source}: not valid XML: {e}") from e
    if root.tag != "robot":
        raise ConfigError(f"robot model {source}: a URDF must have <robot> at the top, "
                          f"found <{root.tag}>")
    for link in root.findall("link"):
        for tag in ("visual", "collision"):
            for el in link.findall(tag):
                link.remove(el)
        if link.find("inertial") is None:
            inertial = ET.SubElement(link, "inertial")
            ET.SubElement(inertial, "mass", value="0.001")
            ET.SubElement(inertial, "inertia", ixx="1e-7", iyy="1e-7", izz="1e-7",
                          ixy="0", ixz="0", iyz="0")
    mj = root.find("mujoco")
    if mj is None:
        mj = ET.SubElement(root, "mujoco")
    comp = mj.find("compiler")
    if comp is None:
        comp = ET.SubElement(mj, "compiler")
    comp.set("fusestatic", "false")
    comp.set("discardvisual", "true")
    return ET.tostring(root, encoding="unicode")


def _root_tag(text: str) -> str:
    """The top element's tag of an XML document ('' when it does not parse)."""
    try:
        for _event, el in ET.iterparse(io.StringIO(text), events=("start",)):
            return el.tag
    except ET.ParseError:
        return ""
    return ""


@functools.lru_cache(maxsize=4)
def _suite_hand_xml(side: str) -> str:
    from hand_capture.model.mjcf import build_hand

    return build_hand(hand=side)


def load_mujoco_model(model: str | Path, side: str = "right") -> mujoco.MjModel:
    """A MuJoCo model from an MJCF (``.xml``) or URDF (``.urdf``) file, or
    :data:`BUILTIN_SUITE_HAND` (the suite's exported hand of ``side``).

    Raises:
        ConfigError: a missing file, or MuJoCo's compile error (with the file named).
    """
    if str(model) == BUILTIN_SUITE_HAND:
        return mujoco.MjModel.from_xml_string(_suite_hand_xml(side))
    path = Path(model).expanduser()
    if not path.is_file():
        raise ConfigError(f"robot model file {str(path)!r} does not exist (an MJCF .xml or "
                          f"URDF .urdf file, or {BUILTIN_SUITE_HAND!r})")
    try:
        text = path.read_text()
        if path.suffix.lower() == ".urdf" or _root_tag(text) == "robot":
            return mujoco.MjModel.from_xml_string(_prepare_urdf(text, str(path)))
        return mujoco.MjModel.from_xml_path(str(path))  # MJCF: includes relative to the file
    except (ValueError, OSError) as e:
        raise ConfigError(f"robot model {path}: MuJoCo could not load it: {e}") from e


def _names(m: mujoco.MjModel, objtype: mujoco.mjtObj, n: int) -> list[str]:
    return [mujoco.mj_id2name(m, objtype, i) or "" for i in range(n)]


@dataclass(frozen=True)
class PointRef:
    """A point fixed to a robot body: ``body`` id and ``offset`` in the body frame [m]."""

    name: str
    body: int
    offset: np.ndarray


class RobotHand:
    """The kinematics of a robot hand (MuJoCo model), over the joints that are optimised.

    Args:
        model: the compiled MuJoCo model.
        base_body: the body the hand's wrist frame is fixed to; no optimised joint may move it.
        joints: the joints to optimise, by name; empty: every hinge / slide joint not matched
            by ``fixed_joints``.
        fixed_joints: names or shell patterns (``root_*``) of joints held at ``qpos0``.
        source: where the model came from (for messages).

    Raises:
        ConfigError: unknown joints or bodies (the message lists those that exist), a joint
            that is not a hinge or slide, optimised joints that move the base body.
    """

    def __init__(self, model: mujoco.MjModel, base_body: str, joints: Sequence[str] = (),
                 fixed_joints: Sequence[str] = (), source: str = "<model>") -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self.source = source
        self.body_names = tuple(_names(model, mujoco.mjtObj.mjOBJ_BODY, model.nbody))
        self.site_names = tuple(_names(model, mujoco.mjtObj.mjOBJ_SITE, model.nsite))
        self.joint_names_all = tuple(_names(model, mujoco.mjtObj.mjOBJ_JOINT, model.njnt))
        self.base_body = self.body_id(base_body)
        one_dof = [i for i in range(model.njnt) if int(model.jnt_type[i]) in (_HINGE, _SLIDE)]
        errors: list[str] = []
        for pat in fixed_joints:
            if not any(fnmatch.fnmatchcase(self.joint_names_all[i], pat)
                       for i in range(model.njnt)):
                errors.append(f"fixed joint {pat!r} matches no joint")
        if joints:
            ids = []
            for n in joints:
                if n not in self.joint_names_all:
                    errors.append(f"joint {n!r} does not exist")
                    continue
                j = self.joint_names_all.index(n)
                if j not in one_dof:
                    errors.append(f"joint {n!r} is not a hinge or slide joint")
                ids.append(j)
        else:
            ids = [j for j in one_dof if not any(
                fnmatch.fnmatchcase(self.joint_names_all[j], p) for p in fixed_joints)]
        if errors:
            raise ConfigError(f"robot model {source}: " + "; ".join(errors)
                              + f"; joints of the model: {list(self.joint_names_all)}")
        if not ids:
            raise ConfigError(f"robot model {source}: no joint to optimise; joints of the "
                              f"model: {list(self.joint_names_all)}")
        self.joint_ids = np.array(ids, dtype=np.int64)
        self.joint_names = tuple(self.joint_names_all[j] for j in ids)
        self.qpos_adr = model.jnt_qposadr[self.joint_ids].copy()
        self.dof_adr = model.jnt_dofadr[self.joint_ids].copy()
        lo = np.empty(len(ids))
        hi = np.empty(len(ids))
        for k, j in enumerate(ids):
            if model.jnt_limited[j]:
                lo[k], hi[k] = model.jnt_range[j]
            else:  # an unlimited hinge turns at most half a turn either way; a slide 1 m
                lim = np.pi if int(model.jnt_type[j]) == _HINGE else 1.0
                lo[k], hi[k] = -lim, lim
        self.lower, self.upper = lo, hi
        # the base body must not move with an optimised joint
        moving = set()
        for j in ids:
            moving.add(int(model.jnt_bodyid[j]))
        b = self.base_body
        while b > 0:
            if b in moving:
                raise ConfigError(f"robot model {source}: base body "
                                  f"{self.body_names[self.base_body]!r} moves with optimised "
                                  f"joint(s) of body {self.body_names[b]!r}; fix them "
                                  "(fixed_joints) or choose another base body")
            b = int(model.body_parentid[b])
        self._jacp = np.zeros((3, model.nv))
        self.set_q(self.reference_q())
        self.base_rot = self.data.xmat[self.base_body].reshape(3, 3).copy()
        self.base_pos = self.data.xpos[self.base_body].copy()

    @property
    def n(self) -> int:
        """Number of optimised joints."""
        return len(self.joint_names)

    def reference_q(self) -> np.ndarray:
        """The optimised joints at the model's reference (``qpos0``), clipped into limits."""
        return np.clip(self.model.qpos0[self.qpos_adr], self.lower, self.upper)

    def body_id(self, name: str) -> int:
        """The id of body ``name``.

        Raises:
            ConfigError: no such body (the message lists the bodies of the model).
        """
        if name not in self.body_names:
            raise ConfigError(f"robot model {self.source}: no body {name!r}; bodies: "
                              f"{[b for b in self.body_names if b]}")
        return self.body_names.index(name)

    def point(self, name: str, *, body: str = "", site: str = "",
              offset: Sequence[float] = (0.0, 0.0, 0.0)) -> PointRef:
        """A point on the robot: a site, or a body origin plus ``offset`` [m, body frame].

        Raises:
            ConfigError: neither or both of body / site, an unknown body or site (listing the
                ones that exist).
        """
        off = np.asarray(offset, dtype=np.float64).reshape(3)
        if bool(body) == bool(site):
            raise ConfigError(f"point {name!r}: give exactly one of body or site")
        if site:
            if site not in self.site_names:
                raise ConfigError(f"robot model {self.source}: no site {site!r} (point "
                                  f"{name!r}); sites: {[s for s in self.site_names if s]}")
            s = self.site_names.index(site)
            return PointRef(name, int(self.model.site_bodyid[s]),
                            self.model.site_pos[s].copy() + self._site_rot(s) @ off)
        return PointRef(name, self.body_id(body), off)

    def _site_rot(self, s: int) -> np.ndarray:
        r = np.empty(9)
        mujoco.mju_quat2Mat(r, self.model.site_quat[s])
        return r.reshape(3, 3)

    def set_q(self, q: np.ndarray) -> None:
        """Set the optimised joints [rad or m] and run the position stage (kinematics and
        the quantities ``mj_jac`` needs)."""
        d = self.data
        d.qpos[self.qpos_adr] = q
        mujoco.mj_kinematics(self.model, d)
        mujoco.mj_comPos(self.model, d)

    def positions(self, points: Sequence[PointRef]) -> np.ndarray:
        """(k, 3) world positions [m] of ``points`` at the last :meth:`set_q`."""
        d = self.data
        bodies = np.fromiter((p.body for p in points), dtype=np.int64, count=len(points))
        off = np.array([p.offset for p in points]).reshape(-1, 3, 1)
        return d.xpos[bodies] + (d.xmat[bodies].reshape(-1, 3, 3) @ off)[..., 0]

    def jacobians(self, points: Sequence[PointRef], pos: np.ndarray | None = None
                  ) -> np.ndarray:
        """(k, 3, n) d position / d optimised joints (analytic, ``mj_jac``) at the last
        :meth:`set_q`."""
        if pos is None:
            pos = self.positions(points)
        out = np.empty((len(points), 3, self.n))
        jacp = self._jacp
        for i, p in enumerate(points):
            mujoco.mj_jac(self.model, self.data, jacp, None, pos[i], p.body)
            out[i] = jacp[:, self.dof_adr]
        return out

    def forward(self, q: np.ndarray, points: Sequence[PointRef]) -> np.ndarray:
        """(k, 3) world positions of ``points`` at joints ``q``.

        Raises:
            InputError: ``q`` of the wrong length or not finite.
        """
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (self.n,) or not np.isfinite(q).all():
            raise InputError(f"robot joints must be {self.n} finite values "
                             f"({list(self.joint_names)}), got shape {q.shape}")
        self.set_q(q)
        return self.positions(points)
