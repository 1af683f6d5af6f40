"""End to end: ``roger run`` starts the real graph as separate processes."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from conftest import REPO, WORLDS, alive, child_pids

from roger_bringup.orchestrator import StopRequested, install_signal_handlers
from roger_experiments.progress import counters_info

ROGER = [sys.executable, "-m", "roger_bringup.cli"]
CONTRACT_COLUMNS = ["cycle", "state", "action", "reward", "td_error", "roi", "true_object",
                    "outcome"]
METRIC_KEYS = {"policy", "world", "seed", "cycles", "attention_shifts", "improvements",
               "positive_identifications", "new_objects", "map_updates", "objects_in_world",
               "objects_visited", "identification_precision", "novelty_precision",
               "wall_seconds", "remaps", "remap_precision"}


def descendants(pid: int) -> set[int]:
    """Every live descendant of ``pid``."""
    children: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if fields[0] != "Z":
                children.setdefault(int(fields[1]), []).append(int(d.name))
    out, todo = set(), [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            out.add(c)
            todo.append(c)
    return out


@pytest.mark.parametrize("policy", ["straightforward", "qlearning"])
def test_roger_run_writes_outputs_and_leaves_nothing(no_leaks, tmp_path, ros_domain, policy):
    out = tmp_path / "run"
    proc = subprocess.run(
        [*ROGER, "run", "--world", str(WORLDS / "table1.yaml"), "--policy", policy,
         "--cycles", "8", "--seed", "3", "--out", str(out),
         "--domain-id", str(ros_domain), "--timeout", "200"],
        capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:] + proc.stdout[-2000:]
    assert f"ROS_DOMAIN_ID={ros_domain}" in proc.stdout
    # The printed hint is the whole environment a ros2 CLI needs to see the run.
    hint = next(ln for ln in proc.stdout.splitlines() if "watch with:" in ln)
    assert f"ROS_DOMAIN_ID={ros_domain} ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST" in hint
    assert "AMENT_PREFIX_PATH=" in hint
    metrics = json.loads((out / "metrics.json").read_text())
    assert METRIC_KEYS <= set(metrics)
    assert metrics["cycles"] == 8 and metrics["policy"] == policy
    assert metrics["attention_shifts"] + metrics["improvements"] + metrics["map_updates"] == 8
    assert metrics["map_updates"] == (metrics["positive_identifications"]
                                      + metrics["new_objects"] + metrics["remaps"])
    assert metrics["objects_in_world"] == 4 and metrics["objects_visited"] >= 1
    # Progress goes to stderr (plain lines: not a terminal); its last line is metrics.json's.
    shown = [ln for ln in proc.stderr.splitlines() if ln.startswith("  run table1")]
    assert shown and shown[-1] == (f"  run table1, {policy}: {metrics['cycles']}/8 cycles "
                                   f"{counters_info(metrics)}"), shown
    with open(out / "cycles.csv") as fh:
        rows = list(csv.reader(fh))
    assert rows[0][:8] == CONTRACT_COLUMNS
    assert [int(r[0]) for r in rows[1:]] == list(range(1, 9))
    assert any(r[6] for r in rows[1:]), "no cycle had an object under the attention window"
    for name in ("sim", "perception", "memory", "attention"):
        assert (out / "logs" / f"{name}.log").exists()
    status = json.loads((out / "run_status.json").read_text())
    assert status["status"] == "done" and status["killed_on_stop"] == []


def test_sigint_mid_run_stops_every_node(no_leaks, tmp_path, ros_domain):
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [*ROGER, "run", "--world", str(WORLDS / "table1.yaml"), "--cycles", "100000",
         "--out", str(out), "--quiet", "--domain-id", str(ros_domain)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 120
        # Wait until cycles are being recorded: the whole graph is running.
        while time.monotonic() < deadline:
            csv_path = out / "cycles.csv"
            if csv_path.exists() and len(csv_path.read_text().splitlines()) > 3:
                break
            assert proc.poll() is None, proc.stdout.read()
            time.sleep(0.2)
        else:
            pytest.fail("the run never started cycling")
        nodes = descendants(proc.pid)
        assert len(nodes) >= 4
        proc.send_signal(signal.SIGINT)
        output, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, output
    assert "stopped by SIGINT" in output
    time.sleep(0)  # children were reaped by the orchestrator before it exited
    left = [p for p in nodes if alive(p)]
    assert not left, f"node processes still alive after SIGINT: {left}"
    assert (out / "metrics.json").exists(), "metrics.json not written on interrupt"
    assert os.getpid() not in child_pids()


def test_a_signal_inside_rclpy_still_stops_the_run() -> None:
    # The orchestrator's handler raises StopRequested wherever the main thread is; inside
    # rclpy's message conversion pybind11 turns it into "RuntimeError: Unable to convert
    # call argument" (seen once in make test: exit 1 instead of 130). The guard remembers
    # the signal, so run_graph re-raises the stop; without a signal the error stays one.
    # The handler it replaces is given back: Python's default, or SIG_IGN when the suite
    # itself runs as a background job of a non-interactive shell (`make test &`).
    before = signal.getsignal(signal.SIGINT)
    guard = install_signal_handlers()
    try:
        assert guard.stop_requested(RuntimeError("other")) is None
        with pytest.raises(StopRequested):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1.0)  # the handler runs between two bytecodes, well before this ends
        stop = guard.stop_requested(RuntimeError("Unable to convert call argument '0'"))
        assert isinstance(stop, StopRequested) and str(stop) == "SIGINT"
    finally:
        guard()
    assert signal.getsignal(signal.SIGINT) is before


@pytest.mark.parametrize("content, field", [
    ("objects:\n  - name: a\n    shape: cube\n    position: [0.8, 0.0]\n    size: 0.2\n"
     "    intensity: 90\n    weight: 1.0\n", "shape"),
    ("objects: [\n", "line"),
    ("objects:\n  - name: a\n    shape: box\n    position: [0.8, 0.0]\n    size: -0.2\n"
     "    intensity: 90\n    weight: 1.0\n", "size"),
])
def test_bad_world_file_gives_one_line_and_exit_2(tmp_path, content, field):
    world = tmp_path / "bad.yaml"
    world.write_text(content)
    proc = subprocess.run([*ROGER, "run", "--world", str(world), "--out", str(tmp_path / "o")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and "pybullet build" not in ln]
    assert len(lines) == 1, proc.stderr
    assert "bad.yaml" in lines[0] and field in lines[0] and "Traceback" not in proc.stderr


def test_an_object_beyond_reach_is_handled_end_to_end(no_leaks, tmp_path, ros_domain):
    """worlds/beyond_reach.yaml: two objects in view beyond the arms' reach. A haptic
    improvement on them fails as a servo goal (controller status, convergence event,
    cycles.csv), and they are still identified or stored from what the eyes measured."""
    from roger_bringup.record import read_messages
    from roger_common.types import ControllerState
    from roger_sim.world import in_reach, load_world

    world = load_world(WORLDS / "beyond_reach.yaml")
    far = {o.name for o in world.objects if not in_reach(*o.position)}
    assert far == {"obj05", "obj06"}
    out = tmp_path / "run"
    proc = subprocess.run(
        [*ROGER, "run", "--world", str(WORLDS / "beyond_reach.yaml"), "--cycles", "40",
         "--seed", "0", "--out", str(out), "--quiet", "--record", str(out / "bag"),
         "--domain-id", str(ros_domain), "--timeout", "300"],
        capture_output=True, text=True, timeout=400)
    assert proc.returncode == 0, proc.stderr[-3000:] + proc.stdout[-2000:]
    with open(out / "cycles.csv") as fh:
        rows = list(csv.DictReader(fh))
    failed = [r for r in rows if r["action"] == "haptic_improvement" and r["converged"] == "0"]
    assert failed and all(r["true_object"] in far for r in failed if r["true_object"]), failed
    entries = {r["roi"] for r in failed}
    settled = [r for r in rows if r["action"] == "map_update" and r["roi"] in entries]
    assert settled and {r["outcome"] for r in settled} <= {"stored", "mapped", "remapped"}
    reached = [r for r in rows if r["action"] == "haptic_improvement"
               and r["true_object"] not in far and r["true_object"]]
    assert all(r["converged"] == "1" for r in reached), reached
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["failed_goals"] == len([r for r in rows if r["converged"] == "0"]) >= 1
    # The simulator reported the failure itself: the arm's status and the goal's event.
    events = [m for _, m, _ in read_messages(out / "bag", ("/roger/convergence",))]
    haptic_failed = [e for e in events if e.action == 2 and not e.converged]
    assert haptic_failed
    arm_status = {e.goal_id: dict(zip(e.controllers, e.status, strict=True))
                  for e in haptic_failed}
    assert all(ControllerState.FAILED in (s["left_arm"], s["right_arm"])
               for s in arm_status.values())
    statuses = [m for _, m, _ in read_messages(out / "bag", ("/roger/controller_status",))]
    assert any(ControllerState.FAILED in m.status for m in statuses)


def test_params_file_reaches_every_node_and_the_flags_win(no_leaks, tmp_path, ros_domain):
    """The documented example runs as is; a copy that changes a parameter changes what the
    robot does; roger run's own options win over it; a misspelt key is one line, exit 2."""
    example = yaml.safe_load((REPO / "docs" / "params_example.yaml").read_text())
    example["roger_attention"]["ros__parameters"]["visual_trials"] = 0   # never a visual look
    example["roger_attention"]["ros__parameters"]["policy"] = "qlearning"  # --policy wins
    edited = tmp_path / "params.yaml"
    edited.write_text(yaml.safe_dump(example))
    for params, cycles in ((REPO / "docs" / "params_example.yaml", 4), (edited, 8)):
        out = tmp_path / params.stem
        proc = subprocess.run(
            [*ROGER, "run", "--world", str(WORLDS / "table1.yaml"), "--cycles", str(cycles),
             "--params-file", str(params), "--out", str(out), "--quiet",
             "--domain-id", str(ros_domain), "--timeout", "200"],
            capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr[-3000:] + proc.stdout[-2000:]
        metrics = json.loads((out / "metrics.json").read_text())
        assert metrics["cycles"] == cycles and metrics["policy"] == "straightforward"
        with open(out / "cycles.csv") as fh:
            actions = [r["action"] for r in csv.DictReader(fh)]
        if params == edited:
            assert "visual_improvement" not in actions and "haptic_improvement" in actions
    example["roger_sim"]["ros__parameters"]["image_sise"] = 64
    edited.write_text(yaml.safe_dump(example))
    proc = subprocess.run(
        [*ROGER, "run", "--world", str(WORLDS / "table1.yaml"), "--cycles", "2",
         "--params-file", str(edited), "--out", str(tmp_path / "bad"), "--quiet",
         "--domain-id", str(ros_domain)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "roger_sim.ros__parameters.image_sise" in proc.stderr and "Traceback" not in proc.stderr
