"""The orchestrator's own node: watches the run and scores it against the ground truth.

It subscribes to what the attention node reports (policy state, metrics), to the
simulator's convergence events and to its ground truth (labels per frame, the world's
objects) and hands every message
to a RunMonitor (the same logic ``roger replay`` uses). It publishes nothing and never
influences the run.
"""

from __future__ import annotations

import time
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from roger_bringup.monitor_logic import RunMonitor
from roger_common import topics
from roger_common.ros_node import LABELS, LATCHED, REPORTS
from roger_experiments.evaluation import RunRecorder
from roger_interfaces.msg import (
    ConvergenceEvent,
    GroundTruth,
    GroundTruthLabels,
    Metrics,
    PolicyState,
)

#: Wall seconds the monitor waits to hear the simulator before it lets the run start.
GATE_TIMEOUT_S = 30.0
#: The node names a complete graph has.
GRAPH_NODES: tuple[str, ...] = ("roger_sim", "roger_perception", "roger_memory",
                                "roger_attention")


class MonitorNode(Node):
    """Records every cycle of the run; the orchestrator polls ``done`` and ``cycles``."""

    def __init__(self, recorder: RunRecorder, **kwargs: Any) -> None:
        super().__init__("roger_monitor", **kwargs)
        self.monitor = RunMonitor(recorder)
        self.recorder = recorder
        self.create_subscription(Metrics, topics.METRICS, self.monitor.on_metrics, REPORTS)
        self.create_subscription(GroundTruth, topics.GROUND_TRUTH, self.monitor.on_truth,
                                 LATCHED)
        # The attention node starts once it sees the /roger/policy_state subscription, so
        # that one comes only once these hear the simulator: the first frames' labels and
        # the first goals' convergence events (volatile) would be lost otherwise.
        self._gated = [
            self.create_subscription(GroundTruthLabels, topics.GROUND_TRUTH_LABELS,
                                     self.monitor.on_labels, LABELS),
            self.create_subscription(ConvergenceEvent, topics.CONVERGENCE,
                                     self.monitor.on_convergence, REPORTS)]
        self._gate_deadline = time.monotonic() + GATE_TIMEOUT_S
        self._gate_timer = self.create_timer(0.02, self._open_gate,
                                             clock=Clock(clock_type=ClockType.STEADY_TIME))
        # Records policy states whose frame's labels are overdue (wall clock: sim time
        # stands still while the graph waits).
        self.create_timer(0.1, self.monitor.flush, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _open_gate(self) -> None:
        unheard = [s.topic_name for s in self._gated if s.get_publisher_count() == 0]
        if unheard and time.monotonic() < self._gate_deadline:
            return
        if unheard:
            self.get_logger().warning(f"no publisher after {GATE_TIMEOUT_S:.0f} s on "
                                      f"{', '.join(unheard)}; recording cycles anyway")
        self._gate_timer.cancel()
        self.destroy_timer(self._gate_timer)
        self.create_subscription(PolicyState, topics.POLICY_STATE, self.monitor.on_state,
                                 REPORTS)

    @property
    def cycles(self) -> int:
        """Cycles recorded so far."""
        return self.monitor.cycles

    @property
    def done(self) -> bool:
        """True once the attention node reported the end of the run."""
        return self.monitor.done

    def graph_up(self) -> bool:
        """True when every node of the graph is visible on this domain."""
        names = set(self.get_node_names())
        return all(n in names for n in GRAPH_NODES)
