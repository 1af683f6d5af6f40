"""roger sweep and Table 2 as one module: the statistics, the spec, resumption after a
failure or a kill, and the embedded Ray's ports and leftovers (issue 37).

The Ray test runs a tiny sweep (2 worlds x 1 seed x 2 policies, 6 cycles) through the
real ``roger sweep`` command; the others run in this process without Ray.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
import yaml
from conftest import WORLDS

from roger_common.errors import ConfigError
from roger_experiments import sweep
from roger_experiments.ray_runner import LOOPBACK_ENV
from roger_experiments.runners import Job, RunSpec, SequentialRunner, run_in_process
from roger_experiments.table2 import paired_test, wilcoxon_signed_rank

TINY = {"worlds": [str(WORLDS / "table1.yaml"),
                   {"recipe": "default", "n_categories": 3, "copies": 2, "seeds": [5]}],
        "seeds": [0], "policies": ["qlearning", "straightforward"], "features": ["paper"],
        "draws": 0, "cycles": 6, "mode": "in_process"}


# --- Statistics ---------------------------------------------------------------------------

def test_wilcoxon_is_exact_with_and_without_ties():
    # Five positive differences: the one most extreme arrangement of 2^5 on each side.
    assert wilcoxon_signed_rank([1, 2, 3, 4, 5])["p"] == pytest.approx(2 / 32)
    # Zeros are dropped; the rank-biserial correlation is +1 when every pair agrees.
    w = wilcoxon_signed_rank([0, 1, 2, 3, 4, 5])
    assert w["n"] == 5 and w["rank_biserial"] == 1.0
    # Symmetric differences: no effect, p = 1.
    assert wilcoxon_signed_rank([-2, -1, 1, 2])["p"] == pytest.approx(1.0)
    # Ties (mean ranks 1.5, 1.5, 3): W+ = 4.5 of 6. Exact null: W+ in {0, 1.5, 1.5, 3, 3,
    # 4.5, 4.5, 6}; P(W+ >= 4.5) = 3/8, two-sided 0.75.
    assert wilcoxon_signed_rank([1, -1, 2])["p"] == pytest.approx(0.75)
    assert wilcoxon_signed_rank([])["p"] == 1.0


def test_paired_test_verdicts_follow_the_claimed_direction():
    more = {f"w{k}": [1.0 + k % 3, 2.0] for k in range(10)}
    assert paired_test(more, +1)["verdict"] == "holds"
    assert paired_test(more, -1)["verdict"] == "contradicted"
    mixed = {f"w{k}": [(-1.0) ** k] for k in range(10)}
    judged = paired_test(mixed, +1)
    assert judged["verdict"] == "not shown" and judged["pairs"] == 10
    lo, hi = judged["ci95"]
    assert lo < 0 < hi


# --- The spec -------------------------------------------------------------------------------

def test_spec_keys_recipes_and_errors(tmp_path):
    spec = sweep.parse_spec({**TINY, "cycles": [6, "until-complete"], "draws": 2,
                             "worlds": [*TINY["worlds"],
                                        {"recipe": "shape_twins", "n_categories": 3,
                                         "copies": 2, "seeds": {"start": 7, "count": 2}}]},
                            "tiny.yaml", tmp_path)
    assert [w.name for w in spec.worlds] == ["table1", "random_3x2_5", "random_3x2_7_twins",
                                             "random_3x2_8_twins"]
    assert spec.cycles == (6, None)
    cells = sweep.cells(spec, "v1")
    # Q-learning once per draw, straightforward once: 4 worlds x 2 budgets x (2 + 1).
    assert len(cells) == 4 * 2 * 3 and len({c.key for c in cells}) == len(cells)
    assert {c.key for c in cells} != {c.key for c in sweep.cells(spec, "v2")}
    for bad, words in (({"mode": "cluster"}, "mode"), ({"colour": 1}, "unknown key"),
                       ({"worlds": [{"recipe": "spiral"}]}, "recipe"),
                       ({"cycles": "forever"}, "cycles")):
        with pytest.raises(ConfigError, match=words):
            sweep.parse_spec({**TINY, **bad}, "bad.yaml", tmp_path)


def test_a_training_world_that_is_an_evaluation_world_is_refused(tmp_path):
    # Draw 1 trains on random worlds of seeds 5 and 6: the evaluation's random_8x3_5 too.
    spec = sweep.parse_spec({**TINY, "draws": 1, "worlds": [
        {"recipe": "default", "n_categories": 8, "copies": 3, "seeds": [5],
         "size_range": [0.08, 0.14]}],
        "training": {"worlds": 2, "seeds": 1, "cycles": 6, "world_seed0": 5}},
        "t.yaml", tmp_path)
    with pytest.raises(ConfigError, match="is the evaluation world"):
        sweep.check_disjoint(spec)


def test_shipped_claims_spec_parses():
    spec = sweep.load_spec(Path(__file__).resolve().parents[1] / "sweeps" / "claims.yaml")
    assert len(spec.worlds) >= 20 and spec.draws == 3 and len(spec.seeds) == 2
    sweep.check_disjoint(spec)


# --- Failures and resumption (in process, no Ray) -------------------------------------------

def test_failing_cells_are_recorded_and_only_unfinished_cells_run_again(tmp_path):
    spec = sweep.parse_spec({**TINY, "worlds": TINY["worlds"][1:]}, "tiny.yaml", tmp_path)
    out = tmp_path / "sweep"
    calls: list[str] = []

    def flaky(run, folder):
        calls.append(f"{run.policy}@{Path(run.world).stem}")
        if run.policy == "straightforward":
            raise RuntimeError("a run that fails")
        return run_in_process(run, folder)

    def runner(run_fn):
        inner = SequentialRunner(run_fn, keep_going=True)

        def go(jobs: list[Job]):
            for job, result in inner(jobs):
                if not isinstance(result, Exception):
                    # What RayRunner does: the run's folder gets the caller's files too.
                    for name, data in job.extra.items():
                        (job.out / name).write_bytes(data)
                yield job, result
        return go

    first = sweep.run_sweep(spec, out, runner(flaky), runner(flaky), "v1", progress=False)
    assert first["done"] == 1 and first["failed"] == 1 and len(calls) == 2
    rows = (out / "runs.csv").read_text().splitlines()
    assert len(rows) == 1 + 2 and ",failed," in rows[2] and "a run that fails" in rows[2]
    failed = sorted((out / "failed").iterdir())
    assert len(failed) == 1
    assert "a run that fails" in (failed[0] / "error.txt").read_text()
    # A driver killed while a cell was being written leaves a folder without cell.json
    # (or a scratch folder): that cell is not finished.
    done = sorted(p for p in (out / "cells").iterdir())
    (done[0] / "cell.json").unlink()
    again: list[str] = []

    def counting(run, folder):
        again.append(run.policy)
        return run_in_process(run, folder)
    second = sweep.run_sweep(spec, out, runner(counting), runner(counting), "v1",
                             progress=False)
    assert second["done"] == 2 and second["failed"] == 0
    assert sorted(again) == ["qlearning", "straightforward"]
    assert not (out / "failed").exists() or not any((out / "failed").iterdir())
    header, *lines = (out / "runs.csv").read_text().splitlines()
    columns = header.split(",")
    for key in ("key", "world_name", "seed", "policy", "features", "draw", "budget",
                "status", "attention_shifts", "every_object_visited", "wall_seconds"):
        assert key in columns, key
    assert all(",done," in line for line in lines)
    for name in ("report.md", "table2.json", "claims.json", "fig_attention_shifts.png"):
        assert (out / name).stat().st_size > 0, name
    # A third pass finds everything on disk and runs nothing.
    again.clear()
    third = sweep.run_sweep(spec, out, runner(counting), runner(counting), "v1",
                            progress=False)
    assert again == [] and third["done"] == 2


# --- The embedded Ray: ports, results, leftovers --------------------------------------------

def _listening(pids: set[int]) -> set[tuple[str, str]]:
    """(process name, local address) of every listening TCP socket of ``pids``."""
    inodes: dict[str, int] = {}
    for pid in pids:
        try:
            for fd in Path(f"/proc/{pid}/fd").iterdir():
                link = os.readlink(fd)
                if link.startswith("socket:["):
                    inodes[link[8:-1]] = pid
        except OSError:
            continue
    found = set()
    for table, v6 in (("/proc/net/tcp", False), ("/proc/net/tcp6", True)):
        for line in Path(table).read_text().splitlines()[1:]:
            parts = line.split()
            if parts[3] != "0A" or parts[9] not in inodes:  # 0A: LISTEN
                continue
            host = parts[1].split(":")[0]
            if v6:
                addr = ("::1" if host == "0" * 31 + "1" else "::" if host == "0" * 32 else
                        "127.0.0.1" if host.endswith("0100007F") and
                        host.startswith("0000000000000000FFFF0000") else f"[{host}]")
            else:
                addr = ".".join(str(int(host[i:i + 2], 16)) for i in (6, 4, 2, 0))
            try:
                name = Path(f"/proc/{inodes[parts[9]]}/comm").read_text().strip()
            except OSError:
                name = "?"
            found.add((name, addr))
    return found


def _ray_pids(marker: str) -> set[int]:
    """Processes of one Ray instance: its temp folder in their command line, or (Ray's
    agents retitle themselves "ray::DashboardAgent" and outlive their raylet for a minute)
    a file open under it."""
    pids = set()
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if marker in (d / "cmdline").read_bytes().decode(errors="replace"):
                    pids.add(int(d.name))
                    continue
                for fd in (d / "fd").iterdir():
                    if os.readlink(fd).startswith(marker):
                        pids.add(int(d.name))
                        break
            except OSError:
                continue
    return pids


@pytest.fixture
def ray_tmp():
    """Ray's temp folder for one test (short: Ray's socket paths live in it); whatever a
    failed test left running from it is stopped afterwards, and the folder removed."""
    path = Path(tempfile.mkdtemp(prefix="rr", dir="/tmp"))
    yield path
    _stop(_ray_pids(str(path)))
    shutil.rmtree(path, ignore_errors=True)


def test_embedded_graph_sweep_loopback_only_side_by_side_and_nothing_left(no_leaks, ray_tmp,
                                                                          tmp_path):
    # Two graph cells at once on the embedded Ray (2 workers), each on a ROS domain of its
    # own; every port the sweep's processes listen on is loopback; nothing is left after.
    shm_before = set(os.listdir("/dev/shm"))
    spec_file = tmp_path / "graph.yaml"
    spec_file.write_text(yaml.safe_dump({**TINY, "worlds": [str(WORLDS / "table1.yaml")],
                                         "mode": "graph"}))
    out = tmp_path / "sweep"
    env = {**os.environ, "RAY_TMPDIR": str(ray_tmp)}
    env.pop("RAY_ADDRESS", None)
    env.pop(LOOPBACK_ENV, None)  # the sweep's own default, not the caller's
    proc = subprocess.Popen([sys.executable, "-m", "roger_bringup.cli", "sweep",
                             str(spec_file), "--out", str(out), "--workers", "2", "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=env)
    seen: set[tuple[str, str]] = set()
    try:
        while proc.poll() is None:
            seen |= _listening(_ray_pids(str(ray_tmp)) | {proc.pid})
            time.sleep(0.2)
        output = proc.stdout.read() if proc.stdout else ""
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        if proc.stdout:
            proc.stdout.close()
    assert proc.returncode == 0, output[-3000:]
    names = {name for name, _ in seen}
    assert {"gcs_server", "raylet"} <= names, seen
    exposed = sorted((n, a) for n, a in seen if a not in ("127.0.0.1", "::1"))
    assert not exposed, f"listening beyond loopback: {exposed}"
    # Every Ray process is gone, and Ray left nothing in /dev/shm.
    left = _ray_pids(str(ray_tmp))
    for _ in range(100):
        if not left:
            break
        time.sleep(0.1)
        left = _ray_pids(str(ray_tmp))
    assert not left, f"Ray processes left: {sorted(left)}"
    assert not (set(os.listdir("/dev/shm")) - shm_before - _roger_shm()), \
        set(os.listdir("/dev/shm")) - shm_before
    # Each cell has its own complete cycles.csv, equal to the same cell run alone (in
    # process: test_graph_matches_core holds the graph to the core loop row for row).
    here = tmp_path / "here"
    rows = {json.loads((c / "cell.json").read_text())["key"]: c
            for c in (out / "cells").iterdir()}
    assert len(rows) == 2
    domains = {json.loads((c / "metrics.json").read_text())["domain_id"] for c in rows.values()}
    assert len(domains) == 2, domains
    for key, folder in rows.items():
        cell = json.loads((folder / "cell.json").read_text())
        assert cell["key"] == key and folder.name == key
        run = RunSpec(cell["world"], Path(cell["world"]).read_text(), cell["policy"],
                            cell["seed"], cell["budget"], cell["features"])
        run_in_process(run, here / key)
        assert (here / key / "cycles.csv").read_text() == (folder / "cycles.csv").read_text()
        metrics = json.loads((folder / "metrics.json").read_text())
        assert metrics["cycles"] == 6 and metrics["policy"] == cell["policy"]


def _roger_shm() -> set[str]:
    """Fast DDS files another graph on the machine may have made meanwhile (not Ray's)."""
    return {f for f in os.listdir("/dev/shm") if "fastrtps" in f or f.startswith("sem.")}


def _stop(pids: set[int]) -> None:
    """SIGTERM, a bounded wait, then SIGKILL: what ``ray stop`` does, but only to the
    processes this test started (found by its own Ray temp folder)."""
    import signal

    for sig in (signal.SIGTERM, signal.SIGKILL):
        for pid in pids:
            try:
                os.kill(pid, sig)
            except ProcessLookupError:
                pass
        for _ in range(50):
            pids = {p for p in pids if Path(f"/proc/{p}").exists()
                    and "Z" not in Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1][:3]}
            if not pids:
                return
            time.sleep(0.1)


def test_a_two_node_cluster_runs_the_cells_as_the_embedded_ray_does(no_leaks, ray_tmp,
                                                                    tmp_path):
    import socket

    shm_before = set(os.listdir("/dev/shm"))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    # A cluster of several nodes cannot use Ray's loopback-only mode (Ray refuses); token
    # authentication on, as Ray's own default for ray.init.
    import secrets

    env = {**os.environ, "RAY_TMPDIR": str(ray_tmp), "RAY_AUTH_MODE": "token",
           "RAY_AUTH_TOKEN": secrets.token_hex(32)}  # this cluster's own, not ~/.ray's
    for name in ("RAY_ADDRESS", LOOPBACK_ENV):
        env.pop(name, None)
    ray_bin = str(Path(sys.executable).parent / "ray")
    address = f"127.0.0.1:{port}"
    spec_file = tmp_path / "two.yaml"
    spec_file.write_text(yaml.safe_dump({**TINY, "worlds": [str(WORLDS / "table1.yaml")]}))
    out = tmp_path / "sweep"
    try:
        for cmd in ([ray_bin, "start", "--head", "--node-ip-address", "127.0.0.1", "--port",
                     str(port), "--num-cpus", "1", "--include-dashboard", "false",
                     "--disable-usage-stats"],
                    [ray_bin, "start", "--address", address, "--node-ip-address",
                     "127.0.0.1", "--num-cpus", "1", "--resources", '{"second_node": 1}',
                     "--disable-usage-stats"]):
            proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
            assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
        proc = subprocess.run([sys.executable, "-m", "roger_bringup.cli", "sweep",
                               str(spec_file), "--out", str(out), "--address", address,
                               "--quiet"], env=env, capture_output=True, text=True,
                              timeout=300)
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    finally:
        _stop(_ray_pids(str(ray_tmp)))
    assert not _ray_pids(str(ray_tmp))
    assert not (set(os.listdir("/dev/shm")) - shm_before - _roger_shm())
    folders = list((out / "cells").iterdir())
    assert len(folders) == 2
    # One run on each node (two 1-CPU nodes, two runs in flight), each equal to the same
    # cell run in this process.
    nodes = {json.loads((f / "worker.json").read_text())["node"] for f in folders}
    assert len(nodes) == 2, nodes
    for folder in folders:
        cell = json.loads((folder / "cell.json").read_text())
        run = RunSpec(cell["world"], Path(cell["world"]).read_text(), cell["policy"],
                      cell["seed"], cell["budget"], cell["features"])
        run_in_process(run, tmp_path / "here" / folder.name)
        assert ((tmp_path / "here" / folder.name / "cycles.csv").read_text()
                == (folder / "cycles.csv").read_text())
