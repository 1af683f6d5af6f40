"""``roger bench``: how close the graph runs to its physical floor (docs/performance.md).

One invocation measures, under the same machine conditions:

* ``graph_vs_core``: control cycles/s of the multi-process graph (``run_graph``) divided by
  cycles/s of the same core loop (``CoreLoop``: same simulator, perception, memory and
  policy code, same world and seed) called directly in one process. Core and graph run
  in alternation, ``ROUNDS`` times each, and their cycles are pooled: a shared VM's speed
  drifts by tens of percent within a minute, and one core-then-graph pair can land on
  either side of the drift (``graph_vs_core_rounds`` keeps each round's ratio);
* ``cycle_vs_floor``: the graph's mean wall time per cycle divided by the floor, the wall
  time pybullet alone needs for the physics steps and the two retina renders of a cycle
  (``Simulator.floor_seconds``, measured in the core run of the same world and seed, which
  executes the same goals);
* ``stages``: milliseconds per cycle of every stage of the core loop, and ``transport``
  (graph minus core);
* ``scaling_64_vs_4``: core wall time per cycle with 64 objects over 4 objects;
* ``match_1000_vs_10``: memory match latency with 1,000 stored objects over 10;
* ``cycles_per_s_128`` and ``cycles_per_s_256``: graph cycles/s at both retina sizes.

Rates are steady-state: from the end of the first control cycle to the end of the last,
so process start-up and the initial scan are left out of both the graph and the core.
"""

from __future__ import annotations

import io
import itertools
import json
import math
import os
import platform
import shutil
import statistics
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Self

import numpy as np
import yaml

from roger_common.types import WorldSpec, feature_dim
from roger_experiments.core_loop import CoreLoop
from roger_experiments.evaluation import ACTION_NAMES
from roger_experiments.progress import ProgressBar
from roger_memory.config import MemoryConfig
from roger_memory.memory import AssociativeMemory
from roger_perception.perception import STAGES
from roger_sim.config import SimConfig
from roger_sim.world import load_world, world_to_dict
from roger_sim.worldgen import random_world

#: Alternating core and graph runs whose cycles are pooled for ``graph_vs_core``.
ROUNDS = 3
#: The world of ``make demo`` (24 objects), relative to the repository root.
DEFAULT_WORLD = Path("worlds/inspection.yaml")
#: The issue's targets (docs/performance.md); ``*_max`` are upper bounds.
TARGETS: dict[str, tuple[str, float]] = {
    "graph_vs_core": (">=", 0.8), "cycle_vs_floor": ("<=", 1.5),
    "scaling_64_vs_4": ("<=", 2.0), "match_1000_vs_10": ("<=", 3.0)}


def _repo_root() -> Path:
    """The repository root (this file is src/roger_bringup/roger_bringup/bench.py)."""
    here = Path(__file__).resolve().parents[3]
    return here if (here / DEFAULT_WORLD).exists() else Path.cwd()


@dataclass
class CoreRun:
    """What one timed run of the in-process core loop measured."""

    cycles: int
    ends: list[float]
    floor: list[float]
    stages: dict[str, float]
    actions: list[str]
    physics_steps: int
    wall_s: float

    @property
    def seconds_per_cycle(self) -> float:
        """Steady-state wall seconds per cycle (end of cycle 1 to end of the last)."""
        return _steady(self.ends)

    @property
    def floor_per_cycle(self) -> float:
        """pybullet physics + render seconds per cycle over the same window."""
        if len(self.floor) < 2:
            return math.nan
        return (self.floor[-1] - self.floor[0]) / (len(self.floor) - 1)


def pool_core(runs: list[CoreRun]) -> CoreRun:
    """Several core runs as one: their steady-state cycles and stage times pooled."""
    if len(runs) == 1:
        return runs[0]
    n = [max(1, r.cycles - 1) for r in runs]
    total = sum(n)
    ends = _pool_ends([r.ends for r in runs])
    floor = _pool_ends([r.floor for r in runs])
    stages = {k: sum(r.stages.get(k, 0.0) * w for r, w in zip(runs, n)) / total
              for k in runs[0].stages}
    return CoreRun(cycles=len(ends), ends=ends, floor=floor, stages=stages,
                   actions=runs[0].actions, physics_steps=runs[0].physics_steps,
                   wall_s=sum(r.wall_s for r in runs))


def _pool_ends(rounds: list[list[float]]) -> list[float]:
    """The steady-state intervals of several runs, end to end."""
    steps = [b - a for r in rounds for a, b in zip(r, r[1:])]
    return list(itertools.accumulate(steps, initial=0.0))


def _steady(ends: list[float]) -> float:
    if len(ends) < 2:
        return math.nan
    return (ends[-1] - ends[0]) / (len(ends) - 1)


def run_core_timed(world: WorldSpec, cycles: int, seed: int = 0, image_size: int = 128,
                   policy: str = "straightforward") -> CoreRun:
    """Run the core loop for ``cycles`` control cycles, timing every stage.

    Stage times (ms per cycle, over every cycle after the first) come from the loop's own
    ``stage_seconds`` and the simulator's ``floor_seconds``.
    """
    t_start = time.perf_counter()
    loop = CoreLoop(world, policy=policy, seed=seed,
                    sim_config=SimConfig(image_size=image_size))
    ends: list[float] = []
    floor: list[float] = []
    actions: list[str] = []
    base: dict[str, float] = {}
    try:
        for record in loop.cycles(cycles):
            ends.append(time.perf_counter())
            fs = loop.sim.floor_seconds
            floor.append(fs["physics"] + fs["render"])
            actions.append(f"{ACTION_NAMES.get(int(record.action))}@{loop.sim.sim_time:.4f}"
                           f":{record.outcome}:{record.address}")
            if len(ends) == 1:  # stages are counted from the end of the first cycle
                base = {**loop.stage_seconds, **fs}
        fs = loop.sim.floor_seconds
        steps = loop.sim.physics_steps
    finally:
        loop.close()
    now = {**loop.stage_seconds, **fs}
    n = max(1, len(ends) - 1)
    d = {k: (now.get(k, 0.0) - base.get(k, 0.0)) * 1e3 / n for k in now}
    stages = {
        "render": d.get("render", 0.0),
        "physics": d.get("physics", 0.0),
        "servo_control": d.get("sim", 0.0) - d.get("render", 0.0) - d.get("physics", 0.0),
        "log": d.get("perception.log", 0.0),
        "segment": d.get("perception.segment", 0.0),
        "stereo_match": d.get("perception.match", 0.0),
        "features": d.get("perception.features", 0.0),
        "activation": d.get("perception.activation", 0.0),
        "memory_matching": d.get("memory", 0.0),
        "policy": d.get("policy", 0.0),
    }
    accounted = (d.get("sim", 0.0) + d.get("perception", 0.0) + d.get("memory", 0.0)
                 + d.get("policy", 0.0))
    stages["perception_other"] = d.get("perception", 0.0) - sum(
        d.get(f"perception.{k}", 0.0) for k in STAGES)
    stages["loop_other"] = _steady(ends) * 1e3 - accounted if len(ends) > 1 else 0.0
    return CoreRun(cycles=len(ends), ends=ends, floor=floor, stages=stages, actions=actions,
                   physics_steps=steps, wall_s=time.perf_counter() - t_start)


class _CsvWatcher:
    """Time-stamps the rows of a growing cycles.csv from another thread (10 ms polls)."""

    def __init__(self, path: Path, period: float = 0.01) -> None:
        self.path, self.period = path, period
        self.ends: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._offset = 0
        self._header = True

    def __enter__(self) -> Self:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self._poll()

    def _poll(self) -> None:
        try:
            with open(self.path, "rb") as fh:
                fh.seek(self._offset)
                chunk = fh.read()
        except FileNotFoundError:
            return
        complete = chunk[: chunk.rfind(b"\n") + 1]
        self._offset += len(complete)
        lines = complete.count(b"\n")
        if self._header and lines:
            lines -= 1
            self._header = False
        now = time.perf_counter()
        self.ends.extend([now] * lines)

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            self._poll()


def run_graph_timed(world_path: Path, out: Path, cycles: int, seed: int = 0,
                    image_size: int = 128) -> dict[str, Any]:
    """Run the real multi-process graph and time-stamp each recorded cycle."""
    from roger_bringup.run import RunOptions, run_graph

    # A fresh folder: a memory, Q-table or resume state left there by an earlier run
    # would be loaded, and the graph would not run what the core runs.
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    opt = RunOptions(world=world_path, out=out, cycles=cycles, seed=seed,
                     image_size=image_size, progress=False)
    t0 = time.perf_counter()
    with _CsvWatcher(out / "cycles.csv") as watcher:
        metrics = run_graph(opt, log=io.StringIO())
    with open(out / "cycles.csv") as fh:
        header = fh.readline().strip().split(",")
        a, t = header.index("action"), header.index("sim_time")
        o, m = header.index("outcome"), header.index("address")
        rows = [line.strip().split(",") for line in fh if line.strip()]
    actions = [f"{r[a]}@{float(r[t]):.4f}:{r[o]}:{r[m]}" for r in rows]
    return {"ends": watcher.ends, "actions": actions, "wall_s": time.perf_counter() - t0,
            "metrics": metrics}


def match_latency(n: int, queries: int, seed: int = 0) -> float:
    """Median seconds of one memory match with ``n`` objects stored (random patterns)."""
    rng = np.random.default_rng(seed)
    config = MemoryConfig()  # the default feature mode's, as a run's
    dim = feature_dim(config.features)
    patterns = rng.random((n, dim)).astype(np.float32)
    known = np.ones((n, dim), bool)
    memory = AssociativeMemory(config, seed=seed)
    memory.store_many(patterns, known)
    for i in range(5):  # warm-up
        memory.match(patterns[i % n], known[i % n])
    times = []
    for i in rng.integers(0, n, queries):
        q = np.clip(patterns[i] + rng.normal(0.0, 0.01, dim), 0.0, 1.0)
        t0 = time.perf_counter()
        memory.match(q, known[i])
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _ratio(a: float, b: float) -> float:
    return a / b if b > 0 and math.isfinite(a) and math.isfinite(b) else math.nan


def _rate(ends: list[float]) -> float:
    s = _steady(ends)
    return 1.0 / s if s > 0 else math.nan


def main_bench(out: Path, quick: bool = False, world: Path | None = None,
               log: Callable[[str], None] = print, progress: bool = True) -> dict[str, Any]:
    """Run every measurement once, write ``out/bench.json`` and print a table.

    Args:
        out: Output folder (graph runs go to ``out/graph_*``).
        quick: A few cycles only (smoke test; the ratios are then noisy).
        world: World file of the graph-vs-core runs (default worlds/inspection.yaml).
        log: Where the table goes.
        progress: Show which measurement runs (a bar on a terminal, lines otherwise).

    Returns:
        The content of bench.json.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    world_path = (world or _repo_root() / DEFAULT_WORLD).resolve()
    spec = load_world(world_path)
    cycles = 12 if quick else 204
    cycles_256 = 6 if quick else 60
    scale_cycles = 8 if quick else 100
    seed = 0
    t_all = time.perf_counter()

    rounds = 1 if quick else ROUNDS
    bar = ProgressBar(2 * rounds + 6, "roger bench", "measurements", enabled=progress)

    started = 0

    def step(what: str) -> None:
        """Show the measurement that starts now (the ones before it are done)."""
        nonlocal started
        bar.update(started, what)
        started += 1
    core_runs: list[CoreRun] = []
    graph_runs: list[dict[str, Any]] = []
    for i in range(rounds):
        tag = f" (round {i + 1} of {rounds})" if rounds > 1 else ""
        step(f"core loop, {cycles} cycles on {world_path.name}{tag}")
        core_runs.append(run_core_timed(spec, cycles, seed))
        step(f"graph, {cycles} cycles on {world_path.name}{tag}")
        graph_runs.append(run_graph_timed(world_path, out / ("graph_128" if i == 0 else
                                                             f"graph_128_{i + 1}"),
                                          cycles, seed))
    core = pool_core(core_runs)
    graph = {"ends": _pool_ends([g["ends"] for g in graph_runs]),
             "wall_s": sum(g["wall_s"] for g in graph_runs)}
    round_ratios = [_ratio(_rate(g["ends"]), 1.0 / c.seconds_per_cycle)
                    for g, c in zip(graph_runs, core_runs)]
    graph_rate = _rate(graph["ends"])
    core_rate = 1.0 / core.seconds_per_cycle
    graph_cycle_s = 1.0 / graph_rate if graph_rate > 0 else math.nan
    # Every graph run executed the same goals as the core loop (same actions, sim times)?
    same = all(g["actions"] == c.actions for g, c in zip(graph_runs, core_runs))
    first_difference = next((i + 1 for i, (a, b) in enumerate(zip(graph_runs[0]["actions"],
                                                                   core_runs[0].actions))
                             if a != b), None)

    step(f"core at 256 px, {cycles_256} cycles")
    core_256 = run_core_timed(spec, cycles_256, seed, image_size=256)
    step(f"graph at 256 px, {cycles_256} cycles")
    graph_256 = run_graph_timed(world_path, out / "graph_256", cycles_256, seed,
                                image_size=256)

    small = random_world(2, 2, seed=3, size_range=(0.05, 0.08), name="bench_4")
    large = random_world(16, 4, seed=3, size_range=(0.05, 0.08), name="bench_64")
    for w in (small, large):
        (out / f"{w.name}.yaml").write_text(yaml.safe_dump(world_to_dict(w), sort_keys=False))
    step(f"scaling, {scale_cycles} cycles on 4 objects")
    run_small = run_core_timed(small, scale_cycles, seed)
    step(f"scaling, {scale_cycles} cycles on 64 objects")
    run_large = run_core_timed(large, scale_cycles, seed)

    queries = 50 if quick else 300
    step("memory match with 10 objects")
    match_10 = match_latency(10, queries, seed)
    step("memory match with 1,000 objects")
    match_1000 = match_latency(1000, queries, seed)
    bar.close(bar.total, "done")

    stages = {k: round(v, 3) for k, v in core.stages.items()}
    stages["transport"] = round(graph_cycle_s * 1e3 - core.seconds_per_cycle * 1e3, 3)
    result: dict[str, Any] = {
        "graph_vs_core": _ratio(graph_rate, core_rate),
        "graph_vs_core_rounds": round_ratios,
        "cycle_vs_floor": _ratio(graph_cycle_s, core.floor_per_cycle),
        "core_vs_floor": _ratio(core.seconds_per_cycle, core.floor_per_cycle),
        "scaling_64_vs_4": _ratio(run_large.seconds_per_cycle, run_small.seconds_per_cycle),
        "match_1000_vs_10": _ratio(match_1000, match_10),
        "cycles_per_s_128": graph_rate,
        "cycles_per_s_256": _rate(graph_256["ends"]),
        "core_cycles_per_s_128": core_rate,
        "core_cycles_per_s_256": 1.0 / core_256.seconds_per_cycle,
        "graph_ms_per_cycle": graph_cycle_s * 1e3,
        "core_ms_per_cycle": core.seconds_per_cycle * 1e3,
        "floor_ms_per_cycle": core.floor_per_cycle * 1e3,
        "stages": stages,
        "scaling": {"ms_per_cycle_4": run_small.seconds_per_cycle * 1e3,
                    "ms_per_cycle_64": run_large.seconds_per_cycle * 1e3,
                    "steps_per_cycle_4": run_small.physics_steps / run_small.cycles,
                    "steps_per_cycle_64": run_large.physics_steps / run_large.cycles,
                    "floor_ms_4": run_small.floor_per_cycle * 1e3,
                    "floor_ms_64": run_large.floor_per_cycle * 1e3,
                    "stages_4": run_small.stages, "stages_64": run_large.stages},
        "match_us_10": match_10 * 1e6,
        "match_us_1000": match_1000 * 1e6,
        "graph_matches_core": same,
        "first_different_cycle": first_difference,
        "rounds": rounds,
        "cycles": {"graph": len(graph_runs[0]["ends"]), "core": core_runs[0].cycles,
                   "graph_256": len(graph_256["ends"]), "core_256": core_256.cycles,
                   "scaling_4": run_small.cycles, "scaling_64": run_large.cycles},
        "physics_steps": core.physics_steps,
        "graph_wall_s": graph["wall_s"],
        "core_wall_s": core.wall_s,
        "quick": quick,
        "world": str(world_path),
        "seed": seed,
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "platform": platform.platform()},
        "bench_seconds": time.perf_counter() - t_all,
        "targets": {k: f"{op} {v}" for k, (op, v) in TARGETS.items()},
    }
    (out / "bench.json").write_text(json.dumps(_finite(result), indent=2) + "\n")
    log(format_table(result))
    return result


def _finite(obj: Any) -> Any:
    """JSON-safe copy: NaN and infinities become None."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def format_table(r: dict[str, Any]) -> str:
    """The printed summary: ratios against their targets, then the stage split."""
    lines = [f"{'measure':<22} {'value':>10}  target", "-" * 44]
    for key in ("graph_vs_core", "cycle_vs_floor", "scaling_64_vs_4", "match_1000_vs_10"):
        op, target = TARGETS[key]
        v = r[key]
        ok = (v >= target) if op == ">=" else (v <= target)
        lines.append(f"{key:<22} {v:>10.2f}  {op} {target}  {'ok' if ok else 'MISSED'}")
    for key in ("cycles_per_s_128", "cycles_per_s_256", "core_cycles_per_s_128",
                "core_cycles_per_s_256", "graph_ms_per_cycle", "core_ms_per_cycle",
                "floor_ms_per_cycle", "core_vs_floor"):
        lines.append(f"{key:<22} {r[key]:>10.2f}")
    lines.append(f"graph_matches_core     {r['graph_matches_core']!s:>10}")
    if len(r.get("graph_vs_core_rounds", [])) > 1:
        each = ", ".join(f"{v:.2f}" for v in r["graph_vs_core_rounds"])
        lines.append(f"graph_vs_core by round: {each} (pooled above)")
    lines += ["", f"{'stage (core, ms/cycle)':<22} {'ms':>10}", "-" * 34]
    lines += [f"{k:<22} {v:>10.2f}" for k, v in r["stages"].items()]
    return "\n".join(lines)


__all__ = ["CoreRun", "format_table", "main_bench", "match_latency", "run_core_timed",
           "run_graph_timed"]
