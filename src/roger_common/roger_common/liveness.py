"""How a Roger node says it is alive, and how it ends: exit codes and a heartbeat.

Every node started through ``spin_node`` (the ``main`` of each node) publishes a heartbeat,
a ``diagnostic_msgs/DiagnosticArray`` on ``/diagnostics``, from a wall-clock
(``STEADY_TIME``) timer in its own executor. A beat therefore means "this process's
executor turns", which is what answering the graph needs: a process that is stopped
(``kill -STOP``), deadlocked, or stuck in one endless callback falls silent, while DDS's own
threads would keep an ``AUTOMATIC`` liveliness lease alive in the last two cases. The
orchestrator listens (``HeartbeatWatch`` on its monitor node) and kills and restarts a node
silent for longer than ``HANG_TIMEOUT_S`` (docs/reliability.md says why that value).

The module imports without ROS (the orchestrator's plain half uses the constants and
``Silence``); what touches ROS imports rclpy when called, as ``spin_node`` always did.
"""

from __future__ import annotations

import os
import socket
import sys
import time
import traceback
from collections.abc import Callable, Hashable
from typing import Any

#: Exit status of a node that refused its setup (bad world, parameter or memory file):
#: restarting it would fail again, so the orchestrator ends the run with its one line.
SETUP_EXIT = 2
#: Exit status of a node whose callback raised after setup (``EX_SOFTWARE`` of sysexits.h):
#: a bug or a transient fault; the orchestrator restarts the node like any other death.
CRASH_EXIT = 70
#: Topic of the heartbeat (the standard diagnostics topic, so ``ros2 topic echo
#: /diagnostics`` and rqt_robot_monitor show it).
HEARTBEAT_TOPIC = "/diagnostics"
#: Wall seconds between two beats of a node.
HEARTBEAT_PERIOD_S = 0.5
#: Suffix of the DiagnosticStatus name of a heartbeat: ``"roger_sim: heartbeat"``.
HEARTBEAT_SUFFIX = ": heartbeat"
#: Wall seconds of silence after which the orchestrator declares a node unresponsive.
#: A node's executor is legitimately busy for up to a second or two on a loaded two-core
#: machine (a memory store retrains the network, a haptic goal runs ~0.2 s of physics), so
#: this is four times that. A node that stops is caught this long after its last beat.
HANG_TIMEOUT_S = 8.0

#: Who a beat comes from: (host, pid), unique even across machines.
Key = tuple[str, int]


class Silence:
    """Wall seconds since each process was last heard from, blind to the watcher's stalls.

    ``tick`` is called at every turn of the watcher's loop. A turn that comes late (the
    watcher itself was stopped, swapped out or busy) moves every last-heard time forward by
    the delay, so that no node is blamed for silence the watcher could not hear.
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic,
                 own_stall_s: float = 1.0) -> None:
        self._clock = clock
        self._own_stall_s = own_stall_s
        self._last: dict[Hashable, float] = {}
        self._names: dict[Hashable, str] = {}
        self._tick = clock()
        #: Longest silence between two beats of one process, by the name it gave (s).
        self.longest: dict[str, float] = {}
        #: Longest late turn of the watcher's own loop (s): what it discounted.
        self.own_longest_stall = 0.0

    def tick(self) -> None:
        """Mark a turn of the watcher's loop (discounting its own stalls)."""
        now = self._clock()
        late = now - self._tick
        if self._last:
            self.own_longest_stall = max(self.own_longest_stall, late)
        if late > self._own_stall_s:
            for key in self._last:
                self._last[key] += late
        self._tick = now

    def heard(self, key: Hashable, name: str = "") -> None:
        """A beat from ``key`` just arrived."""
        now = self._clock()
        if key in self._last:
            gap = now - self._last[key]
            self.longest[name] = max(self.longest.get(name, 0.0), gap)
        self._last[key] = now
        self._names[key] = name

    def silent_for(self, key: Hashable) -> float | None:
        """Seconds since ``key`` was last heard from; None if it was never heard from."""
        last = self._last.get(key)
        return None if last is None else self._clock() - last

    def forget(self, key: Hashable) -> None:
        """Drop a process that ended (its pid may be reused)."""
        self._last.pop(key, None)
        self._names.pop(key, None)


def this_process() -> Key:
    """The key of the calling process."""
    return (socket.gethostname(), os.getpid())


def attach_heartbeat(node: Any, period_s: float = HEARTBEAT_PERIOD_S) -> Any:
    """Publish a heartbeat of ``node``'s process from a wall-clock timer of ``node``.

    The timer runs in the node's executor, so the beats stop when the executor stops.
    Each beat is one DiagnosticStatus named ``"<node name>: heartbeat"`` with the process's
    host (``hardware_id``), ``pid``, beat count and the longest gap between two beats so
    far (how long the executor has been busy at worst).

    Returns:
        The timer.
    """
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rclpy.clock import Clock, ClockType

    from roger_common.ros_node import RELIABLE

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


def heartbeats(msg: Any) -> list[tuple[Key, str]]:
    """The heartbeats in a DiagnosticArray: ((host, pid), node name) each; others ignored."""
    out = []
    for status in msg.status:
        if not status.name.endswith(HEARTBEAT_SUFFIX):
            continue
        values = {kv.key: kv.value for kv in status.values}
        try:
            pid = int(values["pid"])
        except (KeyError, ValueError):
            continue
        out.append(((status.hardware_id, pid), status.name[:-len(HEARTBEAT_SUFFIX)]))
    return out


class HeartbeatWatch:
    """Listens to ``/diagnostics`` on an existing node and keeps a ``Silence`` per process.

    It adds one subscription to ``node`` (the orchestrator's monitor) rather than a node of
    its own, so the graph the user sees does not change.
    """

    def __init__(self, node: Any, silence: Silence | None = None) -> None:
        from diagnostic_msgs.msg import DiagnosticArray

        from roger_common.ros_node import RELIABLE

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


def spin_node(factory: Any, prog: str, args: list[str] | None = None,
              setup: Any = None) -> None:
    """Init, build, spin with a heartbeat, shut down cleanly; exit with a telling status.

    * Ctrl-C (KeyboardInterrupt) and SIGTERM (ExternalShutdownException): quiet, status 0.
    * A setup failure while building the node (RogerError, ValueError, OSError): one line
      ``prog: message``, no traceback, status ``SETUP_EXIT`` (2): "do not restart".
    * Any other exception, from a callback or from building the node: logged with its
      traceback, status ``CRASH_EXIT`` (70): "restart me".
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException

    from roger_common.dds import apply_dds_defaults
    from roger_common.errors import RogerError

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
