"""Ground-truth scoring of a run and the files it writes (cycles.csv, metrics.json).

Evaluation only: it reads the simulator's ground truth, which the policy and the memory
never see. Pure Python: the ROS monitor and the in-process loop both feed it.

Scoring rules (issue 7):
- objects with identical shape, size, intensity, weight and texture are one category;
- identification_precision: share of positive identifications (first mappings) whose
  memory address was first stored from an object of the same category as the one in view;
- remap_precision: the same for remaps (an entry mapped before, identified again);
- novelty_precision: share of new-object detections made while no object of that category
  was yet in memory;
- objects_visited: world objects that filled the attention window at least once
  (``object_under_window``); a "lost" cycle shows no object and visits nothing;
- failed_goals: physical actions whose servo goal failed (``converged`` 0 in cycles.csv),
  e.g. a haptic improvement on an object beyond the arms' reach.

Each scored mistake is also kept, one row of errors.csv (``ERROR_COLUMNS``), so that a run
says what went wrong and not only how often: an identification of an address stored from
another category (and which object it was stored from), a store of a category already
stored (and its first object), a store while no single object filled the window, an
attention shift whose window showed no object (and the nearest object on the ground plane:
a few centimetres means a window spanning two objects, or a part of one).
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from roger_common.atomic import atomic_write_bytes
from roger_common.types import Action, ObjectSpec

#: cycles.csv columns; the first eight are a contract (issue 7), later ones are extensions.
CSV_COLUMNS: tuple[str, ...] = (
    "cycle", "state", "action", "reward", "td_error", "roi", "true_object", "outcome",
    "state_after", "address", "x", "y", "z", "sim_time", "converged",
)
#: Share of the attention window's area an object's extent must exceed for the window to
#: show that object (a visit). Measured on three worlds: windows holding one object reach
#: 0.67 or more, windows spanning two objects 0.26-0.53 for the larger (docs/attention.md).
WINDOW_FILL = 0.5
#: A window that holds one object, all of it, and reaches at most this many pixels past its
#: silhouette on every side is that object's own box, whatever the share: the ROI's box
#: reaches 0-1 px past the silhouette (measured over 4,703 ROIs holding one whole object on
#: random worlds: 0 px on 67 % of the sides, 1 px on 32 %, 2 px on 0.15 %), and for an
#: object 2-5 px across that margin alone keeps its extent at half of the window or less.
WINDOW_HALO_PX = 2
#: errors.csv columns (``ScoredError``).
ERROR_COLUMNS: tuple[str, ...] = ("cycle", "kind", "object", "address", "other", "distance_m")
#: ``ScoredError.kind`` values, in the order a report lists them.
ERROR_KINDS: tuple[str, ...] = ("wrong_identification", "wrong_remap", "repeated_store",
                                "store_of_nothing", "empty_shift")
ACTION_NAMES: dict[int, str] = {
    Action.ATTENTION_SHIFT: "attention_shift",
    Action.VISUAL_IMPROVEMENT: "visual_improvement",
    Action.HAPTIC_IMPROVEMENT: "haptic_improvement",
    Action.MAP_UPDATE: "map_update",
}


@dataclass(frozen=True)
class CycleRow:
    """One control cycle as the evaluation sees it."""

    cycle: int
    state: str
    action: int
    reward: float
    td_error: float | None
    roi: int
    true_object: str | None
    outcome: str
    state_after: str = ""
    address: int = -1
    position: tuple[float, float, float] | None = None
    sim_time: float = 0.0
    converged: bool | None = None

    def as_csv(self) -> list[str]:
        """The row's cells in CSV_COLUMNS order (empty cells for unknowns)."""
        pos = self.position or (math.nan, math.nan, math.nan)
        # /roger/policy_state carries the TD error as float32: round it the same way, or a
        # value on a printing tie (-0.05578125) is written differently by the core loop.
        td = "" if self.td_error is None or not math.isfinite(self.td_error) else \
            f"{float(np.float32(self.td_error)):.6g}"
        return [str(self.cycle), self.state, ACTION_NAMES.get(self.action, str(self.action)),
                f"{self.reward:.6g}", td, str(self.roi), self.true_object or "", self.outcome,
                self.state_after, str(self.address),
                *("" if math.isnan(v) else f"{v:.4f}" for v in pos), f"{self.sim_time:.4f}",
                "" if self.converged is None else str(int(self.converged))]


def object_under_window(labels: np.ndarray, names: tuple[str, ...] | list[str],
                        bbox: tuple[int, int, int, int]) -> str | None:
    """The world object that fills most of the attention window; None when none does.

    The candidate is the object with the most pixels in the window. It fills the window
    when the bounding box of those pixels covers more than WINDOW_FILL of the window's
    area: the object's extent, not its pixel count, because a prism covers half of its
    own bounding box and a ROI's box keeps a margin around the object (docs/attention.md
    has the measured distribution). A window spanning two objects, or mostly ground,
    shows none. A window that is the object's own box (the only object in it, all of its
    pixels inside, within WINDOW_HALO_PX of its silhouette on every side) shows it
    whatever the share: a far or small object 2-5 px across.

    Args:
        labels: Per-pixel object index of the left retina, -1 for ground and robot.
        names: Object names by index.
        bbox: (x0, y0, x1, y1) of the attended ROI, exclusive ends.
    """
    x0, y0, x1, y1 = bbox
    window = labels[max(0, y0):max(0, y1), max(0, x0):max(0, x1)]
    objects = window[window >= 0]
    if objects.size == 0:
        return None
    idx = int(np.bincount(objects).argmax())
    rows, cols = np.nonzero(window == idx)
    extent = (int(rows.max() - rows.min()) + 1) * (int(cols.max() - cols.min()) + 1)
    if extent <= WINDOW_FILL * window.size and not (
            rows.size == objects.size and _own_box(labels, window, idx, rows, cols)):
        return None
    return names[idx] if idx < len(names) else None


def _own_box(labels: np.ndarray, window: np.ndarray, idx: int, rows: np.ndarray,
             cols: np.ndarray) -> bool:
    """Whether ``window`` (a crop of ``labels``), which holds no other object, is object
    ``idx``'s own box: every pixel of ``idx`` in the frame inside it, and no side more
    than WINDOW_HALO_PX beyond the object's pixels (``rows``, ``cols``: theirs in the
    window)."""
    if rows.size != int(np.count_nonzero(labels == idx)):
        return False
    height, width = window.shape
    margins = (int(rows.min()), int(cols.min()), height - 1 - int(rows.max()),
               width - 1 - int(cols.max()))
    return max(margins) <= WINDOW_HALO_PX


@dataclass(frozen=True)
class ScoredError:
    """One mistake of a run, judged on the ground truth (module docstring).

    Attributes:
        cycle: The cycle that made it (the map update of an identification or a store).
        kind: One of ``ERROR_KINDS``.
        object: The object in view ("" when no single object filled the window).
        address: The memory address concerned (-1 for an empty shift).
        other: wrong_identification / wrong_remap: the object the address was first stored
            from ("" when a loaded memory stored it); repeated_store: the first object
            stored of that category; empty_shift: the nearest world object.
        distance_m: empty_shift: ground-plane distance from the window's position to
            ``other``; NaN otherwise.
    """

    cycle: int
    kind: str
    object: str
    address: int
    other: str
    distance_m: float = math.nan

    def as_csv(self) -> list[str]:
        """The error's cells in ERROR_COLUMNS order."""
        d = "" if math.isnan(self.distance_m) else f"{self.distance_m:.4f}"
        return [str(self.cycle), self.kind, self.object, str(self.address), self.other, d]


@dataclass
class RunScorer:
    """Accumulates the ground-truth scores of a run, cycle by cycle."""

    objects: dict[str, ObjectSpec]
    visited: set[str] = field(default_factory=set)
    address_category: dict[int, Any] = field(default_factory=dict)
    identifications: int = 0
    correct_identifications: int = 0
    failed_goals: int = 0
    remaps: int = 0
    correct_remaps: int = 0
    detections: int = 0
    correct_detections: int = 0
    last_true_of_roi: dict[int, str | None] = field(default_factory=dict)
    #: The object each address was first stored from (this run's stores only).
    address_object: dict[int, str] = field(default_factory=dict)
    errors: list[ScoredError] = field(default_factory=list)

    def set_objects(self, objects: list[ObjectSpec]) -> None:
        """The world changed: keep scoring with its current objects (old ones stay known)."""
        for o in objects:
            self.objects[o.name] = o

    def category(self, name: str | None) -> Any:
        """Category of a world object by name; None for no object."""
        if name is None or name not in self.objects:
            return None
        return self.objects[name].category()

    def true_object_for(self, action: int, roi: int, seen: str | None,
                        outcome: str = "") -> str | None:
        """The object under the window: seen now, or (map update) last seen for that ROI.

        A "lost" cycle looked at nothing: the entry's window is one of an earlier frame
        (the place was forgotten because this frame showed nothing there), so scoring it
        against this frame's labels would credit a look that never happened.
        """
        if outcome == "lost":
            return None
        if action == Action.MAP_UPDATE:
            return self.last_true_of_roi.get(roi)
        self.last_true_of_roi[roi] = seen
        return seen

    def add(self, row: CycleRow) -> None:
        """Score one cycle."""
        if row.converged is False:
            self.failed_goals += 1
        if row.true_object is not None:
            self.visited.add(row.true_object)
        if row.action == Action.ATTENTION_SHIFT and (row.true_object is None
                                                     or row.outcome == "lost"):
            self.errors.append(self._empty_shift(row))
        if row.action != Action.MAP_UPDATE:
            return
        cat = self.category(row.true_object)
        seen = (row.true_object or "") if cat is not None else ""
        if row.outcome == "stored":
            self.detections += 1
            if cat is None:
                self.errors.append(ScoredError(row.cycle, "store_of_nothing", "", row.address,
                                               ""))
            elif cat not in self.address_category.values():
                self.correct_detections += 1
            else:
                first = next(a for a, c in self.address_category.items() if c == cat)
                self.errors.append(ScoredError(row.cycle, "repeated_store", seen, row.address,
                                               self.address_object.get(first, "")))
            if row.address >= 0 and row.address not in self.address_category:
                self.address_category[row.address] = cat
                self.address_object[row.address] = seen
        elif row.outcome in ("mapped", "remapped"):
            stored = self.address_category.get(row.address, None)
            correct = int(cat is not None and stored == cat)
            if row.outcome == "mapped":
                self.identifications += 1
                self.correct_identifications += correct
            else:
                self.remaps += 1
                self.correct_remaps += correct
            if not correct:
                kind = "wrong_identification" if row.outcome == "mapped" else "wrong_remap"
                self.errors.append(ScoredError(row.cycle, kind, seen, row.address,
                                               self.address_object.get(row.address, "")))

    def _empty_shift(self, row: CycleRow) -> ScoredError:
        """An attention shift that showed no object, with the nearest object to its window."""
        near, dist = "", math.nan
        if row.position is not None and all(math.isfinite(v) for v in row.position[:2]):
            for name, o in self.objects.items():
                d = math.dist(row.position[:2], o.position)
                if math.isnan(dist) or d < dist:
                    near, dist = name, d
        return ScoredError(row.cycle, "empty_shift", "", -1, near, dist)

    def results(self) -> dict[str, Any]:
        """The ground-truth part of metrics.json."""
        def share(num: int, den: int) -> float | None:
            return None if den == 0 else num / den
        return {
            "objects_in_world": len(self.objects),
            "objects_visited": len(self.visited & set(self.objects)),
            "identification_precision": share(self.correct_identifications,
                                              self.identifications),
            "novelty_precision": share(self.correct_detections, self.detections),
            "remap_precision": share(self.correct_remaps, self.remaps),
            "failed_goals": self.failed_goals,
        }


def truth_sidecar(memory_file: Path) -> Path:
    """Evaluation's record of which category each memory address was stored from.

    Kept beside the long-term memory file so that a later run that loads the memory can
    still score its identifications. Only the evaluation reads it.
    """
    return memory_file.with_name(memory_file.name + ".truth.json")


class RunRecorder:
    """Writes cycles.csv as the run goes (flushed per row: a crash loses nothing) and
    metrics.json at the end (atomically)."""

    def __init__(self, out_dir: Path, objects: list[ObjectSpec], meta: dict[str, Any],
                 memory_file: Path | None = None) -> None:
        self.out_dir = out_dir
        out_dir.mkdir(parents=True, exist_ok=True)
        self.meta = dict(meta)
        self.scorer = RunScorer({o.name: o for o in objects})
        self.sidecar = truth_sidecar(memory_file) if memory_file is not None else None
        if self.sidecar is not None and self.sidecar.exists():
            data = json.loads(self.sidecar.read_text())
            self.scorer.address_category = {
                int(a): (tuple(c) if c is not None else None) for a, c in data.items()}
        self.rows: list[CycleRow] = []
        self.counters: dict[str, int] = {}
        #: True when the run ended by the robot's completion rule (the attention's own).
        self.complete = False
        self._fh: IO[str] = open(out_dir / "cycles.csv", "w", newline="")
        self._csv = csv.writer(self._fh)
        self._csv.writerow(CSV_COLUMNS)
        self._fh.flush()

    def add(self, row: CycleRow) -> None:
        """Record and score one cycle."""
        self.rows.append(row)
        before = len(self.scorer.address_category)
        self.scorer.add(row)
        if self.sidecar is not None and len(self.scorer.address_category) != before:
            atomic_write_bytes(self.sidecar, json.dumps(
                {str(a): c for a, c in self.scorer.address_category.items()}).encode())
        self._csv.writerow(row.as_csv())
        self._fh.flush()

    def metrics(self, wall_seconds: float) -> dict[str, Any]:
        """metrics.json's content: the meta, the counters, the scores and the wall time."""
        c = dict(self.counters)
        out: dict[str, Any] = dict(self.meta)
        for key in ("cycles", "attention_shifts", "improvements", "visual_improvements",
                    "haptic_improvements", "positive_identifications", "new_objects",
                    "map_updates", "remaps"):
            out[key] = int(c.get(key, 0))
        scores = self.scorer.results()
        out.update(scores)
        out["complete"] = bool(self.complete)
        # Judged on the ground truth after the run, whatever ended it.
        out["every_object_visited"] = (
            scores["objects_visited"] >= scores["objects_in_world"] > 0)
        out["wall_seconds"] = round(float(wall_seconds), 3)
        return out

    def close(self, wall_seconds: float) -> dict[str, Any]:
        """Close cycles.csv and write metrics.json and errors.csv; returns the metrics."""
        if not self._fh.closed:
            self._fh.close()
        metrics = self.metrics(wall_seconds)
        write_errors(self.out_dir / "errors.csv", self.scorer.errors)
        atomic_write_bytes(self.out_dir / "metrics.json",
                           (json.dumps(metrics, indent=2) + "\n").encode())
        return metrics


def write_errors(path: Path, errors: list[ScoredError]) -> None:
    """errors.csv (``ERROR_COLUMNS``), written atomically."""
    buf = io.StringIO()
    out = csv.writer(buf)
    out.writerow(ERROR_COLUMNS)
    out.writerows(e.as_csv() for e in errors)
    atomic_write_bytes(path, buf.getvalue().encode())


def rows_from_csv(rows: list[dict[str, str]]) -> list[CycleRow]:
    """cycles.csv's rows (as ``csv.DictReader`` gives them) as CycleRows again."""
    actions = {name: a for a, name in ACTION_NAMES.items()}

    def number(cell: str, default: float = math.nan) -> float:
        return float(cell) if cell not in ("", None) else default

    out = []
    for r in rows:
        pos = tuple(number(r.get(k, "")) for k in ("x", "y", "z"))
        conv = r.get("converged", "")
        td = number(r.get("td_error", ""))
        out.append(CycleRow(
            cycle=int(r["cycle"]), state=r["state"],
            action=actions.get(r["action"], -1), reward=number(r["reward"], 0.0),
            td_error=None if math.isnan(td) else td, roi=int(r["roi"]),
            true_object=r["true_object"] or None, outcome=r["outcome"],
            state_after=r.get("state_after", ""), address=int(r.get("address") or -1),
            position=None if all(math.isnan(v) for v in pos) else pos,  # type: ignore[arg-type]
            sim_time=number(r.get("sim_time", ""), 0.0),
            converged=None if conv in ("", None) else bool(int(conv))))
    return out


def score_cycles(rows: list[dict[str, str]], objects: list[ObjectSpec]) -> RunScorer:
    """Score a finished run's cycles.csv again (e.g. a run from before errors.csv existed):
    the same scores and errors as the run's own scorer, world edits aside."""
    scorer = RunScorer({o.name: o for o in objects})
    for row in rows_from_csv(rows):
        scorer.add(row)
    return scorer


def counters_from_rows(rows: list[CycleRow]) -> dict[str, int]:
    """Table 2's counters recomputed from a cycle log (a check on the live counters)."""
    actions = Counter(r.action for r in rows)
    stored = sum(1 for r in rows if r.action == Action.MAP_UPDATE and r.outcome == "stored")
    mapped = sum(1 for r in rows if r.action == Action.MAP_UPDATE and r.outcome == "mapped")
    remapped = sum(1 for r in rows
                   if r.action == Action.MAP_UPDATE and r.outcome == "remapped")
    return {
        "cycles": len(rows),
        "attention_shifts": actions[Action.ATTENTION_SHIFT],
        "improvements": actions[Action.VISUAL_IMPROVEMENT] + actions[Action.HAPTIC_IMPROVEMENT],
        "visual_improvements": actions[Action.VISUAL_IMPROVEMENT],
        "haptic_improvements": actions[Action.HAPTIC_IMPROVEMENT],
        "positive_identifications": mapped,
        "new_objects": stored,
        "map_updates": actions[Action.MAP_UPDATE],
        "remaps": remapped,
    }
