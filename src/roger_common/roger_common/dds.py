"""The DDS environment of every Roger process (plain Python: no ROS import).

Two defaults, each kept if the user already set it:

* ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``: traffic stays on loopback unless a user asks
  for a multi-host graph (``SUBNET`` plus ``ROS_STATIC_PEERS``).
* ``FASTRTPS_DEFAULT_PROFILES_FILE`` = ``fastdds_profile.xml`` next to this module: a 4 MiB
  shared-memory segment, so that a stereo frame burst fits in shared memory (the file says
  why). A user's own profile file (``FASTRTPS_DEFAULT_PROFILES_FILE`` or
  ``FASTDDS_DEFAULT_PROFILES_FILE``) replaces it, and a user who picked the transports with
  ``FASTDDS_BUILTIN_TRANSPORTS`` (say ``UDPv4`` for a graph across hosts) gets exactly those.

A node the orchestrator restarts gets the same profile with a participant id of its own
(``profile_with_participant_id``), so that it never listens on a port of the participant it
replaces (docs/reliability.md, "A restarted node's ports").
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


#: Participant ids given to restarted nodes (``orchestrator.Graph.restart_env``): above the
#: ids Fast DDS hands out by itself to a graph's first processes and to tools that join it
#: (0, 1, ...), and below 32: with LOCALHOST discovery, two participants whose ids are both
#: 32 or more never find each other (measured: ids 32 and 40 exchange nothing, 31 and 40
#: do), as each announces itself to the ids 0-31 only. Every port of these ids is a valid
#: port in every ROS domain (0-232): the user-unicast port is 7400 + 250 * domain + 11 +
#: 2 * id.
RESTART_PARTICIPANT_IDS = range(8, 32)


def user_unicast_port(domain_id: int, participant_id: int) -> int:
    """The RTPS user-unicast port of a participant (Fast DDS's default port parameters);
    its shared-memory port file is ``/dev/shm/fastrtps_port<port>``."""
    return 7400 + 250 * domain_id + 11 + 2 * participant_id


def profile_with_participant_id(participant_id: int, path: Path,
                                profile: Path = PROFILE_FILE) -> Path:
    """Write ``profile`` with its default participant's id fixed to ``participant_id`` to
    ``path`` and return ``path``.

    Raises:
        ValueError: ``profile`` has no ``<rtps>`` element to put the id in.
    """
    text = profile.read_text()
    if text.count("<rtps>") != 1:
        raise ValueError(f"{profile}: expected one <rtps> element to set participantID in")
    text = text.replace("<rtps>", f"<rtps>\n      <participantID>{int(participant_id)}"
                                  "</participantID>", 1)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def shm_segment_bytes(profile: Path = PROFILE_FILE) -> int:
    """The shared-memory segment size the profile asks for (0 when it sets none)."""
    sizes = re.findall(r"<segment_size>\s*(\d+)\s*</segment_size>", profile.read_text())
    return max((int(s) for s in sizes), default=0)
