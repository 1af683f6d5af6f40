"""One ``RunSpec`` through the real multi-process graph: the graph runner of Table 2 and of
``roger sweep`` (``mode: graph``), passed into the experiment as ``runners.RunFn``."""

from __future__ import annotations

import os
import random
import re
from pathlib import Path
from typing import Any

from roger_experiments.ray_runner import DOMAIN_ENV
from roger_experiments.runners import RunSpec, materialized_qtable

#: Fast DDS's shared-memory port files name their RTPS port: 7400 + 250 * domain + offset.
_PORT_FILE = re.compile(r"fastrtps_port(\d+)")


def free_domains(count: int = 64) -> tuple[int, ...]:
    """Up to ``count`` ROS domain ids for graph runs side by side on this host, in random
    order: of 1-101 (Fast DDS on Linux takes 0-232 without port clashes; 0 is left to the
    user's own graph), none that a graph on this machine uses now (its port files are in
    /dev/shm) nor the caller's ``ROS_DOMAIN_ID``."""
    taken: set[int] = set()
    try:
        names = os.listdir("/dev/shm")
    except OSError:
        names = []
    for name in names:
        m = _PORT_FILE.search(name)
        if m and int(m[1]) >= 7400:
            taken.add((int(m[1]) - 7400) // 250)
    mine = os.environ.get("ROS_DOMAIN_ID", "")
    if mine.isdigit():
        taken.add(int(mine))
    free = [d for d in range(1, 102) if d not in taken]
    random.SystemRandom().shuffle(free)
    return tuple(free[:count])


def run_spec_graph(spec: RunSpec, out: Path, progress: bool = False) -> dict[str, Any]:
    """Run ``spec`` through the graph into ``out``; returns metrics.json's content.

    The world file named in the spec is used when it holds the spec's text (so that
    metrics.json names it as ``roger run`` would); elsewhere (a Ray worker on another
    machine) the text is written to ``out/world.yaml`` first.
    """
    from roger_bringup.run import RunOptions, run_graph

    world = Path(spec.world)
    try:
        same = world.read_text(encoding="utf-8") == spec.world_text
    except OSError:
        same = False
    if not same:
        out.mkdir(parents=True, exist_ok=True)
        world = out / "world.yaml"
        world.write_text(spec.world_text, encoding="utf-8")
    leased = os.environ.get(DOMAIN_ENV)
    with materialized_qtable(spec, out) as (qtable, learn):
        return run_graph(RunOptions(
            world=world, out=out, policy=spec.policy, cycles=spec.cycles,
            until_complete=spec.cycles is None, stable_cycles=spec.stable_cycles,
            max_cycles=spec.max_cycles, seed=spec.seed, qtable=qtable, learn=learn,
            features=spec.features, progress=progress,
            domain_id=int(leased) if leased else None))


def run_spec_graph_quiet(spec: RunSpec, out: Path) -> dict[str, Any]:
    """``run_spec_graph`` without a progress bar (a Ray task's)."""
    return run_spec_graph(spec, out, progress=False)
