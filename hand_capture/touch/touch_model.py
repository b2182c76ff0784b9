"""The trained multi-touch model: encoder coefficients + labelling reference, one small .npz.

``data/touch/touch_model.npz`` holds the linear, quadratic and cubic coefficients (eq. 1-3)
fitted on the generated training set, a float32 subsample of the training poses for the
labelling search (nearest neighbour, sec. 2) and the layout prior of the labelling
(:class:`~hand_capture.touch.labelling.LayoutPrior`). It is made by
``python -m hand_capture.touch.train`` (see that module) and loaded by the encoder node.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hand_capture.errors import ConfigError, InputError
from hand_capture.touch.encoding import DEGREES, POSE_DIM, ContactFrame, PolynomialEncoder
from hand_capture.touch.labelling import LayoutPrior

MODEL_FILE = Path("data") / "touch" / "touch_model.npz"
#: Most reference poses kept in the file (float32, 27 values each: ~430 KB).
MAX_REFERENCE = 4000


def default_model_path() -> Path:
    """``data/touch/touch_model.npz`` in the source tree or the installed share folder."""
    from hand_capture.paths import data_dir

    return data_dir() / MODEL_FILE.relative_to("data")


@dataclass
class TouchModel:
    """Encoders by name and the labelling reference poses (root relative to the leftmost
    contact, or in the contacts' frame when the model has one)."""

    encoders: dict[str, PolynomialEncoder]
    reference_poses: np.ndarray
    meta: dict[str, str] = field(default_factory=dict)
    layout: LayoutPrior | None = None  # labelling prior (None in files made before it)
    #: frame of u and the poses (None in files made before it: the leftmost contact)
    frame: ContactFrame | None = None

    def __post_init__(self) -> None:
        for enc in self.encoders.values():
            enc.frame = self.frame

    def encoder(self, name: str) -> PolynomialEncoder:
        try:
            return self.encoders[name]
        except KeyError as e:
            raise ConfigError(f"encoding {name!r} not in the model file; it has "
                              f"{sorted(self.encoders)}") from e

    def save(self, path: str | Path, max_reference: int = MAX_REFERENCE,
             seed: int = 0) -> Path:
        """Write the model; the reference set is subsampled to ``max_reference`` poses."""
        ref = self.reference_poses
        if len(ref) > max_reference:
            idx = np.sort(np.random.default_rng(seed).choice(len(ref), max_reference, False))
            ref = ref[idx]
        arrays: dict[str, np.ndarray] = {"reference_poses": ref.astype(np.float32),
                                         "encodings": np.array(sorted(self.encoders))}
        for name, enc in self.encoders.items():
            arrays.update(enc.to_arrays(prefix=f"{name}_"))
        if self.layout is not None:
            arrays.update(self.layout.to_arrays())
        if self.frame is not None:
            arrays.update(self.frame.to_arrays())
        for k, v in self.meta.items():
            arrays[f"meta_{k}"] = np.array(str(v))
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(path, **arrays)
        return path

    @staticmethod
    def load(path: str | Path | None = None) -> TouchModel:
        """Read a model file (default: :func:`default_model_path`).

        Raises:
            ConfigError: the file is missing or lacks arrays.
        """
        path = Path(path) if path else default_model_path()
        try:
            with np.load(path, allow_pickle=False) as data:
                names = [str(n) for n in data["encodings"]]
                encoders = {n: PolynomialEncoder.from_arrays(data, prefix=f"{n}_")
                            for n in names}
                ref = np.asarray(data["reference_poses"], np.float64)
                meta = {k[5:]: str(data[k]) for k in data.files if k.startswith("meta_")}
                layout = LayoutPrior.from_arrays(data)
                frame = ContactFrame.from_arrays(data)
        except FileNotFoundError as e:
            raise ConfigError(f"touch model file not found: {path} (make it with "
                              "'python -m hand_capture.touch.train')") from e
        except (KeyError, ValueError, OSError, InputError) as e:
            raise ConfigError(f"touch model file {path} is unreadable: {e}") from e
        unknown = set(names) - set(DEGREES)
        if unknown or ref.ndim != 2 or ref.shape[1] != POSE_DIM:
            raise ConfigError(f"touch model file {path} is malformed")
        return TouchModel(encoders, ref, meta, layout, frame)

