"""``FoxgloveBridge``: a live run in Foxglove, over a Foxglove WebSocket server.

The bridge does for a Roger graph what ``foxglove_bridge`` does in a ROS 2 install, with
the ``foxglove-sdk`` server (``roger run --foxglove [PORT]``, docs/view-record-gym.md):

- **Every topic, discovered.** Every half second it lists the graph's topics; each topic
  with a publisher gets a raw subscription (the CDR bytes, never deserialized) and a
  channel of the server with message encoding ``cdr``, schema encoding ``ros2msg``, the
  type's name ``pkg/msg/Type`` and its complete message definition (``msgdefs``, the
  text rosbag2 and ``roger run --record`` store), so Foxglove decodes it as it decodes a
  bag. The bytes go out unchanged. A topic whose type this Python cannot import (or whose
  .msg files are not installed) is left out, with one warning. The documented topics
  (``topics.TOPICS``) are advertised from the start, before any client connects (a
  channel advertised to a connected client can refuse its first subscription:
  foxglove-sdk 0.30.3 answers "Unknown channel ID"); others when they appear.
- **QoS as the publishers offer it.** Reliable unless a publisher is best effort,
  transient local when every publisher is (``subscription_qos``), depth 10.
- **Latched topics reach late clients.** Of a transient-local topic (``/robot_description``,
  ``/tf_static``, the ground truth, the spatial map and its markers) the bridge keeps the
  last message, and sends it again whenever a client subscribes to the channel. The
  server cannot address one client (foxglove-sdk 0.30's ``sink_id`` names the server, not
  a client), so the clients already subscribed get that message once more: harmless for
  data that is a state. One message per topic: each latched topic of the graph has one
  publisher.
- **Time.** With ``use_sim_time`` (as in a run) the server offers the ``time`` capability
  and broadcasts each ``/clock``, and messages carry the node's ROS time as log time, as
  foxglove_bridge does; the headers' stamps are simulated time too, so TF lookups and the
  plots agree.
- **Loopback.** The server listens on 127.0.0.1 unless told another address: it has no
  authentication, and whoever reaches it sees every topic.

In a run the orchestrator adds the node to its executor, like the recorder; alone:
``python -m roger_bringup.foxglove_node --ros-args -p port:=8765 -p use_sim_time:=true``.
"""

from __future__ import annotations

import importlib
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import foxglove
import rclpy
from foxglove.websocket import ChannelView, Client, ServerListener
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock as ClockMsg

from roger_bringup import msgdefs
from roger_bringup.topics import TOPICS, Topic
from roger_common import topics
from roger_common.dds import apply_dds_defaults
from roger_common.errors import RogerError

#: Foxglove's default port (the app's "Foxglove WebSocket" connection proposes it).
DEFAULT_PORT = 8765
#: Loopback only unless the user names another address.
DEFAULT_HOST = "127.0.0.1"
#: Wall seconds between two looks at the graph's topics.
DISCOVERY_PERIOD_S = 0.5
#: History depth of the bridge's subscriptions.
DEPTH = 10
#: Hosts that only this machine reaches.
LOOPBACK = frozenset({"127.0.0.1", "localhost", "::1"})
CLOCK_TOPIC = topics.CLOCK


class FoxgloveError(RogerError):
    """The Foxglove server cannot start (port taken, address not on this machine)."""


class _LatchedResend(ServerListener):
    """The server's listener: a client subscribing to a latched channel gets its last
    message.

    The server calls it from its own thread; it only reads ``last`` (a dict entry the
    executor's thread replaces whole), so no lock is needed.
    """

    def __init__(self) -> None:
        #: channel id -> (the channel, its last message, that message's log time).
        self.last: dict[int, tuple[foxglove.Channel, bytes, int]] = {}

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        """Send the channel's kept message, if it has one."""
        entry = self.last.get(channel.id)
        if entry is not None:
            entry[0].log(entry[1], log_time=entry[2])


@dataclass
class FoxgloveServer:
    """A running foxglove-sdk WebSocket server with its own context (its channels are
    nobody else's).

    Attributes:
        host: The address it listens on.
        port: The port it listens on (the system's choice when asked for port 0).
        sim_time: Whether it offers the ``time`` capability (broadcast from ``/clock``).
    """

    host: str
    port: int
    sim_time: bool
    _server: Any = field(repr=False)
    _context: Any = field(repr=False)
    _listener: _LatchedResend = field(repr=False)

    @classmethod
    def start(cls, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
              sim_time: bool = True) -> FoxgloveServer:
        """Listen on ``host:port`` (port 0: a free port the system picks).

        Raises:
            FoxgloveError: The port is out of range or taken, or ``host`` is not an address
                of this machine; one line naming it and the way out.
        """
        if not 0 <= int(port) <= 65535:
            raise FoxgloveError(f"foxglove: port {port} is not a TCP port (0-65535; 0 lets "
                                "the system pick a free one)")
        context = foxglove.Context()
        listener = _LatchedResend()
        capabilities = [foxglove.Capability.Time] if sim_time else []
        try:
            server = foxglove.start_server(name="roger", host=host, port=int(port),
                                           capabilities=capabilities, context=context,
                                           server_listener=listener)
        except RuntimeError as exc:
            reason = str(exc).removeprefix("FoxgloveError: ")
            hint = ("another server has that port: give another one (--foxglove PORT, or 0 "
                    "for any free port)" if "in use" in reason else
                    "give an address of this machine (--foxglove-host)")
            raise FoxgloveError(f"foxglove: cannot serve on {host}:{port}: {reason}; "
                                f"{hint}") from exc
        return cls(host, int(server.port), sim_time, server, context, listener)

    @property
    def url(self) -> str:
        """The address to give Foxglove ("Open connection", "Foxglove WebSocket")."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    @property
    def loopback(self) -> bool:
        """Whether only this machine can connect."""
        return self.host in LOOPBACK or self.host.startswith("127.")

    def channel(self, topic: str, type_name: str) -> foxglove.Channel:
        """A ``cdr`` channel of a ROS 2 type, its schema the complete message definition.

        Raises:
            MessageDefinitionError: The type's .msg files are not installed.
        """
        full = msgdefs.normalize(type_name)
        schema = foxglove.Schema(name=full, encoding="ros2msg",
                                 data=msgdefs.full_definition(full).encode())
        return foxglove.Channel(topic, schema=schema, message_encoding="cdr",
                                context=self._context)

    def log(self, channel: foxglove.Channel, data: bytes, log_time_ns: int,
            latched: bool = False) -> None:
        """Send a message to every subscribed client; a latched one is kept for later
        clients too."""
        if latched:
            self._listener.last[channel.id()] = (channel, data, log_time_ns)
        channel.log(data, log_time=log_time_ns)

    def broadcast_time(self, ns: int) -> None:
        """Tell the clients the graph's time (simulated time of ``/clock``)."""
        if self.sim_time:
            self._server.broadcast_time(ns)

    def stop(self) -> None:
        """Close every connection and the port. Idempotent."""
        self._server.stop()


def serving_line(server: FoxgloveServer, asked_port: int | None = None) -> str:
    """What ``roger run --foxglove`` prints: where to connect, and a warning when the
    server is reachable from other machines."""
    line = (f"  foxglove: {server.url} (Foxglove: Open connection, Foxglove WebSocket; "
            "layout: docs/foxglove-layout.json)")
    if asked_port == 0:
        line += f"; port {server.port} picked by the system (asked for 0)"
    if not server.loopback:
        line += (f"\n  foxglove: listening on {server.host}, not loopback: whoever reaches "
                 "this address sees every topic (no authentication)")
    return line


def subscription_qos(publishers: Sequence[QoSProfile]) -> QoSProfile:
    """A subscription that matches every publisher of a topic: reliable unless one offers
    best effort, transient local when all of them are (so it gets their latched message)."""
    best_effort = any(p.reliability == ReliabilityPolicy.BEST_EFFORT for p in publishers)
    latched = bool(publishers) and all(
        p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in publishers)
    return QoSProfile(
        depth=DEPTH, history=HistoryPolicy.KEEP_LAST,
        reliability=ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def message_class(type_name: str) -> Any:
    """The Python class of ``pkg/msg/Type`` (imports its package).

    Raises:
        ImportError, AttributeError: Not installed for this Python.
    """
    pkg, _, name = msgdefs.normalize(type_name).split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


class FoxgloveBridge(Node):
    """Forwards every topic of the graph to a Foxglove WebSocket server.

    Attributes:
        server: The server (started here unless given).
        counts: Messages forwarded per topic.
    """

    def __init__(self, server: FoxgloveServer | None = None,
                 documented: Sequence[Topic] = TOPICS, **node_kwargs: Any) -> None:
        """Advertise the documented topics, subscribe to what the graph has now and look
        again every DISCOVERY_PERIOD_S.

        Args:
            server: A server started by the caller (``roger run`` starts it before the
                graph, to say at once whether the port is free); None starts one on the
                ``host``/``port`` parameters. Either way ``destroy_node`` stops it.
            documented: Topics advertised at once, before any client connects (default:
                the graph's, ``topics.TOPICS``); others are advertised when they appear.
            **node_kwargs: Passed to ``Node`` (``context=``, ``parameter_overrides=``...).

        Raises:
            FoxgloveError: The server could not start.
        """
        super().__init__("roger_foxglove", **node_kwargs)
        self.declare_parameter("host", DEFAULT_HOST, ParameterDescriptor(
            description="address the Foxglove WebSocket server listens on (loopback by "
                        "default: the server has no authentication)", read_only=True))
        self.declare_parameter("port", DEFAULT_PORT, ParameterDescriptor(
            description="its TCP port (0: a free one, printed)", read_only=True))
        sim_time = bool(self.get_parameter("use_sim_time").value)
        self.server = server if server is not None else FoxgloveServer.start(
            str(self.get_parameter("host").value), int(self.get_parameter("port").value),
            sim_time=sim_time)
        self.counts: dict[str, int] = {}
        self._skipped: set[str] = set()
        # A channel made while a client is connected is advertised to it a moment before
        # foxglove-sdk 0.30.3 accepts subscriptions to it: a client that subscribes at once
        # (Foxglove does) may be refused ("Unknown channel ID") and then never gets that
        # topic. The graph's own topics are therefore advertised now, before any client.
        self._channels: dict[str, foxglove.Channel] = {}
        for topic in documented:
            try:
                self._channels[topic.name] = self.server.channel(topic.name, topic.type)
            except RogerError as exc:
                self.get_logger().warning(f"not advertising {topic.name}: {exc}")
        self._timer = self.create_timer(DISCOVERY_PERIOD_S, self.discover,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(f"serving the graph's topics on {self.server.url}")
        self.discover()

    def discover(self) -> list[str]:
        """Subscribe to each topic not forwarded yet that has a publisher; returns them."""
        added = []
        for name, types in self.get_topic_names_and_types():
            if name in self.counts or name in self._skipped:
                continue
            publishers = self.get_publishers_info_by_topic(name)
            if not publishers:
                continue  # a topic only subscribed to (yet): its QoS is unknown
            if len(types) != 1:
                self._skip(name, f"it has several types ({', '.join(types)})")
                continue
            try:
                cls = message_class(types[0])
                channel = self._channels.get(name) or self.server.channel(name, types[0])
            except (ImportError, AttributeError, RogerError) as exc:
                self._skip(name, f"{types[0]} is not installed here ({exc})")
                continue
            if channel.schema_name() != msgdefs.normalize(types[0]):
                self._skip(name, f"its type is {types[0]}, not {channel.schema_name()}")
                continue
            qos = subscription_qos([p.qos_profile for p in publishers])
            latched = qos.durability == DurabilityPolicy.TRANSIENT_LOCAL
            self.counts[name] = 0
            # rclpy passes the message info as a second argument to a callback that takes
            # two (its annotation says one argument only).
            forward = self._forwarder(name, channel, latched)
            self.create_subscription(cls, name, forward, qos, raw=True)  # type: ignore[arg-type]
            added.append(name)
        return added

    def _skip(self, name: str, why: str) -> None:
        self._skipped.add(name)
        self.get_logger().warning(f"not forwarding {name}: {why}")

    def _forwarder(self, name: str, channel: foxglove.Channel, latched: bool
                   ) -> Callable[[bytes, Any], None]:
        clock = name == CLOCK_TOPIC

        def on_message(data: bytes, info: Any) -> None:
            if clock:
                ns = _clock_ns(data)
                if ns is not None:
                    self.server.broadcast_time(ns)
            # The node's ROS time: simulated with use_sim_time (0 before the first /clock).
            self.server.log(channel, data, self.get_clock().now().nanoseconds, latched)
            self.counts[name] += 1
        return on_message

    def destroy_node(self) -> None:
        """Stop the server with the node."""
        self.server.stop()
        super().destroy_node()


def _clock_ns(data: bytes) -> int | None:
    """The time a serialized rosgraph_msgs/Clock carries, in nanoseconds."""
    try:
        msg = deserialize_message(data, ClockMsg)
    except Exception:  # rclpy raises several kinds of error for a bad payload
        return None
    return int(msg.clock.sec) * 1_000_000_000 + int(msg.clock.nanosec)


def main(args: list[str] | None = None) -> None:
    """Serve a running graph to Foxglove until Ctrl-C:
    ``python -m roger_bringup.foxglove_node --ros-args -p port:=8765``."""
    apply_dds_defaults(os.environ)
    rclpy.init(args=args)
    node = None
    try:
        node = FoxgloveBridge()
        print(f"roger-foxglove: {node.server.url} (Foxglove: Open connection, Foxglove "
              "WebSocket; layout docs/foxglove-layout.json)", flush=True)
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RogerError as exc:
        print(f"roger-foxglove: {exc}", file=sys.stderr)
        sys.exit(2)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
