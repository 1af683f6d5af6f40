"""The multi-process graph computes what the in-process core loop computes.

Same world, seed and policy: the four nodes exchanging messages must produce the same
cycles.csv, row for row and column for column, as CoreLoop calling the same code directly.
This fails when a node's result depends on the order in which DDS delivers messages of
different topics (a haptic reading or a spatial map arriving after the stereo pair it
belongs to once made two runs of one seed part ways after ~40 cycles).
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import pytest
from conftest import WORLDS

from roger_bringup.run import RunOptions, run_graph
from roger_experiments.core_loop import run_core
from roger_sim.world import load_world


def rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.parametrize("world_name, policy, cycles", [
    ("two_rows.yaml", "qlearning", 60),
    ("shapes.yaml", "straightforward", 50),
])
def test_graph_and_core_write_the_same_cycles(no_leaks, tmp_path, ros_domain, world_name,
                                              policy, cycles):
    world = WORLDS / world_name
    run_core(load_world(world), policy, cycles, seed=4, out=tmp_path / "core")
    run_graph(RunOptions(world=world, out=tmp_path / "graph", cycles=cycles, seed=4,
                         policy=policy, progress=False, domain_id=ros_domain,
                         timeout_s=240), log=io.StringIO())
    core, graph = rows(tmp_path / "core" / "cycles.csv"), rows(tmp_path / "graph" / "cycles.csv")
    status = (tmp_path / "graph" / "run_status.json").read_text()
    assert len(core) == len(graph) == cycles, f"{len(core)} core, {len(graph)} graph: {status}"
    kinds = {r["action"] for r in core}
    assert {"attention_shift", "haptic_improvement", "map_update"} <= kinds  # a real test
    for c, g in zip(core, graph, strict=True):
        assert c == g, f"cycle {c['cycle']}: core {c} graph {g}"
