"""The graph split across two hosts: the simulator on one, every other node on the other.

Two network namespaces joined by a veth pair stand for two machines (addresses in
10.213.0.0/24 that exist only inside them). Fast DDS talks UDP between them: shared memory
is switched off (FASTDDS_BUILTIN_TRANSPORTS=UDPv4), so nothing crosses by /dev/shm. Needs
root (``ip netns``); skips with the reason otherwise. The namespaces are removed even when
the test fails.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import uuid

import pytest
from conftest import WORLDS

from roger_common.dds import PROFILE_ENV

SUBNET = "10.213.0"


def ip(*args: str) -> subprocess.CompletedProcess:
    """Run ``ip`` and fail with its message."""
    return subprocess.run(["ip", *args], capture_output=True, text=True, check=True,
                          timeout=30)


@pytest.fixture
def two_hosts():
    """Names of two network namespaces joined by a veth pair: (host_a, host_b)."""
    tag = uuid.uuid4().hex[:6]
    a, b = f"roger-a-{tag}", f"roger-b-{tag}"
    try:
        ip("netns", "add", a)
    except (OSError, subprocess.CalledProcessError) as exc:
        msg = getattr(exc, "stderr", "") or str(exc)
        pytest.skip(f"cannot create network namespaces (needs root and iproute2): "
                    f"{msg.strip()}")
    try:
        ip("netns", "add", b)
        ip("link", "add", f"rva{tag}", "type", "veth", "peer", "name", f"rvb{tag}")
        for ns, dev, host in ((a, f"rva{tag}", 1), (b, f"rvb{tag}", 2)):
            ip("link", "set", dev, "netns", ns)
            ip("-n", ns, "addr", "add", f"{SUBNET}.{host}/24", "dev", dev)
            ip("-n", ns, "link", "set", dev, "up", "multicast", "on")
            ip("-n", ns, "link", "set", "lo", "up")
        yield a, b
    finally:
        for ns in (a, b):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=30,
                           check=False)


def test_sim_on_one_host_rest_on_the_other(no_leaks, tmp_path, ros_domain, two_hosts):
    host_a, host_b = two_hosts
    # UDP only, no shared-memory profile: the two hosts share /dev/shm, and traffic must
    # cross the veth pair to prove anything.
    env = dict({k: v for k, v in os.environ.items() if k != PROFILE_ENV},
               ROS_DOMAIN_ID=str(ros_domain),
               ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET", FASTDDS_BUILTIN_TRANSPORTS="UDPv4",
               ROS_LOG_DIR=str(tmp_path / "ros_logs"))
    world = WORLDS / "table1.yaml"
    sim_log = open(tmp_path / "sim.log", "wb")  # noqa: SIM115 (closed in finally)
    sim = subprocess.Popen(
        ["ip", "netns", "exec", host_a, sys.executable, "-m", "roger_sim.sim_node",
         "--ros-args", "-p", f"world:={world}", "-p", "use_sim_time:=true"],
        env={**env, "ROS_STATIC_PEERS": f"{SUBNET}.2"}, stdout=sim_log,
        stderr=subprocess.STDOUT)
    out = tmp_path / "run"
    script = textwrap.dedent(f"""
        from pathlib import Path
        from roger_bringup.run import RunOptions, run_graph
        run_graph(RunOptions(world=Path({str(world)!r}), out=Path({str(out)!r}), cycles=6,
                             seed=2, progress=False, external=("sim",), timeout_s=150,
                             domain_id={ros_domain}))
    """)
    try:
        proc = subprocess.run(["ip", "netns", "exec", host_b, sys.executable, "-c", script],
                              env={**env, "ROS_STATIC_PEERS": f"{SUBNET}.1"},
                              capture_output=True, text=True, timeout=240, check=False)
    finally:
        sim.terminate()
        try:
            sim.wait(timeout=20)
        except subprocess.TimeoutExpired:
            sim.kill()
            sim.wait()
        sim_log.close()
    sim_text = (tmp_path / "sim.log").read_text(errors="replace")
    assert proc.returncode == 0, proc.stderr[-3000:] + proc.stdout[-1500:] + sim_text[-1500:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["cycles"] == 6 and metrics["objects_in_world"] == 4
    assert metrics["attention_shifts"] + metrics["improvements"] + metrics["map_updates"] == 6
    assert "waiting for goals" in sim_text  # the simulator really ran on host A
