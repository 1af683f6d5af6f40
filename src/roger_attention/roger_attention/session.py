"""The attention node's side of the graph protocol, without ROS.

The graph runs each control cycle asynchronously: a goal goes out, the ROI array of the
stereo pair rendered after it comes back, a memory request goes out, its answer comes
back. ``AttentionSession`` keeps that protocol around the AttentionController: which goal
or request is awaited, what to send next, when to re-send an unanswered one, when the run
is over, and the resume file that lets a restarted node go on where a crashed one stopped.
Each event (``start``, ``on_rois``, ``on_result``, ``tick``) returns what must go out,
in order; the node converts each item to a message and publishes it. So every decision is
here and unit-testable, and the node only carries messages.

Resuming after a crash (docs/reliability.md): with a ``state_path`` the session writes the
controller's ``export_state``, the simulated time, the memory's size, the map revision and
the last cycle's report there atomically at the end of every cycle, before the report goes
out. A restarted session restores them, scans again (the controller maps again what was
mapped), re-sends the last report (the orchestrator's recorder drops a cycle number it
already has) and goes on with the next cycle.

A map update's STORE is written ahead: the session saves the state, with the store in it
(``AttentionController.store_in_flight``), before the request goes out. A session restored
from such a state sends that store again first, with its request id and features (the
memory answers a store it already made with the same address, and makes one it never
received), closes the stored cycle from the answer, reports it, and only then scans. So a
kill between the memory's store and its reply loses nothing, and stores nothing twice.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from roger_attention.config import AttentionNodeConfig
from roger_attention.controller import AttentionController, CyclePlan, CycleRecord, is_look
from roger_attention.spatial_map import MapEntry
from roger_common.atomic import atomic_write_bytes
from roger_common.errors import RogerError
from roger_common.types import (
    CameraModel,
    EyePose,
    Goal,
    MatchResult,
    MemoryOp,
    MemoryRequest,
    Roi,
    RunCounters,
)

#: Format tag of the resume state file.
STATE_FORMAT = "roger_attention_state/2"
#: Wall seconds between an idle plan (nothing in the map) and the next look.
IDLE_LOOK_DELAY_S = 0.5
#: Map revisions a restarted session skips: maps published after the last save of the
#: crashed one must stay older than the new session's (perception waits for >=).
REVISION_MARGIN = 1000


@dataclass(frozen=True)
class SendGoal:
    """Publish a goal; its stereo pair is to be perceived with map ``map_revision``."""

    goal: Goal
    stamp: float
    map_revision: int


@dataclass(frozen=True)
class SendRequest:
    """Publish a memory request."""

    request: MemoryRequest
    stamp: float


@dataclass(frozen=True)
class Report:
    """Report a finished cycle; ``frame_stamp`` is that of the stereo pair it looked at
    (0 for a map update)."""

    record: CycleRecord
    stamp: float
    frame_stamp: float


@dataclass(frozen=True)
class PublishMap:
    """Publish the spatial map's entries as they were when this was made."""

    entries: tuple[MapEntry, ...]
    stamp: float
    revision: int


@dataclass(frozen=True)
class PublishMetrics:
    """Publish the run's counters; ``done`` once the run reached its stop condition,
    ``complete`` when that was the robot's completion rule."""

    counters: RunCounters
    map_entries: int
    memory_size: int
    done: bool
    stamp: float
    complete: bool = False


Outgoing = SendGoal | SendRequest | Report | PublishMap | PublishMetrics


class AttentionSession:
    """Runs the controller's cycles over an asynchronous transport.

    Attributes:
        ctl: The controller.
        config: The node's configuration (replace it to change live fields).
        state_path: The resume file, or None.
        qtable_path: Where a learning policy is saved after every cycle, or None.
        done: True once ``max_cycles`` cycles are done, or the controller judged the
            inspection complete (``stop_when_complete``).
        complete: True when the run ended by the completion rule.
        resumed: True from a restore from ``state_path`` until the scan after it ended.
        resends: Goals and requests re-sent so far (no answer within ``retry_after_s``).
    """

    def __init__(self, ctl: AttentionController, config: AttentionNodeConfig,
                 state_path: Path | None = None, qtable_path: Path | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        """Start before the first look; restore from ``state_path`` if it holds a state.

        Raises:
            RogerError: The resume file exists but cannot be used (names it).
        """
        self.ctl, self.config = ctl, config
        self.state_path, self.qtable_path = state_path, qtable_path
        self.done = False
        self.complete = False
        self.resends = 0
        self._clock = clock
        self._sim_now = 0.0
        self._frame_stamp = 0.0
        self._memory_size = 0
        self._revision = 0
        self._plan: CyclePlan | None = None
        self._awaited_goal: int | None = None
        self._awaited_request: int | None = None
        self._last_sent: tuple[SendGoal | SendRequest, float] | None = None
        self._look_due: float | None = None
        self._last_report: Report | None = None
        self._finishing: int | None = None  # request id of a restored store in flight
        self.resumed = self._load()

    # -- events --------------------------------------------------------------------------
    def start(self) -> list[Outgoing]:
        """The peers are up: the first look of the initial scan (after a restart, the
        store in flight first, if there was one)."""
        store = self.ctl.store_in_flight
        if store is not None:
            self._finishing = store.request_id
            return self._send_request(store)
        return self._look()

    def tick(self) -> list[Outgoing]:
        """Called often (wall clock): a due look, or a goal or request re-sent after
        ``retry_after_s`` without an answer."""
        now = self._clock()
        if self._look_due is not None and now >= self._look_due:
            self._look_due = None
            return self._look()
        if self._last_sent is not None and now - self._last_sent[1] > self.config.retry_after_s:
            out = self._last_sent[0]
            self._last_sent = (out, now)
            self.resends += 1
            return [out]
        return []

    def on_rois(self, goal_id: int, rois: Sequence[Roi], stamp: float,
                camera: CameraModel | None, pose: EyePose | None) -> list[Outgoing]:
        """The ROIs of the stereo pair rendered after goal ``goal_id`` (others are ignored).

        Args:
            goal_id: Goal the pair answers.
            rois: Its ROIs (empty when unusable: the focus is then lost).
            stamp: Simulated time of the pair.
            camera, pose: The left retina's intrinsics and eye pose for that pair (None
                when unknown: nothing can then count as vanished).
        """
        if self._awaited_goal is None or goal_id != self._awaited_goal:
            return []
        self._awaited_goal, self._last_sent = None, None
        self._frame_stamp = stamp
        self._sim_now = max(self._sim_now, stamp)
        self.ctl.observe(rois, stamp, self.ctl.visibility(camera, pose), camera, pose)
        if not is_look(goal_id):
            request = self.ctl.match_request()
            return self._send_request(request) if request is not None else self._end_cycle(None)
        out: list[Outgoing] = [self._map(stamp)]  # the next look's goal carries its revision
        look = self.ctl.next_look()
        if look is not None:
            return [*out, self._send_goal(look)]
        if self.resumed:  # the scan after a restart: report where the run stands
            self.resumed = False
            if self._last_report is not None:
                out.append(self._last_report)
            out += [self._map(self._sim_now), self._metrics(False)]
        return out + self._next_cycle()

    def on_result(self, request_id: int, result: MatchResult | None,
                  memory_size: int) -> list[Outgoing]:
        """The memory's answer to request ``request_id`` (None: unusable, the cycle is lost)."""
        if self._awaited_request is None or request_id != self._awaited_request:
            return []
        self._awaited_request, self._last_sent = None, None
        self._memory_size = memory_size
        if self._finishing == request_id:
            return self._finish_store(result)
        return self._end_cycle(result)

    # -- the cycle -----------------------------------------------------------------------
    def _look(self) -> list[Outgoing]:
        look = self.ctl.next_look()
        return [self._send_goal(look)] if look is not None else self._next_cycle()

    def _send_goal(self, goal: Goal) -> SendGoal:
        self._awaited_goal = goal.goal_id
        out = SendGoal(goal, self._sim_now, self._revision)
        self._last_sent = (out, self._clock())
        return out

    def _send_request(self, request: MemoryRequest) -> list[Outgoing]:
        self._awaited_request = request.request_id
        if request.op is MemoryOp.STORE:
            self._save()  # written ahead: a restart sends it again and closes its cycle
        out = SendRequest(request, self._sim_now)
        self._last_sent = (out, self._clock())
        return [out]

    def _next_cycle(self) -> list[Outgoing]:
        stable = self.config.stop_when_complete
        if stable and self.ctl.complete(stable):
            self.done = self.complete = True
            return [self._metrics(True)]
        if self.config.max_cycles and self.ctl.counters.cycles >= self.config.max_cycles:
            self.done = True
            return [self._metrics(True)]
        self._plan = plan = self.ctl.begin_cycle(self._sim_now)
        if plan.idle:
            # Nothing in the map to attend to (an empty world, or everything vanished):
            # the controller queued a new scan; look again in a moment, no cycle counted.
            self.ctl.end_cycle(None, self._sim_now)
            self._plan = None
            self._look_due = self._clock() + IDLE_LOOK_DELAY_S
            return []
        if plan.goal is not None:
            return [self._send_goal(plan.goal)]
        if plan.memory_request is not None:
            return self._send_request(plan.memory_request)
        return self._end_cycle(None)

    def _end_cycle(self, result: MatchResult | None) -> list[Outgoing]:
        plan, self._plan = self._plan, None
        assert plan is not None
        record = self.ctl.end_cycle(result, self._sim_now)
        frame_stamp = self._frame_stamp if plan.goal is not None else 0.0
        self._last_report = Report(record, self._sim_now, frame_stamp)
        # Persist before reporting: a kill between the two loses no cycle that was reported.
        self._save()
        policy = self.ctl.policy
        if self.config.learn and self.qtable_path is not None and policy.learns:
            policy.save(self.qtable_path, durable=False)  # fsynced when the node ends
        return [self._last_report, self._map(self._sim_now), self._metrics(False),
                *self._next_cycle()]

    def _finish_store(self, result: MatchResult | None) -> list[Outgoing]:
        """The restored store in flight was answered: report its cycle, then scan."""
        self._finishing = None
        record = self.ctl.finish_store(result)
        self._last_report = Report(record, self._sim_now, 0.0)
        self._save()
        policy = self.ctl.policy
        if self.config.learn and self.qtable_path is not None and policy.learns:
            policy.save(self.qtable_path, durable=False)
        return [self._last_report, self._metrics(False), *self._look()]

    def _map(self, stamp: float) -> PublishMap:
        self._revision += 1
        # Copies: the next cycle may begin (and change the map) before this goes out.
        entries = tuple(dataclasses.replace(e) for e in self.ctl.spatial_map)
        return PublishMap(entries, stamp, self._revision)

    def _metrics(self, done: bool) -> PublishMetrics:
        return PublishMetrics(dataclasses.replace(self.ctl.counters), len(self.ctl.spatial_map),
                              self._memory_size, done, self._sim_now, self.complete)

    # -- resuming after a restart --------------------------------------------------------
    def _save(self) -> None:
        if self.state_path is None:
            return
        report = self._last_report
        state = {"format": STATE_FORMAT, "controller": self.ctl.export_state(),
                 "sim_now": self._sim_now, "memory_size": self._memory_size,
                 "map_revision": self._revision,
                 "last_report": None if report is None else {
                     "record": report.record.to_dict(), "stamp": report.stamp,
                     "frame_stamp": report.frame_stamp}}
        # Not fsynced: this sits on every cycle's critical path (fsynced when the node ends).
        atomic_write_bytes(self.state_path, json.dumps(state).encode(), durable=False)

    def _load(self) -> bool:
        path = self.state_path
        if path is None or not path.exists():
            return False
        try:
            state = json.loads(path.read_text())
            if state.get("format") != STATE_FORMAT:
                raise ValueError(f"format {state.get('format')!r}")
            self.ctl.restore_state(state["controller"])
            self._sim_now, self._memory_size = float(state["sim_now"]), int(state["memory_size"])
            self._revision = int(state["map_revision"]) + REVISION_MARGIN
            last = state["last_report"]
            if last is not None:
                self._last_report = Report(CycleRecord.from_dict(last["record"]),
                                           float(last["stamp"]), float(last["frame_stamp"]))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise RogerError(f"{path}: resume state unusable ({exc}); delete it to start "
                             "afresh") from None
        # Save at once: a second crash before the next cycle then skips the ids further.
        self._save()
        return True
