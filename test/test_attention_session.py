"""The attention node's protocol without ROS: AttentionSession driven by a fake transport.

The transport delivers each outgoing goal and request to a scripted world and memory
(attention_fakes) and hands the answers back as the node would. The session must run the
same cycles as the controller driven synchronously, re-send what is not answered, ignore
answers to anything else, stop at max_cycles, and resume after a crash with no cycle, id
or mapped place lost.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from attention_fakes import FakeMemory, FakeWorld, check_table2, three_objects

from roger_attention.config import AttentionConfig, AttentionNodeConfig, SpatialMapConfig
from roger_attention.controller import AttentionController, CycleRecord, is_look
from roger_attention.policies import make_policy
from roger_attention.session import (
    AttentionSession,
    PublishMap,
    PublishMetrics,
    Report,
    SendGoal,
    SendRequest,
)
from roger_common.errors import RogerError
from roger_common.types import Action, MatchOutcome, MatchResult, MemoryOp, MemoryRequest


class Clock:
    """A wall clock the test moves by hand."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def make_session(tmp_path=None, policy: str = "qlearning", max_cycles: int = 0,
                 clock: Clock | None = None, **node: object) -> AttentionSession:
    cfg = AttentionConfig(policy=policy, spatial_map=SpatialMapConfig(vanish_frames=2),
                          home_targets=(0.5, 0.3, 0.0, 0.5, -0.3, 0.0))
    rng = np.random.default_rng(0)
    ctl = AttentionController(cfg, make_policy(policy, cfg, rng), rng)
    state = tmp_path / "attention.json" if tmp_path is not None else None
    return AttentionSession(ctl, AttentionNodeConfig(max_cycles=max_cycles, **node), state,
                            clock=clock or Clock())


class Transport:
    """Delivers a session's goals and requests and feeds the answers back."""

    def __init__(self, session: AttentionSession, world: FakeWorld, memory: FakeMemory) -> None:
        self.session, self.world, self.memory = session, world, memory
        self.sim_time = 0.0
        self.reports: list[Report] = []
        self.maps: list[PublishMap] = []
        self.metrics: list[PublishMetrics] = []
        self.goals: list[SendGoal] = []
        self.pending: list[SendGoal | SendRequest] = []

    def take(self, out: list) -> None:
        for item in out:
            if isinstance(item, Report):
                self.reports.append(item)
            elif isinstance(item, PublishMap):
                self.maps.append(item)
            elif isinstance(item, PublishMetrics):
                self.metrics.append(item)
            else:
                if isinstance(item, SendGoal):
                    self.goals.append(item)
                self.pending.append(item)

    def answer(self) -> bool:
        """Answer the oldest pending goal or request; False when none is pending."""
        if not self.pending:
            return False
        item = self.pending.pop(0)
        if isinstance(item, SendGoal):
            self.sim_time += 0.5
            goal = item.goal
            touch = goal.target if goal.action is Action.HAPTIC_IMPROVEMENT else None
            self.take(self.session.on_rois(goal.goal_id, self.world.rois(touch),
                                           self.sim_time, None, None))
        else:
            result = self.memory.handle(item.request)
            self.take(self.session.on_result(item.request.request_id, result,
                                             len(self.memory.stored)))
        return True

    def run(self, max_steps: int = 10_000) -> None:
        self.take(self.session.start())
        for _ in range(max_steps):
            if not self.answer():
                return


def test_session_runs_the_controllers_cycles_and_stops_at_max_cycles() -> None:
    session = make_session(max_cycles=30)
    t = Transport(session, FakeWorld(three_objects()), FakeMemory())
    t.run()
    assert session.done and [r.record.cycle for r in t.reports] == list(range(1, 31))
    assert t.metrics[-1].done and t.metrics[-1].counters.cycles == 30
    assert sum(m.done for m in t.metrics) == 1
    check_table2(t.reports[-1].record.counters)
    # The initial scan: one look per home target, each with an id of its own.
    looks = [g.goal.goal_id for g in t.goals if is_look(g.goal.goal_id)]
    assert len(looks) == 2 and len(set(looks)) == 2
    # Each goal is perceived with the map of the revision published just before it.
    revisions = [m.revision for m in t.maps]
    assert revisions == sorted(revisions) and len(set(revisions)) == len(revisions)
    # A map update's report carries no frame; a physical action's carries its pair's stamp.
    for r in t.reports:
        assert (r.frame_stamp == 0.0) == (r.record.action is Action.MAP_UPDATE)


def test_session_stops_by_the_robots_completion_rule() -> None:
    session = make_session(policy="straightforward", max_cycles=500, stop_when_complete=6)
    t = Transport(session, FakeWorld(three_objects()), FakeMemory())
    t.run()
    # Three objects stored and mapped by cycle 12 (S V H M each); six more cycles without a
    # new representation, nothing unmapped: done, by the rule, not by the budget.
    assert session.done and session.complete
    assert [r.record.cycle for r in t.reports] == list(range(1, 19))
    assert t.metrics[-1].done and t.metrics[-1].complete
    assert not any(m.complete for m in t.metrics[:-1])
    assert session.ctl.cycles_since_new == 6


def test_unanswered_goals_are_resent_and_stale_answers_ignored() -> None:
    clock = Clock()
    session = make_session(clock=clock, retry_after_s=3.0)
    t = Transport(session, FakeWorld(three_objects()), FakeMemory())
    t.take(session.start())
    first = t.pending[0]
    assert session.tick() == [] and session.resends == 0
    clock.now += 3.5
    assert session.tick() == [first] and session.resends == 1
    assert session.tick() == []                  # the retry restarts the wait
    # An answer to another goal changes nothing; the awaited one goes on.
    assert session.on_rois(first.goal.goal_id + 7, [], 1.0, None, None) == []
    assert session.on_result(99, None, 0) == []
    t.answer()
    assert t.pending and t.pending[-1] is not first


def test_idle_plan_looks_again_after_a_delay_without_counting_a_cycle() -> None:
    clock = Clock()
    session = make_session(clock=clock)
    t = Transport(session, FakeWorld({}), FakeMemory())
    t.run()
    assert session.ctl.counters.cycles == 0 and not t.pending and t.reports == []
    assert session.tick() == []
    clock.now += 0.6
    out = session.tick()
    assert len(out) == 1 and isinstance(out[0], SendGoal) and is_look(out[0].goal.goal_id)


def test_a_restarted_session_goes_on_where_the_crashed_one_stopped(tmp_path) -> None:
    world, memory = FakeWorld(three_objects()), FakeMemory()
    first = make_session(tmp_path, policy="straightforward", max_cycles=12)
    t1 = Transport(first, world, memory)
    t1.run()
    assert first.done and first.ctl.spatial_map.all_mapped() and len(memory.stored) == 3
    # "Crash": a new controller and session from the same file, with a larger budget.
    second = make_session(tmp_path, policy="straightforward", max_cycles=20)
    assert second.resumed and second.ctl.counters.cycles == 12
    t2 = Transport(second, world, memory)
    t2.sim_time = t1.sim_time
    t2.run()
    # After its scan the restarted session re-sends the last report, then goes on.
    assert [r.record.cycle for r in t2.reports] == [12, *range(13, 21)]
    assert t2.reports[0].record == t1.reports[-1].record
    # The places mapped before the crash were mapped again after the scan: the known
    # objects are not stored a second time, and no cycle id repeats.
    # Mapped objects are identified again but need no map update.
    assert len(memory.stored) == 3
    assert all(r.record.action is not Action.MAP_UPDATE for r in t2.reports[1:])
    assert second.ctl.spatial_map.all_mapped()
    cycle_goals = [g.goal.goal_id for g in t1.goals + t2.goals if not is_look(g.goal.goal_id)]
    assert len(cycle_goals) == len(set(cycle_goals))


class OnceMemory(FakeMemory):
    """FakeMemory that answers a STORE of features it already holds with their address,
    as the memory node does (``find_exact``)."""

    def handle(self, req: MemoryRequest) -> MatchResult:
        if req.op is MemoryOp.STORE:
            for address, (f, k) in enumerate(self.stored):
                if np.array_equal(f, req.features) and np.array_equal(k, req.known):
                    self.requests.append(req)
                    return MatchResult(MatchOutcome.NEW, address, 1.0)
        return super().handle(req)


def run_until_a_store_is_out(t: Transport, skip: int = 0) -> SendRequest:
    """Drive ``t`` until a STORE is the next thing to answer (after ``skip`` others)."""
    t.take(t.session.start())
    while True:
        head = t.pending[0]
        if isinstance(head, SendRequest) and head.request.op is MemoryOp.STORE:
            if skip == 0:
                return head
            skip -= 1
        assert t.answer()


@pytest.mark.parametrize("memory_made_it", [True, False])
def test_a_store_in_flight_when_the_session_died_is_finished_on_resume(
        tmp_path, memory_made_it) -> None:
    world, memory = FakeWorld(three_objects()), OnceMemory()
    first = make_session(tmp_path, max_cycles=40)
    t1 = Transport(first, world, memory)
    store = run_until_a_store_is_out(t1, skip=1)
    cycles_before = first.ctl.counters.cycles
    if memory_made_it:  # the memory stored it; its reply never reached the dead session
        memory.handle(store.request)
    stored_before = len(memory.stored)
    # "Crash": a new controller and session from the file written before the STORE went out.
    second = make_session(tmp_path, max_cycles=40)
    assert second.resumed and second.ctl.counters.cycles == cycles_before
    t2 = Transport(second, world, memory)
    t2.sim_time = t1.sim_time
    out = second.start()
    assert len(out) == 1 and isinstance(out[0], SendRequest)
    again = out[0].request
    assert again.op is MemoryOp.STORE and again.request_id == store.request.request_id
    np.testing.assert_array_equal(again.features, store.request.features)
    t2.take(out)
    assert t2.answer()
    # The stored cycle is reported first, with the address the memory gave it, once.
    first_report = t2.reports[0].record
    assert first_report.cycle == cycles_before + 1 and first_report.outcome == "stored"
    assert len(memory.stored) == max(stored_before, 1 + stored_before - memory_made_it)
    assert first_report.address == len(memory.stored) - 1
    assert first_report.counters.new_objects == first.ctl.counters.new_objects + 1
    while t2.answer():
        pass
    # Every object the memory holds is recorded as stored exactly once, in order.
    reports = {r.record.cycle: r.record for r in t1.reports + t2.reports}
    assert sorted(reports) == list(range(1, 41))
    stored_at = [r.address for _, r in sorted(reports.items()) if r.outcome == "stored"]
    assert sorted(stored_at) == list(range(len(memory.stored)))
    check_table2(reports[40].counters)
    # The place was mapped with that address after the scan: not stored a second time.
    assert first_report.address in [e.address for e in second.ctl.spatial_map if e.mapped]
    # The Q update of the finished cycle is in the table: its TD error was recorded.
    assert first_report.td_error is not None


def test_a_second_crash_before_the_store_is_answered_keeps_it_in_flight(tmp_path) -> None:
    world, memory = FakeWorld(three_objects()), OnceMemory()
    t1 = Transport(make_session(tmp_path, max_cycles=40), world, memory)
    store = run_until_a_store_is_out(t1)
    second = make_session(tmp_path, max_cycles=40)
    assert second.ctl.store_in_flight is not None
    third = make_session(tmp_path, max_cycles=40)  # died again before anything
    request = third.ctl.store_in_flight
    assert request is not None and request.request_id == store.request.request_id
    # Ids go on after the store's own: nothing later reuses it.
    t3 = Transport(third, world, memory)
    t3.run()
    ids = [r.request_id for r in memory.requests]
    assert ids.count(store.request.request_id) == 1 and ids == sorted(ids)


def test_a_restarted_session_keeps_what_the_q_learner_learnt(tmp_path) -> None:
    first = make_session(tmp_path, max_cycles=25)
    Transport(first, FakeWorld(three_objects()), FakeMemory()).run()
    q = np.asarray(first.ctl.policy.state_dict()["q"])
    assert np.any(q != 0.0)
    second = make_session(tmp_path)
    np.testing.assert_array_equal(second.ctl.policy.state_dict()["q"], q)
    assert second.ctl.counters == first.ctl.counters


def test_an_unusable_resume_file_is_refused_with_its_name(tmp_path) -> None:
    (tmp_path / "attention.json").write_text('{"format": "something else"}')
    with pytest.raises(RogerError, match="attention.json"):
        make_session(tmp_path)
    (tmp_path / "attention.json").write_text("not json")
    with pytest.raises(RogerError, match="resume state unusable"):
        make_session(tmp_path)


def test_cycle_records_survive_their_json_round_trip() -> None:
    session = make_session(max_cycles=12)
    t = Transport(session, FakeWorld(three_objects()), FakeMemory())
    t.run()
    for r in t.reports:
        again = CycleRecord.from_dict(json.loads(json.dumps(r.record.to_dict())))
        assert again == r.record
