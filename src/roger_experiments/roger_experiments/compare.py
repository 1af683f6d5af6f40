"""``roger compare``: both policies on the same world and seeds, Table 2 and Figures 4-6.

Pure Python apart from the runs themselves (``run_graph`` or the in-process loop).
"""

from __future__ import annotations

import csv
import json
import math
import statistics
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from roger_common.atomic import atomic_write_bytes
from roger_common.types import WorldSpec
from roger_experiments.evaluation import ERROR_KINDS
from roger_experiments.progress import ProgressBar, counters_info

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
    """One finished run: its metrics, its cycle log and its errors (errors.csv rows)."""

    policy: str
    seed: int
    metrics: dict[str, Any]
    rows: list[dict[str, str]]
    errors: list[dict[str, str]] = field(default_factory=list)


def read_cycles(path: Path) -> list[dict[str, str]]:
    """cycles.csv as a list of dicts."""
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


#: An empty shift this near an object (metres, ground plane) looked at a window spanning
#: it and a neighbour, or a part of it; farther, at a place with no object.
EMPTY_NEAR_M = 0.1


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


#: The sixth line of the report: the paper's runs "until no more new representations were
#: detected" visited every region of interest.
COMPLETION_CLAIM = "Every object is visited (ground truth, after the robot's own completion)"


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


@dataclass(frozen=True)
class TrainedTable:
    """The Q-table the Q-learning policy runs, greedy and frozen, and where it came from.

    Attributes:
        qtable: The table file.
        origin: How it came: "trained now" (``roger train`` run first) or "given".
        training: The ``train.json`` written beside it by ``roger train``, if any.
        world_seen: Whether the evaluation world is among the training worlds (by
            fingerprint); None when the training is unknown.
    """

    qtable: Path
    origin: str
    training: dict[str, Any] | None
    world_seen: bool | None

    @classmethod
    def of(cls, qtable: Path, world: WorldSpec, origin: str) -> TrainedTable:
        """Describe ``qtable`` for an evaluation on ``world``."""
        from roger_experiments.train import read_training, world_fingerprint

        training = read_training(qtable)
        seen = None
        if training is not None:
            prints = {w["fingerprint"] for w in training.get("worlds", [])}
            seen = world_fingerprint(world) in prints
        return cls(qtable, origin, training, seen)

    def td_errors(self) -> Path | None:
        """The training's ``td_errors.csv`` (Figure 6), if it is there."""
        path = self.qtable.with_name("td_errors.csv")
        return path if path.exists() else None

    def markdown(self) -> str:
        """What the report says about the table."""
        lines = ["## The Q-learning policy", "",
                 f"Greedy and frozen (no learning during these runs): the Q-table "
                 f"`{self.qtable}`, {self.origin}."]
        t = self.training
        if t is None:
            lines.append("No `train.json` beside it: what it was trained on is unknown.")
        else:
            names = ", ".join(f"`{w['name']}`" for w in t.get("worlds", []))
            seeds = ", ".join(str(s) for s in t.get("seeds", []))
            lines.append(f"Trained by `roger train` in {t.get('runs')} runs ({t.get('updates')} "
                         f"Q updates) on the worlds {names} with seeds {seeds}.")
            lines.append("The evaluation world is **one of the training worlds**: this is no "
                         "test on an unseen world." if self.world_seen else
                         "The evaluation world is not among them (compared by content).")
            first, last = t.get("mean_abs_td_first_10pct"), t.get("mean_abs_td_last_10pct")
            if first is not None and last is not None:
                lines.append(f"Mean |TD error| over the first tenth of training {first:.3f}, "
                             f"over the last tenth {last:.3f} (Figure 6).")
            changes = t.get("greedy_changes_second_half") or {}
            moving = {bits: n for bits, n in changes.items() if n}
            if changes:
                lines.append(
                    "In the second half of training the greedy action changed "
                    + (", ".join(f"{n} times in {bits}" for bits, n in moving.items())
                       if moving else "in no state")
                    + (": the values had not settled, and the table run here is where "
                       "training stopped." if moving else "."))
            q = t.get("q", {})
            if q:
                acts = ["attention_shift", "visual_improvement", "haptic_improvement",
                        "map_update"]
                lines += ["", "| state | shift | visual | haptic | map update | greedy |",
                          "|---|---|---|---|---|---|"]
                for bits, row in q.items():
                    cells = [f"{row[a]:.3f}" if a in row else "-" for a in acts]
                    greedy = ", ".join(t.get("greedy", {}).get(bits, []))
                    lines.append(f"| {bits} | " + " | ".join(cells) + f" | {greedy} |")
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
        by_mode: Feature mode name -> what ``compare`` returned for it (table2, claims,
            completion), in the order to show.
        world: The evaluation world.
    """
    modes = list(by_mode)
    names = {"qlearning": "Q-learning (1)", "straightforward": "simple (2)"}
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
            lines.append(f"| {names[policy]} | {mode} | "
                         + " | ".join(_fmt(row[c]) for c in (*COLUMNS, *SCORES)) + " |")
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
    from roger_experiments import plots
    from roger_experiments.train import plot_training, read_td_errors

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
        alpha = float((trained.training or {}).get("alpha", 0.5))
        plot_training(read_td_errors(path), out / "fig6.png", alpha,
                      f"the training of {trained.qtable}")
    else:
        plots.fig6(results, out / "fig6.png")
    return {"table2": table, "claims": claims, "completion": completion}


def compare(world: Path, seeds: list[int], out: Path,
            run_one: Callable[[str, int, Path], dict[str, Any]],
            progress: bool = True,
            trained: TrainedTable | None = None,
            run_complete: Callable[[str, int, Path], dict[str, Any]] | None = None
            ) -> dict[str, Any]:
    """Run both policies for every seed with ``run_one(policy, seed, run_dir)`` and write
    the comparison to ``out`` (``trained``: the Q-table the Q-learning runs use). With
    ``run_complete`` each pair also runs until the robot's own completion rule ends it
    (``out/complete``), for the report's sixth line."""
    def runs(kind: str, run: Callable[[str, int, Path], dict[str, Any]]) -> list[RunResult]:
        done: list[RunResult] = []
        what = ("compare, until the robot's own completion" if kind == "complete"
                else "compare")
        with ProgressBar(len(seeds) * len(POLICIES), what, "runs", enabled=progress) as bar:
            for seed in seeds:
                for policy in POLICIES:
                    bar.update(len(done), f"running {policy}, seed {seed}")
                    run_dir = out / kind / f"{policy}_seed{seed}"
                    metrics = run(policy, seed, run_dir)
                    errors = run_dir / "errors.csv"
                    done.append(RunResult(policy, seed, metrics,
                                          read_cycles(run_dir / "cycles.csv"),
                                          read_cycles(errors) if errors.exists() else []))
                    bar.update(len(done), f"{policy}, seed {seed}: {metrics['cycles']} "
                               f"cycles, {counters_info(metrics)}")
        return done
    results = runs("runs", run_one)
    complete_runs = runs("complete", run_complete) if run_complete is not None else None
    return write_outputs(out, results, str(world), trained, complete_runs)
