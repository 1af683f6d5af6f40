"""Benchmark of the perception core per stereo pair (not a test).

Times the visual buffer (LoG of both retinas at three resolutions) and the whole
``Perception.process`` at 128 and 256 px, with four Table-1-like objects in view, and
prints the median per-stage split.

Run: PYTHONPATH=src/roger_common:src/roger_perception python bench/bench_perception.py
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))

from perception_synth import CENTRE_GAZE, make_frame, table1_objects

from roger_perception.config import PerceptionConfig
from roger_perception.log_filter import log_pyramid
from roger_perception.perception import STAGES, Perception


def bench(width: int, repeats: int, shape: str) -> dict[str, float]:
    """Median milliseconds per stage and in total for one stereo pair of ``width`` px."""
    cfg = PerceptionConfig()
    frames = [make_frame(table1_objects(shape), gaze=CENTRE_GAZE, width=width, seed=s)
              for s in range(4)]
    perception = Perception(cfg)
    for f in frames:  # warm up caches and OpenCV
        perception.process(f)
    buffer_ms, total_ms = [], []
    stages: dict[str, list[float]] = {s: [] for s in STAGES}
    n_rois = 0
    for i in range(repeats):
        f = frames[i % len(frames)]
        t0 = time.perf_counter()
        log_pyramid(f.left, cfg)
        log_pyramid(f.right, cfg)
        buffer_ms.append((time.perf_counter() - t0) * 1e3)
        perception.reset()
        t0 = time.perf_counter()
        n_rois = len(perception.process(f))
        total_ms.append((time.perf_counter() - t0) * 1e3)
        for s in STAGES:
            stages[s].append(perception.last_timings[s] * 1e3)
    out = {"buffer": statistics.median(buffer_ms), "process": statistics.median(total_ms),
           "rois": float(n_rois)}
    out.update({s: statistics.median(v) for s, v in stages.items()})
    return out


def main() -> None:
    """Parse arguments, run the benchmark at each size, print one table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=200)
    parser.add_argument("--shape", default="cylinder", choices=("cube", "sphere", "cylinder"))
    args = parser.parse_args()
    cols = ("buffer", "process", *STAGES)
    print(f"{'px':>5} {'rois':>4} " + " ".join(f"{c:>10}" for c in cols) + "   (median ms)")
    for width in (128, 256):
        r = bench(width, args.repeats, args.shape)
        print(f"{width:>5} {int(r['rois']):>4} " + " ".join(f"{r[c]:>10.3f}" for c in cols))


if __name__ == "__main__":
    main()
