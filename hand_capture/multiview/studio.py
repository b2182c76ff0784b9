"""Synthetic multi-view studio: the hand and objects on a table, rendered from every rig camera.

Seed 000 films a hand manipulating objects with six synchronised colour cameras (sec. 4.1);
seed 002 evaluates on synthetic multi-view sequences with ground truth (Table 1). The studio
gives the suite such data with exact ground truth: a MuJoCo scene (the suite's MJCF hand, free
objects, a table whose top is z = 0) gets one fixed camera per rig camera, posed and with the
field of view of the rig file, and every camera renders

* colour and depth from one render pass (``mjr_render`` then ``mjr_readPixels`` of both
  buffers), with shadows, reflections and skybox off (ENVIRONMENT.md: about ten times faster
  on OSMesa),
* a per-pixel label image from a second, segmentation pass: 0 background and table,
  1 hand, 2... the objects in scene order,

and a colour noise model adds what a real camera does: per-frame exposure (gain) changes, a
slight optical blur and sensor noise. Frame-time jitter is in the stamps
(:func:`jittered_stamps`). The ground truth is the scene's state: the hand's 27-DoF pose and
the objects' poses in the world frame.

MuJoCo cameras have square pixels and a centred principal point; the studio refuses a rig
camera that is not such an ideal pinhole (calibrated real rigs are not rendered, only used).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from hand_capture.config import param, validate
from hand_capture.errors import ConfigError, InputError
from hand_capture.model.joints import N_DOF, matrix_to_quat_wxyz
from hand_capture.multiview.rig import Rig, RigCamera

__all__ = ["HAND_LABEL", "LEFT_PREFIX", "ParallelStudio", "Studio", "StudioNoise", "StudioView",
           "jittered_stamps", "studio_motion", "studio_scene"]

#: label of the (right) hand in :attr:`StudioView.labels`; a left hand and the objects get the
#: next labels (see :attr:`Studio.label_names`)
HAND_LABEL = 1
#: name prefix of the left hand's bodies and joints in a two-hand studio scene
LEFT_PREFIX = "left_"
#: geom group the MJCF hand moves to while a held-out surface stands in for it (not drawn)
_HIDDEN_GROUP = 5
_SKIN = np.array([0.87, 0.68, 0.58, 1.0], dtype=np.float32)
_SLEEVE = np.array([0.25, 0.3, 0.45, 1.0], dtype=np.float32)


@dataclass(frozen=True)
class StudioNoise:
    """Colour camera noise of the studio (0 everywhere = clean images)."""

    sensor_sigma: float = param(2.0, "Gaussian sensor noise [grey levels of 255]", lo=0.0,
                                hi=50.0)
    blur_sigma_px: float = param(0.6, "Gaussian optical blur [px]", lo=0.0, hi=5.0)
    exposure_sigma: float = param(0.05, "relative per-frame gain change (auto exposure)",
                                  lo=0.0, hi=0.5)
    seed: int = param(0, "noise seed", lo=0)

    def __post_init__(self) -> None:
        validate(self)


@dataclass(frozen=True)
class StudioView:
    """One camera's images of one instant.

    Attributes:
        rgb: (H, W, 3) uint8 colour, noise applied.
        depth_m: (H, W) float32 distance along the optical axis [m]; 0 where nothing is hit.
        labels: (H, W) uint8: 0 background/table, 1 hand, 2... objects.
    """

    rgb: np.ndarray
    depth_m: np.ndarray
    labels: np.ndarray


def jittered_stamps(n_frames: int, fps: float, n_cameras: int, *, jitter_s: float = 0.002,
                    offsets_s: Sequence[float] | None = None, seed: int = 0) -> np.ndarray:
    """Frame stamps (n_frames, n_cameras) [s] of free-running cameras: a constant clock offset
    per camera plus uniform jitter, as the synchroniser meets them."""
    rng = np.random.default_rng(seed)
    off = np.zeros(n_cameras) if offsets_s is None else np.asarray(offsets_s, dtype=float)
    if off.shape != (n_cameras,):
        raise InputError(f"offsets_s needs {n_cameras} values, got {off.shape}")
    t = np.arange(n_frames)[:, None] / fps + off[None, :]
    return t + rng.uniform(-jitter_s, jitter_s, (n_frames, n_cameras))


def _pose(q: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(q, dtype=float).reshape(-1)
    if a.shape != (N_DOF,) or not np.all(np.isfinite(a)):
        raise InputError(f"{name} must be {N_DOF} finite values, got {a.shape}")
    return a


def studio_motion(n: int) -> np.ndarray:
    """(n, 27) world poses of the studio's default performance: the MJCF scene's home pose
    (hand above the table) closing every finger towards its flexion limit and back while the
    wrist turns by +-0.3 rad (a motion not taken from the tracker's training clips)."""
    from hand_capture.model.joints import JOINT_LIMITS, JOINT_NAMES
    from hand_capture.model.mjcf import home_pose

    q0 = home_pose()
    out = np.repeat(q0[None], n, axis=0)
    s = 0.5 - 0.5 * np.cos(np.linspace(0.0, 2.0 * np.pi, n))
    for j, name in enumerate(JOINT_NAMES):
        if name.endswith(("_mcp_flex", "_pip_flex", "_dip_flex", "_ip_flex")):
            out[:, j] = q0[j] + s * 0.8 * (JOINT_LIMITS[j, 1] - q0[j])
    out[:, 5] += 0.6 * (s - 0.5)
    return np.clip(out, JOINT_LIMITS[:, 0], JOINT_LIMITS[:, 1])


def _check_ideal(cam: RigCamera) -> None:
    k = cam.intrinsics
    if abs(k.fx - k.fy) > 1e-3 * k.fx or abs(k.cx - (k.width - 1) / 2) > 0.5 or \
            abs(k.cy - (k.height - 1) / 2) > 0.5 or any(abs(d) > 1e-12 for d in k.distortion):
        raise ConfigError(f"camera {cam.name!r}: the studio renders ideal pinholes only (square "
                          f"pixels, centred principal point, no distortion); got fx={k.fx}, "
                          f"fy={k.fy}, cx={k.cx}, cy={k.cy}, d={k.distortion}")


def _add_camera(spec: object, cam: RigCamera) -> None:
    """A fixed MuJoCo camera matching a rig camera (MuJoCo looks along -z with y up)."""
    R = cam.R_wc @ np.diag([1.0, -1.0, -1.0])
    k = cam.intrinsics
    spec.worldbody.add_camera(name=cam.name, pos=cam.t_wc.tolist(),
                              quat=matrix_to_quat_wxyz(R).tolist(),
                              fovy=math.degrees(2.0 * math.atan(k.height / 2.0 / k.fy)))


def studio_scene(objects: Sequence[object] = ("box",), *, two_hands: bool = False,
                 left_root: Sequence[float] = (0.0, 0.3, 0.12)) -> object:
    """The studio's scene as a ``mujoco.MjSpec``: table, objects and the right hand of
    :func:`hand_capture.model.mjcf.build_scene` (object kinds or ``ObjectSpec``), the objects
    textured (a 17 mm checker in their colour: structure for optical flow and edges)
    and four backdrop walls 1.5 m away (visual only); with ``two_hands`` also a left hand
    (its bodies and joints prefixed ``left_``), rooted at ``left_root`` [m]. The qpos layout
    is :func:`~hand_capture.model.mjcf.build_scene`'s (plus the left hand at the end)."""
    import mujoco

    from hand_capture.model.mjcf import build_hand, build_scene

    spec = mujoco.MjSpec.from_string(build_scene(list(objects)))
    for body in spec.bodies:
        if body.name in ("world",) or not body.joints or \
                body.joints[0].type != mujoco.mjtJoint.mjJNT_FREE:
            continue
        for geom in body.geoms:
            rgb = np.asarray(geom.rgba[:3], dtype=float)
            tex = spec.add_texture(name=f"{body.name}_{geom.name or id(geom)}_tex",
                                   type=mujoco.mjtTexture.mjTEXTURE_2D,
                                   builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
                                   rgb1=rgb, rgb2=0.55 * rgb, width=64, height=64)
            mat = spec.add_material(name=f"{tex.name}_mat", texrepeat=[30, 30],
                                    texuniform=True)
            mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = tex.name
            geom.material = mat.name
            geom.rgba = [1.0, 1.0, 1.0, 1.0]
    for i, (pos, euler) in enumerate((((1.5, 0, 0.5), (0, -np.pi / 2, 0)),
                                      ((-1.5, 0, 0.5), (0, np.pi / 2, 0)),
                                      ((0, 1.5, 0.5), (np.pi / 2, 0, 0)),
                                      ((0, -1.5, 0.5), (-np.pi / 2, 0, 0)))):
        spec.worldbody.add_geom(name=f"backdrop{i}", type=mujoco.mjtGeom.mjGEOM_PLANE,
                                size=[1.5, 1.5, 0.05], pos=list(pos),
                                quat=_euler_quat(euler), rgba=[0.72, 0.74, 0.78, 1.0],
                                contype=0, conaffinity=0)
    if two_hands:
        left = mujoco.MjSpec.from_string(build_hand(hand="left", root_pos=tuple(left_root)))
        spec.worldbody.add_frame().attach_body(left.body("palm"), LEFT_PREFIX, "")
    for key in list(spec.keys):  # the keyframes hold the one-hand layout
        spec.delete(key)
    return spec


def _euler_quat(euler: Sequence[float]) -> list[float]:
    """Quaternion (w, x, y, z) of x-y-z Euler angles [rad] (one of them nonzero here)."""
    from hand_capture.cameras.transforms import rotvec_to_matrix

    R = np.eye(3)
    for axis, a in enumerate(euler):
        v = np.zeros(3)
        v[axis] = a
        R = R @ rotvec_to_matrix(v)
    return matrix_to_quat_wxyz(R).tolist()


class Studio:
    """Renders a MuJoCo scene from every camera of a rig; see the module docstring.

    Args:
        rig: the cameras (ideal pinholes, one resolution for all).
        scene: an MJCF scene (text, or a ``mujoco.MjSpec`` from :func:`studio_scene`) whose
            first 27 qpos are the (right) hand's, as :func:`hand_capture.model.mjcf.
            build_scene` builds it; the cameras are added to it.
        noise: colour noise; None = clean images.
    """

    def __init__(self, rig: Rig, scene: object, noise: StudioNoise | None = None) -> None:
        import mujoco

        sizes = {(c.intrinsics.width, c.intrinsics.height) for c in rig.cameras}
        if len(sizes) != 1:
            raise ConfigError(f"rig {rig.name!r}: the studio renders one resolution, got "
                              f"{sorted(sizes)}")
        for cam in rig.cameras:
            _check_ideal(cam)
        self.rig = rig
        self.width, self.height = sizes.pop()
        spec = mujoco.MjSpec.from_string(scene) if isinstance(scene, str) else scene
        for cam in rig.cameras:
            _add_camera(spec, cam)
        spec.visual.global_.offwidth = self.width
        spec.visual.global_.offheight = self.height
        self.model = spec.compile()
        if self.model.nq < N_DOF:
            raise InputError(f"the scene has {self.model.nq} qpos; the hand needs {N_DOF}")
        self.data = mujoco.MjData(self.model)
        if self.model.nkey:
            mujoco.mj_resetDataKeyframe(self.model, self.data, 0)
        mujoco.mj_forward(self.model, self.data)
        self._mj = mujoco
        self._labels_of_geom = self._geom_labels()
        self._hand_groups = self.model.geom_group.copy()[
            self.model.body_rootid[self.model.geom_bodyid] ==
            self.model.body_rootid[self.model.jnt_bodyid[0]]]
        self._surface: tuple[object, object] | None = None
        self._gl = mujoco.GLContext(self.width, self.height)
        self._gl.make_current()
        self._con = mujoco.MjrContext(self.model, mujoco.mjtFontScale.mjFONTSCALE_100)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._con)
        self._scene = mujoco.MjvScene(self.model, maxgeom=2000)
        self._opt = mujoco.MjvOption()
        self._cam = mujoco.MjvCamera()
        self._cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._viewport = mujoco.MjrRect(0, 0, self.width, self.height)
        self._rgb = np.empty((self.height, self.width, 3), np.uint8)
        self._seg = np.empty((self.height, self.width, 3), np.uint8)
        self._depth = np.empty((self.height, self.width), np.float32)
        ext = self.model.stat.extent
        self._near = self.model.vis.map.znear * ext
        self._far = self.model.vis.map.zfar * ext
        self.noise = noise
        self._rng = np.random.default_rng(noise.seed if noise else 0)
        self._bank: np.ndarray | None = None  # sensor noise drawn once (_noise_patch)
        self._closed = False

    def _geom_labels(self) -> np.ndarray:
        """Label per geom: 1 the (right) hand, then the left hand if any, then each object, in
        :attr:`label_names` order (root bodies in model order)."""
        m = self.model
        roots = sorted({int(r) for r in m.body_rootid if r != 0})
        hand_root = int(m.body_rootid[m.jnt_bodyid[0]])
        left = [r for r in roots if m.body(r).name.startswith(LEFT_PREFIX)]
        order = [hand_root, *left, *(r for r in roots if r != hand_root and r not in left)]
        label = {r: i + 1 for i, r in enumerate(order)}
        self._object_names = [m.body(r).name for r in order[1 + len(left):]]
        self.label_names = ["background", "hand", *(["left_hand"] if left else []),
                            *self._object_names]
        self._left_qpos = None
        if left:
            jnts = [j for j in range(m.njnt) if m.joint(j).name.startswith(LEFT_PREFIX)]
            self._left_qpos = np.array([m.jnt_qposadr[j] for j in jnts])
        return np.array([label.get(int(m.body_rootid[m.geom_bodyid[g]]), 0)
                         for g in range(m.ngeom)], dtype=np.uint8)

    @property
    def object_names(self) -> list[str]:
        """Names of the free objects' bodies, in label order."""
        return list(self._object_names)

    @property
    def two_hands(self) -> bool:
        """Whether the scene holds a left hand besides the right one."""
        return self._left_qpos is not None

    def set_state(self, hand_pose: np.ndarray, object_qpos: np.ndarray | None = None,
                  left_pose: np.ndarray | None = None) -> None:
        """Pose the scene: the (right) hand's 27-DoF world pose, the objects' free-joint qpos
        (7 each: position [m], quaternion w x y z, in scene order) and, in a two-hand scene,
        the left hand's 27-DoF world pose."""
        q = _pose(hand_pose, "hand_pose")
        self.data.qpos[:N_DOF] = q
        if left_pose is not None:
            if self._left_qpos is None:
                raise InputError("left_pose given, but the scene has one hand")
            self.data.qpos[self._left_qpos] = _pose(left_pose, "left_pose")
        if object_qpos is not None:
            o = np.asarray(object_qpos, dtype=float).reshape(-1)
            n_obj = self.model.nq - N_DOF * (2 if self._left_qpos is not None else 1)
            if o.size != n_obj or not np.all(np.isfinite(o)):
                raise InputError(f"object_qpos must hold {n_obj} finite values, got {o.size}")
            self.data.qpos[N_DOF: N_DOF + n_obj] = o
        self._mj.mj_kinematics(self.model, self.data)

    def set_qpos(self, qpos: np.ndarray) -> None:
        """Pose the whole scene from a full ``qpos`` (e.g. a simulation's state of the same
        scene: hand first, then the objects' free joints)."""
        q = np.asarray(qpos, dtype=float).reshape(-1)
        if q.size != self.model.nq or not np.all(np.isfinite(q)):
            raise InputError(f"qpos must hold {self.model.nq} finite values, got {q.size}")
        self.data.qpos[:] = q
        self._mj.mj_kinematics(self.model, self.data)

    def object_pose(self, name: str) -> np.ndarray:
        """(4, 4) world pose of an object body (ground truth of ``object/pose_truth``)."""
        b = self.model.body(name)
        T = np.eye(4)
        T[:3, :3] = self.data.xmat[b.id].reshape(3, 3)
        T[:3, 3] = self.data.xpos[b.id]
        return T

    def render(self, camera: str | int, *, labels: bool = True) -> StudioView:
        """Colour (noisy), depth and labels of the current state from one camera."""
        mj = self._mj
        if self._closed:
            raise InputError("the studio is closed")
        idx = camera if isinstance(camera, int) else self.rig.names.index(
            self.rig.camera(camera).name)
        self._gl.make_current()
        self._cam.fixedcamid = idx
        mj.mjv_updateScene(self.model, self.data, self._opt, None, self._cam,
                           mj.mjtCatBit.mjCAT_ALL, self._scene)
        n_model = self._scene.ngeom
        extra = self._add_surface_geoms()  # labels of the geoms added after the model's
        for f in (mj.mjtRndFlag.mjRND_SHADOW, mj.mjtRndFlag.mjRND_REFLECTION,
                  mj.mjtRndFlag.mjRND_SKYBOX, mj.mjtRndFlag.mjRND_SEGMENT,
                  mj.mjtRndFlag.mjRND_IDCOLOR):
            self._scene.flags[f] = 0
        mj.mjr_render(self._viewport, self._scene, self._con)
        mj.mjr_readPixels(self._rgb, self._depth, self._viewport, self._con)
        rgb = np.flipud(self._rgb)  # OpenGL rows run bottom-up
        d = np.flipud(self._depth)
        depth = (self._near / (1.0 - d * (1.0 - self._near / self._far))).astype(np.float32)
        depth[d >= 1.0] = 0.0
        lab = np.zeros((self.height, self.width), np.uint8)
        if labels:
            self._scene.flags[mj.mjtRndFlag.mjRND_SEGMENT] = 1
            self._scene.flags[mj.mjtRndFlag.mjRND_IDCOLOR] = 1
            mj.mjr_render(self._viewport, self._scene, self._con)
            mj.mjr_readPixels(self._seg, None, self._viewport, self._con)
            s = np.flipud(self._seg).astype(np.int64)
            ids = s[..., 0] + 256 * s[..., 1] + 65536 * s[..., 2] - 1  # scene geom index
            lab_of = np.array([self._labels_of_geom[g.objid]
                               if g.objtype == mj.mjtObj.mjOBJ_GEOM and g.objid >= 0 else 0
                               for g in self._scene.geoms[: n_model]] + extra, dtype=np.uint8)
            hit = (ids >= 0) & (ids < len(lab_of))
            lab[hit] = lab_of[ids[hit]]
        return StudioView(self._apply_noise(rgb), depth, lab)

    def set_surface(self, hand: object | None, params: object | None = None) -> None:
        """Show the (right) hand as a surface of the held-out family instead of the MJCF
        capsules: ``hand`` a :class:`~hand_capture.model.HandModel` (the subject's skeleton),
        ``params`` a :class:`~hand_capture.evaldata.surface.SurfaceParams` (finger and palm
        shapes, nails, forearm, sleeve). ``None`` restores the MJCF hand. The forearm and
        sleeve get the label ``arm``; the ground truth is the pose on ``hand``'s skeleton.
        """
        m = self.model
        hand_root = int(m.body_rootid[m.jnt_bodyid[0]])
        mine = np.array([int(m.body_rootid[m.geom_bodyid[g]]) == hand_root
                         for g in range(m.ngeom)])
        if hand is None:
            m.geom_group[mine] = self._hand_groups
            self._surface = None
            if self.label_names[-1] == "arm":
                self.label_names.pop()
            return
        if params is None:
            raise InputError("set_surface: give the surface parameters with the hand model")
        m.geom_group[mine] = _HIDDEN_GROUP
        self._surface = (hand, params)
        if self.label_names[-1] != "arm":
            self.label_names.append("arm")

    def _add_surface_geoms(self) -> list[int]:
        """Draw the held-out surface's primitives into the scene; their labels."""
        if self._surface is None:
            return []
        from hand_capture.evaldata.surface import HAND, SLEEVE, hand_primitives

        mj = self._mj
        hand, params = self._surface
        arm = len(self.label_names) - 1
        labels = []
        for p in hand_primitives(hand, self.data.qpos[:N_DOF], params):
            if self._scene.ngeom >= self._scene.maxgeom:
                break
            g = self._scene.geoms[self._scene.ngeom]
            rgba = _SLEEVE if p.label == SLEEVE else _SKIN
            if hasattr(p, "radius"):  # capsule between a and b
                mj.mjv_initGeom(g, mj.mjtGeom.mjGEOM_CAPSULE, np.zeros(3), np.zeros(3),
                                np.eye(3).ravel(), rgba)
                mj.mjv_connector(g, mj.mjtGeom.mjGEOM_CAPSULE, p.radius,
                                 np.asarray(p.a, float), np.asarray(p.b, float))
            else:
                mj.mjv_initGeom(g, mj.mjtGeom.mjGEOM_ELLIPSOID, np.asarray(p.radii, float),
                                np.asarray(p.centre, float),
                                np.asarray(p.axes, float).ravel(), rgba)
            g.segid = self._scene.ngeom
            self._scene.ngeom += 1
            labels.append(HAND_LABEL if p.label == HAND else arm)
        return labels

    def render_all(self, *, labels: bool = True) -> dict[str, StudioView]:
        """Every camera's view of the current state (one synchronised group)."""
        return {name: self.render(i, labels=labels) for i, name in enumerate(self.rig.names)}

    def _apply_noise(self, rgb: np.ndarray) -> np.ndarray:
        n = self.noise
        if n is None:
            return np.ascontiguousarray(rgb)
        import cv2

        img = rgb.astype(np.float32) * float(1.0 + self._rng.normal(0.0, n.exposure_sigma))
        if n.blur_sigma_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), n.blur_sigma_px)
        if n.sensor_sigma > 0:
            img += n.sensor_sigma * self._noise_patch(img.shape)
        return np.clip(img, 0, 255).round().astype(np.uint8)

    def _noise_patch(self, shape: tuple[int, ...]) -> np.ndarray:
        """Unit Gaussian noise of ``shape``: a window at a random offset into a bank of twice
        the image size drawn once (drawing 0.9 M normals per view took a third of a view's
        time; the windows of consecutive frames are independent draws of the offset)."""
        h, w = shape[0], shape[1]
        if self._bank is None or self._bank.shape[0] < 2 * h or self._bank.shape[1] < 2 * w:
            self._bank = self._rng.standard_normal((2 * h, 2 * w, *shape[2:]),
                                                   dtype=np.float32)
        y, x = self._rng.integers(0, h), self._rng.integers(0, w)
        return self._bank[y: y + h, x: x + w]

    def close(self) -> None:
        """Free the GL context (call it: leaving it to the interpreter's exit prints errors)."""
        if not self._closed:
            self._con.free()
            self._gl.free()
            self._closed = True

    def __enter__(self) -> Studio:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _worker(conn: object, rig: Rig, names: Sequence[str], objects: Sequence[object],
            two_hands: bool, noise: StudioNoise | None) -> None:
    """A :class:`ParallelStudio` process: renders its cameras of each state it is sent."""
    sub = Rig(rig.name, tuple(rig.camera(n) for n in names), rig.world_frame)
    with Studio(sub, studio_scene(objects, two_hands=two_hands), noise) as st:
        conn.send("ready")
        while True:
            msg = conn.recv()
            if msg is None:
                break
            try:
                st.set_qpos(msg)
                conn.send(st.render_all())
            except Exception as e:  # reported in the parent, which raises it
                conn.send(e)


class ParallelStudio:
    """The studio's cameras split over ``workers`` processes (one GL context each), so a
    group renders on every core; :meth:`render_all` returns the same views as one
    :class:`Studio` of the same scene (colour noise drawn per worker).

    Args:
        rig, noise: as :class:`Studio`.
        objects, two_hands: the scene, as :func:`studio_scene` builds it.
        workers: processes (at most one per camera).
    """

    def __init__(self, rig: Rig, objects: Sequence[object] = ("box",), *,
                 two_hands: bool = False, noise: StudioNoise | None = None,
                 workers: int = 2) -> None:
        import multiprocessing as mp

        if workers < 1:
            raise ConfigError(f"workers must be >= 1, got {workers}")
        ctx = mp.get_context("spawn")  # GL contexts must not be inherited across fork
        n = min(workers, len(rig))
        self.rig = rig
        self._parts = [list(rig.names[i::n]) for i in range(n)]
        self._conns, self._procs = [], []
        for i, names in enumerate(self._parts):
            parent, child = ctx.Pipe()
            seeded = None if noise is None else replace(noise, seed=noise.seed + i)
            p = ctx.Process(target=_worker, args=(child, rig, names, list(objects), two_hands,
                                                  seeded), daemon=True)
            p.start()
            self._conns.append(parent)
            self._procs.append(p)
        for c in self._conns:
            if c.recv() != "ready":
                raise InputError("a studio worker failed to start")
        self._nq: int | None = None

    def render_all(self, qpos: np.ndarray) -> dict[str, StudioView]:
        """Every camera's view of the scene state ``qpos`` (the full vector, as
        :meth:`Studio.set_qpos`), rendered in parallel."""
        q = np.asarray(qpos, dtype=float)
        for c in self._conns:
            c.send(q)
        views: dict[str, StudioView] = {}
        for c in self._conns:
            got = c.recv()
            if isinstance(got, Exception):
                raise got
            views.update(got)
        return {n: views[n] for n in self.rig.names}

    def close(self) -> None:
        """Stop the worker processes."""
        for c in self._conns:
            try:
                c.send(None)
            except (BrokenPipeError, OSError):
                pass
        for p in self._procs:
            p.join(timeout=10)
            if p.is_alive():
                p.kill()
        self._conns, self._procs = [], []

    def __enter__(self) -> ParallelStudio:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
