"""Shared test setup: ROS network hygiene and leak checks.

Every test run talks only over loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) on a
domain id of its own, logs into a temporary folder, and must leave no child process and
no new Fast DDS file of its own graph in /dev/shm behind (``shm_ledger`` says which files
are the test's own, so that another graph running on the machine is never blamed).
"""

from __future__ import annotations

import os
import random
import shutil
import tempfile
from pathlib import Path

import pytest
from shm_ledger import ShmLedger, domains_in_use

from roger_common.dds import apply_dds_defaults

_LOG_DIR = tempfile.mkdtemp(prefix="roger-test-ros-logs-")
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
apply_dds_defaults(os.environ)  # the same Fast DDS profile as every Roger process
os.environ["ROS_LOG_DIR"] = _LOG_DIR
os.environ.setdefault("OMP_NUM_THREADS", "1")


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """The ROS log folder goes when every test passed or no node logged anything; after a
    failure it stays, and the terminal summary says where, so that the nodes' logs can be
    read."""
    if exitstatus == 0 or not any(Path(_LOG_DIR).iterdir()):
        shutil.rmtree(_LOG_DIR, ignore_errors=True)


def pytest_terminal_summary(terminalreporter, exitstatus: int) -> None:  # type: ignore[no-untyped-def]
    if exitstatus != 0 and Path(_LOG_DIR).exists():
        terminalreporter.write_line(f"ROS node logs of this run: {_LOG_DIR}")


def free_domain(avoid: set[int] = frozenset()) -> int:
    """A random domain id in 1-101 that no graph on the machine uses now, nor ``avoid``."""
    taken = domains_in_use() | set(avoid)
    free = [d for d in range(1, 102) if d not in taken] or list(range(1, 102))
    return random.SystemRandom().choice(free)


# One domain per test session (pytest-xdist workers or parallel CI runs get different ones).
os.environ["ROS_DOMAIN_ID"] = str(free_domain())
SESSION_DOMAIN = int(os.environ["ROS_DOMAIN_ID"])

REPO = Path(__file__).resolve().parents[1]
WORLDS = REPO / "worlds"


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


def alive(pid: int) -> bool:
    """Whether process ``pid`` still runs (not gone, not a zombie). A process that exits
    between two reads of /proc is gone, not an error (ProcessLookupError, seen on a fresh
    clone's run of the two-node Ray test's clean-up)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


@pytest.fixture
def no_leaks(request):
    """Fail the test if it leaves a child process or a /dev/shm file of its graph behind.

    A leaked file is one of the test's own graph (its domains: the session's and any
    ``ros_domain``; or held by its own processes, ``shm_ledger``) that appeared during the
    test and that no live process holds. Files of other graphs on the machine, and the
    port files Fast DDS keeps mapped in this process until it exits, are not leaks.
    """
    ledger = ShmLedger().start()
    before_children = child_pids()
    try:
        yield
    finally:
        ledger.stop()
    leaked_children = child_pids() - before_children
    domains = {SESSION_DOMAIN, *getattr(request.node, "roger_domains", ())}
    new_shm = ledger.leaked(domains)
    assert not leaked_children, f"child processes left running: {sorted(leaked_children)}"
    assert not new_shm, f"files left in /dev/shm: {new_shm}"


@pytest.fixture
def ros_domain(request) -> int:
    """A fresh domain id, used by no graph on the machine now, for a test that starts one."""
    domain = free_domain({SESSION_DOMAIN})
    request.node.roger_domains = {*getattr(request.node, "roger_domains", ()), domain}
    return domain


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
