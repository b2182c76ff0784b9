"""ros2 launch hand_suite multiview.launch.py [params_file:=FILE]

The graph described in config/graphs/multiview.yaml.
"""

from hand_control.graph import launch_description


def generate_launch_description():
    """Entry point of ros2 launch."""
    return launch_description("multiview")
