"""Shared test setup: ROS network hygiene and leak checks.

Every test run talks only over loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) on a
domain id of its own, logs into a temporary folder, and must leave no child process and
no new Fast DDS file in /dev/shm behind.
"""

from __future__ import annotations

import os
import random
import tempfile
from pathlib import Path

import pytest

from roger_common.dds import apply_dds_defaults

_LOG_DIR = tempfile.mkdtemp(prefix="roger-test-ros-logs-")
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
apply_dds_defaults(os.environ)  # the same Fast DDS profile as every Roger process
os.environ["ROS_LOG_DIR"] = _LOG_DIR
os.environ.setdefault("OMP_NUM_THREADS", "1")
# One domain per test session (pytest-xdist workers or parallel CI runs get different ones).
os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 101))

REPO = Path(__file__).resolve().parents[1]
WORLDS = REPO / "worlds"


def shm_files() -> set[str]:
    """Fast DDS files in /dev/shm."""
    try:
        return {f for f in os.listdir("/dev/shm") if "fastrtps" in f or "fastdds" in f}
    except FileNotFoundError:
        return set()


def child_pids() -> set[int]:
    """Live child processes of this test process (zombies excluded)."""
    me = os.getpid()
    pids = set()
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()
        if int(fields[1]) == me and fields[0] != "Z":
            pids.add(int(d.name))
    return pids


@pytest.fixture
def no_leaks():
    """Fail the test if it leaves a child process or a new /dev/shm file behind.

    A leaked file is one that appeared during the test and that no live process holds:
    files of other graphs running on the machine at the same time are in use (and so are
    the port files Fast DDS keeps mapped in this process until it exits).
    """
    from roger_bringup.orchestrator import held_shm_files

    before_shm = shm_files()
    before_children = child_pids()
    yield
    leaked_children = child_pids() - before_children
    new_shm = shm_files() - before_shm - held_shm_files()
    assert not leaked_children, f"child processes left running: {sorted(leaked_children)}"
    assert not new_shm, f"files left in /dev/shm: {sorted(new_shm)}"


@pytest.fixture
def ros_domain() -> int:
    """A fresh domain id for a test that starts a graph."""
    return random.SystemRandom().randint(1, 101)


@pytest.fixture
def ros_context(ros_domain, monkeypatch):
    """An rclpy Context of the test's own on its domain, in the repository folder (node
    defaults such as the world file are relative to it)."""
    from ros_helpers import ros_context as make_context

    monkeypatch.chdir(REPO)
    with make_context(ros_domain) as context:
        yield context


@pytest.fixture(scope="module")
def one_torch_thread():
    """Torch on one thread for a test module (the memory nodes run so, docs/memory.md:
    the matrices are tiny), restored afterwards."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
