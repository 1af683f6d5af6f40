"""Why a closed-loop run stores a category a second time: for each such store, the features
that part its final look from the first address of its category.

Runs the core loop in process (``run_core``, 204 cycles by default) on each world, policy,
seed and feature mode given, and watches every memory request. For each STORE of an object
whose category is already at an address (ground truth, read only to score), it prints:

- whether that first address was ever weighed (an address stored out of the arms' reach is
  silent to a weighed look: docs/memory.md, "Never weighed"), and whether the look was;
- the memory's own distance from the final look to that address (``distances``) against
  the acceptance distance;
- the features beyond their veto, and the largest |z| (the memory's z: the difference
  over sqrt 2 times the category scale), as compared with the first address's nearest
  look;
- what the memory itself decided on that final look (``AssociativeMemory.decide``): the
  network's winner (an address or the novel unit) and its share, and whether the veto
  (``veto_any_look``, against every look of the winner) turned it down; the nearest-look
  reading above can differ from it;
- the features the look did not know.

Then a summary per mode: stores of a category already stored, and how many of them had a
vetoed feature, a distance beyond the acceptance distance, or a never-weighed first address,
and which features were vetoed or had the largest |z| how often.

    python bench/stored_again.py --world runs/cl8k_ext/worlds/random_8x3_8001.yaml \
        --policies straightforward qlearning --seeds 0 --features extended paper

Diagnosis, not a result: the worlds it is run on are looked at.
"""

from __future__ import annotations

import argparse
import collections
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from roger_common.types import FeatureMode, MemoryOp, MemoryRequest, feature_names
from roger_experiments.core_loop import run_core
from roger_experiments.results import read_cycles
from roger_memory.memory import AssociativeMemory, Decision
from roger_sim.world import parse_world


@dataclass
class Again:
    """One store of a category that was already at an address."""

    world: str
    policy: str
    seed: int
    category: str
    address: int
    first: int
    distance: float
    tau: float
    vetoed: list[str]
    top: list[tuple[str, float]]
    unknown: list[str]
    first_weighed: bool
    look_weighed: bool
    winner: int = -1
    share: float = 0.0
    vetoed_by_memory: bool = False


@dataclass
class Summary:
    runs: int = 0
    stores: int = 0
    again: list[Again] = field(default_factory=list)


@contextmanager
def watched() -> Iterator[list[tuple[MemoryRequest, object, np.ndarray, Decision | None]]]:
    """Every request the memory handles, with its result, the distances before it and
    the memory's own decision (None for a store)."""
    log: list[tuple[MemoryRequest, object, np.ndarray, Decision | None]] = []
    original, original_decide = AssociativeMemory.handle, AssociativeMemory.decide
    decided: list[Decision] = []

    def decide(self: AssociativeMemory, *args, **kwargs):  # type: ignore[no-untyped-def]
        decision = original_decide(self, *args, **kwargs)
        decided.append(decision)
        return decision

    def handle(self: AssociativeMemory, req: MemoryRequest):  # type: ignore[no-untyped-def]
        before = self.distances(req.features, req.known) if self.size else np.zeros(0)
        decided.clear()
        result = original(self, req)
        log.append((req, result, before, decided[-1] if decided else None))
        return result

    AssociativeMemory.handle = handle  # type: ignore[method-assign]
    AssociativeMemory.decide = decide  # type: ignore[method-assign]
    try:
        yield log
    finally:
        AssociativeMemory.handle = original  # type: ignore[method-assign]
        AssociativeMemory.decide = original_decide  # type: ignore[method-assign]


def one_run(world_path: Path, policy: str, seed: int, mode: str, cycles: int,
            summary: Summary) -> None:
    world = parse_world(yaml.safe_load(world_path.read_text()), str(world_path))
    category = {o.name: str(o.category()) for o in world.objects}
    names = feature_names(FeatureMode(mode))
    w_index = names.index("W")
    with tempfile.TemporaryDirectory(prefix="roger-again-") as tmp, watched() as log:
        recorder, loop = run_core(world, policy, cycles, seed=seed, out=Path(tmp),
                                  features=mode)
        assert recorder is not None
        recorder.close(0.0)
        rows = read_cycles(Path(tmp) / "cycles.csv")
    memory = loop.memory
    assert memory is not None
    cfg = memory.config
    scale = np.asarray(cfg.feature_scale)
    address_category = {int(r["address"]): category.get(r["true_object"], "?")
                        for r in rows if r["outcome"] == "stored"}
    first_of: dict[str, int] = {}
    summary.runs += 1
    for i, (req, result, _, _) in enumerate(log):
        if req.op is not MemoryOp.STORE:
            continue
        summary.stores += 1
        address = int(result.address)  # type: ignore[attr-defined]
        cat = address_category.get(address, "?")
        if cat not in first_of:
            first_of[cat] = address
            continue
        first = first_of[cat]
        j = i - 1  # the final MATCH whose NEW made this store
        while j >= 0 and log[j][0].op is MemoryOp.STORE:
            j -= 1
        look = log[j][0]
        distance = float(log[j][2][first]) if first < len(log[j][2]) else float("nan")
        decision = log[j][3]
        looks, known = memory.exemplars(first), memory.exemplar_known(first)
        # The nearest look of the first address, as the veto compares.
        common = known & look.known[None, :]
        diff = np.abs(looks - look.features[None, :])
        z = np.where(common, diff / (np.sqrt(2.0) * scale[None, :]), 0.0)
        k = int(np.argmin(np.sqrt((z ** 2).sum(axis=1) / np.maximum(common.sum(axis=1), 1))))
        veto = memory.veto_between(look.features, look.known, looks[k], known[k])
        vetoed = [names[f] for f in range(len(names)) if common[k, f] and diff[k, f] > veto[f]]
        top = sorted(((names[f], float(z[k, f])) for f in range(len(names)) if common[k, f]),
                     key=lambda t: -t[1])[:4]
        summary.again.append(Again(
            world_path.stem, policy, seed, cat, address, first, distance,
            float(cfg.identify_distance), vetoed, top,
            [names[f] for f in range(len(names)) if not look.known[f]],
            bool(known[:, w_index].any()), bool(look.known[w_index]),
            decision.winner if decision else -1, decision.share if decision else 0.0,
            bool(decision and decision.vetoed)))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--world", type=Path, action="append", required=True)
    p.add_argument("--policies", nargs="+", default=["straightforward", "qlearning"])
    p.add_argument("--seeds", nargs="+", type=int, default=[0])
    p.add_argument("--features", nargs="+", default=["extended", "paper"])
    p.add_argument("--cycles", type=int, default=204)
    args = p.parse_args()
    for mode in args.features:
        summary = Summary()
        for world in args.world:
            for policy in args.policies:
                for seed in args.seeds:
                    one_run(world, policy, seed, mode, args.cycles, summary)
        print(f"\n## {mode}: {summary.runs} runs, {summary.stores} stores, "
              f"{len(summary.again)} of a category already stored")
        for a in summary.again:
            print(f"- {a.world} {a.policy} seed {a.seed}: {a.category} at {a.address} "
                  f"(first {a.first}, weighed {a.first_weighed}; look weighed "
                  f"{a.look_weighed}); memory: winner "
                  f"{'novel' if a.winner < 0 else a.winner} (share {a.share:.2f})"
                  f"{', vetoed' if a.vetoed_by_memory else ''}; "
                  f"distance {a.distance:.2f} (tau {a.tau:.2f}); "
                  f"vetoed by {a.vetoed or '-'}; largest |z| "
                  + ", ".join(f"{n} {v:.1f}" for n, v in a.top)
                  + (f"; unknown {a.unknown}" if a.unknown else ""))
        again = summary.again
        print(f"vetoed: {sum(bool(a.vetoed) for a in again)}; beyond tau, no veto: "
              f"{sum(not a.vetoed and a.distance > a.tau for a in again)}; within tau, no "
              f"veto: {sum(not a.vetoed and a.distance <= a.tau for a in again)}; first "
              f"address never weighed: {sum(not a.first_weighed for a in again)}; vetoed "
              f"by the memory itself: {sum(a.vetoed_by_memory for a in again)}")
        vetoes = collections.Counter(f for a in again for f in a.vetoed)
        tops = collections.Counter(a.top[0][0] for a in again if a.top)
        print(f"features vetoed: {dict(vetoes.most_common())}; largest |z|: "
              f"{dict(tops.most_common())}")


if __name__ == "__main__":
    main()
