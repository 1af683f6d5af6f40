"""The paper's claims per training draw, from a finished sweep's runs.csv.

`roger sweep` judges each claim on Q-learning's mean over the training draws. When one draw
learnt a different robot (docs/experiments.md, "The claims sweep"), that mean hides it; this
judges each draw alone against the straightforward policy, with the same paired test
(``table2.paired_test``: exact Wilcoxon over world x seed, bootstrap interval over worlds),
and adds what share of the runs visited every object.

    python bench/sweep_by_draw.py runs/sweep-claims/runs.csv

Reads runs.csv only, so it needs no cell to run again.
"""

from __future__ import annotations

import argparse
import csv
from collections import defaultdict
from pathlib import Path

from roger_experiments.table2 import CLAIMS, paired_test

#: Columns judged per draw: the paper's five claims, and objects visited (more is better).
JUDGED = (*CLAIMS, ("objects_visited", +1, "Q-learning visits more objects"))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs_csv", type=Path)
    args = p.parse_args()
    rows = [r for r in csv.DictReader(args.runs_csv.open(encoding="utf-8"))
            if r["status"] == "done" and r["budget"] != "until-complete"]
    simple = {(r["features"], r["budget"], r["world_name"], r["seed"]): r
              for r in rows if r["policy"] == "straightforward"}
    groups: dict[tuple[str, str, str, str], list[dict[str, str]]] = defaultdict(list)
    for r in rows:
        if r["policy"] == "qlearning":
            groups[(r["features"], r.get("alpha_schedule", ""), r["budget"], r["draw"])].append(r)
    print("| features | step size | budget | draw | runs | every object visited | "
          + " | ".join(text for _, _, text in JUDGED) + " |")
    print("|---" * (6 + len(JUDGED)) + "|")
    for (features, schedule, budget, draw), mine in sorted(groups.items()):
        cells = []
        for column, sign, _ in JUDGED:
            by_world: dict[str, list[float]] = defaultdict(list)
            for r in mine:
                other = simple.get((features, budget, r["world_name"], r["seed"]))
                if other is not None and r[column] and other[column]:
                    by_world[r["world_name"]].append(float(r[column]) - float(other[column]))
            t = paired_test(by_world, sign)
            lo, hi = t["ci95"]
            cells.append(f"{t['verdict']} {t['mean_difference']:+.1f} [{lo:+.1f}, {hi:+.1f}]")
        every = sum(r["every_object_visited"] in ("True", "true", "1") for r in mine)
        print(f"| {features} | {schedule or '-'} | {budget} | {draw} | {len(mine)} | "
              f"{every}/{len(mine)} | " + " | ".join(cells) + " |")
    for features in sorted({k[0] for k in simple}):
        mine = [r for k, r in simple.items() if k[0] == features]
        every = sum(r["every_object_visited"] in ("True", "true", "1") for r in mine)
        print(f"straightforward, {features}: every object visited in {every}/{len(mine)} runs")


if __name__ == "__main__":
    main()
