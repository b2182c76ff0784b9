"""ros2 launch hand_suite servo.launch.py [params_file:=FILE]

The graph described in config/graphs/servo.yaml: the servo bridge (set port: /dev/ttyUSB0 and
servo_map in params_file for real hardware).
"""

from hand_control.graph import launch_description


def generate_launch_description():
    """Entry point of ros2 launch."""
    return launch_description("servo")
