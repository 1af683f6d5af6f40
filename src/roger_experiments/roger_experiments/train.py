"""``roger train``: Q-learning of the attention policy on the robot, over worlds and seeds.

One Q-table is carried from run to run (saved atomically after each). Each run is a
whole attention session on one world with one seed, learning online (epsilon-greedy),
through the same core loop the graph runs (in process, without ROS, for speed) or through
the real graph. Figure 6 (the paper's "Q-learning convergence") is drawn from these real
trials: the |TD error| of every Q update in order, with its moving average.

The training worlds are random worlds (``roger_sim.worldgen``) with seeds of their own,
written to ``OUT/worlds`` so that they can be looked at and reused, or world files; each
one's fingerprint goes to ``train.json``, so that an evaluation can tell whether it runs
on a world the table was trained on.
"""

from __future__ import annotations

import csv
import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from roger_attention.config import QLearningConfig
from roger_attention.fsm import STATES, possible_actions
from roger_attention.qlearning import QTable
from roger_common.atomic import atomic_write_bytes
from roger_common.types import DEFAULT_FEATURE_MODE, WorldSpec
from roger_experiments import plots
from roger_experiments.evaluation import ACTION_NAMES
from roger_experiments.progress import ProgressBar
from roger_sim.world import load_world, world_to_dict
from roger_sim.worldgen import random_world

#: The feature mode a training runs in unless told.
DEFAULT_FEATURES = DEFAULT_FEATURE_MODE.value
#: Window of the moving average of |TD error| in Figure 6 (Q updates).
MOVING_AVERAGE = 100
#: The Q-values Figure 6 follows: the choices of an undetermined entry, mapped or not.
Q_SHOWN: tuple[tuple[str, str], ...] = (
    ("000", "attention_shift"), ("000", "visual_improvement"), ("000", "haptic_improvement"),
    ("001", "attention_shift"), ("001", "visual_improvement"), ("001", "haptic_improvement"))
#: What train.json keeps of each training run's metrics.
RUN_KEYS: tuple[str, ...] = ("cycles", "attention_shifts", "improvements",
                             "positive_identifications", "new_objects", "remaps", "map_updates",
                             "objects_visited", "objects_in_world")
#: What ``train`` writes besides the runs: the table, every TD error, Figure 6, a summary.
TRAIN_FILES: tuple[str, ...] = ("qtable.json", "td_errors.csv", "td_errors.png", "train.json")


@dataclass(frozen=True)
class RandomWorlds:
    """Random training worlds: ``count`` worlds of seeds ``seed0``, ``seed0 + 1``, ...

    The defaults draw from the family of the demo world (``worlds/inspection.yaml`` is
    ``random_world(8, 3, seed=3, size_range=(0.08, 0.14))``) with other seeds, so that the
    evaluation runs on a world of the same kind that training never saw.
    """

    count: int = 4
    seed0: int = 100
    n_categories: int = 8
    copies: int = 3
    size_range: tuple[float, float] = (0.08, 0.14)

    def worlds(self) -> list[WorldSpec]:
        """The worlds, in seed order."""
        return [random_world(self.n_categories, self.copies, seed=self.seed0 + k,
                             size_range=self.size_range) for k in range(self.count)]


def world_fingerprint(world: WorldSpec) -> str:
    """A digest of a world's objects and light (not its name or file): equal worlds, equal
    fingerprints."""
    d = world_to_dict(world)
    data = json.dumps({"light": d["light"], "objects": d["objects"]}, sort_keys=True)
    return hashlib.sha256(data.encode()).hexdigest()[:16]


def write_worlds(worlds: list[WorldSpec], folder: Path) -> list[Path]:
    """Write worlds as world files (``<name>.yaml``) into ``folder``; returns the paths."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for world in worlds:
        path = folder / f"{world.name}.yaml"
        atomic_write_bytes(path, yaml.safe_dump(world_to_dict(world), sort_keys=False).encode())
        paths.append(path)
    return paths


def read_training(qtable: Path) -> dict[str, Any] | None:
    """The ``train.json`` written beside a trained Q-table, or None when there is none."""
    path = qtable.with_name("train.json")
    if not path.exists():
        return None
    data: dict[str, Any] = json.loads(path.read_text())
    return data


@dataclass(frozen=True)
class TrainingLog:
    """Every Q update of a training, in order (``td_errors.csv``).

    Attributes:
        td: TD error of each update.
        run_starts: Index of the first update of each run.
        states: "nim" bits each update was made in ("" when not recorded).
        actions: Its action (``cycles.csv`` names; "" when not recorded).
    """

    td: np.ndarray
    run_starts: list[int]
    states: list[str]
    actions: list[str]

    def q_history(self, alpha: float, pairs: tuple[tuple[str, str], ...] = Q_SHOWN,
                  initial_q: float = 0.0, alpha_k: float | None = None
                  ) -> dict[str, np.ndarray]:
        """Q(s, a) after each update, rebuilt from the TD errors (Q += alpha td, section
        2; with ``alpha_k``, the "visits" schedule's alpha / (1 + n(s, a) / alpha_k)):
        exact for a training that started from a fresh table of ``initial_q``."""
        out = {f"Q({s}, {a.replace('_improvement', '').replace('attention_', '')})":
               np.full(self.td.size, initial_q) for s, a in pairs}
        keys = dict(zip(pairs, out, strict=True))
        value = dict.fromkeys(pairs, initial_q)
        visits: dict[tuple[str, str], int] = {}
        for k, (s, a, td) in enumerate(zip(self.states, self.actions, self.td, strict=True)):
            n = visits.get((s, a), 0)
            visits[(s, a)] = n + 1
            if (s, a) in value:
                step = alpha if alpha_k is None else alpha / (1.0 + n / alpha_k)
                value[(s, a)] += step * float(td)
            for pair, label in keys.items():
                out[label][k] = value[pair]
        return out


    def greedy_changes(self, alpha: float, since: float = 0.5,
                       alpha_k: float | None = None) -> dict[str, int]:
        """Per state, how often its greedy action (ties: the set of tied actions) changed
        after the fraction ``since`` of the updates: 0 once the values have settled
        (``alpha_k``: as for ``q_history``)."""
        pairs = tuple((s.bits, ACTION_NAMES[int(a)]) for s in STATES
                      for a in possible_actions(s))
        history = self.q_history(alpha, pairs, alpha_k=alpha_k)
        labels = dict(zip(pairs, history, strict=True))
        start = int(since * self.td.size)
        out: dict[str, int] = {}
        for state in STATES:
            acts = [(state.bits, ACTION_NAMES[int(a)]) for a in possible_actions(state)]
            values = np.stack([history[labels[pair]][start:] for pair in acts])
            best = values.max(axis=0)
            greedy = [frozenset(k for k in range(len(acts)) if values[k, t] == best[t])
                      for t in range(values.shape[1])]
            out[state.bits] = sum(1 for a, b in zip(greedy, greedy[1:]) if a != b)
        return out


def read_td_errors(path: Path) -> TrainingLog:
    """The updates of a ``td_errors.csv``, in order."""
    tds: list[float] = []
    starts: list[int] = []
    states: list[str] = []
    actions: list[str] = []
    last_run = None
    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            if row["run"] != last_run:
                starts.append(len(tds))
                last_run = row["run"]
            tds.append(float(row["td_error"]))
            states.append(row.get("state") or "")
            actions.append(row.get("action") or "")
    return TrainingLog(np.array(tds), starts, states, actions)


def convergence(td: np.ndarray, window: int = MOVING_AVERAGE) -> dict[str, Any]:
    """Numbers that say whether |TD error| converged: means over the first and last tenth,
    and the moving average at a few points of training."""
    a = np.abs(np.asarray(td, float))
    if not a.size:
        return {"updates": 0}
    tenth = max(1, a.size // 10)
    w = max(1, min(window, a.size))
    smooth = np.convolve(a, np.ones(w) / w, mode="valid")
    points = {f"{int(q * 100)}%": float(smooth[min(len(smooth) - 1, int(q * len(smooth)))])
              for q in (0.0, 0.25, 0.5, 0.75, 1.0)}
    return {"updates": int(a.size), "mean_abs_td_first_10pct": float(a[:tenth].mean()),
            "mean_abs_td_last_10pct": float(a[-tenth:].mean()),
            "moving_average_window": w, "moving_average_at": points}


def train(worlds: list[Path], seeds: list[int], out: Path,
          run_one: Callable[[Path, int, Path, Path], dict[str, Any]],
          progress: bool = True,
          describe: dict[str, Any] | None = None) -> dict[str, Any]:
    """Train one Q-table over every (world, seed) pair, in that order.

    Args:
        worlds: World files.
        seeds: Seeds; every world is run with every seed.
        out: Output folder: qtable.json, td_errors.csv, td_errors.png (Figure 6),
            train.json, runs/.
        run_one: ``run_one(world, seed, qtable_path, run_dir) -> metrics``; learns from and
            saves to ``qtable_path``.
        describe: How the worlds were made (e.g. the RandomWorlds), kept in train.json.

    Returns:
        The summary written to train.json: runs, worlds and fingerprints, convergence of
        |TD|, the final table and its greedy action per state.
    """
    out.mkdir(parents=True, exist_ok=True)
    qtable = out / "qtable.json"
    rows: list[tuple[int, str, int, float, str, str]] = []
    runs: list[dict[str, Any]] = []
    total = len(worlds) * len(seeds)
    t0 = time.monotonic()
    k = 0
    with ProgressBar(total, "train", "runs", enabled=progress) as bar:
        for world in worlds:
            for seed in seeds:
                bar.update(k, f"running {world.name}, seed {seed}")
                k += 1
                run_dir = out / "runs" / f"{world.stem}_seed{seed}"
                metrics = run_one(world, seed, qtable, run_dir)
                runs.append({"world": world.stem, "seed": seed,
                             **{key: metrics.get(key) for key in RUN_KEYS}})
                with open(run_dir / "cycles.csv", newline="") as fh:
                    for row in csv.DictReader(fh):
                        if row["td_error"]:
                            rows.append((k, world.stem, seed, float(row["td_error"]),
                                         row["state"], row["action"]))
                bar.update(k, f"{world.name}, seed {seed}: {len(rows)} TD updates so far")
    lines = ["trial,run,world,seed,td_error,state,action"] + [
        f"{i + 1},{run},{w},{s},{td:.6g},{st},{a}"
        for i, (run, w, s, td, st, a) in enumerate(rows)]
    atomic_write_bytes(out / "td_errors.csv", ("\n".join(lines) + "\n").encode())
    log = read_td_errors(out / "td_errors.csv")
    table = QTable.load(qtable)
    alpha_k = table.config.alpha_k if table.config.alpha_schedule == "visits" else None
    plot_training(log, out / "td_errors.png", table.config.alpha,
                  f"{total} training runs on {len(worlds)} worlds, {len(seeds)} seeds each"
                  f"; step size {table.config.alpha_schedule}", alpha_k)
    td = log.td
    greedy = {s.bits: [a.name.lower() for a in table.greedy_actions(s, possible_actions(s))]
              for s in STATES}
    summary = {
        "runs": total, "seeds": seeds,
        "worlds": [{"file": str(w), "name": load_world(w).name,
                    "fingerprint": world_fingerprint(load_world(w))} for w in worlds],
        "made_by": describe or {}, "qtable": str(qtable), "run_metrics": runs,
        "alpha": table.config.alpha, "gamma": table.config.gamma,
        "epsilon": table.config.epsilon, "alpha_schedule": table.config.alpha_schedule,
        "alpha_k": table.config.alpha_k,
        **convergence(td),
        "greedy_changes_second_half": log.greedy_changes(table.config.alpha, alpha_k=alpha_k)
        if all(log.states) else None,
        "q": {s.bits: {a.name.lower(): round(table.value(s, a), 4) for a in possible_actions(s)}
              for s in STATES},
        "greedy": greedy, "wall_seconds": round(time.monotonic() - t0, 1)}
    atomic_write_bytes(out / "train.json", (json.dumps(summary, indent=2) + "\n").encode())
    return summary


def plot_training(log: TrainingLog, path: Path, alpha: float, subtitle: str,
                  alpha_k: float | None = None) -> None:
    """Figure 6 of a training: |TD error| per trial, its moving average, the Q-values
    (``alpha_k``: the "visits" step size, as for ``TrainingLog.q_history``)."""
    plots.td_convergence(log.td, path, log.run_starts, MOVING_AVERAGE, subtitle,
                         actions=log.actions,
                         q_values=log.q_history(alpha, alpha_k=alpha_k)
                         if all(log.states) else None)


def describe_random(spec: RandomWorlds) -> dict[str, Any]:
    """A RandomWorlds as JSON-ready data for train.json."""
    return {"generator": "roger_sim.worldgen.random_world", **asdict(spec)}


def run_in_process(world: Path, seed: int, qtable: Path, run_dir: Path, cycles: int,
                   features: str) -> dict[str, Any]:
    """One learning Q-learning run of the core loop in this process (no ROS); the loop saves
    the Q-table it learnt to ``qtable`` when it closes."""
    from roger_experiments.core_loop import run_core

    t0 = time.monotonic()
    recorder, _ = run_core(load_world(world), "qlearning", cycles, seed=seed, out=run_dir,
                           qtable_path=qtable, features=features)
    assert recorder is not None
    return recorder.close(time.monotonic() - t0)


def fresh_table(out: Path, alpha_schedule: str = "constant") -> None:
    """Start training from a fresh table: ``out/qtable.json`` removed, or (a schedule other
    than the paper's constant step size) written afresh with that schedule, which the table
    keeps through training (``QTable.load``)."""
    path = out / "qtable.json"
    if path.exists():
        path.unlink()
    if alpha_schedule != "constant":
        out.mkdir(parents=True, exist_ok=True)
        QTable(QLearningConfig(alpha_schedule=alpha_schedule)).save(path)


def train_in_process(spec: RandomWorlds, seeds: list[int], cycles: int, out: Path,
                     progress: bool = True, features: str | None = None,
                     files: list[Path] | None = None,
                     alpha_schedule: str = "constant") -> dict[str, Any]:
    """``roger train`` in process from a fresh table: the world ``files``, then the random
    worlds of ``spec`` (written to ``out/worlds``), every one with every seed
    (``alpha_schedule``: ``QLearningConfig.alpha_schedule`` of the table)."""
    worlds = list(files or [])
    made: dict[str, Any] = {"files": [str(w) for w in worlds]}
    if spec.count > 0:
        worlds += write_worlds(spec.worlds(), out / "worlds")
        made["random"] = describe_random(spec)
    fresh_table(out, alpha_schedule)

    def run_one(world: Path, seed: int, qtable: Path, run_dir: Path) -> dict[str, Any]:
        return run_in_process(world, seed, qtable, run_dir, cycles,
                              features or DEFAULT_FEATURES)
    return train(worlds, seeds, out, run_one, progress=progress, describe=made)


@dataclass(frozen=True)
class TrainDraw:
    """One training draw of a sweep: a fresh Q-table learnt in process on random worlds
    (``worlds``) with every seed, in one feature mode.

    Attributes:
        draw: The draw's number (1, 2, ...): it picks the worlds' seeds.
        features: Feature mode of the training runs.
        worlds: The random training worlds.
        seeds: Run seeds per world.
        cycles: Control cycles per run.
    """

    draw: int
    features: str
    worlds: RandomWorlds
    seeds: tuple[int, ...] = (0, 1)
    cycles: int = 204


def train_draw(spec: TrainDraw, out: Path) -> dict[str, Any]:
    """Train one draw into ``out`` (qtable.json, train.json, Figure 6, the runs); returns
    the train.json summary. A pure function of ``spec`` (a Ray task of ``roger sweep``)."""
    return train_in_process(spec.worlds, list(spec.seeds), spec.cycles, out, progress=False,
                            features=spec.features)


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
