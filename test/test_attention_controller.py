"""The AttentionController's cycle protocol, driven by a scripted fake world and memory.

(That the core imports without ROS is checked elsewhere.)
"""

from __future__ import annotations

import numpy as np
import pytest
from attention_fakes import FakeMemory, FakeWorld, Obj, check_table2, three_objects

from roger_attention.config import AttentionConfig, SpatialMapConfig
from roger_attention.controller import (
    OUTCOMES,
    AttentionController,
    CyclePlan,
    CycleRecord,
    eyes_still,
)
from roger_attention.fsm import State
from roger_attention.fsm_env import FsmEnv, train_qtable
from roger_attention.policies import QLearningPolicy, make_policy
from roger_attention.qlearning import QTable
from roger_common.types import (
    WEIGHT_INDEX,
    Action,
    CameraModel,
    EyePose,
    MemoryOp,
)

S, V, H, M = (Action.ATTENTION_SHIFT, Action.VISUAL_IMPROVEMENT, Action.HAPTIC_IMPROVEMENT,
              Action.MAP_UPDATE)


class Driver:
    """The in-process loop of the cycle protocol (what the ROS attention node also does)."""

    def __init__(self, ctl: AttentionController, world: FakeWorld, memory: FakeMemory) -> None:
        self.ctl, self.world, self.memory = ctl, world, memory
        self.now = 0.0
        self.log: list[tuple[CyclePlan, CycleRecord]] = []
        for _ in range(ctl.config.spatial_map.settle_observations):  # the initial looks
            ctl.observe(world.rois(), self.now, world.visible)

    def cycle(self) -> tuple[CyclePlan, CycleRecord]:
        plan = self.ctl.begin_cycle(self.now)
        result = None
        if plan.goal is not None:
            self.now += 0.5
            touch = plan.goal.target if plan.goal.action is H else None
            self.ctl.observe(self.world.rois(touch), self.now, self.world.visible)
            req = self.ctl.match_request()
            if req is not None:
                result = self.memory.handle(req)
        elif plan.memory_request is not None:
            result = self.memory.handle(plan.memory_request)
        record = self.ctl.end_cycle(result, self.now)
        check_table2(record.counters)
        assert record.outcome in OUTCOMES
        self.log.append((plan, record))
        return plan, record

    def run(self, n: int) -> list[CycleRecord]:
        return [self.cycle()[1] for _ in range(n)]


def make_ctl(policy: str = "straightforward", seed: int = 0, learn: bool = True,
             table: QTable | None = None) -> AttentionController:
    cfg = AttentionConfig(policy=policy, spatial_map=SpatialMapConfig(vanish_frames=2))
    rng = np.random.default_rng(seed)
    if table is not None:
        pol = QLearningPolicy(table, rng, learn=learn)
    else:
        pol = make_policy(cfg.policy, cfg, rng, learn=learn)
    return AttentionController(cfg, pol, rng)


def test_straightforward_steps_map_every_object() -> None:
    d = Driver(make_ctl(), FakeWorld(three_objects()), FakeMemory())
    records = d.run(12)
    assert [r.action for r in records] == [S, V, H, M] * 3
    assert [r.outcome for r in records] == ["undetermined", "undetermined", "new",
                                            "stored"] * 3
    assert [r.state_after for r in records[:4]] == ["000", "000", "100", "101"]
    # Winner-take-all over activation: b (0.9), then c (0.6), then a (0.4).
    first_shift_targets = [p.goal.target for p, r in d.log if r.action is S]
    assert first_shift_targets == [(0.5, 0.0, 0.05), (0.5, 0.3, 0.05), (0.5, -0.3, 0.05)]
    c = d.ctl.counters
    assert (c.attention_shifts, c.visual_improvements, c.haptic_improvements,
            c.map_updates, c.new_objects, c.positive_identifications) == (3, 3, 3, 3, 3, 0)
    assert len(d.memory.stored) == 3 and all(k[WEIGHT_INDEX] for _, k in d.memory.stored)
    assert sorted(e.address for e in d.ctl.spatial_map) == [0, 1, 2]
    assert len(d.ctl.mapped_positions()) == 3
    assert [r.reward for r in records if r.action is M] == pytest.approx([1.5] * 3)
    assert all(r.td_error is None for r in records) and d.ctl.td_errors == []


def test_vigilance_shifts_to_largest_interest_after_all_mapped() -> None:
    d = Driver(make_ctl(), FakeWorld(three_objects()), FakeMemory())
    d.run(12)
    visited = []
    for _ in range(30):
        smap, focus = d.ctl.spatial_map, d.ctl.focus
        smap.advance(d.now)
        others = {e.entry_id: e.interest for e in smap if e.entry_id != focus}
        plan, record = d.cycle()
        if plan.action is S:
            assert others[plan.entry_id] == pytest.approx(max(others.values()))
            assert others[plan.entry_id] > 0.0
            visited.append(plan.entry_id)
            assert smap.get(plan.entry_id).interest == 0.0      # reset on focus
        assert record.action is not M                          # nothing new to map
    assert set(visited) == {e.entry_id for e in d.ctl.spatial_map}
    assert len(visited) >= 6
    c = d.ctl.counters
    assert (c.map_updates, c.new_objects) == (3, 3)
    # A revisit: shift (001), visual, haptic -> identified (011), then the next shift.
    assert [(r.action, r.outcome, r.state_after) for _, r in d.log[12:16]] == [
        (S, "undetermined", "001"), (V, "undetermined", "001"), (H, "identified", "011"),
        (S, "undetermined", "001")]


def test_interest_grows_for_others_and_stays_zero_in_focus() -> None:
    d = Driver(make_ctl(), FakeWorld(three_objects()), FakeMemory())
    d.run(2)
    smap = d.ctl.spatial_map
    assert smap.get(d.ctl.focus).interest == 0.0
    others = [e.interest for e in smap if e.entry_id != d.ctl.focus]
    assert all(i == pytest.approx(0.1 * d.now) for i in others)   # default 0.1 per sim s


def test_new_object_mid_run_is_visited_and_mapped() -> None:
    world = FakeWorld(three_objects())
    d = Driver(make_ctl(), world, FakeMemory())
    d.run(18)
    world.objects["d"] = Obj((0.8, 0.0, 0.05), 0.8, 0.3, 0.1)
    records = d.run(10)
    new_entry = [e for e in d.ctl.spatial_map if e.position == (0.8, 0.0, 0.05)]
    assert len(new_entry) == 1 and new_entry[0].mapped
    assert any(r.action is M and r.entry_id == new_entry[0].entry_id for r in records)
    assert d.ctl.counters.new_objects == 4 and len(d.ctl.mapped_positions()) == 4


def test_vanished_and_moved_objects_the_map_follows() -> None:
    world = FakeWorld(three_objects())
    d = Driver(make_ctl(), world, FakeMemory())
    d.run(12)
    del world.objects["a"]
    o = world.objects["c"]
    world.objects["c"] = Obj((0.9, 0.3, 0.05), o.value, o.weight, o.activation)
    d.run(12)
    positions = sorted(d.ctl.mapped_positions())
    assert positions == [(0.5, 0.0, 0.05), (0.9, 0.3, 0.05)]
    assert len(d.ctl.spatial_map) == 2
    c = d.ctl.counters
    assert c.positive_identifications == 1 and c.new_objects == 3   # c re-identified


def test_an_entry_that_drifted_is_remapped_not_identified_again() -> None:
    world = FakeWorld(three_objects())
    d = Driver(make_ctl(), world, FakeMemory())
    d.run(12)
    # b drifts 13 cm: still the same entry (association radius 0.15 m), but beyond the
    # moved threshold (0.12 m), so its mapping is cleared and it is mapped again.
    world.objects["b"] = Obj((0.63, 0.0, 0.05), 0.4, 0.5, 0.9)
    records = d.run(8)
    again = [r for r in records if r.action is M]
    assert [r.outcome for r in again] == ["remapped"]
    c = d.ctl.counters
    assert (c.positive_identifications, c.remaps, c.new_objects) == (0, 1, 3)


def test_a_place_lost_and_seen_again_is_remapped() -> None:
    world = FakeWorld(three_objects())
    d = Driver(make_ctl(), world, FakeMemory())
    d.run(12)
    a = world.objects.pop("a")
    d.run(3)                       # a's entry vanishes (vanish_frames 2)
    assert len(d.ctl.spatial_map) == 2
    world.objects["a"] = a         # back at its place: a new entry there
    records = d.run(8)
    assert [r.outcome for r in records if r.action is M] == ["remapped"]
    # A second object somewhere never mapped is a positive identification.
    world.objects["a2"] = Obj((0.9, 0.0, 0.05), a.value, a.weight, 0.95)
    records = d.run(6)
    assert [r.outcome for r in records if r.action is M] == ["mapped"]
    c = d.ctl.counters
    assert (c.positive_identifications, c.remaps, c.new_objects) == (1, 1, 3)


def test_places_mapped_before_survive_a_restart() -> None:
    world = FakeWorld(three_objects())
    d = Driver(make_ctl(), world, FakeMemory())
    d.run(12)
    a = world.objects.pop("a")
    d.run(3)
    saved = d.ctl.export_state()
    ctl = make_ctl()
    ctl.restore_state(saved)
    world.objects["a"] = a
    d2 = Driver(ctl, world, d.memory)
    while ctl.next_look() is not None:
        ctl.observe(world.rois(), d2.now, world.visible)
    records = d2.run(8)
    assert [r.outcome for r in records if r.action is M] == ["remapped"]


def test_complete_when_nothing_new_for_long_enough_and_nothing_unmapped() -> None:
    world = FakeWorld(three_objects())
    d = Driver(make_ctl(), world, FakeMemory())
    d.run(12)                                   # the last of three stores was at cycle 12
    assert d.ctl.cycles_since_new == 0 and not d.ctl.complete(4)
    d.run(4)
    assert d.ctl.complete(4) and not d.ctl.complete(5)
    world.objects["d"] = Obj((0.8, 0.0, 0.05), 0.8, 0.3, 0.1)
    d.ctl.observe(world.rois(), d.now, world.visible)
    assert d.ctl.complete(4)                    # one look: a candidate, not yet an entry
    d.ctl.observe(world.rois(), d.now + 0.5, world.visible)
    assert not d.ctl.complete(4)                # a second agreeing look: an unmapped entry
    assert not make_ctl().complete(0)           # nothing seen yet: not complete


def test_contradicted_mapped_entry_is_mapped_again() -> None:
    world = FakeWorld(three_objects())
    d = Driver(make_ctl(), world, FakeMemory())
    d.run(12)
    o = world.objects["a"]
    world.objects["a"] = Obj(o.position, 0.95, 0.7, o.activation)   # swapped in place
    d.run(16)
    assert d.ctl.counters.new_objects == 4 and len(d.memory.stored) == 4
    assert d.ctl.spatial_map.all_mapped()


def test_new_before_the_final_trial_counts_as_undetermined() -> None:
    d = Driver(make_ctl(), FakeWorld(three_objects()), FakeMemory(always_new=True))
    records = d.run(4)
    assert [r.outcome for r in records] == ["undetermined", "undetermined", "new", "stored"]
    finals = [q.final_trial for q in d.memory.requests if q.op is MemoryOp.MATCH]
    assert finals == [False, False, True]


def test_lost_focus_is_forgotten_and_attention_moves_on() -> None:
    world = FakeWorld(three_objects())
    d = Driver(make_ctl(), world, FakeMemory())
    d.cycle()                                   # shift onto b
    del world.objects["b"]
    plan, record = d.cycle()                    # visual improvement on b, now gone
    assert plan.action is V and record.outcome == "lost"
    assert d.memory.requests[-1].request_id == 1 and len(d.memory.requests) == 1
    # The eyes looked right at b's place and saw nothing: the place is forgotten and the
    # only action left is a shift, to another entry.
    assert record.entry_id not in d.ctl.spatial_map and d.ctl.focus is None
    assert d.ctl.allowed() == (S,)
    plan, _ = d.cycle()
    assert plan.action is S and plan.entry_id != record.entry_id


def test_ids_increase_and_are_unique() -> None:
    d = Driver(make_ctl(), FakeWorld(three_objects()), FakeMemory())
    d.run(30)
    rids = [q.request_id for q in d.memory.requests]
    gids = [p.goal.goal_id for p, _ in d.log if p.goal is not None]
    assert rids == sorted(set(rids)) and gids == sorted(set(gids)) and len(gids) > 10
    assert [p.cycle for p, _ in d.log] == list(range(1, 31))
    assert [r.cycle for _, r in d.log] == list(range(1, 31))


def test_protocol_misuse_raises() -> None:
    ctl = make_ctl()
    with pytest.raises(RuntimeError):
        ctl.end_cycle(None, 0.0)
    for _ in range(2):                 # an entry settles after two agreeing looks
        ctl.observe(FakeWorld(three_objects()).rois(), 0.0)
    ctl.begin_cycle(0.0)
    with pytest.raises(RuntimeError):
        ctl.begin_cycle(0.0)


def test_empty_map_gives_an_idle_uncounted_cycle() -> None:
    ctl = make_ctl()
    plan = ctl.begin_cycle(0.0)
    assert plan.idle and plan.goal is None and plan.entry_id == -1
    assert ctl.match_request() is None
    record = ctl.end_cycle(None, 0.0)
    assert record.outcome == "none" and ctl.counters.cycles == 0


def test_qlearning_policy_switch_learns_and_maps_everything() -> None:
    d = Driver(make_ctl("qlearning", seed=3), FakeWorld(three_objects()), FakeMemory())
    records = d.run(80)
    assert d.ctl.spatial_map.all_mapped() and len(d.ctl.mapped_positions()) == 3
    assert len(d.ctl.td_errors) == 80 and all(r.td_error is not None for r in records)
    assert d.ctl.counters.new_objects == 3
    rewarded = [r for r in records if r.reward > 0]
    assert rewarded and all(r.action is M for r in rewarded)


def test_no_transition_is_terminal_so_the_shift_is_valued() -> None:
    d = Driver(make_ctl("qlearning", seed=3), FakeWorld(three_objects()), FakeMemory())
    d.run(80)
    table = d.ctl.policy.table
    # A shift is worth gamma times the best value of the state it lands in, and a map
    # update what follows it: both learnt like any other action (docs/attention.md).
    assert table.value(State.from_bits("101"), S) > 0.0, table.q


def test_learned_greedy_table_runs_without_learning() -> None:
    table = QTable()
    train_qtable(FsmEnv(), table, 300, np.random.default_rng(0), seed=0)
    d = Driver(make_ctl("qlearning", learn=False, table=table), FakeWorld(three_objects()),
               FakeMemory())
    before = table.q.copy()
    records = d.run(12)
    assert d.ctl.spatial_map.all_mapped()
    assert [r.action for r in records].count(S) == 3      # never abandons an unmapped ROI
    assert all(r.td_error is None for r in records)
    np.testing.assert_array_equal(table.q, before)


def test_same_seed_same_run() -> None:
    def run(seed: int) -> list[tuple[str, str, str]]:
        d = Driver(make_ctl("qlearning", seed=seed), FakeWorld(three_objects()), FakeMemory())
        return [(r.state_before, r.action.name, r.state_after) for r in d.run(40)]

    assert run(8) == run(8)
    assert run(8) != run(9)


def test_the_eyes_stand_still_within_one_pixel_and_unknown_views_count_as_moved() -> None:
    camera = CameraModel(128, 128, focal_px=100.0)      # one pixel: 0.01 rad

    def turned(rad: float, dx: float = 0.0) -> EyePose:
        c, s = np.cos(rad), np.sin(rad)
        return EyePose(np.array([dx, 0.0, 0.7]), np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]))

    here = turned(0.0)
    assert eyes_still(here, turned(0.004), camera)             # an improvement's re-verging
    assert not eyes_still(here, turned(0.02), camera)          # two pixels: a shift
    assert not eyes_still(here, turned(0.0, dx=0.01), camera)  # the neck moved the eye
    # The controller compares each frame with the one before; the first, or one without
    # a pose, is taken as a new view (the map then takes every ROI as it is).
    ctl = AttentionController(AttentionConfig(), make_policy("straightforward",
                                                             AttentionConfig(),
                                                             np.random.default_rng(0)),
                              np.random.default_rng(0))
    seen: list[bool] = []
    real_update = ctl.spatial_map.update

    def update(rois, now, visible=None, still=False):  # type: ignore[no-untyped-def]
        seen.append(still)
        return real_update(rois, now, visible, still)

    ctl.spatial_map.update = update  # type: ignore[method-assign]
    for pose in (here, turned(0.004), None, here, turned(0.3)):
        ctl.observe([], 0.0, None, camera if pose is not None else None, pose)
    assert seen == [False, True, False, False, False]
