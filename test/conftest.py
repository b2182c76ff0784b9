"""Test environment: an isolated, loopback-only ROS 2 domain and headless rendering."""

from __future__ import annotations

import os
import random
import sys
from pathlib import Path

# A domain of its own per test session, so parallel sessions on one machine never cross-talk;
# discovery stays on this machine.
os.environ.setdefault("ROS_DOMAIN_ID", str(random.Random(os.getpid()).randint(1, 100)))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("MUJOCO_GL", "osmesa")
os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
