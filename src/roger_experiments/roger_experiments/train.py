"""``roger train``: Q-learning of the attention policy over worlds and seeds.

One Q-table is carried from run to run (saved atomically after each). Each run is a
whole attention session on one world with one seed, learning online, through the same
core loop the graph runs (in process, without ROS, for speed) or through the real graph.
"""

from __future__ import annotations

import csv
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from roger_attention.fsm import STATES, possible_actions
from roger_attention.qlearning import QTable
from roger_common.atomic import atomic_write_bytes


def train(worlds: list[Path], seeds: list[int], out: Path,
          run_one: Callable[[Path, int, Path, Path], dict[str, Any]],
          progress: Callable[[str], None] = print) -> dict[str, Any]:
    """Train one Q-table over every (world, seed) pair, in that order.

    Args:
        worlds: World files.
        seeds: Seeds; every world is run with every seed.
        out: Output folder: qtable.json, td_errors.csv, td_errors.png, runs/.
        run_one: ``run_one(world, seed, qtable_path, run_dir) -> metrics``; learns from and
            saves to ``qtable_path``.

    Returns:
        A summary: runs, TD errors, the final table's greedy action per state.
    """
    out.mkdir(parents=True, exist_ok=True)
    qtable = out / "qtable.json"
    td_all: list[tuple[int, str, int, float]] = []
    total = len(worlds) * len(seeds)
    t0 = time.monotonic()
    k = 0
    for world in worlds:
        for seed in seeds:
            k += 1
            run_dir = out / "runs" / f"{world.stem}_seed{seed}"
            progress(f"[{k}/{total}] {world.name}, seed {seed}")
            run_one(world, seed, qtable, run_dir)
            with open(run_dir / "cycles.csv", newline="") as fh:
                for row in csv.DictReader(fh):
                    if row["td_error"]:
                        td_all.append((k, world.stem, seed, float(row["td_error"])))
    lines = ["trial,run,world,seed,td_error"] + [
        f"{i + 1},{run},{w},{s},{td:.6g}" for i, (run, w, s, td) in enumerate(td_all)]
    atomic_write_bytes(out / "td_errors.csv", ("\n".join(lines) + "\n").encode())
    td = np.array([t[3] for t in td_all])
    _plot(td, out / "td_errors.png")
    table = QTable.load(qtable)
    greedy = {s.bits: [a.name.lower() for a in table.greedy_actions(s, possible_actions(s))]
              for s in STATES}
    return {"runs": total, "updates": int(td.size), "qtable": str(qtable),
            "mean_abs_td_first_10pct": float(np.abs(td[: max(1, td.size // 10)]).mean())
            if td.size else None,
            "mean_abs_td_last_10pct": float(np.abs(td[-max(1, td.size // 10):]).mean())
            if td.size else None,
            "greedy": greedy, "wall_seconds": round(time.monotonic() - t0, 1)}


def _plot(td: np.ndarray, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    if td.size:
        x = np.arange(1, td.size + 1)
        ax.plot(x, np.abs(td), color="tab:gray", alpha=0.4, lw=0.8, label="|TD error|")
        w = max(1, td.size // 50)
        smooth = np.convolve(np.abs(td), np.ones(w) / w, mode="valid")
        ax.plot(np.arange(w, td.size + 1), smooth, color="tab:blue", label=f"mean of {w}")
        ax.legend()
    ax.set_xlabel("trials (Q-table updates)")
    ax.set_ylabel("|temporal-difference error|")
    ax.set_title("Q-learning convergence (paper Figure 6)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
