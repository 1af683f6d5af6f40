"""The experiment commands end to end: a short roger compare, and memory across runs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from conftest import WORLDS

from roger_experiments.core_loop import run_core
from roger_memory.memory import AssociativeMemory
from roger_sim.world import load_world


def test_short_compare_writes_every_file(no_leaks, tmp_path, ros_domain):
    out = tmp_path / "cmp"
    proc = subprocess.run(
        [sys.executable, "-m", "roger_bringup.cli", "compare", "--world",
         str(WORLDS / "table1.yaml"), "--cycles", "6", "--seeds", "1", "--out", str(out),
         "--train-worlds", "1", "--train-seeds", "1", "--stable-cycles", "10", "--quiet"],
        capture_output=True, text=True, timeout=400,
        env={**__import__("os").environ, "ROS_DOMAIN_ID": str(ros_domain)})
    assert proc.returncode == 0, proc.stderr[-3000:]
    for name in ("table2.md", "table2.json", "report.md", "fig4.png", "fig5.png", "fig6.png"):
        assert (out / name).stat().st_size > 0, name
    data = json.loads((out / "table2.json").read_text())
    assert set(data["table2"]) == {"qlearning", "straightforward"}
    for policy in ("qlearning", "straightforward"):
        m = json.loads((out / "runs" / f"{policy}_seed0" / "metrics.json").read_text())
        assert m["cycles"] == 6
        assert m["attention_shifts"] + m["improvements"] + m["map_updates"] == 6
        assert m["map_updates"] == (m["positive_identifications"] + m["new_objects"]
                                   + m["remaps"])
        errors = (out / "runs" / f"{policy}_seed0" / "errors.csv").read_text().splitlines()
        assert errors[0] == "cycle,kind,object,address,other,distance_m"
    report = (out / "report.md").read_text()
    assert "Q-learning performs more attention shifts" in report
    # The Q-learning runs used the table trained first, on a world other than this one.
    assert "trained now by `roger train`" in report and "not among them" in report
    assert (out / "train" / "td_errors.png").stat().st_size > 0
    # The sixth line: runs until the robot's own rule, judged on ground truth afterwards.
    assert "Every object is visited (ground truth, after the robot's own completion)" in report
    assert data["completion"]["runs"] == 2
    visited = 0
    for policy in ("qlearning", "straightforward"):
        m = json.loads((out / "complete" / f"{policy}_seed0" / "metrics.json").read_text())
        # Ended by the robot's own rule; "every object visited" is the ground truth's count
        # of visited objects against the world's, and the report counts it per run.
        assert m["complete"] is True
        assert m["every_object_visited"] is (m["objects_visited"] == m["objects_in_world"])
        visited += m["every_object_visited"]
        per_policy = data["completion"]["per_policy"][policy]
        assert per_policy["every_object_visited"] == int(m["every_object_visited"])
        assert per_policy["objects_visited"] == [m["objects_visited"]]
    assert data["completion"]["every_object_visited"] == visited


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "roger_bringup.cli", *args],
                          capture_output=True, text=True, timeout=600)


def test_train_learns_on_the_robot_and_compare_runs_the_table_frozen(tmp_path):
    train_out = tmp_path / "train"
    proc = cli("train", "--random-worlds", "1", "--world-seed0", "200", "--seeds", "1",
               "--cycles", "30", "--out", str(train_out), "--quiet")
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads((train_out / "train.json").read_text())
    (world,) = summary["worlds"]
    assert world["name"] == "random_8x3_200" and summary["updates"] == 30
    assert summary["made_by"]["random"]["seed0"] == 200
    lines = (train_out / "td_errors.csv").read_text().splitlines()
    assert lines[0] == "trial,run,world,seed,td_error,state,action" and len(lines) == 31
    assert (train_out / "td_errors.png").stat().st_size > 0
    table = (train_out / "qtable.json").read_bytes()

    def compare(world: Path, out: Path) -> str:
        # --stable-cycles 0: no run until the robot's completion (up to 2000 cycles a
        # policy; other tests cover it): this test is about the table, trained and frozen.
        proc = cli("compare", "--in-process", "--world", str(world), "--cycles", "8",
                   "--seeds", "1", "--qtable", str(train_out / "qtable.json"), "--out",
                   str(out), "--quiet", "--stable-cycles", "0")
        assert proc.returncode == 0, proc.stderr[-3000:]
        return proc.stderr + (out / "report.md").read_text()

    seen = compare(train_out / "worlds" / "random_8x3_200.yaml", tmp_path / "seen")
    assert "warning" in seen and "one of the training worlds" in seen
    unseen = compare(WORLDS / "table1.yaml", tmp_path / "unseen")
    assert "not among them" in unseen and "given with --qtable" in unseen
    rows = (tmp_path / "unseen" / "runs" / "qlearning_seed0" / "cycles.csv").read_text()
    assert all(line.split(",")[4] == "" for line in rows.splitlines()[1:])  # no TD: frozen
    assert (train_out / "qtable.json").read_bytes() == table


def test_second_run_with_the_first_runs_memory_stores_nothing_new(tmp_path):
    # two_rows: four categories, each twice. (Table 1's boxes 02 and 03 have one weight and
    # greys 79 and 69, which the memory's calibrated category spread cannot tell apart.)
    world = load_world(WORLDS / "two_rows.yaml")
    category = {o.name: o.category() for o in world.objects}
    rec1, loop1 = run_core(world, "straightforward", 40, seed=0, out=tmp_path / "one")
    rec1.close(0.0)
    assert rec1.scorer.results()["objects_visited"] == 8
    assert loop1.ctl.counters.new_objects == 4, "each category is stored once"
    loop1.memory.save(tmp_path / "ltm.bin")
    memory = AssociativeMemory.load(tmp_path / "ltm.bin")
    rec2, loop2 = run_core(world, "straightforward", 40, seed=1, out=tmp_path / "two",
                           memory=memory)
    rec2.close(0.0)
    assert loop2.ctl.counters.new_objects == 0
    assert loop2.ctl.counters.positive_identifications >= 4
    # Identified with the address stored for the same category in the first run.
    first = {r.address: category[r.true_object] for r in rec1.rows if r.outcome == "stored"}
    second = [(category[r.true_object], r.address) for r in rec2.rows if r.outcome == "mapped"]
    assert second and all(first[addr] == cat for cat, addr in second), (first, second)


def test_until_complete_on_an_unseen_world_visits_every_object(no_leaks, tmp_path, ros_domain):
    import yaml

    from roger_sim.world import world_to_dict
    from roger_sim.worldgen import random_world

    world = random_world(4, 2, seed=31, size_range=(0.10, 0.18))
    path = tmp_path / "unseen.yaml"
    path.write_text(yaml.safe_dump(world_to_dict(world), sort_keys=False))
    out = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-m", "roger_bringup.cli", "run", "--world", str(path),
         "--policy", "qlearning", "--until-complete", "--stable-cycles", "15",
         "--out", str(out), "--quiet", "--domain-id", str(ros_domain), "--timeout", "400"],
        capture_output=True, text=True, timeout=500)
    assert proc.returncode == 0, proc.stderr[-3000:]
    metrics = json.loads((out / "metrics.json").read_text())
    status = json.loads((out / "run_status.json").read_text())
    # Stopped by the robot's own rule (the attention node), judged on ground truth after.
    assert status["status"] == "complete", status
    assert metrics["complete"] is True and metrics["every_object_visited"] is True
    assert metrics["objects_visited"] == metrics["objects_in_world"] == 8
    assert "stopped after" in proc.stdout and "completion rule" in proc.stdout
