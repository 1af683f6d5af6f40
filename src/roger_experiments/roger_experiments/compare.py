"""``roger compare``: both policies on the same world and seeds, Table 2 and Figures 4-6.

Pure Python apart from the runs themselves (``run_graph`` or the in-process loop).
"""

from __future__ import annotations

import csv
import json
import math
import statistics
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from roger_common.atomic import atomic_write_bytes

POLICIES: tuple[str, ...] = ("qlearning", "straightforward")
#: Table 2 of the paper, after 204 control loops: (1) Q-learning, (2) simple.
PAPER_TABLE2: dict[str, dict[str, int]] = {
    "qlearning": {"attention_shifts": 72, "improvements": 76, "positive_identifications": 29,
                  "new_objects": 27, "map_updates": 56},
    "straightforward": {"attention_shifts": 70, "improvements": 82,
                        "positive_identifications": 20, "new_objects": 32, "map_updates": 52},
}
#: Table 2's columns, with ``remaps`` (not in the paper) between new objects and map
#: updates: map_updates == positive_identifications + new_objects + remaps.
COLUMNS: tuple[str, ...] = ("attention_shifts", "improvements", "positive_identifications",
                            "new_objects", "remaps", "map_updates")
#: Scores shown after Table 2's columns, then the wall time (table2.json only).
SCORES: tuple[str, ...] = ("objects_visited", "identification_precision", "remap_precision",
                           "novelty_precision")
EXTRA: tuple[str, ...] = (*SCORES, "wall_seconds")
#: The paper's qualitative claims: Q-learning has more (+1) or fewer (-1) of each column.
CLAIMS: tuple[tuple[str, int, str], ...] = (
    ("attention_shifts", +1, "Q-learning performs more attention shifts"),
    ("improvements", -1, "Q-learning performs fewer eye/arm improvements"),
    ("positive_identifications", +1, "Q-learning makes more positive identifications"),
    ("new_objects", -1, "Q-learning detects fewer new objects"),
    ("map_updates", +1, "Q-learning performs more map updates"),
)


@dataclass(frozen=True)
class RunResult:
    """One finished run: its metrics and its cycle log."""

    policy: str
    seed: int
    metrics: dict[str, Any]
    rows: list[dict[str, str]]


def read_cycles(path: Path) -> list[dict[str, str]]:
    """cycles.csv as a list of dicts."""
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def mean_sd(values: list[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (0 for one value)."""
    if not values:
        return math.nan, math.nan
    return statistics.fmean(values), statistics.stdev(values) if len(values) > 1 else 0.0


def table2(results: list[RunResult]) -> dict[str, Any]:
    """Per policy, mean and standard deviation over seeds of each column, next to the paper."""
    out: dict[str, Any] = {}
    for policy in POLICIES:
        runs = [r for r in results if r.policy == policy]
        if not runs:
            continue
        row: dict[str, Any] = {"seeds": [r.seed for r in runs], "paper": PAPER_TABLE2[policy]}
        for col in COLUMNS + EXTRA:
            vals = [float(r.metrics[col]) for r in runs if r.metrics.get(col) is not None]
            m, sd = mean_sd(vals)
            row[col] = {"mean": m, "sd": sd, "n": len(vals)}
        row["cycles"] = runs[0].metrics.get("cycles")
        out[policy] = row
    return out


def sign_test_p(wins: int, losses: int) -> float:
    """Two-sided exact sign test p-value (ties dropped)."""
    n = wins + losses
    if n == 0:
        return 1.0
    k = min(wins, losses)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2 ** n
    return min(1.0, 2 * tail)


def check_claims(results: list[RunResult]) -> list[dict[str, Any]]:
    """For each of the paper's claims: in how many seeds it holds, and how surely."""
    by_seed: dict[int, dict[str, RunResult]] = {}
    for r in results:
        by_seed.setdefault(r.seed, {})[r.policy] = r
    paired = [v for v in by_seed.values() if all(p in v for p in POLICIES)]
    claims = []
    for col, sign, text in CLAIMS:
        diffs = [float(p["qlearning"].metrics[col]) - float(p["straightforward"].metrics[col])
                 for p in paired]
        wins = sum(1 for d in diffs if d * sign > 0)
        losses = sum(1 for d in diffs if d * sign < 0)
        m, sd = mean_sd(diffs)
        p = sign_test_p(wins, losses)
        if not diffs:
            verdict = "not tested"
        elif wins > losses and m * sign > 0:
            verdict = "holds" if p < 0.1 else "tends to hold"
        elif wins == losses or m == 0:
            verdict = "no difference"
        else:
            verdict = "contradicted" if p < 0.1 else "tends to be contradicted"
        claims.append({"claim": text, "column": col, "direction": sign, "seeds": len(diffs),
                       "holds_in": wins, "contradicted_in": losses,
                       "mean_difference": m, "sd_difference": sd, "sign_test_p": p,
                       "verdict": verdict})
    return claims


def _fmt(cell: dict[str, Any]) -> str:
    if cell["n"] == 0 or math.isnan(cell["mean"]):
        return "-"
    if abs(cell["mean"]) < 1.5 and cell["mean"] != int(cell["mean"]):
        return f"{cell['mean']:.2f} ± {cell['sd']:.2f}"
    return f"{cell['mean']:.1f} ± {cell['sd']:.1f}"


def table2_markdown(table: dict[str, Any], world: str) -> str:
    """Table 2 as Markdown: ours (mean ± sd over seeds) and the paper's rows."""
    names = {"qlearning": "Q-learning (1)", "straightforward": "simple (2)"}
    head = ("| approach | Att Shift | Eye/Arm Improv | Posit Ident | New Obj | Remaps "
            "| Map Update | objects visited | ident. precision | remap precision "
            "| novelty precision |")
    lines = [f"Table 2 on `{world}`: mean ± sd over seeds "
             f"{', '.join(str(s) for s in next(iter(table.values()))['seeds'])}, "
             f"{next(iter(table.values()))['cycles']} control cycles per run. A positive "
             "identification maps an entry not mapped before; remaps identify again an entry "
             "mapped before (not a column of the paper).", "",
             head, "|" + "---|" * (1 + len(COLUMNS) + len(SCORES))]
    for policy, row in table.items():
        cells = [_fmt(row[c]) for c in COLUMNS + SCORES]
        lines.append(f"| {names[policy]}, here | " + " | ".join(cells) + " |")
        paper = row["paper"]
        lines.append(f"| {names[policy]}, paper | "
                     + " | ".join([*(str(paper.get(c, "-")) for c in COLUMNS),
                                   *("-" for _ in SCORES)]) + " |")
    return "\n".join(lines) + "\n"


def report_markdown(table: dict[str, Any], claims: list[dict[str, Any]], world: str,
                    world_regions: str) -> str:
    """The short report: the table, then each of the paper's claims and whether it holds."""
    lines = ["# Q-learning vs the straightforward policy", "", table2_markdown(table, world),
             world_regions, "", "## The paper's claims", "",
             "| claim | verdict | holds in | contradicted in | mean difference (Q - simple) "
             "| sign test p |", "|---|---|---|---|---|---|"]
    for c in claims:
        lines.append(f"| {c['claim']} | **{c['verdict']}** | {c['holds_in']}/{c['seeds']} | "
                     f"{c['contradicted_in']}/{c['seeds']} | {c['mean_difference']:+.1f} ± "
                     f"{c['sd_difference']:.1f} | {c['sign_test_p']:.2f} |")
    lines += ["", "Verdicts: *holds* when Q-learning differs in the claimed direction in more "
              "seeds than not and a two-sided sign test over the seeds gives p < 0.1; *tends "
              "to* when the direction is right but p >= 0.1. With few seeds no verdict can be "
              "strong. Nothing was tuned to make a claim hold.", ""]
    return "\n".join(lines)


def write_outputs(out: Path, results: list[RunResult], world: str,
                  world_regions: str = "") -> dict[str, Any]:
    """Write table2.json, table2.md, report.md and the three figures."""
    from roger_experiments import plots

    out.mkdir(parents=True, exist_ok=True)
    table = table2(results)
    claims = check_claims(results)
    atomic_write_bytes(out / "table2.json", (json.dumps(
        {"world": world, "table2": table, "claims": claims}, indent=2) + "\n").encode())
    atomic_write_bytes(out / "table2.md", table2_markdown(table, world).encode())
    atomic_write_bytes(out / "report.md",
                       report_markdown(table, claims, world, world_regions).encode())
    plots.fig4(results, out / "fig4.png")
    plots.fig5(results, out / "fig5.png")
    plots.fig6(results, out / "fig6.png")
    return {"table2": table, "claims": claims}


def compare(world: Path, seeds: list[int], out: Path,
            run_one: Callable[[str, int, Path], dict[str, Any]],
            progress: Callable[[str], None] = print) -> dict[str, Any]:
    """Run both policies for every seed with ``run_one(policy, seed, run_dir)`` and write
    the comparison to ``out``."""
    results: list[RunResult] = []
    total = len(seeds) * len(POLICIES)
    for i, seed in enumerate(seeds):
        for j, policy in enumerate(POLICIES):
            run_dir = out / "runs" / f"{policy}_seed{seed}"
            progress(f"[{i * len(POLICIES) + j + 1}/{total}] {policy}, seed {seed}")
            metrics = run_one(policy, seed, run_dir)
            results.append(RunResult(policy, seed, metrics, read_cycles(run_dir / "cycles.csv")))
    return write_outputs(out, results, str(world))
