"""Figures 4-6 of the paper from cycle logs (matplotlib, no display needed)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

if TYPE_CHECKING:
    from roger_experiments.compare import RunResult

STYLE: dict[str, dict[str, Any]] = {
    "qlearning": dict(color="tab:blue", linestyle=":", label="Q-learning"),
    "straightforward": dict(color="tab:orange", linestyle="-", label="straightforward")}


def cumulative(rows: list[dict[str, str]], what: str) -> np.ndarray:
    """Cumulative count per control cycle of one Table 2 column, from a cycle log."""
    def hit(r: dict[str, str]) -> bool:
        a, o = r["action"], r["outcome"]
        return {
            "attention_shifts": a == "attention_shift",
            "improvements": a in ("visual_improvement", "haptic_improvement"),
            "positive_identifications": a == "map_update" and o == "mapped",
            "new_objects": a == "map_update" and o == "stored",
            "map_updates": a == "map_update",
            "remaps": a == "map_update" and o == "remapped",
        }[what]
    return np.cumsum([1 if hit(r) else 0 for r in rows])


def _band(ax: plt.Axes, results: list[RunResult], what: str) -> None:
    for policy, style in STYLE.items():
        curves = [cumulative(r.rows, what) for r in results if r.policy == policy and r.rows]
        if not curves:
            continue
        n = min(len(c) for c in curves)
        arr = np.stack([c[:n] for c in curves])
        x = np.arange(1, n + 1)
        mean = arr.mean(axis=0)
        ax.plot(x, mean, **style)
        if len(curves) > 1:
            ax.fill_between(x, arr.min(axis=0), arr.max(axis=0), color=style["color"],
                            alpha=0.15, linewidth=0)
    ax.set_xlabel("control cycles")
    ax.grid(alpha=0.3)


def fig4(results: list[RunResult], path: Path) -> None:
    """Four panels as the paper's Figure 4 (mean over seeds, band = min-max)."""
    fig, axes = plt.subplots(2, 2, figsize=(10, 7), sharex=True)
    for ax, (what, title) in zip(axes.flat, (
            ("attention_shifts", "attention shifts"), ("improvements", "eye/arm improvements"),
            ("positive_identifications", "positive identifications"),
            ("new_objects", "new objects detected"))):
        _band(ax, results, what)
        ax.set_title(title)
    axes[0, 0].legend()
    fig.suptitle("Partial evaluation (paper Figure 4)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def fig5(results: list[RunResult], path: Path) -> None:
    """Map updates vs control cycles, as the paper's Figure 5."""
    fig, ax = plt.subplots(figsize=(7, 4.5))
    _band(ax, results, "map_updates")
    ax.set_ylabel("map updates")
    ax.set_title("Overall evaluation (paper Figure 5)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def td_curve(rows: list[dict[str, str]]) -> np.ndarray:
    """Absolute TD error of every Q update of a run, in order."""
    return np.array([abs(float(r["td_error"])) for r in rows if r.get("td_error")])


def fig6(results: list[RunResult], path: Path, training: np.ndarray | None = None) -> None:
    """|TD error| vs trials (Q updates), as the paper's Figure 6."""
    fig, ax = plt.subplots(figsize=(7, 4.5))
    if training is not None and training.size:
        ax.plot(np.arange(1, training.size + 1), np.abs(training), color="tab:gray",
                alpha=0.5, label="roger train")
    for r in results:
        if r.policy != "qlearning":
            continue
        td = td_curve(r.rows)
        if td.size:
            ax.plot(np.arange(1, td.size + 1), td, alpha=0.7, label=f"seed {r.seed}")
    ax.set_xlabel("trials (Q-table updates)")
    ax.set_ylabel("|temporal-difference error|")
    ax.set_title("Q-learning convergence (paper Figure 6)")
    if ax.get_legend_handles_labels()[0]:
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
