"""ROS node plumbing shared by every Roger node: QoS profiles, parameters from the config
dataclasses, the heartbeat (``attach_heartbeat``, ``HeartbeatWatch``; the plain half, exit
codes and ``Silence``, is in ``roger_common.liveness``) and the ``main`` every node runs
(``spin_node``).

Message conversions are in ``conversions``; neither module is imported by core code.
"""

from __future__ import annotations

import inspect
import math
import os
import socket
import sys
import time
import traceback
from collections import deque
from collections.abc import Callable
from dataclasses import fields, replace
from typing import Any, TypeVar

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import remove_ros_args

from roger_common.configdoc import (
    config_fields,
    field_default,
    field_description,
    field_range,
    live_fields,
)
from roger_common.dds import apply_dds_defaults
from roger_common.errors import ConfigError, RogerError
from roger_common.liveness import (
    CRASH_EXIT,
    HEARTBEAT_PERIOD_S,
    HEARTBEAT_SUFFIX,
    HEARTBEAT_TOPIC,
    SETUP_EXIT,
    Silence,
    heartbeats,
    this_process,
)

#: Commands and state: reliable, depth 10 (house style).
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                      history=HistoryPolicy.KEEP_LAST)
#: Retinal images. Reliable rather than the sensor-data profile on purpose: every control
#: cycle waits for the stereo pair rendered after its goal, so a dropped pair would stall it.
IMAGES = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE,
                    history=HistoryPolicy.KEEP_LAST)
#: Ground-truth label images (scoring only): reliable and deep. A writer's KEEP_LAST history
#: drops samples its reader has not yet acknowledged, so with depth 5 a monitor that fell
#: 5 frames behind on a loaded machine lost a frame's labels and scored that cycle without
#: them (a rare test_graph_matches_core failure under `make test`).
LABELS = QoSProfile(depth=64, reliability=ReliabilityPolicy.RELIABLE,
                    history=HistoryPolicy.KEEP_LAST)
#: The per-cycle record (policy states, counters, convergence events): reliable and deep,
#: for the same reason as LABELS. With depth 10 a monitor that fell ten messages behind a
#: fast graph (30 cycles/s on an unseen world) lost a cycle's state: "1 cycles unrecorded"
#: in about one run in five of test_until_complete_on_an_unseen_world_visits_every_object.
REPORTS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                     history=HistoryPolicy.KEEP_LAST)
#: One-shot data (world description, spatial map, ground truth): latched.
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     history=HistoryPolicy.KEEP_LAST)

C = TypeVar("C")

#: IntegerRange bounds for an unbounded side (int64).
_INT64 = 2**63 - 1


def descriptor(config_cls: type, name: str, path: tuple[str, ...], owner: type,
               live: bool) -> ParameterDescriptor:
    """The ROS descriptor of one config field: its description, its range (read off the
    dataclass's validation, ``configdoc.field_range``) and ``read_only`` unless ``live``."""
    d = ParameterDescriptor(name=name, description=field_description(owner, path[-1]),
                            read_only=not live)
    bounds = field_range(config_cls, path)
    if bounds is not None:
        lo, hi = bounds
        if isinstance(_get(config_cls(), path), int):
            d.integer_range = [IntegerRange(
                from_value=-_INT64 if math.isinf(lo) else int(lo),
                to_value=_INT64 if math.isinf(hi) else int(hi), step=0)]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(lo),
                                                         to_value=float(hi), step=0.0)]
    return d


def _build(config_cls: type[C], values: dict[tuple[str, ...], Any]) -> C:
    """The dataclass with the leaf values by path (groups built recursively)."""
    kwargs: dict[str, Any] = {}
    groups: dict[str, dict[tuple[str, ...], Any]] = {}
    for path, value in values.items():
        if len(path) == 1:
            kwargs[path[0]] = value
        else:
            groups.setdefault(path[0], {})[path[1:]] = value
    for f in fields(config_cls):  # type: ignore[arg-type]
        if f.name in groups:
            kwargs[f.name] = _build(type(field_default(f)), groups[f.name])
    return config_cls(**kwargs)


def _replace(config: Any, path: tuple[str, ...], value: Any) -> Any:
    """A copy of ``config`` with the field at ``path`` set (validated at every level)."""
    if len(path) > 1:
        value = _replace(getattr(config, path[0]), path[1:], value)
    return replace(config, **{path[0]: value})


def _get(config: Any, path: tuple[str, ...]) -> Any:
    for step in path:
        config = getattr(config, step)
    return config


def declare_config(node: Node, config_cls: type[C], prefix: str = "",
                   overrides: dict[str, Any] | None = None,
                   apply: Callable[[C], None] | None = None) -> C:
    """Declare one ROS parameter per field of a frozen config dataclass, build it, and
    check every later change of those parameters against it.

    Values flow one way: ROS parameters -> config -> core. Tuple fields become arrays;
    nested config dataclasses become groups of dotted names (``config_fields``). Each
    parameter's description is its field's (``configdoc.field_description``). The
    dataclass's own validation (``__post_init__``) rejects bad values: at start the error
    reaches ``main``; at ``ros2 param set`` time the change is refused with its reason.
    Each descriptor also carries the field's range and ``read_only``: only a field that may
    change while running (``configdoc.live_fields``) of a node that passes ``apply`` is
    writable; its valid changes go to ``apply(new_config)``, and a value the dataclass
    refuses is refused with its reason. A value out of range at start (a params file, a
    ``-p`` override) raises ``ConfigError`` naming the parameter.

    Args:
        node: The node that owns the parameters.
        config_cls: A dataclass whose fields all have defaults.
        prefix: Prepended to each parameter name, e.g. ``"memory."``.
        overrides: Defaults to use instead of the dataclass's, by parameter name (still
            overridable by the user).
        apply: Takes the new config after a live change; None: nothing changes live.
    """
    params = config_fields(config_cls, prefix)
    values: dict[tuple[str, ...], Any] = {}
    for name, (path, owner, default) in params.items():
        if overrides and name in overrides:
            default = overrides[name]
        if isinstance(default, tuple):
            default = list(default)
        live = apply is not None and path[-1] in live_fields(owner)
        try:
            node.declare_parameter(name, default,
                                   descriptor(config_cls, name, path, owner, live))
        except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
            raise ConfigError(f"parameter {name}: {exc}") from exc
        value = node.get_parameter(name).value
        values[path] = tuple(value) if isinstance(default, list) else value
    current = [_build(config_cls, values)]

    def check(changed: list[Any]) -> SetParametersResult:
        mine = [p for p in changed if p.name in params]
        if not mine:
            return SetParametersResult(successful=True)
        new = current[0]
        try:
            for p in mine:
                value = tuple(p.value) if isinstance(p.value, list) else p.value
                new = _replace(new, params[p.name].path, value)
        except (ValueError, TypeError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        fixed = [p.name for p in mine if _get(new, params[p.name].path) !=
                 _get(current[0], params[p.name].path) and (
                     apply is None
                     or params[p.name].path[-1] not in live_fields(params[p.name].owner))]
        if fixed:
            return SetParametersResult(
                successful=False,
                reason=f"{', '.join(fixed)}: read at start only; restart the node to change it")
        if new != current[0]:
            assert apply is not None
            current[0] = new
            apply(new)
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(check)
    return current[0]


def attach_heartbeat(node: Any, period_s: float = HEARTBEAT_PERIOD_S) -> Any:
    """Publish a heartbeat of ``node``'s process from a wall-clock timer of ``node``.

    The timer runs in the node's executor, so the beats stop when the executor stops.
    Each beat is one DiagnosticStatus named ``"<node name>: heartbeat"`` with the process's
    host (``hardware_id``), ``pid``, beat count and the longest gap between two beats so
    far (how long the executor has been busy at worst).

    Returns:
        The timer.
    """
    host, pid = this_process()
    pub = node.create_publisher(DiagnosticArray, HEARTBEAT_TOPIC, RELIABLE)
    name = node.get_name() + HEARTBEAT_SUFFIX
    state = {"beat": 0, "last": time.monotonic(), "longest": 0.0}

    def beat() -> None:
        now = time.monotonic()
        if state["beat"]:
            state["longest"] = max(state["longest"], now - state["last"])
        state["beat"] += 1
        state["last"] = now
        msg = DiagnosticArray()
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.status = [DiagnosticStatus(
            level=DiagnosticStatus.OK, name=name, message="alive", hardware_id=host,
            values=[KeyValue(key="pid", value=str(pid)),
                    KeyValue(key="beat", value=str(state["beat"])),
                    KeyValue(key="longest_gap_s", value=f"{state['longest']:.3f}")])]
        pub.publish(msg)

    beat()
    return node.create_timer(period_s, beat, clock=Clock(clock_type=ClockType.STEADY_TIME))


class HeartbeatWatch:
    """Listens to ``/diagnostics`` on an existing node and keeps a ``Silence`` per process.

    It adds one subscription to ``node`` (the orchestrator's monitor) rather than a node of
    its own, so the graph the user sees does not change.
    """

    def __init__(self, node: Any, silence: Silence | None = None) -> None:
        self.silence = silence or Silence()
        self.host = socket.gethostname()
        node.create_subscription(DiagnosticArray, HEARTBEAT_TOPIC, self._on_msg, RELIABLE)

    def _on_msg(self, msg: Any) -> None:
        for key, name in heartbeats(msg):
            self.silence.heard(key, name)

    def silent_for(self, pid: int) -> float | None:
        """Seconds since the local process ``pid`` last beat; None if it never did."""
        return self.silence.silent_for((self.host, pid))

    def forget(self, pid: int) -> None:
        """Drop the local process ``pid`` (it was killed; its pid may be reused)."""
        self.silence.forget((self.host, pid))


#: Seconds between two warnings about unusable messages on one topic (the first comes at
#: once; those dropped in between are counted in the next).
BAD_INPUT_PERIOD_S = 10.0


class BadInput:
    """Drops unusable messages: one warning per topic naming it, then at most one every
    ``period_s`` seconds, so that a publisher flooding a topic with bad messages cannot
    flood the log (docs/reliability.md, "Bad input").

    Attributes:
        dropped: Messages dropped so far, per topic.
        lines: The last warnings given (newest last), for tests and post-mortems.
    """

    def __init__(self, node: Node, period_s: float = BAD_INPUT_PERIOD_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._logger = node.get_logger()
        self.period_s = period_s
        self._clock = clock
        self.dropped: dict[str, int] = {}
        self._held: dict[str, int] = {}
        self._last: dict[str, float] = {}
        self.lines: deque[str] = deque(maxlen=64)

    def drop(self, topic: str, reason: object) -> None:
        """Count a message of ``topic`` dropped for ``reason`` (an exception or text)."""
        self.dropped[topic] = self.dropped.get(topic, 0) + 1
        now = self._clock()
        last = self._last.get(topic)
        if last is not None and now - last < self.period_s:
            self._held[topic] = self._held.get(topic, 0) + 1
            return
        self._last[topic] = now
        held = self._held.pop(topic, 0)
        since = f" ({held} more dropped since the last warning)" if held else ""
        why = " ".join(str(reason).splitlines())
        line = f"{topic}: unusable message dropped: {why}{since}"
        self.lines.append(line)
        self._logger.warning(line)


def node_usage(factory: Any, prog: str) -> str:
    """What ``prog --help`` prints: the summary of the node's module and how to set its
    parameters."""
    doc = inspect.getdoc(sys.modules.get(getattr(factory, "__module__", ""))) or ""
    summary = doc.split("\n\n")[0]
    return (f"usage: {prog} [-h] [--ros-args [-p NAME:=VALUE ...] [--params-file FILE]]\n\n"
            f"{summary}\n\nEvery parameter, with its default and range: docs/parameters.md "
            "(or `ros2 param describe` on the running node).\n")


def spin_node(factory: Any, prog: str, args: list[str] | None = None,
              setup: Any = None) -> None:
    """The ``main`` of every Roger node: init, build, spin with a heartbeat
    (``attach_heartbeat``), shut down cleanly; exit with a telling status.

    * Ctrl-C (KeyboardInterrupt) and SIGTERM (ExternalShutdownException): quiet, status 0;
      also when SIGTERM lands while a callback runs: rclpy's handler shuts the context
      down, and the callback's next publish raises (``RCLError: publisher's context is
      invalid``). An exception raised once the context is shut down is that shutdown, not
      a crash (``roger chaos`` measured 15 of 48 SIGTERMs reported as crashes before).
    * A setup failure while building the node (RogerError, ValueError, OSError): one line
      ``prog: message``, no traceback, status ``SETUP_EXIT`` (2): "do not restart".
    * Any other exception, from a callback or from building the node: logged with its
      traceback, status ``CRASH_EXIT`` (70): "restart me".

    Args:
        factory: Callable returning the node (called after ``rclpy.init``).
        prog: Program name for the error line, e.g. ``"roger-sim"``.
        args: Command-line arguments for ``rclpy.init`` (None: sys.argv).
        setup: Optional callable run once before ``rclpy.init``.
    """
    argv = sys.argv if args is None else args
    if {"-h", "--help"} & set(remove_ros_args(args=argv)[1:]):
        # Before rclpy.init and the node: help needs no graph, world file or parameter.
        print(node_usage(factory, prog), end="")
        return
    if setup is not None:
        setup()
    apply_dds_defaults(os.environ)
    rclpy.init(args=args)
    node = None
    status = 0
    try:
        try:
            node = factory()
        except (RogerError, ValueError, OSError) as exc:
            print(f"{prog}: {exc}", file=sys.stderr)
            status = SETUP_EXIT
        if node is not None:
            attach_heartbeat(node)
            rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as exc:
        if node is not None and not node.context.ok():
            # Shut down (SIGTERM) while a callback ran: its next call into rcl raised.
            return
        status = CRASH_EXIT
        where = "a callback" if node is not None else "the node's construction"
        text = (f"{prog}: {where} raised {type(exc).__name__}: {exc}; exiting with status "
                f"{CRASH_EXIT} (an orchestrator restarts the node)\n"
                f"{traceback.format_exc().rstrip()}")
        if node is not None:
            node.get_logger().fatal(text)
        else:
            print(text, file=sys.stderr)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    if status:
        sys.exit(status)
