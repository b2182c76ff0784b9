"""The DDS environment the suite gives its nodes (issue 13, transport).

Full-size depth images (640x480 16UC1 = 614 kB) are larger than Fast DDS's default
shared-memory segment (512 kB), so they travel as UDP fragments, and a best-effort reader
loses whole frames when a fragment is dropped. ``config/fastdds_profile.xml`` gives every
participant a shared-memory transport with a larger segment (and large socket buffers for
the UDP fallback). The graph runner (``hand-suite run``), the launch files, every node's
``main()`` (:func:`hand_capture.nodes.shell.run_node`) and ``hand-suite`` itself set
``FASTDDS_DEFAULT_PROFILES_FILE`` (Fast DDS 3: Kilted, the PyPI wheels) to it, and on a
Fast DDS 2 distribution (``ROS_DISTRO`` humble, iron or jazzy) also
``FASTRTPS_DEFAULT_PROFILES_FILE``, which those read (Fast DDS 3's rmw warns at every start
that the old name is deprecated, so it is not set there), unless the user already set one.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from hand_capture.paths import config_dir

__all__ = ["PROFILE_VARS", "dds_environment", "profile_file"]

#: the variables Fast DDS 3 / Fast DDS 2 read the default XML profile from
PROFILE_VARS = ("FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE")
#: ROS 2 distributions on Fast DDS 2 (they read the second variable)
FAST_DDS_2_DISTROS = frozenset({"humble", "iron", "jazzy"})


def profile_file() -> Path:
    """The shipped Fast DDS profile."""
    return config_dir() / "fastdds_profile.xml"


def dds_environment(env: Mapping[str, str]) -> dict[str, str]:
    """``env`` plus the shipped profile, unless ``env`` names a profile already (a user's
    own wins; one variable set gives its value to the other)."""
    out = dict(env)
    given = next((out[k] for k in PROFILE_VARS if out.get(k)), None)
    path = given or str(profile_file())
    wanted = PROFILE_VARS if out.get("ROS_DISTRO", "") in FAST_DDS_2_DISTROS else PROFILE_VARS[:1]
    for k in wanted:
        if not out.get(k):
            out[k] = path
    return out
