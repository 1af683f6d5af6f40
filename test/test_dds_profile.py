"""Every Roger process gets the same DDS defaults: LOCALHOST discovery and a shared-memory
segment large enough for a stereo frame burst (roger_common.dds, fastdds_profile.xml)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from roger_common.dds import PROFILE_ENV, PROFILE_FILE, apply_dds_defaults, shm_segment_bytes

NS = {"f": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}


def test_defaults_fill_an_empty_environment() -> None:
    env = apply_dds_defaults({})
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert Path(env[PROFILE_ENV]) == PROFILE_FILE and PROFILE_FILE.is_file()


@pytest.mark.parametrize("user", [
    {"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"},
    {PROFILE_ENV: "/etc/mine.xml"},
    {"FASTDDS_DEFAULT_PROFILES_FILE": "/etc/mine.xml"},
    {"FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"},
])
def test_a_users_own_settings_win(user: dict[str, str]) -> None:
    env = apply_dds_defaults(dict(user))
    for key, value in user.items():
        assert env[key] == value
    if "ROS_AUTOMATIC_DISCOVERY_RANGE" not in user:
        assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    if len(user) == 1 and "ROS_AUTOMATIC_DISCOVERY_RANGE" in user:
        assert env[PROFILE_ENV] == str(PROFILE_FILE)
    elif PROFILE_ENV not in user:
        assert PROFILE_ENV not in env


def test_node_processes_get_the_profile(tmp_path: Path) -> None:
    from roger_bringup.orchestrator import ros_environment

    env = ros_environment(tmp_path, 7, base={"PATH": "/usr/bin"})
    assert env["ROS_DOMAIN_ID"] == "7"
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert env[PROFILE_ENV] == str(PROFILE_FILE)


def test_profile_is_a_default_participant_profile_that_keeps_discovery_alone() -> None:
    root = ET.parse(PROFILE_FILE).getroot()
    participants = root.findall("f:participant", NS)
    assert [p.get("is_default_profile") for p in participants] == ["true"]
    rtps = participants[0].find("f:rtps", NS)
    assert rtps is not None
    # The range stays ROS_AUTOMATIC_DISCOVERY_RANGE's: no peers, locators or transport switch.
    for tag in ("builtin", "useBuiltinTransports", "defaultUnicastLocatorList"):
        assert rtps.find(f"f:{tag}", NS) is None, tag
    used = [t.text for t in rtps.findall("f:userTransports/f:transport_id", NS)]
    kinds = {d.findtext("f:transport_id", namespaces=NS): d.findtext("f:type", namespaces=NS)
             for d in root.findall("f:transport_descriptors/f:transport_descriptor", NS)}
    assert [kinds[t] for t in used] == ["SHM"]


def test_segment_holds_two_frame_bursts_at_256_px() -> None:
    """A frame burst (both float32 retinas + both label images) at 256 px, as sent."""
    from rclpy.serialization import serialize_message

    from roger_common.conversions import image_msg
    from roger_common.types import CameraModel, EyePose, StereoFrame
    from roger_sim.conversions import ground_truth_labels_msg

    size = 256
    rng = np.random.default_rng(0)
    img = rng.random((size, size), dtype=np.float32)
    labels = rng.integers(-1, 24, (size, size), dtype=np.int32)
    pose = EyePose(position=np.zeros(3), rotation=np.eye(3))
    frame = StereoFrame(stamp=1.0, goal_id=1, left=img, right=img,
                        camera=CameraModel(width=size, height=size, focal_px=200.0),
                        left_pose=pose, right_pose=pose, left_labels=labels,
                        right_labels=labels, label_names=tuple(f"o{i}" for i in range(24)))
    burst = sum(len(serialize_message(m)) for m in (
        image_msg(frame.left, 1.0, "l"), image_msg(frame.right, 1.0, "r"),
        ground_truth_labels_msg(frame)))
    # The default 512 KiB segment rmw_fastrtps gives is smaller than one burst: the reason
    # for the profile (if frames shrink below it, the profile can go).
    assert burst > 512 * 1024
    assert shm_segment_bytes() >= 2 * burst


def test_a_restart_profile_is_the_default_with_a_participant_id(tmp_path: Path) -> None:
    from roger_common.dds import profile_with_participant_id

    path = profile_with_participant_id(31, tmp_path / "p.xml")
    root = ET.parse(path).getroot()
    rtps = root.find("f:participant/f:rtps", NS)
    assert rtps is not None and rtps.findtext("f:participantID", namespaces=NS) == "31"
    # Nothing else changes: the same transports, the same segment.
    rtps.remove(rtps.find("f:participantID", NS))
    default = ET.parse(PROFILE_FILE).getroot()
    assert ET.tostring(root) == ET.tostring(default)
    assert shm_segment_bytes(path) == shm_segment_bytes()


def test_restart_ids_keep_every_port_valid_in_every_domain() -> None:
    from roger_common.dds import RESTART_PARTICIPANT_IDS, user_unicast_port

    # Domains 0-101 stay below Linux's ephemeral ports (32768), 215-232 below 65536.
    assert user_unicast_port(101, max(RESTART_PARTICIPANT_IDS)) < 32768
    assert user_unicast_port(232, max(RESTART_PARTICIPANT_IDS)) < 65536
    # Above the ids a graph's own processes get; below 32, the ids LOCALHOST discovery
    # announces to (two participants both at 32 or more never meet).
    assert min(RESTART_PARTICIPANT_IDS) >= 8 and max(RESTART_PARTICIPANT_IDS) < 32


def _graph(tmp_path: Path, env: dict[str, str]):
    from roger_bringup.orchestrator import STATE_DIR_ENV, Graph

    return Graph(tmp_path, dict(env, **{STATE_DIR_ENV: str(tmp_path / "state")}), {})


def test_each_restarted_node_gets_a_participant_id_of_its_own(tmp_path: Path,
                                                              monkeypatch) -> None:
    import roger_bringup.orchestrator as orch
    from roger_common.dds import RESTART_PARTICIPANT_IDS, user_unicast_port

    first = min(RESTART_PARTICIPANT_IDS)
    # The first id's port file exists: a participant of this domain has that id.
    monkeypatch.setattr(orch, "shm_files", lambda: {
        (f"fastrtps_port{user_unicast_port(9, first)}", 1),
        (f"fastrtps_port{user_unicast_port(8, first + 1)}", 2)})  # another domain's
    graph = _graph(tmp_path, orch.ros_environment(tmp_path, 9, base={}))
    ids = []
    for _ in range(3):
        env = graph.restart_env()
        root = ET.parse(env[PROFILE_ENV]).getroot()
        ids.append(int(root.findtext("f:participant/f:rtps/f:participantID", namespaces=NS)))
        assert env["ROS_DOMAIN_ID"] == "9"
    assert ids == [first + 1, first + 2, first + 3]
    assert graph.env[PROFILE_ENV] == str(PROFILE_FILE)  # the first processes' is unchanged


def test_a_users_own_profile_is_kept_on_restart(tmp_path: Path) -> None:
    import roger_bringup.orchestrator as orch

    env = orch.ros_environment(tmp_path, 9, base={PROFILE_ENV: "/etc/mine.xml"})
    assert _graph(tmp_path, env).restart_env()[PROFILE_ENV] == "/etc/mine.xml"
