"""The template hand skeleton (dissertation ch. II.3.1): bones, rest frames, joint axes.

16 rigid bones: the palm (root, 6 DoF) and three segments per finger. Each bone's local frame
has its origin at the bone's proximal joint centre, ``+x`` along the bone (the bone direction
``d_j`` of eq. II.3), ``+y`` the flexion axis and ``+z`` the abduction axis (dorsal for the
fingers). A bone's rest frame relative to its parent is ``(R_rest, offset)``; its pose
transform is ``T_parent @ [R_rest | offset] @ Rz(abd) @ Ry(flex)`` (joints.py conventions).

Dimensions of the template (an average adult right hand):

* Hand length (wrist crease to middle fingertip) 0.187 m and hand breadth at the metacarpal
  heads 0.084 m: the mean of the male and female means of the US Army anthropometric survey
  (ANSUR II, Gordon et al. 2014: hand length about 0.194 / 0.181 m, hand breadth about
  0.089 / 0.079 m for men / women).
* Phalanx lengths: segment-length-to-hand-length ratios of Buchholz, Armstrong & Goldstein,
  "Anthropometric data for describing the kinematics of the human hand", Ergonomics 35(3)
  (1992), Table 2 (thumb metacarpal / proximal / distal 0.251 / 0.196 / 0.158; index proximal /
  middle / distal 0.265 / 0.143 / 0.097; middle 0.277 / 0.170 / 0.108; ring 0.259 / 0.165 /
  0.107; little 0.206 / 0.117 / 0.093). The distal ratio reaches the fingertip.
* Metacarpal heads (MCP centres) placed with the same paper's metacarpal ratios (0.374, 0.373,
  0.336, 0.295) from carpometacarpal joints about 15 mm distal of the wrist centre.
* Segment radii from finger breadths of about 17-20 mm (proximal) tapering to 13-15 mm (tip).

The left hand is the mirror image (``y -> -y`` in every bone frame): rest rotations become
``M R M`` with ``M = diag(1, -1, 1)``, offsets and local points ``M p``, abduction axes ``-z``
(so a positive abduction still moves a finger towards the thumb) and mesh faces flip winding.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hand_capture.errors import InputError
from hand_capture.model.joints import FINGERS, JOINT_INDEX

HAND_LENGTH_M: float = 0.187   # template hand length (ANSUR II, see module docstring)
HAND_BREADTH_M: float = 0.084  # template hand breadth at the metacarpal heads

SEGMENTS: tuple[str, ...] = ("proximal", "middle", "distal")
THUMB_SEGMENTS: tuple[str, ...] = ("metacarpal", "proximal", "distal")


def _bone_names() -> tuple[str, ...]:
    names = ["palm"]
    for f in FINGERS:
        segs = THUMB_SEGMENTS if f == "thumb" else SEGMENTS
        names += [f"{f}_{s}" for s in segs]
    return tuple(names)


#: The 16 bones (= MuJoCo bodies) in kinematic order: palm, then 3 per finger proximal->distal.
BONE_NAMES: tuple[str, ...] = _bone_names()
N_BONES: int = len(BONE_NAMES)
BONE_INDEX: dict[str, int] = {n: i for i, n in enumerate(BONE_NAMES)}
#: parent bone index (-1 for the palm)
BONE_PARENT: np.ndarray = np.array([-1] + [0 if k % 3 == 0 else 1 + k - 1
                                           for k in range(15)], dtype=np.int64)
#: finger bones by level: LEVELS[l][f] is the bone of finger f at depth l+1
LEVELS: np.ndarray = np.arange(1, 16).reshape(5, 3).T.copy()

#: The 21 keypoints returned as ``joint_positions``: the wrist, then per finger the three joint
#: centres and the tip (thumb: TM, MCP, IP, tip; fingers: MCP, PIP, DIP, tip).
KEYPOINT_NAMES: tuple[str, ...] = ("wrist",) + tuple(
    f"{f}_{j}" for f in FINGERS
    for j in (("tm", "mcp", "ip", "tip") if f == "thumb" else ("mcp", "pip", "dip", "tip"))
)
N_KEYPOINTS: int = len(KEYPOINT_NAMES)
#: the bones whose origin is each keypoint (tips use the distal bone and its tip point)
KEYPOINT_BONE: np.ndarray = np.array(
    [0] + [b for f in range(5) for b in (1 + 3 * f, 2 + 3 * f, 3 + 3 * f, 3 + 3 * f)],
    dtype=np.int64)
FINGERTIP_KEYPOINTS: np.ndarray = np.array([4, 8, 12, 16, 20], dtype=np.int64)


def _bone_dofs() -> tuple[np.ndarray, np.ndarray]:
    """(abd_dof, flex_dof) per bone, -1 where the bone has none (palm: root, handled apart)."""
    abd = -np.ones(N_BONES, dtype=np.int64)
    flex = -np.ones(N_BONES, dtype=np.int64)
    for f in FINGERS:
        if f == "thumb":
            joints = (("tm_abd", "tm_flex"), ("mcp_abd", "mcp_flex"), (None, "ip_flex"))
        else:
            joints = (("mcp_abd", "mcp_flex"), (None, "pip_flex"), (None, "dip_flex"))
        for lvl, (a, fl) in enumerate(joints):
            b = LEVELS[lvl, FINGERS.index(f)]
            if a is not None:
                abd[b] = JOINT_INDEX[f"{f}_{a}"]
            flex[b] = JOINT_INDEX[f"{f}_{fl}"]
    return abd, flex


BONE_ABD_DOF, BONE_FLEX_DOF = _bone_dofs()
#: the bone each DoF moves (root DoFs move the palm)
DOF_BONE: np.ndarray = np.zeros(27, dtype=np.int64)
for _b in range(N_BONES):
    for _d in (BONE_ABD_DOF[_b], BONE_FLEX_DOF[_b]):
        if _d >= 0:
            DOF_BONE[_d] = _b


def _descendants_mask() -> np.ndarray:
    """(N_BONES, N_BONES) bool: ``[a, b]`` is True when bone b is a or one of a's descendants."""
    m = np.eye(N_BONES, dtype=bool)
    for b in range(N_BONES):
        p = BONE_PARENT[b]
        while p >= 0:
            m[p, b] = True
            p = BONE_PARENT[p]
    return m


DESCENDANTS: np.ndarray = _descendants_mask()
#: (N_BONES, 27) bool: DoF k moves bone j
BONE_DOF_MASK: np.ndarray = DESCENDANTS[DOF_BONE].T.copy()


# ---------------------------------------------------------------------------------------------
# Template geometry (right hand, metres)
# ---------------------------------------------------------------------------------------------
def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _ry(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


_D = math.radians
_HL = HAND_LENGTH_M
# Buchholz et al. (1992) segment / hand-length ratios (module docstring)
_SEG_RATIO = {
    "thumb": (0.251, 0.196, 0.158),
    "index": (0.265, 0.143, 0.097),
    "middle": (0.277, 0.170, 0.108),
    "ring": (0.259, 0.165, 0.107),
    "little": (0.206, 0.117, 0.093),
}
# Carpometacarpal joints and metacarpal heads in the palm frame [m]. MCP heads are spaced
# about 21 mm apart so that the breadth over the heads plus the soft tissue is HAND_BREADTH_M.
_CMC = {"index": (0.018, 0.011, 0.0), "middle": (0.015, 0.001, 0.0),
        "ring": (0.013, -0.009, 0.0), "little": (0.012, -0.018, 0.0)}
_MCP = {"index": (0.0830, 0.0300, 0.0), "middle": (0.0850, 0.0085, 0.0),
        "ring": (0.0805, -0.0125, 0.0), "little": (0.0725, -0.0320, 0.0)}
# Rest spread of the fingers about the palm normal (a flat, slightly spread hand) [deg].
_SPREAD_DEG = {"index": 9.0, "middle": 1.5, "ring": -6.0, "little": -14.0}
# Thumb carpometacarpal (TM) joint centre and rest orientation of the thumb metacarpal:
# 40 deg radial in the palm plane, 6 deg palmar, rolled -55 deg about its axis so that
# flexion moves the thumb palmar-ulnar (towards the little finger), as in opposition.
_TM_POS = (0.024, 0.021, -0.011)
_TM_ROT = _rz(_D(40.0)) @ _ry(_D(6.0)) @ _rx(_D(-55.0))
_THUMB_MCP_ROT = _rz(_D(-10.0))  # phalanges angle back towards the index
# Round-cone radii [m] (proximal end, distal end) per segment.
_RADII = {
    "thumb": ((0.0135, 0.0105), (0.0102, 0.0094), (0.0094, 0.0084)),
    "index": ((0.0092, 0.0086), (0.0086, 0.0078), (0.0078, 0.0070)),
    "middle": ((0.0095, 0.0088), (0.0088, 0.0080), (0.0080, 0.0072)),
    "ring": ((0.0090, 0.0083), (0.0083, 0.0076), (0.0076, 0.0068)),
    "little": ((0.0080, 0.0073), (0.0073, 0.0066), (0.0066, 0.0060)),
}
PALM_RADIUS: float = 0.0135  # half the palm thickness (ANSUR hand thickness at MC ~ 27-30 mm)


@dataclass(frozen=True)
class Primitive:
    """A round cone (capsule with two radii) fixed in a bone frame; the building block of the
    template surface (an implicit union, see mesh.py) and of the collision capsules."""

    bone: int
    p0: tuple[float, float, float]  # local endpoint [m]
    p1: tuple[float, float, float]
    r0: float  # radius at p0 [m]
    r1: float  # radius at p1 [m]
    collide: bool = True  # also a collision capsule
    scale_yz: tuple[float, float] = (1.0, 1.0)  # cross-section stretch (wrist ellipse)


@dataclass(frozen=True)
class Skeleton:
    """Rest skeleton of one hand side (arrays indexed by bone)."""

    side: str
    rest_rot: np.ndarray        # (16, 3, 3) rest rotation relative to the parent
    offset: np.ndarray          # (16, 3) bone origin in the parent frame (palm: zeros)
    length: np.ndarray          # (16,) joint-to-joint length (distal: to the tip) [m]
    tip_local: np.ndarray       # (16, 3) distal end point in the bone frame
    abd_axis_sign: float        # +1 right, -1 left (abduction about +-z)
    primitives: tuple[Primitive, ...]
    mirror: np.ndarray          # (3, 3) diag(1, +-1, 1)

    @property
    def rest_world(self) -> tuple[np.ndarray, np.ndarray]:
        """Rest-pose world rotations (16, 3, 3) and origins (16, 3) at the zero root."""
        rot = np.zeros((N_BONES, 3, 3))
        pos = np.zeros((N_BONES, 3))
        rot[0] = np.eye(3)
        for b in range(1, N_BONES):
            p = BONE_PARENT[b]
            rot[b] = rot[p] @ self.rest_rot[b]
            pos[b] = pos[p] + rot[p] @ self.offset[b]
        return rot, pos


def _right_template() -> Skeleton:
    rest_rot = np.tile(np.eye(3), (N_BONES, 1, 1))
    offset = np.zeros((N_BONES, 3))
    length = np.zeros(N_BONES)
    prims: list[Primitive] = []
    for fi, f in enumerate(FINGERS):
        lens = [r * _HL for r in _SEG_RATIO[f]]
        b1, b2, b3 = LEVELS[:, fi]
        if f == "thumb":
            offset[b1] = _TM_POS
            rest_rot[b1] = _TM_ROT
            rest_rot[b2] = _THUMB_MCP_ROT
        else:
            offset[b1] = _MCP[f]
            rest_rot[b1] = _rz(_D(_SPREAD_DEG[f]))
        offset[b2] = (lens[0], 0.0, 0.0)
        offset[b3] = (lens[1], 0.0, 0.0)
        length[[b1, b2, b3]] = lens
        for lvl, b in enumerate((b1, b2, b3)):
            r0, r1 = _RADII[f][lvl]
            end = lens[lvl] - (r1 if lvl == 2 else 0.0)  # the tip sphere ends at the tip
            prims.append(Primitive(int(b), (0.0, 0.0, 0.0), (end, 0.0, 0.0), r0, r1))
        if f != "thumb":
            # metacarpal: part of the palm, from the CMC joint to the MCP head
            prims.append(Primitive(0, _CMC[f], _MCP[f], PALM_RADIUS, PALM_RADIUS * 0.96))
    # palm length (wrist to middle MCP) for the palm scale
    length[0] = float(np.linalg.norm(_MCP["middle"]))
    # hypothenar eminence (palmar-ulnar pad) and the carpus / wrist stub
    prims.append(Primitive(0, (0.012, -0.022, -0.004), (0.055, -0.030, -0.004), 0.0125, 0.0115))
    prims.append(Primitive(0, (-0.018, 0.0, 0.0), (0.012, 0.0, -0.001), 0.018, 0.019,
                           collide=False, scale_yz=(1.45, 1.0)))
    tip_local = np.zeros((N_BONES, 3))
    tip_local[:, 0] = length
    return Skeleton("right", rest_rot, offset, length, tip_local, 1.0, tuple(prims),
                    np.eye(3))


_RIGHT = _right_template()


def _mirror_skeleton(s: Skeleton) -> Skeleton:
    m = np.diag([1.0, -1.0, 1.0])
    prims = tuple(
        Primitive(p.bone, tuple(m @ np.array(p.p0)), tuple(m @ np.array(p.p1)), p.r0, p.r1,
                  p.collide, p.scale_yz)
        for p in s.primitives)
    return Skeleton("left", m @ s.rest_rot @ m, s.offset @ m, s.length.copy(),
                    s.tip_local @ m, -1.0, prims, m)


_LEFT = _mirror_skeleton(_RIGHT)


def template_skeleton(side: str = "right") -> Skeleton:
    """The rest skeleton of the template hand for ``side`` ('right' or 'left')."""
    if side == "right":
        return _RIGHT
    if side == "left":
        return _LEFT
    raise InputError(f"side must be 'right' or 'left', got {side!r}")
