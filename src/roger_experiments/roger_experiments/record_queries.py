"""Record the feature sets the attention loop sends to the memory (its MATCH queries).

The robot runs a world in process (``CoreLoop``) with a memory that never decides before
the final trial and calls every final trial new. Every focus then gets all its looks, in
the order the policy takes them: after the attention shift, after a visual improvement,
after a haptic improvement (the weight). Each MATCH request is one row: the features and
known mask exactly as the memory receives them, the final-trial flag, the focus (a number
that grows with each attention shift), the spatial-map entry (the robot's own association
of looks by position) and, for scoring only, the object under the attention window and its
category. The memory's calibration (docs/memory.md) reads the rows without their labels;
the labels only score it.

Run: ``python -m roger_experiments.record_queries --world worlds/inspection.yaml --seeds 0
--policies straightforward qlearning --cycles 204 --out queries.csv``.
"""

from __future__ import annotations

import argparse
import csv
import gzip
import io
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from roger_common.types import (
    DEFAULT_FEATURE_MODE,
    Action,
    FeatureMode,
    MatchOutcome,
    MatchResult,
    MemoryOp,
    MemoryRequest,
    WorldSpec,
    feature_names,
    mode_of_dim,
)
from roger_experiments.core_loop import CoreLoop
from roger_memory.config import MemoryConfig
from roger_memory.memory import AssociativeMemory
from roger_perception.config import PerceptionConfig

#: Columns of a query file before the features: the labels.
LABELS: tuple[str, ...] = (
    "world", "policy", "seed", "cycle", "action", "focus", "entry", "final", "object",
    "category")


def columns(mode: FeatureMode | str) -> tuple[str, ...]:
    """Columns of a query file of ``mode``: labels, then the features, then the known mask
    (the feature columns say which mode a file holds)."""
    names = feature_names(mode)
    return (*LABELS, *names, *(f"k_{n}" for n in names))


#: Columns of a paper-mode query file (the shipped test/data/memory_queries.csv.gz).
COLUMNS: tuple[str, ...] = columns(FeatureMode.PAPER)
_ACTIONS = {Action.ATTENTION_SHIFT: "shift", Action.VISUAL_IMPROVEMENT: "visual",
            Action.HAPTIC_IMPROVEMENT: "haptic"}


@dataclass(frozen=True)
class Query:
    """One recorded MATCH request and where it came from.

    Attributes:
        world: World name.
        policy: Policy that drove the robot.
        seed: Run seed.
        cycle: Control cycle of the request.
        action: "shift", "visual" or "haptic": the physical action before the match.
        focus: Number of the focus (attention shifts so far in the run).
        entry: Spatial-map entry in focus (the robot's association of looks by position).
        final: The request's final-trial flag.
        obj: Ground truth (scoring only): the object under the window; "" for none.
        category: Ground truth (scoring only): that object's category; "" for none.
        features: The feature vector as sent (its mode's length).
        known: Its known mask as sent.
    """

    world: str
    policy: str
    seed: int
    cycle: int
    action: str
    focus: int
    entry: int
    final: bool
    obj: str
    category: str
    features: np.ndarray
    known: np.ndarray


class _UndecidedMemory(AssociativeMemory):
    """A memory that says UNDETERMINED before the final trial and NEW on it, and keeps the
    requests: every focus gets all its improvements."""

    def __init__(self, mode: FeatureMode | str = DEFAULT_FEATURE_MODE) -> None:
        super().__init__(MemoryConfig.for_mode(mode))
        self.requests: list[MemoryRequest] = []
        self._n_stored = 0

    def handle(self, req: MemoryRequest) -> MatchResult:
        if req.op == MemoryOp.STORE:
            self._n_stored += 1
            return MatchResult(MatchOutcome.NEW, self._n_stored - 1, 1.0)
        self.requests.append(req)
        if req.final_trial:
            return MatchResult(MatchOutcome.NEW, -1, 0.0)
        return MatchResult(MatchOutcome.UNDETERMINED, -1, 0.0)


def category_label(world: WorldSpec, name: str | None) -> str:
    """A world object's category as one string (scoring only); "" for no object."""
    for o in world.objects:
        if o.name == name:
            shape, size, intensity, weight, texture = o.category()
            return f"{shape}/{size:g}/{intensity:g}/{weight:g}/{texture}"
    return ""


def record(world: WorldSpec, policy: str, seed: int, cycles: int,
           features: FeatureMode | str = DEFAULT_FEATURE_MODE) -> list[Query]:
    """Run ``cycles`` control cycles and return every MATCH request with its labels
    (feature vectors of the mode ``features``)."""
    mode = FeatureMode.parse(features)
    memory = _UndecidedMemory(mode)
    loop = CoreLoop(world, policy=policy, seed=seed, memory=memory,
                    perception_config=PerceptionConfig(features=mode.value),
                    memory_config=memory.config)
    rows: list[Query] = []
    focus = 0
    try:
        for rec in loop.cycles(cycles):
            if rec.action == Action.ATTENTION_SHIFT:
                focus += 1
            if rec.action == Action.MAP_UPDATE or not memory.requests:
                continue
            req = memory.requests.pop()
            obj = loop.true_object(rec)
            rows.append(Query(world.name, policy, seed, rec.cycle, _ACTIONS[rec.action], focus,
                              rec.entry_id, req.final_trial, obj or "",
                              category_label(world, obj),
                              np.asarray(req.features, np.float32).copy(),
                              np.asarray(req.known, bool).copy()))
    finally:
        loop.close()
    return rows


def _open(path: Path, mode: str) -> io.TextIOBase:
    if path.suffix == ".gz":
        # mtime 0: the same rows give the same bytes.
        raw = gzip.GzipFile(path, mode[0] + "b", mtime=0)
        return io.TextIOWrapper(raw, newline="")
    return open(path, mode, newline="")  # type: ignore[return-value]


def write_csv(queries: Iterable[Query], path: Path) -> None:
    """Write queries to a CSV file (features with 4 decimals; gzip when it ends in .gz).
    All queries must be of one feature mode; the columns name its features."""
    path.parent.mkdir(parents=True, exist_ok=True)
    queries = list(queries)
    modes = {mode_of_dim(len(q.features)) for q in queries} or {FeatureMode.PAPER}
    if len(modes) > 1:
        raise ValueError(f"queries of several feature modes: {sorted(m.value for m in modes)}")
    with _open(path, "w") as fh:
        w = csv.writer(fh)
        w.writerow(columns(modes.pop()))
        for q in queries:
            w.writerow([q.world, q.policy, q.seed, q.cycle, q.action, q.focus, q.entry,
                        int(q.final), q.obj, q.category,
                        *(f"{v:.4f}" if k else "" for v, k in zip(q.features, q.known,
                                                                 strict=True)),
                        *(int(k) for k in q.known)])


def read_csv(path: Path) -> list[Query]:
    """Read a file written by :func:`write_csv`."""
    out: list[Query] = []
    with _open(Path(path), "r") as fh:
        reader = csv.DictReader(fh)
        header = tuple(reader.fieldnames or ())
        modes = [m for m in FeatureMode if header == columns(m)]
        if not modes:
            raise ValueError(f"{path}: the columns are not those of a query file of any "
                             "feature mode")
        names = feature_names(modes[0])
        for r in reader:
            known = np.array([r[f"k_{n}"] == "1" for n in names])
            feats = np.array([float(r[n]) if k else 0.0 for n, k in zip(names, known,
                                                                       strict=True)],
                             np.float32)
            out.append(Query(r["world"], r["policy"], int(r["seed"]), int(r["cycle"]),
                             r["action"], int(r["focus"]), int(r["entry"]), r["final"] == "1",
                             r["object"], r["category"], feats, known))
    return out


@dataclass
class ReplayScore:
    """How a memory decided the foci of one recorded run (labels score it).

    Attributes:
        run: (world, policy, seed).
        identifications: Foci identified (non-final or final).
        correct_identifications: Of them, identified as an address stored from an object of
            the same category.
        stores: Foci called new on their final trial (then stored).
        correct_stores: Of them, stores of a category not yet in memory.
        repeats_final: Final trials of a category already in memory.
        false_new: Of them, called new.
        novel_final: Final trials of a category not in memory.
        false_identified: Of them, identified.
        categories: Categories under the window in the run.
    """

    run: tuple[str, str, int]
    identifications: int = 0
    correct_identifications: int = 0
    stores: int = 0
    correct_stores: int = 0
    repeats_final: int = 0
    false_new: int = 0
    novel_final: int = 0
    false_identified: int = 0
    categories: int = 0


def replay(queries: Sequence[Query], memory_factory: Any) -> list[ReplayScore]:
    """Replay recorded foci through fresh memories, one per run, as the straightforward
    policy would: each look of a focus is matched in order (with the focus id) until one
    is identified; a final trial called new is stored (with the focus id). The labels
    only score it.

    Args:
        queries: Recorded queries (one or several runs).
        memory_factory: Called with no argument per run; returns an AssociativeMemory.
    """
    runs: dict[tuple[str, str, int], dict[int, list[Query]]] = {}
    for q in queries:
        runs.setdefault((q.world, q.policy, q.seed), {}).setdefault(q.focus, []).append(q)
    scores = []
    for run, foci in runs.items():
        memory = memory_factory()
        category_of: dict[int, str] = {}
        score = ReplayScore(run)
        seen: set[str] = set()
        for focus, looks in foci.items():
            for q in looks:
                if q.category:
                    seen.add(q.category)
                result = memory.match(q.features, q.known, q.final, focus_id=focus + 1)
                in_memory = q.category != "" and q.category in category_of.values()
                if q.final and q.category:
                    if in_memory:
                        score.repeats_final += 1
                        score.false_new += result.outcome == MatchOutcome.NEW
                    else:
                        score.novel_final += 1
                        score.false_identified += result.outcome == MatchOutcome.IDENTIFIED
                if result.outcome == MatchOutcome.IDENTIFIED:
                    score.identifications += 1
                    score.correct_identifications += (
                        q.category != "" and category_of.get(result.address) == q.category)
                    break
                if result.outcome == MatchOutcome.NEW:
                    score.stores += 1
                    score.correct_stores += q.category != "" and not in_memory
                    category_of[memory.store(q.features, q.known, focus_id=focus + 1)] = \
                        q.category
                    break
        score.categories = len(seen)
        scores.append(score)
    return scores


def recipe_world(spec: str) -> WorldSpec:
    """A random world named ``RECIPE:SEED``: plain (8 categories x 3, sizes 0.08-0.14 m,
    as bench/memory_targets.py draws them), twins (``shape_twins``: 4 x 3) or yaw
    (``yaw_copies``: 8 x 3)."""
    from roger_sim.worldgen import random_world
    recipe, _, seed_text = spec.partition(":")
    try:
        seed = int(seed_text)
    except ValueError:
        raise ValueError(f"random world {spec!r}: expected RECIPE:SEED, e.g. twins:7") from None
    if recipe == "plain":
        return random_world(8, 3, seed, size_range=(0.08, 0.14))
    if recipe == "twins":
        return random_world(4, 3, seed, size_range=(0.08, 0.14), shape_twins=True)
    if recipe == "yaw":
        return random_world(8, 3, seed, size_range=(0.08, 0.14), yaw_copies=True)
    raise ValueError(f"random world {spec!r}: recipe must be plain, twins or yaw")


def main(argv: Sequence[str] | None = None) -> None:
    """Command line: record one or more worlds, policies and seeds into one CSV file."""
    from roger_sim.world import load_world

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--world", type=Path, action="append", default=None)
    p.add_argument("--policies", nargs="+", default=["straightforward"])
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--cycles", type=int, default=204)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--features", choices=[m.value for m in FeatureMode],
                   default=DEFAULT_FEATURE_MODE.value, help="feature mode to record")
    p.add_argument("--random", nargs="*", default=[], metavar="RECIPE:SEED",
                   help="random worlds too: plain:S, twins:S or yaw:S "
                        "(roger_sim.worldgen.random_world(8 or 4, 3, S, ...))")
    args = p.parse_args(argv)
    rows: list[Query] = []
    worlds = [load_world(w) for w in args.world or []]
    worlds += [recipe_world(spec) for spec in args.random]
    for world in worlds:
        for policy in args.policies:
            for seed in args.seeds:
                rows += record(world, policy, seed, args.cycles, args.features)
    write_csv(rows, args.out)
    print(f"{len(rows)} queries written to {args.out}")


if __name__ == "__main__":
    main()
