"""ros2 launch hand_suite webcam_teleop.launch.py [params_file:=FILE]

The graph described in config/graphs/webcam_teleop.yaml: a colour camera (UVC webcam or the
shipped sample video) -> rgb_tracker -> retarget -> servo bridge on the emulated bus.
"""

from hand_control.graph import launch_description


def generate_launch_description():
    """Entry point of ros2 launch."""
    return launch_description("webcam_teleop")
