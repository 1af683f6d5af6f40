"""MCAP recordings of a run, rosbag2 style, and ``roger replay`` (issue 10, item 2).

Writing: :class:`BagWriter` puts serialized (CDR) messages into an MCAP file with the
conventions of rosbag2's MCAP storage plugin, the default on Jazzy: profile ``ros2``, one
schema per type named ``pkg/msg/Type`` with encoding ``ros2msg`` and the complete message
definition (msgdefs), one channel per topic with message encoding ``cdr`` and the metadata
``offered_qos_profiles`` and ``topic_type_hash``, and a ``rosbag2`` metadata record. So
``ros2 bag info/play FILE.mcap`` and Foxglove open it. The file is written as
``FILE.mcap.part`` and renamed when closed: a crashed run leaves no half file under the
final name. The ROS side (subscribing to every topic) is ``recorder_node.McapRecorder``.

Reading: :func:`message_counts` and :func:`replay`, which feeds the recorded policy states,
metrics and ground truth through the same monitor logic as a live run
(``monitor_logic.RunMonitor``) and rebuilds cycles.csv, metrics.json and Figures 4-6.
"""

from __future__ import annotations

import importlib
import json
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from roger_bringup import msgdefs
from roger_bringup.evaluation import RunRecorder
from roger_common.errors import RogerError

#: Metadata record with the run's policy, world and seed (read back by replay).
RUN_METADATA = "roger_run"
#: Key of RUN_METADATA holding the JSON {address: category} a run started with.
ADDRESS_CATEGORY = "address_category"
#: rosbag2 metadata version whose QoS profiles are written with names ("reliable").
ROSBAG2_METADATA_VERSION = 9
#: RMW_DURATION_INFINITE as rosbag2 writes it.
_INFINITE = {"sec": 9223372036, "nsec": 854775807}
#: Topics replay reads.
REPLAY_TOPICS: tuple[str, ...] = ("/roger/ground_truth", "/roger/ground_truth/labels",
                                  "/roger/policy_state", "/roger/metrics")


class RecordingError(RogerError):
    """A recording cannot be written or read."""


def qos_yaml(qos: str, depth: int) -> str:
    """``offered_qos_profiles`` of a channel (rosbag2 metadata version 9 YAML).

    Args:
        qos: The topic's QoS profile name in topics.TOPICS: "reliable", "images" or
            "latched" (transient local).
        depth: History depth of the publisher.
    """
    durability = "transient_local" if qos == "latched" else "volatile"
    inf = f"\n    sec: {_INFINITE['sec']}\n    nsec: {_INFINITE['nsec']}"
    return (f"- history: keep_last\n  depth: {depth}\n  reliability: reliable\n"
            f"  durability: {durability}\n  deadline:{inf}\n  lifespan:{inf}\n"
            f"  liveliness: automatic\n  liveliness_lease_duration:{inf}\n"
            f"  avoid_ros_namespace_conventions: false\n")


class BagWriter:
    """Writes serialized ROS 2 messages to ``path`` via ``path.part``.

    Attributes:
        path: The final file name.
        counts: Messages written per topic.
    """

    def __init__(self, path: Path, compression: str = "zstd") -> None:
        """Open ``path.part`` and write the MCAP header.

        Args:
            path: Final file name (``.mcap``).
            compression: Chunk compression, "zstd", "lz4" or "none".

        Raises:
            RecordingError: The file cannot be created or the compression is unknown.
        """
        kinds = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                 "none": CompressionType.NONE}
        if compression not in kinds:
            raise RecordingError(f"compression must be one of {sorted(kinds)}, "
                                 f"got {compression!r}")
        self.path = Path(path)
        self.part = self.path.with_name(self.path.name + ".part")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(self.part, "wb")  # noqa: SIM115 (closed in close())
        except OSError as exc:
            raise RecordingError(f"{self.part}: cannot create the recording ({exc})") from exc
        self._writer = Writer(self._fh, compression=kinds[compression])
        self._writer.start(profile="ros2", library="roger record (mcap python)")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._types: dict[str, str] = {}
        self.counts: dict[str, int] = {}
        self._first_ns: int | None = None
        self._last_ns = 0
        self._closed = False

    def add_topic(self, topic: str, type_name: str, qos: str = "reliable",
                  depth: int = 10) -> int:
        """Register a topic (and its type's schema once); returns the channel id."""
        if topic in self._channels:
            return self._channels[topic]
        full = msgdefs.normalize(type_name)
        if full not in self._schemas:
            self._schemas[full] = self._writer.register_schema(
                name=full, encoding="ros2msg", data=msgdefs.full_definition(full).encode())
        channel = self._writer.register_channel(
            topic=topic, message_encoding="cdr", schema_id=self._schemas[full],
            metadata={"offered_qos_profiles": qos_yaml(qos, depth),
                      "topic_type_hash": msgdefs.type_hash(full)})
        self._channels[topic] = channel
        self._types[topic] = full
        self.counts[topic] = 0
        return channel

    def write(self, topic: str, data: bytes, log_time_ns: int,
              publish_time_ns: int | None = None) -> None:
        """Write one CDR-serialized message of a registered topic.

        Raises:
            RecordingError: The topic was not registered, or the writer is closed.
        """
        if self._closed:
            raise RecordingError(f"{self.path}: write after close")
        if topic not in self._channels:
            raise RecordingError(f"{self.path}: topic {topic} was not registered")
        self._writer.add_message(
            channel_id=self._channels[topic], log_time=int(log_time_ns), data=bytes(data),
            publish_time=int(log_time_ns if publish_time_ns is None else publish_time_ns),
            sequence=self.counts[topic])
        self.counts[topic] += 1
        if self._first_ns is None:
            self._first_ns = int(log_time_ns)
        self._last_ns = max(self._last_ns, int(log_time_ns))

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record (string keys and values)."""
        self._writer.add_metadata(name, {str(k): str(v) for k, v in data.items()})

    def close(self) -> Path:
        """Write the rosbag2 metadata and the summary, then rename ``.part`` to ``path``."""
        if self._closed:
            return self.path
        self._closed = True
        self.add_metadata("rosbag2", {"serialized_metadata": self._rosbag2_metadata()})
        self._writer.finish()
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self._fh.close()
        os.replace(self.part, self.path)
        return self.path

    def _rosbag2_metadata(self) -> str:
        # The storage plugin rebuilds topics and counts from the summary; this record
        # mainly says which metadata version the QoS strings follow.
        start = self._first_ns or time.time_ns()
        total = sum(self.counts.values())
        return (f"version: {ROSBAG2_METADATA_VERSION}\nstorage_identifier: mcap\n"
                f"duration:\n  nanoseconds: {self._last_ns - start if total else 0}\n"
                f"starting_time:\n  nanoseconds_since_epoch: {start}\n"
                f"message_count: {total}\ntopics_with_message_count: []\n"
                f"compression_format: \"\"\ncompression_mode: \"\"\n"
                f"relative_file_paths:\n  - {self.path.name}\nfiles: []\n"
                f"custom_data: ~\nros_distro: jazzy\n")


def message_counts(mcap_path: Path) -> dict[str, int]:
    """Messages per topic of a recording (every channel, zero included), from its summary.

    Raises:
        RecordingError: The file is missing or not a finished MCAP file.
    """
    try:
        with open(mcap_path, "rb") as fh:
            summary = make_reader(fh).get_summary()
    except Exception as exc:  # the mcap library raises several kinds of error
        raise RecordingError(f"{mcap_path}: not a readable MCAP file ({exc})") from exc
    if summary is None or summary.statistics is None:
        raise RecordingError(f"{mcap_path}: no summary (the recording was not closed)")
    counts = {ch.topic: 0 for ch in summary.channels.values()}
    for channel_id, n in summary.statistics.channel_message_counts.items():
        counts[summary.channels[channel_id].topic] = int(n)
    return counts


def message_class(type_name: str) -> type:
    """The Python class of ``pkg/msg/Type`` (imports the message package)."""
    pkg, _, cls = msgdefs.normalize(type_name).split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), cls)


def read_messages(mcap_path: Path, topics: tuple[str, ...] | None = None
                  ) -> Iterator[tuple[str, Any, int]]:
    """(topic, message object, log time ns) in log-time order, via rclpy's deserializer."""
    from rclpy.serialization import deserialize_message

    classes: dict[str, type] = {}
    with open(mcap_path, "rb") as fh:
        reader = make_reader(fh)
        for schema, channel, message in reader.iter_messages(
                topics=list(topics) if topics else None, log_time_order=True):
            if schema is None:
                raise RecordingError(f"{mcap_path}: channel {channel.topic} has no schema")
            if schema.name not in classes:
                classes[schema.name] = message_class(schema.name)
            yield channel.topic, deserialize_message(message.data, classes[schema.name]), \
                message.log_time


def run_metadata(mcap_path: Path) -> dict[str, str]:
    """The RUN_METADATA record of a recording ({} when absent)."""
    with open(mcap_path, "rb") as fh:
        for record in make_reader(fh).iter_metadata():
            if record.name == RUN_METADATA:
                return dict(record.metadata)
    return {}


def replay(mcap_path: Path, out_dir: Path) -> dict[str, Any]:
    """Rebuild cycles.csv, metrics.json and Figures 4-6 of a recorded run.

    The recorded ground truth, label images, policy states and metrics go, in the order
    they were received, through the monitor logic of a live run, so the files equal those
    the run wrote (``wall_seconds`` is that of the replay).

    Args:
        mcap_path: A recording made with ``roger run --record``.
        out_dir: Folder for cycles.csv, metrics.json, fig4.png, fig5.png, fig6.png.

    Returns:
        The metrics written to metrics.json, plus ``message_counts``.

    Raises:
        RecordingError: The file is unreadable or holds no policy state.
    """
    from roger_bringup import plots
    from roger_bringup.compare import RunResult, read_cycles
    from roger_bringup.monitor_logic import RunMonitor

    t0 = time.monotonic()
    counts = message_counts(mcap_path)
    # Metadata values are strings in MCAP; integers (seed, domain id) come back as such.
    meta: dict[str, Any] = {k: int(v) if v.lstrip("-").isdigit() else v
                            for k, v in run_metadata(mcap_path).items()}
    meta["recording"] = str(mcap_path)
    # A run that loaded a long-term memory scored its identifications against the
    # categories stored with it (evaluation.truth_sidecar); the recorder may keep them.
    known = json.loads(meta.pop(ADDRESS_CATEGORY, "{}"))
    recorder = RunRecorder(Path(out_dir), [], meta)
    recorder.scorer.address_category = {
        int(a): (tuple(c) if c is not None else None) for a, c in known.items()}
    monitor = RunMonitor(recorder)
    handlers = {"/roger/ground_truth": monitor.on_truth,
                "/roger/ground_truth/labels": monitor.on_labels,
                "/roger/policy_state": monitor.on_state, "/roger/metrics": monitor.on_metrics}
    policy = meta.get("policy")
    try:
        for topic, msg, _ in read_messages(mcap_path, REPLAY_TOPICS):
            handlers[topic](msg)
            if topic == "/roger/metrics" and not policy:
                policy = msg.policy
    finally:
        monitor.flush(force=True)  # states whose labels were not recorded
        if policy:
            recorder.meta["policy"] = policy
        metrics = recorder.close(time.monotonic() - t0)
    if not recorder.rows:
        raise RecordingError(f"{mcap_path}: no /roger/policy_state message recorded")
    result = RunResult(str(policy or "unknown"), int(meta.get("seed", 0)), metrics,
                       read_cycles(Path(out_dir) / "cycles.csv"))
    plots.fig4([result], Path(out_dir) / "fig4.png")
    plots.fig5([result], Path(out_dir) / "fig5.png")
    plots.fig6([result], Path(out_dir) / "fig6.png")
    (Path(out_dir) / "message_counts.json").write_text(json.dumps(counts, indent=2) + "\n")
    return {**metrics, "message_counts": counts}
