"""``McapRecorder``: a node that records every documented topic of a run to a rosbag2 bag.

Each topic of ``topics.TOPICS`` gets a raw subscription (the CDR bytes, never deserialized)
with the topic's durability (transient local for latched topics, so the world's ground truth
and the spatial map published before the recorder joined are recorded too) and a deep
history, and every message goes to a :class:`record.BagWriter` with its receive time as log
time and its source (publish) time as publish time. The bag records, for each topic, the QoS
its publisher offers (the profile of ``topics.Topic.qos_profile``). Add the node to the
executor of the orchestrator (or of a test) next to the other nodes; ``close()`` finishes
the bag.

Run alone: ``python -m roger_bringup.recorder_node --ros-args -p path:=BAG_FOLDER``.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from roger_bringup.record import RUN_METADATA, BagWriter, OfferedQos
from roger_bringup.topics import TOPICS, Topic
from roger_common import topics
from roger_common.dds import apply_dds_defaults
from roger_common.errors import RogerError

#: History depth of the recorder's subscriptions (a slow disk must not drop messages).
RECORD_DEPTH = 100
#: The attention node starts its first cycle once ``wait_for_observers`` subscriptions
#: listen here (the orchestrator counts the recorder among them).
GATE_TOPIC = topics.POLICY_STATE
#: Publishers (``Topic.publisher``) that every run has: their topics are heard before the
#: gate opens.
GRAPH_PUBLISHERS = frozenset({"sim", "perception", "memory", "attention"})
#: Wall seconds after which the gate opens even if some publisher was never heard (a
#: recorder started by hand next to part of a graph); it says which.
GATE_TIMEOUT_S = 30.0


def record_qos(topic: Topic) -> QoSProfile:
    """Reliable, deep, and transient local for latched topics."""
    durability = (DurabilityPolicy.TRANSIENT_LOCAL if topic.qos == "latched"
                  else DurabilityPolicy.VOLATILE)
    return QoSProfile(depth=RECORD_DEPTH, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE, durability=durability)


def default_bag_name() -> str:
    """A new bag folder name, in rosbag2's style: ``roger_YYYY_MM_DD-HH_MM_SS``."""
    return time.strftime("roger_%Y_%m_%d-%H_%M_%S")


class McapRecorder(Node):
    """Subscribes raw to every topic and writes what arrives to the bag ``path``.

    The subscription to GATE_TOPIC comes last, once every other subscription has matched
    a publisher of the graph: the attention node waits for it before its first cycle, so
    nothing the simulator or the other nodes publish is missed. (With only a subscription
    to GATE_TOPIC to wait for, a 5-cycle run once finished before the simulator had
    matched the recorder, and the bag held no image at all.)

    Attributes:
        writer: The bag writer; ``writer.counts`` are the messages recorded per topic.
    """

    def __init__(self, path: Path | None = None, meta: dict[str, Any] | None = None,
                 topics: Sequence[Topic] = TOPICS, compression: str = "zstd",
                 **node_kwargs: Any) -> None:
        """Create the subscriptions and open the bag.

        Args:
            path: The bag: a folder to create (``metadata.yaml`` + ``<name>_0.mcap``), or a
                path ending in ``.mcap`` for that one file; None reads the ``path``
                parameter.
            meta: Run description (policy, world, seed) stored as metadata "roger_run",
                which ``roger replay`` puts into metrics.json, and as the bag's
                ``custom_data``.
            topics: Topics to record (default: all the documented ones).
            compression: Chunk compression: "zstd", "lz4" or "none".
            **node_kwargs: Passed to ``Node`` (``context=``, ``parameter_overrides=``...).

        Raises:
            RecordingError: The bag exists already or cannot be created.
        """
        super().__init__("roger_recorder", **node_kwargs)
        self.declare_parameter("path", "", ParameterDescriptor(
            description="bag to record every documented topic into: a folder (rosbag2 "
                        "layout, like ros2 bag record -o) or FILE.mcap; empty: "
                        "roger_YYYY_MM_DD-HH_MM_SS in the working folder"))
        target = Path(path) if path is not None else \
            Path(str(self.get_parameter("path").value) or default_bag_name())
        self.writer = BagWriter(target, compression=compression, custom_data=meta)
        if meta:
            self.writer.add_metadata(RUN_METADATA, {k: str(v) for k, v in meta.items()})
        self._waiting: dict[str, Any] = {}
        self._gate: Topic | None = None
        for topic in topics:
            self.writer.add_topic(topic.name, topic.type,
                                  [OfferedQos.from_profile(topic.qos_profile())])
            if topic.name == GATE_TOPIC:
                self._gate = topic
                continue
            sub = self._subscribe(topic)
            if topic.publisher in GRAPH_PUBLISHERS:
                self._waiting[topic.name] = sub
        self._closed = False
        self._gate_deadline = time.monotonic() + GATE_TIMEOUT_S
        self._gate_timer = self.create_timer(
            0.02, self._open_gate, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(f"recording {len(topics)} topics to {self.writer.bag}")

    def _subscribe(self, topic: Topic) -> Any:
        # rclpy passes the message info as a second argument to a callback that takes one
        # (its annotation says one argument only).
        return self.create_subscription(topic.msg_class(), topic.name,
                                        self._writer_for(topic.name),  # type: ignore[arg-type]
                                        record_qos(topic), raw=True)

    def _open_gate(self) -> None:
        unheard = [name for name, sub in self._waiting.items() if sub.get_publisher_count() == 0]
        if unheard and time.monotonic() < self._gate_deadline:
            return
        if unheard:
            self.get_logger().warning(f"no publisher after {GATE_TIMEOUT_S:.0f} s on "
                                      f"{', '.join(unheard)}; recording anyway")
        self._gate_timer.cancel()
        self.destroy_timer(self._gate_timer)
        if self._gate is not None:
            self._subscribe(self._gate)
            self._gate = None

    @property
    def gate_open(self) -> bool:
        """Whether every subscription exists (GATE_TOPIC's comes last)."""
        return self._gate is None

    @property
    def counts(self) -> dict[str, int]:
        """Messages recorded per topic."""
        return dict(self.writer.counts)

    def _writer_for(self, name: str) -> Callable[[bytes, Any], None]:
        def on_message(data: bytes, info: Any) -> None:
            # Two parameters: rclpy then passes the message info with its timestamps.
            if self._closed:
                return
            received = int(info.get("received_timestamp") or time.time_ns())
            self.writer.write(name, data, received, int(info.get("source_timestamp") or received))
        return on_message

    def close(self) -> Path:
        """Finish the bag (summary, metadata.yaml); later messages are ignored. Idempotent."""
        self._closed = True
        return self.writer.close()

    def destroy_node(self) -> None:
        """Close the recording with the node."""
        self.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Record the documented topics until Ctrl-C: ``python -m roger_bringup.recorder_node``."""
    apply_dds_defaults(os.environ)
    rclpy.init(args=args)
    node = None
    try:
        node = McapRecorder()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RogerError as exc:
        print(f"roger-recorder: {exc}", file=sys.stderr)
        sys.exit(2)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
