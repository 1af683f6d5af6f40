"""How much one object's touch features change between its own haptic readings, and how far
copies and categories lie apart (docs/perception.md, "Touches pooled per object").

Not a test. Reads query files of ``roger_experiments.record_queries`` (extended mode); the
object and category labels only group the looks (nothing is calibrated here)::

    python bench/touch_spread.py runs/before.csv.gz runs/after.csv.gz

For each file and each of TK, TC: the share of objects whose own readings differ by more
than 0.2 (and of the prisms), the difference between the medians of two copies of one
category (median and 90th percentile) and between two categories' medians (median).
"""

from __future__ import annotations

import argparse
import collections
from pathlib import Path

import numpy as np

from roger_common.types import feature_names
from roger_experiments.record_queries import read_csv


def spread(path: Path, feature: str) -> dict[str, float]:
    """The figures of one query file and feature (module docstring)."""
    rows = read_csv(path)
    fi = feature_names("extended").index(feature)
    per_object: dict[tuple[str, ...], list[float]] = collections.defaultdict(list)
    for q in rows:
        if q.known[fi] and q.obj:
            per_object[(q.world, q.policy, q.seed, q.obj, q.category)].append(
                float(q.features[fi]))
    many = {k: v for k, v in per_object.items() if len(v) > 1}
    prisms = [np.ptp(v) for k, v in many.items() if k[4].startswith("prism")]
    by_category: dict[tuple[str, ...], list[float]] = collections.defaultdict(list)
    for k, v in per_object.items():
        by_category[k[:3] + (k[4],)].append(float(np.median(v)))
    copies = [abs(a - b) for vs in by_category.values()
              for i, a in enumerate(vs) for b in vs[i + 1:]]
    per_run: dict[tuple[str, ...], list[float]] = collections.defaultdict(list)
    for k, vs in by_category.items():
        per_run[k[:3]].append(float(np.median(vs)))
    categories = [abs(a - b) for vs in per_run.values()
                  for i, a in enumerate(vs) for b in vs[i + 1:]]
    return {"objects_over_0.2": float(np.mean([np.ptp(v) > 0.2 for v in many.values()])),
            "prisms_over_0.2": float(np.mean(np.array(prisms) > 0.2)) if prisms else np.nan,
            "copies_median": float(np.median(copies)),
            "copies_p90": float(np.quantile(copies, 0.9)),
            "categories_median": float(np.median(categories))}


def main() -> None:
    """Command line: one line per file and feature."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("files", type=Path, nargs="+")
    args = p.parse_args()
    for path in args.files:
        for feature in ("TK", "TC"):
            f = spread(path, feature)
            print(f"{path} {feature}: objects > 0.2 apart {f['objects_over_0.2']:.3f} "
                  f"(prisms {f['prisms_over_0.2']:.2f}); copies {f['copies_median']:.3f} / "
                  f"p90 {f['copies_p90']:.3f}; categories {f['categories_median']:.3f}")


if __name__ == "__main__":
    main()
