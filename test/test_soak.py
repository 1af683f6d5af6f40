"""Load: a long run of the graph on a 64-object world, with flat RSS and open files per node.

Marked ``soak`` and left out of ``make test`` (pytest.ini); run it with
``pytest -m soak test/test_soak.py`` (ROGER_SOAK_CYCLES sets the length, default 2000).
It samples every node's resident memory and open file descriptors from /proc while the
run goes and writes them to ``soak.json`` in the run's folder.
"""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from test_faults import NODE_MODULES, node_pid, rows_of

from roger_common.errors import WorldFileError
from roger_sim.world import parse_world

ROGER = [sys.executable, "-m", "roger_bringup.cli"]
SHAPES = ("box", "cylinder", "sphere", "prism")


def world_of_64() -> dict:
    """64 small objects on a grid over the workspace (every one valid for parse_world)."""
    objects: list[dict] = []
    for x, y in itertools.product([0.34 + 0.12 * i for i in range(7)],
                                  [-0.9 + 0.12 * j for j in range(16)]):
        n = len(objects)
        entry = {"name": f"o{n:02d}", "shape": SHAPES[n % 4],
                 "position": [round(x, 3), round(y, 3)], "size": 0.07,
                 "intensity": 50 + 10 * (n % 8), "weight": round(0.3 + 0.2 * (n % 5), 1)}
        try:
            parse_world({"objects": [*objects, entry]}, "grid")
        except WorldFileError:
            continue
        objects.append(entry)
        if len(objects) == 64:
            break
    return {"name": "grid64", "objects": objects}


def sample(pid: int) -> tuple[float, int]:
    """(RSS in MiB, open file descriptors) of a process."""
    rss = 0.0
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            rss = int(line.split()[1]) / 1024.0
    return rss, len(os.listdir(f"/proc/{pid}/fd"))


def test_world_of_64_objects_is_valid():
    world = parse_world(world_of_64(), "grid64")
    assert len(world.objects) == 64


@pytest.mark.soak
def test_soak_flat_rss_and_files(no_leaks, tmp_path, ros_domain):
    cycles = int(os.environ.get("ROGER_SOAK_CYCLES", "2000"))
    world = tmp_path / "grid64.yaml"
    world.write_text(yaml.safe_dump(world_of_64()))
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [*ROGER, "run", "--world", str(world), "--policy", "qlearning", "--cycles",
         str(cycles), "--out", str(out), "--quiet", "--domain-id", str(ros_domain),
         "--timeout", str(60 + 3 * cycles)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    samples: dict[str, list[tuple[int, float, int]]] = {n: [] for n in NODE_MODULES}
    try:
        while proc.poll() is None:
            done = len(rows_of(out / "cycles.csv"))
            for name in NODE_MODULES:
                pid = node_pid(proc.pid, name)
                if pid is not None and done > 0:
                    try:
                        samples[name].append((done, *sample(pid)))
                    except OSError:
                        pass
            time.sleep(2.0)
        output = proc.stdout.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, output[-3000:]
    assert json.loads((out / "metrics.json").read_text())["cycles"] == cycles
    report = {}
    for name, rows in samples.items():
        arr = np.asarray(rows, dtype=float)
        assert len(arr) >= 8, f"too few samples of {name}"
        quarter = len(arr) // 4
        # Warm-up (first quarter: torch, the map filling up) against the last quarter.
        early, late = arr[quarter:2 * quarter], arr[-quarter:]
        report[name] = {"rss_mib_start": round(float(early[:, 1].mean()), 1),
                        "rss_mib_end": round(float(late[:, 1].mean()), 1),
                        "rss_mib_max": round(float(arr[:, 1].max()), 1),
                        "fds_start": int(early[:, 2].max()), "fds_end": int(late[:, 2].max()),
                        "samples": len(arr)}
    (out / "soak.json").write_text(json.dumps(report, indent=2))
    print(json.dumps(report, indent=2))
    for name, r in report.items():
        assert r["rss_mib_end"] <= 1.10 * r["rss_mib_start"] + 16.0, (name, r)
        assert r["fds_end"] <= r["fds_start"] + 2, (name, r)
