"""Rig calibration from ChArUco views: every camera's intrinsics and all camera poses.

Input: ``V`` board placements ("views"), each imaged by every camera at the same instant (a
synchronised group). Steps:

1. **Corners** of the board in every image (:func:`~hand_capture.multiview.charuco.detect_board`).
2. **Intrinsics** per camera with OpenCV's ``calibrateCamera`` over the views it saw.
3. **Pairwise initialisation**: the board's pose in each camera by PnP; starting from the
   world frame (the board at the reference view), camera and board poses are chained across
   shared views (camera c at T_wb(v) T_cb(c, v)^-1, board v at T_wc(c) T_cb(c, v)), breadth
   first, each link taken from the observation with the most corners.
4. **Joint refinement** of all camera poses, all board poses and every camera's intrinsics
   by non-linear least squares over every corner of every observation (a bundle adjustment
   with the board as the known structure), with a sparse Jacobian.

The world frame is the board at the reference view (view 0 by default), turned half a turn
about its x axis (:data:`WORLD_FROM_BOARD`): lay the board face up on the table for that view
and the world is z up (REP 103) with the origin at the board's first corner. (OpenCV's board
frame has z pointing away from the printed side, i.e. into the table.)
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from hand_capture.cameras.base import Intrinsics
from hand_capture.cameras.transforms import matrix_to_rotvec, rotvec_to_matrix
from hand_capture.errors import HandSuiteError, InputError
from hand_capture.multiview.charuco import BoardSpec, Detection, detect_board
from hand_capture.multiview.rig import Rig, RigCamera

__all__ = ["WORLD_FROM_BOARD", "CalibrationError", "CalibrationResult",
           "calibrate_from_detections", "calibrate_rig", "compare_rigs"]

#: fewest corners for a usable observation (PnP on a plane needs 4; more for robustness)
MIN_CORNERS = 6
#: fewest views in which a camera must see the board to fit its intrinsics
MIN_VIEWS = 4
#: pose of the reference view's board frame in the calibrated world (z up for a board lying
#: face up)
WORLD_FROM_BOARD = np.diag([1.0, -1.0, -1.0, 1.0])


class CalibrationError(HandSuiteError):
    """Calibration cannot proceed; the message names the camera and what is missing."""


@dataclass
class CalibrationResult:
    """A calibrated rig and how well it fits.

    Attributes:
        rig: the calibrated cameras (world = board frame at the reference view).
        reproj_px: camera -> RMS reprojection error after joint refinement [px].
        observations: camera -> number of views in which it saw the board.
        board_poses: view index -> (4, 4) board pose in the world, for the views used.
        iterations: function evaluations of the joint refinement.
    """

    rig: Rig
    reproj_px: dict[str, float]
    observations: dict[str, int]
    board_poses: dict[int, np.ndarray] = field(default_factory=dict)
    iterations: int = 0


def calibrate_rig(
    images: Mapping[str, Sequence[np.ndarray | None]],
    spec: BoardSpec,
    *,
    name: str = "rig",
    reference_view: int = 0,
    frame_ids: Mapping[str, str] | None = None,
    fix_intrinsics: Mapping[str, Intrinsics] | None = None,
) -> CalibrationResult:
    """Calibrate a rig from synchronised images of a ChArUco board.

    Args:
        images: camera name -> its images, index v = view v (the same instant for every
            camera); None where a camera has no image for a view.
        spec: the board.
        name: the rig's name.
        reference_view: the view whose board frame becomes the world frame.
        frame_ids: optical frame id per camera (default ``NAME_color_optical_frame``).
        fix_intrinsics: cameras whose intrinsics are known and kept (e.g. factory values).

    Raises:
        CalibrationError: no board found in a camera, too few views, a camera that never
            shares a view with the others, or a reference view no camera saw.
    """
    if not images:
        raise CalibrationError("no cameras given")
    n_views = {len(v) for v in images.values()}
    if len(n_views) != 1:
        raise InputError(f"every camera needs one entry per view; got "
                         f"{ {c: len(v) for c, v in images.items()} }")
    V = n_views.pop()
    dets: dict[str, dict[int, Detection]] = {}
    sizes: dict[str, tuple[int, int]] = {}
    for cam, imgs in images.items():
        dets[cam] = {}
        for v, img in enumerate(imgs):
            if img is None:
                continue
            sizes.setdefault(cam, (img.shape[1], img.shape[0]))
            d = detect_board(spec, img)
            if len(d) >= MIN_CORNERS:
                dets[cam][v] = d
    return calibrate_from_detections(dets, sizes, spec, V, name=name,
                                     reference_view=reference_view, frame_ids=frame_ids,
                                     fix_intrinsics=fix_intrinsics)


def calibrate_from_detections(
    dets: Mapping[str, Mapping[int, Detection]],
    sizes: Mapping[str, tuple[int, int]],
    spec: BoardSpec,
    n_views: int,
    *,
    name: str = "rig",
    reference_view: int = 0,
    frame_ids: Mapping[str, str] | None = None,
    fix_intrinsics: Mapping[str, Intrinsics] | None = None,
) -> CalibrationResult:
    """:func:`calibrate_rig` from corners already detected (camera -> view -> detection).

    Args:
        sizes: camera -> image (width, height) [px].
        n_views: number of views (board placements).
    """
    fixed = dict(fix_intrinsics or {})
    cams = list(dets)
    for c in cams:
        if not dets[c]:
            raise CalibrationError(f"camera {c!r}: the board was not found in any of its "
                                   f"{n_views} images")
        if c not in fixed and len(dets[c]) < MIN_VIEWS:
            raise CalibrationError(f"camera {c!r}: the board was found in {len(dets[c])} "
                                   f"views; at least {MIN_VIEWS} are needed for intrinsics")
    intr = {c: fixed.get(c) or _intrinsics(c, dets[c], sizes[c], spec) for c in cams}
    T_cb = {(c, v): _pnp(spec, d, intr[c]) for c in cams for v, d in dets[c].items()}
    T_wc, T_wb = _chain(cams, dets, T_cb, reference_view, n_views)
    cams_x, views_x, intr_x, n_eval = _refine(cams, dets, spec, intr, T_wc, T_wb,
                                              reference_view, fixed)
    ids = dict(frame_ids or {})
    rig_cams = []
    reproj = {}
    for c in cams:
        k = intr_x[c]
        k = Intrinsics(k.width, k.height, k.fx, k.fy, k.cx, k.cy, k.distortion_model,
                       k.distortion, ids.get(c, f"{c}_color_optical_frame"))
        err = _rms(c, dets[c], spec, k, cams_x[c], views_x)
        reproj[c] = err
        rig_cams.append(RigCamera(c, k, cams_x[c][:3, :3], cams_x[c][:3, 3], err))
    return CalibrationResult(Rig(name, tuple(rig_cams)), reproj,
                             {c: len(dets[c]) for c in cams}, views_x, n_eval)


def compare_rigs(estimate: Rig, truth: Rig) -> dict[str, tuple[float, float]]:
    """Per camera: (position error [mm], rotation error [deg]) of ``estimate`` vs ``truth``.

    Both rigs must be given in the same world frame.
    """
    out = {}
    for c in estimate.cameras:
        t = truth.camera(c.name)
        dR = c.R_wc.T @ t.R_wc
        ang = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(dR) - 1.0) / 2.0))))
        out[c.name] = (1000.0 * float(np.linalg.norm(c.t_wc - t.t_wc)), ang)
    return out


# -- steps ---------------------------------------------------------------------------------

def _intrinsics(cam: str, dets: Mapping[int, Detection], size: tuple[int, int],
                spec: BoardSpec) -> Intrinsics:
    """Step 2: OpenCV calibrateCamera over the views of one camera (k1, k2, p1, p2; k3 = 0)."""
    import cv2

    obj = [spec.corners[d.ids].astype(np.float32) for d in dets.values()]
    img = [d.pixels.astype(np.float32) for d in dets.values()]
    w, h = size
    f0 = 0.9 * max(w, h)
    K0 = np.array([[f0, 0, (w - 1) / 2], [0, f0, (h - 1) / 2], [0, 0, 1]])
    try:
        rms, K, D, _, _ = cv2.calibrateCamera(
            obj, img, (w, h), K0, np.zeros(5),
            flags=cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3)
    except cv2.error as e:
        raise CalibrationError(f"camera {cam!r}: intrinsic calibration failed: {e}") from e
    if not math.isfinite(rms):
        raise CalibrationError(f"camera {cam!r}: intrinsic calibration did not converge")
    D = np.asarray(D, dtype=float).reshape(-1)[:5]
    return Intrinsics(w, h, K[0, 0], K[1, 1], K[0, 2], K[1, 2], "plumb_bob", tuple(D))


def _pnp(spec: BoardSpec, det: Detection, k: Intrinsics) -> np.ndarray:
    """Board pose in the camera (4, 4) from one detection (iterative PnP)."""
    import cv2

    ok, rvec, tvec = cv2.solvePnP(spec.corners[det.ids], det.pixels, k.K,
                                  np.asarray(k.distortion), flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise CalibrationError("PnP failed on a board observation")
    return _T(rotvec_to_matrix(rvec.reshape(3)), tvec.reshape(3))


def _chain(cams: list[str], dets: Mapping[str, Mapping[int, Detection]],
           T_cb: Mapping[tuple[str, int], np.ndarray], ref: int,
           n_views: int) -> tuple[dict[str, np.ndarray], dict[int, np.ndarray]]:
    """Step 3: breadth-first initial poses over the camera-view graph."""
    if not 0 <= ref < n_views or not any(ref in dets[c] for c in cams):
        raise CalibrationError(f"the reference view {ref} (the world frame) was seen by no "
                               f"camera; choose a view in which the board is seen")
    T_wb: dict[int, np.ndarray] = {ref: WORLD_FROM_BOARD.copy()}
    T_wc: dict[str, np.ndarray] = {}
    changed = True
    while changed:
        changed = False
        for c in cams:
            if c in T_wc:
                continue
            known = [v for v in dets[c] if v in T_wb]
            if known:
                v = max(known, key=lambda v: len(dets[c][v]))
                T_wc[c] = T_wb[v] @ np.linalg.inv(T_cb[(c, v)])
                changed = True
        for c in list(T_wc):
            for v in dets[c]:
                if v not in T_wb:
                    T_wb[v] = T_wc[c] @ T_cb[(c, v)]
                    changed = True
    lost = [c for c in cams if c not in T_wc]
    if lost:
        raise CalibrationError(f"camera(s) {lost} never share a board view with the "
                               f"cameras linked to the reference view; add views that they "
                               f"see together with another camera")
    return T_wc, T_wb


def _refine(cams: list[str], dets: Mapping[str, Mapping[int, Detection]], spec: BoardSpec,
            intr: Mapping[str, Intrinsics], T_wc: Mapping[str, np.ndarray],
            T_wb: Mapping[int, np.ndarray], ref: int, fixed: Mapping[str, Intrinsics],
            _probe: dict | None = None
            ) -> tuple[dict[str, np.ndarray], dict[int, np.ndarray], dict[str, Intrinsics], int]:
    """Step 4: joint least squares over all poses and intrinsics (Levenberg-Marquardt).

    Unknowns: per camera the world -> camera extrinsic, per board view (but the reference)
    its world pose, per camera not in ``fixed`` its (fx, fy, cx, cy, k1, k2, p1, p2) (k3 stays
    0: a wide lens is not this module's job). Residuals: pixel differences of every detected
    corner. Rotations are updated multiplicatively, R <- R(delta) R, so the rotation vectors
    stay near zero, away from the singularity of Rodrigues' parameters at pi. OpenCV's
    ``projectPoints`` gives the derivatives with respect to the extrinsic and the intrinsics;
    the chain through the board pose uses ``d uv / d X_world = (d uv / d t) R_cw`` and
    Rodrigues' derivative. The normal equations are sparse (cameras x views blocks).

    Returns:
        (camera poses T_wc, board poses T_wb, intrinsics, residual evaluations).
    """
    import cv2
    from scipy.sparse import csr_matrix, diags
    from scipy.sparse.linalg import spsolve

    views = sorted(v for v in T_wb if v != ref)
    free_k = [c for c in cams if c not in fixed]
    ci = {c: i for i, c in enumerate(cams)}
    vi = {v: i for i, v in enumerate(views)}
    nk = 8
    o_view = 6 * len(cams)
    o_k = o_view + 6 * len(views)
    ki = {c: o_k + nk * i for i, c in enumerate(free_k)}
    n_x = o_k + nk * len(free_k)
    obs = [(c, v, d) for c in cams for v, d in dets[c].items() if v in T_wb]
    n_res = 2 * sum(len(d) for _, _, d in obs)

    # The state around which the increments x are taken.
    cam_R = {c: np.linalg.inv(T_wc[c])[:3, :3] for c in cams}  # R_cw
    cam_t = {c: np.linalg.inv(T_wc[c])[:3, 3] for c in cams}
    view_R = {v: T_wb[v][:3, :3] for v in views}
    view_t = {v: T_wb[v][:3, 3] for v in views}
    k_vec = {c: np.array([intr[c].fx, intr[c].fy, intr[c].cx, intr[c].cy,
                          *intr[c].distortion[:4]]) for c in free_k}

    def camera_model(x: np.ndarray, c: str) -> tuple[np.ndarray, np.ndarray]:
        if c in ki:
            p = k_vec[c] + x[ki[c]: ki[c] + nk]
            return np.array([[p[0], 0, p[2]], [0, p[1], p[3]], [0, 0, 1]]), \
                np.array([*p[4:8], 0.0])
        k = fixed[c]
        return k.K, np.asarray(k.distortion, dtype=float)

    def evaluate(x: np.ndarray, want_jac: bool) -> np.ndarray | csr_matrix:
        """Residuals (and the Jacobian) at the state moved by the increments x."""
        res = np.empty(n_res)
        rows, cols, vals = [], [], []
        r0 = 0
        for c, v, d in obs:
            n = len(d)
            X = spec.corners[d.ids]
            if v == ref:
                Xw, dRb = X @ WORLD_FROM_BOARD[:3, :3].T + WORLD_FROM_BOARD[:3, 3], None
            else:
                o = o_view + 6 * vi[v]
                X = X @ view_R[v].T  # pre-rotated: R_wb = R(delta) R_wb0
                Rd, dRb = cv2.Rodrigues(x[o: o + 3])  # dRb: (3, 9) d vec(R) / d delta
                Xw = X @ Rd.T + view_t[v] + x[o + 3: o + 6]
            o = 6 * ci[c]
            Xc = Xw @ cam_R[c].T  # R_cw = R(delta) R_cw0: pre-rotate the world points
            K, D = camera_model(x, c)
            uv, J = cv2.projectPoints(Xc, x[o: o + 3], cam_t[c] + x[o + 3: o + 6], K, D)
            res[r0: r0 + 2 * n] = (uv.reshape(-1, 2) - d.pixels).ravel()
            if want_jac:
                rr = np.arange(r0, r0 + 2 * n)
                blocks = [(o, J[:, 0:6])]
                if c in ki:
                    blocks.append((ki[c], J[:, 6:14]))
                if dRb is not None:
                    R_full = cv2.Rodrigues(x[o: o + 3])[0] @ cam_R[c]
                    dXw = (J[:, 3:6] @ R_full).reshape(n, 2, 3)  # d uv / d X_world
                    dXw_dr = np.einsum("kij,nj->nik", dRb.reshape(3, 3, 3), X)  # (n, 3, 3)
                    j_rot = np.einsum("nai,nik->nak", dXw, dXw_dr).reshape(2 * n, 3)
                    blocks.append((o_view + 6 * vi[v],
                                   np.hstack([j_rot, dXw.reshape(2 * n, 3)])))
                for col0, blk in blocks:
                    rows.append(np.repeat(rr, blk.shape[1]))
                    cols.append(np.tile(np.arange(col0, col0 + blk.shape[1]), 2 * n))
                    vals.append(blk.ravel())
            r0 += 2 * n
        if not want_jac:
            return res
        return csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(n_res, n_x))

    def fold(x: np.ndarray) -> None:
        """Move the state by the increments x (rotations multiplicatively)."""
        for c, i in ci.items():
            cam_R[c] = cv2.Rodrigues(x[6 * i: 6 * i + 3])[0] @ cam_R[c]
            cam_t[c] = cam_t[c] + x[6 * i + 3: 6 * i + 6]
        for v, i in vi.items():
            o = o_view + 6 * i
            view_R[v] = cv2.Rodrigues(x[o: o + 3])[0] @ view_R[v]
            view_t[v] = view_t[v] + x[o + 3: o + 6]
        for c in free_k:
            k_vec[c] = k_vec[c] + x[ki[c]: ki[c] + nk]

    if _probe is not None:  # tests compare the Jacobian with finite differences
        _probe.update(x0=np.zeros(n_x), evaluate=evaluate)
    zero = np.zeros(n_x)
    r = evaluate(zero, False)
    cost = float(r @ r)
    lam, n_eval = 1e-3, 1
    for _ in range(100):
        J = evaluate(zero, True)
        JtJ = (J.T @ J).tocsc()
        g = J.T @ r
        d = JtJ.diagonal()
        improved = False
        while lam < 1e10:
            step = -spsolve(JtJ + diags(lam * np.maximum(d, 1e-12)), g)
            r_new = evaluate(step, False)
            n_eval += 1
            c_new = float(r_new @ r_new)
            if c_new < cost:
                fold(step)
                improved = cost - c_new > 1e-12 * cost and np.abs(step).max() > 1e-12
                r, cost = r_new, c_new
                lam = max(lam / 10.0, 1e-9)
                break
            lam *= 10.0
        if not improved:
            break
    cam_T = {c: np.linalg.inv(_T(cam_R[c], cam_t[c])) for c in cams}
    view_T = {ref: WORLD_FROM_BOARD.copy()}
    view_T.update({v: _T(view_R[v], view_t[v]) for v in views})
    intr_x = dict(intr)
    for c in free_k:
        K, D = camera_model(zero, c)
        k = intr[c]
        intr_x[c] = Intrinsics(k.width, k.height, K[0, 0], K[1, 1], K[0, 2], K[1, 2],
                               "plumb_bob", tuple(float(v) for v in D))
    return cam_T, view_T, intr_x, n_eval


def _rms(cam: str, dets: Mapping[int, Detection], spec: BoardSpec, k: Intrinsics,
         T_wc: np.ndarray, T_wb: Mapping[int, np.ndarray]) -> float:
    """RMS reprojection error [px] of one camera over the views it saw."""
    import cv2

    sq, n = 0.0, 0
    for v, d in dets.items():
        if v not in T_wb:
            continue
        T = np.linalg.inv(T_wc) @ T_wb[v]
        proj, _ = cv2.projectPoints(spec.corners[d.ids], matrix_to_rotvec(T[:3, :3]),
                                    T[:3, 3], k.K, np.asarray(k.distortion))
        sq += float(np.sum((proj.reshape(-1, 2) - d.pixels) ** 2))
        n += len(d)
    return math.sqrt(sq / max(n, 1))


def _T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return T
