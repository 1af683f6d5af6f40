"""Replay recorded looks through fresh memories and count what the labels say went wrong.

    python bench/replay_queries.py FILE.csv.gz [FILE ...] [--smooth-tk] [--no-flat-veto]

Each FILE is a recording of ``python -m roger_experiments.record_queries`` (the robot's
own looks, with the labels that only score). Every run in it is replayed through a fresh
memory of the file's feature mode with the shipped calibration
(``record_queries.replay``), and the script prints per file: identification precision
over every identified look, novelty precision over the stores, copies stored again
(false new / final looks of a category already stored) and false identifications (novel
final looks identified / novel final looks).

``--smooth-tk`` applies TK x (1 - TC) to the looks first: what perception sends since TK
became the curvature of a smooth surface (2026-11-27), for recordings made before it
(nothing else that moves the robot reads TK, so the trajectories are the same).
``--no-flat-veto`` replays without the outline's veto between flat tops
(``MemoryConfig.flat_veto`` all 1.0), to see what it changes. docs/memory.md, "The outline
vetoes between flat tops", has the figures.
"""
from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from roger_common.types import feature_names, mode_of_dim
from roger_experiments.record_queries import Query, read_csv, replay
from roger_memory.config import MemoryConfig
from roger_memory.memory import AssociativeMemory


def smooth_tk(rows: list[Query]) -> list[Query]:
    """TK x (1 - TC) where both are known (extended looks; others are returned as they are)."""
    out = []
    for q in rows:
        names = feature_names(mode_of_dim(len(q.features)))
        if "TK" not in names:
            out.append(q)
            continue
        tk, tc = names.index("TK"), names.index("TC")
        f = q.features.copy()
        if q.known[tk] and q.known[tc]:
            f[tk] = f[tk] * (1.0 - f[tc])
        out.append(dataclasses.replace(q, features=f))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("files", type=Path, nargs="+")
    p.add_argument("--smooth-tk", action="store_true",
                   help="TK x (1 - TC) first (recordings made before 2026-11-27)")
    p.add_argument("--no-flat-veto", action="store_true",
                   help="replay without the outline's veto between flat tops")
    args = p.parse_args()
    for path in args.files:
        rows = read_csv(path)
        if not rows:
            print(f"{path}: no looks")
            continue
        if args.smooth_tk:
            rows = smooth_tk(rows)
        mode = mode_of_dim(len(rows[0].features)).value
        overrides = {"flat_veto": (1.0,) * len(rows[0].features)} if args.no_flat_veto else {}
        cfg = MemoryConfig.for_mode(mode, **overrides)
        scores = replay(rows, lambda cfg=cfg: AssociativeMemory(cfg, seed=0))
        ids = sum(s.identifications for s in scores)
        ok = sum(s.correct_identifications for s in scores)
        stores = sum(s.stores for s in scores)
        ok_stores = sum(s.correct_stores for s in scores)
        print(f"{path} ({mode}, {len(rows)} looks, {len(scores)} runs): "
              f"identification {ok}/{ids} = {ok / max(ids, 1):.3f}, "
              f"novelty {ok_stores}/{stores} = {ok_stores / max(stores, 1):.3f}, "
              f"copies stored again {sum(s.false_new for s in scores)}/"
              f"{sum(s.repeats_final for s in scores)}, "
              f"false identifications {sum(s.false_identified for s in scores)}/"
              f"{sum(s.novel_final for s in scores)}")


if __name__ == "__main__":
    main()
