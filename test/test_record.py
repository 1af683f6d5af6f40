"""MCAP recording and replay (issue 10, item 2).

A short in-process run of the four nodes with the recorder in the same executor: the file
holds as many messages per topic as a counting listener saw, every message decodes with a
third-party decoder from the schemas alone, and ``replay`` rebuilds the cycle log and the
final counters of the run. Per-test Context, bounded spin_once loops, no bare sleeps.
"""

from __future__ import annotations

import csv
import json

import pytest
from conftest import WORLDS
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.serialization import serialize_message
from ros_helpers import TopicListener, ros_graph, spin_until

from roger_attention.attention_node import AttentionNode
from roger_bringup import msgdefs
from roger_bringup.evaluation import RunRecorder
from roger_bringup.monitor_logic import COUNTER_FIELDS, RunMonitor
from roger_bringup.record import (
    BagWriter,
    RecordingError,
    message_counts,
    read_messages,
    replay,
    run_metadata,
)
from roger_bringup.recorder_node import McapRecorder
from roger_bringup.topics import TOPICS
from roger_interfaces.msg import GroundTruth, GroundTruthLabels, Metrics, PolicyState
from roger_memory.memory_node import MemoryNode
from roger_perception.perception_node import PerceptionNode
from roger_sim.sim_node import SimNode

CYCLES = 6


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
        elif isinstance(msg, PolicyState):
            self.monitor.on_state(msg)
        elif isinstance(msg, Metrics):
            self.metrics.append(msg)
            self.monitor.on_metrics(msg)


def read_rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def record_run(tmp, domain_id):
    """One recorded run of CYCLES cycles: (mcap path, listener counts, live run folder)."""
    live = RunRecorder(tmp / "live", [], {"policy": "straightforward", "seed": 3})
    mcap_path = tmp / "run.mcap"
    with ros_graph(domain_id) as g:
        listener = g.add(Listener, RunMonitor(live))
        recorder = g.add(McapRecorder, mcap_path, meta={"policy": "straightforward", "seed": 3,
                                                        "world": "table1.yaml"})
        assert not mcap_path.exists() and recorder.writer.part.exists()
        g.add(SimNode, params=dict(world=str(WORLDS / "table1.yaml"), seed=3))
        g.add(PerceptionNode)
        g.add(MemoryNode, params=dict(memory_file=str(tmp / "ltm.pt")))
        g.add(AttentionNode, params=dict(policy="straightforward", max_cycles=CYCLES))
        assert spin_until(g.executor, lambda: any(m.done for m in listener.metrics), 120), \
            f"no completed run; counts {listener.counts}"
        assert spin_until(g.executor, lambda: recorder.counts == listener.counts, 10), \
            f"recorder {recorder.counts} vs listener {listener.counts}"
        recorder.close()
        listener.monitor.flush(force=True)
        live.close(0.0)
        counts = dict(listener.counts)
    return mcap_path, counts, tmp / "live"


def test_recorded_run_counts_schemas_and_replay(no_leaks, ros_domain, tmp_path):
    path, counts, live_dir = record_run(tmp_path, ros_domain)
    check_counts(path, counts)
    check_rosbag2_style_and_decoding(path)
    check_replay(path, live_dir, tmp_path / "replay")


def check_counts(path, counts):
    """The file holds what the listener saw, per topic."""
    assert path.exists() and not path.with_name(path.name + ".part").exists()
    recorded = message_counts(path)
    assert recorded == counts
    assert recorded["/roger/policy_state"] == CYCLES
    silent = [t.name for t in TOPICS if t.per_cycle and recorded[t.name] == 0]
    assert not silent, f"per-cycle topics recorded empty: {silent}"


def check_rosbag2_style_and_decoding(path):
    """Profile, schema names, channel metadata; a third-party decoder reads the messages."""
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        summary = reader.get_summary()
        assert header.profile == "ros2"
        names = {s.name for s in summary.schemas.values()}
        assert "roger_interfaces/msg/PolicyState" in names
        assert "sensor_msgs/msg/Image" in names
        for ch in summary.channels.values():
            assert ch.message_encoding == "cdr"
            assert "offered_qos_profiles" in ch.metadata
            assert ch.metadata["topic_type_hash"].startswith("RIHS01_")
        latched = next(c for c in summary.channels.values() if c.topic == "/roger/ground_truth")
        assert "transient_local" in latched.metadata["offered_qos_profiles"]
        states = [(m.decoded_message.cycle, m.decoded_message.state_before)
                  for m in reader.iter_decoded_messages(topics=["/roger/policy_state"])]
    assert [c for c, _ in states] == list(range(1, CYCLES + 1))
    assert states[0][1] == "000"
    assert run_metadata(path)["seed"] == "3"


def check_replay(path, live_dir, out):
    """Replay rebuilds the live monitor's cycle log, counters and scores, and the figures."""
    metrics = replay(path, out)
    live = json.loads((live_dir / "metrics.json").read_text())
    for key in COUNTER_FIELDS + ("objects_in_world", "objects_visited",
                                 "identification_precision", "novelty_precision"):
        assert metrics[key] == live[key], key
    assert metrics["cycles"] == CYCLES
    assert metrics["policy"] == "straightforward" and metrics["seed"] == 3
    assert read_rows(out / "cycles.csv") == read_rows(live_dir / "cycles.csv")
    for fig in ("fig4.png", "fig5.png", "fig6.png"):
        assert (out / fig).stat().st_size > 0


def test_bag_writer_round_trip_and_part_file(tmp_path):
    path = tmp_path / "one.mcap"
    writer = BagWriter(path, compression="none")
    writer.add_topic("/roger/policy_state", "roger_interfaces/PolicyState")
    msg = PolicyState(cycle=7, policy="qlearning", state_before="010", action=3,
                      outcome="mapped", td_error=float("nan"))
    writer.write("/roger/policy_state", serialize_message(msg), 1_000, 900)
    with pytest.raises(RecordingError):
        writer.write("/not/registered", b"", 1)
    assert not path.exists()
    writer.close()
    assert message_counts(path) == {"/roger/policy_state": 1}
    [(topic, back, log_time)] = list(read_messages(path))
    assert topic == "/roger/policy_state" and log_time == 1_000
    assert (back.cycle, back.policy, back.state_before, back.outcome) == \
        (7, "qlearning", "010", "mapped")


def test_unfinished_recording_is_refused(tmp_path):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + b"\0" * 20)
    with pytest.raises(RecordingError):
        message_counts(bad)


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
