"""ros2 launch hand_suite retarget.launch.py [params_file:=FILE]

The graph described in config/graphs/retarget.yaml: synthetic camera -> depth tracker ->
retarget (onto the LEAP Hand model) -> servo bridge on robot/joint_command (emulated bus by
default; set port and the retarget config in params_file for a real hand).
"""

from hand_control.graph import launch_description


def generate_launch_description():
    """Entry point of ros2 launch."""
    return launch_description("retarget")
