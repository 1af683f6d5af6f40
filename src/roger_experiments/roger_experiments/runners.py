"""What runs a run: the run as data (``RunSpec``), the jobs of an experiment, and the
runners that are passed into one (Table 2, a sweep).

A run is a pure function of its ``RunSpec``: the same spec writes the same cycles.csv,
whoever runs it. The runners here run jobs one after another in this process
(``SequentialRunner``) with ``run_in_process`` (the core loop without ROS) or the graph's
``roger_bringup.graph_run.run_spec_graph``; ``ray_runner.RayRunner`` runs them as Ray
tasks.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import yaml

from roger_common.types import WorldSpec
from roger_experiments.train import TrainDraw, fresh_table
from roger_sim.world import parse_world

#: Most cycles a run until the robot's own completion may take.
COMPLETE_MAX = 2000


@dataclass(frozen=True)
class RunSpec:
    """One run: a pure function of these fields (same spec, same cycles.csv).

    The world and the Q-table travel as text, so a run needs no file of the machine that
    asked for it (a Ray worker elsewhere).

    Attributes:
        world: The world file's name as given (metrics.json's ``world``).
        world_text: The world file's content.
        policy: "qlearning" or "straightforward".
        seed: Seed of every random choice.
        cycles: Control cycles; None runs until the robot's own completion rule
            (``stable_cycles``), at most ``max_cycles``.
        features: Feature mode of perception and memory.
        qtable_text: A Q-table (qtable.json's content) run greedy and frozen; None learns
            online from zeros (as ``roger run`` without a table) into the run's
            qtable.json.
        stable_cycles: See ``Table2Spec``.
        max_cycles: Most cycles of a run until completion.
        alpha_schedule: The step-size schedule (``QLearningConfig.alpha_schedule``) of a
            Q-learning run that learns online (no ``qtable_text``); a given table keeps
            the schedule it learnt with.
    """

    world: str
    world_text: str
    policy: str
    seed: int
    cycles: int | None
    features: str
    qtable_text: str | None = None
    stable_cycles: int = 40
    max_cycles: int = COMPLETE_MAX
    alpha_schedule: str = "constant"

    @classmethod
    def of_file(cls, world: Path, **kwargs: Any) -> RunSpec:
        """A spec for a world file (its text read now)."""
        return cls(str(world), world.read_text(encoding="utf-8"), **kwargs)

    def load_world(self) -> WorldSpec:
        """The world, parsed from the text (named by ``world`` in messages)."""
        return parse_world(yaml.safe_load(self.world_text), self.world)

    def label(self) -> str:
        """Short words for progress lines."""
        return f"{self.policy}, seed {self.seed}"


#: Runs one run into an empty folder and returns its metrics (metrics.json's content).
RunFn = Callable[[RunSpec, Path], dict[str, Any]]


@dataclass(frozen=True)
class Job:
    """A run (or a sweep's training draw) and the folder its files end up in, with files
    of the caller's to put there with them (a sweep's cell.json)."""

    spec: RunSpec | TrainDraw
    out: Path
    extra: dict[str, bytes] = field(default_factory=dict)


class Runner(Protocol):
    """Runs jobs and yields each with its metrics, or with the exception it raised, as they
    finish (in any order). Only the runner's caller's process writes the jobs' folders."""

    def __call__(self, jobs: Sequence[Job]) -> Iterator[tuple[Job, dict[str, Any] | Exception]]:
        ...


def run_in_process(spec: RunSpec, out: Path) -> dict[str, Any]:
    """One run of the core loop in this process, without ROS (``roger compare
    --in-process``, ``roger sweep`` with ``mode: in_process``)."""
    from roger_experiments.core_loop import run_core

    t0 = time.monotonic()
    with materialized_qtable(spec, out) as (qtable, learn):
        recorder, _ = run_core(spec.load_world(), spec.policy,
                               spec.max_cycles if spec.cycles is None else spec.cycles,
                               seed=spec.seed, out=out,
                               stop_when_complete=spec.stable_cycles if spec.cycles is None
                               else 0, qtable_path=qtable, learn=learn,
                               features=spec.features)
    assert recorder is not None
    return recorder.close(time.monotonic() - t0)


#: Prefixes of the runs' scratch folders in the temporary directory (``scratch_dir``).
SCRATCH_PREFIXES: tuple[str, ...] = ("roger-run-", "roger-qtable-")
#: The file in a scratch folder that names the process that made it.
OWNER_FILE = "owner.pid"


def scratch_dir(prefix: str) -> Path:
    """A new scratch folder in the temporary directory, marked with this process's pid.

    Its maker removes it when the run ends; a worker killed mid-run (a chaos test, a
    killed sweep) cannot, so every new folder first removes the orphans of dead makers
    on this machine (``remove_orphan_scratch``).
    """
    remove_orphan_scratch()
    path = Path(tempfile.mkdtemp(prefix=prefix))
    (path / OWNER_FILE).write_text(str(os.getpid()))
    return path


def remove_orphan_scratch(root: Path | None = None) -> int:
    """Remove the scratch folders (``SCRATCH_PREFIXES``) under ``root`` (the temporary
    directory) whose maker's pid is no live process; returns how many. A folder without
    an owner file (not made by ``scratch_dir``, or being made) is left alone, and so is
    one whose pid a live process holds (possibly reused: kept on the safe side)."""
    root = Path(tempfile.gettempdir()) if root is None else Path(root)
    removed = 0
    for prefix in SCRATCH_PREFIXES:
        for folder in root.glob(prefix + "*"):
            try:
                pid = int((folder / OWNER_FILE).read_text())
            except (OSError, ValueError):
                continue
            if not _alive(pid):
                shutil.rmtree(folder, ignore_errors=True)
                removed += 1
    return removed


def _alive(pid: int) -> bool:
    """Whether a process of that pid exists on this machine."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@contextmanager
def materialized_qtable(spec: RunSpec, out: Path) -> Iterator[tuple[Path | None, bool]]:
    """The Q-table file a run reads and whether it learns: a scratch copy of
    ``spec.qtable_text`` (frozen), or, for a Q-learning run without one, the run's own
    ``out/qtable.json`` (learning from a fresh table of ``spec.alpha_schedule``); (None,
    False) for the straightforward policy."""
    if spec.policy != "qlearning":
        yield None, False
    elif spec.qtable_text is None:
        if spec.alpha_schedule != "constant":
            fresh_table(out, spec.alpha_schedule)  # the table keeps it while it learns
        yield out / "qtable.json", True
    else:
        scratch = scratch_dir("roger-qtable-")
        try:
            (scratch / "qtable.json").write_text(spec.qtable_text)
            yield scratch / "qtable.json", False
        finally:
            shutil.rmtree(scratch, ignore_errors=True)


@dataclass
class SequentialRunner:
    """Runs the jobs one after another in this process with ``run`` (in process or the
    graph), straight into their folders. A failing run stops the runner unless
    ``keep_going``.

    Each run gets an empty folder, as ``RunFn`` promises and ``RayRunner`` gives (it
    replaces the old folder with the new run's files): whatever an earlier run left in
    the job's folder is removed first. A graph run loads the ``memory.pt`` it finds in its
    folder, so a second ``make demo`` into ``runs/demo`` started every run with the first
    one's long-term memory and stored nothing (docs/experiments.md).
    """

    run: RunFn = run_in_process
    keep_going: bool = False

    def __call__(self, jobs: Sequence[Job]) -> Iterator[tuple[Job, dict[str, Any] | Exception]]:
        for job in jobs:
            assert isinstance(job.spec, RunSpec)
            if job.out.exists():
                shutil.rmtree(job.out)
            try:
                metrics = self.run(job.spec, job.out)
            except Exception as exc:
                if not self.keep_going:
                    raise
                yield job, exc
                continue
            yield job, metrics
