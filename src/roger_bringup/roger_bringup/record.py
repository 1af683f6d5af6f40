"""Bags of a run, as ``ros2 bag record -s mcap`` writes them, and ``roger replay``.

Writing: :class:`BagWriter` puts serialized (CDR) messages into a rosbag2 bag: a folder
``DIR`` holding ``DIR/metadata.yaml`` and ``DIR/<name>_0.mcap`` (``<name>`` = the folder's
name), or, for a path ending in ``.mcap``, that one MCAP file alone. The MCAP file follows
rosbag2's MCAP storage plugin (the Jazzy default): profile ``ros2``, one schema per type
named ``pkg/msg/Type`` with encoding ``ros2msg`` and the complete message definition
(msgdefs), one channel per topic with message encoding ``cdr`` and the metadata
``offered_qos_profiles`` (the publishers' QoS, rosbag2 metadata version 9) and
``topic_type_hash``, and a ``rosbag2`` metadata record (``serialized_metadata``) when it
opens and when it closes. ``metadata.yaml`` is the one rosbag2_storage's YAML encoder
writes (version 9, yaml-cpp's layout). So ``ros2 bag info/play``, Foxglove and rosbags open
the folder, and the .mcap file alone too.

Crashes: the files carry their final names from the start, as rosbag2's do, and
``metadata.yaml`` is written (atomically) when the bag opens, again each time a chunk of
messages has reached the file, and at close. A run killed mid-way thus leaves a folder
that ``ros2 bag info`` reads, with the topics and the counts of the messages on disk, and
an MCAP file without its closing summary: Foxglove and ``ros2 bag play`` read it as it is,
``roger replay`` too (everything up to the cut), ``ros2 bag reindex DIR`` or
``mcap recover`` finish it for the other readers. The ROS side (subscribing to every
topic) is ``recorder_node.McapRecorder``.

Reading: :func:`message_counts`, :func:`read_messages` and :func:`replay`, which feeds the
recorded policy states, metrics and ground truth through the same monitor logic as a live
run (``monitor_logic.RunMonitor``) and rebuilds cycles.csv, metrics.json and Figures 4-6.
Each takes the bag folder or an .mcap file.
"""

from __future__ import annotations

import importlib
import json
import os
import re
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from mcap.reader import make_reader
from mcap.records import Channel, Header, Message, Schema
from mcap.records import Metadata as McapMetadata
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from roger_bringup import msgdefs
from roger_common import topics
from roger_common.atomic import atomic_write_bytes, sync_file
from roger_common.errors import RogerError
from roger_experiments.evaluation import RunRecorder

#: Metadata record with the run's policy, world and seed (read back by replay).
RUN_METADATA = "roger_run"
#: Key of RUN_METADATA holding the JSON {address: category} a run started with.
ADDRESS_CATEGORY = "address_category"
#: rosbag2 metadata version of Jazzy (QoS policies written by name: "reliable").
ROSBAG2_METADATA_VERSION = 9
#: The file rosbag2 describes a bag folder with.
METADATA_FILE = "metadata.yaml"
#: RMW_DURATION_INFINITE (sec, nsec) as rosbag2 writes it.
INFINITE = (9223372036, 854775807)
#: starting_time of a bag without messages (rosbag2 starts from the largest time point).
_NO_START = 2**63 - 1
#: Topics replay reads.
REPLAY_TOPICS: tuple[str, ...] = (topics.GROUND_TRUTH, topics.GROUND_TRUTH_LABELS,
                                  topics.CONVERGENCE, topics.POLICY_STATE,
                                  topics.METRICS)


class RecordingError(RogerError):
    """A recording cannot be written or read."""


@dataclass(frozen=True)
class OfferedQos:
    """One publisher's QoS as rosbag2 records it (``offered_qos_profiles``, version 9).

    Durations are (sec, nsec). The values are those the middleware reports for the
    publisher (``get_publishers_info_by_topic``), which is what rosbag2 stores: Fast DDS
    reports an unspecified deadline, lifespan or lease as infinite and the system-default
    liveliness as automatic.
    """

    history: str = "keep_last"
    depth: int = 10
    reliability: str = "reliable"
    durability: str = "volatile"
    deadline: tuple[int, int] = INFINITE
    lifespan: tuple[int, int] = INFINITE
    liveliness: str = "automatic"
    liveliness_lease_duration: tuple[int, int] = INFINITE
    avoid_ros_namespace_conventions: bool = False

    @classmethod
    def from_profile(cls, profile: Any) -> OfferedQos:
        """The QoS a publisher created with ``profile`` (an rclpy QoSProfile) offers."""
        def name(policy: Any, system_default: str) -> str:
            text = str(policy.name).lower()
            return system_default if text == "system_default" else text

        def duration(d: Any) -> tuple[int, int]:
            ns = int(d.nanoseconds)
            return INFINITE if ns <= 0 else (ns // 1_000_000_000, ns % 1_000_000_000)

        return cls(history=name(profile.history, "keep_last"), depth=int(profile.depth),
                   reliability=name(profile.reliability, "reliable"),
                   durability=name(profile.durability, "volatile"),
                   deadline=duration(profile.deadline), lifespan=duration(profile.lifespan),
                   liveliness=name(profile.liveliness, "automatic"),
                   liveliness_lease_duration=duration(profile.liveliness_lease_duration),
                   avoid_ros_namespace_conventions=bool(
                       profile.avoid_ros_namespace_conventions))

    def as_yaml_dict(self) -> dict[str, Any]:
        """rosbag2_storage's ``convert<rclcpp::QoS>::encode`` (version 9), as a dict."""
        def t(d: tuple[int, int]) -> dict[str, int]:
            return {"sec": d[0], "nsec": d[1]}
        return {"history": self.history, "depth": self.depth, "reliability": self.reliability,
                "durability": self.durability, "deadline": t(self.deadline),
                "lifespan": t(self.lifespan), "liveliness": self.liveliness,
                "liveliness_lease_duration": t(self.liveliness_lease_duration),
                "avoid_ros_namespace_conventions": self.avoid_ros_namespace_conventions}


# --- YAML as yaml-cpp emits it (the layout of rosbag2's own metadata.yaml) ---------------

_PLAIN = re.compile(r"[A-Za-z_/][A-Za-z0-9_./-]*")
# Plain words a YAML 1.1 reader (PyYAML, ruamel) would not take as a string.
_RESERVED = frozenset({"true", "false", "yes", "no", "on", "off", "y", "n", "null", "~"})


def _scalar(value: Any) -> str:
    # yaml-cpp writes any string it can as a plain scalar, "3" too; a string that a YAML
    # reader would take for a number or a boolean is quoted here instead, so that Python
    # readers get the string back (yaml-cpp reads both forms as the same string).
    if value is None:
        return "~"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, dict):
        return "{}" if not value else ""
    if isinstance(value, list):
        return "[]" if not value else ""
    text = str(value)
    if _PLAIN.fullmatch(text) and text.lower() not in _RESERVED:
        return text
    return json.dumps(text)  # a JSON string is a YAML double-quoted scalar


def yaml_lines(value: Mapping[str, Any] | Sequence[Any], indent: int = 0) -> list[str]:
    """A non-empty map or sequence in yaml-cpp's block style (sequences indented by 2)."""
    pad = " " * indent
    lines: list[str] = []
    if isinstance(value, Mapping):
        for key, item in value.items():
            if isinstance(item, (dict, list)) and item:
                lines.append(f"{pad}{key}:")
                lines += yaml_lines(item, indent + 2)
            else:
                lines.append(f"{pad}{key}: {_scalar(item)}")
        return lines
    for item in value:
        if isinstance(item, (dict, list)) and item:
            inner = yaml_lines(item, indent + 2)
            lines.append(f"{pad}- {inner[0][indent + 2:]}")
            lines += inner[1:]
        else:
            lines.append(f"{pad}- {_scalar(item)}")
    return lines


def qos_yaml(profiles: Sequence[OfferedQos]) -> str:
    """A channel's ``offered_qos_profiles``: rosbag2's ``serialize_rclcpp_qos_vector``."""
    if not profiles:
        return "[]"
    return "\n".join(yaml_lines([p.as_yaml_dict() for p in profiles]))


@dataclass
class _Topic:
    name: str
    type: str
    qos: tuple[OfferedQos, ...]
    type_hash: str
    count: int = 0


class BagWriter:
    """Writes serialized ROS 2 messages to a rosbag2 bag (a folder, or one .mcap file).

    Attributes:
        bag: What the user named: the bag folder, or the .mcap file.
        path: The MCAP file being written (``bag/<bag.name>_0.mcap`` for a folder).
        counts: Messages written per topic.
    """

    def __init__(self, bag: Path, compression: str = "zstd",
                 custom_data: Mapping[str, Any] | None = None) -> None:
        """Create the bag and write the MCAP header (and ``metadata.yaml`` for a folder).

        Args:
            bag: A folder to create (like ``ros2 bag record -o``), or a path ending in
                ``.mcap`` for one MCAP file. Neither may exist already (a non-empty
                folder or any file): a recording is never overwritten.
            compression: Chunk compression, "zstd", "lz4" or "none".
            custom_data: Strings for the bag's ``custom_data`` (the run's policy, world,
                seed), as ``ros2 bag record --custom-data`` stores them.

        Raises:
            RecordingError: The bag exists already, cannot be created, or the compression
                is unknown.
        """
        kinds = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                 "none": CompressionType.NONE}
        if compression not in kinds:
            raise RecordingError(f"compression must be one of {sorted(kinds)}, "
                                 f"got {compression!r}")
        self.bag = Path(bag)
        check_target(self.bag)
        self.folder = self.bag.suffix != ".mcap"
        self.path = self.bag / f"{self.bag.name}_0.mcap" if self.folder else self.bag
        self.custom_data = {str(k): str(v) for k, v in (custom_data or {}).items()}
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(self.path, "xb")  # noqa: SIM115 (closed in close())
        except OSError as exc:
            raise RecordingError(f"{self.path}: cannot create the recording ({exc})") from exc
        self._writer = Writer(self._fh, compression=kinds[compression])
        self._writer.start(profile="ros2", library="roger record (mcap python)")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._topics: dict[str, _Topic] = {}
        self._first_ns: int | None = None
        self._last_ns = 0
        # Counts and times of the messages that reached the file (the chunks sent out):
        # what metadata.yaml says while recording, so that after a crash it names no
        # message that is not there.
        self._on_disk: tuple[dict[str, int], int | None, int] = ({}, None, 0)
        self._closed = False
        self._mode = os.stat(self.path).st_mode & 0o777
        # rosbag2 writes the metadata when a bag opens and when it closes.
        self.add_metadata("rosbag2", {"serialized_metadata": self._serialized_metadata()})
        self._write_metadata_file()

    @property
    def counts(self) -> dict[str, int]:
        """Messages written per topic, in the order the topics were added."""
        return {name: t.count for name, t in self._topics.items()}

    def add_topic(self, topic: str, type_name: str,
                  qos: Sequence[OfferedQos] = (OfferedQos(),)) -> int:
        """Register a topic (and its type's schema once); returns the channel id.

        Args:
            topic: Topic name.
            type_name: ``pkg/msg/Type`` or ``pkg/Type``.
            qos: The QoS of the topic's publishers (one entry per publisher, as rosbag2
                records them; the Roger graph has one publisher a topic).
        """
        if topic in self._channels:
            return self._channels[topic]
        full = msgdefs.normalize(type_name)
        if full not in self._schemas:
            self._schemas[full] = self._writer.register_schema(
                name=full, encoding="ros2msg", data=msgdefs.full_definition(full).encode())
        entry = _Topic(topic, full, tuple(qos), msgdefs.type_hash(full))
        channel = self._writer.register_channel(
            topic=topic, message_encoding="cdr", schema_id=self._schemas[full],
            metadata={"offered_qos_profiles": qos_yaml(entry.qos),
                      "topic_type_hash": entry.type_hash})
        self._channels[topic] = channel
        self._topics[topic] = entry
        self._write_metadata_file(durable=False)
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
        entry = self._topics[topic]
        before = self._fh.tell()
        self._writer.add_message(
            channel_id=self._channels[topic], log_time=int(log_time_ns), data=bytes(data),
            publish_time=int(log_time_ns if publish_time_ns is None else publish_time_ns),
            sequence=entry.count)
        entry.count += 1
        t = int(log_time_ns)
        self._first_ns = t if self._first_ns is None else min(self._first_ns, t)
        self._last_ns = max(self._last_ns, t)
        if self._fh.tell() != before:
            # A chunk went out, with every message so far: hand it to the kernel (a killed
            # process then loses none of it) and let metadata.yaml count it.
            self._fh.flush()
            self._on_disk = (self.counts, self._first_ns, self._last_ns)
            self._write_metadata_file(durable=False)

    def add_metadata(self, name: str, data: Mapping[str, Any]) -> None:
        """A metadata record (string keys and values)."""
        self._writer.add_metadata(name, {str(k): str(v) for k, v in data.items()})

    def close(self) -> Path:
        """Write the rosbag2 metadata, the summary and ``metadata.yaml``; returns ``bag``."""
        if self._closed:
            return self.bag
        self._closed = True
        self.add_metadata("rosbag2", {"serialized_metadata": self._serialized_metadata()})
        self._writer.finish()
        self._fh.close()
        sync_file(self.path)  # the file and its folder entry
        self._write_metadata_file(durable=True)
        return self.bag

    def metadata(self) -> dict[str, Any]:
        """rosbag2_storage's BagMetadata as it stands (``convert<BagMetadata>::encode``).

        While recording, the counts and times are those of the messages in the file (the
        chunks sent out); once closed, of every message.
        """
        if self._closed:
            counts, first, last = self.counts, self._first_ns, self._last_ns
        else:
            counts, first, last = self._on_disk
        total = sum(counts.values())
        start = first if first is not None and total else _NO_START
        duration = last - start if total else 0
        name = self.path.name
        topics = [{"topic_metadata": {
            "name": t.name, "type": t.type, "serialization_format": "cdr",
            "offered_qos_profiles": [q.as_yaml_dict() for q in t.qos],
            "type_description_hash": t.type_hash}, "message_count": counts.get(t.name, 0)}
            for t in self._topics.values()]
        return {"version": ROSBAG2_METADATA_VERSION, "storage_identifier": "mcap",
                "duration": {"nanoseconds": duration},
                "starting_time": {"nanoseconds_since_epoch": start},
                "message_count": total, "topics_with_message_count": topics,
                "compression_format": "", "compression_mode": "",
                "relative_file_paths": [name],
                "files": [{"path": name, "starting_time": {"nanoseconds_since_epoch": start},
                           "duration": {"nanoseconds": duration}, "message_count": total}],
                "custom_data": dict(self.custom_data) or None, "ros_distro": "jazzy"}

    def _serialized_metadata(self) -> str:
        # rosbag2's MCAP plugin: YAML::Dump of the BagMetadata map (no trailing newline).
        return "\n".join(yaml_lines(self.metadata()))

    def _write_metadata_file(self, durable: bool = True) -> None:
        # Atomic, so a crash leaves the previous one; durable when the bag opens and closes
        # (in between the kernel flushes it, like the chunks).
        if not self.folder:
            return
        text = "\n".join(yaml_lines({"rosbag2_bagfile_information": self.metadata()}))
        try:
            atomic_write_bytes(self.bag / METADATA_FILE, text.encode() + b"\n", durable=durable)
            # The temporary file it renames is private (0600); a bag is shared like its
            # .mcap, which open() created with the usual mode.
            os.chmod(self.bag / METADATA_FILE, self._mode)
        except OSError as exc:
            raise RecordingError(f"{self.bag / METADATA_FILE}: cannot write ({exc})") from exc


def check_target(bag: Path) -> None:
    """Refuse to record over something: ``bag`` must not exist (or be an empty folder).

    Raises:
        RecordingError: Naming the path and the way out.
    """
    bag = Path(bag)
    if bag.suffix == ".mcap":
        if bag.exists():
            raise RecordingError(f"{bag}: exists already; a recording is never overwritten "
                                 f"(remove it or record to another name)")
        return
    if bag.is_file() or (bag.is_dir() and any(bag.iterdir())):
        raise RecordingError(f"{bag}: exists already and is not an empty folder; a recording "
                             f"is never overwritten (remove it or record to another folder)")


# --- Reading ---------------------------------------------------------------------------

def bag_files(bag: Path) -> list[Path]:
    """The MCAP files of a bag folder (from its metadata.yaml), or ``[bag]`` for a file.

    A folder without metadata.yaml (a rosbag2 recording that was killed) gives its
    ``*.mcap`` files in name order.

    Raises:
        RecordingError: Nothing readable there.
    """
    bag = Path(bag)
    if bag.is_file():
        return [bag]
    if not bag.is_dir():
        raise RecordingError(f"{bag}: no such bag folder or .mcap file")
    meta = bag / METADATA_FILE
    if meta.is_file():
        try:
            info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
            names = [str(n) for n in info["relative_file_paths"]]
            storage = info["storage_identifier"]
        except (yaml.YAMLError, KeyError, TypeError) as exc:
            raise RecordingError(f"{meta}: not a rosbag2 metadata file ({exc})") from exc
        if storage != "mcap":
            raise RecordingError(f"{bag}: storage {storage!r}; only mcap bags are read")
        files = [bag / Path(n).name for n in names]
    else:
        files = sorted(bag.glob("*.mcap"))
    if not files:
        raise RecordingError(f"{bag}: no MCAP file in this folder")
    missing = [f.name for f in files if not f.is_file()]
    if missing:
        raise RecordingError(f"{bag}: files named in {METADATA_FILE} are missing: "
                             f"{', '.join(missing)}")
    return files


def _summary(path: Path) -> Any:
    """The summary of a closed MCAP file; None for one cut off by a crash."""
    try:
        with open(path, "rb") as fh:
            summary = make_reader(fh).get_summary()
    except Exception:  # the mcap library raises several kinds of error for a cut file
        return None
    return summary if summary is not None and summary.statistics is not None else None


def _records_up_to_cut(path: Path) -> Iterator[Any]:
    """The records of an MCAP file in file order, up to where a crash cut it.

    Raises:
        RecordingError: Not an MCAP file at all (no header record).
    """
    with open(path, "rb") as fh:
        records = StreamReader(fh).records
        try:
            first = next(records)
        except Exception as exc:  # the mcap library raises several kinds of error
            raise RecordingError(f"{path}: not a readable MCAP file ({exc})") from exc
        if not isinstance(first, Header):
            raise RecordingError(f"{path}: not a readable MCAP file (no header record)")
        yield first
        while True:
            try:
                record = next(records)
            except StopIteration:
                return
            except Exception:  # the tail a crash cut: everything before it is kept
                return
            yield record


def is_complete(bag: Path) -> bool:
    """Whether every MCAP file of a bag was closed (has its summary)."""
    return all(_summary(path) is not None for path in bag_files(bag))


def message_counts(bag: Path) -> dict[str, int]:
    """Messages per topic of a recording (every channel, zero included).

    From each file's summary; a file cut off by a crash is counted record by record up
    to the cut.

    Raises:
        RecordingError: No readable MCAP file.
    """
    counts: dict[str, int] = {}
    for path in bag_files(bag):
        summary = _summary(path)
        if summary is not None:
            for ch in summary.channels.values():
                counts.setdefault(ch.topic, 0)
            for channel_id, n in summary.statistics.channel_message_counts.items():
                topic = summary.channels[channel_id].topic
                counts[topic] += int(n)
            continue
        topics: dict[int, str] = {}
        for record in _records_up_to_cut(path):
            if isinstance(record, Channel):
                topics[record.id] = record.topic
                counts.setdefault(record.topic, 0)
            elif isinstance(record, Message) and record.channel_id in topics:
                counts[topics[record.channel_id]] += 1
    return counts


def _raw_messages(path: Path, topics: Sequence[str] | None
                  ) -> Iterator[tuple[Schema | None, Channel, Message]]:
    """Messages of one file: in log-time order from the index, else in file order."""
    if _summary(path) is not None:
        with open(path, "rb") as fh:
            yield from make_reader(fh).iter_messages(
                topics=list(topics) if topics else None, log_time_order=True)
        return
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    for record in _records_up_to_cut(path):
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message) and record.channel_id in channels:
            channel = channels[record.channel_id]
            if not topics or channel.topic in topics:
                yield schemas.get(channel.schema_id), channel, record


def message_class(type_name: str) -> type:
    """The Python class of ``pkg/msg/Type`` (imports the message package)."""
    pkg, _, cls = msgdefs.normalize(type_name).split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), cls)


def read_messages(bag: Path, topics: tuple[str, ...] | None = None
                  ) -> Iterator[tuple[str, Any, int]]:
    """(topic, message object, log time ns) via rclpy's deserializer, file after file.

    Log-time order within a closed file; file order (the order received) in one a crash
    cut, up to the cut.
    """
    from rclpy.serialization import deserialize_message

    classes: dict[str, type] = {}
    for path in bag_files(bag):
        for schema, channel, message in _raw_messages(path, topics):
            if schema is None:
                raise RecordingError(f"{path}: channel {channel.topic} has no schema")
            if schema.name not in classes:
                classes[schema.name] = message_class(schema.name)
            yield channel.topic, deserialize_message(message.data, classes[schema.name]), \
                message.log_time


def run_metadata(bag: Path) -> dict[str, str]:
    """The RUN_METADATA record of a recording ({} when absent)."""
    for path in bag_files(bag):
        if _summary(path) is not None:
            with open(path, "rb") as fh:
                records = list(make_reader(fh).iter_metadata())
        else:
            records = [r for r in _records_up_to_cut(path) if isinstance(r, McapMetadata)]
        for record in records:
            if record.name == RUN_METADATA:
                return dict(record.metadata)
    return {}


def replay(bag: Path, out_dir: Path) -> dict[str, Any]:
    """Rebuild cycles.csv, metrics.json and Figures 4-6 of a recorded run.

    The recorded ground truth, label images, policy states and metrics go, in the order
    they were received, through the monitor logic of a live run, so the files equal those
    the run wrote (``wall_seconds`` is that of the replay).

    Args:
        bag: A recording made with ``roger run --record``: the bag folder or an .mcap
            file. One a crash cut off is replayed up to the cut, and metrics.json says
            ``"recording_complete": false``.
        out_dir: Folder for cycles.csv, metrics.json, fig4.png, fig5.png, fig6.png.

    Returns:
        The metrics written to metrics.json, plus ``message_counts``.

    Raises:
        RecordingError: The bag is unreadable or holds no policy state.
    """
    from roger_bringup.monitor_logic import RunMonitor
    from roger_experiments import plots
    from roger_experiments.results import RunResult, read_cycles

    t0 = time.monotonic()
    counts = message_counts(bag)
    # Metadata values are strings in MCAP; integers (seed, domain id) come back as such.
    meta: dict[str, Any] = {k: int(v) if v.lstrip("-").isdigit() else v
                            for k, v in run_metadata(bag).items()}
    meta["recording"] = str(bag)
    meta["recording_complete"] = is_complete(bag)
    # A run that loaded a long-term memory scored its identifications against the
    # categories stored with it (evaluation.truth_sidecar); the recorder may keep them.
    known = json.loads(meta.pop(ADDRESS_CATEGORY, "{}"))
    recorder = RunRecorder(Path(out_dir), [], meta)
    recorder.scorer.address_category = {
        int(a): (tuple(c) if c is not None else None) for a, c in known.items()}
    monitor = RunMonitor(recorder)
    handlers = {topics.GROUND_TRUTH: monitor.on_truth,
                topics.GROUND_TRUTH_LABELS: monitor.on_labels,
                topics.CONVERGENCE: monitor.on_convergence,
                topics.POLICY_STATE: monitor.on_state, topics.METRICS: monitor.on_metrics}
    policy = meta.get("policy")
    try:
        for topic, msg, _ in read_messages(bag, REPLAY_TOPICS):
            handlers[topic](msg)
            if topic == topics.METRICS and not policy:
                policy = msg.policy
    finally:
        monitor.flush(force=True)  # states whose labels were not recorded
        if policy:
            recorder.meta["policy"] = policy
        metrics = recorder.close(time.monotonic() - t0)
    if not recorder.rows:
        raise RecordingError(f"{bag}: no /roger/policy_state message recorded")
    result = RunResult(str(policy or "unknown"), int(meta.get("seed", 0)), metrics,
                       read_cycles(Path(out_dir) / "cycles.csv"))
    plots.fig4([result], Path(out_dir) / "fig4.png")
    plots.fig5([result], Path(out_dir) / "fig5.png")
    plots.fig6([result], Path(out_dir) / "fig6.png")
    (Path(out_dir) / "message_counts.json").write_text(json.dumps(counts, indent=2) + "\n")
    return {**metrics, "message_counts": counts}
