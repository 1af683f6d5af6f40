"""A finished run as data (``RunResult``) and the readers of a run's files.

The bottom of the experiments: Table 2 (``table2``), the figures (``plots``), the training
(``train``) and the sweep read runs through this module and it imports none of them, so
that they form layers and not a circle (``.importlinter``, contract ``experiments-layers``).
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: The files a run writes that its results are read from (others may be beside them).
METRICS_FILE = "metrics.json"
CYCLES_FILE = "cycles.csv"
ERRORS_FILE = "errors.csv"


@dataclass(frozen=True)
class RunResult:
    """One finished run: its metrics, its cycle log and its errors (errors.csv rows)."""

    policy: str
    seed: int
    metrics: dict[str, Any]
    rows: list[dict[str, str]]
    errors: list[dict[str, str]] = field(default_factory=list)


def read_cycles(path: Path) -> list[dict[str, str]]:
    """cycles.csv (or any CSV with a header) as a list of dicts."""
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def read_metrics(run_dir: Path) -> dict[str, Any]:
    """A run folder's metrics.json."""
    data: dict[str, Any] = json.loads((run_dir / METRICS_FILE).read_text())
    return data


def read_run(run_dir: Path, metrics: dict[str, Any] | None = None) -> RunResult:
    """A finished run from its folder: metrics.json (or ``metrics`` when given),
    cycles.csv and errors.csv (empty when the run wrote none)."""
    metrics = read_metrics(run_dir) if metrics is None else metrics
    errors = run_dir / ERRORS_FILE
    return RunResult(str(metrics.get("policy", "")), int(metrics.get("seed", 0)), metrics,
                     read_cycles(run_dir / CYCLES_FILE),
                     read_cycles(errors) if errors.exists() else [])
