"""The attention loop called directly in one process, without ROS.

The same core code the graph runs (Simulator, Perception, AssociativeMemory,
AttentionController), driven by the same cycle protocol as the attention node. Used by
tests on many worlds, by the benchmark (graph vs core) and by anyone who wants the
science without the middleware.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from roger_attention.config import AttentionConfig
from roger_attention.controller import AttentionController, CycleRecord
from roger_attention.policies import make_policy
from roger_bringup.evaluation import CycleRow, RunRecorder, object_under_window
from roger_common.geometry import in_view
from roger_common.types import Action, Goal, MatchResult, StereoFrame, WorldSpec
from roger_memory.config import MemoryConfig
from roger_memory.memory import AssociativeMemory
from roger_perception.config import PerceptionConfig
from roger_perception.perception import Perception
from roger_sim.config import SimConfig
from roger_sim.simulator import Simulator

#: The initial scan, as the attention node does it (its ``home_targets`` parameter): five
#: looks from far left to far right (bearings about +-60, +-28 and 0 degrees) that settle
#: the pre-attentional map over the whole workspace before the first cycle.
HOME_TARGETS: tuple[tuple[float, float, float], ...] = (
    (0.45, 0.7, 0.0), (0.75, 0.4, 0.0), (0.9, 0.0, 0.0), (0.75, -0.4, 0.0), (0.45, -0.7, 0.0))


@dataclass
class CoreLoop:
    """One robot, one world, one policy: ``step()`` runs one control cycle."""

    world: WorldSpec
    policy: str = "straightforward"
    seed: int = 0
    sim_config: SimConfig = field(default_factory=SimConfig)
    perception_config: PerceptionConfig = field(default_factory=PerceptionConfig)
    memory_config: MemoryConfig = field(default_factory=MemoryConfig)
    attention_config: AttentionConfig | None = None
    qtable_path: Path | None = None
    learn: bool = True
    memory: AssociativeMemory | None = None

    def __post_init__(self) -> None:
        cfg = self.attention_config or AttentionConfig(policy=self.policy)
        self.sim = Simulator(self.world, self.sim_config, seed=self.seed)
        self.perception = Perception(self.perception_config)
        if self.memory is None:
            self.memory = AssociativeMemory(self.memory_config, seed=self.seed)
        rng = np.random.default_rng(self.seed)
        self.policy_obj = make_policy(cfg.policy, cfg, rng, qtable_path=self.qtable_path,
                                      learn=self.learn)
        self.ctl = AttentionController(cfg, self.policy_obj, rng)
        self.last_frame: StereoFrame | None = None
        self._look()

    def _perceive(self, frame: StereoFrame) -> None:
        self.last_frame = frame
        rois = self.perception.process(frame, self.ctl.mapped_positions())
        pose, camera = frame.left_pose, frame.camera
        margin = 0.1 * camera.width
        self.ctl.observe(rois, frame.stamp, lambda p: in_view(camera, pose, p, margin))

    def _look(self) -> None:
        for target in HOME_TARGETS:
            _, frame = self.sim.run_goal(Goal(0, Action.ATTENTION_SHIFT, target))
            self._perceive(frame)

    def step(self) -> CycleRecord | None:
        """One control cycle; None when there was nothing to attend to (an idle look)."""
        assert self.memory is not None
        plan = self.ctl.begin_cycle(self.sim.sim_time)
        if plan.idle:
            self.ctl.end_cycle(None, self.sim.sim_time)
            self._look()
            return None
        result: MatchResult | None = None
        if plan.goal is not None:
            _, frame = self.sim.run_goal(plan.goal)
            self._perceive(frame)
            req = self.ctl.match_request()
            if req is not None:
                result = self.memory.handle(req)
        elif plan.memory_request is not None:
            result = self.memory.handle(plan.memory_request)
        return self.ctl.end_cycle(result, self.sim.sim_time)

    def cycles(self, n: int, max_idle: int = 50) -> Iterator[CycleRecord]:
        """Run until ``n`` control cycles are counted, yielding each record; idle looks (an
        empty map) are not yielded, and ``max_idle`` of them end the run early."""
        idle = 0
        while self.ctl.counters.cycles < n and idle < max_idle:
            record = self.step()
            if record is None:
                idle += 1
                continue
            yield record

    def true_object(self, record: CycleRecord) -> str | None:
        """Ground truth: the object under the attention window of a physical cycle."""
        frame = self.last_frame
        if (record.action == Action.MAP_UPDATE or record.bbox is None or frame is None
                or frame.left_labels is None):
            return None
        return object_under_window(frame.left_labels, frame.label_names, record.bbox)

    def close(self) -> None:
        """Release the simulator."""
        self.sim.close()


def row_from_record(record: CycleRecord, true_object: str | None, sim_time: float) -> CycleRow:
    """A CycleRecord as an evaluation row."""
    return CycleRow(cycle=record.cycle, state=record.state_before, action=int(record.action),
                    reward=record.reward, td_error=record.td_error, roi=record.entry_id,
                    true_object=true_object, outcome=record.outcome,
                    state_after=record.state_after, address=record.address,
                    position=record.position, sim_time=sim_time)


def run_core(world: WorldSpec, policy: str, cycles: int, seed: int = 0,
             out: Path | None = None, **kwargs: Any) -> tuple[RunRecorder | None, CoreLoop]:
    """Run ``cycles`` control cycles in process; record them to ``out`` if given.

    Returns:
        The recorder (None without ``out``) and the loop (for its counters and map).
    """
    loop = CoreLoop(world, policy=policy, seed=seed, **kwargs)
    recorder = None
    if out is not None:
        recorder = RunRecorder(out, list(world.objects),
                               {"policy": policy, "world": world.source, "seed": seed})
    try:
        for record in loop.cycles(cycles):
            seen = loop.true_object(record)
            if recorder is not None:
                true_obj = recorder.scorer.true_object_for(int(record.action),
                                                           record.entry_id, seen)
                recorder.add(row_from_record(record, true_obj, loop.sim.sim_time))
                recorder.counters = record.counters.as_dict()
    finally:
        loop.close()
    return recorder, loop
