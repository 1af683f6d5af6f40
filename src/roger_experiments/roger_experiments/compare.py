"""``compare``: both policies on one world with run functions of your own.

Table 2, its statistics and the claims live in ``roger_experiments.table2`` (the
experiment), the run data in ``roger_experiments.results`` and the trained table in
``roger_experiments.train``; their names are kept importable from here for scripts
written before the move (bench/memory_targets.py, notebooks).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from roger_experiments.progress import ProgressBar, counters_info
from roger_experiments.results import RunResult, read_cycles, read_run
from roger_experiments.table2 import (
    CLAIMS,
    COLUMNS,
    COMPLETION_CLAIM,
    EMPTY_NEAR_M,
    EXTRA,
    PAPER_TABLE2,
    POLICIES,
    SCORES,
    check_claims,
    check_completion,
    completion_markdown,
    errors_markdown,
    mean_sd,
    modes_markdown,
    report_markdown,
    sign_test_p,
    table2,
    table2_markdown,
    write_outputs,
)
from roger_experiments.train import TrainedTable

#: ``run(policy, seed, run_dir) -> metrics``: one run written into ``run_dir``.
PolicyRun = Callable[[str, int, Path], dict[str, Any]]


def compare(world: Path, seeds: list[int], out: Path, run_one: PolicyRun,
            progress: bool = True, trained: TrainedTable | None = None,
            run_complete: PolicyRun | None = None) -> dict[str, Any]:
    """Run both policies for every seed with ``run_one(policy, seed, run_dir)`` and write
    the comparison to ``out`` (``trained``: the Q-table the Q-learning runs use). With
    ``run_complete`` each pair also runs until the robot's own completion rule ends it
    (``out/complete``), for the report's sixth line. (``table2.run_table2`` is the same
    experiment with a runner and a spec.)"""
    def runs(kind: str, run: PolicyRun) -> list[RunResult]:
        done: list[RunResult] = []
        what = ("compare, until the robot's own completion" if kind == "complete"
                else "compare")
        with ProgressBar(len(seeds) * len(POLICIES), what, "runs", enabled=progress) as bar:
            for seed in seeds:
                for policy in POLICIES:
                    bar.update(len(done), f"running {policy}, seed {seed}")
                    run_dir = out / kind / f"{policy}_seed{seed}"
                    metrics = run(policy, seed, run_dir)
                    done.append(read_run(run_dir, metrics))
                    bar.update(len(done), f"{policy}, seed {seed}: {metrics['cycles']} "
                               f"cycles, {counters_info(metrics)}")
        return done
    results = runs("runs", run_one)
    complete_runs = runs("complete", run_complete) if run_complete is not None else None
    return write_outputs(out, results, str(world), trained, complete_runs)


__all__ = ["CLAIMS", "COLUMNS", "COMPLETION_CLAIM", "EMPTY_NEAR_M", "EXTRA", "PAPER_TABLE2",
           "POLICIES", "SCORES", "RunResult", "TrainedTable", "check_claims",
           "check_completion", "compare", "completion_markdown", "errors_markdown", "mean_sd",
           "modes_markdown", "read_cycles", "report_markdown", "sign_test_p", "table2",
           "table2_markdown", "write_outputs"]
