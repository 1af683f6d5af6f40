"""How a Roger node says it is alive, and how it ends: exit codes and a heartbeat.

Every node started through ``ros_node.spin_node`` (the ``main`` of each node) publishes a
heartbeat, a ``diagnostic_msgs/DiagnosticArray`` on ``/diagnostics``, from a wall-clock
(``STEADY_TIME``) timer in its own executor. A beat therefore means "this process's
executor turns", which is what answering the graph needs: a process that is stopped
(``kill -STOP``), deadlocked, or stuck in one endless callback falls silent, while DDS's own
threads would keep an ``AUTOMATIC`` liveliness lease alive in the last two cases. The
orchestrator listens (``ros_node.HeartbeatWatch`` on its monitor node) and kills and
restarts a node silent for longer than ``HANG_TIMEOUT_S`` (docs/reliability.md says why
that value).

This module is plain Python (the constants, ``Silence``, the parsing of a beat); the ROS
half (``attach_heartbeat``, ``HeartbeatWatch``, ``spin_node``) is in ``roger_common.ros_node``.
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Callable, Hashable
from typing import Any

from roger_common import topics

#: Exit status of a node that refused its setup (bad world, parameter or memory file):
#: restarting it would fail again, so the orchestrator ends the run with its one line.
SETUP_EXIT = 2
#: Exit status of a node whose callback raised after setup (``EX_SOFTWARE`` of sysexits.h):
#: a bug or a transient fault; the orchestrator restarts the node like any other death.
CRASH_EXIT = 70
#: Topic of the heartbeat (the standard diagnostics topic, so ``ros2 topic echo
#: /diagnostics`` and rqt_robot_monitor show it).
HEARTBEAT_TOPIC = topics.DIAGNOSTICS
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
    the part of the delay beyond ``own_stall_s``, so that no node is blamed for silence the
    watcher could not hear. Only that part: turns that keep coming a little over
    ``own_stall_s`` late (a loaded machine) would otherwise discount all the time between
    them, and a node that stopped beating would never be found silent.
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
                self._last[key] += late - self._own_stall_s
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
