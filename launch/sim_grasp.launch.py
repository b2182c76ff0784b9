"""ros2 launch hand_suite sim_grasp.launch.py [params_file:=FILE]

The graph described in config/graphs/sim_grasp.yaml: MuJoCo simulation + contact-force
controller running a scenario of config/scenarios/ (set scenario: in params_file for both).
"""

from hand_control.graph import launch_description


def generate_launch_description():
    """Entry point of ros2 launch."""
    return launch_description("sim_grasp")
