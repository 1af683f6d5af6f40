"""Bags of a run (rosbag2 layout) and replay (issue 10, item 2; issue 18, items 1 and 5).

A short in-process run of the four nodes with the recorder in the same executor: the bag
folder holds metadata.yaml and <name>_0.mcap as ``ros2 bag record -s mcap`` writes them,
as many messages per topic as a counting listener saw, the QoS each publisher really
offers (asked from the graph), and ``replay`` rebuilds the cycle log and the final
counters of the run from the folder and from the .mcap file alone. Unit tests pin the
message definitions (rosbag2's own test case), the metadata.yaml layout, the single-file
form, the refusal to overwrite, and what a killed recorder leaves. The independent readers
(rosbags, mcap-ros2-support, Foxglove's) are in test_bag_readers.py. Per-test Context,
bounded spin_once loops, no bare sleeps.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import textwrap

import pytest
import yaml
from conftest import REPO, WORLDS
from mcap.reader import make_reader
from rclpy.serialization import serialize_message
from ros_helpers import TopicListener, ros_graph, spin_until

from roger_attention.attention_node import AttentionNode
from roger_bringup import msgdefs
from roger_bringup.monitor_logic import COUNTER_FIELDS, RunMonitor
from roger_bringup.record import (
    BagWriter,
    OfferedQos,
    RecordingError,
    bag_files,
    is_complete,
    message_counts,
    read_messages,
    replay,
    run_metadata,
)
from roger_bringup.recorder_node import McapRecorder
from roger_bringup.run import RunOptions, run_graph
from roger_bringup.topics import TOPICS
from roger_experiments.evaluation import RunRecorder
from roger_interfaces.msg import (
    ConvergenceEvent,
    GroundTruth,
    GroundTruthLabels,
    Metrics,
    PolicyState,
)
from roger_memory.memory_node import MemoryNode
from roger_perception.perception_node import PerceptionNode
from roger_sim.sim_node import SimNode

CYCLES = 6
META = {"policy": "straightforward", "seed": 3, "world": "table1.yaml"}


class Listener(TopicListener):
    """Counts messages on every documented topic and scores the run like the live monitor."""

    def __init__(self, monitor: RunMonitor, **kwargs) -> None:
        super().__init__("test_record_listener", depth=100, **kwargs)
        self.monitor = monitor
        self.metrics: list[Metrics] = []

    def on_message(self, topic, msg) -> None:
        if isinstance(msg, GroundTruth):
            self.monitor.on_truth(msg)
        elif isinstance(msg, GroundTruthLabels):
            self.monitor.on_labels(msg)
        elif isinstance(msg, ConvergenceEvent):
            self.monitor.on_convergence(msg)
        elif isinstance(msg, PolicyState):
            self.monitor.on_state(msg)
        elif isinstance(msg, Metrics):
            self.metrics.append(msg)
            self.monitor.on_metrics(msg)


def read_rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def qos_dict(q, fill_defaults=False):
    """An rclpy QoSProfile in the bag's terms; ``fill_defaults`` as OfferedQos.from_profile."""
    if fill_defaults:
        return OfferedQos.from_profile(q).as_yaml_dict()

    def d(duration):
        ns = duration.nanoseconds
        return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}
    return {"history": q.history.name.lower(), "depth": q.depth,
            "reliability": q.reliability.name.lower(), "durability": q.durability.name.lower(),
            "deadline": d(q.deadline), "lifespan": d(q.lifespan),
            "liveliness": q.liveliness.name.lower(),
            "liveliness_lease_duration": d(q.liveliness_lease_duration),
            "avoid_ros_namespace_conventions": q.avoid_ros_namespace_conventions}


def offered_qos(graph, listener):
    """{topic: [QoS]} twice: as each publisher of the graph was created, and as the
    middleware reports it to others (``get_publishers_info_by_topic``, what rosbag2
    records; discovery carries no history, so that says "unknown", depth 0)."""
    names = {t.name for t in TOPICS}
    created: dict[str, list] = {}
    for node in graph.nodes:
        for pub in node.publishers:
            if pub.topic_name in names:
                created.setdefault(pub.topic_name, []).append(qos_dict(pub.qos_profile, True))
    reported = {name: [qos_dict(i.qos_profile) for i in
                       listener.get_publishers_info_by_topic(name)] for name in names}
    return created, {name: qos for name, qos in reported.items() if qos}


def record_run(tmp, domain_id, bag=None):
    """One recorded run of CYCLES cycles: (bag folder, listener counts, live run folder,
    publishers' QoS as offered_qos gives them)."""
    live = RunRecorder(tmp / "live", [], {"policy": "straightforward", "seed": 3})
    bag = bag or tmp / "bag"
    with ros_graph(domain_id) as g:
        listener = g.add(Listener, RunMonitor(live))
        recorder = g.add(McapRecorder, bag, meta=META)
        # The bag is a bag from the start: a killed run leaves one ros2 bag info reads.
        assert (bag / "metadata.yaml").is_file() and recorder.writer.path.is_file()
        g.add(SimNode, params=dict(world=str(WORLDS / "table1.yaml"), seed=3))
        g.add(PerceptionNode)
        g.add(MemoryNode, params=dict(memory_file=str(tmp / "ltm.pt")))
        # As in roger run: the first cycle waits for both observers (the recorder's
        # subscription to /roger/policy_state comes once it hears every publisher).
        g.add(AttentionNode, params=dict(policy="straightforward", max_cycles=CYCLES,
                                         wait_for_observers=2))
        assert spin_until(g.executor, lambda: any(m.done for m in listener.metrics), 120), \
            f"no completed run; counts {listener.counts}"
        assert spin_until(g.executor, lambda: recorder.counts == listener.counts, 10), \
            f"recorder {recorder.counts} vs listener {listener.counts}"
        offered = offered_qos(g, listener)
        recorder.close()
        listener.monitor.flush(force=True)
        live.close(0.0)
        counts = dict(listener.counts)
    return bag, counts, tmp / "live", offered


def test_recorded_run_counts_layout_qos_and_replay(no_leaks, ros_domain, tmp_path):
    bag, counts, live_dir, offered = record_run(tmp_path, ros_domain)
    check_counts(bag, counts)
    check_layout(bag, counts)
    check_qos(bag, offered)
    check_rosbag2_style(bag)
    check_replay(bag, live_dir, tmp_path / "replay")
    # The .mcap file alone replays too (what Foxglove users pass around).
    check_replay(bag / "bag_0.mcap", live_dir, tmp_path / "replay_file")


def check_counts(bag, counts):
    """The bag holds what the listener saw, per topic."""
    assert bag_files(bag) == [bag / "bag_0.mcap"] and is_complete(bag)
    recorded = message_counts(bag)
    assert recorded == counts
    assert recorded["/roger/policy_state"] == CYCLES
    silent = [t.name for t in TOPICS if t.per_cycle and recorded[t.name] == 0]
    assert not silent, f"per-cycle topics recorded empty: {silent}"


def check_layout(bag, counts):
    """metadata.yaml says what ``ros2 bag record -s mcap`` would: version 9, the file, the
    counts and times of the MCAP summary, the run in custom_data."""
    assert sorted(p.name for p in bag.iterdir()) == ["bag_0.mcap", "metadata.yaml"]
    # Readable by whoever may read the recording (the atomic write's temporary is 0600).
    assert (bag / "metadata.yaml").stat().st_mode == (bag / "bag_0.mcap").stat().st_mode
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert list(info) == ["version", "storage_identifier", "duration", "starting_time",
                          "message_count", "topics_with_message_count", "compression_format",
                          "compression_mode", "relative_file_paths", "files", "custom_data",
                          "ros_distro"]
    assert (info["version"], info["storage_identifier"], info["ros_distro"]) == \
        (9, "mcap", "jazzy")
    assert info["relative_file_paths"] == ["bag_0.mcap"]
    with open(bag / "bag_0.mcap", "rb") as fh:
        stats = make_reader(fh).get_summary().statistics
    start, duration = stats.message_start_time, stats.message_end_time - stats.message_start_time
    assert info["starting_time"] == {"nanoseconds_since_epoch": start}
    assert info["duration"] == {"nanoseconds": duration}
    assert info["message_count"] == sum(counts.values()) == stats.message_count
    assert info["files"] == [{"path": "bag_0.mcap",
                              "starting_time": {"nanoseconds_since_epoch": start},
                              "duration": {"nanoseconds": duration},
                              "message_count": sum(counts.values())}]
    assert {t["topic_metadata"]["name"]: t["message_count"]
            for t in info["topics_with_message_count"]} == counts
    for t in info["topics_with_message_count"]:
        meta = t["topic_metadata"]
        assert meta["type"].count("/msg/") == 1 and meta["serialization_format"] == "cdr"
        assert meta["type_description_hash"].startswith("RIHS01_")
    assert info["custom_data"] == {k: str(v) for k, v in META.items()}


def check_qos(bag, offered):
    """Each topic's recorded QoS is the one its publisher was created with (depth 5 for
    images, 1 and transient local for latched topics), which the middleware confirms
    (all but history and depth, which it does not know), in metadata.yaml and in the MCAP
    channel alike."""
    created, reported = offered
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    in_yaml = {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
               for t in info["topics_with_message_count"]}
    with open(bag / "bag_0.mcap", "rb") as fh:
        in_mcap = {c.topic: yaml.safe_load(c.metadata["offered_qos_profiles"])
                   for c in make_reader(fh).get_summary().channels.values()}
    assert in_yaml == in_mcap
    # Topics without a publisher in this run: the view (roger run --view), user edits and
    # the heartbeats (spin_node, the main of each node process, publishes them; the nodes
    # of this in-process graph are built without it).
    assert set(in_yaml) - set(created) == {"/roger/view", "/roger/world_edit", "/diagnostics"}
    assert set(reported) == set(created)
    for name, qos in created.items():
        assert in_yaml[name] == qos, name
        for recorded, seen in zip(in_yaml[name], reported[name], strict=True):
            assert (seen["history"], seen["depth"]) == ("unknown", 0)
            assert {k: v for k, v in recorded.items() if k not in ("history", "depth")} == \
                {k: v for k, v in seen.items() if k not in ("history", "depth")}, name
    depths = {t.qos: in_yaml[t.name][0]["depth"] for t in TOPICS}
    assert depths == {"reliable": 10, "images": 5, "labels": 64, "reports": 1000, "latched": 1}
    assert in_yaml["/roger/ground_truth"][0]["durability"] == "transient_local"


def check_rosbag2_style(bag):
    """Profile, schema names and definitions, channel metadata, the rosbag2 records."""
    with open(bag / "bag_0.mcap", "rb") as fh:
        reader = make_reader(fh)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        schemas = {s.name: s for s in summary.schemas.values()}
        assert "roger_interfaces/msg/PolicyState" in schemas and "sensor_msgs/msg/Image" in schemas
        for schema in schemas.values():
            assert schema.encoding == "ros2msg"
            assert schema.data.decode() == msgdefs.full_definition(schema.name)
            assert b"MSG: std_msgs/msg/" not in schema.data
        for ch in summary.channels.values():
            assert ch.message_encoding == "cdr"
            assert ch.metadata["topic_type_hash"].startswith("RIHS01_")
        records = [yaml.safe_load(m.metadata["serialized_metadata"])
                   for m in reader.iter_metadata() if m.name == "rosbag2"]
    # As rosbag2's writer: one record when the bag opened, one when it closed.
    assert len(records) == 2 and records[0]["message_count"] == 0
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert records[1] == info
    assert run_metadata(bag)["seed"] == "3"


def check_replay(bag, live_dir, out):
    """Replay rebuilds the live monitor's cycle log, counters and scores, and the figures."""
    metrics = replay(bag, out)
    live = json.loads((live_dir / "metrics.json").read_text())
    for key in COUNTER_FIELDS + ("objects_in_world", "objects_visited",
                                 "identification_precision", "novelty_precision"):
        assert metrics[key] == live[key], key
    assert metrics["cycles"] == CYCLES
    assert metrics["policy"] == "straightforward" and metrics["seed"] == 3
    assert metrics["recording_complete"] is True
    assert read_rows(out / "cycles.csv") == read_rows(live_dir / "cycles.csv")
    for fig in ("fig4.png", "fig5.png", "fig6.png"):
        assert (out / fig).stat().st_size > 0


def policy_state(cycle):
    return serialize_message(PolicyState(cycle=cycle, policy="qlearning", state_before="010",
                                         action=3, outcome="mapped", td_error=float("nan")))


def test_mcap_path_gives_one_file_that_reads_back(tmp_path):
    """A path ending in .mcap: that one file (no folder), under its final name at once."""
    path = tmp_path / "one.mcap"
    writer = BagWriter(path, compression="none")
    writer.add_topic("/roger/policy_state", "roger_interfaces/PolicyState")
    writer.write("/roger/policy_state", policy_state(7), 1_000, 900)
    with pytest.raises(RecordingError):
        writer.write("/not/registered", b"", 1)
    assert path.is_file() and writer.path == path
    assert writer.close() == path
    assert sorted(p.name for p in tmp_path.iterdir()) == ["one.mcap"]
    assert message_counts(path) == {"/roger/policy_state": 1}
    [(topic, back, log_time)] = list(read_messages(path))
    assert topic == "/roger/policy_state" and log_time == 1_000
    assert (back.cycle, back.policy, back.state_before, back.outcome) == \
        (7, "qlearning", "010", "mapped")


def test_a_recording_is_never_overwritten(tmp_path):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("")
    (tmp_path / "old.mcap").write_bytes(b"")
    for target in (tmp_path / "full", tmp_path / "old.mcap"):
        with pytest.raises(RecordingError, match="never overwritten"):
            BagWriter(target)
    (tmp_path / "empty").mkdir()
    BagWriter(tmp_path / "empty").close()  # an empty folder is fine (nothing to lose)
    assert (tmp_path / "empty" / "empty_0.mcap").is_file()


def test_roger_run_refuses_an_existing_bag_before_starting(tmp_path):
    bag = tmp_path / "bag"
    BagWriter(bag).close()
    opt = RunOptions(world=WORLDS / "table1.yaml", out=tmp_path / "out", record=bag)
    with pytest.raises(RecordingError, match="never overwritten"):
        run_graph(opt)
    assert not (tmp_path / "out" / "logs").exists()  # no node was started


def test_metadata_yaml_is_rosbag2s_layout(tmp_path):
    """The text yaml-cpp gives for rosbag2's BagMetadata (rosbag2_storage/yaml.hpp, qos.cpp)."""
    writer = BagWriter(tmp_path / "b", compression="none", custom_data={"seed": 3})
    writer.add_topic("/roger/policy_state", "roger_interfaces/msg/PolicyState",
                     [OfferedQos(depth=5)])
    writer.write("/roger/policy_state", policy_state(1), 1_000, 900)
    writer.write("/roger/policy_state", policy_state(2), 3_500, 3_400)
    writer.close()
    digest = msgdefs.type_hash("roger_interfaces/msg/PolicyState")
    qos = textwrap.dedent("""\
        - history: keep_last
          depth: 5
          reliability: reliable
          durability: volatile
          deadline:
            sec: 9223372036
            nsec: 854775807
          lifespan:
            sec: 9223372036
            nsec: 854775807
          liveliness: automatic
          liveliness_lease_duration:
            sec: 9223372036
            nsec: 854775807
          avoid_ros_namespace_conventions: false""")
    expected = textwrap.dedent("""\
        rosbag2_bagfile_information:
          version: 9
          storage_identifier: mcap
          duration:
            nanoseconds: 2500
          starting_time:
            nanoseconds_since_epoch: 1000
          message_count: 2
          topics_with_message_count:
            - topic_metadata:
                name: /roger/policy_state
                type: roger_interfaces/msg/PolicyState
                serialization_format: cdr
                offered_qos_profiles:
                  QOS
                type_description_hash: DIGEST
              message_count: 2
          compression_format: ""
          compression_mode: ""
          relative_file_paths:
            - b_0.mcap
          files:
            - path: b_0.mcap
              starting_time:
                nanoseconds_since_epoch: 1000
              duration:
                nanoseconds: 2500
              message_count: 2
          custom_data:
            seed: "3"
          ros_distro: jazzy
        """).replace("QOS", qos.replace("\n", "\n" + " " * 10)).replace("DIGEST", digest)
    assert (tmp_path / "b" / "metadata.yaml").read_text() == expected
    with open(tmp_path / "b" / "b_0.mcap", "rb") as fh:
        [channel] = make_reader(fh).get_summary().channels.values()
    assert channel.metadata["offered_qos_profiles"] == qos


# A recorder that is killed: it writes WRITTEN images of about 300 kB (the MCAP writer
# sends a chunk out every megabyte), then kills itself before closing.
KILLED_RECORDER = """
import os, signal, sys
from pathlib import Path
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Image
from roger_bringup.record import BagWriter
writer = BagWriter(Path(sys.argv[1]), compression="zstd")
writer.add_topic("/roger/left/image_raw", "sensor_msgs/msg/Image")
writer.add_topic("/roger/view", "sensor_msgs/msg/Image")
for i in range(int(sys.argv[2])):
    img = Image(height=1, width=300_000, encoding="mono8", step=300_000,
                data=os.urandom(300_000))
    img.header.frame_id = str(i)
    writer.write("/roger/left/image_raw", serialize_message(img), 1_000 + i)
os.kill(os.getpid(), signal.SIGKILL)
"""
WRITTEN = 10


def killed_recording(tmp_path):
    bag = tmp_path / "killed"
    proc = subprocess.run([sys.executable, "-c", KILLED_RECORDER, str(bag), str(WRITTEN)],
                          capture_output=True, text=True, timeout=120, cwd=REPO,
                          env=os.environ)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    return bag


def test_killed_recorder_leaves_a_readable_bag(tmp_path):
    """metadata.yaml names the topics and counts the messages that reached the file;
    replay's reader takes every one of them, up to the cut."""
    bag = killed_recording(tmp_path)
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert [t["topic_metadata"]["name"] for t in info["topics_with_message_count"]] == \
        ["/roger/left/image_raw", "/roger/view"]
    on_disk = info["message_count"]
    assert 0 < on_disk < WRITTEN  # the chunks sent out; the last one died with the process
    assert not is_complete(bag)
    counts = message_counts(bag)
    assert counts == {"/roger/left/image_raw": on_disk, "/roger/view": 0}
    frames = [msg.header.frame_id for _, msg, _ in read_messages(bag)]
    assert frames == [str(i) for i in range(on_disk)]


def test_unfinished_recording_is_refused(tmp_path):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + b"\0" * 20)
    with pytest.raises(RecordingError):
        message_counts(bad)
    with pytest.raises(RecordingError):
        message_counts(tmp_path / "missing")


def test_full_definition_is_rosbag2s(tmp_path, monkeypatch):
    """rosbag2_cpp's own test case (test_local_message_definition_source.cpp,
    can_find_msg_deps), then a Roger type: dependencies named as the fields spell them,
    sorted, each once, depth first."""
    share = tmp_path / "share" / "rosbag2_test_msgdefs" / "msg"
    share.mkdir(parents=True)
    (share / "ComplexMsg.msg").write_text("rosbag2_test_msgdefs/BasicMsg b\n")
    (share / "BasicMsg.msg").write_text("float32 c\n")
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path))
    msgdefs.find_file.cache_clear()
    msgdefs.full_definition.cache_clear()
    try:
        assert msgdefs.full_definition("rosbag2_test_msgdefs/ComplexMsg") == (
            "rosbag2_test_msgdefs/BasicMsg b\n"
            "\n"
            "================================================================================\n"
            "MSG: rosbag2_test_msgdefs/BasicMsg\n"
            "float32 c\n")
    finally:
        msgdefs.find_file.cache_clear()
        msgdefs.full_definition.cache_clear()
    text = msgdefs.full_definition("roger_interfaces/GroundTruthLabels")
    headers = [line for line in text.splitlines() if line.startswith("MSG: ")]
    assert headers == ["MSG: sensor_msgs/Image", "MSG: std_msgs/Header",
                       "MSG: builtin_interfaces/Time"]
    assert text.startswith(msgdefs.find_file("roger_interfaces/GroundTruthLabels").read_text())
    assert "\n\n" + "=" * 80 + "\nMSG: sensor_msgs/Image\n" in text
    with pytest.raises(msgdefs.MessageDefinitionError):
        msgdefs.full_definition("roger_interfaces/NoSuchType")
