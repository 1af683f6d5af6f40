"""The paper's property: both policies visit every object of the world at least once.

Runs the real core loop (simulator, perception, memory, attention) without ROS on the
shipped worlds and on random worlds the code has never seen, and checks that every object
came under the attention window within a bounded number of cycles, and that an object added
mid-run is visited and mapped.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import WORLDS

from roger_attention.config import AttentionConfig
from roger_attention.fsm_env import FsmEnv, train_qtable
from roger_attention.qlearning import QTable
from roger_experiments.core_loop import CoreLoop, run_core
from roger_sim.world import load_world, object_from_dict
from roger_sim.worldgen import random_world


def visit_all(loop: CoreLoop, names: set[str], budget: int) -> tuple[set[str], int]:
    """Step until every named object was under the window or the budget is spent."""
    seen: set[str] = set()
    while loop.ctl.counters.cycles < budget and not names <= seen:
        record = loop.step()
        if record is None:
            continue
        obj = loop.true_object(record)
        if obj is not None:
            seen.add(obj)
    return seen, loop.ctl.counters.cycles


WORLD_CASES = [
    ("table1", lambda: load_world(WORLDS / "table1.yaml")),
    ("shapes", lambda: load_world(WORLDS / "shapes.yaml")),
    ("random_3x2_s11", lambda: random_world(3, 2, seed=11)),
    ("random_5x1_s12", lambda: random_world(5, 1, seed=12, size_range=(0.08, 0.14))),
]


@pytest.mark.parametrize("policy", ["straightforward", "qlearning"])
@pytest.mark.parametrize("name, make", WORLD_CASES, ids=[c[0] for c in WORLD_CASES])
def test_every_object_is_visited(policy, name, make):
    world = make()
    names = {o.name for o in world.objects}
    budget = 30 + 12 * len(names)
    loop = CoreLoop(world, policy=policy, seed=7)
    try:
        seen, cycles = visit_all(loop, names, budget)
        c = loop.ctl.counters
        assert c.attention_shifts + c.improvements + c.map_updates == c.cycles
        assert c.map_updates == c.positive_identifications + c.new_objects + c.remaps
    finally:
        loop.close()
    assert names <= seen, f"{policy} on {name}: never visited {sorted(names - seen)} " \
                          f"in {cycles} cycles"


def learnt_table(path: Path) -> Path:
    """A Q-table learnt on the FSM fixture (it prefers an improvement to a shift in 000).

    A table of zeros learning with epsilon 0.1 can dither for dozens of cycles between two
    undetermined entries (improve once, shift, improve once, shift back: the shift's
    bootstrapped value beats an untried final trial; docs/attention.md); the Q-learning
    policy is judged with a learnt table, as roger compare runs it.
    """
    table = QTable()
    train_qtable(FsmEnv(), table, 300, np.random.default_rng(0), seed=0)
    table.save(path)
    return path


@pytest.mark.parametrize("policy", ["straightforward", "qlearning"])
def test_object_added_mid_run_is_visited_and_mapped(policy, tmp_path):
    world = load_world(WORLDS / "table1.yaml")
    table = learnt_table(tmp_path / "q.json") if policy == "qlearning" else None
    loop = CoreLoop(world, policy=policy, seed=3, qtable_path=table, learn=table is None,
                    attention_config=AttentionConfig(policy=policy))
    try:
        visit_all(loop, {o.name for o in world.objects}, 80)
        spec = object_from_dict({"name": "late", "shape": "cylinder", "position": [0.5, 0.0],
                                 "size": 0.12, "intensity": 120, "weight": 0.7},
                                "test", "late")
        loop.sim.add_object(spec)
        start = loop.ctl.counters.cycles
        seen: set[str] = set()
        mapped = False
        while loop.ctl.counters.cycles < start + 80 and not mapped:
            record = loop.step()
            if record is None:
                continue
            if loop.true_object(record) == "late":
                seen.add("late")
            mapped = any(e.mapped and math.dist(e.position[:2], (0.5, 0.0)) < 0.1
                         for e in loop.ctl.spatial_map)
    finally:
        loop.close()
    assert "late" in seen, "the added object never came under the attention window"
    assert mapped, "the added object was never mapped"


@pytest.mark.parametrize("policy", ["straightforward", "qlearning"])
def test_the_robots_completion_rule_ends_the_run_and_every_object_was_visited(policy,
                                                                                tmp_path):
    # The rule reads nothing but the robot's own state (no new representation for 40
    # cycles, no unmapped entry); the ground truth only judges afterwards. On a random
    # world whose objects never share a region of interest (where two do, the hidden one
    # is never visited whatever the rule: docs/attention.md).
    world = random_world(4, 2, seed=31, size_range=(0.10, 0.18))
    recorder, loop = run_core(world, policy, 2000, seed=0, out=tmp_path,
                              stop_when_complete=40)
    metrics = recorder.close(0.0)
    assert loop.complete and metrics["complete"] and metrics["cycles"] < 2000
    assert loop.ctl.cycles_since_new >= 40 and loop.ctl.spatial_map.all_mapped()
    assert metrics["every_object_visited"], sorted(
        {o.name for o in world.objects} - recorder.scorer.visited)
