"""``McapRecorder``: a node that records every documented topic of a run to one MCAP file.

Each topic of ``topics.TOPICS`` gets a raw subscription (the CDR bytes, never deserialized)
with the topic's durability (transient local for latched topics, so the world's ground truth
and the spatial map published before the recorder joined are recorded too) and a deep
history, and every message goes to a :class:`record.BagWriter` with its receive time as log
time and its source (publish) time as publish time. Add it to the executor of the
orchestrator (or of a test) next to the other nodes; ``close()`` finishes the file.

Run alone: ``python -m roger_bringup.recorder_node --ros-args -p path:=run.mcap``.
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
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from roger_bringup.record import RUN_METADATA, BagWriter
from roger_bringup.topics import TOPICS, Topic
from roger_common.dds import apply_dds_defaults
from roger_common.errors import RogerError

#: History depth of the recorder's subscriptions (a slow disk must not drop messages).
RECORD_DEPTH = 100


def record_qos(topic: Topic) -> QoSProfile:
    """Reliable, deep, and transient local for latched topics."""
    durability = (DurabilityPolicy.TRANSIENT_LOCAL if topic.qos == "latched"
                  else DurabilityPolicy.VOLATILE)
    return QoSProfile(depth=RECORD_DEPTH, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE, durability=durability)


class McapRecorder(Node):
    """Subscribes raw to every topic and writes what arrives to ``path`` (via ``.part``).

    Attributes:
        writer: The MCAP writer; ``writer.counts`` are the messages recorded per topic.
    """

    def __init__(self, path: Path | None = None, meta: dict[str, Any] | None = None,
                 topics: Sequence[Topic] = TOPICS, compression: str = "zstd",
                 **node_kwargs: Any) -> None:
        """Create the subscriptions and open the file.

        Args:
            path: The recording (``.mcap``); None reads the ``path`` parameter.
            meta: Run description (policy, world, seed) stored as metadata "roger_run",
                which ``roger replay`` puts into metrics.json.
            topics: Topics to record (default: all the documented ones).
            compression: Chunk compression: "zstd", "lz4" or "none".
            **node_kwargs: Passed to ``Node`` (``context=``, ``parameter_overrides=``...).

        Raises:
            RecordingError: The file cannot be created.
        """
        super().__init__("roger_recorder", **node_kwargs)
        self.declare_parameter("path", "run.mcap", ParameterDescriptor(
            description="MCAP file to record every documented topic into (written as "
                        "FILE.part, renamed when the recorder closes)"))
        target = Path(path) if path is not None else Path(str(self.get_parameter("path").value))
        self.writer = BagWriter(target, compression=compression)
        if meta:
            self.writer.add_metadata(RUN_METADATA, {k: str(v) for k, v in meta.items()})
        for topic in topics:
            self.writer.add_topic(topic.name, topic.type, topic.qos,
                                  depth=1 if topic.qos == "latched" else 10)
            self.create_subscription(topic.msg_class(), topic.name, self._writer_for(topic.name),
                                     record_qos(topic), raw=True)
        self._closed = False

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
        """Finish the file (summary, rename); later messages are ignored. Idempotent."""
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
        node.get_logger().info(f"recording {len(TOPICS)} topics to {node.writer.path}")
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
