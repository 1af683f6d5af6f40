"""Sweep throughput with k Ray workers against 1 worker on the same cells, in process
(issue 37: target >= 0.85 k for k = the machine's cores).

    .venv/bin/python bench/sweep_throughput.py --out runs/bench-sweep [--workers 2]
        [--worlds 4] [--cycles 60]

Each measurement is a fresh ``roger sweep`` into its own folder (so nothing is resumed),
embedded Ray included (its start, about 3 s, is part of the wall time, as for a user).
Prints one JSON line per measurement and the ratio; writes OUT/throughput.json.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import yaml


def spec(worlds: int, cycles: int) -> dict:
    """Random worlds of the demo's recipe x 1 seed x both policies, Q-learning online."""
    return {"worlds": [{"recipe": "default", "n_categories": 8, "copies": 3,
                        "size_range": [0.08, 0.14],
                        "seeds": {"start": 5000, "count": worlds}}],
            "seeds": [0], "policies": ["qlearning", "straightforward"],
            "features": ["paper"], "draws": 0, "cycles": cycles, "mode": "in_process"}


def measure(spec_file: Path, out: Path, workers: int) -> dict:
    """One sweep from scratch with ``workers`` parallel runs: wall seconds and runs/s."""
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "roger_bringup.cli", "sweep", str(spec_file),
                           "--out", str(out), "--workers", str(workers), "--quiet"],
                          capture_output=True, text=True)
    wall = time.monotonic() - t0
    if proc.returncode != 0:
        raise SystemExit(proc.stdout[-2000:] + proc.stderr[-2000:])
    runs = len((out / "runs.csv").read_text().splitlines()) - 1
    return {"workers": workers, "runs": runs, "wall_s": round(wall, 1),
            "runs_per_s": round(runs / wall, 4)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("runs/bench-sweep"))
    p.add_argument("--workers", type=int, default=os.cpu_count() or 2)
    p.add_argument("--worlds", type=int, default=4)
    p.add_argument("--cycles", type=int, default=60)
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    spec_file = args.out / "spec.yaml"
    spec_file.write_text(yaml.safe_dump(spec(args.worlds, args.cycles)))
    one = measure(spec_file, args.out / "w1", 1)
    print(json.dumps(one))
    k = measure(spec_file, args.out / f"w{args.workers}", args.workers)
    print(json.dumps(k))
    ratio = k["runs_per_s"] / one["runs_per_s"]
    result = {"one": one, "k": k, "speedup": round(ratio, 3),
              "per_worker": round(ratio / args.workers, 3), "cpus": os.cpu_count()}
    (args.out / "throughput.json").write_text(json.dumps(result, indent=2) + "\n")
    print(f"speed-up with {args.workers} workers: {ratio:.2f}x "
          f"({ratio / args.workers:.2f} per worker; target 0.85)")


if __name__ == "__main__":
    main()
