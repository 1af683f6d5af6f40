"""What the scorer sees in the attention window: the ROI's whole box against its window.

Runs the core loop in process on each world (one policy and seed, ``--cycles`` cycles) and,
for every attended look (an attention shift or an improvement that found its place), takes
the ROI under the window in ``Perception.last_roi_labels`` and classes it by the
simulator's labels (ground truth, read only to score):

- *clean*: one object holds at least 85 % of the ROI's object pixels;
- *merged*: a second object holds 15 % or more (``feature_report.MERGE_SHARE``);
- *ground*: no object pixel.

For each class it counts the scorer's verdict (``evaluation.object_under_window``) on the
box of all the ROI's pixels (``window_sigmas`` 0) and on its window (the configured
``window_sigmas``): the ROI's main object, another object, or none. A window that is
right turns clean looks' "none" into their object and leaves merged looks as they were.

    python bench/attention_window.py --world runs/cl/worlds/yaw_10007.yaml \\
        --world runs/cl/worlds/random_8x3_10008.yaml --policy straightforward --seed 0

Diagnosis, not a result: the worlds it is run on are looked at.
"""

from __future__ import annotations

import argparse
import collections
from pathlib import Path

import numpy as np

from roger_common.types import Action
from roger_experiments.core_loop import CoreLoop
from roger_experiments.evaluation import object_under_window
from roger_experiments.feature_report import MERGE_SHARE
from roger_memory.config import MemoryConfig
from roger_perception.config import PerceptionConfig
from roger_perception.segmentation import window_boxes
from roger_sim.world import load_world

#: A ROI is clean when its main object holds this share of its object pixels.
CLEAN_SHARE = 1.0 - MERGE_SHARE


def classify(truth: np.ndarray) -> tuple[str, int]:
    """(class, main object index) of a ROI from the labels of its pixels."""
    objects = truth[truth >= 0]
    if objects.size == 0:
        return "ground", -1
    counts = np.bincount(objects)
    main = int(counts.argmax())
    second = np.sort(counts)[-2] if np.count_nonzero(counts) > 1 else 0
    return ("merged" if second >= MERGE_SHARE * objects.size else "clean"), main


def run(world_path: Path, policy: str, seed: int, cycles: int, features: str
        ) -> collections.Counter[tuple[str, str, str]]:
    world = load_world(world_path)
    cfg = PerceptionConfig(features=features)
    loop = CoreLoop(world, policy=policy, seed=seed, perception_config=cfg,
                    memory_config=MemoryConfig.for_mode(features))
    counts: collections.Counter[tuple[str, str, str]] = collections.Counter()
    try:
        for rec in loop.cycles(cycles):
            frame = loop.last_frame
            if (rec.bbox is None or frame is None or frame.left_labels is None
                    or rec.action == Action.MAP_UPDATE or rec.outcome == "lost"):
                continue
            rois = loop.perception.last_roi_labels
            x0, y0, x1, y1 = rec.bbox
            under = rois[y0:y1, x0:x1]
            ids, n = np.unique(under[under > 0], return_counts=True)
            if ids.size == 0:
                continue
            own = int(ids[n.argmax()])
            mask = rois == own
            rows, cols = np.nonzero(mask)
            whole = (int(cols.min()), int(rows.min()), int(cols.max()) + 1,
                     int(rows.max()) + 1)
            cls, main = classify(frame.left_labels[mask])
            boxes = [(0, 0, 0, 0)] * (own - 1) + [whole]
            window = window_boxes(frame.left, rois, boxes, cfg.window_sigmas)[own - 1]
            for name, box in (("box", whole), ("window", window)):
                seen = object_under_window(frame.left_labels, frame.label_names, box)
                verdict = ("none" if seen is None else
                           "main" if main >= 0 and seen == frame.label_names[main]
                           else "other")
                counts[(cls, name, verdict)] += 1
    finally:
        loop.close()
    return counts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--world", type=Path, action="append", required=True)
    ap.add_argument("--policy", default="straightforward")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cycles", type=int, default=204)
    ap.add_argument("--features", default="extended")
    args = ap.parse_args()
    total: collections.Counter[tuple[str, str, str]] = collections.Counter()
    for w in args.world:
        counts = run(w, args.policy, args.seed, args.cycles, args.features)
        total.update(counts)
        print(f"{w.stem}: " + ", ".join(f"{c} {n} {v}: {k}"
                                        for (c, n, v), k in sorted(counts.items())),
              flush=True)
    print("\n| ROI | scorer on the whole box | scorer on the window |\n|---|---|---|")
    for cls in ("clean", "merged", "ground"):
        cells = [", ".join(f"{v} {total[(cls, name, v)]}" for v in ("main", "other", "none")
                           if total[(cls, name, v)]) for name in ("box", "window")]
        if any(cells):
            print(f"| {cls} | {cells[0]} | {cells[1]} |")

if __name__ == "__main__":
    main()
