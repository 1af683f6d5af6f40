"""Figures 4-6 of the paper from cycle logs (matplotlib, no display needed)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from roger_experiments.results import RunResult  # noqa: E402

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


#: Colours of Figure 6's points by the action of the update.
TD_COLOURS: dict[str, str] = {"map_update": "tab:red", "attention_shift": "tab:blue",
                              "visual_improvement": "tab:green",
                              "haptic_improvement": "tab:olive"}


def td_convergence(td: np.ndarray, path: Path, run_starts: list[int] | tuple[int, ...] = (),
                   window: int = 100, subtitle: str = "",
                   actions: list[str] | None = None,
                   q_values: dict[str, np.ndarray] | None = None) -> None:
    """The paper's Figure 6: |TD error| per trial (Q update) and its moving average.

    Panels: every trial's |TD error| (coloured by action when ``actions`` is given) with
    the moving average over it; the moving average alone, on its own scale; and, with
    ``q_values``, the Q-values after each trial (what the TD errors move).

    Args:
        td: TD errors in the order of the updates.
        path: PNG to write.
        run_starts: Trial indices where a new run (world, seed) begins: dotted lines.
        window: Moving-average window (trials), clamped to the number of trials.
        subtitle: What the trials were (shown under the title).
        actions: The action of each update (``cycles.csv`` names), for the colours.
        q_values: Label -> Q(s, a) after each trial (``train.q_history``).
    """
    a = np.abs(np.asarray(td, float))
    rows = 3 if q_values else 2
    fig, axes = plt.subplots(rows, 1, figsize=(8, 3.2 * rows), sharex=True,
                             gridspec_kw={"height_ratios": [3, 2, 3][:rows]})
    top, bottom = axes[0], axes[1]
    if a.size:
        x = np.arange(1, a.size + 1)
        if actions is not None and len(actions) == a.size:
            for name, colour in TD_COLOURS.items():
                pick = np.array([act == name for act in actions])
                if pick.any():
                    top.plot(x[pick], a[pick], ".", color=colour, alpha=0.5, markersize=3,
                             label=name.replace("_", " "))
        else:
            top.plot(x, a, ".", color="tab:gray", alpha=0.4, markersize=3, label="|TD error|")
        w = max(1, min(window, a.size))
        smooth = np.convolve(a, np.ones(w) / w, mode="valid")
        for ax in (top, bottom):
            ax.plot(np.arange(w, a.size + 1), smooth, color="black", lw=1.6,
                    label=f"moving average of {w}" if ax is top else None)
            for start in run_starts:
                if start > 0:
                    ax.axvline(start + 0.5, color="tab:gray", lw=0.6, ls=":")
            ax.grid(alpha=0.3)
        bottom.set_ylim(0.0, float(smooth.max()) * 1.15 + 1e-9)
        top.legend(loc="upper right", fontsize=8)
        if q_values:
            ax = axes[2]
            for label, values in q_values.items():
                ax.plot(x, values, lw=1.2, label=label)
            ax.set_ylabel("Q(s, a)")
            ax.grid(alpha=0.3)
            ax.legend(loc="upper right", fontsize=7, ncol=3)
    else:
        top.text(0.5, 0.5, "no Q-learning updates", ha="center", transform=top.transAxes)
    top.set_ylabel("|TD error|")
    bottom.set_ylabel("moving average")
    axes[-1].set_xlabel("trials (Q-table updates, in training order; dotted: a new run)")
    top.set_title("Q-learning convergence (paper Figure 6)"
                  + (f"\n{subtitle}" if subtitle else ""), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def fig6(results: list[RunResult], path: Path) -> None:
    """Figure 6 from the Q-learning runs' own updates (runs that learnt: a replayed one, a
    training run); a comparison draws it from the training of its table instead
    (``train.plot_training``)."""
    rows = [row for r in results if r.policy == "qlearning" for row in r.rows
            if row.get("td_error")]
    starts, total = [], 0
    for r in results:
        if r.policy == "qlearning":
            starts.append(total)
            total += sum(1 for row in r.rows if row.get("td_error"))
    td = np.array([float(row["td_error"]) for row in rows])
    td_convergence(td, path, starts, subtitle="the updates of these runs",
                   actions=[row["action"] for row in rows])


def distribution(values: dict[str, dict[str, list[float]]], what: str, path: Path) -> None:
    """One Table 2 column across worlds (``roger sweep``): per feature mode, a box and the
    points of each policy's per-world means."""
    modes = list(values)
    fig, axes = plt.subplots(1, len(modes), figsize=(4.2 * len(modes), 4), sharey=True,
                             squeeze=False)
    for ax, mode in zip(axes[0], modes, strict=True):
        policies = [p for p in STYLE if p in values[mode]]
        data = [values[mode][p] for p in policies]
        ax.boxplot(data, widths=0.5, showfliers=False)
        for k, (policy, ys) in enumerate(zip(policies, data, strict=True)):
            xs = np.full(len(ys), k + 1.0) + np.linspace(-0.08, 0.08, len(ys))
            ax.plot(xs, ys, "o", color=STYLE[policy]["color"], alpha=0.6, markersize=4)
        ax.set_xticks(range(1, len(policies) + 1),
                      [STYLE[p]["label"] for p in policies])
        ax.set_title(f"{mode} features")
        ax.grid(alpha=0.3, axis="y")
    axes[0][0].set_ylabel(f"{what} (mean per world)")
    fig.suptitle(f"Table 2 across worlds: {what}")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
