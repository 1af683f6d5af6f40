"""What the robot saw of some objects in one closed-loop run: every look at them, its
features, the memory's answer, and (``--rois``) which objects its ROIs held.

Runs the core loop in process (``CoreLoop``, 204 cycles by default) on one world, policy
and seed. For every physical cycle whose attention window shows one of the objects named
by ``--objects`` (name prefixes: ``c04`` is every copy of category c04; the window's object
as the scorer reads it, ``evaluation.object_under_window``), it prints the cycle, action,
outcome, map entry, the features of the look the memory was asked about (``-`` where
unknown) and the memory's answer; a store that follows prints the address it wrote.
With ``--rois`` it also prints, from the simulator's label image, the objects the
window holds and those of every ROI of that frame that holds a traced object: a ROI
holding two objects (a merge) or an object spread over two ROIs (a split) shows there.

    python bench/trace_looks.py --world runs/cl/worlds/random_8x3_10124.yaml \\
        --policy straightforward --seed 0 --objects c04 c06_0 --rois

The labels are read only to print (the robot never sees them). Diagnosis, not a result:
the worlds it is run on are looked at. docs/perception.md ("Limits", same-grey pairs)
has traces made with it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from roger_common.types import FeatureMode, MatchResult, MemoryRequest, feature_names
from roger_experiments.core_loop import CoreLoop
from roger_memory.config import MemoryConfig
from roger_perception.config import PerceptionConfig
from roger_sim.world import load_world

#: Features printed unless ``--show`` names others (those of the extended mode that
#: the paper mode lacks are skipped there).
SHOWN = ("I1", "T2", "D", "W", "H", "O", "A", "AS", "TH", "TC", "TR", "AP")


def composition(labels: np.ndarray, names: list[str], mask: np.ndarray) -> str:
    """The objects (and ground, ``-``) under ``mask``, most pixels first."""
    ids, counts = np.unique(labels[mask], return_counts=True)
    parts = sorted(zip(counts.tolist(), ids.tolist(), strict=True), reverse=True)
    return " ".join(f"{names[i] if 0 <= i < len(names) else '-'}:{n}" for n, i in parts)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--world", type=Path, required=True)
    p.add_argument("--policy", default="straightforward",
                   choices=("straightforward", "qlearning"))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--objects", nargs="+", required=True,
                   help="object name prefixes to trace (c04: every copy of category c04)")
    p.add_argument("--features", choices=("paper", "extended"), default="extended")
    p.add_argument("--cycles", type=int, default=204)
    p.add_argument("--show", nargs="+", default=list(SHOWN), help="features to print")
    p.add_argument("--rois", action="store_true",
                   help="also print what the window and the traced objects' ROIs hold")
    args = p.parse_args()
    world = load_world(args.world)
    mode = FeatureMode(args.features)
    names = feature_names(mode)
    shown = [n for n in args.show if n in names]
    loop = CoreLoop(world, policy=args.policy, seed=args.seed,
                    perception_config=PerceptionConfig(features=args.features),
                    memory_config=MemoryConfig.for_mode(args.features))
    memory = loop.memory
    assert memory is not None
    asked: list[tuple[MemoryRequest, MatchResult]] = []
    handle = memory.handle

    def watched(request: MemoryRequest) -> MatchResult:
        result = handle(request)
        asked.append((request, result))
        return result

    memory.handle = watched  # type: ignore[method-assign]

    def traced(name: str | None) -> bool:
        return name is not None and any(name.startswith(o) for o in args.objects)

    print(f"# {args.world.name} {args.policy} seed {args.seed} {args.features}: "
          f"{' '.join(args.objects)}")
    last: str | None = None
    for record in loop.cycles(args.cycles):
        shown_object = loop.true_object(record)
        answer = asked[-1] if asked else None
        asked.clear()
        if record.outcome == "stored" and traced(last):
            print(f"  -> stored at address {record.address} (cycle {record.cycle})")
        if shown_object is None:
            continue
        last = shown_object
        if not traced(shown_object):
            continue
        line = (f"{record.cycle:4d} {record.action.name.lower():19s} {record.outcome:12s} "
                f"entry {record.entry_id:3d} window {shown_object}")
        if answer is not None:
            request, result = answer
            values = " ".join(
                f"{n}={request.features[names.index(n)]:.3f}"
                if request.known[names.index(n)] else f"{n}=-" for n in shown)
            line += (f" | {request.op.name.lower()} -> {result.outcome.name.lower()} "
                     f"{result.address} | {values}")
        print(line, flush=True)
        frame = loop.last_frame
        if not args.rois or frame is None or frame.left_labels is None \
                or record.bbox is None:
            continue
        labels, label_names = frame.left_labels, list(frame.label_names)
        u0, v0, u1, v1 = record.bbox
        window = np.zeros(labels.shape, bool)
        window[v0:v1, u0:u1] = True
        print(f"       window: {composition(labels, label_names, window)}")
        roi_labels = loop.perception.last_roi_labels
        for roi in range(1, int(roi_labels.max()) + 1):
            mask = roi_labels == roi
            held = composition(labels, label_names, mask)
            if any(traced(n.split(":")[0]) for n in held.split()):
                print(f"       roi {roi - 1}: {held}")
    loop.close()


if __name__ == "__main__":
    main()
