"""The hand model: skeleton, joint vocabulary and limits, shape, skinned mesh, FK, Jacobians.

Pure numpy (MJCF export needs only the standard library). Typical use::

    from hand_capture.model import HandModel, sample_shape, JOINT_NAMES

    model = HandModel(sample_shape(0), side="right")
    fk = model.forward(pose)                  # pose (27,) in JOINT_NAMES order, or (B, 27)
    fk.vertices, fk.joint_positions, fk.joint_frames      # (V,3), (21,3), (16,4,4)
    model.faces                               # (F, 3) triangles, CCW from outside
    model.normals(fk.vertices)                # (V, 3) outward normals
    model.fingertips(pose)                    # (5, 3) thumb..little, 'tip' or 'pad'
    model.jacobian(pose, vertex_idx)          # (N, 3, 27) analytic d vertex / d pose
    model.linearize(pose, vertex_idx)         # (vertices[idx], jacobian) from one FK pass
    model.keypoint_jacobian(pose)             # (21, 3, 27)
    model.shape_jacobian(pose, vertex_idx)    # (N, 3, 1 + N_ALPHA + N_BETA)
    model.capsules, model.capsule_segments(pose), model.self_penetration(pose)

See joints.py for the frame and angle conventions (root orientation = intrinsic XYZ hinge
angles, matching the MJCF export exactly). MuJoCo models and scenes: ``hand_capture.model.mjcf``
(``build_hand``, ``build_scene``, ``export_mjcf``, ``GAIN_TABLE``, ``ObjectSpec``);
``python -m hand_capture.model.mjcf OUT_DIR`` writes hand.xml and the scene files.
"""

from hand_capture.model.hand import (
    Capsule,
    FKResult,
    HandModel,
    segment_closest,
    segment_distance,
)
from hand_capture.model.joints import (
    ARTICULATED_JOINTS,
    FINGER_DOFS,
    FINGER_JOINTS,
    FINGERS,
    JOINT_INDEX,
    JOINT_LIMITS,
    JOINT_NAMES,
    N_DOF,
    ROOT_JOINTS,
    THUMB_JOINTS,
    clamp_to_limits,
    joint_limits_dict,
    matrix_to_quat,
    matrix_to_quat_wxyz,
    mirror_pose,
    pose_from_dict,
    pose_from_names,
    pose_to_dict,
    quat_from_root_angles,
    quat_to_matrix,
    quat_wxyz_to_matrix,
    rest_pose,
    root_angles_from_matrix,
    root_angles_from_quat,
    root_rotation_matrix,
    validate_pose,
    within_limits,
)
from hand_capture.model.keypoints21 import KEYPOINT21_NAMES, keypoints21
from hand_capture.model.mesh import vertex_normals
from hand_capture.model.shape import (
    BETA_NAMES,
    N_ALPHA,
    N_BETA,
    SCALE_NAMES,
    HandShape,
    default_shape,
    sample_shape,
)
from hand_capture.model.skeleton import (
    BONE_NAMES,
    BONE_PARENT,
    FINGERTIP_KEYPOINTS,
    KEYPOINT_NAMES,
    N_BONES,
    N_KEYPOINTS,
)

__all__ = [
    "ARTICULATED_JOINTS", "BETA_NAMES", "BONE_NAMES", "BONE_PARENT", "FINGERS",
    "FINGERTIP_KEYPOINTS", "FINGER_DOFS", "FINGER_JOINTS", "JOINT_INDEX", "JOINT_LIMITS",
    "JOINT_NAMES", "KEYPOINT21_NAMES",
    "KEYPOINT_NAMES", "N_ALPHA", "N_BETA", "N_BONES", "N_DOF", "N_KEYPOINTS", "ROOT_JOINTS",
    "SCALE_NAMES", "THUMB_JOINTS", "Capsule", "FKResult", "HandModel", "HandShape",
    "clamp_to_limits", "default_shape", "joint_limits_dict", "keypoints21", "matrix_to_quat",
    "matrix_to_quat_wxyz",
    "mirror_pose",
    "pose_from_dict", "pose_from_names", "pose_to_dict", "quat_from_root_angles",
    "quat_to_matrix", "quat_wxyz_to_matrix", "rest_pose", "root_angles_from_matrix",
    "root_angles_from_quat",
    "root_rotation_matrix", "sample_shape", "segment_closest", "segment_distance",
    "validate_pose",
    "vertex_normals", "within_limits",
]
