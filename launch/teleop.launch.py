"""ros2 launch hand_suite teleop.launch.py [params_file:=FILE]

The graph described in config/graphs/teleop.yaml: camera -> tracker -> grasp_phase ->
controller + sim -> servo_bridge, with a recorder of every topic.
"""

from hand_control.graph import launch_description


def generate_launch_description():
    """Entry point of ros2 launch."""
    return launch_description("teleop")
