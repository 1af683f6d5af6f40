"""The DDS environment of every Roger process (plain Python: no ROS import).

Two defaults, each kept if the user already set it:

* ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``: traffic stays on loopback unless a user asks
  for a multi-host graph (``SUBNET`` plus ``ROS_STATIC_PEERS``).
* ``FASTRTPS_DEFAULT_PROFILES_FILE`` = ``fastdds_profile.xml`` next to this module: a 4 MiB
  shared-memory segment, so that a stereo frame burst fits in shared memory (the file says
  why). A user's own profile file (``FASTRTPS_DEFAULT_PROFILES_FILE`` or
  ``FASTDDS_DEFAULT_PROFILES_FILE``) replaces it, and a user who picked the transports with
  ``FASTDDS_BUILTIN_TRANSPORTS`` (say ``UDPv4`` for a graph across hosts) gets exactly those.
"""

from __future__ import annotations

import re
from collections.abc import MutableMapping
from pathlib import Path

PROFILE_FILE = Path(__file__).with_name("fastdds_profile.xml")
PROFILE_ENV = "FASTRTPS_DEFAULT_PROFILES_FILE"
_OTHER_PROFILE_ENV = "FASTDDS_DEFAULT_PROFILES_FILE"
TRANSPORTS_ENV = "FASTDDS_BUILTIN_TRANSPORTS"


def apply_dds_defaults(env: MutableMapping[str, str]) -> MutableMapping[str, str]:
    """Set Roger's DDS defaults in ``env`` (``os.environ`` or a child's dict) and return it.

    Call it before ``rclpy.init``: Fast DDS reads the profile file when the participant is
    created.
    """
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if not any(env.get(k) for k in (PROFILE_ENV, _OTHER_PROFILE_ENV, TRANSPORTS_ENV)):
        env[PROFILE_ENV] = str(PROFILE_FILE)
    return env


def shm_segment_bytes(profile: Path = PROFILE_FILE) -> int:
    """The shared-memory segment size the profile asks for (0 when it sets none)."""
    sizes = re.findall(r"<segment_size>\s*(\d+)\s*</segment_size>", profile.read_text())
    return max((int(s) for s in sizes), default=0)
