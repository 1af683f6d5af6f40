"""The leak check blames a test for its own graph's files in /dev/shm, and only for those.

Two stand-in graphs (``dds_graph.py``: two rclpy participants each) run side by side on two
domains, each a process tree of its own. In each, one participant is killed with SIGKILL
and the other stops cleanly, which leaves files of every kind in /dev/shm (``shm_ledger``
lists them): port files named after the domain, port files of Roger's profile transport
(7000, 7001...) and participant segments. A ledger rooted at one graph must claim exactly
what that graph left, and nothing the other left, although the old check (new and
unheld) blamed both on the test.
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path

from conftest import SESSION_DOMAIN, free_domain
from shm_ledger import SHM, ShmLedger, domain_of, group_of, holders, process_tree, shm_files

HERE = Path(__file__).resolve().parent


def test_a_port_file_name_says_its_domain() -> None:
    assert domain_of("fastrtps_port9161") == 7  # 7400 + 250 * 7 + 11
    assert domain_of("sem.fastrtps_port12411_mutex") == 20
    assert domain_of("fastrtps_port12413_el") == 20
    assert domain_of("fastrtps_port7000") is None  # Roger's profile transport: any domain
    assert domain_of("sem.fastrtps_port7001_mutex") is None
    assert domain_of("fastrtps_4cce2f0a67eba4d4_el") is None  # a participant's segment
    assert group_of("sem.fastrtps_port7001_mutex") == "fastrtps_port7001"
    assert group_of("fastrtps_4cce2f0a67eba4d4_el") == "fastrtps_4cce2f0a67eba4d4"


def test_a_file_named_after_the_tests_domain_is_caught(no_leaks) -> None:
    # Nobody ever holds a port's mutex file: only its name can place it.
    ours = SHM / f"sem.fastrtps_port{7400 + 250 * SESSION_DOMAIN + 248}_mutex"
    other_domain = free_domain({SESSION_DOMAIN})
    theirs = SHM / f"sem.fastrtps_port{7400 + 250 * other_domain + 248}_mutex"
    ledger = ShmLedger()
    try:
        ours.write_bytes(b"\0" * 32)
        theirs.write_bytes(b"\0" * 32)
        assert ledger.leaked({SESSION_DOMAIN}) == [ours.name]
        assert ledger.leaked({other_domain}) == [theirs.name]
    finally:
        ours.unlink(missing_ok=True)
        theirs.unlink(missing_ok=True)


@dataclass
class StandIn:
    """A stand-in graph: a launcher process and its participants."""

    domain: int
    proc: subprocess.Popen
    pids: list[int] = field(default_factory=list)
    lines: queue.Queue = field(default_factory=queue.Queue)

    @classmethod
    def start(cls, domain: int, n: int = 2) -> StandIn:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
        proc = subprocess.Popen([sys.executable, str(HERE / "dds_graph.py"), str(n)],
                                env=env, stdout=subprocess.PIPE, text=True)
        graph = cls(domain, proc)
        threading.Thread(target=lambda: [graph.lines.put(ln) for ln in proc.stdout],
                         daemon=True).start()
        return graph

    def wait_ready(self, n: int = 2, timeout: float = 60.0) -> None:
        """Until every participant has heard from another (each maps the others' files)."""
        ready = 0
        while ready < n:
            line = self.lines.get(timeout=timeout)
            if line.startswith("pid "):
                self.pids.append(int(line.split()[1]))
            elif line.startswith("ready "):
                ready += 1

    def files(self) -> set[str]:
        """The ports and segments this graph's processes have open or mapped now."""
        return {group_of(name) for name, pids in holders().items() if pids & set(self.pids)}

    def end(self) -> None:
        # Its participants whether or not they said their pid (a launcher that timed out
        # before they did must not leave them running).
        for pid in set(self.pids) | (process_tree([self.proc.pid]) - {self.proc.pid}):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(timeout=30)


def left_unheld(ledger: ShmLedger, groups: set[str]) -> set[str]:
    """Files of ``groups`` created since ``ledger`` was made, of a port or segment that
    nobody holds now."""
    held = {group_of(name) for name in holders()}
    return {name for name, inode in shm_files().items()
            if (name, inode) not in ledger.before and group_of(name) not in held
            and group_of(name) in groups}


def test_each_graph_is_blamed_for_its_own_files_only(no_leaks) -> None:
    own_domain = free_domain({SESSION_DOMAIN})
    other_domain = free_domain({SESSION_DOMAIN, own_domain})
    mine = ShmLedger()  # this test's whole tree: what it must clean up at the end
    ledgers = {d: ShmLedger(roots=()) for d in (own_domain, other_domain)}
    graphs: dict[int, StandIn] = {}
    try:
        for d in ledgers:
            graphs[d] = StandIn.start(d)
        for d, graph in graphs.items():
            graph.wait_ready()
            ledgers[d].roots = {graph.proc.pid}
        files = {d: g.files() for d, g in graphs.items()}
        assert not files[own_domain] & files[other_domain], \
            sorted(files[own_domain] & files[other_domain])
        for ledger in (mine, *ledgers.values()):
            ledger.sample()
        for graph in graphs.values():
            os.kill(graph.pids[0], signal.SIGKILL)
            os.kill(graph.pids[1], signal.SIGINT)
            assert graph.proc.wait(timeout=60) == 0
        left = {d: left_unheld(mine, files[d]) for d in graphs}
        for d in graphs:
            # The killed participant left files of every kind, some of them unplaceable by
            # name: the old check (new and unheld) blamed them on whichever test ran.
            assert any(domain_of(f) == d for f in left[d]), left[d]
            assert any(domain_of(f) is None and "port" in f for f in left[d]), left[d]
            assert any(domain_of(f) is None and "port" not in f for f in left[d]), left[d]
        # Each ledger catches all its graph left and nothing of the other's.
        assert set(ledgers[own_domain].leaked({own_domain})) == left[own_domain]
        assert set(ledgers[other_domain].leaked({other_domain})) == left[other_domain]
    finally:
        mine.sample()
        for graph in graphs.values():
            graph.end()
        for name in mine.leaked({own_domain, other_domain}):
            (SHM / name).unlink(missing_ok=True)
