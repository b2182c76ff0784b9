"""ros2 launch hand_suite tracking.launch.py [params_file:=FILE]

The graph described in config/graphs/tracking.yaml: synthetic_camera -> tracker (hand/pose,
hand/joint_states, hand/markers, hand/debug_image).
"""

from hand_control.graph import launch_description


def generate_launch_description():
    """Entry point of ros2 launch."""
    return launch_description("tracking")
