"""``roger sweep SPEC.yaml --out DIR``: Table 2 over worlds x seeds x policies x feature
modes x step-size schedules x training draws, and the paper's claims judged across worlds.

Read top to bottom: the spec (``SweepSpec``, parsed from the YAML file), its cells (one run
each, keyed by a hash of the cell and the code version), train (a Q-table per draw and
feature mode and step-size schedule on random worlds disjoint from the evaluation worlds),
run (the cells not on disk yet), score (runs.csv, Table 2 with spreads across worlds and
draws, how much the draws' tables agree), judge (the claims, a paired test over world x
seed) and report (report.md, one figure per column).

What runs the runs is passed in (``runners.Runner``; ``roger sweep`` hands in a
``ray_runner.RayRunner``). The runner writes each finished cell's folder atomically; this
module writes everything else, so a killed sweep leaves whole cells and resumes from them.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import shutil
import statistics
from collections import defaultdict
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from roger_attention.config import ALPHA_SCHEDULES
from roger_attention.fsm import STATES, State, possible_actions
from roger_attention.qlearning import QTable
from roger_common.atomic import atomic_write_bytes
from roger_common.errors import ConfigError
from roger_common.types import Action
from roger_experiments import plots
from roger_experiments.progress import ProgressBar
from roger_experiments.results import read_metrics, read_run
from roger_experiments.runners import Job, Runner, RunSpec
from roger_experiments.table2 import (
    CLAIMS,
    COLUMNS,
    POLICIES,
    SCORES,
    check_completion,
    mean_sd,
    paired_test,
)
from roger_experiments.train import (
    RandomWorlds,
    TrainDraw,
    train_in_process,
    world_fingerprint,
)
from roger_sim.world import load_world, parse_world, world_to_dict
from roger_sim.worldgen import random_world

#: Random-world recipes: ``roger_sim.worldgen.random_world`` plain, or with the flag of
#: that name.
RECIPES: tuple[str, ...] = ("default", "shape_twins", "yaw_copies")
#: Keys of a recipe mapping handed to ``random_world``.
RECIPE_ARGS: tuple[str, ...] = ("n_categories", "copies", "size_range", "textures",
                                "min_gap", "out_of_reach")
MODES: tuple[str, ...] = ("in_process", "graph")
UNTIL_COMPLETE = "until-complete"
SPEC_KEYS: tuple[str, ...] = ("worlds", "seeds", "policies", "features", "draws", "cycles",
                              "mode", "training", "stable_cycles", "timeout_s",
                              "alpha_schedules")
#: The paper's step size (``QLearningConfig.alpha_schedule``): the schedule of every sweep
#: before ``alpha_schedules`` existed, so it adds nothing to a key (old cells keep theirs).
PAPER_SCHEDULE = "constant"

# --- The spec ---------------------------------------------------------------------------


@dataclass(frozen=True)
class World:
    """An evaluation world: a file's, or a recipe's draw (``recipe``, ``world_seed``)."""

    name: str
    text: str
    file: str = ""
    recipe: str = ""
    world_seed: int | None = None

    def digest(self) -> str:
        """Its content's fingerprint (``train.world_fingerprint``)."""
        return world_fingerprint(parse_world(yaml.safe_load(self.text), self.name))


@dataclass(frozen=True)
class ScheduledDraw(TrainDraw):
    """A training draw of the sweep: ``train.TrainDraw`` and the Q-learning step-size
    schedule its table learns with (``QLearningConfig.alpha_schedule``)."""

    alpha_schedule: str = PAPER_SCHEDULE


@dataclass(frozen=True)
class TrainingSpec:
    """How each draw's Q-table is trained: ``worlds`` random worlds of the demo's recipe
    (seeds from ``world_seed0``, each draw its own), ``seeds`` run seeds each."""

    worlds: int = 4
    seeds: int = 2
    cycles: int = 204
    world_seed0: int = 100000

    def draw(self, k: int, features: str, alpha_schedule: str = PAPER_SCHEDULE
             ) -> ScheduledDraw:
        """Draw ``k`` (1, 2, ...) in one feature mode, trained with one step-size schedule
        (draw ``k`` of either schedule trains on the same worlds and seeds)."""
        return ScheduledDraw(k, features, RandomWorlds(self.worlds, self.world_seed0
                                                       + (k - 1) * self.worlds),
                             tuple(range(self.seeds)), self.cycles, alpha_schedule)


@dataclass(frozen=True)
class SweepSpec:
    """A sweep (the YAML file's keys; see docs/experiments.md "Sweeps").

    Attributes:
        worlds: Evaluation worlds (files and recipe draws).
        seeds: Run seeds.
        policies: Attention policies.
        features: Feature modes.
        draws: Training draws of the Q-learning policy (a table each, run greedy and
            frozen); 0: Q-learning learns online from zeros, as ``roger run``.
        cycles: Cycle budgets; None is ``until-complete`` (the robot's own rule).
        mode: ``in_process`` or ``graph``.
        training: How a draw trains.
        stable_cycles: The completion rule's cycles without a new object.
        timeout_s: Wall seconds after which a run fails (None: no limit).
        alpha_schedules: Step-size schedules of Q-learning (``QLearningConfig.
            alpha_schedule``): each draw is trained (or, with ``draws`` 0, each run learns)
            once per schedule.
    """

    worlds: tuple[World, ...]
    seeds: tuple[int, ...] = (0,)
    policies: tuple[str, ...] = POLICIES
    features: tuple[str, ...] = ("paper",)
    draws: int = 0
    cycles: tuple[int | None, ...] = (204,)
    mode: str = "in_process"
    training: TrainingSpec = field(default_factory=TrainingSpec)
    stable_cycles: int = 40
    timeout_s: float | None = None
    alpha_schedules: tuple[str, ...] = (PAPER_SCHEDULE,)


def _list(data: dict[str, Any], key: str, default: list[Any]) -> list[Any]:
    value = data.get(key, default)
    return list(value) if isinstance(value, list | tuple) else [value]


def _seeds(value: Any, where: str) -> list[int]:
    if isinstance(value, dict) and set(value) <= {"start", "count"}:
        return list(range(int(value.get("start", 0)),
                          int(value.get("start", 0)) + int(value["count"])))
    if isinstance(value, list) and all(isinstance(s, int) for s in value):
        return value
    if isinstance(value, int):
        return [value]
    raise ConfigError(f"{where}: seeds must be a list of integers or {{start: S, count: N}}, "
                      f"got {value!r}")


def parse_spec(data: Any, source: str, base: Path) -> SweepSpec:
    """A sweep spec from the YAML data of ``source``; file names relative to ``base``
    (the repository or the spec's folder, whichever holds them).

    Raises:
        ConfigError: naming the file and the key.
    """
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a sweep spec is a mapping of {', '.join(SPEC_KEYS)}")
    unknown = sorted(set(data) - set(SPEC_KEYS))
    if unknown:
        raise ConfigError(f"{source}: unknown key {unknown[0]!r} (keys: {', '.join(SPEC_KEYS)})")
    worlds: list[World] = []
    for i, entry in enumerate(_list(data, "worlds", [])):
        where = f"{source}: worlds[{i}]"
        if isinstance(entry, str):
            path = Path(entry)
            if not path.is_absolute() and not path.exists():
                path = base / entry
            load_world(path)  # a bad world file stops the sweep now, named
            worlds.append(World(path.stem, path.read_text(encoding="utf-8"), file=str(path)))
        elif isinstance(entry, dict):
            recipe = entry.get("recipe", "default")
            if recipe not in RECIPES:
                raise ConfigError(f"{where}.recipe: {recipe!r} is not one of "
                                  f"{', '.join(RECIPES)}")
            bad = sorted(set(entry) - {"recipe", "seeds", *RECIPE_ARGS})
            if bad:
                raise ConfigError(f"{where}: unknown key {bad[0]!r}")
            args: dict[str, Any] = {k: entry[k] for k in RECIPE_ARGS if k in entry}
            args.setdefault("n_categories", 8)
            args.setdefault("copies", 3)
            args["size_range"] = tuple(args.get("size_range", (0.08, 0.14)))
            if "textures" in args:
                args["textures"] = tuple(args["textures"])
            for s in _seeds(entry.get("seeds", [0]), where):
                w = random_world(seed=s, **args, shape_twins=recipe == "shape_twins",
                                 yaw_copies=recipe == "yaw_copies")
                text = yaml.safe_dump(world_to_dict(w), sort_keys=False)
                worlds.append(World(w.name, text, recipe=recipe, world_seed=s))
        else:
            raise ConfigError(f"{where}: a world file name or a recipe mapping")
    if not worlds:
        raise ConfigError(f"{source}: worlds: give at least one world file or recipe")
    names = [w.name for w in worlds]
    if len(set(names)) != len(names):
        raise ConfigError(f"{source}: worlds: two worlds are named "
                          f"{next(n for n in names if names.count(n) > 1)!r}")
    policies = _list(data, "policies", list(POLICIES))
    for p in policies:
        if p not in POLICIES:
            raise ConfigError(f"{source}: policies: {p!r} is not one of {', '.join(POLICIES)}")
    features = _list(data, "features", ["paper"])
    for f in features:
        if f not in ("paper", "extended"):
            raise ConfigError(f"{source}: features: {f!r} is not paper or extended")
    cycles: list[int | None] = []
    for c in _list(data, "cycles", [204]):
        if c == UNTIL_COMPLETE:
            cycles.append(None)
        elif isinstance(c, int) and c > 0:
            cycles.append(c)
        else:
            raise ConfigError(f"{source}: cycles: a positive number or {UNTIL_COMPLETE!r}, "
                              f"got {c!r}")
    mode = data.get("mode", "in_process")
    if mode not in MODES:
        raise ConfigError(f"{source}: mode: {mode!r} is not one of {', '.join(MODES)}")
    draws = data.get("draws", 0)
    if not isinstance(draws, int) or draws < 0:
        raise ConfigError(f"{source}: draws: a number >= 0, got {draws!r}")
    training = data.get("training") or {}
    try:
        train_spec = TrainingSpec(**training)
    except TypeError as exc:
        raise ConfigError(f"{source}: training: {exc}") from None
    schedules = _list(data, "alpha_schedules", [PAPER_SCHEDULE])
    for a in schedules:
        if a not in ALPHA_SCHEDULES:
            raise ConfigError(f"{source}: alpha_schedules: {a!r} is not one of "
                              f"{', '.join(ALPHA_SCHEDULES)}")
    if not schedules or len(set(schedules)) != len(schedules):
        raise ConfigError(f"{source}: alpha_schedules: a list of distinct schedules "
                          f"({', '.join(ALPHA_SCHEDULES)}), got {schedules!r}")
    timeout = data.get("timeout_s")
    return SweepSpec(tuple(worlds), tuple(_seeds(data.get("seeds", [0]), f"{source}: seeds")),
                     tuple(policies), tuple(features), draws, tuple(cycles), mode, train_spec,
                     int(data.get("stable_cycles", 40)),
                     None if timeout is None else float(timeout), tuple(schedules))


def load_spec(path: Path, base: Path | None = None) -> SweepSpec:
    """Read a sweep spec file (see ``parse_spec``)."""
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"{path}: cannot read the sweep spec: {exc}") from None
    return parse_spec(data, str(path), base or Path.cwd())


# --- Cells ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Cell:
    """One run of the sweep and where it stands."""

    key: str
    world: World
    policy: str
    seed: int
    features: str
    cycles: int | None
    draw: int | None  # None: the straightforward policy (no table); 0: learns online
    train_key: str | None
    #: The world file the run reads (a recipe's is written to DIR/worlds/ by the sweep).
    world_file: str = ""
    #: Q-learning's step-size schedule ("" for the straightforward policy, which has none).
    alpha_schedule: str = ""

    def row(self) -> dict[str, Any]:
        """The cell's spec as runs.csv's first columns."""
        return {"key": self.key, "world_name": self.world.name, "world": self.world_file,
                "recipe": self.world.recipe,
                "world_seed": "" if self.world.world_seed is None else self.world.world_seed,
                "seed": self.seed, "policy": self.policy, "features": self.features,
                "draw": "" if self.draw is None else self.draw,
                "budget": UNTIL_COMPLETE if self.cycles is None else self.cycles,
                "train_key": self.train_key or "", "alpha_schedule": self.alpha_schedule}


def digest(data: Any, version: str) -> str:
    """The key of a cell or a training: a hash of its spec and the code version."""
    text = json.dumps([data, version], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def train_key(draw: TrainDraw, version: str) -> str:
    """The key of a training draw: its spec with its step-size schedule, which is left out
    when it is the paper's (the keys of the draws trained before there was a choice)."""
    data = asdict(draw)
    if data.get("alpha_schedule", PAPER_SCHEDULE) == PAPER_SCHEDULE:
        data.pop("alpha_schedule", None)
    return digest({"train": data}, version)


def cells(spec: SweepSpec, version: str, folder: Path = Path("worlds")) -> list[Cell]:
    """Every run of the sweep, Q-learning once per step-size schedule and draw, the
    straightforward policy once (``folder``: where the recipes' worlds are written)."""
    out: list[Cell] = []
    for world in spec.worlds:
        wdigest = world.digest()
        for features in spec.features:
            for cycles in spec.cycles:
                for seed in spec.seeds:
                    for policy in spec.policies:
                        draws: list[int | None] = [None]
                        schedules = [""]
                        if policy == "qlearning":
                            draws = list(range(1, spec.draws + 1)) if spec.draws else [0]
                            schedules = list(spec.alpha_schedules)
                        for schedule in schedules:
                            for draw in draws:
                                out.append(_make_cell(
                                    spec, version, folder, world, wdigest, policy, seed,
                                    features, cycles, draw, schedule))
    return out


def _make_cell(spec: SweepSpec, version: str, folder: Path, world: World, wdigest: str,
               policy: str, seed: int, features: str, cycles: int | None,
               draw: int | None, schedule: str) -> Cell:
    tkey = (train_key(spec.training.draw(draw, features, schedule), version)
            if draw else None)
    data: dict[str, Any] = {"world": world.name, "world_digest": wdigest, "policy": policy,
                            "seed": seed, "features": features, "cycles": cycles,
                            "draw": draw, "train": tkey, "mode": spec.mode,
                            "stable_cycles": spec.stable_cycles}
    if schedule not in ("", PAPER_SCHEDULE):
        # Only another schedule than the paper's is in the key: the cells of a spec
        # without alpha_schedules keep the keys they had before the key existed.
        data["alpha_schedule"] = schedule
    return Cell(digest(data, version), world, policy, seed, features, cycles, draw, tkey,
                world.file or str(folder / f"{world.name}.yaml"), schedule)


def check_disjoint(spec: SweepSpec) -> None:
    """Refuse a sweep whose training worlds include an evaluation world (by fingerprint)."""
    evaluation = {w.digest(): w.name for w in spec.worlds}
    for k in range(1, spec.draws + 1):
        for w in spec.training.draw(k, "paper").worlds.worlds():
            if world_fingerprint(w) in evaluation:
                raise ConfigError(
                    f"training draw {k}: its world {w.name} is the evaluation world "
                    f"{evaluation[world_fingerprint(w)]}: move training.world_seed0")


def is_done(folder: Path) -> bool:
    """A cell or training folder is finished once its cell.json is there (written with
    the run's files in one rename)."""
    return (folder / "cell.json").exists()


# --- Train, run -------------------------------------------------------------------------


def train_scheduled(spec: TrainDraw, out: Path) -> dict[str, Any]:
    """``train.train_draw`` with the draw's step-size schedule: what a sweep's training
    task runs (a pure function of ``spec``)."""
    schedule = spec.alpha_schedule if isinstance(spec, ScheduledDraw) else PAPER_SCHEDULE
    return train_in_process(spec.worlds, list(spec.seeds), spec.cycles, out, progress=False,
                            features=spec.features, alpha_schedule=schedule)


def run_sweep(spec: SweepSpec, out: Path, runner: Runner, train_runner: Runner,
              version: str, progress: bool = True, in_flight: Callable[[], int] = lambda: 0
              ) -> dict[str, Any]:
    """Train, run what is not on disk yet, then score, judge and report.

    Args:
        spec: The sweep.
        out: DIR: cells/<key>/, train/<key>/, failed/<key>/, worlds/, runs.csv,
            table2.json, claims.json, report.md, fig_<column>.png.
        runner: Runs the cells' RunSpecs (keeping going past failures) and writes each
            job's folder.
        train_runner: The same for the training draws (``train.train_draw``).
        version: The code version in the keys (``ray_runner.code_version``).
        in_flight: How many runs are in flight now (the progress line).

    Returns:
        What report.md says, as data (counts, table2, claims).
    """
    check_disjoint(spec)
    out.mkdir(parents=True, exist_ok=True)
    for w in spec.worlds:
        if w.recipe:
            path = out / "worlds" / f"{w.name}.yaml"
            if not path.exists():
                atomic_write_bytes(path, w.text.encode())
    all_cells = cells(spec, version, out / "worlds")
    draws = {c.train_key: spec.training.draw(c.draw, c.features, c.alpha_schedule)
             for c in all_cells if c.train_key and c.draw}
    todo_train = [Job(d, out / "train" / k, {"cell.json": _json({"train": asdict(d),
                                                                  "code_version": version})})
                  for k, d in draws.items() if not is_done(out / "train" / k)]
    failed: dict[str, str] = {}
    total = len(todo_train) + sum(1 for c in all_cells if not is_done(out / "cells" / c.key))
    with ProgressBar(max(total, 1), "sweep", "runs", enabled=progress) as bar:
        done = 0

        def tick(what: str) -> None:
            bar.update(done, f"{in_flight()} running, {len(failed)} failed; {what}")
        for job, result in train_runner(todo_train):
            done += 1
            key = job.out.name
            if isinstance(result, Exception):
                failed[key] = str(result)
                _record_failure(out, key, {"train": asdict(job.spec)}, result)
            tick(f"trained {key}")
        tables = {k: (out / "train" / k / "qtable.json").read_text()
                  for k in draws if is_done(out / "train" / k)}
        for k, text in list(tables.items()):
            # The key holds the schedule; this holds the table to it as well, so that a
            # table learnt with one schedule never runs as the other's.
            learnt = json.loads(text).get("alpha_schedule", PAPER_SCHEDULE)
            if learnt != draws[k].alpha_schedule:
                del tables[k]
                failed[k] = (f"its table learnt with step size {learnt}, not "
                             f"{draws[k].alpha_schedule}")
        jobs = []
        for c in all_cells:
            if is_done(out / "cells" / c.key):
                continue
            if c.train_key and c.train_key not in tables:
                why = failed.get(c.train_key, "").strip().splitlines()
                failed[c.key] = (f"its training {c.train_key} failed"
                                 + (f": {why[-1]}" if why else ""))
                continue
            run = RunSpec(c.world_file, c.world.text, c.policy, c.seed, c.cycles, c.features,
                          tables[c.train_key] if c.train_key else None, spec.stable_cycles,
                          alpha_schedule=c.alpha_schedule or PAPER_SCHEDULE)
            jobs.append(Job(run, out / "cells" / c.key,
                            {"cell.json": _json({**c.row(), "mode": spec.mode,
                                                 "code_version": version})}))
        for job, result in runner(jobs):
            done += 1
            if isinstance(result, Exception):
                failed[job.out.name] = str(result)
                _record_failure(out, job.out.name, json.loads(job.extra["cell.json"]), result)
            else:
                shutil.rmtree(out / "failed" / job.out.name, ignore_errors=True)
            assert isinstance(job.spec, RunSpec)
            tick(f"{job.spec.features} {job.spec.label()} on {Path(job.spec.world).stem}")
        bar.close(done, f"{total - len(failed)} done, {len(failed)} failed")
    return report(spec, all_cells, out, failed, version)


def versions_on_disk(out: Path) -> list[str]:
    """The code versions of the runs and trainings already in DIR (their cell.json)."""
    found = set()
    for sub in ("cells", "train"):
        for path in (out / sub).glob("*/cell.json"):
            try:
                version = json.loads(path.read_text()).get("code_version")
            except (OSError, ValueError):
                continue
            if version:
                found.add(str(version))
    return sorted(found)


def report_from_disk(spec: SweepSpec, out: Path, version: str) -> dict[str, Any]:
    """Report on the cells of ``spec`` that code version ``version`` left in ``out``,
    running and training nothing (``roger sweep --report-only``): a change to the report
    itself need not run the sweep again, since every cell's key holds the code version."""
    all_cells = cells(spec, version, out / "worlds")
    return report(spec, all_cells, out, {}, version)


def _json(data: Any) -> bytes:
    return (json.dumps(data, indent=2, default=str) + "\n").encode()


def _record_failure(out: Path, key: str, spec: dict[str, Any], exc: Exception) -> None:
    """A failed cell's error (and what it had written) under failed/<key>/; the sweep goes
    on, and the next one tries the cell again."""
    from roger_experiments.ray_runner import write_run_files

    files = dict(getattr(exc, "files", {}) or {})
    files["error.txt"] = str(exc).encode()
    files["spec.json"] = _json(spec)
    write_run_files(out / "failed" / key, files)


# --- Score, judge, report ---------------------------------------------------------------


def runs_table(all_cells: list[Cell], out: Path, failed: dict[str, str]
               ) -> list[dict[str, Any]]:
    """One row per run: the cell's spec, its status and error, every metrics.json key."""
    rows = []
    for c in all_cells:
        row: dict[str, Any] = c.row()
        folder = out / "cells" / c.key
        if is_done(folder):
            row.update(status="done", error="")
            row.update(read_metrics(folder))
        else:
            err = failed.get(c.key)
            if err is None and (out / "failed" / c.key / "error.txt").exists():
                err = (out / "failed" / c.key / "error.txt").read_text()
            last = (err or "").strip().splitlines()
            row.update(status="failed" if err else "not run", error=last[-1] if last else "")
        rows.append(row)
    return rows


def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    """A tidy CSV: every key of every row a column, in order of first appearance."""
    columns: list[str] = []
    for r in rows:
        columns += [k for k in r if k not in columns]
    buf = io.StringIO()
    w = csv.DictWriter(buf, columns, restval="")
    w.writeheader()
    for r in rows:
        w.writerow({k: json.dumps(v) if isinstance(v, dict | list) else v
                    for k, v in r.items()})
    atomic_write_bytes(path, buf.getvalue().encode())


def _num(v: Any) -> float | None:
    if v is None or v == "" or isinstance(v, dict | list):
        return None
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return None if math.isnan(x) else x


def spread_table(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Table 2 per feature mode, budget, policy and step-size schedule: mean and sd over
    every run, sd across worlds (of the world means) and across draws (of the draw
    means)."""
    groups: dict[tuple[str, str, str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        if r["status"] == "done":
            groups[(r["features"], str(r["budget"]), r["policy"],
                    r.get("alpha_schedule", ""))].append(r)
    out = []
    for (features, budget, policy, schedule), runs in sorted(groups.items()):
        entry: dict[str, Any] = {"features": features, "budget": budget, "policy": policy,
                                 "alpha_schedule": schedule, "runs": len(runs),
                                 "worlds": len({r["world_name"] for r in runs})}
        for col in (*COLUMNS, *SCORES, "cycles"):
            vals = [(r, x) for r in runs if (x := _num(r.get(col))) is not None]
            m, sd = mean_sd([x for _, x in vals])
            by_world: dict[str, list[float]] = defaultdict(list)
            by_draw: dict[Any, list[float]] = defaultdict(list)
            for r, x in vals:
                by_world[r["world_name"]].append(x)
                by_draw[r["draw"]].append(x)
            _, sd_w = mean_sd([statistics.fmean(v) for v in by_world.values()])
            _, sd_d = mean_sd([statistics.fmean(v) for v in by_draw.values()])
            entry[col] = {"mean": m, "sd": sd, "sd_worlds": sd_w,
                          "sd_draws": sd_d if len(by_draw) > 1 else None, "n": len(vals)}
        out.append(entry)
    return out


def _schedules(rows: list[dict[str, Any]]) -> list[str]:
    """The step-size schedules of the Q-learning rows ([""] when there are none)."""
    return sorted({r.get("alpha_schedule", "") for r in rows
                   if r["policy"] == "qlearning"}) or [""]


def _against(rows: list[dict[str, Any]], schedule: str) -> list[dict[str, Any]]:
    """The rows that face each other under one schedule: its Q-learning runs and the
    straightforward policy's (which has no schedule, so it faces every one)."""
    return [r for r in rows
            if r["policy"] != "qlearning" or r.get("alpha_schedule", "") == schedule]


def judge(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The five claims per feature mode, step-size schedule and fixed budget, paired over
    world x seed: the Q-learning value (mean over the draws) minus the straightforward
    one."""
    judged = []
    done = [r for r in rows if r["status"] == "done"]
    for features in sorted({r["features"] for r in done}):
        of_mode = [r for r in done if r["features"] == features]
        for schedule in _schedules(of_mode):
            for budget in sorted({str(r["budget"]) for r in done} - {UNTIL_COMPLETE}):
                mine = [r for r in _against(of_mode, schedule) if str(r["budget"]) == budget]
                for col, sign, text in CLAIMS:
                    q: dict[tuple[str, int], list[float]] = defaultdict(list)
                    s: dict[tuple[str, int], float] = {}
                    for r in mine:
                        x = _num(r.get(col))
                        if x is None:
                            continue
                        if r["policy"] == "qlearning":
                            q[(r["world_name"], int(r["seed"]))].append(x)
                        else:
                            s[(r["world_name"], int(r["seed"]))] = x
                    by_world: dict[str, list[float]] = defaultdict(list)
                    for pair, vals in q.items():
                        if pair in s:
                            by_world[pair[0]].append(statistics.fmean(vals) - s[pair])
                    judged.append({"claim": text, "column": col, "direction": sign,
                                   "features": features, "alpha_schedule": schedule,
                                   "budget": budget, **paired_test(by_world, sign)})
    return judged


def completion(rows: list[dict[str, Any]], out: Path) -> list[dict[str, Any]]:
    """The sixth claim per feature mode and step-size schedule, from the until-complete
    runs."""
    result = []
    for features in sorted({r["features"] for r in rows}):
        of_mode = [r for r in rows if r["status"] == "done" and r["features"] == features
                   and r["budget"] == UNTIL_COMPLETE]
        for schedule in _schedules(of_mode):
            mine = [read_run(out / "cells" / r["key"]) for r in _against(of_mode, schedule)]
            if mine:
                result.append({"features": features, "alpha_schedule": schedule,
                               **check_completion(mine)})
    return result


def ranking(table: QTable, state: State) -> list[list[str]]:
    """The actions possible in ``state``, best first by Q(s, a), tied actions together, up
    to the attention shift.

    The FSM takes an action once per focus where the paper allows it once (an
    improvement's trial), so after the greedy action the next ranked one is what the robot
    does: two tables with the same greedy action and another order are two robots. The
    shift is always allowed and ends the focus, so what ranks below it is never taken and
    is left out (its group is kept whole when tied)."""
    values: dict[float, list[str]] = defaultdict(list)
    for a in possible_actions(state):
        values[table.value(state, a)].append(a.name.lower())
    order = [values[v] for v in sorted(values, reverse=True)]
    shift = Action.ATTENTION_SHIFT.name.lower()
    for i, group in enumerate(order):
        if shift in group:
            return order[:i + 1]
    return order


def draw_agreement(all_cells: list[Cell], out: Path) -> list[dict[str, Any]]:
    """How much the training draws agree, per feature mode and step-size schedule: each
    state's greedy action in each draw's table (train/<key>/qtable.json; several when
    tied) and the share of the states whose greedy action is the same in every trained
    draw (None with fewer than two); likewise for the whole ranking of the state's
    actions (``ranking``), which the greedy action alone can hide."""
    keys: dict[tuple[str, str], dict[int, str]] = defaultdict(dict)
    for c in all_cells:
        if c.draw and c.train_key:
            keys[(c.features, c.alpha_schedule)][c.draw] = c.train_key
    result = []
    for (features, schedule), by_draw in sorted(keys.items()):
        greedy: dict[int, dict[str, list[str]]] = {}
        ranks: dict[int, dict[str, list[list[str]]]] = {}
        for draw, key in sorted(by_draw.items()):
            if is_done(out / "train" / key):
                table = QTable.load(out / "train" / key / "qtable.json")
                greedy[draw] = {s.bits: [a.name.lower() for a in
                                         table.greedy_actions(s, possible_actions(s))]
                                for s in STATES}
                ranks[draw] = {s.bits: ranking(table, s) for s in STATES}
        compared = len(greedy) >= 2
        states: list[dict[str, Any]] = []
        agreeing = ranked_alike = 0
        for s in STATES:
            per_draw = {str(d): g[s.bits] for d, g in greedy.items()}
            per_rank = {str(d): r[s.bits] for d, r in ranks.items()}
            agree = compared and len({tuple(v) for v in per_draw.values()}) == 1
            alike = compared and len({repr(v) for v in per_rank.values()}) == 1
            agreeing += agree
            ranked_alike += alike
            states.append({"state": s.bits, "greedy": per_draw, "agree": agree,
                           "ranking": per_rank, "ranked_alike": alike})
        result.append({"features": features, "alpha_schedule": schedule,
                       "draws": len(by_draw), "trained": len(greedy),
                       "states": len(STATES),
                       "states_agreeing": agreeing if compared else None,
                       "share": agreeing / len(STATES) if compared else None,
                       "states_ranked_alike": ranked_alike if compared else None,
                       "per_state": states})
    return result


def report(spec: SweepSpec, all_cells: list[Cell], out: Path, failed: dict[str, str],
           version: str | None = None) -> dict[str, Any]:
    """runs.csv, table2.json, claims.json, draws.json, the figures and report.md
    (``version``: the code version of the cells, named in report.md)."""
    rows = runs_table(all_cells, out, failed)
    write_csv(out / "runs.csv", rows)
    table = spread_table(rows)
    claims = judge(rows)
    complete = completion(rows, out)
    agreement = draw_agreement(all_cells, out)
    atomic_write_bytes(out / "table2.json", _json(table))
    atomic_write_bytes(out / "claims.json", _json({"claims": claims, "completion": complete}))
    atomic_write_bytes(out / "draws.json", _json({"agreement": agreement}))
    figures = []
    several = len(spec.alpha_schedules) > 1
    for col in COLUMNS:
        values: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
        per_world: dict[tuple[str, str, str, str], list[float]] = defaultdict(list)
        for r in rows:
            if r["status"] == "done" and r["budget"] != UNTIL_COMPLETE \
                    and (x := _num(r.get(col))) is not None:
                per_world[(r["features"], r["alpha_schedule"], r["policy"],
                           r["world_name"])].append(x)
        for (features, schedule, policy, _), xs in sorted(per_world.items()):
            # One panel per feature mode, and per schedule when there are several (the
            # straightforward policy, which has none, in each).
            for s in (list(spec.alpha_schedules) if several and not schedule else [schedule]):
                panel = f"{features} / {s}" if several else features
                values[panel][policy].append(statistics.fmean(xs))
        if values:
            path = out / f"fig_{col}.png"
            plots.distribution(values, col.replace("_", " "), path)
            figures.append(path.name)
    counts = {"cells": len(rows), "done": sum(r["status"] == "done" for r in rows),
              "failed": sum(r["status"] == "failed" for r in rows)}
    atomic_write_bytes(out / "report.md",
                       report_markdown(spec, counts, table, claims, complete, figures,
                                       rows, agreement, version).encode())
    return {**counts, "table2": table, "claims": claims, "completion": complete,
            "draw_agreement": agreement}


def _cell(c: dict[str, Any] | None) -> str:
    if not c or not c["n"]:
        return "-"
    digits = 2 if abs(c["mean"]) < 1.5 else 1
    text = f"{c['mean']:.{digits}f} ± {c['sd_worlds']:.{digits}f}"
    if c.get("sd_draws") is not None:
        text += f" (draws ± {c['sd_draws']:.{digits}f})"
    return text


def agreement_markdown(agreement: list[dict[str, Any]]) -> list[str]:
    """report.md's lines on how much the training draws agree (none without draws)."""
    if not agreement:
        return []
    lines = ["", "## Do the training draws agree?", "",
             "Per feature mode and step size, the greedy action of each state in each "
             "draw's table (several when tied; a state no training run reached keeps its "
             "initial values, all tied), and how many of the six states have the same "
             "greedy action in every trained draw. The greedy action can hide two "
             "robots: once an improvement's trial is used the FSM takes the next ranked "
             "action, so the ranking is compared too (each draw's column: best first, "
             "`=` for a tie, down to the attention shift, which ends the focus, so "
             "nothing ranked below it is ever taken). Details in draws.json.", ""]
    for a in agreement:
        head = f"**{a['features']}, step size {a['alpha_schedule']}**: "
        if a["share"] is None:
            lines.append(head + f"{a['trained']} of {a['draws']} draws trained, nothing to "
                         "compare.")
        else:
            lines.append(head + f"{a['states_agreeing']} of {a['states']} states "
                         f"({a['share']:.0%}) agree in all {a['trained']} trained draws"
                         + ("" if a["trained"] == a["draws"] else f" (of {a['draws']})")
                         + f" on the greedy action, {a['states_ranked_alike']} on the "
                         "ranking of the state's actions up to the shift.")
    draws = sorted({d for a in agreement for st in a["per_state"] for d in st["greedy"]},
                   key=int)
    lines += ["", "| features | step size | state | " + " | ".join(
        f"draw {d}" for d in draws) + " | same greedy action | same ranking |",
        "|" + "---|" * (5 + len(draws))]
    for a in agreement:
        for st in a["per_state"]:
            acts = [_ranked(st.get("ranking", {}).get(d), st["greedy"].get(d))
                    for d in draws]
            lines.append(f"| {a['features']} | {a['alpha_schedule']} | {st['state']} | "
                         + " | ".join(acts) + f" | {'yes' if st['agree'] else 'no'} | "
                         + f"{'yes' if st.get('ranked_alike') else 'no'} |")
    return lines


def _ranked(rank: list[list[str]] | None, greedy: list[str] | None) -> str:
    """One draw's cell: its ranking, best first (`>` between, `=` in a tie), or its greedy
    action where no ranking is known."""
    if rank:
        return " > ".join(" = ".join(group) for group in rank).replace("_", " ")
    return " = ".join(greedy or ["-"]).replace("_", " ")


def report_markdown(spec: SweepSpec, counts: dict[str, int], table: list[dict[str, Any]],
                    claims: list[dict[str, Any]], complete: list[dict[str, Any]],
                    figures: list[str], rows: list[dict[str, Any]],
                    agreement: list[dict[str, Any]] | None = None,
                    version: str | None = None) -> str:
    """report.md: what ran, Table 2 with spreads, the claims across worlds, how much the
    training draws agree, the figures."""
    cols = (*COLUMNS, *SCORES)
    lines = ["# Sweep: Table 2 and the paper's claims across worlds", "",
             f"{len(spec.worlds)} worlds x {len(spec.seeds)} seeds x "
             f"{len(spec.policies)} policies x {len(spec.features)} feature modes, "
             f"{spec.draws} training draws, Q-learning step size "
             f"{', '.join(spec.alpha_schedules)}, budgets "
             f"{', '.join(UNTIL_COMPLETE if c is None else str(c) for c in spec.cycles)}, "
             f"mode {spec.mode}: {counts['cells']} runs, {counts['done']} done, "
             f"{counts['failed']} failed. Every run's row is in runs.csv."
             + (f" Code version {version}." if version else ""), "",
             "## Table 2", "",
             "Mean ± sd across worlds (of each world's mean over seeds and draws); for "
             "Q-learning with several draws, the sd across draws (of each draw's mean) in "
             "brackets.", "",
             "| features | budget | policy | step size | runs | " + " | ".join(
                 c.replace("_", " ") for c in cols) + " |",
             "|" + "---|" * (5 + len(cols))]
    for e in table:
        lines.append(f"| {e['features']} | {e['budget']} | {e['policy']} | "
                     f"{e.get('alpha_schedule') or '-'} | {e['runs']} | "
                     + " | ".join(_cell(e.get(c)) for c in cols) + " |")
    lines += ["", "## The paper's claims across worlds", "",
              "Each pair is one world and one run seed: Q-learning (its mean over the "
              "training draws, per step size) minus the straightforward policy. The test is "
              "the exact Wilcoxon signed-rank test over the pairs: counts are discrete and "
              "their differences far from normal (no t test), and the signed ranks use how "
              "large each difference is, which the sign test (shown too) throws away. The "
              "effect is the mean difference with a bootstrap 95 % interval that resamples "
              "whole worlds (the seeds of one world are not independent), and the "
              "rank-biserial correlation r. *holds*: the interval lies on the claimed side "
              "of 0 and p < 0.05; *contradicted*: on the other side and p < 0.05; else "
              "*not shown*.",
              "",
              "| features | step size | budget | claim | verdict | pairs (worlds) | holds in "
              "| mean difference [95 % CI] | r | Wilcoxon p | sign test p |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in claims:
        lo, hi = c["ci95"]
        lines.append(f"| {c['features']} | {c['alpha_schedule'] or '-'} | {c['budget']} | "
                     f"{c['claim']} | **{c['verdict']}** "
                     f"| {c['pairs']} ({c['groups']}) | {c['holds_in']}/{c['pairs']} | "
                     f"{c['mean_difference']:+.2f} [{lo:+.2f}, {hi:+.2f}] | "
                     f"{c['rank_biserial']:+.2f} | {c['wilcoxon_p']:.3g} | "
                     f"{c['sign_test_p']:.3g} |")
    for c in complete:
        per = "; ".join(f"{p}: {v['every_object_visited']}/{v['runs']} runs"
                        for p, v in c["per_policy"].items())
        lines.append(f"| {c['features']} | {c['alpha_schedule'] or '-'} | {UNTIL_COMPLETE} "
                     f"| {c['claim']} | **{c['verdict']}** | "
                     f"{c['runs']} runs | {c['every_object_visited']}/{c['runs']} ({per}) "
                     "| - | - | - | - |")
    lines += agreement_markdown(agreement or [])
    if figures:
        lines += ["", "## Figures", "", "Per Table 2 column, each world's mean per policy "
                  "and feature mode (and step size, when there are several; fixed budgets): "
                  + ", ".join(f"[{f}]({f})" for f in figures) + "."]
    bad = [r for r in rows if r["status"] == "failed"]
    if bad:
        lines += ["", "## Failed runs", "", "Their errors are under failed/<key>/error.txt; "
                  "the next `roger sweep` of this spec tries them again.", ""]
        lines += [f"- {r['key']}: {r['policy']} seed {r['seed']} on {r['world_name']} "
                  f"({r['features']}"
                  + (f", step size {r['alpha_schedule']}" if r["alpha_schedule"] else "")
                  + f"): {r['error']}" for r in bad]
    lines.append("")
    return "\n".join(lines)
