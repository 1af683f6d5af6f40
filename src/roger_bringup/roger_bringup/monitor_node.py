"""The orchestrator's own node: watches the run and scores it against the ground truth.

It subscribes to what the attention node reports (policy state, metrics) and to the
simulator's ground truth (labels per frame, the world's objects), and hands each finished
cycle to a RunRecorder. It publishes nothing and never influences the run.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Any

import numpy as np
from rclpy.node import Node
from roger_common.conversions import IMAGES, LATCHED, RELIABLE, point_tuple, time_to_seconds
from roger_common.types import ObjectSpec

from roger_bringup.evaluation import CycleRow, RunRecorder, object_under_window
from roger_interfaces.msg import GroundTruth, GroundTruthLabels, Metrics, PolicyState

#: The node names a complete graph has.
GRAPH_NODES: tuple[str, ...] = ("roger_sim", "roger_perception", "roger_memory",
                                "roger_attention")


def spec_from_msg(o: Any) -> ObjectSpec:
    """A WorldObject message as an ObjectSpec (for categories)."""
    return ObjectSpec(name=o.name, shape=o.shape, position=(o.x, o.y), size=o.size,
                      intensity=o.intensity, weight=o.weight, yaw=o.yaw, texture=o.texture)


class MonitorNode(Node):
    """Records every cycle of the run; the orchestrator polls ``done`` and ``cycles``."""

    def __init__(self, recorder: RunRecorder, **kwargs: Any) -> None:
        super().__init__("roger_monitor", **kwargs)
        self.recorder = recorder
        self.labels: OrderedDict[tuple[int, int], tuple[np.ndarray, tuple[str, ...]]] = \
            OrderedDict()
        self.metrics: Metrics | None = None
        self.done = False
        self.topic_counts: dict[str, int] = {}
        self.create_subscription(PolicyState, "/roger/policy_state", self.on_state, RELIABLE)
        self.create_subscription(Metrics, "/roger/metrics", self.on_metrics, RELIABLE)
        self.create_subscription(GroundTruthLabels, "/roger/ground_truth/labels",
                                 self.on_labels, IMAGES)
        self.create_subscription(GroundTruth, "/roger/ground_truth", self.on_truth, LATCHED)

    @property
    def cycles(self) -> int:
        """Cycles recorded so far."""
        return len(self.recorder.rows)

    def graph_up(self) -> bool:
        """True when every node of the graph is visible on this domain."""
        names = set(self.get_node_names())
        return all(n in names for n in GRAPH_NODES)

    def on_truth(self, msg: GroundTruth) -> None:
        """The world's objects (at start and after each change)."""
        self.recorder.scorer.set_objects([spec_from_msg(o) for o in msg.objects])

    def on_labels(self, msg: GroundTruthLabels) -> None:
        """Keep the last few frames' label images by stamp."""
        img = msg.left
        labels = np.frombuffer(bytes(img.data), np.int32).reshape(img.height, img.width)
        key = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        self.labels[key] = (labels, tuple(msg.label_names))
        while len(self.labels) > 32:
            self.labels.popitem(last=False)

    def on_state(self, msg: PolicyState) -> None:
        """One finished cycle: find the object under the attention window, record it."""
        seen = None
        key = (msg.frame_stamp.sec, msg.frame_stamp.nanosec)
        if msg.action != 3 and key in self.labels and msg.x1 > msg.x0:
            labels, names = self.labels[key]
            seen = object_under_window(labels, names, (msg.x0, msg.y0, msg.x1, msg.y1))
        true_object = self.recorder.scorer.true_object_for(msg.action, msg.entry_id, seen)
        td = float(msg.td_error)
        self.recorder.add(CycleRow(
            cycle=int(msg.cycle), state=msg.state_before, action=int(msg.action),
            reward=float(msg.reward), td_error=None if np.isnan(td) else td,
            roi=int(msg.entry_id), true_object=true_object, outcome=msg.outcome,
            state_after=msg.state_after, address=int(msg.address),
            position=point_tuple(msg.position) if msg.entry_id >= 0 else None,
            sim_time=time_to_seconds(msg.header.stamp)))

    def on_metrics(self, msg: Metrics) -> None:
        """Live counters; ``done`` ends the run."""
        self.metrics = msg
        self.recorder.counters = {
            "cycles": msg.cycles, "attention_shifts": msg.attention_shifts,
            "improvements": msg.improvements, "visual_improvements": msg.visual_improvements,
            "haptic_improvements": msg.haptic_improvements,
            "positive_identifications": msg.positive_identifications,
            "new_objects": msg.new_objects, "map_updates": msg.map_updates}
        if msg.done:
            self.done = True
