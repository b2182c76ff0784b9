"""ros2 launch hand_suite bag_roundtrip.launch.py params_file:=my_roundtrip.yaml

The graph described in config/graphs/bag_roundtrip.yaml: bag_player -> bag_recorder (a record /
replay round trip). Name the bag to play (bag_player: bag) and the output (bag_recorder:
output) in params_file.
"""

from hand_control.graph import launch_description


def generate_launch_description():
    """Entry point of ros2 launch."""
    return launch_description("bag_roundtrip")
