"""Camera rig description: N calibrated cameras and their poses in one world frame.

A rig file (``config/rigs/NAME.yaml``) is the one description every multi-view component reads:
the rig graph, the synchroniser, the synthetic studio, calibration (which writes it) and the
multi-view tracker. Seed 000 records with six synchronised cameras (sec. 4.1), seed 002 with
eight (sec. 3); the file carries, per camera, what ``sensor_msgs/CameraInfo`` carries
(resolution, pinhole, distortion) plus the camera's pose in the world frame.

File format (every length in metres, every angle in radians)::

    rig:
      name: studio6
      world_frame: world
      cameras:
        - name: cam0                       # namespace of its topics: cam0/color/image_raw
          frame_id: cam0_color_optical_frame
          width: 640                       # [px]
          height: 480                      # [px]
          fx: 520.0                        # [px]
          fy: 520.0
          cx: 319.5
          cy: 239.5
          distortion_model: plumb_bob      # k1, k2, t1, t2, k3 (OpenCV order)
          distortion: [0.0, 0.0, 0.0, 0.0, 0.0]
          position: [0.7, 0.0, 0.5]        # optical centre in the world [m]
          rotation: [1.9, 0.0, 1.2]        # rotation vector of R_world_camera [rad]
          reproj_px: 0.21                  # optional: RMS reprojection error of calibration

The optical frame follows REP 103's camera convention: z forward, x right, y down.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hand_capture.cameras.base import Intrinsics
from hand_capture.cameras.transforms import matrix_to_rotvec, rotvec_to_matrix
from hand_capture.config import load_yaml
from hand_capture.errors import ConfigError, InputError
from hand_capture.paths import config_dir, resolve_path

__all__ = ["Rig", "RigCamera", "distort", "list_rigs", "load_rig", "look_at", "rig_from_mapping",
           "rig_path", "ring_rig", "save_rig"]

_CAMERA_KEYS = ("name", "frame_id", "width", "height", "fx", "fy", "cx", "cy",
                "distortion_model", "distortion", "position", "rotation", "reproj_px")
_DISTORTION_SIZES = {"plumb_bob": 5, "rational_polynomial": 8}


@dataclass(frozen=True)
class RigCamera:
    """One camera of a rig.

    Attributes:
        name: the camera's namespace (``cam0`` -> ``cam0/color/image_raw``).
        intrinsics: resolution, pinhole [px], distortion, optical frame id.
        R_wc: (3, 3) rotation of the optical frame in the world (world <- camera).
        t_wc: (3,) optical centre in the world [m].
        reproj_px: RMS reprojection error of the calibration that wrote it [px], or None.
    """

    name: str
    intrinsics: Intrinsics
    R_wc: np.ndarray
    t_wc: np.ndarray
    reproj_px: float | None = None

    def __post_init__(self) -> None:
        R = np.asarray(self.R_wc, dtype=float)
        t = np.asarray(self.t_wc, dtype=float).reshape(-1)
        if R.shape != (3, 3) or not np.all(np.isfinite(R)):
            raise ConfigError(f"camera {self.name!r}: rotation must be a finite 3x3 matrix")
        if abs(np.linalg.det(R) - 1.0) > 1e-6 or not np.allclose(R.T @ R, np.eye(3), atol=1e-6):
            raise ConfigError(f"camera {self.name!r}: rotation is not a proper rotation")
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise ConfigError(f"camera {self.name!r}: position must be 3 finite numbers [m]")
        object.__setattr__(self, "R_wc", R)
        object.__setattr__(self, "t_wc", t)

    @property
    def T_wc(self) -> np.ndarray:
        """(4, 4) pose of the optical frame in the world (world <- camera)."""
        T = np.eye(4)
        T[:3, :3] = self.R_wc
        T[:3, 3] = self.t_wc
        return T

    @property
    def T_cw(self) -> np.ndarray:
        """(4, 4) world -> camera transform (the extrinsic matrix of OpenCV)."""
        T = np.eye(4)
        T[:3, :3] = self.R_wc.T
        T[:3, 3] = -self.R_wc.T @ self.t_wc
        return T

    def to_camera(self, points_w: np.ndarray) -> np.ndarray:
        """World points (N, 3) [m] in this camera's optical frame (N, 3) [m]."""
        p = _points(points_w)
        return (p - self.t_wc) @ self.R_wc

    def project(self, points_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) of world points (N, 3) through the pinhole and distortion model.

        Returns:
            (uv, in_front): pixel coordinates [px] and a (N,) mask of points with z > 0.
        """
        pc = self.to_camera(points_w)
        z = pc[:, 2]
        in_front = z > 1e-9
        x = pc[:, 0] / np.where(in_front, z, 1.0)
        y = pc[:, 1] / np.where(in_front, z, 1.0)
        xd, yd = distort(x, y, self.intrinsics.distortion)
        k = self.intrinsics
        return np.stack([k.fx * xd + k.cx, k.fy * yd + k.cy], axis=1), in_front

    def frustum_segments(self, depth_m: float = 0.15) -> np.ndarray:
        """(8, 2, 3) line segments [m, world] drawing the camera's viewing pyramid out to
        ``depth_m``: four edges from the optical centre and the image rectangle."""
        k = self.intrinsics
        corners_px = np.array([[0, 0], [k.width, 0], [k.width, k.height], [0, k.height]],
                              dtype=float) - 0.5
        rays = np.column_stack([(corners_px[:, 0] - k.cx) / k.fx,
                                (corners_px[:, 1] - k.cy) / k.fy, np.ones(4)])
        far = (rays * depth_m) @ self.R_wc.T + self.t_wc
        edges = [(self.t_wc, far[i]) for i in range(4)]
        edges += [(far[i], far[(i + 1) % 4]) for i in range(4)]
        return np.array(edges)

    def camera_info(self) -> dict[str, Any]:
        """The fields of ``sensor_msgs/CameraInfo`` (row-major k, r, p; d as a list)."""
        k = self.intrinsics
        return {
            "width": k.width, "height": k.height, "distortion_model": k.distortion_model,
            "d": list(k.distortion), "k": k.K.reshape(-1).tolist(),
            "r": np.eye(3).reshape(-1).tolist(), "p": k.P.reshape(-1).tolist(),
            "frame_id": k.frame_id,
        }

    def to_mapping(self) -> dict[str, Any]:
        """The camera's entry of a rig file."""
        k = self.intrinsics
        out: dict[str, Any] = {
            "name": self.name, "frame_id": k.frame_id, "width": k.width, "height": k.height,
            "fx": _num(k.fx), "fy": _num(k.fy), "cx": _num(k.cx), "cy": _num(k.cy),
            "distortion_model": k.distortion_model,
            "distortion": [_num(d, 8) for d in k.distortion],
            "position": [_num(v, 6) for v in self.t_wc],
            "rotation": [_num(v, 7) for v in matrix_to_rotvec(self.R_wc)],
        }
        if self.reproj_px is not None:
            out["reproj_px"] = _num(self.reproj_px, 4)
        return out


@dataclass(frozen=True)
class Rig:
    """N cameras posed in one world frame.

    Attributes:
        name: the rig's name (file stem by convention).
        cameras: the cameras, in the order of the file (their names are unique).
        world_frame: the frame id the camera poses are given in.
    """

    name: str
    cameras: tuple[RigCamera, ...]
    world_frame: str = "world"
    _index: dict[str, int] = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        cams = tuple(self.cameras)
        if not cams:
            raise ConfigError(f"rig {self.name!r}: no cameras")
        names = [c.name for c in cams]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ConfigError(f"rig {self.name!r}: camera names must be unique, repeated: {dup}")
        frames = [c.intrinsics.frame_id for c in cams]
        dup = sorted({f for f in frames if frames.count(f) > 1})
        if dup:
            raise ConfigError(f"rig {self.name!r}: frame ids must be unique, repeated: {dup}")
        object.__setattr__(self, "cameras", cams)
        self._index.update({n: i for i, n in enumerate(names)})

    @property
    def names(self) -> tuple[str, ...]:
        """Camera names in file order."""
        return tuple(c.name for c in self.cameras)

    def __len__(self) -> int:
        return len(self.cameras)

    def camera(self, name: str) -> RigCamera:
        """The camera called ``name``.

        Raises:
            ConfigError: naming the rig's cameras when there is no such camera.
        """
        try:
            return self.cameras[self._index[name]]
        except KeyError:
            raise ConfigError(
                f"rig {self.name!r} has no camera {name!r}; cameras: {list(self.names)}"
            ) from None

    def transformed(self, T_new_old: np.ndarray) -> Rig:
        """The same rig with every camera pose expressed in another world frame.

        Args:
            T_new_old: (4, 4) pose of the current world frame in the new one.
        """
        T = np.asarray(T_new_old, dtype=float)
        cams = tuple(RigCamera(c.name, c.intrinsics, T[:3, :3] @ c.R_wc,
                               T[:3, :3] @ c.t_wc + T[:3, 3], c.reproj_px)
                     for c in self.cameras)
        return Rig(self.name, cams, self.world_frame)

    def to_mapping(self) -> dict[str, Any]:
        """The content of a rig file."""
        return {"rig": {"name": self.name, "world_frame": self.world_frame,
                        "cameras": [c.to_mapping() for c in self.cameras]}}


def distort(x: np.ndarray, y: np.ndarray, coeffs: Sequence[float]) -> tuple[np.ndarray,
                                                                              np.ndarray]:
    """OpenCV's radial-tangential model applied to normalised coordinates.

    Args:
        x, y: undistorted normalised image coordinates (x/z, y/z), any equal shapes.
        coeffs: (k1, k2, p1, p2, k3[, k4, k5, k6]) as in ``sensor_msgs/CameraInfo.d``.
    """
    c = list(coeffs) + [0.0] * (8 - len(coeffs))
    k1, k2, p1, p2, k3, k4, k5, k6 = c[:8]
    r2 = x * x + y * y
    radial = (1 + k1 * r2 + k2 * r2**2 + k3 * r2**3) / (1 + k4 * r2 + k5 * r2**2 + k6 * r2**3)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return xd, yd


def look_at(position: Sequence[float], target: Sequence[float],
            up: Sequence[float] = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Rotation R_world_camera of an optical frame at ``position`` looking at ``target``.

    The optical z axis points at the target, x to the right and y down in the image, so that
    the world's ``up`` appears upward.

    Raises:
        InputError: when position and target coincide or the view is parallel to ``up``.
    """
    p, t, u = (np.asarray(v, dtype=float).reshape(3) for v in (position, target, up))
    z = t - p
    if np.linalg.norm(z) < 1e-9:
        raise InputError("look_at: position and target coincide")
    z /= np.linalg.norm(z)
    x = np.cross(z, u)
    if np.linalg.norm(x) < 1e-9:
        raise InputError("look_at: viewing direction is parallel to 'up'")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


def ring_rig(name: str, n: int, *, radius_m: float = 0.75, height_m: float = 0.55,
             target: Sequence[float] = (0.0, 0.0, 0.08), width: int = 640, height: int = 480,
             hfov_deg: float = 60.0,
             distortion: Sequence[float] = (0.0, 0.0, 0.0, 0.0, 0.0)) -> Rig:
    """``n`` identical cameras on a circle around a table, all looking at ``target``.

    The world is z up with the table top at z = 0 (seed 000's studio: cameras around the
    performer's workspace, sec. 4.1). Camera i sits at angle 2 pi i / n, alternately 10 cm
    higher and lower than ``height_m`` so that the views are not all coplanar.
    """
    cams = []
    for i in range(n):
        a = 2.0 * math.pi * i / n
        pos = np.array([radius_m * math.cos(a), radius_m * math.sin(a),
                        height_m + (0.1 if i % 2 else -0.1)])
        intr = Intrinsics.from_fov(width, height, hfov_deg, distortion=tuple(distortion),
                                   frame_id=f"cam{i}_color_optical_frame")
        cams.append(RigCamera(f"cam{i}", intr, look_at(pos, target), pos))
    return Rig(name, tuple(cams))


def rig_from_mapping(data: Mapping[str, Any], *, source: str = "rig") -> Rig:
    """Build a :class:`Rig` from the content of a rig file.

    Raises:
        ConfigError: naming the camera and the field that is missing or invalid.
    """
    if not isinstance(data, Mapping) or not isinstance(data.get("rig"), Mapping):
        raise ConfigError(f"{source}: expected a top-level 'rig:' mapping")
    r = data["rig"]
    unknown = sorted(set(r) - {"name", "world_frame", "cameras"})
    if unknown:
        raise ConfigError(f"{source}: unknown rig key(s) {unknown}; valid keys: "
                          "['name', 'world_frame', 'cameras']")
    cams = r.get("cameras")
    if not isinstance(cams, list) or not cams:
        raise ConfigError(f"{source}: 'rig.cameras' must be a non-empty list")
    name = str(r.get("name") or Path(source).stem)
    return Rig(name, tuple(_camera_from_mapping(c, i, source) for i, c in enumerate(cams)),
               str(r.get("world_frame", "world")))


def _camera_from_mapping(c: Any, i: int, source: str) -> RigCamera:
    label = f"{source}: camera {i}"
    if not isinstance(c, Mapping):
        raise ConfigError(f"{label}: expected a mapping")
    if "name" in c:
        label = f"{source}: camera {c['name']!r}"
    unknown = sorted(set(c) - set(_CAMERA_KEYS))
    if unknown:
        raise ConfigError(f"{label}: unknown field(s) {unknown}; valid: {list(_CAMERA_KEYS)}")
    for key in ("name", "width", "height", "fx", "fy", "cx", "cy", "position", "rotation"):
        if key not in c:
            raise ConfigError(f"{label}: missing field '{key}'")
    name = str(c["name"])
    model = str(c.get("distortion_model", "plumb_bob"))
    if model not in _DISTORTION_SIZES:
        raise ConfigError(f"{label}: distortion_model {model!r} is not one of "
                          f"{sorted(_DISTORTION_SIZES)}")
    dist = c.get("distortion", [0.0] * _DISTORTION_SIZES[model])
    if not isinstance(dist, list) or len(dist) != _DISTORTION_SIZES[model]:
        raise ConfigError(f"{label}: 'distortion' must list {_DISTORTION_SIZES[model]} "
                          f"coefficients for {model}")
    for key in ("width", "height"):
        if not isinstance(c[key], int) or isinstance(c[key], bool) or c[key] <= 0:
            raise ConfigError(f"{label}: '{key}' must be a positive integer [px], "
                              f"got {c[key]!r}")
    vals = {}
    for key in ("fx", "fy", "cx", "cy"):
        vals[key] = _finite(c[key], f"{label}: '{key}'")
    pos = _vector(c["position"], f"{label}: 'position'")
    rot = _vector(c["rotation"], f"{label}: 'rotation'")
    dist_f = tuple(_finite(d, f"{label}: 'distortion'") for d in dist)
    reproj = c.get("reproj_px")
    try:
        intr = Intrinsics(c["width"], c["height"], vals["fx"], vals["fy"], vals["cx"],
                          vals["cy"], model, dist_f,
                          str(c.get("frame_id", f"{name}_color_optical_frame")))
        return RigCamera(name, intr, rotvec_to_matrix(rot), pos,
                         None if reproj is None else _finite(reproj, f"{label}: 'reproj_px'"))
    except ConfigError as e:
        raise ConfigError(f"{label}: {e}") from e


def load_rig(path_or_name: str | Path) -> Rig:
    """Load a rig from a file path or from a name under ``config/rigs/``.

    Raises:
        ConfigError: the file is missing (the message lists the shipped rigs) or invalid.
    """
    p = rig_path(path_or_name)
    return rig_from_mapping(load_yaml(p) or {}, source=str(p))


def rig_path(path_or_name: str | Path) -> Path:
    """The file of a rig given as a path or as a name of ``config/rigs/NAME.yaml``."""
    s = str(path_or_name)
    if s.endswith((".yaml", ".yml")) or "/" in s:
        p = resolve_path(s)
        if not p.is_file():
            raise ConfigError(f"rig file not found: {p}")
        return p
    p = config_dir() / "rigs" / f"{s}.yaml"
    if not p.is_file():
        raise ConfigError(f"no rig named {s!r}; shipped rigs: {list_rigs()}")
    return p


def list_rigs() -> list[str]:
    """Names of the rigs shipped in ``config/rigs/``."""
    return sorted(p.stem for p in (config_dir() / "rigs").glob("*.yaml"))


def save_rig(rig: Rig, path: str | Path, header: Iterable[str] = ()) -> Path:
    """Write a rig file (readable by :func:`load_rig`), with optional comment lines on top."""
    import yaml

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    text = yaml.safe_dump(rig.to_mapping(), sort_keys=False, default_flow_style=None,
                          width=99)
    lines = [f"# {h}" for h in header]
    p.write_text("\n".join(lines + [text]) if lines else text)
    return p


def _points(points: np.ndarray) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"points must have shape (N, 3), got {p.shape}")
    return p


def _finite(v: Any, label: str) -> float:
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise ConfigError(f"{label} must be a number, got {v!r}") from None
    if not math.isfinite(f):
        raise ConfigError(f"{label} must be finite, got {v!r}")
    return f


def _vector(v: Any, label: str) -> np.ndarray:
    if not isinstance(v, (list, tuple)) or len(v) != 3:
        raise ConfigError(f"{label} must list 3 numbers, got {v!r}")
    return np.array([_finite(x, label) for x in v])


def _num(v: float, digits: int = 4) -> float:
    return round(float(v), digits)
