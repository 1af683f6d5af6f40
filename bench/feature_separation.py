"""How far apart are the features of one category and of two? (a measurement, not a test)

For every object of a world: an attention shift, a visual and a haptic improvement on the
real simulator; the ROI nearest the fixation is kept. Prints the features, then the RMS
distances (over the features known in both) within a category (the same object at other
stages, and other objects of the same category) and between categories. The memory can
only identify repeats and tell categories apart if the first are clearly below the second.

    .venv/bin/python bench/feature_separation.py worlds/two_rows.yaml [--seed 1]
"""

from __future__ import annotations

import argparse
import itertools

import numpy as np

from roger_common.types import Action, Goal
from roger_experiments.evaluation import object_under_window
from roger_perception.perception import Perception
from roger_sim.simulator import Simulator
from roger_sim.world import load_world

STAGES = (Action.ATTENTION_SHIFT, Action.VISUAL_IMPROVEMENT, Action.HAPTIC_IMPROVEMENT)


def rms(a: np.ndarray, b: np.ndarray, ka: np.ndarray, kb: np.ndarray) -> float:
    """RMS difference over the features known in both."""
    k = ka & kb
    return float(np.sqrt(np.mean((a[k] - b[k]) ** 2)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("world")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    world = load_world(args.world)
    sim, perception = Simulator(world, seed=args.seed), Perception()
    category = {o.name: o.category() for o in world.objects}
    obs: dict[str, list[tuple[str, np.ndarray, np.ndarray]]] = {}
    goal = 1
    for o in world.objects:
        target = (o.position[0], o.position[1], 0.08)
        for action in STAGES:
            _, frame = sim.run_goal(Goal(goal, action, target))
            goal += 1
            rois = perception.process(frame)
            if not rois:
                continue
            roi = min(rois, key=lambda r: np.hypot(r.position[0] - target[0],
                                                   r.position[1] - target[1]))
            seen = object_under_window(frame.left_labels, frame.label_names, roi.bbox)
            obs.setdefault(o.name, []).append((action.name[:3], roi.features.copy(),
                                               roi.known.copy()))
            f = roi.features
            print(f"{o.name:8s} {action.name[:3]} I={f[0]:.2f},{f[1]:.2f},{f[2]:.2f} "
                  f"T={f[3]:.3f} S={f[6]:.2f},{f[7]:.2f},{f[8]:.2f} D={f[9]:.2f} "
                  f"W={f[10]:.2f}{'' if roi.known[10] else '?'} seen={seen}")
    sim.close()
    within, between = [], []
    for a, b in itertools.combinations(obs, 2):
        for (_, fa, ka), (_, fb, kb) in itertools.product(obs[a], obs[b]):
            (within if category[a] == category[b] else between).append(rms(fa, fb, ka, kb))
    for name in obs:
        for (_, fa, ka), (_, fb, kb) in itertools.combinations(obs[name], 2):
            within.append(rms(fa, fb, ka, kb))
    print(f"within-category RMS: median {np.median(within):.3f} "
          f"p90 {np.percentile(within, 90):.3f} max {max(within):.3f}")
    print(f"between-category RMS: min {min(between):.3f} "
          f"p10 {np.percentile(between, 10):.3f} median {np.median(between):.3f}")


if __name__ == "__main__":
    main()
