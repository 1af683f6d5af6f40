"""A world edit that moves an object: the spatial map notices, attends to and maps it at its
new place (issue 15, item 5), with the real core loop (simulator, perception, memory).

An object added mid-run is covered by test_coverage.py.
"""

from __future__ import annotations

import math

import pytest

from roger_common.errors import WorldFileError
from roger_experiments.core_loop import CoreLoop
from roger_sim.worldgen import random_world


def free_place(loop: CoreLoop, name: str) -> tuple[float, float]:
    """Move ``name`` to the first place, scanned over the workspace, the world rules accept
    at least 0.25 m from where it stood and 0.3 m from every other object."""
    objects = {o.name: o for o in loop.world.objects}
    old = objects[name].position
    for r in (0.55, 0.7, 0.85):
        for bearing in range(-60, 61, 15):
            p = (round(r * math.cos(math.radians(bearing)), 3),
                 round(r * math.sin(math.radians(bearing)), 3))
            if math.dist(p, old) < 0.25 or any(
                    math.dist(p, o.position) < 0.3 for n, o in objects.items() if n != name):
                continue
            try:
                loop.sim.move_object(name, p)
            except WorldFileError:
                continue
            return p
    raise AssertionError("no free place to move the object to")


@pytest.mark.parametrize("policy", ["straightforward", "qlearning"])
def test_a_moved_object_is_noticed_visited_and_mapped_again(policy: str) -> None:
    world = random_world(4, 2, seed=31, size_range=(0.08, 0.12))
    loop = CoreLoop(world, policy=policy, seed=3)
    try:
        for _ in loop.cycles(40):
            pass
        mover = world.objects[0].name
        place = free_place(loop, mover)
        start = loop.ctl.counters.cycles
        visited = mapped = False
        while loop.ctl.counters.cycles < start + 40 and not (visited and mapped):
            record = loop.step()
            if record is None:
                continue
            visited |= loop.true_object(record) == mover and record.outcome != "lost"
            mapped = any(e.mapped and math.dist(e.position[:2], place) < 0.08
                         for e in loop.ctl.spatial_map)
        c = loop.ctl.counters
        assert c.attention_shifts + c.improvements + c.map_updates == c.cycles
        assert c.map_updates == c.positive_identifications + c.new_objects
    finally:
        loop.close()
    assert visited, f"{policy}: the moved object never came under the attention window"
    assert mapped, f"{policy}: the moved object was never mapped at {place}"
