"""Can every object be visited? Each object fixated once, and whether any window shows it.

For every object of each world, the robot fixates the object (an attention shift aimed at
its true position: ground truth aims, as the scorer reads it, diagnosis only) and
perception turns the frame into ROIs with the shipped configuration. The object *has a
window* when the attention window of some ROI (``Roi.bbox``) shows it as the scorer sees
it (``evaluation.object_under_window``, what "every object visited" counts). One that has
none from its own fixation is hardly visited at all: every other gaze sees it from
farther off-axis. For each such object it prints the objects of the ROI that holds most
of its pixels (the nearer one it is joined to, docs/perception.md "Limits").

    python bench/fixated_objects.py --recipe inspection --random 10040 10041 10042
    python bench/fixated_objects.py --world worlds/inspection.yaml --behind-split

Diagnosis, not a result: the worlds it is run on are looked at.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from roger_common.errors import WorldFileError
from roger_common.types import Action, Goal, WorldSpec
from roger_experiments.core_loop import with_light
from roger_experiments.evaluation import object_under_window
from roger_perception.config import PerceptionConfig
from roger_perception.perception import Perception
from roger_sim.config import SimConfig
from roger_sim.simulator import Simulator
from roger_sim.world import load_world
from roger_sim.worldgen import random_world

sys.path.insert(0, str(Path(__file__).resolve().parent))
from memory_targets import RECIPES  # noqa: E402


def without_window(world: WorldSpec, config: PerceptionConfig, seed: int = 0
                   ) -> tuple[int, list[str]]:
    """(objects, one line for each object no window shows when it is fixated)."""
    sim_config = SimConfig()
    perception = Perception(with_light(config, world, sim_config))
    lines = []
    with Simulator(world, sim_config, seed=seed) as sim:
        specs = {o.name: o for o in world.objects}
        poses = sim.object_poses()
        for goal_id, (name, pose) in enumerate(poses.items(), start=1):
            _, frame = sim.run_goal(Goal(goal_id, Action.ATTENTION_SHIFT, pose[:3]))
            assert frame.left_labels is not None
            rois = perception.process(frame)
            shown = {object_under_window(frame.left_labels, frame.label_names, r.bbox)
                     for r in rois}
            if name in shown:
                continue
            index = frame.label_names.index(name)
            mine = frame.left_labels == index
            held = perception.last_roi_labels[mine]
            held = held[held > 0]
            spec = specs[name]
            where = (f"{name} ({spec.shape} {spec.size:.2f} m, grey {spec.intensity:.0f}, "
                     f"{math.hypot(*spec.position):.2f} m): {int(mine.sum())} px")
            if held.size == 0:
                lines.append(f"{where}, in no ROI")
                continue
            roi = int(np.bincount(held).argmax())
            under = frame.left_labels[perception.last_roi_labels == roi]
            counts = np.bincount(under[under >= 0], minlength=len(frame.label_names))
            joined = ", ".join(
                f"{frame.label_names[i]} {counts[i]} px" + (
                    f" (grey {specs[frame.label_names[i]].intensity:.0f}, "
                    f"{math.hypot(*specs[frame.label_names[i]].position):.2f} m)"
                    if frame.label_names[i] != name else "")
                for i in np.argsort(-counts) if counts[i] > 0)
            lines.append(f"{where}, in a ROI of {joined}")
    return len(poses), lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--world", type=Path, action="append", default=[],
                    help="world file (repeatable)")
    ap.add_argument("--random", type=int, nargs="*", default=[],
                    help="seeds of random worlds (one world per seed and --recipe)")
    ap.add_argument("--recipe", action="append", choices=sorted(RECIPES),
                    help="recipe of the random worlds (repeatable; default inspection)")
    ap.add_argument("--features", default="extended", choices=("paper", "extended"))
    ap.add_argument("--behind-split", action="store_true",
                    help="perception's behind_split on (docs/perception.md step 9)")
    args = ap.parse_args()
    config = replace(PerceptionConfig(features=args.features),
                     behind_split=args.behind_split)
    worlds: list[tuple[str, WorldSpec | None]] = [(str(w), load_world(w)) for w in args.world]
    for recipe in args.recipe or ["inspection"]:
        for seed in args.random:
            try:
                worlds.append((f"{recipe} {seed}", random_world(seed=seed, **RECIPES[recipe])))
            except WorldFileError as e:
                print(f"{recipe} {seed}: not placed ({e})", flush=True)
    total = missing = hit = 0
    for label, world in worlds:
        assert world is not None
        n, lines = without_window(world, config)
        total += n
        missing += len(lines)
        hit += bool(lines)
        print(f"{label}: {n - len(lines)} of {n} objects have a window", flush=True)
        for line in lines:
            print(f"    {line}", flush=True)
    print(f"\n{missing} of {total} objects have no window when fixated, in {hit} of "
          f"{len(worlds)} worlds")


if __name__ == "__main__":
    main()
