"""RunMonitor: a policy state is scored against its frame's labels whatever the arrival order.

DDS orders messages per topic only: the label image of a frame may reach the monitor after
the PolicyState that refers to it. The state then waits (in order) for its labels, for newer
labels that prove they will not come, or for LABELS_WAIT_S of wall time.
"""

from __future__ import annotations

import numpy as np
import pytest

from roger_bringup.monitor_logic import LABELS_WAIT_S, RunMonitor
from roger_common.types import Action
from roger_experiments.evaluation import RunRecorder


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def state(cycle: int, frame_s: int, action: int = Action.ATTENTION_SHIFT):
    from roger_interfaces.msg import PolicyState
    msg = PolicyState(cycle=cycle, action=action, entry_id=cycle, x0=0, y0=0, x1=4, y1=4,
                      outcome="new", address=-1, td_error=float("nan"))
    msg.state_before = msg.state_after = "000"
    msg.position.x = msg.position.y = msg.position.z = float("nan")
    msg.frame_stamp.sec = frame_s
    msg.header.stamp.sec = frame_s
    return msg


def labels(frame_s: int, name: str):
    from roger_interfaces.msg import GroundTruthLabels
    msg = GroundTruthLabels(label_names=[name])
    msg.header.stamp.sec = frame_s
    msg.left.height = msg.left.width = 4
    msg.left.data = np.zeros((4, 4), np.int32).tobytes()  # all pixels: label 0 = name
    return msg


@pytest.fixture()
def monitor(tmp_path):
    clock = FakeClock()
    recorder = RunRecorder(tmp_path, [], {"policy": "straightforward", "seed": 0})
    yield RunMonitor(recorder, clock=clock), recorder, clock
    recorder.close(0.0)


def seen(recorder: RunRecorder) -> list[tuple[int, str | None]]:
    return [(r.cycle, r.true_object) for r in recorder.rows]


def test_labels_first_is_scored_at_once(monitor) -> None:
    mon, rec, _ = monitor
    mon.on_labels(labels(1, "cube"))
    mon.on_state(state(1, 1))
    assert seen(rec) == [(1, "cube")]


def test_state_before_its_labels_waits_for_them_and_keeps_order(monitor) -> None:
    mon, rec, _ = monitor
    mon.on_state(state(1, 1))
    mon.on_state(state(2, 2))
    assert seen(rec) == [] and mon.waiting == 2
    mon.on_labels(labels(1, "cube"))
    assert seen(rec) == [(1, "cube")]      # cycle 2 still waits for frame 2's labels
    mon.on_labels(labels(2, "ball"))
    assert seen(rec) == [(1, "cube"), (2, "ball")] and mon.waiting == 0


def test_newer_labels_release_a_state_whose_labels_never_come(monitor) -> None:
    mon, rec, _ = monitor
    mon.on_state(state(1, 1))
    mon.on_labels(labels(2, "ball"))
    assert seen(rec) == [(1, None)]


def test_overdue_state_is_recorded_without_labels(monitor) -> None:
    mon, rec, clock = monitor
    mon.on_state(state(1, 1))
    clock.now += LABELS_WAIT_S / 2
    mon.flush()
    assert seen(rec) == []
    clock.now += LABELS_WAIT_S
    mon.flush()
    assert seen(rec) == [(1, None)]


def test_map_update_needs_no_labels_but_waits_its_turn(monitor) -> None:
    mon, rec, _ = monitor
    mon.on_state(state(1, 1))
    update = state(2, 0, Action.MAP_UPDATE)
    mon.on_state(update)
    assert seen(rec) == []
    mon.flush(force=True)
    assert [r.cycle for r in rec.rows] == [1, 2]


def event(goal_id: int, converged: bool):
    from roger_interfaces.msg import ConvergenceEvent
    return ConvergenceEvent(goal_id=goal_id, action=int(Action.HAPTIC_IMPROVEMENT),
                            converged=converged)


def test_a_state_waits_for_its_goals_convergence_event_too(monitor) -> None:
    mon, rec, _ = monitor
    mon.on_labels(labels(1, "cube"))
    mon.on_labels(labels(2, "cube"))
    first, second = state(1, 1), state(2, 2)
    first.goal_id, second.goal_id = 7, 8
    mon.on_state(first)
    mon.on_state(second)
    assert seen(rec) == []                 # labels here, events not yet
    mon.on_convergence(event(7, False))    # the arm could not reach
    assert [r.converged for r in rec.rows] == [False]
    mon.on_convergence(event(1 << 62, True))   # a look's event proves nothing about 8
    assert len(rec.rows) == 1
    mon.on_convergence(event(9, True))     # a newer goal's event: 8's never comes
    assert [r.converged for r in rec.rows] == [False, None]
    assert rec.scorer.failed_goals == 1
