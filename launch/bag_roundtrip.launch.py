"""ros2 launch hand_suite replay.launch.py params_file:=my_replay.yaml

The replay graph described in config/graphs/replay.yaml: bag_player -> bag_recorder. Name the
bag to play (bag_player: bag) and the output (bag_recorder: output) in params_file.
"""

from hand_control.graph import launch_description


def generate_launch_description():
    """Entry point of ros2 launch."""
    return launch_description("replay")
