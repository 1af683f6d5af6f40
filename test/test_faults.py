"""Fault injection on the real graph: kill -9 each node mid-run, corrupt the stored files.

Killing any one node neither ends the run nor loses a stored object or Q-value: the
orchestrator restarts it, the memory node reloads its file, the attention node resumes
from its state file, and cycles.csv stays one row per cycle number.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import WORLDS

from roger_attention.fsm import State
from roger_common.types import Action
from roger_memory.persistence import load_snapshot

ROGER = [sys.executable, "-m", "roger_bringup.cli"]
NODE_MODULES = {"sim": "roger_sim.sim_node", "perception": "roger_perception.perception_node",
                "memory": "roger_memory.memory_node",
                "attention": "roger_attention.attention_node"}
ALPHA = 0.5  # QLearningConfig's default learning rate


def node_pid(orchestrator: int, name: str) -> int | None:
    """Pid of the live child of ``orchestrator`` running node ``name``."""
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            cmd = (d / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if int(fields[1]) == orchestrator and fields[0] != "Z" \
                and NODE_MODULES[name].encode() in cmd:
            return int(d.name)
    return None


def rows_of(path: Path) -> list[list[str]]:
    """Data rows of cycles.csv so far."""
    if not path.exists():
        return []
    with open(path) as fh:
        return list(csv.reader(fh))[1:]


def wait_rows(proc: subprocess.Popen, path: Path, n: int, timeout: float = 120.0) -> None:
    """Wait until cycles.csv holds ``n`` rows (the run must keep going meanwhile)."""
    deadline = time.monotonic() + timeout
    while len(rows_of(path)) < n:
        assert proc.poll() is None, f"the run ended early:\n{proc.stdout.read()}"
        assert time.monotonic() < deadline, f"stuck at {len(rows_of(path))} rows"
        time.sleep(0.1)


def test_kill_each_node_mid_run_loses_nothing(no_leaks, tmp_path, ros_domain):
    out = tmp_path / "run"
    cycles = 44
    proc = subprocess.Popen(
        [*ROGER, "run", "--world", str(WORLDS / "table1.yaml"), "--policy", "qlearning",
         "--cycles", str(cycles), "--seed", "1", "--out", str(out), "--quiet",
         "--domain-id", str(ros_domain), "--timeout", "400"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    killed = []
    try:
        csv_path = out / "cycles.csv"
        for i, name in enumerate(("memory", "sim", "attention", "perception")):
            wait_rows(proc, csv_path, 6 + 8 * i)
            pid = node_pid(proc.pid, name)
            assert pid is not None, f"no {name} process"
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)
        output, _ = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, output
    for name in NODE_MODULES:
        assert f"node {name} died (killed by SIGKILL)" in output, output
    status = json.loads((out / "run_status.json").read_text())
    assert status["status"].startswith("done") and status["restarts"] == dict.fromkeys(
        NODE_MODULES, 1), status
    # One row per cycle number, none lost or repeated.
    rows = rows_of(out / "cycles.csv")
    assert [int(r[0]) for r in rows] == list(range(1, cycles + 1))
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["cycles"] == cycles
    assert metrics["attention_shifts"] + metrics["improvements"] + metrics["map_updates"] \
        == cycles
    assert metrics["map_updates"] == metrics["positive_identifications"] \
        + metrics["new_objects"] + metrics["remaps"]
    # Every stored object is in the memory file, once.
    stored = sum(1 for r in rows if r[7] == "stored")
    assert stored == metrics["new_objects"] >= 1
    assert load_snapshot(out / "memory.pt").n_addresses == stored
    # The Q-table is the sum of every recorded update: none lost to a restart.
    table = json.loads((out / "qtable.json").read_text())
    q = np.full((6, 4), float(table["initial_q"]))
    for r in rows:
        if r[4]:
            q[State.from_bits(r[1]).index, int(Action[r[2].upper()])] += ALPHA * float(r[4])
    np.testing.assert_allclose(np.asarray(table["q"]), q, atol=1e-4)
    # No file of a killed node is left in /dev/shm (no_leaks checks that too).
    for pid in killed:
        assert not any(str(pid) in f for f in os.listdir("/dev/shm"))


@pytest.mark.parametrize("content", [b"not a memory file at all", b"ROGERMEM\x01"])
def test_corrupt_memory_file_is_refused_with_one_line(no_leaks, tmp_path, content):
    memory = tmp_path / "ltm.pt"
    memory.write_bytes(content)
    proc = subprocess.run(
        [*ROGER, "run", "--world", str(WORLDS / "table1.yaml"), "--memory", str(memory),
         "--out", str(tmp_path / "o"), "--cycles", "2"],
        capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 2
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and "pybullet build" not in ln]
    assert len(lines) == 1 and "ltm.pt" in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr


def test_corrupt_qtable_file_is_refused_with_one_line(no_leaks, tmp_path):
    qtable = tmp_path / "q.json"
    qtable.write_text('{"format": "roger_qtable/1", "q": [[1, 2]')
    proc = subprocess.run(
        [*ROGER, "run", "--world", str(WORLDS / "table1.yaml"), "--qtable", str(qtable),
         "--policy", "qlearning", "--out", str(tmp_path / "o"), "--cycles", "2"],
        capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 2
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and "pybullet build" not in ln]
    assert len(lines) == 1 and "q.json" in lines[0], proc.stderr


def test_sigterm_mid_run_stops_every_node(no_leaks, tmp_path, ros_domain):
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [*ROGER, "run", "--world", str(WORLDS / "table1.yaml"), "--cycles", "100000",
         "--out", str(out), "--quiet", "--domain-id", str(ros_domain)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        wait_rows(proc, out / "cycles.csv", 2)
        pids = [node_pid(proc.pid, n) for n in NODE_MODULES]
        proc.send_signal(signal.SIGTERM)
        output, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130 and "stopped by SIGTERM" in output, output
    assert all(p is not None and not Path(f"/proc/{p}").exists() for p in pids)
    status = json.loads((out / "run_status.json").read_text())
    assert status["killed_on_stop"] == [], status
