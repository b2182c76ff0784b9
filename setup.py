"""ament_python package hand_suite: Python packages hand_capture and hand_control."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "hand_suite"

# Console scripts: one per node (names used by launch files and graph descriptions) plus the
# `hand-suite` command. Keep this table in step with config/graphs/*.yaml (a test checks it).
NODES = {
    "bag_recorder": "hand_capture.nodes.recorder:main",
    "bag_player": "hand_capture.nodes.player:main",
    "camera": "hand_capture.nodes.camera:main",
    "synthetic_camera": "hand_capture.nodes.synthetic_camera:main",
    "grasp_phase": "hand_control.nodes.grasp_phase:main",
    "servo_bridge": "hand_control.nodes.servo_bridge:main",
    "touch_source": "hand_capture.nodes.touch_source:main",
    "touch_encoder": "hand_capture.nodes.touch_encoder:main",
    "sim": "hand_control.nodes.sim:main",
    "controller": "hand_control.nodes.controller:main",
    "tracker": "hand_capture.nodes.tracker:main",
    "rig_sync": "hand_capture.nodes.rig_sync:main",
    "multiview_tracker": "hand_capture.nodes.multiview_tracker:main",
    "rgb_tracker": "hand_capture.nodes.rgb_tracker:main",
    "retarget": "hand_control.nodes.retarget:main",
}

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=["hand_capture", "hand_capture.*", "hand_control",
                                    "hand_control.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.xml")),
        (f"share/{PACKAGE}/config/graphs", glob("config/graphs/*.yaml")),
        (f"share/{PACKAGE}/config/servo_maps", glob("config/servo_maps/*.yaml")),
        (f"share/{PACKAGE}/config/retarget", glob("config/retarget/*.yaml")),
        (f"share/{PACKAGE}/config/robot_hands", glob("config/robot_hands/*")),
        (f"share/{PACKAGE}/config/rigs", glob("config/rigs/*.yaml")),
        (f"share/{PACKAGE}/config/scenarios", glob("config/scenarios/*.yaml")),
        (f"share/{PACKAGE}/data/touch", glob("data/touch/*.npz")),
        (f"share/{PACKAGE}/data/tracker", glob("data/tracker/*.npz")),
        (f"share/{PACKAGE}/data/salient", glob("data/salient/*.npz")),
        (f"share/{PACKAGE}/data/teleop", glob("data/teleop/*.npz")),
        (f"share/{PACKAGE}/data/webcam", glob("data/webcam/*.mp4")),
        (f"share/{PACKAGE}/data/grasp", glob("data/grasp/*.npz") + glob("data/grasp/*.json")),
        (f"share/{PACKAGE}/data/sample_capture", glob("data/sample_capture/*")),
        (f"share/{PACKAGE}/data/sample_rig_capture", glob("data/sample_rig_capture/*")),
    ],
    install_requires=["setuptools"],
    extras_require={"realsense": ["pyrealsense2"]},
    zip_safe=False,
    maintainer="hand_suite maintainers",
    maintainer_email="maintainers@hand-suite.dev",
    description="Hand motion capture and dexterous-hand control for ROS 2",
    license="Apache-2.0",
    python_requires=">=3.10",
    entry_points={
        "console_scripts": [f"{name} = {target}" for name, target in NODES.items()]
        + ["hand-suite = hand_control.cli:main"],
    },
)
