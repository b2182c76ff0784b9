"""Kinematic retargeting: 21 human hand keypoints -> the joint angles of a robot hand.

Per frame, a small box-constrained least-squares problem over the robot's optimised joints
``q`` (within their limits), warm-started from the previous frame's solution and solved by
Levenberg-Marquardt / Gauss-Newton steps with MuJoCo's analytic point Jacobians:

    min_q  sum_k w_k || A_k P(q) - t_k ||^2  +  mu || q - q_prev ||^2,   lo <= q <= hi

where ``P(q)`` are the robot points of the config (world frame), each row ``A_k P`` is one
point (position mode) or the difference of two points (a vector), and ``t_k`` its target:

* position: each robot point onto the human keypoint it follows, expressed in the human hand
  frame (``hand_frame_from_keypoints21``), scaled by ``scale`` about the wrist and placed in
  the robot by the config's wrist frame;
* vector: the same wrist-to-point vectors plus the tip-to-tip vectors (thumb to every other
  tip, and neighbouring fingertips), scaled, weighted by ``vector_weight``;
* pinch: vector mode where a thumb-to-finger vector whose human length ``d`` is below
  ``pinch_close_m`` keeps the human length (not scaled up: the robot closes the pinch the
  operator closes) with weight ``pinch_weight``, blending linearly to the scaled vector and
  ``vector_weight`` at ``pinch_open_m`` (the distance-dependent vector projection of the
  kinematic retargeting cost of DexPilot, Handa et al., ICRA 2020, with a linear blend
  between the two regimes instead of a switch).

Each step solves ``(J^T W J + (lambda + mu) I) dq = -(J^T W r + mu (q - q_prev))`` under the
box ``lo - q <= dq <= hi - q`` (an active-set solve of the small QP), so the limits hold
exactly at every iterate; a joint step is at most ``max_step`` (a trust region), and a step
that raises the cost is retried with 10x the damping.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from hand_capture.model.keypoints21 import (
    KEYPOINT21_INDEX,
    hand_frame_from_keypoints21,
    validate_keypoints21,
)
from hand_control.dynamixel.retarget import LowPassFilter
from hand_control.errors import InputError
from hand_control.retarget.config import RetargetConfig, load_retarget_config
from hand_control.retarget.robot import PointRef, RobotHand, load_mujoco_model

_TIP_ORDER = ("thumb_tip", "index_tip", "middle_tip", "ring_tip", "little_tip")


@dataclass(frozen=True)
class RetargetResult:
    """One frame's answer.

    Attributes:
        q: (n,) robot joints after the low-pass filter [rad or m], within the limits.
        q_solved: (n,) the optimiser's joints before the filter.
        point_error_m: (k,) distance of each robot point from its position target [m]
            (the scaled human keypoint placed in the robot), at ``q_solved``.
        iterations: Gauss-Newton steps taken.
        cost: the final value of the cost [m^2].
        time_s: wall time of the solve [s].
    """

    q: np.ndarray
    q_solved: np.ndarray
    point_error_m: np.ndarray
    iterations: int
    cost: float
    time_s: float


def solve_box_qp(h: np.ndarray, g: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 max_rounds: int | None = None) -> np.ndarray:
    """``argmin 0.5 x^T H x + g^T x`` subject to ``lo <= x <= hi`` (H positive definite).

    A primal active-set method: solve over the free variables, fix the violated ones at
    their bound, release a fixed one whose gradient points back into the box; it ends at the
    KKT point (or after ``max_rounds``, default 3 n, with a feasible point: clipped).
    """
    n = g.shape[0]
    x = np.linalg.solve(h, -g)
    if ((x >= lo) & (x <= hi)).all():  # the usual case: no bound active
        return x
    fixed = (x < lo) | (x > hi)
    x = np.clip(x, lo, hi)
    for _ in range(max_rounds or 3 * n + 3):
        free = ~fixed
        x_f = x.copy()
        if free.any():
            rhs = -(g[free] + h[np.ix_(free, fixed)] @ x[fixed])
            x_f[free] = np.linalg.solve(h[np.ix_(free, free)], rhs)
        viol = free & ((x_f < lo) | (x_f > hi))
        if viol.any():
            x = np.clip(x_f, lo, hi)
            fixed |= viol
            continue
        x = x_f
        grad = h @ x + g
        release = fixed & (((x <= lo) & (grad < 0)) | ((x >= hi) & (grad > 0)))
        if not release.any():
            break
        fixed &= ~release
    return np.clip(x, lo, hi)


class HandRetargeter:
    """Retargets 21 human keypoints (or a suite HandPose) onto one robot hand.

    Args:
        config: the validated config (or a name / path for :func:`load_retarget_config`).
        robot: an already loaded robot (default: loaded from ``config.model``).

    Raises:
        ConfigError: the model does not load, or names a body / site / joint it lacks.
    """

    def __init__(self, config: RetargetConfig | str, robot: RobotHand | None = None) -> None:
        if not isinstance(config, RetargetConfig):
            config = load_retarget_config(config)
        self.config = config
        self.settings = config.settings
        if robot is None:
            robot = RobotHand(load_mujoco_model(config.model, config.handedness),
                              config.base_body, config.joints, config.fixed_joints,
                              source=config.model)
        self.robot = robot
        self.points: list[PointRef] = [
            robot.point(p.keypoint, body=p.body, site=p.site, offset=p.offset)
            for p in config.points]
        self.keypoint_idx = np.array([KEYPOINT21_INDEX[p.keypoint] for p in config.points])
        self.point_weight = np.array([p.weight for p in config.points])
        # the human hand frame in the world of the robot model
        self.wrist_rot = robot.base_rot @ config.wrist_rotation()
        self.wrist_pos = robot.base_pos + robot.base_rot @ np.asarray(config.wrist_pos)
        names = [p.keypoint for p in config.points]
        tips = [names.index(t) for t in _TIP_ORDER if t in names]
        self.tip_rows = tips
        thumb = names.index("thumb_tip") if "thumb_tip" in names else -1
        pairs: list[tuple[int, int, bool]] = []  # (from, to, is a thumb-finger pair)
        if thumb >= 0:
            pairs += [(thumb, t, True) for t in tips if t != thumb]
        others = [t for t in tips if t != thumb]
        pairs += [(a, b, False) for a, b in zip(others[:-1], others[1:], strict=True)]
        self.pairs = pairs
        self.filter = LowPassFilter(self.settings.filter_cutoff_hz)
        self.lower, self.upper = robot.lower, robot.upper
        self._q = robot.reference_q()
        self._last_stamp: float | None = None
        self._warm = False

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.robot.joint_names

    def reset(self, q0: np.ndarray | None = None) -> None:
        """Forget the previous frame: warm start from ``q0`` (default the reference pose)."""
        self._q = self.robot.reference_q() if q0 is None else np.clip(
            np.asarray(q0, dtype=np.float64), self.lower, self.upper)
        self.filter = LowPassFilter(self.settings.filter_cutoff_hz)
        self._last_stamp = None
        self._warm = False

    # ------------------------------------------------------------------------ targets
    def human_points(self, keypoints: np.ndarray, side: str | None = None) -> np.ndarray:
        """(k, 3) the config's human keypoints in the human hand frame [m] (unscaled).

        Raises:
            InputError: wrong shape, NaN in a keypoint the config uses or in the palm.
        """
        kp = validate_keypoints21(keypoints)
        used = kp[self.keypoint_idx]
        if not np.isfinite(used).all():
            bad = np.flatnonzero(~np.isfinite(used).all(axis=1))
            raise InputError(f"NaN/Inf in keypoint(s) "
                             f"{[self.config.points[i].keypoint for i in bad]}")
        rot, origin = hand_frame_from_keypoints21(kp, side or self.config.handedness)
        return (used - origin) @ rot

    def targets(self, human: np.ndarray) -> np.ndarray:
        """(k, 3) world position targets: the scaled human points placed in the robot."""
        return self.wrist_pos + (self.settings.scale * human) @ self.wrist_rot.T

    def _rows(self, human: np.ndarray
              ) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray, np.ndarray]:
        """The residual rows of the mode: point index pairs (from, to) (-1 = the wrist),
        targets (m, 3) and weights (m,)."""
        s = self.settings
        scale = s.scale
        rows: list[tuple[int, int]] = [(-1, i) for i in range(len(self.points))]
        tgt = [self.targets(human)[i] - self.wrist_pos for i in range(len(self.points))]
        w = list(self.point_weight)
        if s.mode != "position":
            for a, b, thumb_pair in self.pairs:
                v = human[b] - human[a]
                factor, weight = scale, s.vector_weight
                if s.mode == "pinch" and thumb_pair:
                    d = float(np.linalg.norm(v))
                    alpha = min(max((d - s.pinch_close_m)
                                    / (s.pinch_open_m - s.pinch_close_m), 0.0), 1.0)
                    # DexPilot-style projection: human length in a pinch, scaled when open
                    factor = (1.0 - alpha) * 1.0 + alpha * scale
                    weight = (1.0 - alpha) * s.pinch_weight + alpha * s.vector_weight
                rows.append((a, b))
                tgt.append(self.wrist_rot @ (factor * v))
                w.append(weight)
        idx = np.array(rows, dtype=np.int64).T
        return (idx[0], idx[1]), np.asarray(tgt), np.asarray(w)

    def _residual(self, rows: tuple[np.ndarray, np.ndarray], tgt: np.ndarray,
                  pos: np.ndarray) -> np.ndarray:
        """(m, 3) ``P_b - P_a - t`` per row (``a = -1``: the wrist, a constant)."""
        ext = np.vstack([pos, self.wrist_pos])
        return ext[rows[1]] - ext[rows[0]] - tgt

    def _jac(self, rows: tuple[np.ndarray, np.ndarray], jp: np.ndarray) -> np.ndarray:
        """(m, 3, n) Jacobian of each row (the wrist's is zero)."""
        ext = np.concatenate([jp, np.zeros((1,) + jp.shape[1:])])
        return ext[rows[1]] - ext[rows[0]]

    def residual_and_jacobian(self, q: np.ndarray, human: np.ndarray
                              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The weighted residual (3m,), its Jacobian (3m, n) at ``q`` and the weights (m,)
        (for tests: the Jacobian is MuJoCo's analytic one)."""
        rows, tgt, w = self._rows(human)
        self.robot.set_q(q)
        pos = self.robot.positions(self.points)
        jp = self.robot.jacobians(self.points, pos)
        sw = np.sqrt(w)[:, None]
        r = (self._residual(rows, tgt, pos) * sw).reshape(-1)
        j = (self._jac(rows, jp) * sw[:, :, None]).reshape(-1, self.robot.n)
        return r, j, w

    # ---------------------------------------------------------------------------- solve
    def solve(self, keypoints: np.ndarray, stamp_s: float | None = None,
              side: str | None = None) -> RetargetResult:
        """Retarget one frame of 21 keypoints (any frame; the hand frame is fitted).

        Args:
            keypoints: (21, 3) in the common order [m].
            stamp_s: the frame's time [s] for the low-pass filter (None: no filtering).
            side: the human hand's side (default the config's handedness).

        Raises:
            InputError: bad keypoints (nothing changes: the last solution is kept).
        """
        t0 = time.perf_counter()
        human = self.human_points(keypoints, side)
        s = self.settings
        rows, tgt, w = self._rows(human)
        sw = np.sqrt(w)[:, None]
        robot = self.robot
        q_prev = self._q.copy()
        q = q_prev.copy()
        n = robot.n
        mu = s.smoothness
        lam = s.damping
        eye = np.eye(n)

        def evaluate(qq: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
            robot.set_q(qq)
            pos = robot.positions(self.points)
            r = (self._residual(rows, tgt, pos) * sw).reshape(-1)
            dq = qq - q_prev
            return pos, r, float(r @ r + mu * (dq @ dq))

        pos, r, cost = evaluate(q)
        it = 0
        # a cold start (no previous frame) may need to travel far: more steps
        limit = s.max_iterations * (1 if self._warm else 5)
        while it < limit:
            it += 1
            jp = robot.jacobians(self.points, pos)
            j = (self._jac(rows, jp) * sw[:, :, None]).reshape(-1, n)
            h = j.T @ j
            g = j.T @ r + mu * (q - q_prev)
            h_scale = float(np.trace(h)) / n
            damped = False
            for _ in range(8):
                step = solve_box_qp(h + (lam + mu) * eye, g, self.lower - q, self.upper - q)
                big = float(np.max(np.abs(step)))
                if big > s.max_step:  # a trust region: the box holds 0, so it holds the step
                    step *= s.max_step / big
                q_new = np.clip(q + step, self.lower, self.upper)
                pos_new, r_new, cost_new = evaluate(q_new)
                if cost_new <= cost + 1e-15:
                    break
                damped = True
                lam = max(lam * 10.0, 1e-4 * h_scale)
            else:  # no step lowers the cost: q is a (local) minimum
                robot.set_q(q)
                break
            gain = cost - cost_new
            q, pos, r, cost = q_new, pos_new, r_new, cost_new
            lam = max(lam * 0.1, s.damping)
            if float(np.max(np.abs(step))) < s.tolerance or (
                    not damped and gain <= s.cost_tolerance * cost):
                break
        self._q = q
        self._warm = True
        err = np.linalg.norm(pos - self.targets(human), axis=1)
        if stamp_s is None or self.settings.filter_cutoff_hz <= 0:
            q_out = q.copy()
        else:
            dt = 0.0 if self._last_stamp is None else max(stamp_s - self._last_stamp, 0.0)
            q_out = self.filter(q, dt).copy()
        self._last_stamp = stamp_s
        return RetargetResult(np.clip(q_out, self.lower, self.upper), q.copy(), err, it,
                              cost, time.perf_counter() - t0)

    def solve_pose(self, pose: np.ndarray, model: object | None = None,
                   stamp_s: float | None = None, side: str | None = None) -> RetargetResult:
        """Retarget a suite hand pose (27,) through its 21 keypoints (``model``: the
        :class:`~hand_capture.model.HandModel` of the operator, default the template)."""
        from hand_capture.model.keypoints21 import keypoints21

        side = side or self.config.handedness
        return self.solve(keypoints21(model, pose, side), stamp_s, side)

    def robot_points(self, q: np.ndarray) -> np.ndarray:
        """(k, 3) world positions of the config's robot points at joints ``q`` [m]."""
        return self.robot.forward(q, self.points)

