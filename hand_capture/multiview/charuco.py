"""ChArUco calibration boards: the board's geometry, detection, and rendering into a camera.

A ChArUco board is a chessboard whose white squares hold ArUco markers: the markers identify
each chessboard corner, so a partly visible or partly occluded board still gives corners with
known board coordinates, and the chessboard corners are refined to sub-pixel accuracy. It is
the calibration target of the multi-view rig (OpenCV's aruco module from opencv-contrib).

:func:`render_board_view` draws the board as a given camera (with its distortion) sees it at a
given pose; the synthetic studio and the calibration tests use it, so calibration is checked
against a rig whose poses are known exactly.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

from hand_capture.cameras.base import Intrinsics
from hand_capture.config import param, validate
from hand_capture.errors import ConfigError, InputError
from hand_capture.multiview.rig import Rig, RigCamera

__all__ = ["BoardSpec", "Detection", "boards_seen_by", "detect_board", "parse_board",
           "render_board_view", "sample_board_poses"]

_DICTIONARIES = ("DICT_4X4_50", "DICT_4X4_100", "DICT_5X5_100", "DICT_5X5_250",
                 "DICT_6X6_250", "DICT_APRILTAG_36h11")


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board (the printed target).

    The board frame has its origin at the outer corner of the first square, x along the
    columns, y along the rows, z out of the printed side's back (OpenCV's convention: the
    camera looking at the printed side sees z pointing away from it).
    """

    squares_x: int = param(7, "chessboard squares along x", lo=3, hi=40)
    squares_y: int = param(5, "chessboard squares along y", lo=3, hi=40)
    square_m: float = param(0.05, "side of a chessboard square [m]", lo=1e-3, hi=1.0)
    marker_m: float = param(0.036, "side of an ArUco marker [m]", lo=1e-3, hi=1.0)
    dictionary: str = param("DICT_4X4_50", "ArUco dictionary", choices=_DICTIONARIES)

    def __post_init__(self) -> None:
        validate(self)
        if self.marker_m >= self.square_m:
            raise ConfigError(f"BoardSpec: marker_m ({self.marker_m}) must be smaller than "
                              f"square_m ({self.square_m})")

    @cached_property
    def board(self) -> object:
        """The OpenCV board object (``cv2.aruco.CharucoBoard``)."""
        import cv2

        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_m,
                                      self.marker_m, d)

    @property
    def size_m(self) -> tuple[float, float]:
        """Printed size (width along x, height along y) [m]."""
        return self.squares_x * self.square_m, self.squares_y * self.square_m

    @cached_property
    def corners(self) -> np.ndarray:
        """(K, 3) inner chessboard corners in the board frame [m], indexed by corner id."""
        return np.asarray(self.board.getChessboardCorners(), dtype=float).reshape(-1, 3)

    @lru_cache(maxsize=4)  # noqa: B019 - specs are few, small and immutable
    def image(self, px_per_square: int = 120) -> np.ndarray:
        """The printable board as a grey image (uint8), ``px_per_square`` per square side."""
        w, h = self.squares_x * px_per_square, self.squares_y * px_per_square
        return self.board.generateImage((w, h), marginSize=0, borderBits=1)


def parse_board(text: str) -> BoardSpec:
    """A board from ``"SXxSY:SQUARE_M:MARKER_M[:DICTIONARY]"``, e.g. ``"7x5:0.05:0.036"``.

    Raises:
        ConfigError: the text does not have that form (the message shows it).
    """
    parts = text.split(":")
    try:
        sx, sy = (int(v) for v in parts[0].lower().split("x"))
        kw = {"squares_x": sx, "squares_y": sy, "square_m": float(parts[1]),
              "marker_m": float(parts[2])}
        if len(parts) > 4:
            raise ValueError
    except (ValueError, IndexError):
        raise ConfigError(f"board {text!r}: expected SQUARESxSQUARES:SQUARE_M:MARKER_M"
                          f"[:DICTIONARY], e.g. 7x5:0.05:0.036:DICT_4X4_50") from None
    if len(parts) == 4:
        kw["dictionary"] = parts[3]
    return BoardSpec(**kw)


@dataclass(frozen=True)
class Detection:
    """The board's corners found in one image.

    Attributes:
        ids: (M,) corner ids (rows of :attr:`BoardSpec.corners`).
        pixels: (M, 2) sub-pixel corner positions [px].
    """

    ids: np.ndarray
    pixels: np.ndarray

    def __len__(self) -> int:
        return len(self.ids)


def detect_board(spec: BoardSpec, image: np.ndarray) -> Detection:
    """Find the ChArUco corners of ``spec`` in a grey or colour image.

    Returns:
        The detection; empty (``len == 0``) when the board is not seen.
    """
    import cv2

    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    if img.ndim != 2 or img.dtype != np.uint8:
        raise InputError(f"detect_board: expected a uint8 grey or RGB image, got "
                         f"{img.dtype} {img.shape}")
    corners, ids, _, _ = cv2.aruco.CharucoDetector(spec.board).detectBoard(img)
    if ids is None or corners is None or len(ids) == 0:
        return Detection(np.zeros(0, dtype=int), np.zeros((0, 2)))
    return Detection(np.asarray(ids, dtype=int).reshape(-1),
                     np.asarray(corners, dtype=float).reshape(-1, 2))


def render_board_view(spec: BoardSpec, camera: RigCamera, T_world_board: np.ndarray, *,
                      background: np.ndarray | None = None, supersample: int = 2,
                      px_per_square: int = 120) -> np.ndarray:
    """Grey image (H, W) uint8 of the board at ``T_world_board`` seen by ``camera``.

    Every output pixel is traced back through the camera's distortion and pinhole onto the
    board plane (exact perspective, not an affine approximation), rendered at ``supersample``
    times the resolution and averaged down, so corner positions are not biased by aliasing.
    Only the printed side is drawn; a board seen from behind is not.

    Args:
        T_world_board: (4, 4) pose of the board frame in the world.
        background: (H, W) uint8 image behind the board; mid grey when None.
    """
    import cv2

    k = camera.intrinsics
    s = int(supersample)
    T_cb = camera.T_cw @ np.asarray(T_world_board, dtype=float)
    R, t = T_cb[:3, :3], T_cb[:3, 3]
    if float(R[:, 2] @ t) <= 0.0:  # the camera is behind the board (it sees the back)
        return _background(background, k.height, k.width)
    rays = _pixel_rays(k, s)  # (H s * W s, 3), cached per camera
    # Ray-plane intersection with the board plane z_b = 0: n . (lambda r - t) = 0.
    n = R[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (n @ t) / (rays @ n)
    hit = (rays * lam[:, None] - t) @ R  # board coordinates [m]
    scale = px_per_square / spec.square_m
    shape = (k.height * s, k.width * s)
    map_x = (hit[:, 0] * scale - 0.5).astype(np.float32).reshape(shape)
    map_y = (hit[:, 1] * scale - 0.5).astype(np.float32).reshape(shape)
    map_x[~np.isfinite(map_x) | (lam <= 0).reshape(shape)] = -1e6
    # Board and coverage in one remap; generateImage's row 0 is the board's y = 0.
    img = spec.image(px_per_square)
    src = np.dstack([img, np.full(img.shape, 255, np.uint8)])
    warped = cv2.remap(src, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                       borderValue=(0, 0, 0, 0)).astype(np.float32)
    bg = _background(background, k.height, k.width)
    bg = cv2.resize(bg, (k.width * s, k.height * s), interpolation=cv2.INTER_NEAREST)
    a = warped[..., 1] / 255.0
    out = a * warped[..., 0] + (1.0 - a) * bg.astype(np.float32)
    return cv2.resize(out, (k.width, k.height), interpolation=cv2.INTER_AREA).round().clip(
        0, 255).astype(np.uint8)


@lru_cache(maxsize=32)
def _pixel_rays(k: Intrinsics, s: int) -> np.ndarray:
    """Undistorted rays (x/z, y/z, 1) through every pixel centre at ``s`` x supersampling."""
    import cv2

    us = (np.arange(k.width * s) + 0.5) / s - 0.5
    vs = (np.arange(k.height * s) + 0.5) / s - 0.5
    uu, vv = np.meshgrid(us, vs)
    pts = np.stack([uu.ravel(), vv.ravel()], axis=1).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-10)
    und = cv2.undistortPoints(pts, k.K, np.asarray(k.distortion), None, None, None, crit)
    rays = np.concatenate([und.reshape(-1, 2), np.ones((und.shape[0], 1))], axis=1)
    rays.flags.writeable = False
    return rays


def sample_board_poses(spec: BoardSpec, rig: Rig, n: int, *, seed: int = 0,
                       min_cameras: int = 2, max_tilt_deg: float = 40.0,
                       centre: Sequence[float] = (0.0, 0.0, 0.0),
                       spread_m: float = 0.3) -> list[np.ndarray]:
    """``n`` board poses (4, 4) in the rig's world, each facing at least ``min_cameras``.

    The first lies face up, flat on the table at ``centre`` (the reference view of
    calibration); the others are lifted up to 0.25 m, shifted up to ``spread_m`` and tilted up
    to ``max_tilt_deg`` about a random horizontal axis, as a person waves a board through the
    workspace.
    """
    from hand_capture.cameras.transforms import rotvec_to_matrix

    rng = np.random.default_rng(seed)
    w, h = spec.size_m
    flip = np.diag([1.0, -1.0, -1.0])  # board z into the table: printed side up
    c0 = np.asarray(centre, dtype=float)
    out: list[np.ndarray] = []
    tries = 0
    while len(out) < n:
        tries += 1
        if tries > 100 * n:
            raise InputError(f"sample_board_poses: found only {len(out)} of {n} poses seen "
                             f"by {min_cameras} cameras")
        if not out:
            R, p = flip, c0
        else:
            axis = rng.normal(size=3)
            axis[2] = 0.0
            axis /= np.linalg.norm(axis)
            tilt = np.radians(rng.uniform(0.0, max_tilt_deg))
            spin = rotvec_to_matrix(np.array([0.0, 0.0, rng.uniform(-np.pi, np.pi)]))
            R = rotvec_to_matrix(axis * tilt) @ spin @ flip
            p = c0 + np.array([*rng.uniform(-spread_m, spread_m, 2), rng.uniform(0.0, 0.3)])
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = p - R @ np.array([w / 2, h / 2, 0.0])  # centre the board on p
        if len(boards_seen_by(spec, rig, T)) >= min_cameras:
            out.append(T)
    return out


def boards_seen_by(spec: BoardSpec, rig: Rig, T_world_board: np.ndarray,
                   min_cos: float = 0.5, min_fraction: float = 0.5) -> list[str]:
    """Cameras that see the printed side at a usable angle (viewing direction within
    acos(``min_cos``) of the board's normal), with at least ``min_fraction`` of its corners
    inside the image."""
    pts = spec.corners @ T_world_board[:3, :3].T + T_world_board[:3, 3]
    n = T_world_board[:3, 2]
    seen = []
    for cam in rig.cameras:
        view = cam.t_wc - pts.mean(axis=0)
        if -(n @ view) / np.linalg.norm(view) < min_cos:  # printed side faces -z
            continue
        uv, front = cam.project(pts)
        k = cam.intrinsics
        inside = front & (uv[:, 0] > 5) & (uv[:, 0] < k.width - 6) & (uv[:, 1] > 5) & (
            uv[:, 1] < k.height - 6)
        if inside.mean() >= min_fraction:
            seen.append(cam.name)
    return seen


def _background(background: np.ndarray | None, h: int, w: int) -> np.ndarray:
    if background is None:
        return np.full((h, w), 128, np.uint8)
    bg = np.asarray(background)
    if bg.shape != (h, w) or bg.dtype != np.uint8:
        raise InputError(f"background must be uint8 of shape ({h}, {w}), got "
                         f"{bg.dtype} {bg.shape}")
    return bg
