"""ros2 launch hand_suite touch.launch.py [params_file:=FILE]

The graph described in config/graphs/touch.yaml: touch_source -> touch_encoder -> servo_bridge.
"""

from hand_control.graph import launch_description


def generate_launch_description():
    """Entry point of ros2 launch."""
    return launch_description("touch")
