"""PCA-based inverse kinematics baseline (Chung et al., sec. 3, after Mulatto et al. 2013).

The fingers move only along the first principal components (postural synergies) of the
training poses; how many depends on the number of contacts (3, 6, 9, 12 for 2, 3, 4, 5, as in
the paper; 3 for a single contact). The wrist moves freely. Each iteration takes the
compliance-weighted minimum-norm step that moves the contacting fingertip pads towards their
contacts on the surface,

    dv = C J^T (J C J^T + lambda I)^-1 e,   v = (wrist position, wrist angles, synergies),

with compliance C = diag(0.1 for translation, 25.0 for rotation, ``synergy`` for the
synergies), the paper's values; 100 iterations, as in the paper. Each step is scaled down to
stay within a small trust region (without it a few percent of the poses run away). The
synergy coordinates are in units of one standard deviation of the training data along each
component. Labels are
chosen by the nearest neighbour of the contact input u among the training inputs (sec. 3),
see :class:`hand_capture.touch.labelling.FingerLabeller` with ``mode="input"``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hand_capture.config import param, validate
from hand_capture.errors import InputError
from hand_capture.model.joints import N_DOF
from hand_capture.touch.datagen import ContactIK
from hand_capture.touch.encoding import N_FINGERS, surface_to_table_xy

_ARTIC = slice(6, N_DOF)


@dataclass(frozen=True)
class PcaIkConfig:
    """Parameters of the PCA-IK baseline (sec. 3)."""

    compliance_translation: float = param(0.1, "compliance of the wrist position", lo=0.0)
    compliance_rotation: float = param(25.0, "compliance of the wrist angles", lo=0.0)
    compliance_synergy: float = param(1.0, "compliance of each synergy (not in the paper)",
                                      lo=0.0)
    iterations: int = param(100, "iterations per pose (paper: 100)", lo=1, hi=10000)
    damping: float = param(1e-9, "lambda of the damped pseudo-inverse [m^2]", lo=0.0)
    max_translation: float = param(0.005, "largest wrist move per iteration [m]", lo=1e-6)
    max_rotation: float = param(0.05, "largest wrist angle change per iteration [rad]",
                                lo=1e-6)
    max_synergy: float = param(0.25, "largest synergy change per iteration [SD]", lo=1e-6)

    def __post_init__(self) -> None:
        validate(self)


def components_for(n_contacts: int) -> int:
    """Principal components used with n contacts: 3 per contact beyond the first (sec. 3)."""
    return 3 * max(1, n_contacts - 1)


class PcaIk:
    """Synergy IK on the hand model.

    Args:
        model: the hand model (``fingertips(q, where='pad')``).
        poses: (M, 27) training poses, root relative to the leftmost contact (table frame).
    """

    def __init__(self, model: object, poses: np.ndarray, config: PcaIkConfig | None = None
                 ) -> None:
        self.config = config or PcaIkConfig()
        self.ik = ContactIK(model, clearance=0.0)
        y = np.asarray(poses, np.float64)
        fingers = y[:, _ARTIC]
        self.mean = fingers.mean(axis=0)
        _, s, vt = np.linalg.svd(fingers - self.mean, full_matrices=False)
        sd = s / np.sqrt(len(y))
        self.basis = vt.T * sd  # (21, r): one column = one SD along a component
        self.explained = np.cumsum(s ** 2) / np.sum(s ** 2)
        self.root_offset = y[:, :3].mean(axis=0)   # wrist relative to the leftmost contact
        self.root_angles = y[:, 3:6].mean(axis=0)

    def explained_variance(self, n_contacts: int) -> float:
        """Fraction of the finger-pose variance the components for n contacts capture."""
        k = min(components_for(n_contacts), len(self.explained))
        return float(self.explained[k - 1])

    def solve(self, pads: np.ndarray, contact: np.ndarray) -> np.ndarray:
        """Poses (B, 27), table frame, for labelled contacts ``pads`` (B, 5, 2) [m, surface
        coordinates] where ``contact`` (B, 5)."""
        pads = np.asarray(pads, np.float64)
        contact = np.asarray(contact, bool)
        if pads.shape[1:] != (N_FINGERS, 2) or contact.shape != pads.shape[:2]:
            raise InputError(f"pads must be (B, 5, 2) and contact (B, 5), got {pads.shape}, "
                             f"{contact.shape}")
        n = contact.sum(axis=1)
        out = np.empty((len(pads), N_DOF))
        for k in np.unique(n):
            rows = np.nonzero(n == k)[0]
            out[rows] = self._solve_group(pads[rows], contact[rows], int(k))
        return out

    def _solve_group(self, pads: np.ndarray, contact: np.ndarray, n: int) -> np.ndarray:
        cfg = self.config
        b = len(pads)
        k = min(components_for(n), self.basis.shape[1])
        basis = self.basis[:, :k]
        targets = np.concatenate([surface_to_table_xy(pads), np.zeros((b, N_FINGERS, 1))], -1)
        lead = np.argmin(np.where(contact, pads[..., 0], np.inf), axis=1)
        origin = targets[np.arange(b), lead]
        v = np.zeros((b, 6 + k))
        v[:, :3] = origin + self.root_offset
        v[:, 3:6] = self.root_angles
        comp = np.r_[np.full(3, cfg.compliance_translation),
                     np.full(3, cfg.compliance_rotation), np.full(k, cfg.compliance_synergy)]
        rows = np.repeat(contact, 3, axis=1)  # (B, 15) residual rows in use
        eye = np.eye(3 * N_FINGERS)
        for _ in range(cfg.iterations):
            q = self._pose(v, basis)
            p = self.ik.pads(q)
            e = ((targets - p).reshape(b, -1)) * rows
            jq = self.ik.pad_jacobian(q, p).reshape(b, 3 * N_FINGERS, N_DOF)
            jv = np.concatenate([jq[..., :6], jq[..., 6:] @ basis], axis=-1) * rows[..., None]
            jc = jv * comp
            a = jc @ np.swapaxes(jv, 1, 2) + cfg.damping * eye + np.where(rows, 0.0, 1.0)[
                :, :, None] * eye
            dv = np.einsum("bmr,br->bm", np.swapaxes(jc, 1, 2),
                           np.linalg.solve(a, e[..., None])[..., 0])
            # step limit (a trust region; without it some poses run away)
            ratio = np.maximum.reduce([
                np.linalg.norm(dv[:, :3], axis=1) / cfg.max_translation,
                np.abs(dv[:, 3:6]).max(axis=1) / cfg.max_rotation,
                np.abs(dv[:, 6:]).max(axis=1) / cfg.max_synergy, np.ones(b)])
            v += dv / ratio[:, None]
        return self._pose(v, basis)

    def _pose(self, v: np.ndarray, basis: np.ndarray) -> np.ndarray:
        q = np.empty((len(v), N_DOF))
        q[:, :6] = v[:, :6]
        q[:, _ARTIC] = self.mean + v[:, 6:] @ basis.T
        return q
