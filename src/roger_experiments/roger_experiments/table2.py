"""Table 2 of the paper as one experiment: Q-learning against the straightforward policy.

Read top to bottom, as the experiment goes:

1. the spec (``Table2Spec``); one run is a ``runners.RunSpec``, a pure function of it;
2. train: a Q-table learnt on random worlds other than the evaluation world (``train``),
   unless one is given, and checked by fingerprint (``TrainedTable``);
3. run: every policy x seed (and, for the sixth claim, again until the robot's own
   completion rule), by a *runner* passed in (``roger_experiments.runners``): one after
   another in this process (``SequentialRunner`` with ``run_in_process``), through the ROS
   graph (``roger_bringup.graph_run``), or as Ray tasks (``ray_runner.RayRunner``);
4. score: Table 2's counters per policy (``table2``);
5. judge: the paper's five claims and "every object visited" (``check_claims``,
   ``check_completion``); the same tests over many worlds serve ``roger sweep``
   (``paired_test``);
6. report: table2.json, table2.md, report.md and Figures 4-6 (``write_outputs``).

``roger compare`` and ``roger demo`` call ``run_table2``; ``roger sweep`` reuses the runs,
statistics and claims over worlds x seeds x draws.
"""

from __future__ import annotations

import json
import math
import random
import statistics
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from roger_common.atomic import atomic_write_bytes
from roger_experiments import plots
from roger_experiments.evaluation import ERROR_KINDS
from roger_experiments.progress import ProgressBar, counters_info
from roger_experiments.results import RunResult, read_run
from roger_experiments.runners import Job, Runner, RunSpec
from roger_experiments.train import (
    RandomWorlds,
    TrainedTable,
    plot_training,
    read_td_errors,
    train_in_process,
)

# --- Table 2 and the paper's claims ------------------------------------------------------

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
#: The sixth line of the report: the paper's runs "until no more new representations were
#: detected" visited every region of interest.
COMPLETION_CLAIM = "Every object is visited (ground truth, after the robot's own completion)"

# --- The spec ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Table2Spec:
    """One Table 2 experiment (``roger compare``, ``roger demo``).

    Attributes:
        world: The evaluation world file.
        seeds: Run seeds; every policy runs every seed.
        cycles: Control cycles of each run (the paper: 204).
        features: The feature mode whose outputs go to the output folder itself.
        also_modes: Further feature modes, same seeds and Q-table, into ``OUT/<mode>``.
        stable_cycles: Also run each policy and seed until the robot's own completion rule
            (no new object for this many cycles, no unmapped entry), for the sixth claim;
            0 skips those runs.
        qtable: A trained Q-table; None trains one first, in process, into ``OUT/train``.
        training: The random worlds of that training.
        train_seeds: Seeds per training world.
    """

    world: Path
    seeds: tuple[int, ...]
    cycles: int = 204
    features: str = "extended"
    also_modes: tuple[str, ...] = ()
    stable_cycles: int = 40
    qtable: Path | None = None
    training: RandomWorlds = field(default_factory=RandomWorlds)
    train_seeds: int = 2

    def modes(self) -> list[str]:
        """The feature modes, the main one first."""
        return [self.features] + [m for m in self.also_modes if m != self.features]


# --- Run, score, judge, report ----------------------------------------------------------


def run_table2(spec: Table2Spec, out: Path, runner: Runner, progress: bool = True,
               log: Callable[[str], None] = print) -> dict[str, dict[str, Any]]:
    """Train (unless a table is given), run both policies on every seed in every feature
    mode with ``runner``, and write Table 2, the claims and the figures of each mode.

    Returns:
        Feature mode -> what ``write_outputs`` returned (table2, claims, completion), plus
        ``qtable`` and ``trained`` (the TrainedTable) under each.
    """
    from roger_sim.world import load_world

    world = load_world(spec.world)
    # 1. Train.
    if spec.qtable is not None:
        qtable, origin = spec.qtable, "given with --qtable"
    else:
        t, train_out = spec.training, out / "train"
        log(f"training the Q-learning policy first: {t.count} random worlds (seeds "
            f"{t.seed0}-{t.seed0 + t.count - 1}) x seeds 0-{spec.train_seeds - 1}, "
            f"{spec.cycles} cycles each, in process -> {train_out}")
        train_in_process(t, list(range(spec.train_seeds)), spec.cycles, train_out,
                         progress=progress, features=spec.features)
        qtable, origin = train_out / "qtable.json", "trained now by `roger train` (in process)"
    trained = TrainedTable.of(qtable, world, origin)
    qtable_text = qtable.read_text()
    # 2. Run: every mode, policy and seed, at once, so a parallel runner has them all.
    modes = spec.modes()
    kinds = ["runs"] + (["complete"] if spec.stable_cycles > 0 else [])
    jobs: list[Job] = []
    for mode in modes:
        mode_out = out if mode == spec.features else out / mode
        for kind in kinds:
            for seed in spec.seeds:
                for policy in POLICIES:
                    jobs.append(Job(RunSpec.of_file(
                        spec.world, policy=policy, seed=seed,
                        cycles=None if kind == "complete" else spec.cycles, features=mode,
                        qtable_text=qtable_text if policy == "qlearning" else None,
                        stable_cycles=spec.stable_cycles),
                        mode_out / kind / f"{policy}_seed{seed}"))
    done: dict[Path, RunResult] = {}
    with ProgressBar(len(jobs), "compare", "runs", enabled=progress) as bar:
        for job, metrics in runner(jobs):
            if isinstance(metrics, Exception):
                raise metrics
            assert isinstance(job.spec, RunSpec)
            done[job.out] = read_run(job.out, metrics)
            bar.update(len(done), f"{job.spec.features} {job.spec.label()}: "
                       f"{metrics['cycles']} cycles, {counters_info(metrics)}")
    # 3. Score, judge and report, mode by mode.
    results: dict[str, dict[str, Any]] = {}
    for mode in modes:
        mode_out = out if mode == spec.features else out / mode
        picked = {kind: [done[j.out] for j in jobs if j.out.parent == mode_out / kind]
                  for kind in kinds}
        results[mode] = write_outputs(mode_out, picked["runs"], str(spec.world), trained,
                                      picked.get("complete"))
        results[mode].update(qtable=qtable, trained=trained)
    if len(modes) > 1:
        side = modes_markdown(results, str(spec.world))
        atomic_write_bytes(out / "modes.md", side.encode())
        report = out / "report.md"
        atomic_write_bytes(report, (report.read_text() + "\n" + side).encode())
    return results


def mean_sd(values: Sequence[float]) -> tuple[float, float]:
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


def wilcoxon_signed_rank(diffs: Sequence[float]) -> dict[str, float]:
    """Two-sided exact Wilcoxon signed-rank test of paired differences (zeros dropped, tied
    magnitudes given their mean rank; the null distribution is enumerated exactly for that
    tie pattern, so small samples need no normal approximation).

    Returns:
        ``n`` (non-zero differences), ``w_plus`` (rank sum of the positive ones), ``p``,
        and ``rank_biserial`` ((W+ - W-) / (W+ + W-), the matched-pairs effect size in
        [-1, 1]; 0 without differences).
    """
    nz = sorted((abs(d), d) for d in diffs if d != 0)
    n = len(nz)
    if n == 0:
        return {"n": 0, "w_plus": 0.0, "p": 1.0, "rank_biserial": 0.0}
    # Twice the mean ranks: integers even with ties.
    ranks2: list[int] = []
    i = 0
    while i < n:
        j = i
        while j + 1 < n and nz[j + 1][0] == nz[i][0]:
            j += 1
        ranks2 += [i + j + 2] * (j - i + 1)
        i = j + 1
    total2 = sum(ranks2)
    w2 = sum(r for r, (_, d) in zip(ranks2, nz, strict=True) if d > 0)
    counts = [0] * (total2 + 1)  # ways to reach each doubled rank sum
    counts[0] = 1
    for r in ranks2:
        for s in range(total2, r - 1, -1):
            counts[s] += counts[s - r]
    lo = min(w2, total2 - w2)
    tail = sum(counts[: lo + 1]) / 2 ** n
    return {"n": n, "w_plus": w2 / 2, "p": min(1.0, 2 * tail),
            "rank_biserial": (2 * w2 - total2) / total2}


def bootstrap_mean_ci(groups: Sequence[Sequence[float]], seed: int = 0,
                      resamples: int = 4000, level: float = 0.95) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of all values, resampling whole groups
    (the worlds: pairs on one world are not independent of each other)."""
    groups = [list(g) for g in groups if g]
    if not groups:
        return math.nan, math.nan
    rng = random.Random(seed)
    means = []
    for _ in range(resamples):
        pick = [v for _ in groups for v in groups[rng.randrange(len(groups))]]
        means.append(statistics.fmean(pick))
    means.sort()
    k = (1 - level) / 2
    return means[int(k * resamples)], means[min(resamples - 1, int((1 - k) * resamples))]


def paired_test(diffs_by_group: dict[Any, list[float]], sign: int) -> dict[str, Any]:
    """A claim judged on paired differences (Q-learning minus simple) grouped by world.

    The test is the exact Wilcoxon signed-rank test over the pairs (world x seed): counts
    are discrete and their differences far from normal, which rules out a t test, and the
    signed ranks use how large each difference is, which the sign test (reported too)
    throws away. The effect size is the mean difference with a bootstrap 95 % interval
    over worlds, and the rank-biserial correlation.

    Verdict: *holds* when the interval lies on the claimed side of 0 and p < 0.05;
    *contradicted* when it lies on the other side and p < 0.05; *not shown* otherwise.
    """
    diffs = [d for g in diffs_by_group.values() for d in g]
    wins = sum(1 for d in diffs if d * sign > 0)
    losses = sum(1 for d in diffs if d * sign < 0)
    m, sd = mean_sd(diffs)
    w = wilcoxon_signed_rank(diffs)
    lo, hi = bootstrap_mean_ci(list(diffs_by_group.values()))
    if not diffs:
        verdict = "not tested"
    elif w["p"] < 0.05 and sign * lo > 0 and sign * hi > 0:
        verdict = "holds"
    elif w["p"] < 0.05 and sign * lo < 0 and sign * hi < 0:
        verdict = "contradicted"
    else:
        verdict = "not shown"
    return {"pairs": len(diffs), "groups": len(diffs_by_group), "holds_in": wins,
            "contradicted_in": losses, "mean_difference": m, "sd_difference": sd,
            "ci95": [lo, hi], "wilcoxon_p": w["p"], "rank_biserial": w["rank_biserial"],
            "sign_test_p": sign_test_p(wins, losses), "verdict": verdict}


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


def check_completion(runs: list[RunResult]) -> dict[str, Any]:
    """The sixth claim, from runs that ended by the robot's completion rule: in how many
    every object of the world was visited (judged on the ground truth afterwards)."""
    per_policy: dict[str, Any] = {}
    for policy in POLICIES:
        mine = [r for r in runs if r.policy == policy]
        if not mine:
            continue
        per_policy[policy] = {
            "runs": len(mine),
            "complete": sum(1 for r in mine if r.metrics.get("complete")),
            "every_object_visited": sum(1 for r in mine
                                        if r.metrics.get("every_object_visited")),
            "cycles": [int(r.metrics["cycles"]) for r in mine],
            "objects_visited": [int(r.metrics["objects_visited"]) for r in mine],
            "objects_in_world": int(mine[0].metrics["objects_in_world"]),
        }
    n = sum(v["runs"] for v in per_policy.values())
    complete = sum(v["complete"] for v in per_policy.values())
    visited = sum(v["every_object_visited"] for v in per_policy.values())
    if n == 0:
        verdict = "not tested"
    elif visited == n:
        verdict = "holds"
    elif visited == 0:
        verdict = "does not hold"
    else:
        verdict = "holds in some runs"
    return {"claim": COMPLETION_CLAIM, "runs": n, "complete": complete,
            "every_object_visited": visited, "verdict": verdict, "per_policy": per_policy}


#: An empty shift this near an object (metres, ground plane) looked at a window spanning
#: it and a neighbour, or a part of it; farther, at a place with no object.
EMPTY_NEAR_M = 0.1
NAMES = {"qlearning": "Q-learning (1)", "straightforward": "simple (2)"}


def errors_markdown(results: list[RunResult]) -> str:
    """What went wrong in each run, from its errors.csv: who was taken for whom, which
    categories were stored again, where the empty attention shifts looked."""
    lines = ["## What went wrong (ground truth)", "",
             "Per run, from its errors.csv: identifications of an address stored from "
             "another category (*object* **as** *the object the address was stored from*, "
             "times), stores of a category already stored (*object* (*first stored*)), "
             "stores while no single object filled the window, and attention shifts whose "
             f"window showed no object (within {EMPTY_NEAR_M:g} m of an object: a window "
             "spanning two objects or a part of one).", ""]
    for r in results:
        by_kind: dict[str, list[dict[str, str]]] = defaultdict(list)
        for e in r.errors:
            by_kind[e["kind"]].append(e)
        parts = []
        for kind in ERROR_KINDS:
            errs = by_kind.get(kind, [])
            if not errs:
                continue
            name = kind.replace("_", " ")
            if kind in ("wrong_identification", "wrong_remap"):
                pairs: dict[str, list[str]] = defaultdict(list)
                for e in errs:
                    pairs[e["other"] or "?"].append(e["object"] or "no single object")
                detail = "; ".join(f"{', '.join(sorted(set(objs)))} **as** {other} x{len(objs)}"
                                   for other, objs in sorted(pairs.items(),
                                                             key=lambda kv: -len(kv[1])))
            elif kind == "repeated_store":
                detail = ", ".join(f"{e['object']} ({e['other'] or 'a loaded memory'})"
                                   for e in errs)
            elif kind == "empty_shift":
                near = [e for e in errs if e["distance_m"]
                        and float(e["distance_m"]) <= EMPTY_NEAR_M]
                objs = sorted({e["other"] for e in near})
                detail = (f"{len(near)} near an object ({', '.join(objs)})" if near
                          else "none near an object")
            else:
                detail = f"cycles {', '.join(e['cycle'] for e in errs)}"
            parts.append(f"{len(errs)} {name}{'s' if len(errs) > 1 else ''}: {detail}")
        lines.append(f"- {r.policy}, seed {r.seed}: " + (". ".join(parts) if parts
                                                        else "no error"))
    lines.append("")
    return "\n".join(lines)


def completion_markdown(c: dict[str, Any]) -> tuple[str, str]:
    """The sixth line of the report's claims table, and what each policy's runs did."""
    names = {"qlearning": "Q-learning", "straightforward": "simple"}
    parts = []
    for policy, v in c["per_policy"].items():
        parts.append(f"{names[policy]}: {v['every_object_visited']}/{v['runs']} runs visited "
                     f"all {v['objects_in_world']} objects (visited "
                     f"{', '.join(str(k) for k in v['objects_visited'])}); the robot's rule "
                     f"ended {v['complete']}/{v['runs']} of them, after "
                     f"{', '.join(str(k) for k in v['cycles'])} cycles.")
    missed = c["runs"] - c["every_object_visited"]
    row = (f"| {c['claim']} | **{c['verdict']}** | {c['every_object_visited']}/{c['runs']} "
           f"runs | {missed}/{c['runs']} runs | - | - |")
    return row, " ".join(parts)


def fmt(cell: dict[str, Any]) -> str:
    """A table cell: mean ± sd (two decimals for fractions)."""
    if cell["n"] == 0 or math.isnan(cell["mean"]):
        return "-"
    if abs(cell["mean"]) < 1.5 and cell["mean"] != int(cell["mean"]):
        return f"{cell['mean']:.2f} ± {cell['sd']:.2f}"
    return f"{cell['mean']:.1f} ± {cell['sd']:.1f}"


def table2_markdown(table: dict[str, Any], world: str) -> str:
    """Table 2 as Markdown: ours (mean ± sd over seeds) and the paper's rows."""
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
        cells = [fmt(row[c]) for c in COLUMNS + SCORES]
        lines.append(f"| {NAMES[policy]}, here | " + " | ".join(cells) + " |")
        paper = row["paper"]
        lines.append(f"| {NAMES[policy]}, paper | "
                     + " | ".join([*(str(paper.get(c, "-")) for c in COLUMNS),
                                   *("-" for _ in SCORES)]) + " |")
    return "\n".join(lines) + "\n"


def report_markdown(table: dict[str, Any], claims: list[dict[str, Any]], world: str,
                    policy_note: str = "", completion: dict[str, Any] | None = None) -> str:
    """The short report: the table, then each of the paper's claims and whether it holds."""
    lines = ["# Q-learning vs the straightforward policy", "", table2_markdown(table, world),
             policy_note, "", "## The paper's claims", "",
             "| claim | verdict | holds in | contradicted in | mean difference (Q - simple) "
             "| sign test p |", "|---|---|---|---|---|---|"]
    for c in claims:
        lines.append(f"| {c['claim']} | **{c['verdict']}** | {c['holds_in']}/{c['seeds']} | "
                     f"{c['contradicted_in']}/{c['seeds']} | {c['mean_difference']:+.1f} ± "
                     f"{c['sd_difference']:.1f} | {c['sign_test_p']:.2f} |")
    detail = ""
    if completion is not None:
        row, detail = completion_markdown(completion)
        lines.append(row)
    lines += ["", "Verdicts: *holds* when Q-learning differs in the claimed direction in more "
              "seeds than not and a two-sided sign test over the seeds gives p < 0.1; *tends "
              "to* when the direction is right but p >= 0.1. With few seeds no verdict can be "
              "strong. Nothing was tuned to make a claim hold."]
    if completion is not None:
        lines.append("The last line comes from other runs of both policies and the same "
                     "seeds that went on until the robot itself had stored no new object for "
                     "a while and had no unmapped entry left (as the paper's runs \"until no "
                     "more new representations were detected\"); only then did the ground "
                     "truth judge whether every object had filled the attention window once. "
                     + detail)
    lines.append("")
    return "\n".join(lines)


def modes_markdown(by_mode: dict[str, dict[str, Any]], world: str) -> str:
    """Table 2 and the claims of several feature modes side by side (``roger demo``).

    Args:
        by_mode: Feature mode name -> what ``write_outputs`` returned for it (table2,
            claims, completion), in the order to show.
        world: The evaluation world.
    """
    modes = list(by_mode)
    lines = [f"## Feature modes side by side on `{world}`", "",
             "The same world, seeds and Q-table; `paper` is the eleven features of "
             "equations 1-5, `extended` adds shape from stereo and touch "
             "(docs/perception.md, \"Extended features\"). Mean ± sd over seeds.", "",
             "| approach | mode | " + " | ".join(c.replace("_", " ") for c in
                                                 (*COLUMNS, *SCORES)) + " |",
             "|" + "---|" * (2 + len(COLUMNS) + len(SCORES))]
    for policy in POLICIES:
        for mode in modes:
            row = by_mode[mode]["table2"].get(policy)
            if row is None:
                continue
            lines.append(f"| {NAMES[policy]} | {mode} | "
                         + " | ".join(fmt(row[c]) for c in (*COLUMNS, *SCORES)) + " |")
    lines += ["", "| claim | " + " | ".join(f"{m}: verdict (holds in)" for m in modes) + " |",
              "|---|" + "---|" * len(modes)]
    first = by_mode[modes[0]]["claims"]
    for i, claim in enumerate(first):
        cells = []
        for mode in modes:
            c = by_mode[mode]["claims"][i]
            cells.append(f"{c['verdict']} ({c['holds_in']}/{c['seeds']})")
        lines.append(f"| {claim['claim']} | " + " | ".join(cells) + " |")
    if all(by_mode[m].get("completion") for m in modes):
        cells = []
        for mode in modes:
            c = by_mode[mode]["completion"]
            cells.append(f"{c['verdict']} ({c['every_object_visited']}/{c['runs']})")
        lines.append(f"| {first and by_mode[modes[0]]['completion']['claim']} | "
                     + " | ".join(cells) + " |")
    lines.append("")
    return "\n".join(lines)


def write_outputs(out: Path, results: list[RunResult], world: str,
                  trained: TrainedTable | None = None,
                  complete_runs: list[RunResult] | None = None) -> dict[str, Any]:
    """Write table2.json, table2.md, report.md and the three figures (Figure 6 from the
    training of the Q-table when its log is there)."""
    out.mkdir(parents=True, exist_ok=True)
    table = table2(results)
    claims = check_claims(results)
    completion = check_completion(complete_runs) if complete_runs is not None else None
    qlearning = None if trained is None else {
        "qtable": str(trained.qtable), "origin": trained.origin,
        "evaluation_world_in_training": trained.world_seen,
        "training": trained.training}
    atomic_write_bytes(out / "table2.json", (json.dumps(
        {"world": world, "table2": table, "claims": claims, "completion": completion,
         "qlearning": qlearning},
        indent=2) + "\n").encode())
    atomic_write_bytes(out / "table2.md", table2_markdown(table, world).encode())
    note = trained.markdown() if trained is not None else ""
    report = report_markdown(table, claims, world, note, completion)
    if any(r.errors for r in results):
        report += "\n" + errors_markdown(results)
    atomic_write_bytes(out / "report.md", report.encode())
    plots.fig4(results, out / "fig4.png")
    plots.fig5(results, out / "fig5.png")
    if trained is not None and (path := trained.td_errors()) is not None:
        training = trained.training or {}
        alpha = float(training.get("alpha", 0.5))
        alpha_k = (float(training.get("alpha_k", 20.0))
                   if training.get("alpha_schedule") == "visits" else None)
        plot_training(read_td_errors(path), out / "fig6.png", alpha,
                      f"the training of {trained.qtable}", alpha_k)
    else:
        plots.fig6(results, out / "fig6.png")
    return {"table2": table, "claims": claims, "completion": completion}

