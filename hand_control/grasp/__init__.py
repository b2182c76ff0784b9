"""Grasp database, closing-phase models and grasp synthesis (dissertation III.3-III.4).

    records = load_grasp_database()          # demonstrations in the object frame (III.3)
    models = load_grasp_models()             # {grip mode: ClosingModel} (III.4.1.1)
    m = models["thumb_index_middle"]
    params = m.sample(64, rng)               # (64, m.n_params) from the GMM prior
    motion = m.decode(params[0])             # (m.n_frames, 27) closing motion, object frame
    e_p = m.neg_log_prior(params)            # eq. (III.5)

``hand-suite train grasps [--quick]`` rebuilds ``data/grasp/`` (seeded).
"""

from hand_control.grasp.closing import ClosingModel, fit_closing_model
from hand_control.grasp.database import (
    GRIP_CONTACT_FINGERS,
    GRIP_MODES,
    GraspRecord,
    from_object_frame,
    load_grasp_database,
    load_grasp_models,
    object_frame_yaw,
    to_object_frame,
)

__all__ = [
    "GRIP_CONTACT_FINGERS", "GRIP_MODES", "ClosingModel", "GraspRecord", "fit_closing_model",
    "from_object_frame", "load_grasp_database", "load_grasp_models", "object_frame_yaw",
    "to_object_frame",
]
