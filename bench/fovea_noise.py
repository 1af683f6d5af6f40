"""O's noise from repeated foveal looks, and its spread between categories and copies.

Not a test (a measurement for docs/perception.md, "Extended features"). For each object of
each world: an attention shift onto it, then ``--looks`` visual improvements, each with a
fresh fovea (fresh pixel noise; the O kept from the previous look is forgotten first, so
every look measures anew). Per world it prints each object's O (median and spread of its
looks, ground truth used for scoring only), then:

* within: the pooled standard deviation of one object's looks (the sensor's own noise);
* between categories: the standard deviation of the category means;
* between copies: the pooled standard deviation of the copies' means around their
  category's mean (view dependence: yaw, place, neighbours);
* the ratios between categories / within and between categories / between copies.

Run: ``.venv/bin/python bench/fovea_noise.py --random twins:1001 yaw:1001 --looks 4``
(worlds: ``roger_experiments.record_queries.recipe_world``) or ``--world FILE``.
"""

from __future__ import annotations

import argparse
import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from roger_common.types import Action, FeatureMode, Goal, WorldSpec, feature_names
from roger_experiments.record_queries import recipe_world
from roger_perception.config import PerceptionConfig
from roger_perception.perception import Perception
from roger_sim.config import SimConfig
from roger_sim.simulator import Simulator
from roger_sim.world import load_world

O_INDEX = feature_names(FeatureMode.EXTENDED).index("O")


def looks(world: WorldSpec, n_looks: int, seed: int = 0) -> dict[str, list[float]]:
    """O of every look at every object (module docstring)."""
    out: dict[str, list[float]] = defaultdict(list)
    perception = Perception(PerceptionConfig(features="extended"))
    goal = 0
    with Simulator(world, SimConfig(), seed=seed) as sim:
        for obj in world.objects:
            target = (obj.position[0], obj.position[1], 0.05)
            goal += 1
            sim.run_goal(Goal(goal, Action.ATTENTION_SHIFT, target))
            for _ in range(n_looks):
                goal += 1
                _, frame = sim.run_goal(Goal(goal, Action.VISUAL_IMPROVEMENT, target))
                perception.fovea_looks.clear()
                rois = perception.process(frame)
                near = min(rois, key=lambda r: math.dist(r.position[:2], target[:2]),
                           default=None)
                if near is not None and math.dist(near.position[:2], target[:2]) < 0.05 \
                        and near.known[O_INDEX]:
                    out[obj.name].append(float(near.features[O_INDEX]))
    return out


def report(world: WorldSpec, values: dict[str, list[float]]) -> None:
    """Print one world's figures (module docstring)."""
    cat = {o.name: o.category() for o in world.objects}
    shape = {o.name: (o.shape, o.yaw) for o in world.objects}
    print(f"world {world.name}")
    sq, dof = 0.0, 0
    means: dict[tuple, list[float]] = defaultdict(list)
    for name in sorted(values, key=lambda n: (shape[n][0], n)):
        v = np.asarray(values[name])
        print(f"  {name} {shape[name][0]:8s} yaw {shape[name][1]:4.2f}  O median "
              f"{np.median(v):.3f}  sd {v.std(ddof=1) if v.size > 1 else math.nan:.3f}  "
              f"({v.size} looks)")
        if v.size > 1:
            sq += float(((v - v.mean()) ** 2).sum())
            dof += v.size - 1
        means[cat[name]].append(float(v.mean()))
    within = math.sqrt(sq / dof) if dof else math.nan
    cat_means = [float(np.mean(m)) for m in means.values()]
    between = float(np.std(cat_means, ddof=1)) if len(cat_means) > 1 else math.nan
    csq = sum(float(((np.asarray(m) - np.mean(m)) ** 2).sum()) for m in means.values())
    cdof = sum(len(m) - 1 for m in means.values())
    copies = math.sqrt(csq / cdof) if cdof else math.nan
    print(f"  within {within:.4f}  between categories {between:.4f}  between copies "
          f"{copies:.4f}  ratios: categories/within {between / within:.1f}, "
          f"categories/copies {between / copies:.1f}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--world", type=Path, action="append", default=[])
    p.add_argument("--random", nargs="*", default=[], metavar="RECIPE:SEED")
    p.add_argument("--looks", type=int, default=4)
    args = p.parse_args()
    worlds = [load_world(w) for w in args.world] + [recipe_world(s) for s in args.random]
    for world in worlds:
        report(world, looks(world, args.looks))


if __name__ == "__main__":
    main()
