"""Subject shape parameters (dissertation ch. II.3.2): global scale, bone scales, vertex offsets.

* ``global_scale`` is ``s_g`` of eq. II.2: a uniform scale of the whole template.
* Bone scales ``S = S0 + C_S alpha`` (eq. II.4): 17 relative scales (palm length, palm breadth
  and the length of each of the 15 finger segments), each applied along its bone's own axis
  (eq. II.3; the palm breadth along the palm's ``y``). ``alpha`` has :data:`N_ALPHA`
  coefficients with a standard-normal prior.
* Vertex offsets ``Q = Q0 + C_Q beta`` (eq. II.6): :data:`N_BETA` smooth offset fields along the
  rest-pose normals (finger girth, thumb girth, palm thickness, palm width, fingertip pads);
  ``beta`` is in metres of surface displacement.

The dissertation learns ``C_S`` and ``C_Q`` by PCA over 166 scanned subjects (II.3.5). We have no
scans, so ``C_S`` is the principal-component basis of an explicit covariance model built from
published anthropometry: hand-shape factor analyses find three main factors, hand breadth,
palm length and finger length (Jee & Yun, Int. J. Ind. Ergonomics 53, 2016; Kouchi et al.,
AIST digital hand family, 2004), plus each digit varying as a unit; the coefficients of variation
(3-5 %) follow the ANSUR II standard deviations of hand length and breadth (Gordon et al. 2014).
``C_Q`` is a set of hand-made smooth fields (mesh.py). Both can be replaced by learnt bases
without changing the API.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from hand_capture.errors import InputError
from hand_capture.model.skeleton import BONE_INDEX, BONE_NAMES, FINGERS, LEVELS

#: The 17 bone-scale entries of ``S`` and the (bone, local axis) each one stretches.
SCALE_NAMES: tuple[str, ...] = ("palm_length", "palm_breadth") + BONE_NAMES[1:]
N_SCALES: int = len(SCALE_NAMES)
SCALE_BONE: np.ndarray = np.array([0, 0] + [BONE_INDEX[n] for n in BONE_NAMES[1:]],
                                  dtype=np.int64)
SCALE_AXIS: np.ndarray = np.array([0, 1] + [0] * 15, dtype=np.int64)

#: Names of the vertex-offset fields (columns of C_Q), see mesh.py.
BETA_NAMES: tuple[str, ...] = ("finger_girth", "thumb_girth", "palm_thickness", "palm_width",
                               "fingertip_pad")
N_BETA: int = len(BETA_NAMES)
N_ALPHA: int = 6

#: prior of the global scale: ANSUR II pooled hand length SD / mean ~ 6 %
GLOBAL_SCALE_SD: float = 0.06
#: prior SD of each beta coefficient [m]
BETA_SD: float = 0.0012


def _scale_covariance() -> np.ndarray:
    """Covariance of the 17 relative bone scales (see module docstring)."""
    n = N_SCALES
    cov = np.zeros((n, n))

    def add(vec: np.ndarray, sd: float) -> None:
        nonlocal cov
        cov += sd * sd * np.outer(vec, vec)

    phal = np.zeros(n)
    phal[2:] = 1.0
    add(phal, 0.040)            # finger-length factor (long- vs short-fingered hands)
    e = np.zeros(n)
    e[0] = 1.0
    add(e, 0.035)               # palm-length factor
    e = np.zeros(n)
    e[1] = 1.0
    add(e, 0.050)               # hand-breadth factor
    for fi in range(len(FINGERS)):
        d = np.zeros(n)
        for b in LEVELS[:, fi]:
            d[SCALE_NAMES.index(BONE_NAMES[b])] = 1.0
        add(d, 0.030)           # each digit varies as a unit
    cov += np.diag(np.r_[0.0, 0.0, np.full(n - 2, 0.018 ** 2)])  # independent segments
    return cov


def _scale_basis() -> tuple[np.ndarray, np.ndarray, float]:
    cov = _scale_covariance()
    w, v = np.linalg.eigh(cov)
    order = np.argsort(w)[::-1]
    w, v = w[order], v[:, order]
    # deterministic sign: the largest-magnitude entry of each component is positive
    for k in range(v.shape[1]):
        if v[np.argmax(np.abs(v[:, k])), k] < 0:
            v[:, k] *= -1.0
    basis = v[:, :N_ALPHA] * np.sqrt(w[:N_ALPHA])
    explained = float(w[:N_ALPHA].sum() / w.sum())
    basis.setflags(write=False)
    return np.ones(N_SCALES), basis, explained


#: ``S0`` (17,) and ``C_S`` (17, N_ALPHA) of eq. II.4; alpha ~ N(0, I).
SCALE_MEAN, SCALE_BASIS, SCALE_EXPLAINED = _scale_basis()


@dataclass(frozen=True)
class HandShape:
    """One subject's shape: ``(s_g, alpha, beta)`` of eq. II.9.

    Attributes:
        global_scale: ``s_g`` (1.0 = the template, hand length 0.187 m).
        alpha: bone-scale coefficients (N_ALPHA,), unit-variance prior.
        beta: vertex-offset coefficients (N_BETA,) [m] along the rest normals.
        subject_id: free-form name.
    """

    global_scale: float = 1.0
    alpha: tuple[float, ...] = field(default=(0.0,) * N_ALPHA)
    beta: tuple[float, ...] = field(default=(0.0,) * N_BETA)
    subject_id: str = ""

    def __post_init__(self) -> None:
        try:
            gs = float(self.global_scale)
            alpha = tuple(float(a) for a in np.asarray(self.alpha, dtype=float).ravel())
            beta = tuple(float(b) for b in np.asarray(self.beta, dtype=float).ravel())
        except (TypeError, ValueError) as e:
            raise InputError(f"HandShape values must be numbers: {e}") from e
        if not math.isfinite(gs) or not 0.5 <= gs <= 2.0:
            raise InputError(f"HandShape.global_scale = {gs} is out of range [0.5, 2.0]")
        if len(alpha) != N_ALPHA or not all(math.isfinite(a) and abs(a) <= 6.0 for a in alpha):
            raise InputError(f"HandShape.alpha must be {N_ALPHA} finite values in [-6, 6], "
                             f"got {alpha}")
        if len(beta) != N_BETA or not all(math.isfinite(b) and abs(b) <= 0.01 for b in beta):
            raise InputError(f"HandShape.beta must be {N_BETA} finite values in [-0.01, 0.01] "
                             f"m, got {beta}")
        object.__setattr__(self, "global_scale", gs)
        object.__setattr__(self, "alpha", alpha)
        object.__setattr__(self, "beta", beta)

    def bone_scales(self) -> np.ndarray:
        """``S(alpha) = S0 + C_S alpha`` (eq. II.4), shape (17,), in SCALE_NAMES order."""
        s = SCALE_MEAN + SCALE_BASIS @ np.asarray(self.alpha)
        return np.maximum(s, 0.3)

    def with_params(self, global_scale: float | None = None, alpha: object = None,
                    beta: object = None) -> HandShape:
        """A copy with some parameters replaced (for optimisers)."""
        return HandShape(self.global_scale if global_scale is None else global_scale,
                         self.alpha if alpha is None else tuple(np.ravel(alpha)),
                         self.beta if beta is None else tuple(np.ravel(beta)),
                         self.subject_id)

    @property
    def params(self) -> np.ndarray:
        """``[s_g, alpha..., beta...]`` (1 + N_ALPHA + N_BETA,): the shape Jacobian's columns."""
        return np.r_[self.global_scale, self.alpha, self.beta]

    @classmethod
    def from_params(cls, params: object, subject_id: str = "") -> HandShape:
        p = np.asarray(params, dtype=float).ravel()
        if p.size != 1 + N_ALPHA + N_BETA:
            raise InputError(f"shape params must have {1 + N_ALPHA + N_BETA} entries, "
                             f"got {p.size}")
        return cls(float(p[0]), tuple(p[1:1 + N_ALPHA]), tuple(p[1 + N_ALPHA:]), subject_id)

    def to_msg_fields(self) -> dict[str, object]:
        """Field values of hand_msgs/HandShape (without header / handedness / residual)."""
        return {"subject_id": self.subject_id, "global_scale": self.global_scale,
                "bone_names": list(SCALE_NAMES), "bone_scales": self.bone_scales().tolist(),
                "alpha": list(self.alpha), "beta": list(self.beta)}

    @classmethod
    def from_msg_fields(cls, global_scale: float, alpha: object, beta: object,
                        subject_id: str = "") -> HandShape:
        """Inverse of :meth:`to_msg_fields` (bone_scales are derived from alpha)."""
        return cls(global_scale, tuple(np.ravel(alpha)), tuple(np.ravel(beta)), subject_id)


def default_shape() -> HandShape:
    """The template (average adult) shape."""
    return HandShape()


def sample_shape(rng: np.random.Generator | int | None = None, subject_id: str = "") -> HandShape:
    """A random plausible subject (II.4 'subject variation': random (alpha, beta)).

    ``s_g ~ N(1, 0.06)`` clipped to [0.85, 1.15], ``alpha ~ N(0, I)`` clipped to +-2.5,
    ``beta ~ N(0, 1.2 mm)`` clipped to +-3 mm.
    """
    rng = np.random.default_rng(rng)
    gs = float(np.clip(rng.normal(1.0, GLOBAL_SCALE_SD), 0.85, 1.15))
    alpha = np.clip(rng.standard_normal(N_ALPHA), -2.5, 2.5)
    beta = np.clip(rng.normal(0.0, BETA_SD, N_BETA), -0.003, 0.003)
    return HandShape(gs, tuple(alpha), tuple(beta), subject_id)
