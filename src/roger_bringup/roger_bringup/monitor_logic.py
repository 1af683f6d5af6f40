"""The monitor's bookkeeping, message by message, without a node around it.

The live monitor (``monitor_node.MonitorNode``) and ``roger replay`` (``record.replay``) must
score a run the same way, so both feed this one class with the same five message types:
the world's objects (GroundTruth), the label images of each stereo pair
(GroundTruthLabels), whether each goal converged (ConvergenceEvent), each finished cycle
(PolicyState) and the live counters (Metrics).
Messages are read by attribute only, so this module needs no rclpy.
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from typing import Any

import numpy as np

from roger_attention.controller import is_look
from roger_common.types import Action, ObjectSpec
from roger_experiments.evaluation import CycleRow, RunRecorder, object_under_window

#: Label images kept, by stamp, for the policy states that refer to them.
LABELS_KEPT = 32
#: Convergence events kept, by goal id, for the policy states that refer to them.
GOALS_KEPT = 64
#: Wall seconds a policy state waits for the label image of its frame (DDS orders messages
#: per topic only) before it is scored without it.
LABELS_WAIT_S = 2.0
#: Metrics message fields that are Table 2 counters.
COUNTER_FIELDS: tuple[str, ...] = (
    "cycles", "attention_shifts", "improvements", "visual_improvements",
    "haptic_improvements", "positive_identifications", "new_objects", "map_updates",
    "remaps")


def spec_from_msg(o: Any) -> ObjectSpec:
    """A WorldObject message as an ObjectSpec (for categories)."""
    return ObjectSpec(name=o.name, shape=o.shape, position=(o.x, o.y), size=o.size,
                      intensity=o.intensity, weight=o.weight, yaw=o.yaw, texture=o.texture)


def _stamp_key(t: Any) -> tuple[int, int]:
    return int(t.sec), int(t.nanosec)


def _seconds(t: Any) -> float:
    return t.sec + t.nanosec * 1e-9


class RunMonitor:
    """Turns the attention node's reports and the simulator's ground truth into a run log.

    Attributes:
        recorder: Receives one CycleRow per finished cycle and the live counters.
        labels: The last LABELS_KEPT left label images and their object names, by stamp.
        done: True once a Metrics message said the run reached its stop condition.
    """

    def __init__(self, recorder: RunRecorder,
                 clock: Callable[[], float] = time.monotonic) -> None:
        """Start with no labels and nothing recorded (``clock``: wall seconds, for waits)."""
        self.recorder = recorder
        self.labels: OrderedDict[tuple[int, int], tuple[np.ndarray, tuple[str, ...]]] = \
            OrderedDict()
        self.done = False
        self._clock = clock
        self._newest_label: tuple[int, int] | None = None
        self.converged: OrderedDict[int, bool] = OrderedDict()
        self._newest_goal = 0
        #: Policy states not recorded yet (in arrival order) and when each arrived.
        self._waiting: deque[tuple[Any, float]] = deque()

    @property
    def cycles(self) -> int:
        """Cycles recorded so far."""
        return len(self.recorder.rows)

    def on_truth(self, msg: Any) -> None:
        """The world's objects (at start and after each change)."""
        self.recorder.scorer.set_objects([spec_from_msg(o) for o in msg.objects])

    def on_labels(self, msg: Any) -> None:
        """Keep the last few frames' left label images by stamp."""
        img = msg.left
        labels = np.frombuffer(bytes(img.data), np.int32).reshape(img.height, img.width)
        key = _stamp_key(msg.header.stamp)
        self.labels[key] = (labels, tuple(msg.label_names))
        while len(self.labels) > LABELS_KEPT:
            self.labels.popitem(last=False)
        self._newest_label = key if self._newest_label is None else max(self._newest_label,
                                                                         key)
        self.flush()

    def on_convergence(self, msg: Any) -> None:
        """A goal finished: keep whether it converged, by goal id."""
        goal_id = int(msg.goal_id)
        self.converged[goal_id] = bool(msg.converged)
        while len(self.converged) > GOALS_KEPT:
            self.converged.popitem(last=False)
        if not is_look(goal_id):
            self._newest_goal = max(self._newest_goal, goal_id)
        self.flush()

    def _awaits_labels(self, msg: Any) -> bool:
        """True while the labels of this state's frame, or its goal's convergence event,
        may still come (each comes in order on its own topic)."""
        key = _stamp_key(msg.frame_stamp)
        labels = (msg.action != Action.MAP_UPDATE and msg.x1 > msg.x0 and key != (0, 0)
                  and key not in self.labels
                  and (self._newest_label is None or self._newest_label < key))
        goal_id = int(getattr(msg, "goal_id", 0))
        event = (goal_id > 0 and goal_id not in self.converged
                 and self._newest_goal < goal_id)
        return labels or event

    def row_from_state(self, msg: Any) -> CycleRow:
        """The CycleRow of a PolicyState message, scored against the labels of its frame."""
        seen = None
        key = _stamp_key(msg.frame_stamp)
        if msg.action != Action.MAP_UPDATE and key in self.labels and msg.x1 > msg.x0:
            labels, names = self.labels[key]
            seen = object_under_window(labels, names, (msg.x0, msg.y0, msg.x1, msg.y1))
        true_object = self.recorder.scorer.true_object_for(msg.action, msg.entry_id, seen,
                                                           msg.outcome)
        goal_id = int(getattr(msg, "goal_id", 0))
        td = float(msg.td_error)
        p = msg.position
        return CycleRow(
            cycle=int(msg.cycle), state=msg.state_before, action=int(msg.action),
            reward=float(msg.reward), td_error=None if math.isnan(td) else td,
            roi=int(msg.entry_id), true_object=true_object, outcome=msg.outcome,
            state_after=msg.state_after, address=int(msg.address),
            position=(p.x, p.y, p.z) if msg.entry_id >= 0 and math.isfinite(p.x) else None,
            sim_time=_seconds(msg.header.stamp),
            converged=self.converged.get(goal_id) if goal_id else None)

    def on_state(self, msg: Any) -> None:
        """One finished cycle: find the object under the attention window, record it.

        The labels of its frame travel on another topic and may come after it: the state
        is recorded once they are here, once newer labels show they never will be, or
        after LABELS_WAIT_S (see :meth:`flush`); states are recorded in arrival order.
        """
        self._waiting.append((msg, self._clock()))
        self.flush()

    @property
    def waiting(self) -> int:
        """Policy states received but not recorded yet."""
        return len(self._waiting)

    def flush(self, force: bool = False) -> None:
        """Record the states whose labels are here or overdue (all of them with ``force``)."""
        now = self._clock()
        while self._waiting:
            msg, since = self._waiting[0]
            if not force and self._awaits_labels(msg) and now - since < LABELS_WAIT_S:
                return
            self._waiting.popleft()
            self.recorder.add(self.row_from_state(msg))

    def on_metrics(self, msg: Any) -> None:
        """Live counters; ``done`` ends the run."""
        # A bag recorded before a counter existed has none: it counts 0 there.
        self.recorder.counters = {k: int(getattr(msg, k, 0)) for k in COUNTER_FIELDS}
        if msg.done:
            self.done = True
            self.recorder.complete = bool(getattr(msg, "complete", False))
