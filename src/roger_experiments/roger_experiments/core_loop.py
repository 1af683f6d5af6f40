"""The attention loop called directly in one process, without ROS.

The same core code the graph runs (Simulator, Perception, AssociativeMemory,
AttentionController), driven by the same cycle protocol as the attention node. Used by
tests on many worlds, by the benchmark (graph vs core) and by anyone who wants the
science without the middleware.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from roger_attention.config import AttentionConfig
from roger_attention.controller import AttentionController, CycleRecord
from roger_attention.policies import Policy, make_policy
from roger_common.errors import ConfigError
from roger_common.types import Action, ControllerReport, MatchResult, StereoFrame, WorldSpec
from roger_experiments.evaluation import CycleRow, RunRecorder, object_under_window
from roger_memory.config import MemoryConfig
from roger_memory.memory import AssociativeMemory
from roger_perception.config import PerceptionConfig
from roger_perception.perception import STAGES, Perception
from roger_sim.config import SimConfig
from roger_sim.simulator import Simulator

#: Stages of ``CoreLoop.stage_seconds``: the simulator (servo control, physics, renders),
#: perception, the memory, the attention controller, and perception's own stages
#: (``perception.<stage>``, see roger_perception.perception.STAGES).
LOOP_STAGES: tuple[str, ...] = ("sim", "perception", "memory", "policy",
                                *(f"perception.{s}" for s in STAGES))



def with_light(config: PerceptionConfig, world: WorldSpec,
               sim_config: SimConfig) -> PerceptionConfig:
    """``config`` told the light the simulator renders ``world`` under: the world file's
    ``light_direction`` and the simulator's ``light_ambient`` and ``light_diffuse``
    (``PerceptionConfig.light_direction``; the extended mode's AS divides by it)."""
    return replace(config, light_direction=world.light_direction,
                   light_ambient=sim_config.light_ambient,
                   light_diffuse=sim_config.light_diffuse)

@dataclass
class CoreLoop:
    """One robot, one world, one policy: ``step()`` runs one control cycle.

    ``agent`` replaces the named policy (e.g. an outside learner choosing every action);
    ``stage_seconds`` holds the wall seconds spent in each of LOOP_STAGES so far.
    """

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
    agent: Policy | None = None

    def __post_init__(self) -> None:
        mode = self.perception_config.features
        wanted = self.memory.config.features if self.memory is not None \
            else self.memory_config.features
        if mode != wanted:
            raise ConfigError(f"perception computes {mode}-mode features but the memory "
                              f"compares {wanted}-mode ones: give both one feature mode")
        cfg = self.attention_config or AttentionConfig(policy=self.policy)
        # The robot knows its light as it knows its camera: the world's and the simulator's.
        self.perception_config = with_light(self.perception_config, self.world,
                                            self.sim_config)
        self.sim = Simulator(self.world, self.sim_config, seed=self.seed)
        self.perception = Perception(self.perception_config)
        if self.memory is None:
            self.memory = AssociativeMemory(self.memory_config, seed=self.seed)
        rng = np.random.default_rng(self.seed)
        chosen = self.agent or make_policy(cfg.policy, cfg, rng, qtable_path=self.qtable_path,
                                           learn=self.learn)
        self.ctl = AttentionController(cfg, chosen, rng)
        self.last_frame: StereoFrame | None = None
        #: The convergence report of the last goal executed.
        self.last_report: ControllerReport | None = None
        #: True once ``cycles`` stopped by the robot's completion rule.
        self.complete = False
        self.stage_seconds: dict[str, float] = dict.fromkeys(LOOP_STAGES, 0.0)
        self._look()

    @contextmanager
    def _timed(self, stage: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.stage_seconds[stage] += time.perf_counter() - t0

    def _perceive(self, frame: StereoFrame) -> None:
        self.last_frame = frame
        with self._timed("perception"):
            rois = self.perception.process(frame, self.ctl.mapped_positions())
        for stage, seconds in self.perception.last_timings.items():
            self.stage_seconds[f"perception.{stage}"] += seconds
        with self._timed("policy"):
            self.ctl.observe(rois, frame.stamp,
                             self.ctl.visibility(frame.camera, frame.left_pose),
                             frame.camera, frame.left_pose)

    def _look(self) -> None:
        while (look := self.ctl.next_look()) is not None:
            with self._timed("sim"):
                _, frame = self.sim.run_goal(look)
            self._perceive(frame)

    def step(self) -> CycleRecord | None:
        """One control cycle; None when there was nothing to attend to (an idle look)."""
        assert self.memory is not None
        with self._timed("policy"):
            plan = self.ctl.begin_cycle(self.sim.sim_time)
        if plan.idle:
            self.ctl.end_cycle(None, self.sim.sim_time)
            self._look()
            return None
        result: MatchResult | None = None
        request = plan.memory_request
        if plan.goal is not None:
            with self._timed("sim"):
                self.last_report, frame = self.sim.run_goal(plan.goal)
            self._perceive(frame)
            with self._timed("policy"):
                request = self.ctl.match_request()
        if request is not None:
            with self._timed("memory"):
                result = self.memory.handle(request)
        with self._timed("policy"):
            return self.ctl.end_cycle(result, self.sim.sim_time)

    def cycles(self, n: int, max_idle: int = 50,
               stop_when_complete: int = 0) -> Iterator[CycleRecord]:
        """Run until ``n`` control cycles are counted, yielding each record; idle looks (an
        empty map) are not yielded, and ``max_idle`` of them end the run early. With
        ``stop_when_complete`` the run also ends (``complete`` set) once the controller
        judges the inspection complete (AttentionController.complete), as the attention
        node does with the parameter of that name."""
        idle = 0
        while self.ctl.counters.cycles < n and idle < max_idle:
            if stop_when_complete and self.ctl.complete(stop_when_complete):
                self.complete = True
                return
            record = self.step()
            if record is None:
                idle += 1
                continue
            yield record

    def true_object(self, record: CycleRecord) -> str | None:
        """Ground truth: the object that fills the attention window of a physical cycle
        (None for a map update and for a "lost" cycle, which looked at nothing)."""
        frame = self.last_frame
        if (record.action == Action.MAP_UPDATE or record.outcome == "lost"
                or record.bbox is None or frame is None or frame.left_labels is None):
            return None
        return object_under_window(frame.left_labels, frame.label_names, record.bbox)

    def converged(self, record: CycleRecord) -> bool | None:
        """Whether the servo goal of a physical cycle converged (None for a map update); a
        haptic improvement on an object beyond reach fails."""
        report = self.last_report
        if record.goal_id == 0 or report is None or report.goal_id != record.goal_id:
            return None
        return report.converged

    def close(self) -> None:
        """Release the simulator; a learning Q-table with a file is saved there."""
        if self.learn and self.qtable_path is not None and self.ctl.policy.learns:
            self.ctl.policy.save(self.qtable_path)
        self.sim.close()


def row_from_record(record: CycleRecord, true_object: str | None, sim_time: float,
                    converged: bool | None = None) -> CycleRow:
    """A CycleRecord as an evaluation row."""
    return CycleRow(cycle=record.cycle, state=record.state_before, action=int(record.action),
                    reward=record.reward, td_error=record.td_error, roi=record.entry_id,
                    true_object=true_object, outcome=record.outcome,
                    state_after=record.state_after, address=record.address,
                    position=record.position, sim_time=sim_time, converged=converged)


def run_core(world: WorldSpec, policy: str, cycles: int, seed: int = 0,
             out: Path | None = None, stop_when_complete: int = 0,
             features: str | None = None,
             **kwargs: Any) -> tuple[RunRecorder | None, CoreLoop]:
    """Run ``cycles`` control cycles in process (fewer when ``stop_when_complete`` ends the
    run by the robot's completion rule); record them to ``out`` if given.

    ``features`` (a FeatureMode name) sets the mode of perception and memory, with each
    one's calibrated defaults (give ``perception_config``/``memory_config`` instead for
    other values).

    Returns:
        The recorder (None without ``out``) and the loop (for its counters and map).
    """
    if features is not None:
        kwargs.setdefault("perception_config", PerceptionConfig(features=features))
        kwargs.setdefault("memory_config", MemoryConfig.for_mode(features))
    loop = CoreLoop(world, policy=policy, seed=seed, **kwargs)
    recorder = None
    if out is not None:
        recorder = RunRecorder(out, list(world.objects),
                               {"policy": policy, "world": world.source, "seed": seed,
                                "features": loop.perception_config.features})
    try:
        for record in loop.cycles(cycles, stop_when_complete=stop_when_complete):
            seen = loop.true_object(record)
            if recorder is not None:
                true_obj = recorder.scorer.true_object_for(int(record.action),
                                                           record.entry_id, seen,
                                                           record.outcome)
                recorder.add(row_from_record(record, true_obj, loop.sim.sim_time,
                                             loop.converged(record)))
                recorder.counters = record.counters.as_dict()
    finally:
        loop.close()
    if recorder is not None:
        recorder.complete = loop.complete
    return recorder, loop
