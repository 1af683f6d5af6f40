"""The memory's targets (issue 16, docs/memory.md): closed-loop runs and recorded replays.

Not a test. Run from the repository root with the packages importable, e.g.::

    python bench/memory_targets.py closed-loop --world worlds/inspection.yaml \\
        --random 41 42 43 --seeds 3 --cycles 204 --out runs/memory_targets
    python bench/memory_targets.py closed-loop --recipe far --recipe crowded \\
        --random 121 --seeds 1 --out runs/recipes
    python bench/memory_targets.py replay test/data/memory_queries.csv.gz
    python bench/memory_targets.py replay test/data/memory_queries.csv.gz --unknown T1 T2 T3

``closed-loop`` writes each random world (``roger_sim.worldgen.random_world(8, 3, seed,
size_range=(0.08, 0.14))``, the recipe of worlds/inspection.yaml, or another of
``RECIPES`` named by ``--recipe``: small, large, textured, touching objects, objects out
of reach, crowded) to OUT/worlds, runs
``roger compare --in-process`` on every world (both policies, ``--seeds`` run seeds) and
prints, per run, the figures the project is judged by (computed as
shared/tools/run_figures.py computes them): identification and novelty precision (1.0
when there was none), new objects against the categories the window showed, objects
visited, empty attention shifts, failed touches (haptic improvements whose target lay
within reach, ``roger_sim.world.in_reach``, and whose arm did not converge: a weight lost,
the look then decided on sight; docs/memory.md, "Fresh seeds 10138-10147"), and whether
the run meets issue 16's three targets
(identification >= 0.95, novelty >= 0.9, new objects within one of the categories) and
issue 38's (the same, new objects at most one more than the categories). ``replay``
replays recorded query sets through fresh memories
(``roger_experiments.record_queries.replay``) and prints per world the false novelty and
false identification rates of the final trials, and the memory's counts
(vetoes, non-final identifications held back for want of the weight, refinements).
``--unknown`` marks the named features unknown in every recorded look before the replay
(the memory then decides without them: an ablation of a feature, not of the network).
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import torch
import yaml

from roger_common.types import FEATURE_NAMES, mode_of_dim
from roger_experiments.compare import compare
from roger_experiments.core_loop import run_core
from roger_experiments.record_queries import read_csv, replay
from roger_memory.config import MemoryConfig
from roger_memory.memory import AssociativeMemory, MemoryStats
from roger_sim.world import TEXTURES, in_reach, load_world, world_to_dict
from roger_sim.worldgen import random_world

#: Recipes of random worlds (keyword arguments of ``random_world``); ``inspection`` is the
#: recipe of worlds/inspection.yaml, the others vary one thing the memory has to hold
#: through (docs/memory.md, "Worlds of other recipes").
RECIPES: dict[str, dict[str, Any]] = {
    "inspection": dict(n_categories=8, copies=3, size_range=(0.08, 0.14)),
    "small": dict(n_categories=4, copies=5, size_range=(0.05, 0.08)),
    "large": dict(n_categories=6, copies=2, size_range=(0.15, 0.22)),
    "textured": dict(n_categories=8, copies=3, size_range=(0.08, 0.14), textures=TEXTURES),
    "touching": dict(n_categories=5, copies=3, size_range=(0.08, 0.14), min_gap=0.0),
    "far": dict(n_categories=8, copies=3, size_range=(0.08, 0.14), out_of_reach=3),
    "crowded": dict(n_categories=12, copies=3, size_range=(0.06, 0.10)),
    # Issue 38's hard cases: categories that differ only in shape, copies at yaws 0..pi/2.
    "twins": dict(n_categories=4, copies=3, size_range=(0.08, 0.14), shape_twins=True),
    "yaw": dict(n_categories=8, copies=3, size_range=(0.08, 0.14), yaw_copies=True),
}


def write_random_world(seed: int, folder: Path, recipe: str = "inspection") -> Path:
    """The random world of ``seed`` and ``recipe`` (``RECIPES``) as a world file."""
    folder.mkdir(parents=True, exist_ok=True)
    kw = RECIPES[recipe]
    name = (f"random_{kw['n_categories']}x{kw['copies']}_{seed}" if recipe == "inspection"
            else f"{recipe}_{seed}")
    path = folder / f"{name}.yaml"
    world = random_world(seed=seed, name=name, **kw)
    path.write_text(yaml.safe_dump(world_to_dict(world), sort_keys=False))
    return path


def figures(run: Path, world: Path) -> dict[str, Any]:
    """The judged figures of one run (as shared/tools/run_figures.py computes them)."""
    m = json.loads((run / "metrics.json").read_text())
    objs = yaml.safe_load(world.read_text())["objects"]
    cat = {o["name"]: (o["shape"], o["size"], o["intensity"], o["weight"],
                       o.get("texture", "plain")) for o in objs}
    with open(run / "cycles.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    visited = {r["true_object"] for r in rows if r["true_object"] in cat}
    shifts = [r for r in rows if r["action"] == "attention_shift"]
    empty = sum(1 for r in shifts if r.get("outcome") == "lost" or not r["true_object"])
    touches = [r for r in rows if r["action"] == "haptic_improvement"
               and in_reach(float(r["x"]), float(r["y"]))]
    failed = sum(1 for r in touches if r.get("converged") in ("0", "False"))
    return {
        "id": m["identification_precision"] if m["positive_identifications"] else 1.0,
        "nov": m["novelty_precision"] if m["new_objects"] else 1.0,
        "new": m["new_objects"], "categories_visited": len({cat[n] for n in visited}),
        "visited": f"{len(visited)}/{len(cat)}", "empty": f"{empty}/{len(shifts)}",
        "identifications": m["positive_identifications"],
        "failed_touches": f"{failed}/{len(touches)}",
    }


def closed_loop(args: argparse.Namespace) -> None:
    """Both policies on every world; one line of figures per run, then the summary."""
    torch.set_num_threads(1)
    worlds = list(args.world) + [write_random_world(s, args.out / "worlds", recipe)
                                 for recipe in args.recipe or ["inspection"]
                                 for s in args.random]
    seeds = list(range(args.seeds))
    lines = []
    for world_path in worlds:
        world = load_world(world_path)
        name = world_path.stem

        def run_one(policy: str, seed: int, run_dir: Path, world: Any = world) -> dict:
            t0 = time.monotonic()
            recorder, _ = run_core(world, policy, args.cycles, seed=seed, out=run_dir,
                                   features=args.features)
            assert recorder is not None
            return recorder.close(time.monotonic() - t0)

        out = args.out / name
        compare(world_path, seeds, out, run_one)
        for run in sorted((out / "runs").iterdir()):
            f = figures(run, world_path)
            # Issue 16's three targets: new objects within one of the categories seen.
            ok = (f["id"] >= 0.95 and f["nov"] >= 0.9
                  and abs(f["new"] - f["categories_visited"]) <= 1)
            # Issue 38's: at most one more (fewer, where a category was never decided,
            # is no failure of novelty).
            ok38 = (f["id"] >= 0.95 and f["nov"] >= 0.9
                    and f["new"] <= f["categories_visited"] + 1)
            line = (f"{name:18} {run.name:24} id={f['id']:.2f} nov={f['nov']:.2f} "
                    f"new={f['new']} categories_visited={f['categories_visited']} "
                    f"visited={f['visited']} empty={f['empty']} "
                    f"failed_touches={f['failed_touches']} "
                    f"{'meets' if ok else 'misses'} "
                    f"issue38={'meets' if ok38 else 'misses'}")
            print(line, flush=True)
            lines.append(line)
    (args.out / "figures.txt").write_text("\n".join(lines) + "\n")


def replay_sets(args: argparse.Namespace) -> None:
    """Recorded query sets through fresh memories; rates per world."""
    torch.set_num_threads(1)
    queries = [q for path in args.files for q in read_csv(path)]
    drop = [FEATURE_NAMES.index(name) for name in args.unknown]
    if drop:
        for q in queries:
            q.known[drop] = False
    memories: list[AssociativeMemory] = []

    def make() -> AssociativeMemory:
        mode = mode_of_dim(len(queries[0].features)) if queries else "paper"
        memories.append(AssociativeMemory(MemoryConfig.for_mode(mode), seed=0))
        return memories[-1]

    scores = replay(queries, make)
    by_world: dict[str, list[Any]] = defaultdict(list)
    stats: dict[str, MemoryStats] = defaultdict(MemoryStats)
    for score, memory in zip(scores, memories, strict=True):
        by_world[score.run[0]].append(score)
        total = stats[score.run[0]]
        for key, value in vars(memory.stats).items():
            setattr(total, key, getattr(total, key) + value)
    print("| world | runs | id precision | novelty precision | false new (repeats) | "
          "false id (novel) | new - categories | matches | vetoes | held for W | "
          "refinements |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for world, ss in by_world.items():
        ids = sum(s.identifications for s in ss)
        ok_ids = sum(s.correct_identifications for s in ss)
        stores = sum(s.stores for s in ss)
        ok_stores = sum(s.correct_stores for s in ss)
        rep, fn = sum(s.repeats_final for s in ss), sum(s.false_new for s in ss)
        nov, fi = sum(s.novel_final for s in ss), sum(s.false_identified for s in ss)
        st = stats[world]
        print(f"| {world} | {len(ss)} | {ok_ids}/{ids} = {ok_ids / max(ids, 1):.2f} | "
              f"{ok_stores}/{stores} = {ok_stores / max(stores, 1):.2f} | "
              f"{fn}/{rep} = {fn / max(rep, 1):.2f} | {fi}/{nov} = {fi / max(nov, 1):.2f} | "
              f"{[s.stores - s.categories for s in ss]} | {st.matches} | {st.vetoes} | "
              f"{st.coverage_holds} | {st.refinements} |")


def main() -> None:
    """Parse arguments and run one of the two measurements."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("closed-loop", help="roger compare on shipped and random worlds")
    p.add_argument("--world", type=Path, action="append", default=[])
    p.add_argument("--random", type=int, nargs="*", default=[],
                   help="seeds of random worlds (one world per seed and --recipe)")
    p.add_argument("--recipe", action="append", choices=sorted(RECIPES),
                   help="recipe of the random worlds (repeatable; default inspection)")
    p.add_argument("--seeds", type=int, default=3, help="run seeds 0..N-1 per policy")
    p.add_argument("--cycles", type=int, default=204)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--features", choices=("paper", "extended"), default="extended",
                   help="feature mode of perception and memory")
    p.set_defaults(func=closed_loop)
    r = sub.add_parser("replay", help="recorded query sets through fresh memories")
    r.add_argument("files", type=Path, nargs="+")
    r.add_argument("--unknown", nargs="*", default=[], choices=FEATURE_NAMES,
                   help="features to mark unknown in every look (e.g. T1 T2 T3)")
    r.set_defaults(func=replay_sets)
    args = parser.parse_args()
    args.func(args)


if __name__ == "__main__":
    main()
